r"""Synthetic rig campaigns from a known truth, through the forward solver.

A campaign is layers A-F x 3 samples x 3 platen speeds (0.17, 0.83, 6 mm/s) = 54 loading
cycles, written in the rig log format of ``shared/RIG_LOGS.md`` with a realistic sensor model
(:mod:`experiments.sensor`) and the file variants of the contract (:mod:`experiments.rigfile`),
plus ``truth.json`` beside the data (read by tests, never by the pipeline).

How one campaign is made
------------------------
1. *Plan* (cheap, no simulation; :func:`plan_campaign`). Per layer the thesis' Table 1 gives
   the one-term Ogden truth (:data:`TABLE_1`). Per sample: seeded scatter of the modulus
   (lognormal, 5 %) and the exponent (3 %), the geometry measured by the operator (1 %, rounded
   to 0.1 mm; nominal 38 x 24 mm for samples whose files carry no metadata), and the order of
   its three tests (a seeded permutation of the speeds). Per cycle: the scenario's
   :class:`~experiments.scenarios.CycleLaw`, the rig programme (pre-roll, approach 0.5-2 mm,
   optional hold, unloading) and the file variant.
2. *Simulate* the loading with :func:`solver.simulate` at constant platen speed on a finer
   mesh than the fitting default (24 x 30 quads; ``fast=True`` uses the default 14 x 18).
   Hyperelastic runs are independent of the speed and proportional to the modulus
   (``solver.explicit``), so one run per sample serves all its tests (preconditioning included);
   viscoelastic runs are made per cycle at the cycle's speed. With ``truth_code="felupe"``
   the hyperelastic runs come from an independent code instead: FElupe's static r-z solution
   (:func:`experiments.felupe_reference.compression_curve`, quadratic 16 x 16 graded cells,
   mixed formulation, penalty contact of the side rolling onto bonded platens), for the
   scenarios it can run (bonded or frictionless platens, no rate dependence). The toolkit
   then fits data that its own discretisation did not make.
3. *Rig*: the loading curve in platen travel from the first touch, :math:`x`, follows from the
   simulated curve :math:`F_\mathrm{sim}(u)` by the scenario's rig-side effects (contact toe,
   series compliance), interpolated monotonically (PCHIP) onto the logger's samples. The rig
   stops at :math:`x = 0.3\,H` (stated height).
4. *Hold and unloading* are approximate, since loaders discard them: during a hold the force
   of a viscoelastic sample relaxes as :math:`F_\infty + (F_\mathrm{peak} - F_\infty)
   e^{-t/\tau_1}` (exact for one Prony term at fixed deformation, with :math:`F_\infty` from a
   long-term run on the default mesh), and is constant otherwise; unloading at the same speed
   follows the (long-term) loading curve scaled to the force at the end of the hold, with a
   fixed 5 % hysteresis loop :math:`(1 - 0.05 (1 - x / x_\mathrm{max}))`, and the force is zero
   once the platen has left the sample.
5. *Sense and write*: sensor noise, then the file variant; files go to ``DIR/<layer>/`` with a
   ``manifest.csv`` per layer folder where some files have no header.

Random streams are keyed by (seed, stream, layer, sample, test), so a campaign's layer A is the
same whether or not the other layers are generated, and two scenarios with the same seed share
every draw (materials, geometry, test order, programme, variants, noise): they differ only by
the physics of their hidden effect.

The embedded campaign
---------------------
``experiments/campaign/`` is the ``rate_dependence`` scenario at magnitude 1, seed
:data:`EMBEDDED_SEED`, all layers, fine mesh. Regenerate it with::

    python -m experiments.generator --embedded

(about 1-2 minutes on one core of the development machine).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from scipy.interpolate import PchipInterpolator

from solver import CompressionTest, Ogden, axisymmetric_cylinder, simulate

from .rigfile import (
    CycleMeta,
    FileVariant,
    cycle_file_name,
    draw_variant,
    format_cycle,
    manifest_text,
)
from .scenarios import CycleLaw, get_scenario
from .sensor import SensorModel

__all__ = [
    "LAYERS",
    "TABLE_1",
    "RATES",
    "EMBEDDED_SEED",
    "EMBEDDED_DIR",
    "Scatter",
    "RigProgramme",
    "CampaignSpec",
    "SamplePlan",
    "CyclePlan",
    "GenerationSummary",
    "plan_campaign",
    "loading_curve",
    "generate_campaign",
    "generate_embedded",
    "parse_layers",
]

#: Gel layers in the order their batches were made (du Plessis 2016, Sect. 5.5).
LAYERS = ("A", "B", "C", "D", "E", "F")

#: One-term Ogden truth per layer, (mu_Pa, alpha): du Plessis (2016) Table 1.
TABLE_1 = {"A": (1875.0, 4.9), "B": (1875.0, 6.5), "C": (2165.0, 6.0),
           "D": (3000.0, 6.0), "E": (3000.0, 5.7), "F": (3100.0, 5.5)}

#: Platen speeds of the campaign (mm/s).
RATES = (0.17, 0.83, 6.0)

NOMINAL_DIAMETER_MM = 38.0
NOMINAL_HEIGHT_MM = 24.0
STRAIN = 0.3

#: Meshes (n_radial, n_axial): generation and ``fast`` (the fitting default).
FINE_MESH = (24, 30)
#: The codes that can make a campaign's curves (:class:`CampaignSpec`).
TRUTH_CODES = ("solver", "felupe")
#: how the logs and summaries name each truth code
CODE_NAMES = {"solver": "solver", "felupe": "FElupe"}
#: FElupe truth: r-z quadratic cells (radial, axial) and equal load increments to 31 %.
FELUPE_MESH = (16, 16)
FELUPE_INCREMENTS = 62
FAST_MESH = (14, 18)
#: Solver output points along the ramp (interpolated by PCHIP onto the samples).
N_OUT = 121

#: Seed and folder of the embedded campaign.
EMBEDDED_SEED = 2016
EMBEDDED_DIR = Path(__file__).resolve().parent / "campaign"

# random stream identifiers (see the module docstring)
_MATERIAL, _GEOMETRY, _ORDER, _FORMAT, _PROGRAMME, _NOISE = 1, 2, 3, 4, 5, 6


@dataclasses.dataclass(frozen=True)
class Scatter:
    """Sample-to-sample scatter of the truth.

    Parameters
    ----------
    mu_cv : float
        Relative standard deviation of the modulus (lognormal).
    alpha_cv : float
        Relative standard deviation of the exponent (normal).
    diameter_cv, height_cv : float
        Relative standard deviation of the measured size.
    clip_sigma : float
        Draws are clipped at this many standard deviations.
    geometry_round_mm : float
        The operator's reading resolution (mm).
    """

    mu_cv: float = 0.05
    alpha_cv: float = 0.03
    diameter_cv: float = 0.01
    height_cv: float = 0.01
    clip_sigma: float = 2.0
    geometry_round_mm: float = 0.1

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"Scatter.{f.name}={value} must be a non-negative number")
        if not self.geometry_round_mm > 0:
            raise ValueError("Scatter.geometry_round_mm must be positive")


@dataclasses.dataclass(frozen=True)
class RigProgramme:
    """What the rig does around the loading ramp (each range drawn uniformly per cycle).

    Parameters
    ----------
    preroll_s : tuple of float
        Logging before the platen starts moving (s).
    approach_mm : tuple of float
        Platen travel before it touches the sample (mm), at the test speed.
    hold_probability : float
        Share of cycles with a hold at peak.
    hold_s : tuple of float
        Hold duration (s).
    retract_fraction : tuple of float
        After unloading, the platen retracts this fraction of the approach beyond the first
        touch before logging stops.
    hysteresis : float
        Depth of the approximate unloading loop (fraction of the loading force).
    """

    preroll_s: tuple[float, float] = (0.0, 0.5)
    approach_mm: tuple[float, float] = (0.5, 2.0)
    hold_probability: float = 0.5
    hold_s: tuple[float, float] = (0.5, 3.0)
    retract_fraction: tuple[float, float] = (0.1, 0.8)
    hysteresis: float = 0.05

    def __post_init__(self):
        for name in ("preroll_s", "approach_mm", "hold_s", "retract_fraction"):
            lo, hi = getattr(self, name)
            if not (0 <= lo <= hi and math.isfinite(hi)):
                raise ValueError(f"RigProgramme.{name}={(lo, hi)} must be an ordered "
                                 "non-negative range")
        if not 0 <= self.hold_probability <= 1:
            raise ValueError("RigProgramme.hold_probability must lie in [0, 1]")
        if not 0 <= self.hysteresis < 1:
            raise ValueError("RigProgramme.hysteresis must lie in [0, 1)")
        if self.approach_mm[0] <= 0:
            raise ValueError("RigProgramme.approach_mm must be positive: the log starts "
                             "before contact")


@dataclasses.dataclass(frozen=True)
class CampaignSpec:
    """Everything that defines a synthetic campaign.

    Parameters
    ----------
    scenario : str
        A name of :data:`experiments.scenarios.SCENARIOS`.
    magnitude : float
        Effect magnitude M >= 0 (1 moderate, 0 = clean).
    seed : int
        Master seed (non-negative).
    layers : tuple of str
        Subset of :data:`LAYERS`.
    n_samples : int
        Samples per layer.
    rates : tuple of float
        Platen speeds (mm/s), one test per speed per sample.
    fast : bool
        Simulate on the fitting default mesh instead of the finer generation mesh.
    truth_code : {"solver", "felupe"}
        The code that makes the hyperelastic curves: this project's explicit solver, or FElupe
        (static, independent; bonded or frictionless platens, no Prony terms; ``fast`` then
        has no effect).
    axial_ratio : float
        Largest over smallest element height of the solver's meshes (3, the fitting
        default, unless the fitting mesh is graded otherwise too: ``FitSettings.axial_ratio``).
    sensor, scatter, programme
        Sensor model, sample scatter and rig programme.
    filename_only_probability : float
        Share of samples whose files carry no metadata but the file name.
    """

    scenario: str = "clean"
    magnitude: float = 1.0
    seed: int = 0
    layers: tuple[str, ...] = LAYERS
    n_samples: int = 3
    rates: tuple[float, ...] = RATES
    fast: bool = False
    truth_code: str = "solver"
    axial_ratio: float = 3.0
    sensor: SensorModel = dataclasses.field(default_factory=SensorModel)
    scatter: Scatter = dataclasses.field(default_factory=Scatter)
    programme: RigProgramme = dataclasses.field(default_factory=RigProgramme)
    filename_only_probability: float = 0.12

    def __post_init__(self):
        scenario = get_scenario(self.scenario)
        scenario.parameters(self.magnitude)  # validates the magnitude
        if isinstance(self.seed, bool) or int(self.seed) != self.seed or self.seed < 0:
            raise ValueError(f"seed {self.seed!r} must be a non-negative integer")
        object.__setattr__(self, "seed", int(self.seed))
        object.__setattr__(self, "layers", parse_layers(self.layers))
        if not 1 <= self.n_samples <= 9:
            raise ValueError(f"n_samples={self.n_samples} must lie in 1..9")
        rates = tuple(float(r) for r in self.rates)
        if not rates or len(set(rates)) != len(rates):
            raise ValueError(f"rates {self.rates} must be distinct and at least one")
        if any(not (math.isfinite(r) and 0.01 <= r <= 50.0) for r in rates):
            raise ValueError(f"rates {rates} must lie in 0.01..50 mm/s")
        object.__setattr__(self, "rates", rates)
        if not 0 <= self.filename_only_probability <= 1:
            raise ValueError("filename_only_probability must lie in [0, 1]")
        if not (math.isfinite(self.axial_ratio) and self.axial_ratio >= 1.0):
            raise ValueError(f"axial_ratio={self.axial_ratio!r} must be a finite number >= 1 "
                             "(largest over smallest element height)")
        if self.truth_code not in TRUTH_CODES:
            raise ValueError(f"truth_code {self.truth_code!r} is not one of "
                             f"{', '.join(TRUTH_CODES)}")
        for layer in self.layers:  # the effect must be valid at every layer's Table 1 truth
            law = scenario.law(*TABLE_1[layer], test=len(rates), magnitude=self.magnitude)
            if self.truth_code == "felupe" and (law.viscoelastic or law.platen == "coulomb"):
                raise ValueError(
                    f"scenario {self.scenario!r} at magnitude {self.magnitude:g} needs "
                    f"{'a Prony series' if law.viscoelastic else 'Coulomb platens'}, which the "
                    "FElupe truth does not run (static hyperelastic, bonded or frictionless "
                    "platens: FElupe's frictional contact did not converge on every sample; "
                    "platen_slip is frictionless above magnitude 150)")

    @property
    def mesh_size(self) -> tuple[int, int]:
        """(n_radial, n_axial) of the generation mesh."""
        return FAST_MESH if self.fast else FINE_MESH

    @property
    def curve_mesh(self) -> tuple[int, int]:
        """(n_radial, n_axial) of the mesh the truth code makes the curves on."""
        return self.mesh_size if self.truth_code == "solver" else FELUPE_MESH

    def to_dict(self) -> dict:
        """JSON-ready description."""
        return {
            "scenario": self.scenario, "magnitude": float(self.magnitude), "seed": self.seed,
            "layers": list(self.layers), "n_samples": self.n_samples,
            "rates_mm_per_s": list(self.rates), "fast": self.fast,
            "truth_code": self.truth_code,
            "mesh": ({"n_radial": self.mesh_size[0], "n_axial": self.mesh_size[1],
                      "axial_ratio": float(self.axial_ratio), "n_out": N_OUT}
                     if self.truth_code == "solver" else
                     {"code": "felupe", "n_radial": FELUPE_MESH[0], "n_axial": FELUPE_MESH[1],
                      "order": "quadratic", "increments": FELUPE_INCREMENTS}),
            "sensor": self.sensor.to_dict(), "scatter": dataclasses.asdict(self.scatter),
            "programme": dataclasses.asdict(self.programme),
            "filename_only_probability": self.filename_only_probability,
        }


def parse_layers(layers: str | Sequence[str] | None) -> tuple[str, ...]:
    """Validate a layer selection (``"A,B"`` or a sequence) into campaign order.

    Raises
    ------
    ValueError
        On an unknown, duplicated or empty selection, naming it.
    """
    if layers is None:
        return LAYERS
    items = [s.strip().upper() for s in layers.split(",")] if isinstance(layers, str) \
        else [str(s).strip().upper() for s in layers]
    if not items or any(not s for s in items):
        raise ValueError(f"layer selection {layers!r} is empty or has an empty entry")
    unknown = [s for s in items if s not in LAYERS]
    if unknown:
        raise ValueError(f"unknown layer(s) {', '.join(unknown)}; layers are "
                         f"{', '.join(LAYERS)}")
    if len(set(items)) != len(items):
        raise ValueError(f"layer selection {layers!r} repeats a layer")
    return tuple(s for s in LAYERS if s in items)


def _rng(seed: int, stream: int, *key: int) -> np.random.Generator:
    return np.random.default_rng([seed, stream, *key])


@dataclasses.dataclass(frozen=True)
class SamplePlan:
    """One sample's truth: its virgin one-term law, size and test order."""

    layer: str
    sample: str
    mu_Pa: float
    alpha: float
    diameter_mm: float
    height_mm: float
    geometry_source: str
    test_rates: tuple[float, ...]
    filename_only: bool

    def to_dict(self) -> dict:
        """JSON-ready truth of the sample."""
        return {"layer": self.layer, "mu_Pa": self.mu_Pa, "alpha": self.alpha,
                "diameter_mm": self.diameter_mm, "height_mm": self.height_mm,
                "geometry_source": self.geometry_source,
                "test_order_rates_mm_per_s": list(self.test_rates),
                "metadata": "filename only" if self.filename_only else "header/manifest"}


@dataclasses.dataclass(frozen=True)
class CyclePlan:
    """One cycle: metadata, truth law, rig programme and file variant."""

    meta: CycleMeta
    law: CycleLaw
    variant: FileVariant
    path: str
    preroll_s: float
    approach_mm: float
    hold_s: float
    retract_mm: float
    key: tuple[int, int, int]

    @property
    def peak_travel_mm(self) -> float:
        """Platen travel from the first touch at which the rig stops (mm)."""
        return STRAIN * self.meta.height_mm


def plan_campaign(spec: CampaignSpec) -> tuple[list[SamplePlan], list[CyclePlan]]:
    """Draw every sample's truth and every cycle's programme and variant (no simulation).

    Parameters
    ----------
    spec : CampaignSpec

    Returns
    -------
    samples : list of SamplePlan
    cycles : list of CyclePlan
        In layer, sample, test order.
    """
    scenario = get_scenario(spec.scenario)
    sc = spec.scatter
    samples, cycles = [], []
    for layer in spec.layers:
        li = LAYERS.index(layer)
        mu_layer, alpha_layer = TABLE_1[layer]
        for s in range(1, spec.n_samples + 1):
            name = f"{layer}{s}"
            z = np.clip(_rng(spec.seed, _MATERIAL, li, s).standard_normal(2),
                        -sc.clip_sigma, sc.clip_sigma)
            mu = mu_layer * math.exp(sc.mu_cv * z[0] - 0.5 * sc.mu_cv**2)
            alpha = alpha_layer * (1.0 + sc.alpha_cv * z[1])
            fmt = _rng(spec.seed, _FORMAT, li, s)
            filename_only = bool(fmt.random() < spec.filename_only_probability)
            zg = np.clip(_rng(spec.seed, _GEOMETRY, li, s).standard_normal(2),
                         -sc.clip_sigma, sc.clip_sigma)
            if filename_only:
                diameter, height, source = NOMINAL_DIAMETER_MM, NOMINAL_HEIGHT_MM, "nominal"
            else:
                step = sc.geometry_round_mm
                diameter = round(NOMINAL_DIAMETER_MM * (1 + sc.diameter_cv * zg[0]) / step)
                height = round(NOMINAL_HEIGHT_MM * (1 + sc.height_cv * zg[1]) / step)
                diameter, height = round(diameter * step, 6), round(height * step, 6)
                source = "measured"
            order = _rng(spec.seed, _ORDER, li, s).permutation(len(spec.rates))
            test_rates = tuple(spec.rates[i] for i in order)
            sample = SamplePlan(layer, name, mu, alpha, diameter, height, source, test_rates,
                                filename_only)
            samples.append(sample)
            for test, rate in enumerate(test_rates, start=1):
                meta = CycleMeta(layer=layer, sample=name, test=test, rate_mm_per_s=rate,
                                 diameter_mm=diameter, height_mm=height)
                variant = draw_variant(_rng(spec.seed, _FORMAT, li, s, test),
                                       metadata="filename" if filename_only else None)
                prog = _rng(spec.seed, _PROGRAMME, li, s, test)
                pr = spec.programme
                preroll = float(prog.uniform(*pr.preroll_s))
                approach = float(prog.uniform(*pr.approach_mm))
                hold = float(prog.uniform(*pr.hold_s)) if prog.random() < pr.hold_probability \
                    else 0.0
                retract = approach * float(prog.uniform(*pr.retract_fraction))
                law = scenario.law(mu, alpha, test, spec.magnitude)
                path = f"{layer}/{cycle_file_name(meta, variant.name_style)}"
                cycles.append(CyclePlan(meta, law, variant, path, preroll, approach, hold,
                                        retract, (li, s, test)))
    return samples, cycles


# ---------------------------------------------------------------------- physics
def _simulate_curve(material: Ogden, meta: CycleMeta, law: CycleLaw, mesh_size, rate: float,
                    axial_ratio: float):
    """Loading curve (sample compression u in mm, force in N) of one solver run."""
    test = CompressionTest(diameter_mm=meta.diameter_mm, height_mm=meta.height_mm,
                           strain=STRAIN, rate_mm_per_s=rate, platen=law.platen,
                           friction=law.friction, ramp="constant")
    mesh = axisymmetric_cylinder(meta.diameter_mm, meta.height_mm, n_radial=mesh_size[0],
                                 n_axial=mesh_size[1], axial_ratio=axial_ratio)
    result = simulate(material, test, mesh=mesh, n_out=N_OUT)
    return np.asarray(result.displacement_mm, float), np.asarray(result.force_N, float)


def _felupe_curve(material: Ogden, meta: CycleMeta, law: CycleLaw):
    """Loading curve (sample compression u in mm, force in N) of one FElupe solve."""
    from .felupe_reference import compression_curve

    result = compression_curve(list(material.mu_Pa), list(material.alpha), material.nu,
                               meta.diameter_mm, meta.height_mm, strain=STRAIN + 0.01,
                               platen=law.platen, n_radial=FELUPE_MESH[0],
                               n_axial=FELUPE_MESH[1], n_increments=FELUPE_INCREMENTS)
    return (np.asarray(result["displacement_mm"], float),
            np.asarray(result["force_N"], float))


class _CurveCache:
    """Solver runs of one campaign, reusing hyperelastic runs across tests and moduli.

    A hyperelastic run does not depend on the platen speed (the solver removes inertia) and
    its force is proportional to the modulus at fixed exponents, ratios and Poisson's ratio
    (``solver.explicit``), so it is stored per unit modulus.
    """

    def __init__(self, progress: Callable[[str], None] | None = None,
                 truth_code: str = "solver", axial_ratio: float = 3.0):
        self.truth_code = truth_code
        self.axial_ratio = axial_ratio
        self._store: dict = {}
        self.n_runs = 0
        self.wall_s = 0.0
        self._progress = progress

    def curve(self, material: Ogden, meta: CycleMeta, law: CycleLaw, mesh_size,
              rate: float) -> tuple[np.ndarray, np.ndarray]:
        mu0 = material.mu0_Pa
        geometry = (meta.diameter_mm, meta.height_mm, law.platen, law.friction,
                    tuple(mesh_size))
        if material.prony is None:
            ratios = tuple(m / mu0 for m in material.mu_Pa)
            key = ("elastic", ratios, material.alpha, material.nu, geometry)
            scale = mu0
        else:
            key = ("viscoelastic", material, rate, geometry)
            scale = 1.0
        if key not in self._store:
            start = time.perf_counter()
            if material.prony is None:
                unit = dataclasses.replace(material, mu_Pa=tuple(m / mu0 for m in
                                                                  material.mu_Pa))
                if self.truth_code == "felupe":
                    u, f = _felupe_curve(unit, meta, law)
                else:
                    u, f = _simulate_curve(unit, meta, law, mesh_size, rate,
                                           self.axial_ratio)
            else:
                u, f = _simulate_curve(material, meta, law, mesh_size, rate, self.axial_ratio)
            self.wall_s += time.perf_counter() - start
            self.n_runs += 1
            self._store[key] = (u, f)
            if self._progress:
                size = FELUPE_MESH if self.truth_code == "felupe" else mesh_size
                self._progress(f"  {self.truth_code} run {self.n_runs}: {meta.sample} "
                               f"({key[0]}, {size[0]}x{size[1]}) in "
                               f"{time.perf_counter() - start:.2f} s")
        u, f = self._store[key]
        return u, f * scale


def _toe(s: np.ndarray, offset_mm: float) -> np.ndarray:
    """Full-face compression h(s) after travel s from the first touch (contact_offset)."""
    if offset_mm <= 0.0:
        return s
    return np.where(s < 2.0 * offset_mm, s * s / (4.0 * offset_mm), s - offset_mm)


def loading_curve(u_mm, force_N, law: CycleLaw, peak_travel_mm: float,
                  n: int = 2001) -> tuple[np.ndarray, np.ndarray]:
    """Loading force against logged platen travel from the first touch.

    Parameters
    ----------
    u_mm, force_N : ndarray, shape (m,)
        Simulated curve: sample compression (mm, from 0) and force (N).
    law : CycleLaw
        Supplies the contact offset and the series compliance.
    peak_travel_mm : float
        Logged travel from the first touch at which the rig stops (mm).
    n : int
        Points of the dense result.

    Returns
    -------
    travel_mm, force_N : ndarray, shape (n,)
        Increasing logged travel from 0 to ``peak_travel_mm`` and the force there.

    Notes
    -----
    With offset :math:`\\delta` and compliance :math:`c`: the platen surface travel :math:`s`
    compresses the full face by :math:`h(s)`, the force is :math:`F_\\mathrm{sim}(h(s))`
    (PCHIP in the simulated travel, monotone), and the logged travel is :math:`s + c F`.
    """
    u_mm = np.asarray(u_mm, float)
    force_N = np.asarray(force_N, float)
    if u_mm[-1] < peak_travel_mm * (1 - 1e-9) - law.contact_offset_mm:
        raise ValueError(f"simulated travel {u_mm[-1]:.4f} mm does not reach the "
                         f"{peak_travel_mm:.4f} mm the rig travels")
    sim = PchipInterpolator(u_mm, force_N, extrapolate=False)
    s = np.linspace(0.0, peak_travel_mm, n)
    h = np.clip(_toe(s, law.contact_offset_mm), 0.0, u_mm[-1])
    f = sim(h)
    x = s + law.compliance_mm_per_N * f
    if law.compliance_mm_per_N > 0:
        if np.any(np.diff(x) <= 0):
            raise ValueError("logged travel is not increasing along the loading curve")
        s_end = np.interp(peak_travel_mm, x, s)
        s = np.linspace(0.0, s_end, n)
        h = np.clip(_toe(s, law.contact_offset_mm), 0.0, u_mm[-1])
        f = sim(h)
        x = s + law.compliance_mm_per_N * f
        x[-1] = peak_travel_mm
    return x, f


@dataclasses.dataclass(frozen=True)
class _Timeline:
    """Platen programme of one cycle in time (s) and travel from logging start (mm)."""

    rate: float
    preroll_s: float
    approach_mm: float
    peak_travel_mm: float
    hold_s: float
    retract_mm: float

    @property
    def t_touch(self) -> float:
        return self.preroll_s + self.approach_mm / self.rate

    @property
    def t_peak(self) -> float:
        return self.t_touch + self.peak_travel_mm / self.rate

    @property
    def t_unload(self) -> float:
        return self.t_peak + self.hold_s

    @property
    def t_end(self) -> float:
        return self.t_unload + (self.peak_travel_mm + self.retract_mm) / self.rate

    def travel(self, t: np.ndarray) -> np.ndarray:
        """Platen travel from the start of logging (mm, compression positive)."""
        v = self.rate
        p = v * np.clip(t - self.preroll_s, 0.0, None)
        top = self.approach_mm + self.peak_travel_mm
        p = np.minimum(p, top)
        down = t > self.t_unload
        p[down] = top - v * (t[down] - self.t_unload)
        return p


def _cycle_force(tl: _Timeline, t: np.ndarray, x_load, f_load, x_ref, f_ref, law: CycleLaw,
                 hysteresis: float) -> np.ndarray:
    """True platen force at times t: loading curve, hold relaxation, approximate unloading."""
    p = tl.travel(t)
    x = p - tl.approach_mm  # travel from the first touch
    f = np.zeros_like(t)
    loading = (t <= tl.t_peak) & (x > 0)
    f[loading] = np.interp(x[loading], x_load, f_load)
    f_peak = float(f_load[-1])
    ref_peak = float(f_ref[-1])
    tau = law.material.prony.tau_s[0] if law.viscoelastic else None

    def relaxed(dt):
        if tau is None:
            return np.full_like(dt, f_peak)
        return ref_peak + (f_peak - ref_peak) * np.exp(-dt / tau)

    holding = (t > tl.t_peak) & (t <= tl.t_unload)
    f[holding] = relaxed(t[holding] - tl.t_peak)
    f_end = float(relaxed(np.array([tl.hold_s]))[0])
    unloading = (t > tl.t_unload) & (x > 0)
    xu = x[unloading]
    shape = np.interp(xu, x_ref, f_ref) / ref_peak
    f[unloading] = np.clip(f_end * shape * (1.0 - hysteresis * (1.0 - xu / x_load[-1])),
                           0.0, None)
    return f


# ---------------------------------------------------------------------- campaign
@dataclasses.dataclass(frozen=True)
class GenerationSummary:
    """What :func:`generate_campaign` wrote."""

    out: str
    scenario: str
    effect: str
    magnitude: float
    seed: int
    layers: tuple[str, ...]
    n_cycles: int
    n_files: int
    n_bytes: int
    n_simulations: int
    mesh: tuple[int, int]
    simulate_wall_s: float
    wall_s: float
    truth: str
    #: the code that made the curves (:attr:`CampaignSpec.truth_code`) on ``mesh``
    truth_code: str = "solver"

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        out = dataclasses.asdict(self)
        out["layers"] = list(self.layers)
        out["mesh"] = list(self.mesh)
        return out


def _sample_curves(spec: CampaignSpec, cache: _CurveCache, plan: CyclePlan):
    """Loading curve of a cycle and its long-term reference (for hold and unloading)."""
    law, meta = plan.law, plan.meta
    peak = plan.peak_travel_mm
    u, f = cache.curve(law.material, meta, law, spec.mesh_size, meta.rate_mm_per_s)
    x_load, f_load = loading_curve(u, f, law, peak)
    if law.viscoelastic:
        lt = dataclasses.replace(law.material, prony=None)
        u_r, f_r = cache.curve(lt, meta, law, FAST_MESH, meta.rate_mm_per_s)
        x_ref, f_ref = loading_curve(u_r, f_r, law, peak)
    else:
        x_ref, f_ref = x_load, f_load
    return x_load, f_load, x_ref, f_ref


def _check_target(out: Path, overwrite: bool) -> None:
    """Refuse a target folder that is in the way (checked before and after the work)."""
    if not out.exists():
        return
    if not out.is_dir():
        raise FileExistsError(f"{out} exists and is not a folder")
    if any(out.iterdir()):
        if not overwrite:
            raise FileExistsError(f"{out} is not empty; choose a new folder, or overwrite an "
                                  "earlier generated campaign")
        if not (out / "truth.json").is_file():
            raise FileExistsError(f"{out} is not empty and has no truth.json, so it is not a "
                                  "generated campaign; refusing to replace it")


def _safe_replace_dir(tmp: Path, out: Path, overwrite: bool) -> None:
    """Move the finished campaign ``tmp`` to ``out`` (replacing an old campaign if allowed)."""
    _check_target(out, overwrite)
    if out.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
        os.replace(out, old / out.name)
        os.replace(tmp, out)
        shutil.rmtree(old)
    else:
        os.replace(tmp, out)


def generate_campaign(out: str | os.PathLike, spec: CampaignSpec | None = None, *,
                      overwrite: bool = False,
                      progress: Callable[[str], None] | None = None,
                      **spec_kwargs) -> GenerationSummary:
    """Write a synthetic campaign and its truth to the folder ``out``.

    Parameters
    ----------
    out : path
        Target folder; it must not exist or be empty, unless ``overwrite`` and it holds an
        earlier generated campaign (a ``truth.json``). The campaign is built in a temporary
        sibling folder and moved into place when complete.
    spec : CampaignSpec, optional
        The campaign; or give its fields as keyword arguments
        (``scenario=``, ``seed=``, ``magnitude=``, ``layers=``, ``fast=``, ...).
    overwrite : bool
    progress : callable, optional
        Called with one-line progress messages.

    Returns
    -------
    GenerationSummary

    Raises
    ------
    ValueError
        Bad specification (unknown scenario or layer, negative magnitude, ...).
    FileExistsError
        ``out`` is in the way.
    solver.SolverInstability
        A forward run failed.
    """
    if spec is None:
        spec = CampaignSpec(**spec_kwargs)
    elif spec_kwargs:
        spec = dataclasses.replace(spec, **spec_kwargs)
    out = Path(out)
    _check_target(out, overwrite)
    start = time.perf_counter()
    say = progress or (lambda message: None)
    scenario = get_scenario(spec.scenario)
    samples, cycles = plan_campaign(spec)
    say(f"generating {len(cycles)} cycles: scenario {spec.scenario} (M = {spec.magnitude:g}), "
        f"seed {spec.seed}, layers {','.join(spec.layers)}, "
        + (f"mesh {spec.mesh_size[0]}x{spec.mesh_size[1]}" if spec.truth_code == "solver" else
           f"FElupe {FELUPE_MESH[0]}x{FELUPE_MESH[1]} quadratic"))
    cache = _CurveCache(progress, spec.truth_code, spec.axial_ratio)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    try:
        n_bytes = 0
        manifests: dict[str, list] = {}
        cycle_truth = []
        for plan in cycles:
            meta, law = plan.meta, plan.law
            x_load, f_load, x_ref, f_ref = _sample_curves(spec, cache, plan)
            tl = _Timeline(meta.rate_mm_per_s, plan.preroll_s, plan.approach_mm,
                           plan.peak_travel_mm, plan.hold_s, plan.retract_mm)
            rng = _rng(spec.seed, _NOISE, *plan.key)
            rate_hz = spec.sensor.sample_rate_hz(meta.rate_mm_per_s)
            true_s, logged_s, info = spec.sensor.sample_instants(tl.t_end, rate_hz, rng)
            travel = tl.travel(true_s)
            force = _cycle_force(tl, true_s, x_load, f_load, x_ref, f_ref, law,
                                 spec.programme.hysteresis)
            rec = spec.sensor.record(true_s, logged_s, travel, force, rng, info)
            text = format_cycle(meta, rec.time_s, rec.displacement_mm, rec.force_N,
                                plan.variant)
            target = tmp / plan.path
            target.parent.mkdir(parents=True, exist_ok=True)
            data = text.encode("utf-8")
            target.write_bytes(data)
            n_bytes += len(data)
            if plan.variant.in_manifest:
                manifests.setdefault(meta.layer, []).append((Path(plan.path).name, meta))
            keep = np.unique(np.round(np.linspace(0, len(x_load) - 1, 121)).astype(int))
            cycle_truth.append({
                "file": plan.path, "layer": meta.layer, "sample": meta.sample,
                "test": meta.test, "rate_mm_per_s": meta.rate_mm_per_s,
                "diameter_mm": meta.diameter_mm, "height_mm": meta.height_mm,
                **law.to_dict(),
                "programme": {"preroll_s": plan.preroll_s, "approach_mm": plan.approach_mm,
                              "hold_s": plan.hold_s, "retract_mm": plan.retract_mm,
                              "touch_time_s": tl.t_touch, "peak_time_s": tl.t_peak,
                              "end_time_s": tl.t_end},
                "first_touch_mm": plan.approach_mm,
                "contact_mm": plan.approach_mm + law.contact_offset_mm,
                "peak_travel_from_touch_mm": plan.peak_travel_mm,
                "peak_force_N": float(f_load[-1]),
                "sensor": {"tare_N": rec.info["tare_N"], "rate_hz": rate_hz,
                           "n_samples": rec.info["n_samples"],
                           "n_repeated_timestamps": rec.info["n_repeated"],
                           "gaps": rec.info["gaps"],
                           "saturated_samples": rec.info["saturated_samples"]},
                "variant": plan.variant.to_dict(),
                "curve": {"note": "noise-free loading force against logged platen travel "
                                  "from the first touch (compression positive); subtract "
                                  "contact_offset_mm for travel from full contact",
                          "travel_mm": x_load[keep].tolist(),
                          "force_N": f_load[keep].tolist()},
            })
            say(f"  wrote {plan.path} ({len(rec.time_s)} rows)")
        for layer, rows in manifests.items():
            (tmp / layer / "manifest.csv").write_text(manifest_text(rows), encoding="utf-8")
        truth = {
            "about": "Truth of a synthetic campaign written by experiments.generator; for "
                     "tests and benchmarks only, never read by the calibration pipeline.",
            "scenario": scenario.to_dict(spec.magnitude),
            "spec": spec.to_dict(),
            "table_1": {k: {"mu_Pa": v[0], "alpha": v[1]} for k, v in TABLE_1.items()
                        if k in spec.layers},
            "samples": {s.sample: s.to_dict() for s in samples},
            "cycles": cycle_truth,
            "conventions": {
                "mu": "small-strain shear modulus, W = sum 2 mu_i/alpha_i^2 (...); long-term "
                      "modulus where a Prony series is given",
                "frame": "compression positive; travel in mm from the start of logging "
                         "(first_touch_mm, contact_mm) or from the first touch (curve)",
                "unloading": "approximate (scaled loading curve with a 5 % loop)",
            },
        }
        (tmp / "truth.json").write_text(json.dumps(truth, indent=1), encoding="utf-8")
        _safe_replace_dir(tmp, out, overwrite)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    wall = time.perf_counter() - start
    say(f"done: {len(cycles)} cycles, {cache.n_runs} {CODE_NAMES[spec.truth_code]} runs "
        f"({cache.wall_s:.1f} s), {n_bytes / 1e6:.2f} MB in {wall:.1f} s")
    return GenerationSummary(
        out=str(out), scenario=spec.scenario, effect=scenario.effect,
        magnitude=float(spec.magnitude), seed=spec.seed, layers=spec.layers,
        n_cycles=len(cycles), n_files=len(cycles) + len(manifests), n_bytes=n_bytes,
        n_simulations=cache.n_runs, mesh=spec.curve_mesh, simulate_wall_s=cache.wall_s,
        wall_s=wall, truth=str(out / "truth.json"),
        truth_code=spec.truth_code)


def generate_embedded(out: str | os.PathLike = EMBEDDED_DIR,
                      progress: Callable[[str], None] | None = None) -> GenerationSummary:
    """Regenerate the embedded campaign (``rate_dependence``, M = 1, seed 2016, fine mesh)."""
    return generate_campaign(out, CampaignSpec(scenario="rate_dependence", magnitude=1.0,
                                               seed=EMBEDDED_SEED),
                             overwrite=True, progress=progress)


def main(argv: list[str] | None = None) -> int:
    """``python -m experiments.generator``: the embedded campaign or any scenario."""
    parser = argparse.ArgumentParser(
        prog="python -m experiments.generator",
        description="Write a synthetic rig campaign (see also `calib generate`).")
    parser.add_argument("--embedded", action="store_true",
                        help=f"regenerate the embedded campaign in {EMBEDDED_DIR}")
    parser.add_argument("--scenario", default="clean")
    parser.add_argument("--out")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--magnitude", type=float, default=1.0)
    parser.add_argument("--layers")
    parser.add_argument("--fast", action="store_true")
    parser.add_argument("--truth-code", choices=TRUTH_CODES, default="solver",
                        help="the code that makes the curves (felupe: independent, static)")
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args(argv)

    def say(message):
        print(message, file=sys.stderr, flush=True)

    if args.embedded:
        summary = generate_embedded(progress=say)
    else:
        if not args.out:
            parser.error("--out is required unless --embedded")
        summary = generate_campaign(args.out, scenario=args.scenario, seed=args.seed,
                                    magnitude=args.magnitude, layers=args.layers,
                                    fast=args.fast, truth_code=args.truth_code,
                                    overwrite=args.overwrite, progress=say)
    print(json.dumps(summary.to_dict()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
