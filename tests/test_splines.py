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
