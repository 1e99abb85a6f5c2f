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

import numpy as np

from ._jit import njit
from .materials import ogden_energy, ogden_kirchhoff, prony_relaxed

__all__ = ["AxisymmetricOperators", "axisymmetric_operators", "axisym_forces", "axisym_energy"]

#: Status codes returned by the force kernels.
OK, INVERTED, NOT_FINITE = 0, 1, 2

_XI = np.array([-1.0, 1.0, 1.0, -1.0])
_ETA = np.array([-1.0, -1.0, 1.0, 1.0])
_HOURGLASS = np.array([1.0, -1.0, 1.0, -1.0])


class AxisymmetricOperators:
    """Reference-configuration operators of the axisymmetric mean-gradient quad.

    Attributes
    ----------
    bbar : ndarray, shape (n_elem, 4, 2)
        Volume-averaged gradients :math:`\\bar b_i` (1/m).
    hbar : ndarray, shape (n_elem, 4)
        Volume-averaged hoop operator :math:`\\bar h_i` (1/m).
    volume : ndarray, shape (n_elem,)
        Element volume :math:`\\int 2\\pi R\\,dA` (m^3).
    node_volume : ndarray, shape (n_elem, 4)
        :math:`\\int N_i\\,dV` (m^3), the lumped-mass share of each node.
    gamma : ndarray, shape (n_elem, 4)
        Flanagan-Belytschko hourglass vectors (dimensionless), orthogonal to linear fields.
    gamma_scale : ndarray, shape (n_elem,)
        :math:`V \\sum_i |\\bar b_i|^2` (m); the hourglass stiffness is
        :math:`\\kappa \\mu` times this.
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


@njit
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


@njit
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
    n_prony = g.shape[1]
    f[:] = 0.0
    for e in range(n_elem):
        m = mat[e]
        Frr, Frz, Fzr, Fzz, Ftt = _axisym_state(u, conn, bbar, hbar, e)
        det2 = Frr * Fzz - Frz * Fzr
        if not (det2 > 0.0 and Ftt > 0.0):
            if det2 <= 0.0 or Ftt <= 0.0:
                return INVERTED, e
            return NOT_FINITE, e
        C11 = Frr * Frr + Fzr * Fzr
        C22 = Frz * Frz + Fzz * Fzz
        C12 = Frr * Frz + Fzr * Fzz
        mean = 0.5 * (C11 + C22)
        half = math.sqrt(0.25 * (C11 - C22) ** 2 + C12 * C12)
        c1 = mean + half
        c2 = det2 * det2 / c1  # = mean - half without cancellation
        t1, t2, t3, tvol = ogden_kirchhoff(math.sqrt(c1), math.sqrt(c2), Ftt, mu[m], alpha[m],
                                           K[m])
        # instantaneous isochoric PK2 in tensor components
        s11, s22, s12 = _inplane_pk2(C11, C22, C12, c1, c2, t1 / c1, t2 / c2)
        stt = t3 / (Ftt * Ftt)
        if n_prony > 0:
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
    """Bound on how much each element's highest frequency has grown since the start.

    The element frequency scales with the current gradient operator (the element shrinks as
    it is compressed) and with the tangent p-wave modulus. The gradient operator in the
    current configuration is :math:`\\bar b F^{-1}`; the tangent shear modulus of the Ogden
    law along a principal direction is bounded by :math:`\\sum_i \\mu_i \\max_a
    \\bar\\lambda_a^{\\alpha_i}` (its value at the stretches reached).
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
