"""Small-strain stiffness of the mesh: element frequencies, lowest natural period, influence field.

These linear quantities set up an explicit run once, before the time loop:

- the highest frequency of each element (its 8x8 or 24x24 stiffness against its lumped masses)
  bounds
  the highest frequency of the mesh (Irons & Treharne) and gives the stable time step;
- the lowest natural frequency of the constrained sample sets the ramp time (or the mass
  scaling) that keeps the run quasi-static;
- the *influence field* w, the static displacement per unit platen travel, is the test field
  in which the platen force is evaluated by virtual work; it removes the sample's inertia from
  the reported force to first order (see :mod:`solver.explicit`).

The stiffness is that of the same mean-gradient quad or hexahedron with hourglass stiffness as
in :mod:`solver.kernels`, linearised at the reference state (tests check it against finite
differences of the force kernels).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .kernels import AxisymmetricOperators, HexOperators

__all__ = ["element_stiffness", "assemble", "element_max_frequency_sq", "lowest_mode",
           "influence_field"]


def _axisym_B(ops: AxisymmetricOperators) -> np.ndarray:
    """Small-strain operator, shape (n_elem, 4 strains (rr, zz, tt, rz), 8 dofs)."""
    n = len(ops.volume)
    B = np.zeros((n, 4, 8))
    br = ops.bbar[:, :, 0]
    bz = ops.bbar[:, :, 1]
    B[:, 0, 0::2] = br
    B[:, 1, 1::2] = bz
    B[:, 2, 0::2] = ops.hbar
    B[:, 3, 0::2] = bz
    B[:, 3, 1::2] = br
    return B


def _hex_B(ops: HexOperators) -> np.ndarray:
    """Small-strain operator, shape (n_elem, 6 strains (xx, yy, zz, 2xy, 2yz, 2xz), 24 dofs)."""
    n = len(ops.volume)
    B = np.zeros((n, 6, 24))
    bx, by, bz = ops.bbar[:, :, 0], ops.bbar[:, :, 1], ops.bbar[:, :, 2]
    B[:, 0, 0::3] = bx
    B[:, 1, 1::3] = by
    B[:, 2, 2::3] = bz
    B[:, 3, 0::3] = by
    B[:, 3, 1::3] = bx
    B[:, 4, 1::3] = bz
    B[:, 4, 2::3] = by
    B[:, 5, 0::3] = bz
    B[:, 5, 2::3] = bx
    return B


def element_stiffness(ops: AxisymmetricOperators | HexOperators, shear: np.ndarray,
                      bulk: np.ndarray, k_hg: np.ndarray) -> np.ndarray:
    """Small-strain element stiffness matrices.

    Parameters
    ----------
    ops : AxisymmetricOperators or HexOperators
    shear, bulk : ndarray, shape (n_elem,)
        Small-strain shear and bulk moduli of each element (Pa).
    k_hg : ndarray, shape (n_elem,)
        Hourglass stiffness (N/m).

    Returns
    -------
    ndarray, shape (n_elem, 8, 8) or (n_elem, 24, 24)
        DOF order (r0, z0, r1, z1, ...) or (x0, y0, z0, x1, ...) (N/m).
    """
    if isinstance(ops, HexOperators):
        return _hex_stiffness(ops, shear, bulk, k_hg)
    lam = bulk - 2.0 * shear / 3.0
    D = np.zeros((len(shear), 4, 4))
    for i in range(3):
        for j in range(3):
            D[:, i, j] = lam
        D[:, i, i] += 2.0 * shear
    D[:, 3, 3] = shear
    B = _axisym_B(ops)
    Ke = np.einsum("e,eki,ekl,elj->eij", ops.volume, B, D, B)
    G = np.einsum("ea,eb->eab", ops.gamma, ops.gamma) * k_hg[:, None, None]
    Ke[:, 0::2, 0::2] += G
    Ke[:, 1::2, 1::2] += G
    return Ke


def _hex_stiffness(ops: HexOperators, shear, bulk, k_hg) -> np.ndarray:
    lam = bulk - 2.0 * shear / 3.0
    D = np.zeros((len(shear), 6, 6))
    for i in range(3):
        for j in range(3):
            D[:, i, j] = lam
        D[:, i, i] += 2.0 * shear
        D[:, 3 + i, 3 + i] = shear
    B = _hex_B(ops)
    Ke = ops.volume[:, None, None] * (B.transpose(0, 2, 1) @ (D @ B))
    G = np.einsum("eka,ekb->eab", ops.gamma, ops.gamma) * k_hg[:, None, None]
    for a in range(3):
        Ke[:, a::3, a::3] += G
    return Ke


def assemble(cells: np.ndarray, Ke: np.ndarray, n_nodes: int, dim: int = 2) -> sp.csr_matrix:
    """Assemble element matrices (n_elem, n_en*dim, n_en*dim) into a sparse global matrix."""
    n_en = cells.shape[1]
    dofs = (cells[:, :, None] * dim + np.arange(dim)[None, None, :]).reshape(len(cells), -1)
    rows = np.repeat(dofs, n_en * dim, axis=1).ravel()
    cols = np.tile(dofs, (1, n_en * dim)).ravel()
    n = n_nodes * dim
    return sp.coo_matrix((Ke.ravel(), (rows, cols)), shape=(n, n)).tocsr()


def element_max_frequency_sq(Ke: np.ndarray, element_mass: np.ndarray) -> np.ndarray:
    """Highest eigenvalue :math:`\\omega^2` of each element against its lumped masses.

    Parameters
    ----------
    Ke : ndarray, shape (n_elem, n_dof_e, n_dof_e)
    element_mass : ndarray, shape (n_elem, n_en)
        The element's share of the lumped mass of each of its nodes (kg).

    Returns
    -------
    ndarray, shape (n_elem,)
        :math:`\\omega^2_{max}` (1/s^2).
    """
    dim = Ke.shape[1] // element_mass.shape[1]
    m = np.repeat(element_mass, dim, axis=1)  # (n_elem, n_dof_e)
    s = 1.0 / np.sqrt(m)
    A = Ke * s[:, :, None] * s[:, None, :]
    return np.linalg.eigvalsh(A)[:, -1]


#: Participation below which a mode counts as not excited by the platen (see lowest_mode).
PARTICIPATION = 1e-3


def lowest_mode(K: sp.csr_matrix, mass: np.ndarray, free: np.ndarray,
                load: np.ndarray | None = None, n_modes: int = 8) -> float:
    r"""Lowest natural angular frequency squared of the constrained sample.

    Parameters
    ----------
    K : sparse matrix, shape (n_dof, n_dof)
    mass : ndarray, shape (n_dof,)
        Lumped mass per DOF (kg).
    free : ndarray of bool, shape (n_dof,)
    load : ndarray, shape (n_dof,), optional
        The influence field :math:`w`. With the platen's motion written as
        :math:`u = w\,d(t) + u_d`, the free DOFs obey :math:`M\ddot u_d + K u_d =
        -M w\,\ddot d`, so a mode :math:`\phi` is excited in proportion to
        :math:`\phi^T M w`. Given ``load``, the lowest mode whose participation
        :math:`(\phi^T M w)^2 / (\phi^T M \phi\; w^T M w)` reaches :data:`PARTICIPATION`
        is returned: a 3D model's torsion and sway modes, orthogonal to an axisymmetric load
        by symmetry, do not set the time scale of the run. Without ``load``: the lowest mode.
    n_modes : int
        Modes computed at first (doubled up to 64 while none participates; if none does,
        the lowest is returned).

    Returns
    -------
    float
        :math:`\omega_1^2` (1/s^2).

    Notes
    -----
    ARPACK's start vector is seeded, so that the result, and every run built on it, is the
    same from one call to the next (with a random start, stick-slip decisions of a Coulomb
    run amplified its last-digit differences to 5e-4 of the force).
    """
    Kff = K[free][:, free].tocsc()
    m = mass[free]
    Mff = sp.diags(m).tocsc()
    n = Kff.shape[0]
    v0 = np.random.default_rng(0).uniform(0.5, 1.5, n)
    if load is None:
        vals = spla.eigsh(Kff, k=1, M=Mff, sigma=0.0, which="LM", v0=v0,
                          return_eigenvectors=False)
        return float(vals[0])
    Mw = m * load[free]
    ww = float(load[free] @ Mw)
    k = min(n_modes, n - 2)
    while True:
        vals, vecs = spla.eigsh(Kff, k=k, M=Mff, sigma=0.0, which="LM", v0=v0)
        for i in np.argsort(vals):
            phi = vecs[:, i]
            participation = (phi @ Mw) ** 2 / (float(phi @ (m * phi)) * ww)
            if participation >= PARTICIPATION:
                return float(vals[i])
        if k >= min(64, n - 2):
            return float(vals.min())
        k = min(2 * k, n - 2)


def influence_field(K: sp.csr_matrix, free: np.ndarray, prescribed: np.ndarray) -> np.ndarray:
    """Static displacement field for a prescribed unit motion of the constrained DOFs.

    Parameters
    ----------
    K : sparse matrix, shape (n_dof, n_dof)
    free : ndarray of bool, shape (n_dof,)
    prescribed : ndarray, shape (n_dof,)
        Values on the constrained DOFs (ignored on free ones).

    Returns
    -------
    ndarray, shape (n_dof,)
        w with w = prescribed on constrained DOFs and K_ff w_f = -K_fc w_c.
    """
    w = np.where(free, 0.0, prescribed)
    rhs = -(K[free][:, ~free] @ w[~free])
    w[free] = spla.spsolve(K[free][:, free].tocsc(), rhs)
    return w
