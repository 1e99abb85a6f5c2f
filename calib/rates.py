r"""Strain-rate dependence of the material modulus, per layer and for the campaign.

Design of the campaign (du Plessis 2016, Sect. 6.1): per layer three samples, each tested
once at each platen speed (0.17, 0.83 and 6 mm/s) in a varied order. Samples differ (cut from
different places of a layer, slightly different sizes and cure), so a sample is a *block*:
comparing the rates within each sample removes the sample-to-sample scatter (5-10 %) from the
rate effect, leaving the cycle-to-cycle noise (2-3 %).

Per layer the model is ordinary least squares with one intercept per sample and a common
slope in the decimal logarithm of the rate,

.. math::

    E_{ij} = a_i + b \log_{10} v_j + \varepsilon_{ij}, \qquad
    \varepsilon_{ij} \sim N(0, s^2),

so :math:`b` is the change of the material modulus per tenfold increase of the platen speed
(Pa per decade). Its standard error, t-based confidence interval and two-sided p-value use
:math:`n - n_{samples} - 1` degrees of freedom (5 for a full 3 x 3 layer). A sample tested at
one rate only carries no information on :math:`b` (its own intercept absorbs it) and costs no
degree of freedom. The rate is log-spaced in the test plan (factor 4.9 then 7.2) and a
viscoelastic modulus rises about linearly in the logarithm of the rate over a few decades,
hence :math:`\log_{10} v`.

Six layers are tested per campaign, and one pooled campaign-level test is added: the
logarithm of the modulus against :math:`\log_{10} v` with one intercept per sample across all
layers (the layers' moduli differ by a factor of about two, so their rate effects are compared
as relative changes). The seven p-values form one family whose family-wise error rate is held
at ``significance`` by Holm's step-down procedure; ``rate_dependent`` is set from the
Holm-adjusted p-values. The confidence intervals are per test (not adjusted).

The test order matters: a sample softening from one test to the next (Mullins-like
preconditioning) looks like a rate effect if the order follows the rate. The analysis reports
the within-sample correlation between test order and :math:`\log_{10} v` per layer and notes
a confounded design.

References
----------
Holm S (1979). A simple sequentially rejective multiple test procedure. Scand J Stat
6:65-70.
du Plessis G (2016). Squashing brains. Sect. 8.1.2 and Fig. 11.
"""

from __future__ import annotations

import dataclasses
import io
import math
import os
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import special, stats

__all__ = [
    "RATES_MM_PER_S",
    "PooledTrend",
    "RateAnalysis",
    "RateTrend",
    "analyse_rates",
    "block_slope",
    "flag_rates",
    "holm",
    "plot_rates",
    "save_figure",
    "simulate_moduli",
]

#: Platen speeds of the campaign (mm/s).
RATES_MM_PER_S = (0.17, 0.83, 6.0)


# ================================================================================= statistics
def block_slope(y, x, block) -> tuple[float, float, int]:
    r"""OLS slope of ``y`` on ``x`` with one intercept per block (the within-block slope).

    Parameters
    ----------
    y, x : array_like, shape (n,)
        Response and regressor.
    block : array_like, shape (n,)
        Block label of each observation (any hashable values).

    Returns
    -------
    slope : float
        :math:`\hat b = \sum (x - \bar x_i)(y - \bar y_i) / \sum (x - \bar x_i)^2`;
        NaN if ``x`` does not vary within any block.
    stderr : float
        Standard error of the slope; NaN without residual degrees of freedom.
    dof : int
        Residual degrees of freedom, :math:`n - n_{blocks} - 1` (may be <= 0).

    Examples
    --------
    >>> b, se, dof = block_slope([1.0, 2.0, 11.0, 12.0], [0.0, 1.0, 0.0, 1.0], ["a", "a", "b", "b"])
    >>> b, dof
    (1.0, 1)
    """
    y = np.asarray(y, dtype=float)
    x = np.asarray(x, dtype=float)
    block = np.asarray(block)
    if not (y.shape == x.shape == block.shape and y.ndim == 1):
        raise ValueError(f"y, x and block must be 1-D of one length; got shapes {y.shape}, "
                         f"{x.shape}, {block.shape}")
    _, index = np.unique(block, return_inverse=True)
    n_blocks = int(index.max()) + 1 if index.size else 0
    counts = np.bincount(index, minlength=n_blocks)
    dx = x - (np.bincount(index, x, n_blocks) / counts)[index]
    dy = y - (np.bincount(index, y, n_blocks) / counts)[index]
    sxx = float(dx @ dx)
    dof = int(y.size - n_blocks - 1)
    if not sxx > 1e-12 * max(float(x @ x), 1e-300):
        return math.nan, math.nan, dof
    slope = float(dx @ dy) / sxx
    if dof <= 0:
        return slope, math.nan, dof
    resid = dy - slope * dx
    return slope, math.sqrt(float(resid @ resid) / dof / sxx), dof


def holm(p_values: Sequence[float]) -> np.ndarray:
    r"""Holm step-down adjusted p-values (NaN entries are left out of the family).

    Parameters
    ----------
    p_values : sequence of float
        Unadjusted p-values; NaN for a test that could not be made.

    Returns
    -------
    ndarray
        Adjusted p-values, :math:`\tilde p_{(k)} = \max_{j \le k} \min(1, (m - j + 1)
        p_{(j)})` in ascending order of :math:`p`; rejecting where :math:`\tilde p \le`
        the level holds the family-wise error rate at that level.

    Examples
    --------
    >>> holm([0.01, 0.04, 0.03, float("nan")]).round(3).tolist()
    [0.03, 0.06, 0.06, nan]
    """
    p = np.asarray(p_values, dtype=float)
    out = np.full(p.shape, np.nan)
    ok = np.flatnonzero(np.isfinite(p))
    m = ok.size
    if m == 0:
        return out
    order = ok[np.argsort(p[ok], kind="stable")]
    adjusted = np.minimum(1.0, (m - np.arange(m)) * p[order])
    out[order] = np.maximum.accumulate(adjusted)
    return out


def _t_test(slope: float, se: float, dof: int, confidence: float):
    """(t, p, ci_lo, ci_hi) of a slope; NaN where it cannot be tested."""
    if not (math.isfinite(slope) and math.isfinite(se) and dof > 0):
        return math.nan, math.nan, math.nan, math.nan
    if se == 0.0:
        return (math.copysign(math.inf, slope) if slope else math.nan,
                0.0 if slope else 1.0, slope, slope)
    t = slope / se
    p = float(2.0 * special.stdtr(dof, -abs(t)))  # two-sided, Student's t with dof
    half = float(special.stdtrit(dof, 0.5 + 0.5 * confidence)) * se
    return t, p, slope - half, slope + half


# ================================================================================= records
@dataclasses.dataclass(frozen=True)
class RateTrend:
    """Rate dependence of the material modulus of one layer.

    Attributes
    ----------
    layer : str
    slope_per_decade_Pa : float
        Change of the material modulus per tenfold increase of the platen speed (Pa).
    slope_stderr_Pa : float
        Its standard error (Pa).
    slope_ci_Pa : tuple of float
        Its t-based confidence interval at ``confidence`` (Pa), not adjusted for the
        multiple layers.
    t_value, p_value : float
        t statistic and two-sided p-value of :math:`b = 0`.
    p_holm : float
        Holm-adjusted p-value over the campaign's family of tests.
    rate_dependent : bool
        ``p_holm <= significance``.
    dof, n_cycles, n_samples : int
        Residual degrees of freedom, cycles and samples used.
    mean_modulus_Pa : float
        Mean material modulus of the cycles used (Pa).
    relative_slope_per_decade : float
        ``slope_per_decade_Pa / mean_modulus_Pa``.
    fitted_Pa : dict
        Model modulus at each rate tested (mm/s -> Pa), averaged over the samples.
    residual_sd_Pa : float
        Cycle-to-cycle scatter left by the model (Pa).
    order_rate_correlation : float
        Within-sample correlation between test order and log rate (NaN without test numbers);
        near +-1, preconditioning and rate dependence cannot be told apart.
    note : str or None
        Why the test could not be made, or what limits it.
    """

    layer: str
    slope_per_decade_Pa: float
    slope_stderr_Pa: float
    slope_ci_Pa: tuple[float, float]
    t_value: float
    p_value: float
    p_holm: float
    rate_dependent: bool
    dof: int
    n_cycles: int
    n_samples: int
    mean_modulus_Pa: float
    relative_slope_per_decade: float
    fitted_Pa: dict
    residual_sd_Pa: float
    order_rate_correlation: float
    note: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """Return the layer entry of ``calib modulus --json``."""
        return {
            "layer": self.layer,
            "slope_per_decade_Pa": self.slope_per_decade_Pa,
            "slope_ci_Pa": list(self.slope_ci_Pa),
            "p_value": self.p_value,
            "rate_dependent": bool(self.rate_dependent),
            "p_holm": self.p_holm,
            "slope_stderr_Pa": self.slope_stderr_Pa,
            "t_value": self.t_value,
            "dof": self.dof,
            "n_cycles": self.n_cycles,
            "n_samples": self.n_samples,
            "mean_E_material_Pa": self.mean_modulus_Pa,
            "relative_slope_per_decade": self.relative_slope_per_decade,
            "E_material_fitted_Pa": {f"{k:g}": v for k, v in self.fitted_Pa.items()},
            "residual_sd_Pa": self.residual_sd_Pa,
            "order_rate_correlation": self.order_rate_correlation,
            "note": self.note,
        }


@dataclasses.dataclass(frozen=True)
class PooledTrend:
    r"""Campaign-level rate dependence: relative change of the modulus per decade of rate.

    Attributes
    ----------
    slope_per_decade : float
        Slope of :math:`\ln E` against :math:`\log_{10} v` with one intercept per sample.
    relative_change_per_decade : float
        :math:`e^{b} - 1`, the fractional change of the modulus per tenfold rate.
    relative_change_ci : tuple of float
        Its confidence interval.
    t_value, p_value, p_holm : float
    rate_dependent : bool
    dof, n_cycles, n_samples, n_layers : int
    note : str or None
    """

    slope_per_decade: float
    relative_change_per_decade: float
    relative_change_ci: tuple[float, float]
    t_value: float
    p_value: float
    p_holm: float
    rate_dependent: bool
    dof: int
    n_cycles: int
    n_samples: int
    n_layers: int
    note: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """Return the ``pooled`` entry of ``calib modulus --json``."""
        return {
            "model": "ln(E_material) ~ sample + b log10(rate)",
            "slope_per_decade_ln": self.slope_per_decade,
            "relative_change_per_decade": self.relative_change_per_decade,
            "relative_change_ci": list(self.relative_change_ci),
            "t_value": self.t_value, "p_value": self.p_value, "p_holm": self.p_holm,
            "rate_dependent": bool(self.rate_dependent), "dof": self.dof,
            "n_cycles": self.n_cycles, "n_samples": self.n_samples, "n_layers": self.n_layers,
            "note": self.note,
        }


@dataclasses.dataclass(frozen=True)
class RateAnalysis:
    """Per-layer and pooled rate dependence of a campaign.

    Attributes
    ----------
    layers : tuple of RateTrend
        One per layer, sorted by name.
    pooled : PooledTrend
    significance : float
        Family-wise error rate of the Holm procedure.
    confidence : float
        Level of the confidence intervals.
    value : str
        The modulus analysed (column name, ``E_material_Pa``).
    excluded : tuple of tuple
        ``(file, reason)`` of every cycle left out (no modulus).
    """

    layers: tuple[RateTrend, ...]
    pooled: PooledTrend
    significance: float
    confidence: float
    value: str
    excluded: tuple[tuple[str, str], ...] = ()

    @property
    def rate_dependent(self) -> bool:
        """Whether any test of the family (a layer or the pooled test) is significant."""
        return self.pooled.rate_dependent or any(t.rate_dependent for t in self.layers)

    def layer(self, name: str) -> RateTrend:
        """Return the trend of one layer."""
        for t in self.layers:
            if t.layer == name:
                return t
        raise KeyError(f"no layer {name!r}; layers are {[t.layer for t in self.layers]}")

    def to_dict(self) -> dict[str, Any]:
        """Return ``{"layers": [...], "pooled": {...}, ...}`` for JSON."""
        return {
            "layers": [t.to_dict() for t in self.layers],
            "pooled": self.pooled.to_dict(),
            "significance": self.significance,
            "confidence": self.confidence,
            "multiplicity": f"Holm over {sum(math.isfinite(t.p_value) for t in self.layers)} "
                            f"layer tests and the pooled test",
            "excluded": [{"file": f, "reason": r} for f, r in self.excluded],
        }


# ================================================================================= analysis
def _frame(moduli, value: str):
    """Return a DataFrame with layer, sample, rate_mm_per_s, ``value`` (and test, file)."""
    import pandas as pd

    if not isinstance(moduli, pd.DataFrame):
        from .modulus import moduli_frame

        moduli = moduli_frame(list(moduli))
    missing = [c for c in ("layer", "sample", "rate_mm_per_s", value) if c not in moduli]
    if missing:
        raise ValueError(f"moduli table lacks the columns {missing}")
    return moduli


def _layer_trend(layer: str, E: np.ndarray, rate: np.ndarray, sample: np.ndarray,
                 test: np.ndarray | None, confidence: float) -> RateTrend:
    x = np.log10(rate)
    n_samples = len(set(sample.tolist()))
    slope, se, dof = block_slope(E, x, sample)
    t, p, lo, hi = _t_test(slope, se, dof, confidence)
    notes = []
    if not math.isfinite(slope):
        notes.append("the rate does not vary within any sample: no rate effect can be "
                     "estimated")
    elif dof <= 0:
        notes.append(f"{E.size} cycles of {n_samples} samples leave no residual degree of "
                     "freedom: no test")
    # model fit: per-sample intercepts, common slope
    fitted, resid_sd = {}, math.nan
    if math.isfinite(slope):
        keys = sample.tolist()
        offsets = {s: float(np.mean(E[sample == s] - slope * x[sample == s])) for s in set(keys)}
        mean_offset = float(np.mean(list(offsets.values())))
        fitted = {float(v): mean_offset + slope * math.log10(v) for v in sorted(set(rate))}
        if dof > 0:
            resid = E - np.array([offsets[s] for s in keys]) - slope * x
            resid_sd = math.sqrt(float(resid @ resid) / dof)
    order_r = math.nan
    if test is not None and np.all(np.isfinite(test)):
        _, index = np.unique(sample, return_inverse=True)
        counts = np.bincount(index)
        dt = test - (np.bincount(index, test) / counts)[index]
        dx = x - (np.bincount(index, x) / counts)[index]
        denom = math.sqrt(float(dt @ dt) * float(dx @ dx))
        if denom > 0.0:
            order_r = float(dt @ dx) / denom
            if abs(order_r) > 0.8:
                notes.append(f"test order and rate are confounded (within-sample correlation "
                             f"{order_r:+.2f}): softening from test to test would look like a "
                             "rate effect")
    mean_E = float(np.mean(E)) if E.size else math.nan
    return RateTrend(
        layer=layer, slope_per_decade_Pa=slope, slope_stderr_Pa=se, slope_ci_Pa=(lo, hi),
        t_value=t, p_value=p, p_holm=math.nan, rate_dependent=False, dof=dof,
        n_cycles=int(E.size), n_samples=n_samples, mean_modulus_Pa=mean_E,
        relative_slope_per_decade=slope / mean_E if E.size else math.nan,
        fitted_Pa=fitted, residual_sd_Pa=resid_sd, order_rate_correlation=order_r,
        note="; ".join(notes) or None,
    )


def analyse_rates(
    moduli,
    *,
    value: str = "E_material_Pa",
    significance: float = 0.05,
    confidence: float = 0.95,
) -> RateAnalysis:
    """Rate dependence of the modulus per layer and pooled, with Holm's family-wise control.

    Parameters
    ----------
    moduli : pandas.DataFrame or iterable of calib.modulus.CycleModulus
        One row per cycle with ``layer``, ``sample``, ``rate_mm_per_s``, ``value`` and
        optionally ``test`` and ``file``; rows whose ``value`` is missing are excluded (with
        their ``reason`` where the table has one).
    value : str
        Column analysed, default the material modulus (Pa).
    significance : float
        Family-wise error rate over the layer tests and the pooled test.
    confidence : float
        Level of the per-test confidence intervals.

    Returns
    -------
    RateAnalysis

    Raises
    ------
    ValueError
        Missing columns, non-positive rates, or levels outside (0, 1).
    """
    if not (0.0 < significance < 1.0 and 0.0 < confidence < 1.0):
        raise ValueError(f"significance={significance} and confidence={confidence} must lie "
                         "in (0, 1)")
    frame = _frame(moduli, value)
    values = np.asarray(frame[value], dtype=float)
    rate_all = np.asarray(frame["rate_mm_per_s"], dtype=float)
    usable = np.isfinite(values)
    excluded = []
    for i in np.flatnonzero(~usable):
        row = frame.iloc[i]
        reason = row["reason"] if "reason" in frame and isinstance(row.get("reason"), str) \
            else f"no {value}"
        excluded.append((str(row.get("file", f"row {i}")), str(reason)))
    bad_rate = usable & ~(np.isfinite(rate_all) & (rate_all > 0.0))
    if bad_rate.any():
        i = int(np.flatnonzero(bad_rate)[0])
        raise ValueError(f"rate_mm_per_s={rate_all[i]} of {frame.iloc[i].get('file', i)} must "
                         "be a positive number")
    for i in np.flatnonzero(usable & ~(values > 0.0)):  # a modulus must be positive
        row = frame.iloc[i]
        excluded.append((str(row.get("file", f"row {i}")),
                         f"{value}={values[i]:.6g} is not positive"))
    usable &= values > 0.0
    data = frame[usable]
    E = values[usable]
    rate = rate_all[usable]
    layer = np.asarray(data["layer"]).astype(str)
    sample = np.char.add(np.char.add(layer, "/"), np.asarray(data["sample"]).astype(str))
    test = np.asarray(data["test"], dtype=float) if "test" in data else None

    trends = []
    for name in sorted(set(layer.tolist())):
        m = layer == name
        trends.append(_layer_trend(name, E[m], rate[m], sample[m],
                                   None if test is None else test[m], confidence))

    # pooled: ln E, one intercept per sample, common slope
    slope, se, dof = block_slope(np.log(E), np.log10(rate), sample) if E.size else (
        math.nan, math.nan, 0)
    t, p, lo, hi = _t_test(slope, se, dof, confidence)
    pooled_note = None
    if not math.isfinite(p):
        pooled_note = "not enough cycles at different rates within samples for a pooled test"

    adjusted = holm([tr.p_value for tr in trends] + [p])
    trends = [dataclasses.replace(tr, p_holm=float(a),
                                  rate_dependent=bool(math.isfinite(a) and a <= significance))
              for tr, a in zip(trends, adjusted[:-1], strict=True)]
    pooled = PooledTrend(
        slope_per_decade=slope, relative_change_per_decade=math.expm1(slope)
        if math.isfinite(slope) else math.nan,
        relative_change_ci=(math.expm1(lo), math.expm1(hi)), t_value=t, p_value=p,
        p_holm=float(adjusted[-1]),
        rate_dependent=bool(math.isfinite(adjusted[-1]) and adjusted[-1] <= significance),
        dof=dof, n_cycles=int(E.size), n_samples=len(set(sample.tolist())),
        n_layers=len(trends), note=pooled_note)
    return RateAnalysis(layers=tuple(trends), pooled=pooled, significance=significance,
                        confidence=confidence, value=value, excluded=tuple(excluded))


# ================================================================== operating characteristics
def simulate_moduli(
    rng: np.random.Generator,
    *,
    layer_moduli_Pa: Sequence[float] = (5625.0, 5625.0, 6495.0, 9000.0, 9000.0, 9300.0),
    n_samples: int = 3,
    rates_mm_per_s: Sequence[float] = RATES_MM_PER_S,
    sample_cv: float = 0.07,
    cycle_cv: float = 0.025,
    fast_over_slow: float = 1.0,
):
    r"""Synthetic material moduli of a campaign, for the operating characteristics of the test.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of all randomness (seed it).
    layer_moduli_Pa : sequence of float
        Mean material modulus of each layer (Pa); default :math:`3\mu` of thesis Table 1.
    n_samples : int
        Samples per layer, each tested once at every rate, in a random order.
    rates_mm_per_s : sequence of float
        Platen speeds (mm/s).
    sample_cv, cycle_cv : float
        Sample-to-sample and cycle-to-cycle scatter (coefficients of variation, normal,
        multiplicative).
    fast_over_slow : float
        Modulus at the fastest over the slowest rate, log-linear in between (1: no rate
        effect; 2: the thesis's Fig. 11 doubling).

    Returns
    -------
    pandas.DataFrame
        ``layer, sample, test, rate_mm_per_s, E_material_Pa``, one row per cycle.
    """
    import pandas as pd

    rates = np.asarray(rates_mm_per_s, dtype=float)
    span = math.log10(rates.max() / rates.min())
    beta = math.log(fast_over_slow) / span  # d ln E / d log10 v
    rows = []
    for k, base in enumerate(layer_moduli_Pa):
        layer = chr(ord("A") + k)
        for i in range(n_samples):
            sample_E = base * (1.0 + sample_cv * rng.standard_normal())
            order = rng.permutation(rates.size)
            for test, j in enumerate(order, start=1):
                E = sample_E * math.exp(beta * math.log10(rates[j] / rates.min()))
                E *= 1.0 + cycle_cv * rng.standard_normal()
                rows.append((layer, f"{layer}{i + 1}", test, float(rates[j]), E))
    return pd.DataFrame(rows, columns=["layer", "sample", "test", "rate_mm_per_s",
                                       "E_material_Pa"])


def flag_rates(n_campaigns: int, seed: int, *, significance: float = 0.05,
               **campaign) -> dict[str, float]:
    """How often simulated campaigns are flagged rate dependent.

    Parameters
    ----------
    n_campaigns : int
        Campaigns simulated.
    seed : int
        Seed of :func:`numpy.random.default_rng`.
    significance : float
        Family-wise level.
    **campaign
        Options of :func:`simulate_moduli` (``fast_over_slow=1`` for the false-positive
        rate, ``2`` for the power against a doubling).

    Returns
    -------
    dict
        ``campaign`` (any test of the family significant), ``pooled``, ``any_layer`` and
        ``per_layer`` (mean over layers): fractions of campaigns flagged.
    """
    rng = np.random.default_rng(seed)
    flags = np.zeros((n_campaigns, 3))
    per_layer = 0.0
    for c in range(n_campaigns):
        result = analyse_rates(simulate_moduli(rng, **campaign), significance=significance)
        layer_flags = [t.rate_dependent for t in result.layers]
        flags[c] = (result.rate_dependent, result.pooled.rate_dependent, any(layer_flags))
        per_layer += float(np.mean(layer_flags))
    share = flags.mean(axis=0)
    return {"campaign": float(share[0]), "pooled": float(share[1]),
            "any_layer": float(share[2]), "per_layer": per_layer / n_campaigns}


# ================================================================================= plotting
def plot_rates(analysis: RateAnalysis, moduli, *, value: str | None = None):
    """Modulus against platen speed per layer, like the thesis's Fig. 11.

    One colour per layer: per-cycle markers (one marker shape per sample, nudged sideways
    so they do not hide each other), the fitted per-layer trend (mean over samples) and the
    confidence band of that mean line; log rate axis.

    Parameters
    ----------
    analysis : RateAnalysis
    moduli : pandas.DataFrame or iterable of CycleModulus
        The per-cycle moduli analysed.
    value : str, optional
        Column plotted; default ``analysis.value``.

    Returns
    -------
    matplotlib.figure.Figure
        Built without pyplot (no global state, no window); save it with :func:`save_figure`.
    """
    from matplotlib.figure import Figure

    value = value or analysis.value
    frame = _frame(moduli, value)
    fig = Figure(figsize=(7.5, 5.0), layout="constrained")
    ax = fig.add_subplot()
    colours = [f"C{k}" for k in range(10)]
    markers = ["o", "s", "^", "D", "v", "P"]
    rates = np.asarray(frame["rate_mm_per_s"], dtype=float)
    finite = np.isfinite(rates) & (rates > 0)
    grid = (np.geomspace(rates[finite].min(), rates[finite].max(), 50)
            if finite.any() else np.array(RATES_MM_PER_S))
    for k, trend in enumerate(analysis.layers):
        colour = colours[k % len(colours)]
        rows = frame[(frame["layer"].astype(str) == trend.layer)]
        for j, (_, g) in enumerate(rows.groupby("sample", sort=True)):
            E = np.asarray(g[value], dtype=float)
            nudge = 1.0 + 0.025 * (j - 1)  # samples side by side on the log axis
            ax.plot(np.asarray(g["rate_mm_per_s"], dtype=float) * nudge, E / 1e3,
                    linestyle="none", marker=markers[j % len(markers)], color=colour,
                    markerfacecolor="none", markersize=6, alpha=0.85)
        if trend.fitted_Pa and math.isfinite(trend.slope_per_decade_Pa):
            v0 = min(trend.fitted_Pa)
            E0 = trend.fitted_Pa[v0]
            line = E0 + trend.slope_per_decade_Pa * np.log10(grid / v0)
            flag = " *" if trend.rate_dependent else ""
            label = (f"{trend.layer}: {trend.slope_per_decade_Pa:+.0f} Pa/decade, "
                     f"p = {trend.p_value:.2g}{flag}")
            ax.plot(grid, line / 1e3, color=colour, label=label)
            if math.isfinite(trend.slope_stderr_Pa) and trend.dof > 0:
                # band of the mean-sample line, var = s^2/n + (x - xbar)^2 se_b^2 (exact for
                # a balanced design), times the t quantile
                x = np.log10(grid)
                xm = float(np.mean(np.log10(np.asarray(rows["rate_mm_per_s"], dtype=float))))
                s_mean = trend.residual_sd_Pa / math.sqrt(max(trend.n_cycles, 1))
                half = stats.t.ppf(0.5 + 0.5 * analysis.confidence, trend.dof) * np.sqrt(
                    s_mean**2 + (trend.slope_stderr_Pa * (x - xm)) ** 2)
                ax.fill_between(grid, (line - half) / 1e3, (line + half) / 1e3,
                                color=colour, alpha=0.12, linewidth=0)
        else:
            ax.plot([], [], color=colour, label=f"{trend.layer}: no trend ({trend.note})")
    ax.set_xscale("log")
    tested = sorted({float(r) for r in rates[finite]})
    ax.set_xticks(tested)
    ax.set_xticklabels([f"{r:g}" for r in tested])
    ax.minorticks_off()
    ax.set_xlabel("platen speed (mm/s)")
    label = "material" if value == "E_material_Pa" else value
    ax.set_ylabel(f"Young's modulus, {label} (kPa)")
    pooled = analysis.pooled
    ax.set_title(
        f"Modulus vs rate ({int(100 * analysis.confidence)} % bands; * = rate dependent, "
        f"Holm FWER {analysis.significance:g})\npooled: "
        f"{100 * pooled.relative_change_per_decade:+.1f} % per decade, p = "
        f"{pooled.p_value:.2g}", fontsize=10)
    ax.legend(fontsize=8, loc="best")
    ax.grid(True, which="major", alpha=0.3)
    return fig


def save_figure(fig, path: str | os.PathLike, dpi: int = 150) -> str:
    """Write a figure to a PNG file atomically (Agg renderer, no pyplot) and return the path."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from ._io import write_bytes

    FigureCanvasAgg(fig)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    write_bytes(path, buffer.getvalue())
    return os.fspath(path)

