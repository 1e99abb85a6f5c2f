"""Slow, readable NumPy twins of the JIT kernels, for the tests only.

Each twin computes the same quantity as a kernel in :mod:`solver` by a different route
(full 3x3 eigen-decompositions with ``numpy.linalg.eigh``, vectorised over elements), so that a
shared mistake is unlikely.
"""

from __future__ import annotations

import numpy as np

from solver.kernels import AxisymmetricOperators
from solver.materials import Ogden


def distorted_axisym_mesh(points, cells, amount, rng):
    """Move interior nodes by up to ``amount`` of the local element size, seeded."""
    from solver.mesh import Mesh

    mesh = Mesh(points=points, cells=cells, cell_type="quad")
    boundary = mesh.boundary_nodes()
    edges = np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]]])
    h = np.linalg.norm(points[edges[:, 0]] - points[edges[:, 1]], axis=1).min()
    moved = points.copy()
    jitter = rng.uniform(-amount * h, amount * h, size=points.shape)
    moved[~boundary] += jitter[~boundary]
    return moved


def mean_gradient(u, cells, ops: AxisymmetricOperators):
    """(F (n_elem, 3, 3)) of the mean-gradient quad, hoop as the third direction."""
    ue = u[cells]  # (n_elem, 4, 2)
    F = np.zeros((len(cells), 3, 3))
    F[:, :2, :2] = np.eye(2) + np.einsum("eia,eib->eab", ue, ops.bbar)
    F[:, 2, 2] = 1.0 + np.einsum("ei,ei->e", ue[:, :, 0], ops.hbar)
    return F


def pk2_numpy(F, material: Ogden):
    """Second Piola-Kirchhoff stress (n_elem, 3, 3) via eigh of C (long-term moduli)."""
    C = np.einsum("eka,ekb->eab", F, F)
    c, N = np.linalg.eigh(C)
    tau = material.kirchhoff_stress(np.sqrt(c))
    return np.einsum("ea,eia,eja->eij", tau / c, N, N)


def axisym_forces_numpy(u, cells, ops: AxisymmetricOperators, material: Ogden, k_hg):
    """Internal nodal forces (n_nodes, 2) of elastic axisymmetric quads."""
    F = mean_gradient(u, cells, ops)
    S = pk2_numpy(F, material)
    P = np.einsum("eik,ekj->eij", F, S) * ops.volume[:, None, None]
    fe = np.einsum("eab,eib->eia", P[:, :2, :2], ops.bbar)
    fe[:, :, 0] += P[:, 2, 2][:, None] * ops.hbar
    q = np.einsum("ei,eia->ea", ops.gamma, u[cells]) * k_hg[:, None]  # (n_elem, 2)
    fe += ops.gamma[:, :, None] * q[:, None, :]
    f = np.zeros_like(u)
    np.add.at(f, cells, fe)
    return f


def axisym_energy_numpy(u, cells, ops: AxisymmetricOperators, material: Ogden, k_hg):
    """(elastic energy, hourglass energy) in J."""
    F = mean_gradient(u, cells, ops)
    C = np.einsum("eka,ekb->eab", F, F)
    lam = np.sqrt(np.linalg.eigvalsh(C))
    W = float(np.sum(ops.volume * material.strain_energy(lam)))
    q = np.einsum("ei,eia->ea", ops.gamma, u[cells])
    return W, float(0.5 * np.sum(k_hg[:, None] * q**2))


def prony_convolution(t_eval, s0_of, g, tau, breakpoints=()):
    """Hereditary integral of a stress history by adaptive quadrature (scipy.integrate.quad).

    S(t) = g_inf s0(t) + sum_k g_k int_0^t exp(-(t - s)/tau_k) ds0/ds ds, with ds0/ds by central
    differences of the callable ``s0_of``; ``breakpoints`` are kinks of the history.
    """
    from scipy.integrate import quad

    def rate(s, h=1e-5):
        return (s0_of(s + h) - s0_of(s - h)) / (2 * h)

    out = []
    for t in np.atleast_1d(t_eval):
        total = (1.0 - sum(g)) * s0_of(t)
        for gk, tk in zip(g, tau):
            pts = [p for p in breakpoints if 0 < p < t]
            val, _ = quad(lambda s, t=t, tk=tk: np.exp(-(t - s) / tk) * rate(s), 0.0, t,
                          points=pts or None,
                          limit=400, epsabs=1e-9, epsrel=1e-9)
            total += gk * val
        out.append(total)
    return np.array(out)


# ---------------------------------------------------------------------- hexahedron
def distorted_hex_mesh(mesh, amount, rng):
    """Move interior nodes of a hexahedral mesh by up to ``amount`` of the shortest edge."""
    from solver.mesh import Mesh

    boundary = mesh.boundary_nodes()
    edges = mesh.cells[:, [0, 1, 1, 2, 0, 4]].reshape(-1, 2)
    h = np.linalg.norm(mesh.points[edges[:, 0]] - mesh.points[edges[:, 1]], axis=1).min()
    moved = mesh.points.copy()
    jitter = rng.uniform(-amount * h, amount * h, size=moved.shape)
    moved[~boundary] += jitter[~boundary]
    return Mesh(points=moved, cells=mesh.cells, cell_type="hexahedron",
                cell_material=mesh.cell_material)


def hex_gradient(u, cells, ops):
    """Mean deformation gradient F (n_elem, 3, 3) of the uniform-strain hexahedra."""
    return np.eye(3) + np.einsum("eia,eib->eab", u[cells], ops.bbar)


def hex_forces_numpy(u, cells, ops, material: Ogden, k_hg):
    """Internal nodal forces (n_nodes, 3) of elastic hexahedra, via ``numpy.linalg.eigh``."""
    F = hex_gradient(u, cells, ops)
    S = pk2_numpy(F, material)
    P = np.einsum("eik,ekj->eij", F, S) * ops.volume[:, None, None]
    fe = np.einsum("eab,eib->eia", P, ops.bbar)  # (n_elem, 8, 3)
    q = np.einsum("eki,eia->eka", ops.gamma, u[cells])  # (n_elem, 4, 3) hourglass modes
    fe += k_hg[:, None, None] * np.einsum("eki,eka->eia", ops.gamma, q)
    f = np.zeros_like(u)
    np.add.at(f, cells, fe)
    return f


def hex_energy_numpy(u, cells, ops, material: Ogden, k_hg):
    """(elastic energy, hourglass energy) of elastic hexahedra in J."""
    F = hex_gradient(u, cells, ops)
    C = np.einsum("eka,ekb->eab", F, F)
    lam = np.sqrt(np.linalg.eigvalsh(C))
    W = float(np.sum(ops.volume * material.strain_energy(lam)))
    q = np.einsum("eki,eia->eka", ops.gamma, u[cells])
    return W, float(0.5 * np.sum(k_hg[:, None, None] * q**2))


# ---------------------------------------------------------------------- volumetric mass
def volumetric_gradient_numpy(u, cells, ops: AxisymmetricOperators):
    """dJ/du (n_elem, 4, 2) of the mean Jacobian, by the cofactor J F^-T of the 3x3 F."""
    F = mean_gradient(u, cells, ops)
    cof = np.linalg.det(F)[:, None, None] * np.transpose(np.linalg.inv(F), (0, 2, 1))
    out = np.zeros((len(cells), 4, 2))
    out[:, :, 0] = (cof[:, 0, 0, None] * ops.bbar[:, :, 0] + cof[:, 0, 1, None] * ops.bbar[:, :, 1]
                    + cof[:, 2, 2, None] * ops.hbar)
    out[:, :, 1] = cof[:, 1, 0, None] * ops.bbar[:, :, 0] + cof[:, 1, 1, None] * ops.bbar[:, :, 1]
    return out


def volumetric_mass_dense(cells, mass, grad, coefficient):
    """M = diag(m) + sum_e a_e b_e b_e^T as a dense (n_dof, n_dof) array, DOFs (n, dim)."""
    n = len(mass)
    M = np.diag(np.repeat(mass, 2))
    dofs = (2 * cells[:, :, None] + np.arange(2)).reshape(len(cells), 8)
    b = grad.reshape(len(cells), 8)
    for e in range(len(cells)):
        M[np.ix_(dofs[e], dofs[e])] += coefficient[e] * np.outer(b[e], b[e])
    return M.reshape(2 * n, 2 * n)


def bulk_viscosity_dense(u, cells, ops: AxisymmetricOperators, coefficient):
    """C = sum_e c_e b_e b_e^T (b_e of the cofactor twin) as a dense (n_dof, n_dof) array."""
    n = len(u)
    C = np.zeros((2 * n, 2 * n))
    dofs = (2 * cells[:, :, None] + np.arange(2)).reshape(len(cells), 8)
    b = volumetric_gradient_numpy(u, cells, ops).reshape(len(cells), 8)
    for e in range(len(cells)):
        C[np.ix_(dofs[e], dofs[e])] += coefficient[e] * np.outer(b[e], b[e])
    return C
