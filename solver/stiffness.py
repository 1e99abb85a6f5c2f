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

import math

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ._jit import njit
from .kernels import AxisymmetricOperators, HexOperators

__all__ = ["element_stiffness", "assemble", "element_max_frequency_sq",
           "element_max_frequency_sq_coupled", "factorize", "lanczos_max", "lowest_mode",
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
    r"""Highest eigenvalue :math:`\omega^2` of each element against its lumped masses.

    Parameters
    ----------
    Ke : ndarray, shape (n_elem, n_dof_e, n_dof_e)
    element_mass : ndarray, shape (n_elem, n_en)
        The element's share of the lumped mass of each of its nodes (kg).

    Returns
    -------
    ndarray, shape (n_elem,)
        :math:`\omega^2_{max}` (1/s^2).
    """
    dim = Ke.shape[1] // element_mass.shape[1]
    m = np.repeat(element_mass, dim, axis=1)  # (n_elem, n_dof_e)
    s = 1.0 / np.sqrt(m)
    A = Ke * s[:, :, None] * s[:, None, :]
    return np.linalg.eigvalsh(A)[:, -1]


def element_max_frequency_sq_coupled(Ke: np.ndarray, element_mass: np.ndarray,
                                     grad: np.ndarray, coefficient: np.ndarray) -> np.ndarray:
    r"""Highest :math:`\omega^2` of each element against lumped plus volumetric mass.

    The element's mass is :math:`M_e = \mathrm{diag}(m_e) + a_e b_e b_e^T` (see
    :mod:`solver.mass`); the eigenvalues of :math:`L^{-1} K_e L^{-T}` with
    :math:`M_e = L L^T` are those of the pencil. The largest over the elements bounds the
    mesh's highest frequency (the Rayleigh quotient of a sum of element terms).

    Parameters
    ----------
    Ke : ndarray, shape (n_elem, 8, 8)
    element_mass : ndarray, shape (n_elem, 4)
    grad : ndarray, shape (n_elem, 4, 2)
        :math:`b_e`.
    coefficient : ndarray, shape (n_elem,)
        :math:`a_e`.

    Returns
    -------
    ndarray, shape (n_elem,)
    """
    n = len(Ke)
    b = grad.reshape(n, -1)
    Me = coefficient[:, None, None] * np.einsum("ei,ej->eij", b, b)
    diag = np.arange(Me.shape[1])
    Me[:, diag, diag] += np.repeat(element_mass, 2, axis=1)
    L_inv = np.linalg.inv(np.linalg.cholesky(Me))
    return np.linalg.eigvalsh(L_inv @ Ke @ np.transpose(L_inv, (0, 2, 1)))[:, -1]


def lanczos_max(apply_K, apply_M, apply_M_inv, start: np.ndarray, n_iter: int = 10):
    r"""Largest eigenvalue of the pencil :math:`(K, M)` by Lanczos in the M-inner product.

    :math:`M^{-1} K` is self-adjoint in :math:`\langle x, y\rangle_M = x^T M y`; the
    Krylov space from ``start`` is orthogonalised against every earlier vector (twice). The
    largest Ritz value approaches the largest eigenvalue from below; ten steps from a warm
    start (the last call's Ritz vector) find it to a few per cent.

    Parameters
    ----------
    apply_K, apply_M, apply_M_inv : callable
        Products with :math:`K`, :math:`M`, :math:`M^{-1}` (arrays of the shape of
        ``start``).
    start : ndarray
    n_iter : int

    Returns
    -------
    value : float
    vector : ndarray
        The Ritz vector (M-normalised), a warm start for the next call.
    """
    q = start / math.sqrt(float(np.vdot(start, apply_M(start))))
    basis, m_basis, alphas, betas = [], [], [], []
    for _ in range(n_iter):
        kq = apply_K(q)
        basis.append(q)
        m_basis.append(apply_M(q))
        alphas.append(float(np.vdot(q, kq)))
        w = apply_M_inv(kq)
        for _ in range(2):
            for qi, mqi in zip(basis, m_basis):
                w = w - float(np.vdot(mqi, w)) * qi
        beta = math.sqrt(max(float(np.vdot(w, apply_M(w))), 0.0))
        if beta <= 1e-12 * abs(alphas[-1]):
            break
        betas.append(beta)
        q = w / beta
    k = len(alphas)
    vals, vecs = scipy.linalg.eigh_tridiagonal(np.array(alphas), np.array(betas[:k - 1]))
    top = vecs[:, -1]
    return float(vals[-1]), sum(c * qi for c, qi in zip(top, basis))


def factorize(K: sp.spmatrix, free: np.ndarray):
    """Sparse LU factors of the free-free block, shared by the static set-up.

    :func:`lowest_mode` and :func:`influence_field` take them as ``lu``.
    The block is symmetric positive definite once the platens hold the sample, so SuperLU
    runs in its symmetric mode with a minimum-degree ordering of :math:`K + K^T` and no
    pivoting: for the 17 000 DOFs of a 6000-hexahedron cylinder this factorises in a
    third of the time of the default column ordering, with a quarter less fill.

    A block already banded in its own numbering (half-bandwidth at most four times the
    square root of its size: a structured quad mesh numbered row by row) keeps that order,
    whose fill is the band: for the 500 DOFs of the default axisymmetric mesh this factorises
    in two thirds of the time of the minimum-degree ordering (0.39 against 0.60 ms).

    Returns
    -------
    scipy.sparse.linalg.SuperLU
    """
    Kff = K[free][:, free].tocsc()
    coo = Kff.tocoo()
    banded = coo.nnz and np.abs(coo.row - coo.col).max() <= 4.0 * math.sqrt(Kff.shape[0])
    return spla.splu(Kff, permc_spec="NATURAL" if banded else "MMD_AT_PLUS_A",
                     diag_pivot_thresh=0.0, options={"SymmetricMode": True})


#: Participation below which a mode counts as not excited by the platen (see lowest_mode).
PARTICIPATION = 1e-3


def lowest_mode(K: sp.csr_matrix, mass, free: np.ndarray,
                load: np.ndarray | None = None, n_modes: int = 8, lu=None) -> float:
    r"""Lowest natural angular frequency squared of the constrained sample.

    Parameters
    ----------
    K : sparse matrix, shape (n_dof, n_dof)
    mass : ndarray, shape (n_dof,), or sparse matrix, shape (n_dof, n_dof)
        Lumped mass per DOF (kg), or a mass matrix (with the volumetric mass of
        :mod:`solver.mass`).
    free : ndarray of bool, shape (n_dof,)
    load : ndarray, shape (n_dof,), optional
        The influence field :math:`w`. With the platen's motion written as
        :math:`u = w\,d(t) + u_d`, the free DOFs obey :math:`M\ddot u_d + K u_d =
        -M w\,\ddot d`, so a mode :math:`\phi` is excited in proportion to
        :math:`\phi^T M w`. Given ``load``, the lowest mode whose participation
        :math:`(\phi^T M w)^2 / (\phi^T M \phi\; w^T M w)` reaches :data:`PARTICIPATION`
        is returned: a 3D model's torsion and sway modes, orthogonal to an axisymmetric load
        by symmetry, do not set the time scale of the run. The mode is found by
        Rayleigh-Ritz in the Krylov space of :math:`K^{-1}M` started from :math:`w`, which
        holds only excited modes (:func:`_krylov_lowest`); should that not converge,
        ``n_modes`` modes are computed by ARPACK (doubled up to 64 while none
        participates; if none does, the lowest is returned). Without ``load``: the lowest
        mode.
    n_modes : int
        See ``load``.
    lu : scipy.sparse.linalg.SuperLU, optional
        :func:`factorize` of ``K`` and ``free``, to reuse.

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
    if sp.issparse(mass):
        Mff = sp.csr_matrix(mass)[free][:, free].tocsc()
    else:
        Mff = sp.diags(mass[free]).tocsc()
    n = Kff.shape[0]
    if lu is None:
        lu = factorize(K, free)
    OPinv = spla.LinearOperator((n, n), matvec=lu.solve, dtype=float)

    def modes(k, v0, vectors=True):
        return spla.eigsh(Kff, k=k, M=Mff, sigma=0.0, which="LM", v0=v0, OPinv=OPinv,
                          return_eigenvectors=vectors)

    seeded = np.random.default_rng(0).uniform(0.5, 1.5, n)
    if load is None:
        return float(modes(1, seeded, vectors=False)[0])
    Mw = Mff @ load[free]
    ww = float(load[free] @ Mw)

    def participation(phi):
        return (phi @ Mw) ** 2 / (float(phi @ (Mff @ phi)) * ww)

    found = _krylov_lowest(Kff, Mff, lu, load[free], participation)
    if found is not None:
        return found
    k = min(n_modes, n - 2)
    while True:
        vals, vecs = modes(k, seeded)
        for i in np.argsort(vals):
            if participation(vecs[:, i]) >= PARTICIPATION:
                return float(vals[i])
        if k >= min(64, n - 2):
            return float(vals.min())
        k = min(2 * k, n - 2)


def _krylov_lowest(Kff, Mff, lu, w, participation, n_max: int = 24, rtol: float = 1e-10):
    """Lowest participating Ritz value in the Krylov space of K^-1 M started from ``w``.

    Block-free Lanczos with full M-orthogonalisation (twice, against the rounding that would
    let non-excited modes leak in); stops when the lowest participating Ritz value changes
    by less than ``rtol``. Returns None if it does not converge within ``n_max`` vectors.
    """
    basis = []
    x = w.copy()
    scale = math.sqrt(float(x @ (Mff @ x)))
    previous = None
    for _ in range(n_max):
        for _ in range(2):
            for v in basis:
                x = x - (v @ (Mff @ x)) * v
        norm = math.sqrt(float(x @ (Mff @ x)))
        if basis and norm <= 1e-12 * scale:
            break  # the space is exhausted (invariant subspace reached)
        x = x / norm
        basis.append(x)
        V = np.column_stack(basis)
        Kr = V.T @ (Kff @ V)
        Mr = V.T @ (Mff @ V)
        vals, vecs = scipy.linalg.eigh(0.5 * (Kr + Kr.T), 0.5 * (Mr + Mr.T))
        current = None
        for i in np.argsort(vals):
            if participation(V @ vecs[:, i]) >= PARTICIPATION:
                current = float(vals[i])
                break
        if current is not None and previous is not None and abs(current - previous) <= (
                rtol * abs(current)):
            return current
        previous = current
        x = lu.solve(Mff @ x)
    return None


@njit
def _free_band(indptr, indices, data, index, band):
    """Symmetric part of the free-free block of a CSR matrix, in lower band storage.

    ``index`` (n_dof,) numbers the free DOFs (-1: held); ``band`` (n_free, kd + 1) must be
    wide enough (entry (i, i - k) in ``band[i, k]``).
    """
    band[:] = 0.0
    for row in range(len(indptr) - 1):
        i = index[row]
        if i < 0:
            continue
        for k in range(indptr[row], indptr[row + 1]):
            j = index[indices[k]]
            if j < 0:
                continue
            if i == j:
                band[i, 0] += data[k]
            elif i > j:
                band[i, i - j] += 0.5 * data[k]
            else:
                band[j, j - i] += 0.5 * data[k]


def _banded_solve(K: sp.csr_matrix, free: np.ndarray, rhs: np.ndarray):
    """Solve the free-free block's symmetric part for ``rhs`` by banded Cholesky.

    Returns None when the numbering is not banded (half-bandwidth above four times the square
    root of the size) or the symmetric part is not positive definite.
    """
    from .mass import band_cholesky, band_solve

    index = np.full(K.shape[0], -1, dtype=np.int64)
    index[free] = np.arange(int(free.sum()))
    rows = np.repeat(np.arange(K.shape[0]), np.diff(K.indptr))
    keep = (index[rows] >= 0) & (index[K.indices] >= 0)
    if not keep.any():
        return None
    kd = int(np.abs(index[rows[keep]] - index[K.indices[keep]]).max())
    n = len(rhs)
    if kd > 4.0 * math.sqrt(n):
        return None
    band = np.zeros((n, kd + 1))
    _free_band(K.indptr.astype(np.int64), K.indices.astype(np.int64), K.data, index, band)
    if band_cholesky(band) >= 0:
        return None
    x = np.array(rhs, dtype=np.float64)
    band_solve(band, x)
    return x


def influence_field(K: sp.csr_matrix, free: np.ndarray, prescribed: np.ndarray,
                    lu=None, banded: bool = False) -> np.ndarray:
    """Static displacement field for a prescribed unit motion of the constrained DOFs.

    Parameters
    ----------
    K : sparse matrix, shape (n_dof, n_dof)
    free : ndarray of bool, shape (n_dof,)
    prescribed : ndarray, shape (n_dof,)
        Values on the constrained DOFs (ignored on free ones).
    lu : scipy.sparse.linalg.SuperLU, optional
        :func:`factorize` of ``K`` and ``free``, to reuse.

    banded : bool
        Solve with the symmetric part of :math:`K_{ff}` by banded Cholesky when the block
        is banded in its numbering (a tangent by finite differences is symmetric to its
        differencing error): a quarter of the time of the sparse LU on the default
        axisymmetric mesh. Falls back to the LU otherwise.

    Returns
    -------
    ndarray, shape (n_dof,)
        w with w = prescribed on constrained DOFs and K_ff w_f = -K_fc w_c.
    """
    K = sp.csr_matrix(K)
    w = np.where(free, 0.0, prescribed)
    rhs = -(K[free][:, ~free] @ w[~free])
    solved = _banded_solve(K, free, rhs) if banded and lu is None else None
    if solved is None:
        if lu is None:
            lu = factorize(K, free)
        solved = lu.solve(rhs)
    w[free] = solved
    return w


# ====================================================================== tangent stiffness
class TangentProbe:
    """Tangent stiffness of the mesh by coloured finite differences of its force kernel.

    Nodes are coloured so that no two nodes of one colour share an element *or a neighbour*
    (greedy colouring of the square of the node graph, a distance-2 colouring); perturbing
    every node of a colour in one direction at once then yields the stiffness columns of all
    of them from one kernel call, because each node's force row sees at most one perturbed
    node. ``n_colours * dim + 1`` kernel calls give the whole sparse matrix (9 colours on a
    structured quad mesh).

    Parameters
    ----------
    cells : ndarray, shape (n_elem, n_en)
    n_nodes, dim : int
    """

    def __init__(self, cells: np.ndarray, n_nodes: int, dim: int):
        self.dim = dim
        n_en = cells.shape[1]
        pairs = np.stack(np.meshgrid(np.arange(n_en), np.arange(n_en), indexing="ij"), -1)
        pairs = pairs.reshape(-1, 2)
        a = cells[:, pairs[:, 0]].ravel()
        b = cells[:, pairs[:, 1]].ravel()
        adj = sp.coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)),
                            shape=(n_nodes, n_nodes)).tocsr()
        adj.sum_duplicates()
        square = (adj.astype(np.int32) @ adj.astype(np.int32)).tocsr()
        colour = np.full(n_nodes, -1, dtype=np.int64)
        for node in range(n_nodes):
            taken = colour[square.indices[square.indptr[node]:square.indptr[node + 1]]]
            c = 0
            while c in taken:
                c += 1
            colour[node] = c
        self.colour = colour
        self.n_colours = int(colour.max()) + 1
        # neighbour[c, m]: the node of colour c adjacent to m (or m itself), -1 if none
        neighbour = np.full((self.n_colours, n_nodes), -1, dtype=np.int64)
        rows = np.repeat(np.arange(n_nodes), np.diff(adj.indptr))
        neighbour[colour[adj.indices], rows] = adj.indices
        self.neighbour = neighbour
        # the fixed sparsity pattern, in the order the values are gathered by stiffness():
        # for colour c, direction a, row direction b: rows m*dim+b, columns nb(m)*dim+a
        r_all, c_all = [], []
        node_rows = np.arange(n_nodes)
        for c in range(self.n_colours):
            has = neighbour[c] >= 0
            for a in range(dim):
                for b in range(dim):
                    r_all.append(node_rows[has] * dim + b)
                    c_all.append(neighbour[c][has] * dim + a)
        r_all = np.concatenate(r_all)
        c_all = np.concatenate(c_all)
        n = n_nodes * dim
        pattern = sp.csr_matrix((np.arange(1, len(r_all) + 1, dtype=np.float64),
                                 (r_all, c_all)), shape=(n, n))
        pattern.sort_indices()
        self._order = pattern.data.astype(np.int64) - 1  # csr position -> gathered value
        self._indices = pattern.indices.copy()
        self._indptr = pattern.indptr.copy()
        self._shape = (n, n)

    def stiffness(self, forces, u: np.ndarray, h: float) -> sp.csr_matrix:
        """Tangent stiffness at the displacement ``u`` (forward differences of step ``h``).

        Parameters
        ----------
        forces : callable
            ``forces(u)`` returns the internal nodal forces (n_nodes, dim) without changing
            any state (no history update).
        u : ndarray, shape (n_nodes, dim)
        h : float
            Displacement step (m), small against the elements, large against rounding.
        """
        dim = self.dim
        f0 = forces(u)
        vals = []
        for c in range(self.n_colours):
            mask = self.colour == c
            has = self.neighbour[c] >= 0
            for a in range(dim):
                up = u.copy()
                up[mask, a] += h
                df = (forces(up) - f0)[has] / h
                for b in range(dim):
                    vals.append(df[:, b])
        data = np.concatenate(vals)[self._order]
        return sp.csr_matrix((data, self._indices, self._indptr), shape=self._shape)
