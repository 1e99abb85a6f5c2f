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

Hexahedra take the same damping with :math:`b_e = \partial \det \bar F_e / \partial u`
(:func:`hex_bulk_viscosity_forces`). Array order as in :mod:`solver.kernels`.
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import njit
from .kernels import _hex_state
from .mass import element_dot, volumetric_gradient

__all__ = ["DEFAULT_BULK_VISCOSITY", "bulk_viscosity_coefficient", "bulk_viscosity_forces",
           "hex_bulk_viscosity_forces", "step_factor"]

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


@njit
def hex_bulk_viscosity_forces(
    u,  # (n_nodes, 3) displacement (m)
    v,  # (n_nodes, 3) velocity (m/s)
    conn,  # (n_elem, 8) int32
    bbar,  # (n_elem, 8, 3) mean shape-function gradients (solver.kernels.hex_operators)
    coefficient,  # (n_elem,) c_e; elements with zero get no damping
    grad,  # (n_elem, 8, 3) work array: b_e = cof(F) bbar_a at u
    out,  # (n_nodes, 3) output: f_v = sum_e c_e b_e (b_e . v) (N)
):
    """Bulk-viscous nodal forces of the hexahedra, :math:`b_e` by the cofactor of F."""
    out[:, :] = 0.0
    for e in range(conn.shape[0]):
        if not coefficient[e] > 0.0:
            continue
        F00, F01, F02, F10, F11, F12, F20, F21, F22 = _hex_state(u, conn, bbar, e)
        c00 = F11 * F22 - F12 * F21
        c01 = F12 * F20 - F10 * F22
        c02 = F10 * F21 - F11 * F20
        c10 = F02 * F21 - F01 * F22
        c11 = F00 * F22 - F02 * F20
        c12 = F01 * F20 - F00 * F21
        c20 = F01 * F12 - F02 * F11
        c21 = F02 * F10 - F00 * F12
        c22 = F00 * F11 - F01 * F10
        s = 0.0
        for a in range(8):
            bx = bbar[e, a, 0]
            by = bbar[e, a, 1]
            bz = bbar[e, a, 2]
            grad[e, a, 0] = c00 * bx + c01 * by + c02 * bz
            grad[e, a, 1] = c10 * bx + c11 * by + c12 * bz
            grad[e, a, 2] = c20 * bx + c21 * by + c22 * bz
            n = conn[e, a]
            s += grad[e, a, 0] * v[n, 0] + grad[e, a, 1] * v[n, 1] + grad[e, a, 2] * v[n, 2]
        s *= coefficient[e]
        for a in range(8):
            n = conn[e, a]
            out[n, 0] += s * grad[e, a, 0]
            out[n, 1] += s * grad[e, a, 1]
            out[n, 2] += s * grad[e, a, 2]
