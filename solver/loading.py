"""Platen travel histories and the compression test they belong to.

A :class:`CompressionTest` says what the rig does: the sample's size, how far and how fast the
top platen travels, and how the platens hold the sample. Its travel history is either the
smooth 3-4-5 polynomial ramp used in explicit analyses (zero velocity and acceleration at both
ends) or the rig's constant platen speed.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._jit import njit

__all__ = ["CompressionTest", "PLATENS", "ramp_345", "table_interp", "travel"]

#: Platen conditions the solver knows.
PLATENS = ("bonded", "frictionless", "coulomb")

#: History kinds understood by :func:`travel`.
RAMP_345, TABLE = 0, 1


def ramp_345(s):
    """3-4-5 polynomial :math:`10 s^3 - 15 s^4 + 6 s^5` of the normalised time ``s`` in [0, 1]."""
    s = np.clip(np.asarray(s, dtype=float), 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


@dataclasses.dataclass(frozen=True)
class CompressionTest:
    """A platen compression test of a cylindrical sample.

    Parameters
    ----------
    diameter_mm, height_mm : float
        Sample size (mm).
    strain : float
        Final nominal compression, travel / height (fraction, 0 < strain < 0.9).
    rate_mm_per_s : float
        Mean platen speed (mm/s): the ramp lasts ``travel / rate``.
    platen : {"bonded", "frictionless", "coulomb"}
        ``bonded``: the faces are glued (sandpaper), and free-surface nodes that roll onto a
        platen stick where they land. ``frictionless``: the faces slide freely.
        ``coulomb``: sliding resisted by ``friction`` times the contact pressure.
    friction : float
        Coulomb coefficient (used with ``platen="coulomb"``).
    ramp : {"345", "constant"}
        Travel history: the smooth 3-4-5 polynomial, or constant speed as the rig moves from
        the contact point on.
    hold_s : float
        Hold at the final travel after the ramp (s), e.g. for relaxation.
    """

    diameter_mm: float = 38.0
    height_mm: float = 24.0
    strain: float = 0.3
    rate_mm_per_s: float = 0.83
    platen: str = "bonded"
    friction: float = 0.0
    ramp: str = "345"
    hold_s: float = 0.0

    def __post_init__(self):
        for name in ("diameter_mm", "height_mm", "rate_mm_per_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name}={value} must be a positive number")
        if not 0.0 < self.strain < 0.9:
            raise ValueError(f"strain={self.strain} must lie in (0, 0.9)")
        if self.platen not in PLATENS:
            raise ValueError(f"platen={self.platen!r} is not one of {PLATENS}")
        if not (np.isfinite(self.friction) and self.friction >= 0.0):
            raise ValueError(f"friction={self.friction} must be a non-negative number")
        if self.platen == "coulomb" and self.friction == 0.0:
            raise ValueError("platen='coulomb' needs a positive friction coefficient "
                             "(use platen='frictionless' for zero friction)")
        if not (np.isfinite(self.hold_s) and self.hold_s >= 0.0):
            raise ValueError(f"hold_s={self.hold_s} must be a non-negative number")
        if self.ramp not in ("345", "constant"):
            raise ValueError(f"ramp={self.ramp!r} is not '345' or 'constant'")

    @property
    def travel_mm(self) -> float:
        """Final platen travel (mm)."""
        return self.strain * self.height_mm

    @property
    def ramp_time_s(self) -> float:
        """Duration of the loading ramp (s)."""
        return self.travel_mm / self.rate_mm_per_s

    def history(self) -> tuple[int, float, float, np.ndarray, np.ndarray]:
        """History arguments of :func:`travel` in SI units: (kind, T_s, D_m, t_table, d_table)."""
        T = self.ramp_time_s
        D = 1e-3 * self.travel_mm
        if self.ramp == "345":
            return RAMP_345, T, D, np.zeros(1), np.zeros(1)
        return TABLE, T, D, np.array([0.0, T]), np.array([0.0, D])

    def initial_rate_m_per_s(self) -> float:
        """Platen speed at the start of the ramp (m/s): 0 for the 3-4-5 ramp."""
        return 0.0 if self.ramp == "345" else 1e-3 * self.rate_mm_per_s

    def output_times(self, n: int) -> np.ndarray:
        """Output times (s) along the ramp and the hold.

        ``n`` from 0 to the end of the ramp at equal travel increments, then, with a hold,
        ``max(10, n // 2)`` more at equal time increments over the hold.
        """
        ramp = self._ramp_output_times(n)
        if self.hold_s == 0.0:
            return ramp
        hold = np.linspace(0.0, self.hold_s, max(10, n // 2) + 1)[1:]
        return np.concatenate([ramp, self.ramp_time_s + hold])

    def _ramp_output_times(self, n: int) -> np.ndarray:
        levels = np.linspace(0.0, 1.0, n)
        if self.ramp == "constant":
            return levels * self.ramp_time_s
        # invert the monotone 3-4-5 polynomial by bisection (vectorised)
        lo = np.zeros(n)
        hi = np.ones(n)
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            below = ramp_345(mid) < levels
            lo = np.where(below, mid, lo)
            hi = np.where(below, hi, mid)
        s = 0.5 * (lo + hi)
        s[0], s[-1] = 0.0, 1.0
        return s * self.ramp_time_s


@njit
def travel(t, kind, T, D, t_table, d_table):
    """Platen travel (m) at time ``t`` (s); constant ``D`` after the ramp.

    Parameters
    ----------
    kind : int
        ``RAMP_345`` or ``TABLE`` (piecewise linear through ``t_table``, ``d_table``).
    T, D : float
        Ramp time (s) and final travel (m).
    t_table, d_table : ndarray, shape (n,)
        Increasing times (s) and travels (m) for ``TABLE``.
    """
    if kind == RAMP_345:
        if t >= T:
            return D
        if t <= 0.0:
            return 0.0
        s = t / T
        return D * s * s * s * (10.0 + s * (-15.0 + 6.0 * s))
    return table_interp(t, t_table, d_table)


@njit
def table_interp(t, grid, values):
    """``np.interp`` at one point ``t``.

    Linear between the points of ``grid`` ((n,) float64, increasing), the end ``values``
    ((n,) float64) beyond them; NaN at a NaN ``t``.
    """
    n = grid.shape[0]
    if t <= grid[0]:
        return values[0]
    if t >= grid[n - 1]:
        return values[n - 1]
    lo = 0
    hi = n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if grid[mid] <= t:
            lo = mid
        else:
            hi = mid
    w = (t - grid[lo]) / (grid[hi] - grid[lo])
    return values[lo] + w * (values[hi] - values[lo])
