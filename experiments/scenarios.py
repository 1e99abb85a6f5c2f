r"""Synthetic-campaign scenarios: the clean truth and one hidden effect each.

A :class:`Scenario` turns a sample's one-term Ogden truth (long-term shear modulus
:math:`\mu`, exponent :math:`\alpha`, convention of :mod:`solver.materials`) into the
:class:`CycleLaw` of one loading cycle: the material the solver runs, the platen condition,
and the rig-side effects applied to the simulated force-travel curve. Every scenario has a
magnitude :math:`M \ge 0`: :math:`M = 1` is the moderate default written below and
:math:`M = 0` reduces to ``clean`` exactly.

Scenarios and their truth at magnitude :math:`M` (:math:`M = 1` values in brackets):

``clean``
    One-term Ogden :math:`(\mu, \alpha)`, :math:`\nu = 0.499`, hyperelastic, bonded platens
    (sandpaper). Effect name ``none``.
``rate_dependence``
    Hyperviscoelastic Ogden (Miller & Chinzei 2002): the same long-term law relaxing through
    one Prony term, :math:`g_1 = 1 - (1 - 0.6)^M` [0.6], :math:`\tau_1 = 0.5` s; ``mu_Pa`` is
    the long-term modulus, so the instantaneous modulus is :math:`\mu / (1 - g_1)` [2.5
    :math:`\mu`]. Simulated at each cycle's real speed with a constant-speed ramp. The apparent
    modulus (secant slope of nominal stress over 1-5 % strain) then rises by a factor 2.16
    from 0.17 to 6 mm/s (1.3 at 0.83 mm/s), like the doubling of the thesis' Fig. 11.
``platen_slip``
    The platens are not bonded: Coulomb friction with coefficient :math:`0.15 / M` [0.15]
    instead of the sandpaper bond (:math:`M \to 0`: infinite friction, i.e. bonded). Below
    friction 0.001 (:math:`M > 150`) the platens are frictionless: wholly unbonded faces,
    e.g. lubricated platens (also what :mod:`experiments.generator`'s FElupe truth can run).
``contact_offset``
    An uneven (domed) top face: the platen first touches the sample at travel 0 but meets the
    full face only later. With offset :math:`\delta = 0.3 M` mm [0.3 mm] the force is
    :math:`F(x) = F_\mathrm{sim}(h(x))`, :math:`h(x) = x^2 / (4\delta)` for
    :math:`x < 2\delta` and :math:`x - \delta` beyond: a smooth (C1) toe over the first
    :math:`2\delta` of travel, then the bonded curve shifted by :math:`\delta`. A loader that
    takes the first rise of force as contact is off by :math:`\delta` for the rest of the curve;
    :mod:`calib.loaders` compensates the toe (its step 8) and is off by what the
    back-extrapolation of the initial rise misses (26 um at the default, seed 1, layers A, D).
``machine_compliance``
    Rig and load-cell compliance :math:`c = 0.15 M` mm/N [0.15 mm/N] in series: logged
    travel = sample compression + :math:`c F`. The rig still stops at 30 % of the stated
    height in logged travel, so the sample is compressed less. The moderate default is set
    where the effect is identifiable from loading branches alone: refitting the one-term
    law's mu and alpha absorbs a series spring almost entirely (bonded 30 % test, layer A
    sample: the remaining residual shape is 0.13 % of the peak force at 0.04 mm/N, 0.32 %
    at 0.1 mm/N, 0.7 % at 0.2 mm/N), so smaller compliances are named ``none``, correctly:
    their only trace is a bias in mu and alpha.
``compressibility``
    Poisson's ratio :math:`\nu = 0.499 - 0.079 M` [0.42] instead of the assumed 0.499
    (bulk modulus from :math:`\mu` and :math:`\nu`). As for the compliance, refitting mu
    and alpha absorbs most of it (residual shape 0.25 % of the peak force at nu = 0.46,
    0.43 % at 0.42), so the moderate default is the identifiable one.
``second_ogden_term``
    A two-term Ogden law with the same small-strain shear modulus :math:`\mu`:
    :math:`\mu_1 = (1 + 0.5 M)\mu`, :math:`\alpha_1 = \alpha + 4\min(M, 1)`,
    :math:`\mu_2 = -0.5 M \mu`, :math:`\alpha_2 = -4` [:math:`1.5\mu, \alpha + 4;
    -0.5\mu, -4`], so :math:`\mu_i \alpha_i > 0` for both terms. In the bonded 30 % test
    (24 x 30 mesh, layer A sample) the best one-term law (mu = 1408 Pa, alpha = 9.4 against a
    true mu of 1794 Pa) misses the curve by 0.037 N RMS, 0.7 % of the peak force and twelve
    times the load-cell noise, with a systematic S-shaped residual; homogeneous uniaxial
    compression gives about 1.0-1.6 % for the layers' exponents (smaller for larger alpha).
``preconditioning``
    Mullins-like softening from one test of a sample to the next: test :math:`k` (1, 2, 3 in
    the order run) has modulus :math:`\mu (1 - s)^{k-1}` with :math:`s = 1 - (1 - 0.08)^M`
    [0.08]; :math:`\alpha` unchanged.

References
----------
du Plessis G (2016). Squashing brains. MPE thesis, The University of Western Australia.
Miller K, Chinzei K (2002). Mechanical properties of brain tissue in tension. J Biomech
35:483-490. doi:10.1016/S0021-9290(01)00234-2
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from solver import Ogden, Prony

__all__ = ["Scenario", "CycleLaw", "SCENARIOS", "get_scenario", "NU_ASSUMED", "EFFECTS"]

#: Poisson's ratio assumed by the calibration (nearly incompressible gel).
NU_ASSUMED = 0.499

# ---- effect sizes at M = 1 (see the module docstring)
G1_UNIT = 0.6
TAU1_S = 0.5
FRICTION_UNIT = 0.15
#: Below this friction coefficient the slip scenario's platens are frictionless (M > 150):
#: the solver's Coulomb platens at friction 1e-4 give the frictionless curve within 0.1 %.
FRICTIONLESS_BELOW = 1e-3
OFFSET_UNIT_MM = 0.3
COMPLIANCE_UNIT_MM_PER_N = 0.15
NU_DROP_UNIT = 0.079
SECOND_TERM_WEIGHT = 0.5
SECOND_TERM_ALPHA_SHIFT = 4.0
SECOND_TERM_ALPHA2 = -4.0
SOFTENING_UNIT = 0.08


@dataclasses.dataclass(frozen=True)
class CycleLaw:
    """The truth of one loading cycle: what the solver runs and what the rig adds.

    Parameters
    ----------
    material : solver.Ogden
        The sample's material in this test (long-term moduli if viscoelastic).
    platen : {"bonded", "coulomb", "frictionless"}
    friction : float
        Coulomb coefficient (0 when bonded or frictionless).
    contact_offset_mm : float
        Travel between the first touch and full-face contact, :math:`\\delta` (mm).
    compliance_mm_per_N : float
        Series compliance of the rig and load cell (mm/N).
    softening_factor : float
        Modulus of this test over the sample's virgin modulus (preconditioning), else 1.
    """

    material: Ogden
    platen: str = "bonded"
    friction: float = 0.0
    contact_offset_mm: float = 0.0
    compliance_mm_per_N: float = 0.0
    softening_factor: float = 1.0

    @property
    def viscoelastic(self) -> bool:
        """Whether the material relaxes (the simulation then depends on the rate)."""
        return self.material.prony is not None

    def to_dict(self) -> dict:
        """JSON-ready truth of the cycle."""
        m = self.material
        return {
            "material": {
                "mu_Pa": list(m.mu_Pa), "alpha": list(m.alpha), "nu": m.nu,
                "mu0_Pa": m.mu0_Pa,
                "prony": None if m.prony is None else {"g": list(m.prony.g),
                                                       "tau_s": list(m.prony.tau_s)},
            },
            "platen": self.platen, "friction": self.friction,
            "contact_offset_mm": self.contact_offset_mm,
            "compliance_mm_per_N": self.compliance_mm_per_N,
            "softening_factor": self.softening_factor,
        }


def _check_magnitude(name: str, magnitude: float) -> float:
    magnitude = float(magnitude)
    if not (math.isfinite(magnitude) and magnitude >= 0.0):
        raise ValueError(f"scenario {name!r}: magnitude {magnitude} must be a finite number "
                         ">= 0 (0 reduces to clean, 1 is the moderate default)")
    return magnitude


# ---------------------------------------------------------------------- the laws
def _clean(mu, alpha, test, M):
    return CycleLaw(Ogden(mu_Pa=mu, alpha=alpha, nu=NU_ASSUMED))


def _rate(mu, alpha, test, M):
    g1 = 1.0 - (1.0 - G1_UNIT) ** M
    if g1 <= 0.0:
        return _clean(mu, alpha, test, M)
    if g1 > 0.95:
        raise ValueError(f"scenario 'rate_dependence': magnitude {M} gives g1={g1:.3f}; the "
                         "instantaneous modulus would exceed 20 times the long-term one "
                         "(use M <= 3.2)")
    return CycleLaw(Ogden(mu_Pa=mu, alpha=alpha, nu=NU_ASSUMED,
                          prony=Prony(g=(g1,), tau_s=(TAU1_S,))))


def _slip_platen(M: float) -> tuple[str, float]:
    """Platen condition and friction of the slip scenario at magnitude ``M``."""
    if M == 0.0:
        return "bonded", 0.0
    friction = FRICTION_UNIT / M
    return ("frictionless", 0.0) if friction < FRICTIONLESS_BELOW else ("coulomb", friction)


def _slip(mu, alpha, test, M):
    platen, friction = _slip_platen(M)
    if platen == "bonded":
        return _clean(mu, alpha, test, M)
    return CycleLaw(Ogden(mu_Pa=mu, alpha=alpha, nu=NU_ASSUMED), platen=platen,
                    friction=friction)


def _offset(mu, alpha, test, M):
    return CycleLaw(Ogden(mu_Pa=mu, alpha=alpha, nu=NU_ASSUMED),
                    contact_offset_mm=OFFSET_UNIT_MM * M)


def _compliance(mu, alpha, test, M):
    return CycleLaw(Ogden(mu_Pa=mu, alpha=alpha, nu=NU_ASSUMED),
                    compliance_mm_per_N=COMPLIANCE_UNIT_MM_PER_N * M)


def _compressible(mu, alpha, test, M):
    nu = NU_ASSUMED - NU_DROP_UNIT * M
    if nu <= 0.0:
        raise ValueError(f"scenario 'compressibility': magnitude {M} gives Poisson's ratio "
                         f"{nu:.3f}; it must stay positive (use M < 6.3)")
    return CycleLaw(Ogden(mu_Pa=mu, alpha=alpha, nu=nu))


def _second_term(mu, alpha, test, M):
    if M == 0.0:
        return _clean(mu, alpha, test, M)
    f = SECOND_TERM_WEIGHT * M
    a1 = alpha + SECOND_TERM_ALPHA_SHIFT * min(M, 1.0)
    mus = (mu * (1.0 + f), -mu * f)
    alphas = (a1, SECOND_TERM_ALPHA2)
    material = Ogden(mu_Pa=mus, alpha=alphas, nu=NU_ASSUMED)
    # the homogeneous compression tangent must stay positive well beyond the 30 % nominal
    # compression (the bonded rims see larger local compression): stretch 0.3 ... 1
    lam = np.linspace(0.3, 1.0, 701)
    tangent = np.gradient(material.uniaxial_nominal_stress(lam), lam)
    if not np.all(tangent > 0.0):
        raise ValueError(f"scenario 'second_ogden_term': magnitude {M} makes the two-term law "
                         f"mu={mus}, alpha={alphas} lose stiffness in compression (tangent "
                         f"<= 0 at stretch {lam[np.argmin(tangent)]:.2f}); use a smaller M")
    return CycleLaw(material)


def _preconditioning(mu, alpha, test, M):
    if test < 1:
        raise ValueError(f"scenario 'preconditioning': test number {test} must be >= 1")
    factor = (1.0 - SOFTENING_UNIT) ** (M * (test - 1))
    return CycleLaw(Ogden(mu_Pa=mu * factor, alpha=alpha, nu=NU_ASSUMED),
                    softening_factor=factor)


@dataclasses.dataclass(frozen=True)
class Scenario:
    """One scenario: its name, the effect it hides, and its cycle law.

    Parameters
    ----------
    name : str
    effect : str
        The effect name of the ``calib discover`` contract (``"none"`` for ``clean``).
    meaning : str
        Physical meaning, one sentence.
    unit_parameters : dict
        The effect's parameters at magnitude 1, for the truth file.
    """

    name: str
    effect: str
    meaning: str
    unit_parameters: dict
    _law: Callable = dataclasses.field(repr=False, compare=False)

    def law(self, mu_Pa: float, alpha: float, test: int, magnitude: float = 1.0) -> CycleLaw:
        """The truth of one cycle of a sample with one-term truth ``(mu_Pa, alpha)``.

        Parameters
        ----------
        mu_Pa : float
            The sample's (long-term, virgin) small-strain shear modulus (Pa).
        alpha : float
            The sample's Ogden exponent.
        test : int
            Test number (1, 2, 3: the order in which the sample's tests were run).
        magnitude : float
            Effect magnitude M >= 0; 1 is the moderate default, 0 reduces to clean.

        Returns
        -------
        CycleLaw
        """
        M = _check_magnitude(self.name, magnitude)
        if not (math.isfinite(mu_Pa) and mu_Pa > 0):
            raise ValueError(f"scenario {self.name!r}: mu_Pa={mu_Pa} must be positive")
        if not (math.isfinite(alpha) and alpha != 0):
            raise ValueError(f"scenario {self.name!r}: alpha={alpha} must be non-zero")
        return self._law(float(mu_Pa), float(alpha), int(test), M)

    def parameters(self, magnitude: float = 1.0) -> dict:
        """The effect's parameters at ``magnitude``, in closed form (for the truth file)."""
        M = _check_magnitude(self.name, magnitude)
        p = {}
        if self.name == "rate_dependence":
            p = {"g1": 1.0 - (1.0 - G1_UNIT) ** M, "tau1_s": TAU1_S}
        elif self.name == "platen_slip":
            platen, friction = _slip_platen(M)
            p = {"platen": platen, "friction": None if platen == "bonded" else friction}
        elif self.name == "contact_offset":
            p = {"contact_offset_mm": OFFSET_UNIT_MM * M,
                 "toe_length_mm": 2.0 * OFFSET_UNIT_MM * M}
        elif self.name == "machine_compliance":
            p = {"compliance_mm_per_N": COMPLIANCE_UNIT_MM_PER_N * M}
        elif self.name == "compressibility":
            p = {"nu": NU_ASSUMED - NU_DROP_UNIT * M, "nu_assumed": NU_ASSUMED}
        elif self.name == "second_ogden_term":
            p = {"mu1_over_mu": 1.0 + SECOND_TERM_WEIGHT * M,
                 "alpha1_minus_alpha": SECOND_TERM_ALPHA_SHIFT * min(M, 1.0),
                 "mu2_over_mu": -SECOND_TERM_WEIGHT * M, "alpha2": SECOND_TERM_ALPHA2}
        elif self.name == "preconditioning":
            p = {"softening_per_test": 1.0 - (1.0 - SOFTENING_UNIT) ** M}
        return p

    def to_dict(self, magnitude: float = 1.0) -> dict:
        """JSON-ready description of the scenario at ``magnitude``."""
        return {"name": self.name, "effect": self.effect, "meaning": self.meaning,
                "magnitude": float(magnitude), "parameters": self.parameters(magnitude),
                "unit_parameters": self.unit_parameters}


SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    Scenario("clean", "none",
             "one-term Ogden, bonded platens, nu = 0.499, hyperelastic", {}, _clean),
    Scenario("rate_dependence", "rate_dependence",
             "hyperviscoelastic Ogden: one Prony term relaxes the isochoric stress, so faster "
             "tests are stiffer",
             {"g1": G1_UNIT, "tau1_s": TAU1_S}, _rate),
    Scenario("platen_slip", "platen_slip",
             "platens not bonded: Coulomb friction lets the faces slide outward",
             {"friction": FRICTION_UNIT}, _slip),
    Scenario("contact_offset", "contact_offset",
             "domed top face: a soft toe before the platen meets the full face, a travel "
             "offset after the first touch", {"contact_offset_mm": OFFSET_UNIT_MM}, _offset),
    Scenario("machine_compliance", "machine_compliance",
             "rig and load-cell compliance in series: logged travel = sample compression + c F",
             {"compliance_mm_per_N": COMPLIANCE_UNIT_MM_PER_N}, _compliance),
    Scenario("compressibility", "compressibility",
             "Poisson's ratio below the assumed 0.499",
             {"nu": NU_ASSUMED - NU_DROP_UNIT}, _compressible),
    Scenario("second_ogden_term", "second_ogden_term",
             "two-term Ogden law with the same small-strain modulus; one term cannot follow "
             "its shape",
             {"mu1_over_mu": 1.0 + SECOND_TERM_WEIGHT,
              "alpha1_minus_alpha": SECOND_TERM_ALPHA_SHIFT,
              "mu2_over_mu": -SECOND_TERM_WEIGHT, "alpha2": SECOND_TERM_ALPHA2},
             _second_term),
    Scenario("preconditioning", "preconditioning",
             "Mullins-like softening: each test of a sample is softer than the one before",
             {"softening_per_test": SOFTENING_UNIT}, _preconditioning),
)}

#: Effect names of the ``calib discover`` contract, scenario by scenario.
EFFECTS = {name: s.effect for name, s in SCENARIOS.items()}


def get_scenario(name: str) -> Scenario:
    """The scenario called ``name``; a clear error listing the known ones otherwise."""
    try:
        return SCENARIOS[name]
    except KeyError:
        raise ValueError(f"unknown scenario {name!r}; known scenarios: "
                         f"{', '.join(SCENARIOS)}") from None
