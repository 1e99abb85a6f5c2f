"""Plots and text reports of fits, written atomically into a report folder.

Figures are built with matplotlib's object API on the Agg canvas (no pyplot state, no
display needed) and saved through :func:`save_figure`.
"""

from __future__ import annotations

import io
import math
import os
from pathlib import Path

import numpy as np

from ._io import write_bytes, write_text

__all__ = ["save_figure", "plot_layer_fit", "plot_layer_residuals", "layer_report",
           "write_fit_report"]

RATE_COLOURS = {0.17: "#1b9e77", 0.83: "#d95f02", 6.0: "#7570b3"}


def _figure(*size):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig, path: str | os.PathLike, dpi: int = 130) -> Path:
    """Save a figure as PNG atomically and return the path."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return write_bytes(path, buf.getvalue())


def _rate_colour(rate: float) -> str:
    for r, colour in RATE_COLOURS.items():
        if abs(rate - r) <= 0.05 * r:
            return colour
    return "0.3"


def plot_layer_fit(fit, cycles):
    """Measured cycles with their simulations at the fitted parameters.

    Parameters
    ----------
    fit : calib.fit.LayerFit
    cycles : sequence of calib.loaders.Cycle
        The layer's cycles (their full loading branches are drawn).
    """
    fig = _figure(7.0, 4.6)
    ax = fig.add_subplot()
    by_file = {c.file: c for c in cycles}
    for info, (travel, force) in zip(fit.data.cycles, fit.curves):
        colour = _rate_colour(info.rate_mm_per_s)
        cycle = by_file.get(info.file)
        if cycle is not None:
            ax.plot(cycle.displacement_mm, cycle.force_N, color=colour, lw=0.8, alpha=0.55)
        keep = travel <= info.height_mm * fit.data.levels[-1] * 1.001
        ax.plot(travel[keep], force[keep], color=colour, lw=1.4, ls="--")
    valid = fit.data.valid
    ax.plot(fit.data.travel_mm[valid], fit.data.force[valid], "k.", ms=3, label="compared levels")
    for rate, colour in RATE_COLOURS.items():
        if any(abs(c.rate_mm_per_s - rate) <= 0.05 * rate for c in fit.data.cycles):
            ax.plot([], [], color=colour, lw=1.2, label=f"{rate:g} mm/s")
    ax.plot([], [], "k--", lw=1.2, label="FE simulation (fit)")
    ax.set_xlabel("platen travel from contact (mm)")
    ax.set_ylabel("force (N)")
    ax.set_title(f"layer {fit.layer}: mu = {fit.mu_Pa:.0f} +- {fit.mu_stderr_Pa:.0f} Pa, "
                 f"alpha = {fit.alpha:.2f} +- {fit.alpha_stderr:.2f} ({fit.model})")
    ax.legend(frameon=False, fontsize=8)
    ax.grid(alpha=0.3)
    return fig


def plot_layer_residuals(fit):
    """Residuals (measured minus simulated) at the compared levels, per cycle."""
    fig = _figure(7.0, 4.0)
    ax_abs, ax_rel = fig.subplots(1, 2)
    markers = "osD^v<>p*h"
    samples = fit.data.samples
    for c, info in enumerate(fit.data.cycles):
        ok = fit.data.valid[c]
        lv = 100 * fit.data.levels[ok]
        r = fit.residual_N[c][ok]
        colour = _rate_colour(info.rate_mm_per_s)
        marker = markers[samples.index(info.sample) % len(markers)]
        ax_abs.plot(lv, 1e3 * r, marker=marker, color=colour, lw=0.8, ms=4)
        ax_rel.plot(lv, 100 * r / fit.predicted[c][ok], marker=marker, color=colour, lw=0.8,
                    ms=4, label=f"{info.sample} {info.rate_mm_per_s:g} mm/s")
    for ax in (ax_abs, ax_rel):
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_xlabel("strain level (%)")
        ax.grid(alpha=0.3)
    ax_abs.set_ylabel("measured - simulated (mN)")
    ax_rel.set_ylabel("measured / simulated - 1 (%)")
    ax_rel.legend(fontsize=6, frameon=False, ncol=2)
    fig.suptitle(f"layer {fit.layer}: residuals, RMS {1e3 * fit.rms_N:.1f} mN")
    return fig


def _fmt(x: float, digits: int = 4) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:.{digits}g}"


def layer_report(fit) -> str:
    """Plain-text report of one layer's fit."""
    hom = fit.homogeneous
    lines = [
        f"Layer {fit.layer}: FE-coupled fit ({fit.model}, nu = {fit.nu} fixed, bonded platens)",
        "=" * 72,
        f"mu    = {fit.mu_Pa:.1f} Pa  +- {_fmt(fit.mu_stderr_Pa)} Pa (standard error)",
        f"alpha = {fit.alpha:.4f}     +- {_fmt(fit.alpha_stderr)}",
        f"correlation(mu, alpha) = {_fmt(fit.mu_alpha_correlation, 3)}",
    ]
    for name, (lo, hi) in fit.ci.items():
        lines.append(f"95 % profile interval of {name}: [{lo:.4g}, {hi:.4g}]")
    lines += [
        f"RMS gap = {1e3 * fit.rms_N:.2f} mN over {fit.ndata} compared points of "
        f"{fit.n_cycles} cycles; reduced chi-square {fit.redchi:.3f}; AIC {fit.aic:.1f}, "
        f"BIC {fit.bic:.1f}",
        "",
        "Noise model (relative): samples' (log mu, alpha) sd "
        f"({math.sqrt(fit.noise.sample_cov[0, 0]):.4f}, "
        f"{math.sqrt(fit.noise.sample_cov[1, 1]):.4f}), cycle {fit.noise.cycle:.4f}, "
        f"level {fit.noise.level:.4f}",
        "",
        "Homogeneous closed-form fit (uniaxial Ogden stress x area, what a hand calibration "
        "would give):",
        f"  mu = {hom['mu_Pa']:.1f} Pa ({hom['mu_Pa'] / fit.mu_Pa - 1:+.1%} vs FE), "
        f"alpha = {hom['alpha']:.3f} ({hom['alpha'] / fit.alpha - 1:+.1%} vs FE)",
        f"Initial guesses: mu from the modulus estimator {fit.initial['mu_Pa_modulus']:.1f} Pa; "
        f"alpha {fit.initial['alpha_guess']:.3f} (homogeneous, bias-corrected by one FE solve)",
        "Discretisation correction (finer / fitting mesh, at the fitted alpha) at 10, 20, 30 %: "
        + ", ".join(f"{100 * (np.interp(x, fit.data.levels, fit.mesh_ratio) - 1):+.2f} %"
                    for x in (0.1, 0.2, 0.3)),
        f"Alpha surrogate vs direct solve at the optimum: max difference "
        f"{fit.surrogate_error:.2e} (relative)",
        f"Forward solves: {fit.n_solves} ({fit.solve_s:.1f} s); layer wall time "
        f"{fit.wall_s:.1f} s",
    ]
    if fit.warnings:
        lines += ["", "Warnings:"] + [f"  - {w}" for w in fit.warnings]
    lines += ["", "lmfit report (whitened residuals)", "-" * 34, fit.report]
    return "\n".join(lines) + "\n"


def write_fit_report(campaign_fit, campaign, out_dir: str | os.PathLike) -> dict:
    """Write ``parameters.csv`` and, per layer, the fit plot, residual plot and text report.

    Returns
    -------
    dict
        Paths written, by kind.
    """
    from .export import write_parameters

    out = Path(out_dir)
    written = {"parameters": None, "layers": {}}
    if campaign_fit.fits:
        written["parameters"] = str(write_parameters(campaign_fit.table(),
                                                     out / "parameters.csv"))
    for layer, fit in sorted(campaign_fit.fits.items()):
        cycles = campaign.select(layer=layer)
        paths = {
            "fit_plot": save_figure(plot_layer_fit(fit, cycles), out / f"fit_{layer}.png"),
            "residual_plot": save_figure(plot_layer_residuals(fit),
                                         out / f"residuals_{layer}.png"),
            "report": write_text(out / f"report_{layer}.txt", layer_report(fit)),
        }
        written["layers"][layer] = {k: str(v) for k, v in paths.items()}
    if campaign_fit.failed:
        text = "".join(f"{layer}: {reason}\n" for layer, reason in
                       sorted(campaign_fit.failed.items()))
        written["failed"] = str(write_text(out / "failed_layers.txt", text))
    return written


def summary_table(campaign_fit) -> str:
    """The per-layer table as aligned text for the terminal."""
    head = (f"{'layer':<6}{'mu_Pa':>10}{'+-':>8}{'alpha':>9}{'+-':>7}{'corr':>8}"
            f"{'rms_mN':>9}{'cycles':>8}{'hom_mu':>9}{'hom_a':>7}")
    rows = [head, "-" * len(head)]
    for layer, f in sorted(campaign_fit.fits.items()):
        rows.append(f"{layer:<6}{f.mu_Pa:>10.1f}{f.mu_stderr_Pa:>8.1f}{f.alpha:>9.3f}"
                    f"{f.alpha_stderr:>7.3f}{f.mu_alpha_correlation:>8.3f}"
                    f"{1e3 * f.rms_N:>9.2f}{f.n_cycles:>8d}{f.homogeneous['mu_Pa']:>9.0f}"
                    f"{f.homogeneous['alpha']:>7.2f}")
    for layer, reason in sorted(campaign_fit.failed.items()):
        rows.append(f"{layer:<6}failed: {reason}")
    return "\n".join(rows)


def fit_plot_grid(campaign_fit):
    """All layers' measured cycles and simulations on one figure (an overview)."""
    layers = sorted(campaign_fit.fits)
    n = max(1, len(layers))
    cols = min(3, n)
    rows = int(np.ceil(n / cols))
    fig = _figure(4.2 * cols, 3.2 * rows)
    axes = np.atleast_1d(fig.subplots(rows, cols)).ravel()
    for ax, layer in zip(axes, layers):
        fit = campaign_fit.fits[layer]
        valid = fit.data.valid
        for c, info in enumerate(fit.data.cycles):
            colour = _rate_colour(info.rate_mm_per_s)
            ax.plot(fit.data.travel_mm[c][valid[c]], fit.data.force[c][valid[c]], "o",
                    color=colour, ms=2.5)
            ax.plot(fit.data.travel_mm[c][valid[c]], fit.predicted[c][valid[c]], "-",
                    color=colour, lw=0.8)
        ax.set_title(f"{layer}: mu {fit.mu_Pa:.0f} Pa, alpha {fit.alpha:.2f}", fontsize=9)
        ax.set_xlabel("travel (mm)", fontsize=8)
        ax.set_ylabel("force (N)", fontsize=8)
        ax.grid(alpha=0.3)
    for ax in axes[len(layers):]:
        ax.set_visible(False)
    return fig
