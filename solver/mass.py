r"""Volumetric selective mass scaling of the axisymmetric quads.

A gel at :math:`\nu = 0.499` carries dilatational waves about 22 times faster than shear waves
(:math:`c_d / c_s = \sqrt{(K + 4\mu/3)/\mu}`), so the explicit step of a lumped-mass model is
set by the volumetric stiffness, although the quasi-static platen force does not depend on the
inertia of volumetric deformation. The mass matrix here adds inertia to the volumetric
deformation of each element only,

.. math::

    M = M_L + \sum_e a_e\, b_e b_e^T, \qquad b_e = \frac{\partial \bar J_e}{\partial u_e},

(:math:`M_L` the lumped masses, :math:`b_e` the gradient of the element's mean Jacobian in
the current configuration), so that isochoric motions, among them the lowest natural mode
that sets the quasi-static time scale, keep their inertia, and the element's volumetric
frequency against it drops to ``c`` times its deviatoric one (Olovsson, Simonsson & Unosson
2005 scale the mass selectively in the same spirit). With the element bound of the highest
frequency

.. math::

    \omega^2_{max} \le \max_e \big[\lambda_{max}(K^{dev}_e, M_{L,e})
        + \lambda_{max}(\kappa_e b_e b_e^T, M_{L,e} + a_e b_e b_e^T)\big]
    \le \max_e (1 + c)\,\omega^2_{dev,e},

the stable step is that of the deviatoric response alone, :math:`(1 + c)^{-1/2}` of it,
instead of about :math:`c_s / c_d` of it.

Applying :math:`M^{-1}` is cheap because every added term has rank one: by Woodbury's identity

.. math::

    M^{-1} r = M_L^{-1}\big(r - B y\big), \qquad
    (D^{-1} + B^T M_L^{-1} B)\, y = B^T M_L^{-1} r,

with :math:`B = [b_1 \ldots b_{n_e}]` and :math:`D = \mathrm{diag}(a_e)`: one unknown per
element (a pressure-like variable), coupled only between elements that share a node. In the
mesh's own numbering or a reverse Cuthill-McKee order, whichever is narrower, this system is
banded (half-bandwidth one element row plus one, 15 on the default mesh) and is factorised by
a banded Cholesky whenever the mass is refreshed: when an element's volume gradient has
turned far enough from the one in the mass (:func:`volumetric_drift`), so that :math:`b_e`
follows the deformation, and whenever the set of held DOFs changes (a node lands on or leaves
a platen). The time loop applies the inverse of the free-free block (``b_e`` zero on held
DOFs); the held DOFs take the accelerations their constraints prescribe, and their coupling
to the free ones goes to the right side (:func:`solver.explicit._coupled_update`).

Array order as in :mod:`solver.kernels`: nodal ``(n_nodes, 2)``, element ``(n_elem, 4, 2)``,
the band ``(n_elem, kd + 1)`` in lower storage (``band[i, k]`` is entry ``(i, i - k)``).

References
----------
Olovsson L, Simonsson K, Unosson M (2005). Selective mass scaling for explicit finite element
analyses. Int J Numer Methods Eng 63:1436-1445. doi:10.1002/nme.1293
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee

from ._jit import njit, njit_inline
from .kernels import _axisym_state

__all__ = ["VolumetricMass", "volumetric_gradient", "assemble_band",
           "band_cholesky", "band_solve", "apply_inverse", "apply_mass", "added_mass_matrix",
           "volumetric_drift"]


class VolumetricMass:
    """The fixed part of the volumetric mass: coefficients, element order and work arrays.

    Attributes
    ----------
    coefficient : ndarray, shape (n_elem,)
        :math:`a_e` (kg m^2 in the axisymmetric model); zero where no mass is added.
    position : ndarray of int64, shape (n_elem,)
        Band position of each element (reverse Cuthill-McKee).
    kd : int
        Half-bandwidth of the element system.
    ptr, slot : ndarray of int64
        Node-to-element incidence (:func:`solver.kernels.node_slots`).
    gradient : ndarray, shape (n_elem, 4, 2)
        :math:`b_e` at the last refresh, zero on held DOFs.
    band : ndarray, shape (n_elem, kd + 1)
        Cholesky factor of :math:`D^{-1} + B^T M_L^{-1} B` at the last refresh.
    work : ndarray, shape (n_elem,)
    """

    def __init__(self, coefficient, position, kd, ptr, slot):
        n = len(coefficient)
        self.coefficient = np.ascontiguousarray(coefficient, dtype=np.float64)
        self.position = np.ascontiguousarray(position, dtype=np.int64)
        self.kd = int(kd)
        self.ptr = ptr
        self.slot = slot
        self.gradient = np.zeros((n, 4, 2))
        self.band = np.zeros((n, self.kd + 1))
        self.work = np.zeros(n)

    def with_coefficient(self, coefficient: np.ndarray) -> VolumetricMass:
        """The same topology with other coefficients and fresh work arrays."""
        return VolumetricMass(coefficient, self.position, self.kd, self.ptr, self.slot)

    @classmethod
    def for_mesh(cls, cells: np.ndarray, n_nodes: int,
                 coefficient: np.ndarray) -> VolumetricMass:
        """Set up the volumetric mass of a quad mesh with element coefficients ``a_e``.

        Parameters
        ----------
        cells : ndarray, shape (n_elem, 4)
        n_nodes : int
        coefficient : ndarray, shape (n_elem,)
            :math:`a_e` (kg m^2), >= 0.
        """
        from .kernels import node_slots

        n = len(cells)
        ptr, slot = node_slots(cells, n_nodes)
        # element adjacency through shared nodes, for the band order
        corner_elem = slot // cells.shape[1]
        rows, cols = [], []
        for node in range(n_nodes):
            elems = corner_elem[ptr[node]:ptr[node + 1]]
            rows.append(np.repeat(elems, len(elems)))
            cols.append(np.tile(elems, len(elems)))
        rows = np.concatenate(rows) if rows else np.zeros(0, np.int64)
        cols = np.concatenate(cols) if cols else np.zeros(0, np.int64)
        if not len(rows):
            return cls(coefficient, np.arange(n), 0, ptr, slot)
        graph = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
        # the mesh's own numbering or reverse Cuthill-McKee, whichever has the narrower band
        # (a structured mesh numbered row by row: one element row, 15 on the default mesh;
        # RCM: 27 there, but it repairs an unstructured numbering)
        best = None
        for order in (np.arange(n), reverse_cuthill_mckee(graph, symmetric_mode=True)):
            position = np.empty(n, dtype=np.int64)
            position[order] = np.arange(n)
            kd = int(np.max(np.abs(position[rows] - position[cols])))
            if best is None or kd < best[1]:
                best = (position, kd)
        return cls(coefficient, best[0], best[1], ptr, slot)



# ====================================================================== JIT kernels
@njit_inline
def element_dot(e, grad, x, conn):
    r""":math:`b_e \cdot x_e` of element ``e`` (grad (n_elem, 4, 2), x (n_nodes, 2))."""
    s = 0.0
    for a in range(4):
        n = conn[e, a]
        s += grad[e, a, 0] * x[n, 0] + grad[e, a, 1] * x[n, 1]
    return s


@njit
def volumetric_gradient(
    u,  # (n_nodes, 2) displacement (m)
    conn,  # (n_elem, 4) int32
    bbar,  # (n_elem, 4, 2)
    hbar,  # (n_elem, 4)
    coupled,  # (n_nodes, 2) bool: DOFs that take part in the volumetric mass
    coefficient,  # (n_elem,) a_e: elements without added mass get a zero gradient
    out,  # (n_elem, 4, 2) output: dJ/du of each element's mean Jacobian, zero off ``coupled``
):
    r"""Gradient of the mean Jacobian :math:`\bar J = \det \bar F_{rz}\, \bar F_{\theta\theta}`.

    :math:`\partial \bar J/\partial u_{r,a} = F_{\theta\theta}(F_{zz} \bar b_{a,r} - F_{zr}
    \bar b_{a,z}) + \det \bar F_{rz}\, \bar h_a` and :math:`\partial \bar J/\partial u_{z,a}
    = F_{\theta\theta}(F_{rr} \bar b_{a,z} - F_{rz} \bar b_{a,r})`; at the reference state the
    volumetric row of the small-strain operator. Elements without added mass get zeros, so
    that they drop out of the Woodbury system.
    """
    for e in range(conn.shape[0]):
        if not coefficient[e] > 0.0:
            out[e, :, :] = 0.0
            continue
        Frr, Frz, Fzr, Fzz, Ftt = _axisym_state(u, conn, bbar, hbar, e)
        det2 = Frr * Fzz - Frz * Fzr
        for a in range(4):
            n = conn[e, a]
            br = bbar[e, a, 0]
            bz = bbar[e, a, 1]
            out[e, a, 0] = (Ftt * (Fzz * br - Fzr * bz) + det2 * hbar[e, a]) if coupled[n, 0] \
                else 0.0
            out[e, a, 1] = Ftt * (Frr * bz - Frz * br) if coupled[n, 1] else 0.0


@njit
def assemble_band(
    grad,  # (n_elem, 4, 2) b_e, zero on held DOFs
    mass,  # (n_nodes,) lumped masses (kg)
    coefficient,  # (n_elem,) a_e
    position,  # (n_elem,) int64 band position
    ptr,  # (n_nodes + 1,) int64
    slot,  # (n_elem * 4,) int64
    band,  # (n_elem, kd + 1) output: D^-1 + B^T M_L^-1 B in lower band storage
):
    r"""Assemble the element system of the Woodbury identity (see the module notes).

    An element without added mass (:math:`a_e = 0`) gets a unit diagonal and no coupling:
    its unknown is then zero, as :math:`D^{-1} \to \infty` demands.
    """
    n_elem = grad.shape[0]
    band[:] = 0.0
    for e in range(n_elem):
        a = coefficient[e]
        band[position[e], 0] = 1.0 / a if a > 0.0 else 1.0
    for node in range(mass.shape[0]):
        inv_m = 1.0 / mass[node]
        for i in range(ptr[node], ptr[node + 1]):
            e1 = slot[i] // 4
            if coefficient[e1] <= 0.0:
                continue
            a1 = slot[i] % 4
            p1 = position[e1]
            for j in range(ptr[node], ptr[node + 1]):
                e2 = slot[j] // 4
                p2 = position[e2]
                if p2 > p1 or coefficient[e2] <= 0.0:
                    continue
                a2 = slot[j] % 4
                band[p1, p1 - p2] += inv_m * (grad[e1, a1, 0] * grad[e2, a2, 0]
                                              + grad[e1, a1, 1] * grad[e2, a2, 1])


@njit
def band_cholesky(band):  # (n, kd + 1) lower band storage, factorised in place
    """Cholesky factor L (lower, same storage) of a symmetric positive definite band matrix.

    Returns
    -------
    int
        -1 on success, else the first row whose pivot is not positive.
    """
    n, w = band.shape
    kd = w - 1
    for i in range(n):
        j0 = max(0, i - kd)
        for j in range(j0, i + 1):
            s = band[i, i - j]
            for k in range(max(j0, j - kd), j):
                s -= band[i, i - k] * band[j, j - k]
            if j == i:
                if not s > 0.0:
                    return i
                band[i, 0] = math.sqrt(s)
            else:
                band[i, i - j] = s / band[j, 0]
    return -1


@njit
def band_solve(band, y):  # band (n, kd + 1) Cholesky factor; y (n,) right side, solved in place
    """Solve :math:`L L^T y = q` in place with the factor of :func:`band_cholesky`."""
    n, w = band.shape
    kd = w - 1
    for i in range(n):
        s = y[i]
        for k in range(max(0, i - kd), i):
            s -= band[i, i - k] * y[k]
        y[i] = s / band[i, 0]
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, min(n, i + kd + 1)):
            s -= band[k, k - i] * y[k]
        y[i] = s / band[i, 0]


@njit
def apply_inverse(
    r,  # (n_nodes, 2) force (N)
    conn,  # (n_elem, 4) int32
    mass,  # (n_nodes,) lumped masses (kg)
    grad,  # (n_elem, 4, 2) b_e of the last refresh, zero on held DOFs
    position,  # (n_elem,) int64
    band,  # (n_elem, kd + 1) Cholesky factor of the element system
    y,  # (n_elem,) work array
    out,  # (n_nodes, 2) output: M^-1 r (m/s^2)
):
    """Acceleration :math:`M^{-1} r` by Woodbury's identity (see the module notes)."""
    n_nodes = r.shape[0]
    for i in range(n_nodes):
        inv_m = 1.0 / mass[i]
        out[i, 0] = r[i, 0] * inv_m
        out[i, 1] = r[i, 1] * inv_m
    for e in range(conn.shape[0]):
        y[position[e]] = element_dot(e, grad, out, conn)
    band_solve(band, y)
    for e in range(conn.shape[0]):
        ye = y[position[e]]
        for a in range(4):
            n = conn[e, a]
            inv_m = 1.0 / mass[n]
            out[n, 0] -= inv_m * grad[e, a, 0] * ye
            out[n, 1] -= inv_m * grad[e, a, 1] * ye


def added_mass_matrix(cells: np.ndarray, grad: np.ndarray, coefficient: np.ndarray,
                      n_nodes: int) -> sp.csr_matrix:
    r"""The added part :math:`\sum_e a_e b_e b_e^T` as a sparse matrix (n_dof, n_dof)."""
    Ae = coefficient[:, None, None] * np.einsum("ei,ej->eij", grad.reshape(len(cells), -1),
                                                 grad.reshape(len(cells), -1))
    from .stiffness import assemble

    return assemble(cells, Ae, n_nodes, 2)


@njit
def apply_mass(
    x,  # (n_nodes, 2)
    conn,  # (n_elem, 4) int32
    mass,  # (n_nodes,) lumped masses (kg)
    grad,  # (n_elem, 4, 2) b_e, zero on DOFs left out
    coefficient,  # (n_elem,) a_e
    out,  # (n_nodes, 2) output: M x (N)
):
    r"""Product :math:`M x = M_L x + \sum_e a_e b_e (b_e \cdot x_e)`."""
    for i in range(x.shape[0]):
        out[i, 0] = mass[i] * x[i, 0]
        out[i, 1] = mass[i] * x[i, 1]
    for e in range(conn.shape[0]):
        s = element_dot(e, grad, x, conn) * coefficient[e]
        for a in range(4):
            n = conn[e, a]
            out[n, 0] += grad[e, a, 0] * s
            out[n, 1] += grad[e, a, 1] * s


@njit
def volumetric_drift(
    u,  # (n_nodes, 2) displacement (m)
    conn,  # (n_elem, 4) int32
    bbar,  # (n_elem, 4, 2)
    hbar,  # (n_elem, 4)
    grad,  # (n_elem, 4, 2) b_e at the last refresh (every DOF)
    share,  # (n_elem, 4) the element's share of the lumped mass of each node (kg)
    coefficient,  # (n_elem,) a_e (kg m^2)
    everywhere,  # (n_nodes, 2) bool, all true
    out,  # (n_elem, 4, 2) work array: b_e now
):
    r"""Largest growth of an element's volumetric frequency since the mass was refreshed.

    The element's volumetric stiffness is :math:`\kappa_e b b^T` with the current gradient
    :math:`b`; its mass still holds :math:`a_e b_r b_r^T` of the last refresh, so the part
    of :math:`b` off :math:`b_r` meets only the lumped masses. The frequency is
    :math:`\lambda_e = \kappa_e (s_{bb} - a_e s_{rb}^2 / (1 + a_e s_{rr}))` with
    :math:`s_{xy} = \sum x y / m`; returned is :math:`\max_e \lambda_e \beta_e` with
    :math:`\beta_e = a_e / \kappa_e`, whose design value (no drift) is just below 1:
    :math:`a_e s_{bb} - a_e^2 s_{rb}^2/(1 + a_e s_{rr})`, which needs no :math:`\kappa_e`.
    """
    volumetric_gradient(u, conn, bbar, hbar, everywhere, coefficient, out)
    worst = 0.0
    for e in range(conn.shape[0]):
        a = coefficient[e]
        if not a > 0.0:
            continue
        s_bb = 0.0
        s_rb = 0.0
        s_rr = 0.0
        for k in range(4):
            inv_m = 1.0 / share[e, k]
            for d in range(2):
                b = out[e, k, d]
                r = grad[e, k, d]
                s_bb += b * b * inv_m
                s_rb += r * b * inv_m
                s_rr += r * r * inv_m
        ratio = a * (s_bb - a * s_rb * s_rb / (1.0 + a * s_rr))
        if ratio > worst:
            worst = ratio
    return worst
