r"""Hyperelastic and hyperviscoelastic materials: parameter schema plus pure JIT kernels.

One convention throughout the project (Abaqus; Miller & Chinzei 2002; FElupe's ``ogden``):

.. math::

    W = \sum_{i=1}^{N} \frac{2\mu_i}{\alpha_i^2}
        \left(\bar\lambda_1^{\alpha_i} + \bar\lambda_2^{\alpha_i}
              + \bar\lambda_3^{\alpha_i} - 3\right)
        + \frac{K}{2} (J - 1)^2,
    \qquad \bar\lambda_a = J^{-1/3} \lambda_a ,

so that the small-strain shear modulus is :math:`\mu = \sum_i \mu_i`, Young's modulus of the
incompressible limit is :math:`E = 3\mu`, and the slope of the uniaxial nominal stress at
stretch 1 is :math:`3\mu`. The bulk modulus follows from :math:`\mu` and Poisson's ratio,
:math:`K = 2\mu(1+\nu) / (3(1-2\nu))`; Abaqus writes the volumetric term with
:math:`D_1 = 2/K`. Other conventions (FEBio's :math:`c_i = 2\mu_i`) appear only inside
:mod:`calib.export`.

Viscoelasticity (Miller & Chinzei 2002) relaxes the isochoric stress with a Prony series,

.. math::

    \mu(t) = \mu_\infty + \sum_k \mu_k e^{-t/\tau_k}
           = \mu_0 \left(1 - \sum_k g_k \left(1 - e^{-t/\tau_k}\right)\right),

with :math:`g_k = \mu_k / \mu_0` normalised by the instantaneous modulus as in Abaqus'
``*VISCOELASTIC, TIME=PRONY``. The ``mu_Pa`` of a viscoelastic :class:`Ogden` is the long-term
(relaxed) modulus :math:`\mu_\infty`; the volumetric response is elastic.

The kernels work on principal stretches and return principal *Kirchhoff* stresses
:math:`\tau_a = \lambda_a \partial W / \partial \lambda_a`; the element kernels in
:mod:`solver.kernels` rotate them back. All kernels take plain floats and float64 arrays.

References
----------
Miller K, Chinzei K (2002). Mechanical properties of brain tissue in tension. J Biomech 35:483-490.
doi:10.1016/S0021-9290(01)00234-2
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import optimize

from ._jit import njit_inline

__all__ = ["Ogden", "Prony", "NeoHookean", "bulk_modulus"]


def bulk_modulus(mu_Pa: float, nu: float) -> float:
    r"""Bulk modulus from the small-strain shear modulus and Poisson's ratio.

    Parameters
    ----------
    mu_Pa : float
        Small-strain shear modulus (Pa).
    nu : float
        Poisson's ratio, -1 < nu < 0.5.

    Returns
    -------
    float
        :math:`K = 2\mu(1+\nu)/(3(1-2\nu))` (Pa).
    """
    if not -1.0 < nu < 0.5:
        raise ValueError(f"Poisson's ratio nu={nu} must lie in (-1, 0.5)")
    return 2.0 * mu_Pa * (1.0 + nu) / (3.0 * (1.0 - 2.0 * nu))


def _as_tuple(value, name: str) -> tuple[float, ...]:
    if np.ndim(value) == 0:
        out = (float(value),)
    else:
        out = tuple(float(v) for v in value)
    if not out:
        raise ValueError(f"{name} must have at least one term")
    if not all(math.isfinite(v) for v in out):
        raise ValueError(f"{name}={out} must be finite")
    return out


@dataclasses.dataclass(frozen=True)
class Prony:
    r"""Prony series of the isochoric relaxation (Abaqus normalisation).

    Parameters
    ----------
    g : sequence of float
        Relative moduli :math:`g_k = \mu_k / \mu_0` (dimensionless), each in [0, 1),
        with :math:`\sum_k g_k < 1`.
    tau_s : sequence of float
        Relaxation times :math:`\tau_k` (s), positive.
    """

    g: tuple[float, ...]
    tau_s: tuple[float, ...]

    def __post_init__(self):
        g = _as_tuple(self.g, "g")
        tau = _as_tuple(self.tau_s, "tau_s")
        if len(g) != len(tau):
            raise ValueError(f"Prony g has {len(g)} terms but tau_s has {len(tau)}")
        if any(v < 0.0 for v in g) or sum(g) >= 1.0:
            raise ValueError(f"Prony g={g} must be non-negative with sum(g) < 1")
        if any(v <= 0.0 for v in tau):
            raise ValueError(f"Prony tau_s={tau} must be positive")
        object.__setattr__(self, "g", g)
        object.__setattr__(self, "tau_s", tau)

    @property
    def g_inf(self) -> float:
        r"""Long-term fraction :math:`1 - \sum g_k` of the instantaneous modulus."""
        return 1.0 - sum(self.g)

    def relaxation(self, t_s) -> np.ndarray:
        r"""Normalised relaxation function :math:`\mu(t)/\mu_0` at times ``t_s`` (s)."""
        t = np.asarray(t_s, dtype=float)
        out = np.full_like(t, self.g_inf)
        for gk, tk in zip(self.g, self.tau_s):
            out = out + gk * np.exp(-t / tk)
        return out


@dataclasses.dataclass(frozen=True)
class Ogden:
    r"""N-term Ogden material, optionally hyperviscoelastic (Miller & Chinzei 2002).

    Parameters
    ----------
    mu_Pa : float or sequence of float
        Moduli :math:`\mu_i` (Pa); their sum is the small-strain shear modulus. For a
        viscoelastic material these are the long-term (relaxed) moduli.
    alpha : float or sequence of float
        Exponents :math:`\alpha_i` (dimensionless, non-zero), one per modulus.
    nu : float
        Small-strain Poisson's ratio of the long-term response; sets the bulk modulus.
    prony : Prony, optional
        Relaxation of the isochoric stress. ``None`` for a purely hyperelastic material.
    density_kg_m3 : float
        Mass density (kg/m^3). Used as given only without mass scaling.

    Examples
    --------
    >>> m = Ogden(mu_Pa=1875.0, alpha=4.9, nu=0.499)
    >>> round(m.mu0_Pa, 1), round(m.youngs_modulus_Pa / m.mu0_Pa, 3)
    (1875.0, 2.998)
    >>> slope = (m.uniaxial_nominal_stress(1.0 + 1e-7) - m.uniaxial_nominal_stress(1.0)) / 1e-7
    >>> round(float(slope) / m.mu0_Pa, 3)
    3.0
    """

    mu_Pa: tuple[float, ...]
    alpha: tuple[float, ...]
    nu: float = 0.499
    prony: Prony | None = None
    density_kg_m3: float = 1000.0

    def __post_init__(self):
        mu = _as_tuple(self.mu_Pa, "mu_Pa")
        alpha = _as_tuple(self.alpha, "alpha")
        if len(mu) != len(alpha):
            raise ValueError(f"Ogden mu_Pa has {len(mu)} terms but alpha has {len(alpha)}")
        if any(a == 0.0 for a in alpha):
            raise ValueError(f"Ogden alpha={alpha}: every exponent must be non-zero")
        if sum(mu) <= 0.0:
            raise ValueError(f"Ogden mu_Pa={mu}: the shear modulus sum(mu) must be positive")
        if any(m * a <= 0.0 for m, a in zip(mu, alpha)):
            raise ValueError(
                f"Ogden mu_Pa={mu}, alpha={alpha}: each mu_i * alpha_i must be positive "
                "(Hill's stability condition for the small-strain response)"
            )
        bulk_modulus(1.0, self.nu)  # validates nu
        if not self.density_kg_m3 > 0.0:
            raise ValueError(f"density_kg_m3={self.density_kg_m3} must be positive")
        object.__setattr__(self, "mu_Pa", mu)
        object.__setattr__(self, "alpha", alpha)
        object.__setattr__(self, "nu", float(self.nu))

    # ------------------------------------------------------------------ derived constants
    @property
    def n_terms(self) -> int:
        """Number of Ogden terms."""
        return len(self.mu_Pa)

    @property
    def mu0_Pa(self) -> float:
        r"""Small-strain shear modulus :math:`\sum_i \mu_i` of the long-term response (Pa)."""
        return float(sum(self.mu_Pa))

    @property
    def instantaneous_mu_Pa(self) -> tuple[float, ...]:
        r"""Instantaneous moduli :math:`\mu_i / g_\infty` (Pa); equal to ``mu_Pa`` if elastic."""
        scale = 1.0 if self.prony is None else 1.0 / self.prony.g_inf
        return tuple(m * scale for m in self.mu_Pa)

    @property
    def bulk_modulus_Pa(self) -> float:
        """Bulk modulus :math:`K` (Pa) from ``mu0_Pa`` and ``nu``."""
        return bulk_modulus(self.mu0_Pa, self.nu)

    @property
    def youngs_modulus_Pa(self) -> float:
        r"""Small-strain Young's modulus :math:`2\mu(1+\nu)` (Pa)."""
        return 2.0 * self.mu0_Pa * (1.0 + self.nu)

    def with_mu_scaled(self, factor: float) -> Ogden:
        """The same material with every modulus (and the density) multiplied by ``factor``.

        With ``nu`` fixed and the ramp chosen relative to the natural period, forces scale
        exactly by ``factor``: see :func:`solver.explicit.simulate`.
        """
        return dataclasses.replace(self, mu_Pa=tuple(m * factor for m in self.mu_Pa))

    # ------------------------------------------------------------------ kernel arrays
    def kernel_arrays(self) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]:
        """Plain arrays for the JIT kernels.

        Returns
        -------
        mu : ndarray, shape (n_terms,)
            Instantaneous moduli (Pa).
        alpha : ndarray, shape (n_terms,)
        K : float
            Bulk modulus (Pa).
        g : ndarray, shape (n_prony,)
            Prony relative moduli (empty if elastic).
        tau : ndarray, shape (n_prony,)
            Prony times (s) (empty if elastic).
        """
        mu = np.array(self.instantaneous_mu_Pa, dtype=np.float64)
        alpha = np.array(self.alpha, dtype=np.float64)
        if self.prony is None:
            g = np.zeros(0)
            tau = np.zeros(0)
        else:
            g = np.array(self.prony.g, dtype=np.float64)
            tau = np.array(self.prony.tau_s, dtype=np.float64)
        return mu, alpha, self.bulk_modulus_Pa, g, tau

    # ------------------------------------------------------------------ closed forms
    def strain_energy(self, stretches) -> np.ndarray:
        """Elastic (long-term) strain energy density W (J/m^3) at principal stretches.

        Parameters
        ----------
        stretches : array_like, shape (..., 3)
            Principal stretches.
        """
        lam = np.asarray(stretches, dtype=float)
        J = np.prod(lam, axis=-1)
        lb = lam * J[..., None] ** (-1.0 / 3.0)
        W = 0.5 * self.bulk_modulus_Pa * (J - 1.0) ** 2
        for m, a in zip(self.mu_Pa, self.alpha):
            W = W + 2.0 * m / a**2 * (np.sum(lb**a, axis=-1) - 3.0)
        return W

    def kirchhoff_stress(self, stretches) -> np.ndarray:
        """Principal Kirchhoff stresses (Pa) of the long-term response, NumPy reference.

        Parameters
        ----------
        stretches : array_like, shape (..., 3)
        """
        lam = np.asarray(stretches, dtype=float)
        J = np.prod(lam, axis=-1)
        lb = lam * J[..., None] ** (-1.0 / 3.0)
        tau = np.zeros_like(lb) + (self.bulk_modulus_Pa * J * (J - 1.0))[..., None]
        for m, a in zip(self.mu_Pa, self.alpha):
            beta = lb**a
            tau = tau + 2.0 * m / a * (beta - beta.mean(axis=-1, keepdims=True))
        return tau

    def uniaxial_nominal_stress(self, stretch, incompressible: bool = True) -> np.ndarray:
        r"""Homogeneous uniaxial nominal (first Piola-Kirchhoff) stress (Pa), long-term.

        Parameters
        ----------
        stretch : array_like
            Axial stretch :math:`\lambda` (compression < 1).
        incompressible : bool
            ``True``: the closed form of the incompressible limit,
            :math:`P = \sum_i \frac{2\mu_i}{\alpha_i}
            (\lambda^{\alpha_i-1} - \lambda^{-\alpha_i/2-1})`.
            ``False``: the compressible material with this ``nu``; the lateral stretch that
            makes the lateral stress vanish is found by a bracketed root search.

        Returns
        -------
        ndarray
            Nominal stress, tension positive (Pa).
        """
        lam = np.asarray(stretch, dtype=float)
        if incompressible:
            P = np.zeros_like(lam)
            for m, a in zip(self.mu_Pa, self.alpha):
                P = P + 2.0 * m / a * (lam ** (a - 1.0) - lam ** (-0.5 * a - 1.0))
            return P
        flat = np.atleast_1d(lam).ravel()
        out = np.empty_like(flat)
        for k, lk in enumerate(flat):
            lt = self.uniaxial_lateral_stretch(lk)
            out[k] = self.kirchhoff_stress([lk, lt, lt])[0] / lk
        return out.reshape(lam.shape)

    def uniaxial_lateral_stretch(self, stretch: float) -> float:
        """Lateral stretch of homogeneous uniaxial stress at axial ``stretch`` (compressible)."""

        def lateral_stress(lt):
            return self.kirchhoff_stress([stretch, lt, lt])[1]

        lo, hi = 0.2, 5.0
        return optimize.brentq(lateral_stress, lo, hi, xtol=1e-15, rtol=1e-15)

    # ------------------------------------------------------------------ lmfit schema
    def parameters(self, vary_nu: bool = False):
        """Lmfit ``Parameters`` of this material in physical units with bounds.

        Names: ``mu_Pa`` and ``alpha`` for one term; ``mu1_Pa``, ``alpha1``, ``mu2_Pa``, ...
        for several; ``nu``; ``g1``, ``tau1_s``, ... for a Prony series.
        """
        import lmfit

        p = lmfit.Parameters()
        if self.n_terms == 1:
            p.add("mu_Pa", value=self.mu_Pa[0], min=1e-3 * self.mu_Pa[0], max=1e3 * self.mu_Pa[0])
            p.add("alpha", value=self.alpha[0], min=0.2, max=40.0)
        else:
            for i, (m, a) in enumerate(zip(self.mu_Pa, self.alpha), start=1):
                p.add(f"mu{i}_Pa", value=m)
                p.add(f"alpha{i}", value=a, min=-40.0, max=40.0)
        p.add("nu", value=self.nu, min=0.3, max=0.4999, vary=vary_nu)
        if self.prony is not None:
            for k, (gk, tk) in enumerate(zip(self.prony.g, self.prony.tau_s), start=1):
                p.add(f"g{k}", value=gk, min=0.0, max=0.95)
                p.add(f"tau{k}_s", value=tk, min=1e-3, max=1e4)
        return p

    @classmethod
    def from_parameters(cls, params, density_kg_m3: float = 1000.0) -> Ogden:
        """Build the material from lmfit ``Parameters`` (or a name -> value mapping)."""
        values = {k: (v.value if hasattr(v, "value") else float(v)) for k, v in params.items()}
        if "mu_Pa" in values:
            mu, alpha = (values["mu_Pa"],), (values["alpha"],)
        else:
            n = 1
            while f"mu{n + 1}_Pa" in values:
                n += 1
            mu = tuple(values[f"mu{i}_Pa"] for i in range(1, n + 1))
            alpha = tuple(values[f"alpha{i}"] for i in range(1, n + 1))
        prony = None
        if "g1" in values:
            n = 1
            while f"g{n + 1}" in values:
                n += 1
            prony = Prony(
                g=tuple(values[f"g{k}"] for k in range(1, n + 1)),
                tau_s=tuple(values[f"tau{k}_s"] for k in range(1, n + 1)),
            )
        return cls(mu_Pa=mu, alpha=alpha, nu=values.get("nu", 0.499), prony=prony,
                   density_kg_m3=density_kg_m3)


def NeoHookean(mu_Pa: float, nu: float = 0.499, **kwargs) -> Ogden:
    r"""Neo-Hookean material as the one-term Ogden law with :math:`\alpha = 2`.

    :math:`W = \frac{\mu}{2}(\bar I_1 - 3) + \frac{K}{2}(J-1)^2`, i.e. :math:`C_{10} = \mu/2`.
    """
    return Ogden(mu_Pa=mu_Pa, alpha=2.0, nu=nu, **kwargs)


# ====================================================================== JIT kernels
@njit_inline
def ogden_kirchhoff(lam1, lam2, lam3, mu, alpha, K):
    """Principal Kirchhoff stresses of the Ogden law, split into isochoric and volumetric.

    Parameters
    ----------
    lam1, lam2, lam3 : float
        Principal stretches (positive).
    mu : ndarray, shape (n_terms,)
        Moduli (Pa).
    alpha : ndarray, shape (n_terms,)
        Exponents.
    K : float
        Bulk modulus (Pa).

    Returns
    -------
    t1, t2, t3 : float
        Isochoric principal Kirchhoff stresses (Pa), deviatoric (they sum to zero).
    tvol : float
        Volumetric Kirchhoff stress :math:`J p = K J (J - 1)` (Pa), the same in every direction.
    """
    return ogden_kirchhoff_logs(math.log(lam1), math.log(lam2), math.log(lam3),
                                lam1 * lam2 * lam3, mu, alpha, K)


@njit_inline
def ogden_kirchhoff_logs(log1, log2, log3, J, mu, alpha, K):
    """:func:`ogden_kirchhoff` from the logarithms of the principal stretches and J.

    The element kernels have the squared stretches (eigenvalues of C) and J at hand:
    ``log(lam) = log(c) / 2`` saves the square roots and the logarithm of J.
    """
    third_log_J = (log1 + log2 + log3) / 3.0
    l1 = log1 - third_log_J
    l2 = log2 - third_log_J
    l3 = log3 - third_log_J
    t1 = 0.0
    t2 = 0.0
    t3 = 0.0
    for i in range(mu.shape[0]):
        a = alpha[i]
        b1 = math.exp(a * l1)
        b2 = math.exp(a * l2)
        b3 = math.exp(a * l3)
        mean = (b1 + b2 + b3) / 3.0
        c = 2.0 * mu[i] / a
        t1 += c * (b1 - mean)
        t2 += c * (b2 - mean)
        t3 += c * (b3 - mean)
    return t1, t2, t3, K * J * (J - 1.0)


@njit_inline
def ogden_energy(lam1, lam2, lam3, mu, alpha, K):
    """Strain energy density (J/m^3) of the Ogden law at principal stretches (elastic part)."""
    J = lam1 * lam2 * lam3
    third_log_J = math.log(J) / 3.0
    l1 = math.log(lam1) - third_log_J
    l2 = math.log(lam2) - third_log_J
    l3 = math.log(lam3) - third_log_J
    W = 0.5 * K * (J - 1.0) ** 2
    for i in range(mu.shape[0]):
        a = alpha[i]
        W += 2.0 * mu[i] / (a * a) * (math.exp(a * l1) + math.exp(a * l2) + math.exp(a * l3) - 3.0)
    return W


@njit_inline
def prony_relaxed(s0, s0_prev, h, g, decay, gain, update):
    r"""Relaxed value of one isochoric stress component (recursive Prony update).

    With the instantaneous isochoric stress :math:`S_0(t)` (computed with the instantaneous
    moduli), the relaxed stress is the hereditary integral

    .. math::

        S(t) = g_\infty S_0(t) + \sum_k g_k h_k(t), \qquad
        h_k(t) = \int_0^t e^{-(t-s)/\tau_k} \dot S_0(s)\,ds,

    advanced over a step :math:`\Delta t` by the standard recursion, exact when :math:`S_0`
    varies linearly within the step:
    :math:`h_k \leftarrow e^{-\Delta t/\tau_k} h_k
    + \frac{1 - e^{-\Delta t/\tau_k}}{\Delta t/\tau_k} (S_0^{n+1} - S_0^n)`.

    Parameters
    ----------
    s0, s0_prev : float
        Instantaneous stress component now and at the previous update (Pa).
    h : ndarray, shape (n_prony,)
        History variables of this component (Pa), advanced in place if ``update``.
    g, decay, gain : ndarray, shape (n_prony,)
        Relative moduli, :math:`e^{-\Delta t/\tau_k}` and the gain factor.
    update : bool
        Advance the history (once per time step) or only evaluate.

    Returns
    -------
    float
        :math:`S(t)` (Pa).
    """
    out = s0
    for k in range(g.shape[0]):
        if update:
            h[k] = decay[k] * h[k] + gain[k] * (s0 - s0_prev)
        out += g[k] * (h[k] - s0)
    return out
