r"""Element kernels of the Total Lagrangian explicit solver.

Axis order (all arrays float64 or int32, C-contiguous):

- nodal arrays ``(n_nodes, dim)``: displacement ``u``, force ``f``; ``dim`` = 2 (r, z) for the
  axisymmetric quad, 3 (x, y, z) for the hexahedron;
- element arrays ``(n_elem, n_en, dim)`` for gradient operators, ``(n_elem, n_en)`` for
  shape-function weights, ``(n_elem,)`` for scalars;
- material tables ``(n_mat, n_terms)`` indexed by the element's material index.

The axisymmetric element is the 4-node quad with one integration point in the sense of a
*mean deformation gradient*: the in-plane gradient operator and the hoop operator are the
volume (r-weighted) averages over the element,

.. math::

    \bar b_i = \frac{1}{V}\int_{V_e} \frac{\partial N_i}{\partial \mathbf X} \, dV, \qquad
    \bar h_i = \frac{1}{V}\int_{V_e} \frac{N_i}{R} \, dV, \qquad dV = 2\pi R \, dA,

evaluated once in the reference configuration (2x2 Gauss rule, exact for these integrands).
Then :math:`\bar F = I + \sum_i u_i \otimes \bar b_i`, :math:`\bar F_{\theta\theta} = 1 +
\sum_i \bar h_i u_{r,i}`, the internal energy of the element is :math:`V W(\bar F)` and the
nodal forces are its exact derivative. Because the averaged operators reproduce homogeneous
deformations exactly (also the hoop stretch) and integrate :math:`\partial (R N_i)/\partial R`
exactly, a homogeneous state gives zero interior forces on any mesh (the patch test), and a
single pressure per element avoids volumetric locking. The two hourglass modes per direction
are held by Flanagan-Belytschko stiffness in the reference configuration (Total Lagrangian,
Joldes et al. 2008), scaled by the shear modulus so that near-incompressible bulging is not
over-constrained.

The hexahedron is the same idea in 3D, Flanagan and Belytschko's uniform-strain element:
:math:`\bar b_i = V^{-1}\int \partial N_i/\partial\mathbf X\,dV` (exact with 2x2x2
Gauss points), :math:`\bar F = I + \sum_i u_i \otimes \bar b_i`, and four hourglass
vectors per direction, :math:`\gamma_\alpha = h_\alpha - (h_\alpha\cdot\mathbf X_a)
\bar b_a`, fixed in the reference configuration (Joldes et al. 2008), with the hourglass
energy :math:`\tfrac12 k \sum_\alpha |\gamma_\alpha \cdot u|^2` and the stiffness
:math:`k = \kappa\mu V \sum_i|\bar b_i|^2/3` (see :class:`HexOperators` for the 1/3). The
principal stretches come from :func:`spectral_sym3`, which needs no eigenvectors and stays
exact at repeated eigenvalues (the undeformed state, uniaxial states). The force kernel
exists twice: :func:`hex_forces` runs the elements and then the nodes on numba's threads
(every element writes its own forces, every node gathers its corners in a fixed order, so
there is no race and the result does not depend on the thread count), and
:func:`hex_forces_serial` scatters element by element.

References
----------
Miller K, Joldes G, Lance D, Wittek A (2007). Total Lagrangian explicit dynamics finite element
algorithm for computing soft tissue deformation. Commun Numer Methods Eng 23:121-134.
doi:10.1002/cnm.887

Flanagan DP, Belytschko T (1981). A uniform strain hexahedron and quadrilateral with orthogonal
hourglass control. Int J Numer Methods Eng 17:679-706. doi:10.1002/nme.1620170504

Joldes GR, Wittek A, Miller K (2008). An efficient hourglass control implementation for the
uniform strain hexahedron using the Total Lagrangian formulation. Commun Numer Methods Eng
24:1315-1323. doi:10.1002/cnm.1036
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ._jit import njit, njit_inline, njit_parallel
from .materials import ogden_energy, ogden_kirchhoff_logs, prony_relaxed

__all__ = [
    "AxisymmetricOperators",
    "axisymmetric_operators",
    "axisym_forces",
    "axisym_energy",
    "axisym_stiffening",
    "axisym_stress",
    "HexOperators",
    "hex_operators",
    "hex_forces",
    "hex_forces_serial",
    "hex_energy",
    "hex_stress",
    "hex_stiffening",
    "node_slots",
    "spectral_sym3",
]

#: Status codes returned by the force kernels.
OK, INVERTED, NOT_FINITE = 0, 1, 2

_XI = np.array([-1.0, 1.0, 1.0, -1.0])
_ETA = np.array([-1.0, -1.0, 1.0, 1.0])
_HOURGLASS = np.array([1.0, -1.0, 1.0, -1.0])


class AxisymmetricOperators:
    r"""Reference-configuration operators of the axisymmetric mean-gradient quad.

    Attributes
    ----------
    bbar : ndarray, shape (n_elem, 4, 2)
        Volume-averaged gradients :math:`\bar b_i` (1/m).
    hbar : ndarray, shape (n_elem, 4)
        Volume-averaged hoop operator :math:`\bar h_i` (1/m).
    volume : ndarray, shape (n_elem,)
        Element volume :math:`\int 2\pi R\,dA` (m^3).
    node_volume : ndarray, shape (n_elem, 4)
        :math:`\int N_i\,dV` (m^3), the lumped-mass share of each node.
    gamma : ndarray, shape (n_elem, 4)
        Flanagan-Belytschko hourglass vectors (dimensionless), orthogonal to linear fields.
    gamma_scale : ndarray, shape (n_elem,)
        :math:`V \sum_i |\bar b_i|^2` (m); the hourglass stiffness is
        :math:`\kappa \mu` times this.
    """

    def __init__(self, bbar, hbar, volume, node_volume, gamma, gamma_scale):
        self.bbar = bbar
        self.hbar = hbar
        self.volume = volume
        self.node_volume = node_volume
        self.gamma = gamma
        self.gamma_scale = gamma_scale


def axisymmetric_operators(points: np.ndarray, cells: np.ndarray) -> AxisymmetricOperators:
    """Precompute the mean-gradient operators of every quad (vectorised NumPy, done once).

    Parameters
    ----------
    points : ndarray, shape (n_nodes, 2)
        Reference coordinates (r, z) (m).
    cells : ndarray, shape (n_elem, 4)
        Counter-clockwise connectivity.

    Raises
    ------
    ValueError
        If an element has a non-positive Jacobian at a Gauss point (wrong orientation or a
        degenerate element), naming the element.
    """
    X = points[cells]  # (n_elem, 4, 2)
    g = 1.0 / math.sqrt(3.0)
    n_elem = len(cells)
    bsum = np.zeros((n_elem, 4, 2))
    hsum = np.zeros((n_elem, 4))
    vol = np.zeros(n_elem)
    nvol = np.zeros((n_elem, 4))
    for xi, eta in ((-g, -g), (g, -g), (g, g), (-g, g)):
        N = 0.25 * (1 + _XI * xi) * (1 + _ETA * eta)  # (4,)
        dN = np.stack([0.25 * _XI * (1 + _ETA * eta), 0.25 * _ETA * (1 + _XI * xi)], axis=1)
        Jac = np.einsum("ia,eib->eab", dN, X)  # dX_b/dxi_a, (n_elem, 2, 2)
        det = Jac[:, 0, 0] * Jac[:, 1, 1] - Jac[:, 0, 1] * Jac[:, 1, 0]
        if np.any(det <= 0.0):
            bad = int(np.flatnonzero(det <= 0.0)[0])
            raise ValueError(f"element {bad} has a non-positive Jacobian: nodes must be "
                             "counter-clockwise in (r, z) and the element not degenerate")
        inv = np.empty_like(Jac)
        inv[:, 0, 0] = Jac[:, 1, 1] / det
        inv[:, 1, 1] = Jac[:, 0, 0] / det
        inv[:, 0, 1] = -Jac[:, 0, 1] / det
        inv[:, 1, 0] = -Jac[:, 1, 0] / det
        dNdX = np.einsum("ia,eba->eib", dN, inv)  # dN/dX_b = sum_a inv[b, a] dN/dxi_a
        r = X[:, :, 0] @ N  # (n_elem,)
        w = 2.0 * np.pi * r * det
        vol += w
        bsum += w[:, None, None] * dNdX
        hsum += (2.0 * np.pi * det)[:, None] * N[None, :]
        nvol += w[:, None] * N[None, :]
    bbar = bsum / vol[:, None, None]
    hbar = hsum / vol[:, None]
    hx = np.einsum("i,eia->ea", _HOURGLASS, X)  # (n_elem, 2)
    gamma = _HOURGLASS[None, :] - np.einsum("ea,eia->ei", hx, bbar)
    gamma_scale = vol * np.einsum("eia,eia->e", bbar, bbar)
    return AxisymmetricOperators(
        bbar=np.ascontiguousarray(bbar),
        hbar=np.ascontiguousarray(hbar),
        volume=np.ascontiguousarray(vol),
        node_volume=np.ascontiguousarray(nvol),
        gamma=np.ascontiguousarray(gamma),
        gamma_scale=np.ascontiguousarray(gamma_scale),
    )


@njit_inline
def _inplane_pk2(C11, C22, C12, c1, c2, S1, S2):
    """In-plane second Piola-Kirchhoff tensor from its principal values.

    ``S = S2 I + (S1 - S2) (C - c2 I) / (c1 - c2)`` uses the projector onto the first
    eigenvector without computing it. At repeated in-plane stretches (c1 == c2, e.g. the
    undeformed state) the projector is undefined but its coefficient S1 - S2 vanishes with
    c1 - c2; below a relative gap of 1e-10 the isotropic mean is exact to that order.
    """
    gap = c1 - c2
    if gap > 1e-10 * (c1 + c2):
        k = (S1 - S2) / gap
        return S2 + k * (C11 - c2), S2 + k * (C22 - c2), k * C12
    mean = 0.5 * (S1 + S2)
    return mean, mean, 0.0


@njit_inline
def _axisym_state(u, conn, bbar, hbar, e):
    """Mean deformation gradient of element ``e``: (Frr, Frz, Fzr, Fzz, Ftt)."""
    Frr = 1.0
    Frz = 0.0
    Fzr = 0.0
    Fzz = 1.0
    Ftt = 1.0
    for a in range(4):
        n = conn[e, a]
        ur = u[n, 0]
        uz = u[n, 1]
        br = bbar[e, a, 0]
        bz = bbar[e, a, 1]
        Frr += ur * br
        Frz += ur * bz
        Fzr += uz * br
        Fzz += uz * bz
        Ftt += ur * hbar[e, a]
    return Frr, Frz, Fzr, Fzz, Ftt


@njit_inline
def _axisym_pk2(Frr, Frz, Fzr, Fzz, Ftt, m, mu, alpha, K, g, decay, gain, s_prev, hist, e,
                update_history):
    """Second Piola-Kirchhoff stress (S_rr, S_zz, S_rz, S_tt) of one quad.

    J > 0 is checked by the caller; the isochoric part is relaxed by the Prony recursion
    (history in ``hist[e]``).
    """
    det2 = Frr * Fzz - Frz * Fzr
    C11 = Frr * Frr + Fzr * Fzr
    C22 = Frz * Frz + Fzz * Fzz
    C12 = Frr * Frz + Fzr * Fzz
    mean = 0.5 * (C11 + C22)
    half = math.sqrt(0.25 * (C11 - C22) ** 2 + C12 * C12)
    c1 = mean + half
    c2 = det2 * det2 / c1  # = mean - half without cancellation
    t1, t2, t3, tvol = ogden_kirchhoff_logs(0.5 * math.log(c1), 0.5 * math.log(c2),
                                            math.log(Ftt), det2 * Ftt, mu[m], alpha[m], K[m])
    # instantaneous isochoric PK2 in tensor components
    s11, s22, s12 = _inplane_pk2(C11, C22, C12, c1, c2, t1 / c1, t2 / c2)
    stt = t3 / (Ftt * Ftt)
    if g.shape[1] > 0:
        r11 = prony_relaxed(s11, s_prev[e, 0], hist[e, 0], g[m], decay[m], gain[m],
                            update_history)
        r22 = prony_relaxed(s22, s_prev[e, 1], hist[e, 1], g[m], decay[m], gain[m],
                            update_history)
        r12 = prony_relaxed(s12, s_prev[e, 2], hist[e, 2], g[m], decay[m], gain[m],
                            update_history)
        rtt = prony_relaxed(stt, s_prev[e, 3], hist[e, 3], g[m], decay[m], gain[m],
                            update_history)
        if update_history:
            s_prev[e, 0] = s11
            s_prev[e, 1] = s22
            s_prev[e, 2] = s12
            s_prev[e, 3] = stt
        s11, s22, s12, stt = r11, r22, r12, rtt
    # volumetric PK2: tvol C^-1
    det_c = C11 * C22 - C12 * C12
    S11 = s11 + tvol * C22 / det_c
    S22 = s22 + tvol * C11 / det_c
    S12 = s12 - tvol * C12 / det_c
    Stt = stt + tvol / (Ftt * Ftt)
    return S11, S22, S12, Stt


@njit
def axisym_forces(
    u,  # (n_nodes, 2) displacement (m)
    conn,  # (n_elem, 4) int32
    bbar,  # (n_elem, 4, 2)
    hbar,  # (n_elem, 4)
    vol,  # (n_elem,)
    gamma,  # (n_elem, 4)
    k_hg,  # (n_elem,) hourglass stiffness (N/m)
    mat,  # (n_elem,) int32 material index
    mu,  # (n_mat, n_terms) instantaneous moduli (Pa)
    alpha,  # (n_mat, n_terms)
    K,  # (n_mat,) bulk modulus (Pa)
    g,  # (n_mat, n_prony) Prony relative moduli
    decay,  # (n_mat, n_prony) exp(-dt / tau_k)
    gain,  # (n_mat, n_prony) (1 - decay) / (dt / tau_k)
    s_prev,  # (n_elem, 4) instantaneous isochoric PK2 (rr, zz, rz, tt) at the last update
    hist,  # (n_elem, 4, n_prony) Prony history variables (Pa)
    update_history,  # bool: advance the Prony recursion (once per time step)
    f,  # (n_nodes, 2) output: internal nodal forces (N), overwritten
):
    """Internal nodal forces of the axisymmetric mean-gradient quads.

    Returns
    -------
    status : int
        ``OK``, ``INVERTED`` (J <= 0 or hoop stretch <= 0) or ``NOT_FINITE``.
    element : int
        The first offending element, -1 if none.
    """
    n_elem = conn.shape[0]
    f[:] = 0.0
    for e in range(n_elem):
        Frr, Frz, Fzr, Fzz, Ftt = _axisym_state(u, conn, bbar, hbar, e)
        det2 = Frr * Fzz - Frz * Fzr
        if not (det2 > 0.0 and Ftt > 0.0):
            if det2 <= 0.0 or Ftt <= 0.0:
                return INVERTED, e
            return NOT_FINITE, e
        S11, S22, S12, Stt = _axisym_pk2(Frr, Frz, Fzr, Fzz, Ftt, mat[e], mu, alpha, K, g,
                                         decay, gain, s_prev, hist, e, update_history)
        # first Piola-Kirchhoff P = F S, times the volume
        v = vol[e]
        Prr = v * (Frr * S11 + Frz * S12)
        Prz = v * (Frr * S12 + Frz * S22)
        Pzr = v * (Fzr * S11 + Fzz * S12)
        Pzz = v * (Fzr * S12 + Fzz * S22)
        Ptt = v * Ftt * Stt
        if not math.isfinite(Prr + Prz + Pzr + Pzz + Ptt):
            return NOT_FINITE, e
        # hourglass: f = k gamma (gamma . u), per direction
        qr = 0.0
        qz = 0.0
        for a in range(4):
            n = conn[e, a]
            qr += gamma[e, a] * u[n, 0]
            qz += gamma[e, a] * u[n, 1]
        qr *= k_hg[e]
        qz *= k_hg[e]
        for a in range(4):
            n = conn[e, a]
            br = bbar[e, a, 0]
            bz = bbar[e, a, 1]
            f[n, 0] += Prr * br + Prz * bz + Ptt * hbar[e, a] + qr * gamma[e, a]
            f[n, 1] += Pzr * br + Pzz * bz + qz * gamma[e, a]
    return OK, -1


@njit
def axisym_energy(
    u,  # (n_nodes, 2)
    conn,  # (n_elem, 4) int32
    bbar,  # (n_elem, 4, 2)
    hbar,  # (n_elem, 4)
    vol,  # (n_elem,)
    gamma,  # (n_elem, 4)
    k_hg,  # (n_elem,)
    mat,  # (n_elem,) int32
    mu,  # (n_mat, n_terms) long-term moduli (Pa)
    alpha,  # (n_mat, n_terms)
    K,  # (n_mat,)
):
    """Stored elastic energy (J) and hourglass energy (J) of the mesh.

    For a viscoelastic material pass the long-term moduli: the result is then the energy the
    sample would store once relaxed, a lower bound of the internal work.
    """
    W = 0.0
    Whg = 0.0
    for e in range(conn.shape[0]):
        m = mat[e]
        Frr, Frz, Fzr, Fzz, Ftt = _axisym_state(u, conn, bbar, hbar, e)
        det2 = Frr * Fzz - Frz * Fzr
        C11 = Frr * Frr + Fzr * Fzr
        C22 = Frz * Frz + Fzz * Fzz
        C12 = Frr * Frz + Fzr * Fzz
        mean = 0.5 * (C11 + C22)
        half = math.sqrt(0.25 * (C11 - C22) ** 2 + C12 * C12)
        c1 = mean + half
        c2 = det2 * det2 / c1
        W += vol[e] * ogden_energy(math.sqrt(c1), math.sqrt(c2), Ftt, mu[m], alpha[m], K[m])
        qr = 0.0
        qz = 0.0
        for a in range(4):
            n = conn[e, a]
            qr += gamma[e, a] * u[n, 0]
            qz += gamma[e, a] * u[n, 1]
        Whg += 0.5 * k_hg[e] * (qr * qr + qz * qz)
    return W, Whg


@njit
def axisym_stress(u, conn, bbar, hbar, mat, mu, alpha, K, g, decay, gain, s_prev, hist, out):
    """Cauchy stress of every quad (Pa) at the state ``u``, Prony history as it is.

    ``out`` (n_elem, 6) receives (rr, tt, zz, r-t, t-z, rz) = (xx, yy, zz, xy, yz, xz) of the
    section in the x-z plane (hoop = y), the order VTK readers take for a symmetric tensor.
    Inverted elements get NaN.
    """
    for e in range(conn.shape[0]):
        Frr, Frz, Fzr, Fzz, Ftt = _axisym_state(u, conn, bbar, hbar, e)
        det2 = Frr * Fzz - Frz * Fzr
        if not (det2 > 0.0 and Ftt > 0.0):
            out[e, :] = np.nan
            continue
        S11, S22, S12, Stt = _axisym_pk2(Frr, Frz, Fzr, Fzz, Ftt, mat[e], mu, alpha, K, g,
                                         decay, gain, s_prev, hist, e, False)
        J = det2 * Ftt
        # sigma = F S F^T / J in the r-z plane, hoop separately
        Arr = Frr * S11 + Frz * S12
        Arz = Frr * S12 + Frz * S22
        Azr = Fzr * S11 + Fzz * S12
        Azz = Fzr * S12 + Fzz * S22
        out[e, 0] = (Arr * Frr + Arz * Frz) / J
        out[e, 1] = Ftt * Ftt * Stt / J
        out[e, 2] = (Azr * Fzr + Azz * Fzz) / J
        out[e, 3] = 0.0
        out[e, 4] = 0.0
        out[e, 5] = (Arr * Fzr + Arz * Fzz) / J


@njit
def axisym_stiffening(
    u,  # (n_nodes, 2)
    conn,  # (n_elem, 4) int32
    bbar,  # (n_elem, 4, 2)
    hbar,  # (n_elem, 4)
    mat,  # (n_elem,) int32
    alpha,  # (n_mat, n_terms)
    share,  # (n_mat, n_terms) mu_i / sum(mu) of each material
    k_ratio,  # (n_mat,) K / sum(mu) of each material
    out,  # (n_elem,) output: omega^2(current) / omega^2(reference) bound per element
):
    r"""Bound on how much each element's highest frequency has grown since the start.

    The element frequency scales with the current gradient operator (the element shrinks as
    it is compressed) and with the tangent p-wave modulus. The gradient operator in the
    current configuration is :math:`\bar b F^{-1}`; the tangent shear modulus of the Ogden
    law along a principal direction is bounded by :math:`\sum_i \mu_i \max_a
    \bar\lambda_a^{\alpha_i}` (its value at the stretches reached).
    """
    for e in range(conn.shape[0]):
        m = mat[e]
        Frr, Frz, Fzr, Fzz, Ftt = _axisym_state(u, conn, bbar, hbar, e)
        det2 = Frr * Fzz - Frz * Fzr
        if det2 <= 0.0 or Ftt <= 0.0:
            out[e] = np.inf
            continue
        # inverse of the in-plane F
        i11 = Fzz / det2
        i12 = -Frz / det2
        i21 = -Fzr / det2
        i22 = Frr / det2
        ref = 0.0
        cur = 0.0
        for a in range(4):
            br = bbar[e, a, 0]
            bz = bbar[e, a, 1]
            h = hbar[e, a]
            ref += br * br + bz * bz + h * h
            xr = br * i11 + bz * i21
            xz = br * i12 + bz * i22
            ht = h / Ftt
            cur += xr * xr + xz * xz + ht * ht
        C11 = Frr * Frr + Fzr * Fzr
        C22 = Frz * Frz + Fzz * Fzz
        C12 = Frr * Frz + Fzr * Fzz
        mean = 0.5 * (C11 + C22)
        half = math.sqrt(0.25 * (C11 - C22) ** 2 + C12 * C12)
        c1 = mean + half
        c2 = det2 * det2 / c1
        J = det2 * Ftt
        third = math.log(J) / 3.0
        l1 = 0.5 * math.log(c1) - third
        l2 = 0.5 * math.log(c2) - third
        l3 = math.log(Ftt) - third
        mu_t = 0.0
        for i in range(alpha.shape[1]):
            a = alpha[m, i]
            big = max(math.exp(a * l1), math.exp(a * l2), math.exp(a * l3))
            mu_t += share[m, i] * max(big, 1.0)
        modulus = (k_ratio[m] * J + 4.0 / 3.0 * mu_t) / (k_ratio[m] + 4.0 / 3.0)
        out[e] = cur / ref * max(modulus, 1.0)


# ====================================================================== hexahedron
#: Reference coordinates of the 8 nodes (VTK order: bottom face 0-3 counter-clockwise seen
#: from +zeta, then the top face 4-7 above it).
_HEX_XI = np.array([-1.0, 1.0, 1.0, -1.0, -1.0, 1.0, 1.0, -1.0])
_HEX_ETA = np.array([-1.0, -1.0, 1.0, 1.0, -1.0, -1.0, 1.0, 1.0])
_HEX_ZETA = np.array([-1.0, -1.0, -1.0, -1.0, 1.0, 1.0, 1.0, 1.0])
#: Flanagan-Belytschko hourglass base vectors: nodal values of xi*eta, eta*zeta, zeta*xi and
#: xi*eta*zeta, shape (4, 8).
_HEX_HOURGLASS = np.array([_HEX_XI * _HEX_ETA, _HEX_ETA * _HEX_ZETA, _HEX_ZETA * _HEX_XI,
                           _HEX_XI * _HEX_ETA * _HEX_ZETA])


class HexOperators:
    r"""Reference-configuration operators of the uniform-strain (mean-gradient) hexahedron.

    Attributes
    ----------
    bbar : ndarray, shape (n_elem, 8, 3)
        Volume-averaged gradients :math:`\bar b_i = V^{-1}\int \partial N_i/\partial
        \mathbf X\,dV` (1/m).
    volume : ndarray, shape (n_elem,)
        Element volume (m^3).
    node_volume : ndarray, shape (n_elem, 8)
        :math:`\int N_i\,dV` (m^3), the lumped-mass share of each node.
    gamma : ndarray, shape (n_elem, 4, 8)
        Flanagan-Belytschko hourglass vectors :math:`\gamma_\alpha = h_\alpha -
        (h_\alpha \cdot \mathbf X_a)\,\bar b_{a}` (dimensionless), orthogonal to every
        linear field; fixed in the reference configuration (Total Lagrangian).
    gamma_scale : ndarray, shape (n_elem,)
        :math:`V \sum_i |\bar b_i|^2 / 3` (m); the hourglass stiffness is
        :math:`\kappa \mu` times this. The factor 1/3 keeps the quad's meaning of
        :math:`\kappa` as a fraction of the fully integrated element's (deviatoric)
        stiffness in the same mode: the ratio is 10.3 :math:`\kappa` for the quad's mode
        on a square and for a cube's bilinear modes that stretch along the displacement
        (e.g. :math:`u_x \propto \xi\eta`), 12 :math:`\kappa` for its pure-shear bilinear
        modes (:math:`u_x \propto \eta\zeta`) and 21.6 :math:`\kappa` for the trilinear
        one (a test pins these numbers). Without it the same :math:`\kappa` would hold the
        hexahedron's modes 3 to 6 times harder than the quad's, which added
        +1 % to the bonded force of the 5760-element cylinder.
    """

    def __init__(self, bbar, volume, node_volume, gamma, gamma_scale):
        self.bbar = bbar
        self.volume = volume
        self.node_volume = node_volume
        self.gamma = gamma
        self.gamma_scale = gamma_scale


def hex_operators(points: np.ndarray, cells: np.ndarray) -> HexOperators:
    r"""Precompute the mean-gradient operators of every hexahedron (vectorised NumPy, once).

    The integrals are evaluated with the 2x2x2 Gauss rule, which is exact for them: the
    integrand :math:`\partial N_i/\partial\mathbf X \det J` (the cofactors of the
    Jacobian times the shape-function derivatives) and :math:`N_i \det J` are polynomials of
    degree at most 3 in each reference coordinate.

    Parameters
    ----------
    points : ndarray, shape (n_nodes, 3)
        Reference coordinates (x, y, z) (m).
    cells : ndarray, shape (n_elem, 8)
        Connectivity in VTK hexahedron order.

    Raises
    ------
    ValueError
        If an element has a non-positive Jacobian at a Gauss point (wrong node order or a
        degenerate element), naming the element.
    """
    X = points[cells]  # (n_elem, 8, 3)
    g = 1.0 / math.sqrt(3.0)
    n_elem = len(cells)
    bsum = np.zeros((n_elem, 8, 3))
    vol = np.zeros(n_elem)
    nvol = np.zeros((n_elem, 8))
    for xi in (-g, g):
        for eta in (-g, g):
            for zeta in (-g, g):
                sx = 1.0 + _HEX_XI * xi
                se = 1.0 + _HEX_ETA * eta
                sz = 1.0 + _HEX_ZETA * zeta
                N = 0.125 * sx * se * sz  # (8,)
                dN = 0.125 * np.stack([_HEX_XI * se * sz, _HEX_ETA * sx * sz,
                                       _HEX_ZETA * sx * se], axis=1)  # (8, 3) dN/dxi_a
                Jac = np.einsum("ia,eib->eab", dN, X)  # dX_b/dxi_a, (n_elem, 3, 3)
                det = np.linalg.det(Jac)
                if np.any(det <= 0.0):
                    bad = int(np.flatnonzero(det <= 0.0)[0])
                    raise ValueError(
                        f"hexahedron {bad} has a non-positive Jacobian: nodes must follow the "
                        "VTK order (bottom face counter-clockwise seen from the top face) and "
                        "the element must not be degenerate")
                inv = np.linalg.inv(Jac)
                dNdX = np.einsum("ia,eba->eib", dN, inv)  # dN/dX_b = sum_a inv[b, a] dN/dxi_a
                vol += det
                bsum += det[:, None, None] * dNdX
                nvol += det[:, None] * N[None, :]
    bbar = bsum / vol[:, None, None]
    hx = np.einsum("ki,eia->eka", _HEX_HOURGLASS, X)  # (n_elem, 4, 3)
    gamma = _HEX_HOURGLASS[None, :, :] - np.einsum("eka,eia->eki", hx, bbar)
    gamma_scale = vol * np.einsum("eia,eia->e", bbar, bbar) / 3.0
    return HexOperators(
        bbar=np.ascontiguousarray(bbar),
        volume=np.ascontiguousarray(vol),
        node_volume=np.ascontiguousarray(nvol),
        gamma=np.ascontiguousarray(gamma),
        gamma_scale=np.ascontiguousarray(gamma_scale),
    )


def node_slots(cells: np.ndarray, n_nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Node-to-element incidence in compressed rows, for the race-free parallel gather.

    Returns
    -------
    ptr : ndarray of int64, shape (n_nodes + 1,)
    slot : ndarray of int64, shape (n_elem * n_en,)
        ``slot[ptr[n]:ptr[n + 1]]`` are the flat indices ``e * n_en + a`` of the element
        corners at node ``n``, in increasing order (a fixed summation order).
    """
    flat = cells.ravel().astype(np.int64)
    order = np.argsort(flat, kind="stable")
    counts = np.bincount(flat, minlength=n_nodes)
    ptr = np.zeros(n_nodes + 1, dtype=np.int64)
    np.cumsum(counts, out=ptr[1:])
    return np.ascontiguousarray(ptr), np.ascontiguousarray(order.astype(np.int64))


@njit_inline
def spectral_sym3(C00, C11, C22, C01, C02, C12):
    r"""Eigenvalues and spectral projectors of a symmetric 3x3 matrix, robust when repeated.

    Writes :math:`C = q I + p \hat B` (:math:`q` the mean eigenvalue, :math:`\hat B` the
    normalised deviator with :math:`\operatorname{tr} \hat B^2 = 6`). The eigenvalue of
    :math:`\hat B` farthest from the other two, :math:`\beta`, comes from the trigonometric
    solution of the characteristic cubic, :math:`r = \det \hat B / 2 = \cos 3\phi`; it is
    well conditioned (its distance to the others is at least :math:`\sqrt 3`). Its projector
    follows without eigenvectors from the other two eigenvalues' sum :math:`-\beta` and
    product :math:`\pi = 2r/\beta`,

    .. math::

        P_1 = \frac{\hat B^2 + \beta \hat B + \pi I}{2\beta^2 + \pi},

    and the remaining pair is described by its deviator within the complement,
    :math:`\hat D = \hat B + \tfrac{\beta}{2}(I - 3P_1) = \tfrac{\hat\delta}{2}(P_2 - P_3)`,
    whose norm gives the pair's gap :math:`\hat\delta = \sqrt{2\,\hat D:\hat D}` to the
    absolute accuracy of the entries (no square root of a difference of squares). An
    isotropic function with principal values :math:`s_a` is then

    .. math::

        S = s_1 P_1 + \tfrac{s_2 + s_3}{2}(I - P_1) + \frac{s_2 - s_3}{\hat\delta}\hat D.

    Guards (each at an exactly repeated state, tested):

    - all three eigenvalues equal (:math:`\hat B` undefined, e.g. the undeformed state):
      ``p2 == 0`` returns ``P1 = D = 0``, ``delta = 0``, so :math:`S = s I`;
    - a repeated pair (uniaxial states, :math:`r = \pm 1`): rounding may push
      :math:`|r|` past 1 and :func:`math.acos` would return NaN, so ``r`` is clipped; then
      :math:`\hat D = 0` to rounding and the caller drops the last term (see
      :func:`_hex_pk2`).

    Returns
    -------
    c1, c2, c3 : float
        Eigenvalues: the isolated one, then the pair (c2 >= c3).
    P00, P11, P22, P01, P02, P12 : float
        Projector :math:`P_1` onto the isolated eigenvalue's eigenvector.
    D00, D11, D22, D01, D02, D12 : float
        :math:`\hat D` (dimensionless, scaled by ``1/p``).
    delta : float
        :math:`\hat\delta` (the pair's gap over ``p``).
    scale : float
        ``p``, so that ``c2 - c3 = p * delta``.
    """
    q = (C00 + C11 + C22) / 3.0
    B00 = C00 - q
    B11 = C11 - q
    B22 = C22 - q
    p2 = (B00 * B00 + B11 * B11 + B22 * B22 + 2.0 * (C01 * C01 + C02 * C02 + C12 * C12)) / 6.0
    if p2 == 0.0:
        # guard: C = q I exactly; every direction is principal and S = s I
        return (q, q, q, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    p = math.sqrt(p2)
    b00 = B00 / p
    b11 = B11 / p
    b22 = B22 / p
    b01 = C01 / p
    b02 = C02 / p
    b12 = C12 / p
    r = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02)
               + b02 * (b01 * b12 - b11 * b02))
    # guard: |r| <= 1 in exact arithmetic, and |r| = 1 exactly at a repeated pair; rounding
    # can exceed it, where acos is undefined
    r = min(1.0, max(-1.0, r))
    phi = math.acos(r) / 3.0
    if r >= 0.0:  # the largest eigenvalue is the isolated one (pair below it)
        beta = 2.0 * math.cos(phi)
    else:  # the smallest is
        beta = 2.0 * math.cos(phi + 2.0 * math.pi / 3.0)
    pair_product = 2.0 * r / beta
    den = 2.0 * beta * beta + pair_product
    s00 = b00 * b00 + b01 * b01 + b02 * b02
    s11 = b01 * b01 + b11 * b11 + b12 * b12
    s22 = b02 * b02 + b12 * b12 + b22 * b22
    s01 = b00 * b01 + b01 * b11 + b02 * b12
    s02 = b00 * b02 + b01 * b12 + b02 * b22
    s12 = b01 * b02 + b11 * b12 + b12 * b22
    P00 = (s00 + beta * b00 + pair_product) / den
    P11 = (s11 + beta * b11 + pair_product) / den
    P22 = (s22 + beta * b22 + pair_product) / den
    P01 = (s01 + beta * b01) / den
    P02 = (s02 + beta * b02) / den
    P12 = (s12 + beta * b12) / den
    h = 0.5 * beta
    D00 = b00 + h * (1.0 - 3.0 * P00)
    D11 = b11 + h * (1.0 - 3.0 * P11)
    D22 = b22 + h * (1.0 - 3.0 * P22)
    D01 = b01 - 3.0 * h * P01
    D02 = b02 - 3.0 * h * P02
    D12 = b12 - 3.0 * h * P12
    delta = math.sqrt(2.0 * (D00 * D00 + D11 * D11 + D22 * D22
                             + 2.0 * (D01 * D01 + D02 * D02 + D12 * D12)))
    c1 = q + p * beta
    pair_mean = q - 0.5 * p * beta
    c2 = pair_mean + 0.5 * p * delta
    c3 = pair_mean - 0.5 * p * delta
    return (c1, c2, c3, P00, P11, P22, P01, P02, P12, D00, D11, D22, D01, D02, D12, delta, p)


#: Relative gap of the repeated pair below which its deviatoric term is dropped: the term is
#: :math:`|s_2 - s_3|/2 \approx \alpha\mu\,(c_2 - c_3)/(2c)`, below rounding there.
PAIR_GAP = 1e-13


@njit_inline
def _hex_state(u, conn, bbar, e):
    """Mean deformation gradient of hexahedron ``e``, row-major F00..F22."""
    F00 = 1.0
    F01 = 0.0
    F02 = 0.0
    F10 = 0.0
    F11 = 1.0
    F12 = 0.0
    F20 = 0.0
    F21 = 0.0
    F22 = 1.0
    for a in range(8):
        n = conn[e, a]
        ux = u[n, 0]
        uy = u[n, 1]
        uz = u[n, 2]
        bx = bbar[e, a, 0]
        by = bbar[e, a, 1]
        bz = bbar[e, a, 2]
        F00 += ux * bx
        F01 += ux * by
        F02 += ux * bz
        F10 += uy * bx
        F11 += uy * by
        F12 += uy * bz
        F20 += uz * bx
        F21 += uz * by
        F22 += uz * bz
    return F00, F01, F02, F10, F11, F12, F20, F21, F22


@njit_inline
def _hex_pk2(F00, F01, F02, F10, F11, F12, F20, F21, F22, m, mu, alpha, K, g, decay, gain,
             s_prev, hist, e, update_history):
    """Second Piola-Kirchhoff stress (S00, S11, S22, S01, S02, S12) and J of one element.

    The isochoric part is relaxed by the Prony recursion component by component (six PK2
    components per element, history in ``hist[e]``). Returns J <= 0 untouched for the caller
    to report.
    """
    J = (F00 * (F11 * F22 - F12 * F21) - F01 * (F10 * F22 - F12 * F20)
         + F02 * (F10 * F21 - F11 * F20))
    if not J > 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, J
    C00 = F00 * F00 + F10 * F10 + F20 * F20
    C11 = F01 * F01 + F11 * F11 + F21 * F21
    C22 = F02 * F02 + F12 * F12 + F22 * F22
    C01 = F00 * F01 + F10 * F11 + F20 * F21
    C02 = F00 * F02 + F10 * F12 + F20 * F22
    C12 = F01 * F02 + F11 * F12 + F21 * F22
    (c1, c2, c3, P00, P11, P22, P01, P02, P12,
     D00, D11, D22, D01, D02, D12, delta, scale) = spectral_sym3(C00, C11, C22, C01, C02, C12)
    t1, t2, t3, tvol = ogden_kirchhoff_logs(0.5 * math.log(c1), 0.5 * math.log(c2),
                                            0.5 * math.log(c3), J, mu[m], alpha[m], K[m])
    s1 = t1 / c1
    s2 = t2 / c2
    s3 = t3 / c3
    mean = 0.5 * (s2 + s3)
    k = 0.0
    # guard: a repeated pair (exactly, or within PAIR_GAP) has no deviatoric pair term
    if scale * delta > PAIR_GAP * (c2 + c3):
        k = (s2 - s3) / delta
    d1 = s1 - mean
    i00 = mean + d1 * P00 + k * D00
    i11 = mean + d1 * P11 + k * D11
    i22 = mean + d1 * P22 + k * D22
    i01 = d1 * P01 + k * D01
    i02 = d1 * P02 + k * D02
    i12 = d1 * P12 + k * D12
    if g.shape[1] > 0:
        r00 = prony_relaxed(i00, s_prev[e, 0], hist[e, 0], g[m], decay[m], gain[m],
                            update_history)
        r11 = prony_relaxed(i11, s_prev[e, 1], hist[e, 1], g[m], decay[m], gain[m],
                            update_history)
        r22 = prony_relaxed(i22, s_prev[e, 2], hist[e, 2], g[m], decay[m], gain[m],
                            update_history)
        r01 = prony_relaxed(i01, s_prev[e, 3], hist[e, 3], g[m], decay[m], gain[m],
                            update_history)
        r02 = prony_relaxed(i02, s_prev[e, 4], hist[e, 4], g[m], decay[m], gain[m],
                            update_history)
        r12 = prony_relaxed(i12, s_prev[e, 5], hist[e, 5], g[m], decay[m], gain[m],
                            update_history)
        if update_history:
            s_prev[e, 0] = i00
            s_prev[e, 1] = i11
            s_prev[e, 2] = i22
            s_prev[e, 3] = i01
            s_prev[e, 4] = i02
            s_prev[e, 5] = i12
        i00, i11, i22, i01, i02, i12 = r00, r11, r22, r01, r02, r12
    # volumetric PK2: tvol C^-1, with det C = J^2
    w = tvol / (J * J)
    S00 = i00 + w * (C11 * C22 - C12 * C12)
    S11 = i11 + w * (C00 * C22 - C02 * C02)
    S22 = i22 + w * (C00 * C11 - C01 * C01)
    S01 = i01 + w * (C02 * C12 - C01 * C22)
    S02 = i02 + w * (C01 * C12 - C02 * C11)
    S12 = i12 + w * (C01 * C02 - C00 * C12)
    return S00, S11, S22, S01, S02, S12, J


@njit_inline
def _hex_element(e, u, conn, bbar, vol, gamma, k_hg, mat, mu, alpha, K, g, decay, gain,
                 s_prev, hist, update_history, fe):
    """Internal forces of hexahedron ``e`` into ``fe`` (8, 3); returns the status code."""
    F00, F01, F02, F10, F11, F12, F20, F21, F22 = _hex_state(u, conn, bbar, e)
    S00, S11, S22, S01, S02, S12, J = _hex_pk2(F00, F01, F02, F10, F11, F12, F20, F21, F22,
                                               mat[e], mu, alpha, K, g, decay, gain, s_prev,
                                               hist, e, update_history)
    if not J > 0.0:
        if J <= 0.0:
            return INVERTED
        return NOT_FINITE
    v = vol[e]
    # first Piola-Kirchhoff P = F S, times the volume
    P00 = v * (F00 * S00 + F01 * S01 + F02 * S02)
    P01 = v * (F00 * S01 + F01 * S11 + F02 * S12)
    P02 = v * (F00 * S02 + F01 * S12 + F02 * S22)
    P10 = v * (F10 * S00 + F11 * S01 + F12 * S02)
    P11 = v * (F10 * S01 + F11 * S11 + F12 * S12)
    P12 = v * (F10 * S02 + F11 * S12 + F12 * S22)
    P20 = v * (F20 * S00 + F21 * S01 + F22 * S02)
    P21 = v * (F20 * S01 + F21 * S11 + F22 * S12)
    P22 = v * (F20 * S02 + F21 * S12 + F22 * S22)
    if not math.isfinite(P00 + P01 + P02 + P10 + P11 + P12 + P20 + P21 + P22):
        return NOT_FINITE
    # hourglass: f_i = k sum_alpha gamma_alpha,i (gamma_alpha . u), per direction
    kh = k_hg[e]
    q00 = 0.0
    q01 = 0.0
    q02 = 0.0
    q10 = 0.0
    q11 = 0.0
    q12 = 0.0
    q20 = 0.0
    q21 = 0.0
    q22 = 0.0
    q30 = 0.0
    q31 = 0.0
    q32 = 0.0
    for a in range(8):
        n = conn[e, a]
        ux = u[n, 0]
        uy = u[n, 1]
        uz = u[n, 2]
        g0 = gamma[e, 0, a]
        g1 = gamma[e, 1, a]
        g2 = gamma[e, 2, a]
        g3 = gamma[e, 3, a]
        q00 += g0 * ux
        q01 += g0 * uy
        q02 += g0 * uz
        q10 += g1 * ux
        q11 += g1 * uy
        q12 += g1 * uz
        q20 += g2 * ux
        q21 += g2 * uy
        q22 += g2 * uz
        q30 += g3 * ux
        q31 += g3 * uy
        q32 += g3 * uz
    for a in range(8):
        bx = bbar[e, a, 0]
        by = bbar[e, a, 1]
        bz = bbar[e, a, 2]
        g0 = kh * gamma[e, 0, a]
        g1 = kh * gamma[e, 1, a]
        g2 = kh * gamma[e, 2, a]
        g3 = kh * gamma[e, 3, a]
        fe[a, 0] = P00 * bx + P01 * by + P02 * bz + g0 * q00 + g1 * q10 + g2 * q20 + g3 * q30
        fe[a, 1] = P10 * bx + P11 * by + P12 * bz + g0 * q01 + g1 * q11 + g2 * q21 + g3 * q31
        fe[a, 2] = P20 * bx + P21 * by + P22 * bz + g0 * q02 + g1 * q12 + g2 * q22 + g3 * q32
    return OK


@njit_parallel
def hex_forces(
    u,  # (n_nodes, 3) displacement (m)
    conn,  # (n_elem, 8) int32
    bbar,  # (n_elem, 8, 3)
    vol,  # (n_elem,)
    gamma,  # (n_elem, 4, 8)
    k_hg,  # (n_elem,) hourglass stiffness (N/m)
    mat,  # (n_elem,) int32 material index
    mu,  # (n_mat, n_terms) instantaneous moduli (Pa)
    alpha,  # (n_mat, n_terms)
    K,  # (n_mat,) bulk modulus (Pa)
    g,  # (n_mat, n_prony) Prony relative moduli
    decay,  # (n_mat, n_prony) exp(-dt / tau_k)
    gain,  # (n_mat, n_prony) (1 - decay) / (dt / tau_k)
    s_prev,  # (n_elem, 6) instantaneous isochoric PK2 (00, 11, 22, 01, 02, 12), last update
    hist,  # (n_elem, 6, n_prony) Prony history variables (Pa)
    update_history,  # bool: advance the Prony recursion (once per time step)
    ptr,  # (n_nodes + 1,) int64 node -> element-corner rows (see node_slots)
    slot,  # (n_elem * 8,) int64 element corners e * 8 + a, by node
    fe,  # (n_elem, 8, 3) work array: element forces
    status,  # (n_elem,) int32 work array: element status
    f,  # (n_nodes, 3) output: internal nodal forces (N), overwritten
):
    """Internal nodal forces of the hexahedra, parallel over elements and nodes.

    Race-free in two passes: every element writes its own forces ``fe[e]`` (``prange`` over
    elements), then every node sums the corners that touch it in the fixed order of
    ``slot`` (``prange`` over nodes). The result does not depend on the number of threads.

    Returns
    -------
    status : int
        ``OK``, ``INVERTED`` (J <= 0) or ``NOT_FINITE``.
    element : int
        The first offending element, -1 if none.
    """
    n_elem = conn.shape[0]
    for e in numba.prange(n_elem):
        status[e] = _hex_element(e, u, conn, bbar, vol, gamma, k_hg, mat, mu, alpha, K, g,
                                 decay, gain, s_prev, hist, update_history, fe[e])
    for e in range(n_elem):
        if status[e] != OK:
            return status[e], e
    for n in numba.prange(f.shape[0]):
        fx = 0.0
        fy = 0.0
        fz = 0.0
        for k in range(ptr[n], ptr[n + 1]):
            s = slot[k]
            e = s // 8
            a = s - 8 * e
            fx += fe[e, a, 0]
            fy += fe[e, a, 1]
            fz += fe[e, a, 2]
        f[n, 0] = fx
        f[n, 1] = fy
        f[n, 2] = fz
    return OK, -1


@njit
def hex_forces_serial(u, conn, bbar, vol, gamma, k_hg, mat, mu, alpha, K, g, decay, gain,
                      s_prev, hist, update_history, fe, f):
    """Serial variant of :func:`hex_forces`: one element at a time, scattered directly.

    ``fe`` is a (8, 3) work array. Same arguments and results otherwise (the nodal sums in
    element order rather than in ``slot`` order, so equal to rounding).
    """
    f[:] = 0.0
    for e in range(conn.shape[0]):
        st = _hex_element(e, u, conn, bbar, vol, gamma, k_hg, mat, mu, alpha, K, g, decay,
                          gain, s_prev, hist, update_history, fe)
        if st != OK:
            return st, e
        for a in range(8):
            n = conn[e, a]
            f[n, 0] += fe[a, 0]
            f[n, 1] += fe[a, 1]
            f[n, 2] += fe[a, 2]
    return OK, -1


@njit
def hex_energy(
    u,  # (n_nodes, 3)
    conn,  # (n_elem, 8) int32
    bbar,  # (n_elem, 8, 3)
    vol,  # (n_elem,)
    gamma,  # (n_elem, 4, 8)
    k_hg,  # (n_elem,)
    mat,  # (n_elem,) int32
    mu,  # (n_mat, n_terms) long-term moduli (Pa)
    alpha,  # (n_mat, n_terms)
    K,  # (n_mat,)
):
    """Stored elastic energy (J) and hourglass energy (J) of the hexahedra.

    For a viscoelastic material pass the long-term moduli (see :func:`axisym_energy`).
    """
    W = 0.0
    Whg = 0.0
    for e in range(conn.shape[0]):
        m = mat[e]
        F00, F01, F02, F10, F11, F12, F20, F21, F22 = _hex_state(u, conn, bbar, e)
        C00 = F00 * F00 + F10 * F10 + F20 * F20
        C11 = F01 * F01 + F11 * F11 + F21 * F21
        C22 = F02 * F02 + F12 * F12 + F22 * F22
        C01 = F00 * F01 + F10 * F11 + F20 * F21
        C02 = F00 * F02 + F10 * F12 + F20 * F22
        C12 = F01 * F02 + F11 * F12 + F21 * F22
        c1, c2, c3 = spectral_sym3(C00, C11, C22, C01, C02, C12)[:3]
        W += vol[e] * ogden_energy(math.sqrt(c1), math.sqrt(c2), math.sqrt(c3), mu[m],
                                   alpha[m], K[m])
        for k in range(4):
            qx = 0.0
            qy = 0.0
            qz = 0.0
            for a in range(8):
                n = conn[e, a]
                qx += gamma[e, k, a] * u[n, 0]
                qy += gamma[e, k, a] * u[n, 1]
                qz += gamma[e, k, a] * u[n, 2]
            Whg += 0.5 * k_hg[e] * (qx * qx + qy * qy + qz * qz)
    return W, Whg


@njit
def hex_stress(u, conn, bbar, mat, mu, alpha, K, g, decay, gain, s_prev, hist, out):
    """Cauchy stress of every hexahedron (Pa) at the state ``u``, Prony history as it is.

    ``out`` (n_elem, 6) receives (xx, yy, zz, xy, yz, xz), the order VTK readers take for a
    symmetric tensor. Inverted elements get NaN.
    """
    for e in range(conn.shape[0]):
        F00, F01, F02, F10, F11, F12, F20, F21, F22 = _hex_state(u, conn, bbar, e)
        S00, S11, S22, S01, S02, S12, J = _hex_pk2(F00, F01, F02, F10, F11, F12, F20, F21,
                                                   F22, mat[e], mu, alpha, K, g, decay, gain,
                                                   s_prev, hist, e, False)
        if not J > 0.0:
            out[e, :] = np.nan
            continue
        # sigma = F S F^T / J
        A00 = F00 * S00 + F01 * S01 + F02 * S02
        A01 = F00 * S01 + F01 * S11 + F02 * S12
        A02 = F00 * S02 + F01 * S12 + F02 * S22
        A10 = F10 * S00 + F11 * S01 + F12 * S02
        A11 = F10 * S01 + F11 * S11 + F12 * S12
        A12 = F10 * S02 + F11 * S12 + F12 * S22
        A20 = F20 * S00 + F21 * S01 + F22 * S02
        A21 = F20 * S01 + F21 * S11 + F22 * S12
        A22 = F20 * S02 + F21 * S12 + F22 * S22
        out[e, 0] = (A00 * F00 + A01 * F01 + A02 * F02) / J
        out[e, 1] = (A10 * F10 + A11 * F11 + A12 * F12) / J
        out[e, 2] = (A20 * F20 + A21 * F21 + A22 * F22) / J
        out[e, 3] = (A00 * F10 + A01 * F11 + A02 * F12) / J
        out[e, 4] = (A10 * F20 + A11 * F21 + A12 * F22) / J
        out[e, 5] = (A00 * F20 + A01 * F21 + A02 * F22) / J


@njit
def hex_stiffening(
    u,  # (n_nodes, 3)
    conn,  # (n_elem, 8) int32
    bbar,  # (n_elem, 8, 3)
    mat,  # (n_elem,) int32
    alpha,  # (n_mat, n_terms)
    share,  # (n_mat, n_terms) mu_i / sum(mu) of each material
    k_ratio,  # (n_mat,) K / sum(mu) of each material
    out,  # (n_elem,) output: omega^2(current) / omega^2(reference) bound per element
):
    r"""Bound on how much each hexahedron's highest frequency has grown.

    As :func:`axisym_stiffening`: the current gradient operator :math:`\bar b F^{-1}` and the
    tangent p-wave modulus at the principal stretches reached.
    """
    for e in range(conn.shape[0]):
        m = mat[e]
        F00, F01, F02, F10, F11, F12, F20, F21, F22 = _hex_state(u, conn, bbar, e)
        J = (F00 * (F11 * F22 - F12 * F21) - F01 * (F10 * F22 - F12 * F20)
             + F02 * (F10 * F21 - F11 * F20))
        if not J > 0.0:
            out[e] = np.inf
            continue
        # inverse of F (adjugate / J)
        i00 = (F11 * F22 - F12 * F21) / J
        i01 = (F02 * F21 - F01 * F22) / J
        i02 = (F01 * F12 - F02 * F11) / J
        i10 = (F12 * F20 - F10 * F22) / J
        i11 = (F00 * F22 - F02 * F20) / J
        i12 = (F02 * F10 - F00 * F12) / J
        i20 = (F10 * F21 - F11 * F20) / J
        i21 = (F01 * F20 - F00 * F21) / J
        i22 = (F00 * F11 - F01 * F10) / J
        ref = 0.0
        cur = 0.0
        for a in range(8):
            bx = bbar[e, a, 0]
            by = bbar[e, a, 1]
            bz = bbar[e, a, 2]
            ref += bx * bx + by * by + bz * bz
            x0 = bx * i00 + by * i10 + bz * i20
            x1 = bx * i01 + by * i11 + bz * i21
            x2 = bx * i02 + by * i12 + bz * i22
            cur += x0 * x0 + x1 * x1 + x2 * x2
        C00 = F00 * F00 + F10 * F10 + F20 * F20
        C11 = F01 * F01 + F11 * F11 + F21 * F21
        C22 = F02 * F02 + F12 * F12 + F22 * F22
        C01 = F00 * F01 + F10 * F11 + F20 * F21
        C02 = F00 * F02 + F10 * F12 + F20 * F22
        C12 = F01 * F02 + F11 * F12 + F21 * F22
        c1, c2, c3 = spectral_sym3(C00, C11, C22, C01, C02, C12)[:3]
        third = math.log(J) / 3.0
        l1 = 0.5 * math.log(c1) - third
        l2 = 0.5 * math.log(c2) - third
        l3 = 0.5 * math.log(c3) - third
        mu_t = 0.0
        for i in range(alpha.shape[1]):
            a = alpha[m, i]
            big = max(math.exp(a * l1), math.exp(a * l2), math.exp(a * l3))
            mu_t += share[m, i] * max(big, 1.0)
        modulus = (k_ratio[m] * J + 4.0 / 3.0 * mu_t) / (k_ratio[m] + 4.0 / 3.0)
        out[e] = cur / ref * max(modulus, 1.0)
