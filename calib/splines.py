"""Fast reading of the forward model's curves: several cubic splines, each at its own shift.

The discrepancy workflow's fast refits read a geometry's solves (one per tabulated alpha,
:meth:`calib.discover.LayerContext.unit_curve_rows`) hundreds of thousands of times per
layer, most of them inside a series spring's equilibrium (Newton's method on the compliant
strain). scipy's per-call checks made those reads a seventh of a layer's workflow; one JIT
kernel over all the splines' coefficients reads them about twelve times faster (2.7 against
33 us for four splines at 60 travels), and a second one solves the spring's equilibrium on
them without NumPy's per-iteration overhead (:meth:`ShiftedSplines.spring_equilibrium`).
"""

from __future__ import annotations

import numpy as np

from solver._jit import njit  # the solver's one JIT policy (cache, locking, error model)
from solver.loading import table_interp

__all__ = ["ShiftedSplines"]

#: Newton's method on the compliant strain: iterations, the central difference's half step
#: (strain), the step below which every point has converged, and the largest final step of a
#: point that counts as an equilibrium
SPRING_ITERATIONS = 30
SPRING_DIFF = 1e-6
SPRING_TOL = 1e-11
SPRING_ACCEPT = 1e-8


@njit
def _piece(x, c, k, last, t):
    """Spline ``k`` at ``t`` (mm).

    The last of its ``last + 1`` pieces starting at or before t (bisection), evaluated; the
    end pieces extended beyond the breakpoints.
    """
    lo = 0
    hi = last
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if x[k, mid] <= t:
            lo = mid
        else:
            hi = mid - 1
    dx = t - x[k, lo]
    return ((c[k, 0, lo] * dx + c[k, 1, lo]) * dx + c[k, 2, lo]) * dx + c[k, 3, lo]


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
            out[k, p] = _piece(x, c, k, last, travel[p] + shifts[k])


@njit
def _weighted_force(x, c, n_pieces, shifts, weights, grid, ratio, height, s):
    """sum_k weights[k] spline_k(s height + shifts[k]) times interp(s, grid, ratio)."""
    total = 0.0
    for k in range(x.shape[0]):
        total += weights[k] * _piece(x, c, k, n_pieces[k] - 1, s * height + shifts[k])
    return total * table_interp(s, grid, ratio)


@njit
def _spring_equilibrium(x, c, n_pieces, shifts, weights, grid, ratio, height, k_spring,
                        strain_m, s, iterations, diff, tol, accept):
    """Sample strain ``s`` with s + k f(s) = strain_m, Newton's method on every point at once.

    x, c, n_pieces, shifts : the splines as in :func:`_shifted_cubic_rows`. weights :
    (n_splines,) float64. grid, ratio : (n_grid,) float64, strain and a factor on the force.
    height : mm. k_spring : compliance times mu over height (1/force unit). strain_m :
    (n,) float64, the measured strain. s : (n,) float64, out: the equilibrium, NaN where none
    is stable (1 + k f'(s) <= 0 at some iterate) or Newton did not settle.

    The iteration of :func:`calib.discover._compliant_strain`, its NumPy twin: f at max(s, 0)
    and max(s +- diff, 0), all points stepped until the largest step is below ``tol``.
    """
    n = strain_m.shape[0]
    stable = np.ones(n, np.bool_)
    step = np.full(n, np.inf)
    for p in range(n):
        s[p] = strain_m[p]
    for _ in range(iterations):
        largest = 0.0
        unsettled = False
        for p in range(n):
            f = _weighted_force(x, c, n_pieces, shifts, weights, grid, ratio, height,
                                max(s[p], 0.0))
            up = _weighted_force(x, c, n_pieces, shifts, weights, grid, ratio, height,
                                 max(s[p] + diff, 0.0))
            down = _weighted_force(x, c, n_pieces, shifts, weights, grid, ratio, height,
                                   max(s[p] - diff, 0.0))
            stiffness = 1.0 + k_spring * (up - down) / (2.0 * diff)
            if not stiffness > 0.0:
                stable[p] = False
            if stable[p]:
                step[p] = (s[p] + k_spring * f - strain_m[p]) / stiffness
            else:
                step[p] = 0.0
            s[p] = s[p] - step[p]
            if abs(step[p]) > largest:
                largest = abs(step[p])
            elif step[p] != step[p]:  # a NaN step keeps the iteration going, as in NumPy's
                unsettled = True
        if largest < tol and not unsettled:
            break
    for p in range(n):
        s[p] = max(s[p], 1e-6)
        if not (stable[p] and abs(step[p]) < accept):
            s[p] = np.nan


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

    def spring_equilibrium(self, strain, weights, height_mm: float, k_spring: float,
                           ratio_grid, ratio) -> np.ndarray:
        """The sample's strain behind a series spring, s + k_spring f(s) = strain.

        f(s) = (weights @ self(s * height_mm)) * np.interp(s, ratio_grid, ratio): the weighted
        curves at the sample's own travel, times a factor tabulated along the strain (the
        discretisation correction). Newton's method with a central difference, as
        :func:`calib.discover._compliant_strain` iterates it.

        Parameters
        ----------
        strain : array_like
            Measured strain (travel over height, fraction), any shape.
        weights : (n_splines,) array_like
            Weight of each spline (Lagrange weights over the solved alphas).
        height_mm : float
            Sample height (mm) that turns strain into the splines' travel.
        k_spring : float
            Compliance times mu over height: the strain the spring takes per unit of f.
        ratio_grid, ratio : (n_grid,) array_like
            Strain (increasing) and the factor on f there.

        Returns
        -------
        numpy.ndarray
            The sample's strain, shape of ``strain``; NaN where there is no stable equilibrium
            (a negative compliance whose spring is softer than the sample) or Newton did not
            settle.
        """
        strain = np.asarray(strain, dtype=float)
        weights = np.ascontiguousarray(weights, dtype=float)
        if weights.shape != self.shifts.shape:
            raise ValueError(f"{len(self.shifts)} splines but weights of shape "
                             f"{weights.shape}")
        grid = np.ascontiguousarray(ratio_grid, dtype=float)
        factor = np.ascontiguousarray(ratio, dtype=float)
        if grid.ndim != 1 or grid.shape != factor.shape or len(grid) < 2:
            raise ValueError(f"ratio_grid {grid.shape} and ratio {factor.shape} must be one "
                             "table of two or more points")
        s = np.empty(strain.size)
        _spring_equilibrium(self.x, self.c, self.n_pieces, self.shifts, weights, grid, factor,
                            float(height_mm), float(k_spring),
                            np.ascontiguousarray(strain.ravel()), s, SPRING_ITERATIONS,
                            SPRING_DIFF, SPRING_TOL, SPRING_ACCEPT)
        return s.reshape(strain.shape)
