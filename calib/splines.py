"""Fast reading of the forward model's curves: several cubic splines, each at its own shift.

The discrepancy workflow's fast refits read a geometry's solves (one per tabulated alpha,
:meth:`calib.discover.LayerContext.unit_curve_rows`) hundreds of thousands of times per
layer, most of them inside a series spring's equilibrium (Newton's method on the compliant
strain). scipy's per-call checks made those reads a seventh of a layer's workflow; one JIT
kernel over all the splines' coefficients reads them about twelve times faster (2.7 against
33 us for four splines at 60 travels).
"""

from __future__ import annotations

import numpy as np

from solver._jit import njit  # the solver's one JIT policy (cache, locking, error model)

__all__ = ["ShiftedSplines"]


@njit
def _shifted_cubic_rows(x, c, n_pieces, shifts, travel, out):
    """Piecewise cubics, spline ``k`` read at ``travel + shifts[k]``, into ``out``.

    x : (n_splines, n_breaks_max) float64, mm; spline k's breakpoints in ``x[k, :n_pieces[k]
        + 1]``, increasing. c : (n_splines, 4, n_breaks_max - 1) float64; coefficients of
    dx^3, dx^2, dx, 1 of each piece. n_pieces : (n_splines,) int64. shifts : (n_splines,)
    float64, mm. travel : (n,) float64, mm. out : (n_splines, n) float64.

    Piece i holds x[i] <= t < x[i + 1]; travels beyond the ends take the end pieces (scipy's
    ``extrapolate=True``); a NaN travel gives NaN.
    """
    for k in range(x.shape[0]):
        last = n_pieces[k] - 1
        for p in range(travel.shape[0]):
            t = travel[p] + shifts[k]
            lo = 0
            hi = last
            while lo < hi:  # the last piece starting at or before t (bisection)
                mid = (lo + hi + 1) // 2
                if x[k, mid] <= t:
                    lo = mid
                else:
                    hi = mid - 1
            dx = t - x[k, lo]
            out[k, p] = ((c[k, 0, lo] * dx + c[k, 1, lo]) * dx + c[k, 2, lo]) * dx + c[k, 3, lo]


class ShiftedSplines:
    """Cubic splines, each read at the travel plus its own shift.

    ``rows(travel)[k] == splines[k](travel + shifts[k])`` as scipy evaluates a
    :class:`scipy.interpolate.CubicSpline` (the end pieces extended beyond the breakpoints).
    The splines may have different breakpoints (the solves' output travels differ by the time
    step, and a solve may stop early).

    Parameters
    ----------
    splines : sequence of scipy.interpolate.CubicSpline
        One-dimensional cubic splines (force against travel, mm).
    shifts : sequence of float
        Travel (mm) added to the argument of each spline.
    """

    def __init__(self, splines, shifts):
        splines = list(splines)
        if any(sp.c.ndim != 2 or sp.c.shape[0] != 4 for sp in splines):
            raise ValueError("ShiftedSplines takes one-dimensional cubic splines")
        self.n_pieces = np.array([len(sp.x) - 1 for sp in splines], dtype=np.int64)
        width = int(self.n_pieces.max())
        self.x = np.full((len(splines), width + 1), np.inf)  # (n_splines, n_breaks_max) mm
        self.c = np.zeros((len(splines), 4, width))  # (n_splines, 4, n_breaks_max - 1)
        for k, sp in enumerate(splines):
            self.x[k, :len(sp.x)] = sp.x
            self.c[k, :, :len(sp.x) - 1] = sp.c
        self.shifts = np.asarray(shifts, dtype=float)  # (n_splines,) mm
        if self.shifts.shape != (len(splines),):
            raise ValueError(f"{len(splines)} splines but shifts of shape {self.shifts.shape}")

    def __call__(self, travel) -> np.ndarray:
        """Every spline at ``travel`` (mm, any shape), shape ``(n_splines,) + travel.shape``."""
        travel = np.asarray(travel, dtype=float)
        out = np.empty((len(self.shifts), travel.size))
        _shifted_cubic_rows(self.x, self.c, self.n_pieces, self.shifts,
                            np.ascontiguousarray(travel.ravel()), out)
        return out.reshape((len(self.shifts),) + travel.shape)
