"""Strain-rate dependence of the modulus (calib/rates.py).

Pure statistics, fast: the block OLS slope against a dummy-variable least squares, Holm against
its definition, the t test's exactness and the family-wise false-positive rate under no rate
effect, the power against the thesis's doubling, confidence-interval coverage, and the
degenerate designs. Every simulation is seeded.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from calib.rates import (
    analyse_rates,
    block_slope,
    flag_rates,
    holm,
    plot_rates,
    save_figure,
    simulate_moduli,
)


def test_block_slope_equals_dummy_variable_least_squares():
    rng = np.random.default_rng(0)
    block = np.repeat(["a", "b", "c", "d"], [3, 3, 2, 4])
    x = rng.uniform(-1.0, 1.0, block.size)
    y = rng.normal(size=block.size) + 2.5 * x + np.repeat([1.0, 5.0, -2.0, 0.5], [3, 3, 2, 4])
    dummies = (block[:, None] == np.unique(block)[None, :]).astype(float)
    X = np.column_stack([dummies, x])
    coef, rss, *_ = np.linalg.lstsq(X, y, rcond=None)
    dof = block.size - X.shape[1]
    se = math.sqrt(rss[0] / dof * np.linalg.inv(X.T @ X)[-1, -1])
    slope, stderr, d = block_slope(y, x, block)
    assert d == dof
    assert slope == pytest.approx(coef[-1], abs=1e-12)
    assert stderr == pytest.approx(se, rel=1e-10)


def test_block_slope_degenerate_designs():
    assert math.isnan(block_slope([1.0, 2.0], [0.5, 0.5], ["a", "a"])[0])  # x constant
    slope, se, dof = block_slope([1.0, 2.0, 5.0], [0.0, 1.0, 3.0], ["a", "a", "b"])
    assert slope == pytest.approx(1.0) and dof == 0 and math.isnan(se)
    with pytest.raises(ValueError, match="1-D of one length"):
        block_slope([1.0, 2.0], [1.0], ["a", "a"])


def test_holm_matches_its_definition():
    rng = np.random.default_rng(1)
    for _ in range(50):
        p = rng.uniform(0.0, 0.2, 7)
        adjusted = holm(p)
        order = np.argsort(p)
        m = p.size
        expected = np.empty(m)
        running = 0.0
        for rank, i in enumerate(order):
            running = max(running, min(1.0, (m - rank) * p[i]))
            expected[i] = running
        np.testing.assert_allclose(adjusted, expected, rtol=0, atol=1e-15)
    assert np.isnan(holm([np.nan, 0.01])[0]) and holm([np.nan, 0.01])[1] == pytest.approx(0.01)


def test_layer_p_values_are_uniform_without_a_rate_effect():
    """The per-layer t test is exact for normal errors: under no rate effect its p-values are
    Uniform(0, 1). Kolmogorov-Smirnov over 1200 p-values at the 0.1 % level (a wrongly scaled
    standard error, e.g. ignoring the blocks, shifts them far more than that)."""
    rng = np.random.default_rng(2)
    p = []
    for _ in range(200):
        result = analyse_rates(simulate_moduli(rng, fast_over_slow=1.0))
        p.extend(t.p_value for t in result.layers)
    assert stats.kstest(p, "uniform").pvalue > 1e-3


def test_clean_campaigns_are_rarely_flagged():
    """No rate effect, 7 % sample and 2.5 % cycle scatter: a campaign is flagged (any layer or
    the pooled test) in at most 5 % of campaigns by Holm's construction. With 400 campaigns the
    observed share has a binomial SD of 1.1 %; bound at 8.5 % (5 % + 3 SD)."""
    share = flag_rates(400, seed=3, fast_over_slow=1.0)
    assert share["campaign"] <= 0.085, share
    # also with the scatter at the top of the realistic range
    assert flag_rates(200, seed=4, fast_over_slow=1.0, sample_cv=0.10,
                      cycle_cv=0.03)["campaign"] <= 0.11


def test_a_doubling_is_detected():
    """The thesis's Fig. 11: the modulus doubles from 0.17 to 6 mm/s. Every campaign, and at
    least 95 % of the layers, must be flagged."""
    share = flag_rates(60, seed=5, fast_over_slow=2.0)
    assert share["campaign"] == 1.0 and share["pooled"] == 1.0
    assert share["per_layer"] >= 0.95


def test_confidence_interval_covers_the_true_slope():
    """E = a_i + b log10(v) + noise exactly: the 95 % t interval covers b in 95 % of 400
    layers (binomial SD 1.1 %: accept 91-99 %)."""
    rng = np.random.default_rng(6)
    b = 600.0
    covered = 0
    n = 400
    for _ in range(n):
        rows = []
        for i in range(3):
            a = 6000.0 * (1.0 + 0.07 * rng.standard_normal())
            for test, v in enumerate(rng.permutation([0.17, 0.83, 6.0]), start=1):
                rows.append(("A", f"A{i}", test, v,
                             a + b * math.log10(v) + 150.0 * rng.standard_normal()))
        frame = pd.DataFrame(rows, columns=["layer", "sample", "test", "rate_mm_per_s",
                                            "E_material_Pa"])
        lo, hi = analyse_rates(frame).layers[0].slope_ci_Pa
        covered += lo <= b <= hi
    assert 0.91 <= covered / n <= 0.99


def test_slope_and_fitted_values_of_an_exact_trend():
    rows = [("A", s, 1, v, base + 500.0 * math.log10(v))
            for s, base in (("A1", 5000.0), ("A2", 5400.0)) for v in (0.17, 0.83, 6.0)]
    frame = pd.DataFrame(rows, columns=["layer", "sample", "test", "rate_mm_per_s",
                                        "E_material_Pa"])
    trend = analyse_rates(frame).layers[0]
    assert trend.slope_per_decade_Pa == pytest.approx(500.0, rel=1e-12)
    assert trend.fitted_Pa[6.0] == pytest.approx(5200.0 + 500.0 * math.log10(6.0), rel=1e-12)
    assert trend.dof == 6 - 2 - 1


def test_degenerate_layers_and_excluded_cycles_are_explained():
    rows = [
        # layer A: fine
        *[("A", f"A{i}", k, v, 6000.0 + 100 * i + 10 * k, f"A/A{i}_{v}.csv", None)
          for i in (1, 2, 3) for k, v in enumerate((0.17, 0.83, 6.0), start=1)],
        # layer B: every cycle at one rate
        *[("B", f"B{i}", 1, 0.83, 7000.0 + 50 * i, f"B/B{i}.csv", None) for i in (1, 2, 3)],
        # a cycle without a modulus
        ("A", "A1", 4, 0.83, np.nan, "A/bad.csv", "no linear region: ..."),
    ]
    frame = pd.DataFrame(rows, columns=["layer", "sample", "test", "rate_mm_per_s",
                                        "E_material_Pa", "file", "reason"])
    result = analyse_rates(frame)
    b = result.layer("B")
    assert math.isnan(b.p_value) and not b.rate_dependent and "does not vary" in b.note
    assert result.layer("A").n_cycles == 9
    assert result.excluded == (("A/bad.csv", "no linear region: ..."),)
    assert result.to_dict()["excluded"][0]["file"] == "A/bad.csv"
    with pytest.raises(KeyError, match="no layer 'Z'"):
        result.layer("Z")
    with pytest.raises(ValueError, match="lacks the columns"):
        analyse_rates(frame.drop(columns=["sample"]))
    with pytest.raises(ValueError, match="significance"):
        analyse_rates(frame, significance=1.5)


def test_order_confounded_with_rate_is_noted():
    rows = [("A", f"A{i}", k, v, 6000.0 + 300 * k + 40 * i * (-1) ** k)
            for i in (1, 2, 3) for k, v in enumerate((0.17, 0.83, 6.0), start=1)]
    frame = pd.DataFrame(rows, columns=["layer", "sample", "test", "rate_mm_per_s",
                                        "E_material_Pa"])
    trend = analyse_rates(frame).layers[0]
    assert trend.order_rate_correlation > 0.9 and "confounded" in trend.note
    latin = simulate_moduli(np.random.default_rng(8))
    latin["test"] = [1, 2, 3, 2, 3, 1, 3, 1, 2] * 6  # each rate once per test position
    assert all(abs(t.order_rate_correlation) < 0.8 for t in analyse_rates(latin).layers)


def test_plot_is_written_atomically_as_png(tmp_path):
    frame = simulate_moduli(np.random.default_rng(9), fast_over_slow=2.0)
    analysis = analyse_rates(frame)
    fig = plot_rates(analysis, frame)
    ax = fig.axes[0]
    assert ax.get_xscale() == "log"
    assert len([line for line in ax.get_lines() if line.get_linestyle() == "-"]) == 6
    target = tmp_path / "fig11.png"
    save_figure(fig, target)
    assert target.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig11.png"]  # no temporary left
