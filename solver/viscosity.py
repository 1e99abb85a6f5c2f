r"""Linear bulk viscosity of the axisymmetric quads (lumped-mass runs).

A lumped-mass explicit model of a gel at :math:`\nu = 0.499` rings in its volumetric modes,
22 times faster than its shear modes, and central differences never damp them. A bonded
platen force averages that ringing out, but a Coulomb platen does not: whether a contact
node sticks or slips is decided on its instantaneous normal and tangential forces, which
carry the ringing, and the decisions rectify it into an irregular, ramp-dependent force
(the default test at friction 0.15: -21.3, -22.0, -22.4, -23.6 % off bonded at 3, 12, 24 and
27 % strain with a ramp of 20 natural periods, -20.8, -20.5, -20.1, -21.5 % with 10; with
this bulk viscosity -20.8, -20.4, -20.1, -21.5 % with either, and with 40 or 80).
Explicit codes damp these modes with a bulk viscosity (Abaqus/Explicit's linear bulk
viscosity, default 0.06 of critical in the element's dilatational mode); here the damping
matrix of each element is its volumetric stiffness scaled to that fraction at the element's
highest frequency,

.. math::

    C = \sum_e c_e\, b_e b_e^T, \qquad c_e = \frac{2 \xi K_e V_e}{\omega_e},
    \qquad f_v = C v,

with :math:`b_e = \partial \bar J_e / \partial u` in the current configuration
(:func:`solver.mass.volumetric_gradient`), :math:`K_e V_e` the element's volumetric
stiffness and :math:`\omega_e` its highest frequency at the reference state. The element's
dilatational mode gets the damping ratio :math:`\xi` (a lower one if its highest mode is not
dilatational), its isochoric modes none: the lowest natural mode, and with it the
quasi-static time scale, is left alone, and a quasi-static run sees a viscous pressure
proportional to :math:`\dot J`, which an incompressible gel keeps near zero. The forces use
the lagging velocity :math:`v^{n-1/2}`; the stable step shrinks by
:math:`\sqrt{1 + \xi^2} - \xi` (0.94 at :math:`\xi = 0.06`).

Array order as in :mod:`solver.kernels`.
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import njit
from .mass import element_dot, volumetric_gradient

__all__ = ["DEFAULT_BULK_VISCOSITY", "bulk_viscosity_coefficient", "bulk_viscosity_forces",
           "step_factor"]

#: Fraction of critical damping of each element's dilatational mode (Abaqus/Explicit's
#: default linear bulk viscosity).
DEFAULT_BULK_VISCOSITY = 0.06


def bulk_viscosity_coefficient(bulk_Pa: np.ndarray, volume: np.ndarray, omega: np.ndarray,
                               fraction: float) -> np.ndarray:
    r""":math:`c_e = 2 \xi K_e V_e / \omega_e` of every element.

    Parameters
    ----------
    bulk_Pa : ndarray, shape (n_elem,)
        Bulk modulus of each element's material (Pa).
    volume : ndarray, shape (n_elem,)
        Reference volume (m^3 per radian in the axisymmetric model).
    omega : ndarray, shape (n_elem,)
        Highest natural frequency of each element with its lumped masses (rad/s).
    fraction : float
        :math:`\xi`, fraction of critical damping, >= 0.

    Returns
    -------
    ndarray, shape (n_elem,)
        :math:`c_e` (N s per unit :math:`\dot J`, per radian).
    """
    if not (math.isfinite(fraction) and fraction >= 0.0):
        raise ValueError(f"bulk_viscosity={fraction!r} must be a finite fraction >= 0")
    return np.ascontiguousarray(2.0 * fraction * np.asarray(bulk_Pa) * np.asarray(volume)
                                / np.asarray(omega), dtype=np.float64)


def step_factor(fraction: float) -> float:
    r"""Stable step with damping ratio :math:`\xi` over the undamped one, :math:`\sqrt{1+\xi^2}-\xi`."""
    return math.sqrt(1.0 + fraction * fraction) - fraction


@njit
def bulk_viscosity_forces(
    u,  # (n_nodes, 2) displacement (m)
    v,  # (n_nodes, 2) velocity (m/s)
    conn,  # (n_elem, 4) int32
    bbar,  # (n_elem, 4, 2)
    hbar,  # (n_elem, 4)
    coefficient,  # (n_elem,) c_e; elements with zero get no damping
    everywhere,  # (n_nodes, 2) bool, all true
    grad,  # (n_elem, 4, 2) work array: b_e at u
    out,  # (n_nodes, 2) output: f_v = sum_e c_e b_e (b_e . v) (N per radian)
):
    r"""Bulk-viscous nodal forces :math:`f_v = C(u) v` (they resist :math:`\dot J`)."""
    volumetric_gradient(u, conn, bbar, hbar, everywhere, coefficient, grad)
    out[:, :] = 0.0
    for e in range(conn.shape[0]):
        if not coefficient[e] > 0.0:
            continue
        s = coefficient[e] * element_dot(e, grad, v, conn)
        for a in range(4):
            n = conn[e, a]
            out[n, 0] += s * grad[e, a, 0]
            out[n, 1] += s * grad[e, a, 1]
