"""Assertions shared by the axisymmetric and hexahedral tests (same rung, same bounds)."""

from __future__ import annotations

import numpy as np
import pytest


def assert_energy_balance(result) -> None:
    """Platen work = stored (strain + hourglass) + kinetic energy of an explicit run.

    The platen work and the internal work are path integrals over the run, the stored energy
    comes from the state: they agree to the O(dt^2) error of the path integral (bound 2e-3 of
    the final work). The kinetic energy stays below 5 % of the stored energy over the second
    half of the 3-4-5 ramp (the usual explicit quasi-static guideline) and vanishes at full
    travel (bound 1e-4); the work equals the integral of the reported force over the travel.
    """
    E = result.energy
    stored = E["strain_J"] + E["hourglass_J"]
    total = E["external_J"][-1]
    assert total > 0
    assert np.abs(E["external_J"] - stored - E["kinetic_J"]).max() < 2e-3 * total
    assert np.abs(E["internal_J"] - stored).max() < 2e-3 * total
    half = result.displacement_mm >= 0.5 * result.displacement_mm[-1]
    assert np.max(E["kinetic_J"][half] / stored[half]) < 0.05
    assert E["kinetic_J"][-1] / stored[-1] < 1e-4
    work = np.trapezoid(result.force_N, 1e-3 * result.displacement_mm)
    assert work == pytest.approx(total, rel=5e-3)


def assert_energy_gradient(f, energy, u, nodes, h=1e-9) -> None:
    """Forces ``f`` (n_nodes, dim) equal central differences of ``energy`` at ``nodes``.

    The rounding of the energy sum (~1e-16 W / h) bounds the finite-difference error, hence
    the absolute tolerance 1e-6 of the largest force.
    """
    for node in nodes:
        for a in range(u.shape[1]):
            up, dn = u.copy(), u.copy()
            up[node, a] += h
            dn[node, a] -= h
            fd = (energy(up) - energy(dn)) / (2 * h)
            assert f[node, a] == pytest.approx(fd, abs=1e-6 * np.abs(f).max())
