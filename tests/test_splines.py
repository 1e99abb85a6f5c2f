"""The fast reading of several shifted cubic splines, against scipy's own evaluation."""

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from calib.splines import ShiftedSplines


def test_shifted_splines_read_each_curve_as_scipy_does():
    """The refits' fused reading of a geometry's solves against its twin, scipy's own
    evaluation of each spline at the travel plus that solve's shift: inside, on breakpoints,
    beyond both ends (the end pieces extended), NaN kept, any input shape; the solves' output
    travels differ (by the time step, or a solve that stopped early). 1e-12: the two sum the
    same cubic in a different order."""
    rng = np.random.default_rng(5)
    splines = []
    for k in range(4):
        x = np.linspace(0.0, 7.4 if k != 2 else 6.0, 63 if k != 2 else 50)
        x[1:-1] += rng.uniform(-0.01, 0.01, len(x) - 2)
        splines.append(CubicSpline(x, (x / 7.4) ** (1.5 + 0.3 * k)
                                   + 0.01 * rng.standard_normal(len(x))))
    shifts = rng.normal(0.0, 0.01, 4)
    rows = ShiftedSplines(splines, shifts)
    x = splines[0].x
    travel = np.concatenate([rng.uniform(-0.5, 8.0, 300), x[[0, 7, 61, 62]] - shifts[0],
                             [np.nan, -1e6, 1e6]])
    twin = np.array([sp(travel + h) for sp, h in zip(splines, shifts)])
    got = rows(travel)
    assert got.shape == twin.shape
    np.testing.assert_array_equal(np.isnan(got), np.isnan(twin))
    np.testing.assert_allclose(got, twin, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(rows(travel[:6].reshape(2, 3)), twin[:, :6].reshape(4, 2, 3),
                               rtol=1e-12, atol=1e-14)
    assert rows(np.float64(3.0)).shape == (4,)


def test_shifted_splines_refuse_what_they_cannot_read():
    x = np.linspace(0.0, 1.0, 5)
    with pytest.raises(ValueError, match="one-dimensional"):
        ShiftedSplines([CubicSpline(x, np.column_stack([x, x]))], [0.0])
    with pytest.raises(ValueError, match="2 splines but shifts"):
        ShiftedSplines([CubicSpline(x, x), CubicSpline(x, x ** 2)], [0.0])


def _stiffening_splines(rng):
    """Four force-travel splines (N/Pa against mm) of a stiffening curve, breakpoints apart."""
    splines = []
    for k in range(4):
        x = np.linspace(0.0, 7.4 if k != 3 else 6.5, 80 if k != 3 else 71)
        x[1:-1] += rng.uniform(-0.01, 0.01, len(x) - 2)
        splines.append(CubicSpline(x, 1e-3 * (x / 7.4 + (x / 7.4) ** (3.0 + 0.5 * k))))
    return splines


@pytest.mark.parametrize("compliance", [0.0, 0.15, 0.5, -0.05, -2.0])
def test_spring_equilibrium_matches_its_numpy_twin(compliance):
    """The JIT Newton solve of a series spring's equilibrium against its twin,
    calib.discover._compliant_strain, on the weighted splines times a tabulated correction:
    same iteration, so the same strains to 1e-12 (the sums' order differs) and NaN at the
    same points. -2 mm/N: a negative spring softer than the sample, no stable equilibrium
    near the top. Each point is checked against its equation, too."""
    from calib.discover import _compliant_strain

    rng = np.random.default_rng(11)
    splines = _stiffening_splines(rng)
    shifts = rng.normal(0.0, 0.005, 4)
    rows = ShiftedSplines(splines, shifts)
    weights = np.array([-0.06, 0.56, 0.56, -0.06])
    grid = np.linspace(0.0, 0.33, 241)[1:]
    ratio = 1.0 + 0.004 * np.sin(40.0 * grid)
    height, mu = 24.0, 2900.0

    def f(s):
        return (weights @ np.array([sp(s * height + h) for sp, h in zip(splines, shifts)])
                * np.interp(s, grid, ratio))

    strain = np.concatenate([np.linspace(0.005, 0.3, 60), [0.0, 0.31, np.nan]])
    k = compliance * mu / height
    got = rows.spring_equilibrium(strain, weights, height, k, grid, ratio)
    twin = _compliant_strain(strain, f, mu, compliance, height)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(twin))
    np.testing.assert_allclose(got, twin, rtol=1e-12, atol=1e-15)
    ok = np.isfinite(got) & (got > 1e-6)
    np.testing.assert_allclose(got[ok] + k * f(got[ok]), strain[ok], rtol=0, atol=1e-10)
    if compliance == -2.0:
        assert np.isnan(got[:60]).any() and np.isfinite(got[:3]).all()
    else:
        assert np.isfinite(got[:62]).all()
    assert rows.spring_equilibrium(strain[:6].reshape(2, 3), weights, height, k, grid,
                                   ratio).shape == (2, 3)


def test_spring_equilibrium_refuses_mismatched_tables():
    x = np.linspace(0.0, 1.0, 5)
    rows = ShiftedSplines([CubicSpline(x, x), CubicSpline(x, x ** 2)], [0.0, 0.0])
    with pytest.raises(ValueError, match="2 splines but weights"):
        rows.spring_equilibrium([0.1], [1.0], 24.0, 1.0, [0.0, 1.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="one table"):
        rows.spring_equilibrium([0.1], [0.5, 0.5], 24.0, 1.0, [0.0, 1.0], [1.0])
