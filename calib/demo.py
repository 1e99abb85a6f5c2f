"""``calib demo``: the main job on the embedded campaign, start to finish.

Load the campaign (``experiments/campaign``), estimate every cycle's modulus and analyse the
strain-rate dependence, fit Ogden mu and alpha per layer with the FE simulation, export the
table in every format, run the discrepancy workflow, and write it all into one report folder
with a ``summary.md`` that links the pieces.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from ._io import write_text

__all__ = ["embedded_campaign_path", "run_demo"]


def embedded_campaign_path() -> Path:
    """Folder of the embedded campaign shipped with the ``experiments`` package."""
    import experiments

    path = Path(next(iter(experiments.__path__))) / "campaign"
    if not path.is_dir():
        raise FileNotFoundError(f"the embedded campaign is missing: {path}")
    return path


def run_demo(out_dir, *, workers=None, scheduler=None, progress=True, log=print,
             discover=True) -> dict:
    """Run the main job on the embedded campaign and write the report folder.

    Parameters
    ----------
    out_dir : path
        Report folder (created).
    workers, scheduler
        Passed to the fits (:func:`calib.fit.fit_campaign`).
    progress : bool
        Progress bars on stderr.
    log : callable
        Where progress notes go.
    discover : bool
        Run the discrepancy workflow as the last step.

    Returns
    -------
    dict
        Summary: paths, per-layer parameters, rate analysis, discovery, timings.
    """
    from .export import FORMATS, export_file
    from .fit import FitSettings, fit_campaign
    from .loaders import load_campaign
    from .modulus import campaign_moduli, moduli_frame
    from .rates import analyse_rates, plot_rates
    from .report import fit_plot_grid, save_figure, summary_table, write_fit_report

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    timings = {}
    start = time.perf_counter()

    data = embedded_campaign_path()
    campaign = load_campaign(data)
    write_text(out / "load_report.json", json.dumps(campaign.report(), indent=1))
    timings["load_s"] = time.perf_counter() - start
    log(f"loaded {len(campaign.cycles)} cycles from {data} "
        f"({len(campaign.rejected)} entries not loaded)")

    t0 = time.perf_counter()
    moduli = [m for m in campaign_moduli(campaign)]
    good = [m for m in moduli if m.ok]
    frame = moduli_frame(moduli)
    write_text(out / "moduli.csv", frame.to_csv(index=False))
    rates = analyse_rates(good)
    write_text(out / "rates.json", json.dumps(rates.to_dict(), indent=1))
    save_figure(plot_rates(rates, good), out / "rates.png")
    timings["modulus_s"] = time.perf_counter() - t0
    flagged = [t.layer for t in rates.layers if t.rate_dependent]
    log(f"moduli of {len(good)}/{len(moduli)} cycles; rate dependent layers: "
        f"{flagged or 'none'}; pooled change per decade {rates.pooled.to_dict()}")

    t0 = time.perf_counter()
    fits = fit_campaign(campaign, FitSettings(), max_workers=workers, scheduler=scheduler,
                        progress=progress)
    written = write_fit_report(fits, campaign, out / "fit")
    save_figure(fit_plot_grid(fits), out / "fit_overview.png")
    timings["fit_s"] = time.perf_counter() - t0
    log(f"fitted {len(fits.fits)} layers in {fits.wall_s:.1f} s")

    discovery = None
    table = fits.table()
    if discover:
        from .discover import discover_campaign, write_discovery_report

        t0 = time.perf_counter()
        discovery = discover_campaign(campaign, workers=workers, scheduler=scheduler,
                                      progress=progress, log=log, base=fits)
        write_discovery_report(discovery, campaign, out / "discover")
        timings["discover_s"] = time.perf_counter() - t0
        table = discovery.parameter_table()

    # the final model's table in every format (the base fit's is fit/parameters.csv)
    exports = {}
    suffix = {"csv": "csv", "json": "json", "markdown": "md", "latex": "tex",
              "abaqus": "inp", "febio": "feb"}
    for fmt in FORMATS:
        exports[fmt] = str(export_file(table, out / f"parameters.{suffix[fmt]}", fmt))

    timings["total_s"] = time.perf_counter() - start
    table_text = "FE-coupled fit, one-term Ogden (base model):\n" + summary_table(fits)
    if discovery is not None and discovery.model.effects:
        table_text += (f"\n\nWith the discovered effect ({' + '.join(discovery.accepted)}):\n"
                       + final_table_text(table))
    summary = {
        "data": str(data),
        "out": str(out),
        "cycles": len(campaign.cycles),
        "rejected": [{"file": r.file, "reason": r.reason} for r in campaign.rejected],
        "parameters": table.to_dict(orient="records"),
        "failed_layers": fits.failed,
        "rates": rates.to_dict(),
        "discovery": None if discovery is None else discovery.to_dict(),
        "outputs": {"fit": written, "exports": exports},
        "timings": timings,
    }
    write_text(out / "summary.json", json.dumps(summary, indent=1, default=float))
    write_text(out / "summary.md", _summary_markdown(summary, table_text))
    summary["table_text"] = table_text
    return summary


def final_table_text(table) -> str:
    """The final model's per-layer table as aligned text."""
    columns = [c for c in table.columns if c not in ("model", "mu_alpha_correlation",
                                                    "n_cycles")]
    head = "".join(f"{c:>14}" if i else f"{c:<6}" for i, c in enumerate(columns))
    rows = [head, "-" * len(head)]
    for _, r in table.iterrows():
        cells = []
        for i, c in enumerate(columns):
            v = r[c]
            if i == 0:
                cells.append(f"{v:<6}")
            elif isinstance(v, float):
                cells.append(f"{v:>14.4g}")
            else:
                cells.append(f"{v!s:>14}")
        rows.append("".join(cells))
    return "\n".join(rows)


def _summary_markdown(summary: dict, table_text: str) -> str:
    lines = [
        "# calib demo: the embedded Sylgard 527 campaign",
        "",
        f"Data: `{summary['data']}` ({summary['cycles']} loading cycles).",
        "",
        "## Per-layer Ogden parameters (FE-coupled fit, bonded platens)",
        "",
        "```",
        table_text,
        "```",
        "",
        "Exports of the final model's table: " + ", ".join(
            f"[{k}]({Path(v).name})" for k, v in summary["outputs"]["exports"].items())
        + "; the base fit's table is [fit/parameters.csv](fit/parameters.csv).",
        "",
        "Plots: [rate dependence (Fig. 11 of the thesis)](rates.png), "
        "[fits of all layers](fit_overview.png), per layer in [fit/](fit/).",
        "",
        "## Strain-rate dependence of the material modulus",
        "",
        "| layer | slope per decade (Pa) | 95 % CI (Pa) | p | rate dependent |",
        "| --- | --- | --- | --- | --- |",
    ]
    for t in summary["rates"]["layers"]:
        ci = t.get("slope_ci_Pa") or [float("nan")] * 2
        lines.append(f"| {t['layer']} | {t['slope_per_decade_Pa']:.0f} | "
                     f"[{ci[0]:.0f}, {ci[1]:.0f}] | {t['p_value']:.2g} | "
                     f"{'yes' if t['rate_dependent'] else 'no'} |")
    disc = summary.get("discovery")
    if disc:
        lines += ["", "## Discrepancy workflow", "",
                  f"Missing effect named: **{disc['effect']}**; RMS gap "
                  f"{1e3 * disc['rms_before_N']:.1f} mN before, "
                  f"{1e3 * disc['rms_after_N']:.1f} mN after; with every sample at its own mu "
                  f"and alpha {1e3 * disc['rms_samples_before_N']:.1f} mN before, "
                  f"{1e3 * disc['rms_samples_after_N']:.1f} mN after. See "
                  "[discover/](discover/)."]
    lines += ["", "## Timings (s)", ""]
    lines += [f"- {k}: {v:.1f}" for k, v in summary["timings"].items()]
    return "\n".join(lines) + "\n"
