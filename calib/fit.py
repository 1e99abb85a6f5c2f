r"""FE-coupled Ogden fit per layer.

Find mu and alpha such that the explicit simulation of the bonded compression reproduces the
measured cycles.

The objective
-------------
Every cycle of a layer is compared with *its own* simulation (its sample's diameter and height)
at a set of strain levels along the loading branch (default 2, 4, ..., 30 %). The measured
force at a level is a local linear regression of the branch within +-0.5 % strain, which
averages the load-cell noise without biasing a smooth curve. Residuals are in newtons
(``residual="relative"``: fractions of the measured force). The measured travel starts where
the loader's contact fit put the contact, which on a smooth stiffening curve is a few
micrometres after the touch; ``contact_fit=True`` reads each simulation through the same fit,
so that both travels start alike (off by default, see :class:`FitSettings`).

The weights come from the measured scatter. Samples of one layer differ (a few percent in
stiffness), and a sample that is stiffer is stiffer at every level and in every test, so the
residuals of one sample are correlated: treating thousands of points, or even every level, as
independent makes the fit look far more certain than it is. The noise model is multiplicative
with random effects,

.. math::

    F_{ci} = \hat F_{ci}\,(1 + b_{s(c)} + a_c + e_{ci}) + n_{ci}, \qquad
    b \sim (0, s_b^2),\ a \sim (0, s_a^2),\ e \sim (0, s_e^2),

(sample, cycle and level effects; :math:`n` the measurement noise of the level regression),
whose variances are estimated by moments from a first, simply weighted fit. The second fit is
generalised least squares: residuals are whitened per sample with the Cholesky factor of this
covariance, so lmfit's standard errors, correlations, profile intervals and AIC/BIC see the
information the data really hold.

Speed through structure
-----------------------
- With Poisson's ratio fixed the force is exactly proportional to mu
  (:func:`solver.simulate`): for a trial alpha the best mu is a closed form (variable
  projection), so the search is one-dimensional in alpha.
- Cycles of the same sample share a geometry and, the material being rate-independent here,
  one forward solve. Solves are cached.
- The unit response is interpolated in alpha by local cubic splines through solves on a fixed
  grid of alpha (step 0.5): smooth in alpha, so finite-difference Jacobians (steps of 1 % of the
  value, far above the solver's noise floor of ~3e-5 relative per 0.001 in alpha) and profile
  likelihoods are cheap and clean. The surrogate is checked against direct solves at the
  optimum and the check is reported (``surrogate_error``).
- Layers are independent and fitted in parallel through :mod:`calib.parallel`.

Why FE-coupled
--------------
The fit of the homogeneous closed form (uniaxial Ogden stress times the undeformed area), the
route users would take instead, is reported beside the FE-coupled one: it misreads the stiffening
of the bonded platens as material nonlinearity and biases mu and alpha by tens of percent.

Identifiability
---------------
Ogden fits are often non-unique (Ogden, Saccomandi & Sgura 2004): over 30 % compression mu and
alpha trade off. A warning is raised where the correlation exceeds 0.95 in magnitude or alpha's
relative standard error exceeds 25 %. An alpha on a bound of the search (``FitSettings.
alpha_bounds``) is reported with a warning and no standard error or interval: it is the box's
value, not an estimate.

References
----------
Golub G, Pereyra V (2003). Separable nonlinear least squares: the variable projection method
and its applications. Inverse Problems 19:R1-R26. doi:10.1088/0266-5611/19/2/201

Ogden RW, Saccomandi G, Sgura I (2004). Fitting hyperelastic models to experimental data.
Comput Mech 34:484-502. doi:10.1007/s00466-004-0593-y
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterable, Sequence

import numpy as np
from scipy import interpolate, linalg, optimize

from solver import (
    CompressionTest,
    Ogden,
    Prony,
    SolverInstability,
    axisymmetric_cylinder,
    simulate,
)

__all__ = [
    "DEFAULT_LEVELS",
    "FitError",
    "FitSettings",
    "ForwardModel",
    "CurveKey",
    "LayerData",
    "LayerFit",
    "CampaignFit",
    "NoiseModel",
    "OgdenUnitResponse",
    "layer_data",
    "homogeneous_fit",
    "fit_layer",
    "fit_campaign",
]

#: Strain levels at which cycles and simulations are compared (fraction).
DEFAULT_LEVELS = tuple(round(0.02 * k, 4) for k in range(1, 16))
#: Half width of the local regression at each level (strain).
LEVEL_HALF_WIDTH = 0.005
#: A level counts as reached if the branch comes within this strain of it.
REACH_TOLERANCE = 0.002
#: Points needed in a level's regression window.
MIN_LEVEL_POINTS = 6


class FitError(ValueError):
    """A layer that cannot be fitted, with the reason."""


@dataclasses.dataclass(frozen=True)
class FitSettings:
    """How a layer is fitted.

    Parameters
    ----------
    levels : tuple of float
        Strain levels of the comparison (fractions).
    nu : float
        Poisson's ratio assumed (fixed).
    platen : str
        Platen condition of the simulation (``bonded`` for the sandpaper rig).
    residual : {"absolute", "relative"}
        Residuals in newtons, or as fractions of the measured force.
    mesh_scale : float
        Mesh density relative to the solver's default mesh.
    axial_ratio : float
        Largest over smallest element height of the fitting mesh and of its correction mesh
        (:func:`solver.mesh.axisymmetric_cylinder`; cells shrink towards both platens).
        Where the bulging side folds onto the platens (beyond about 22 % strain) the default
        3 puts node-by-node bumps into the curves. With Coulomb platens (friction 0.15) the
        fitting mesh's force departs from FElupe's (12 x 12 cells) by up to 2.8 % at 3 and
        0.97 % at 10 (at 25.5 %, where the first side node lands, at every grading; beyond
        27.5 %: 2.8 against 0.44 %), and from the 24 x 30 generating mesh's by 2.1 and 0.5 %.
        Bonded curves move by up to 0.7 % (at 24 %) from 3 to 10, and the 14 x 18 and 24 x
        30 meshes then differ by a smooth 0.2-0.4 % instead of -0.5 to +0.4 %. A grading of
        10 about doubles the time steps (a Coulomb solve takes 2.3 s instead of 1.3 s).
    mesh_correction : float or None
        Mesh scale of the discretisation correction: the unit responses are multiplied by the
        ratio of a solve on this finer mesh to one on the fitting mesh, at the layer's median
        geometry and the force's alpha (one finer solve per alpha node the fit reaches).
        ``None`` switches it off.
    alpha_step : float
        Node spacing of the alpha surrogate.
    alpha_bounds : tuple of float
        Bounds of alpha in the fit.
    profile : bool
        Compute profile confidence intervals (lmfit ``conf_interval``).
    contact_fit : bool
        Read every simulation through the loader's contact fit: the measured travel starts
        where that fit put the contact (:func:`calib.loaders.contact_fit_bias`), so the
        simulated force at a measured travel ``d`` is taken at ``d`` plus the same fit's
        offset on the simulated curve; ``False`` compares the base model at ``d``. On a smooth
        stiffening curve the fit puts the contact a few micrometres late (3.6 um for the
        default sample at alpha 5, 6 um at alpha 2.5), and noise and coarse sampling move it
        by as much again, growing with the rate (1.0, 3.1, 5.7 um late at 0.17, 0.83, 6 mm/s
        on the generated compliance campaign), which no reading of a noise-free curve models.
        A round trip of fitting-mesh solves through the loader recovers mu and alpha to 1e-4
        with it (0.23 % and 0.5 % off without), but it is off by default: the weakly
        identified effects of the discrepancy workflow moved away from their truths with it
        (series compliance 0.117 mm/N against 0.153 without, truth 0.15; nu 0.443 against
        0.428, truth 0.42; on a campaign with a tenth of the sensor noise 0.111 and 0.461).
        What an effect changes in the reading is read either way (see
        :meth:`calib.discover.LayerContext.contact_shift`): a relaxing gel's stiff start puts
        the contact 50-70 um early at the slow rates.
    contact_noise : bool
        Give the discrepancy workflow's judging noise model a per-cycle scatter of the contact
        reading (:func:`calib.discover._structure_free_noise`): each cycle's curve shifted
        along its travel by an amount of a standard deviation estimated from the data (1-4 um
        on generated campaigns, whose loader contacts are 1-6 um off within a rate). Off by
        default: on the generated campaigns of layers A and D it recovered the relaxing gel's
        Prony term closer to its truth (g1 0.607, tau1 0.498 s against 0.611, 0.586 s; truth
        0.6, 0.5 s) and named the compressible gel alone, but moved the weakly identified
        effects away from theirs (nu 0.446 against 0.429, truth 0.42; series compliance 0.127
        mm/N against 0.153, truth 0.15), closed less of the travel offset's systematic gap
        (4.5 -> 3.2 % against 2.2 %) and named the spring's campaign a travel offset all the
        same (``experiments/results/confusion_contact_noise``).
    """

    levels: tuple[float, ...] = DEFAULT_LEVELS
    nu: float = 0.499
    platen: str = "bonded"
    residual: str = "absolute"
    mesh_scale: float = 1.0
    axial_ratio: float = 3.0
    mesh_correction: float | None = 2.0
    alpha_step: float = 0.5
    alpha_bounds: tuple[float, float] = (1.0, 25.0)
    profile: bool = True
    contact_fit: bool = False
    contact_noise: bool = False

    def __post_init__(self):
        if self.residual not in ("absolute", "relative"):
            raise ValueError(f"residual={self.residual!r} is not 'absolute' or 'relative'")
        levels = tuple(float(x) for x in self.levels)
        if not levels or min(levels) <= 0 or max(levels) >= 0.9 or sorted(levels) != list(levels):
            raise ValueError(f"levels={levels} must increase within (0, 0.9)")
        object.__setattr__(self, "levels", levels)
        if not (math.isfinite(self.axial_ratio) and self.axial_ratio >= 1.0):
            raise ValueError(f"axial_ratio={self.axial_ratio!r} must be a finite number >= 1 "
                             "(largest over smallest element height)")


# ============================================================================ forward model
@dataclasses.dataclass(frozen=True)
class CurveKey:
    """Everything one forward solve depends on, with the shear modulus set to 1 Pa.

    ``fractions`` are mu_i / sum(mu); ``rate_mm_per_s`` matters only with a Prony series
    (``None`` otherwise, so rate-independent cycles share a solve).
    """

    alpha: tuple[float, ...]
    diameter_mm: float
    height_mm: float
    fractions: tuple[float, ...] = (1.0,)
    nu: float = 0.499
    platen: str = "bonded"
    friction: float = 0.0
    g: tuple[float, ...] = ()
    tau_s: tuple[float, ...] = ()
    rate_mm_per_s: float | None = None

    @property
    def viscoelastic(self) -> bool:
        """Whether the material relaxes (then the real test rate matters)."""
        return bool(self.g)


class ForwardModel:
    """Unit force-travel curves (N per Pa of mu) from the explicit solver, cached.

    Parameters
    ----------
    mesh_scale : float
        Mesh density relative to the default (14 x 18 graded quads).
    axial_ratio : float
        Largest over smallest element height (see :class:`FitSettings`).
    strain_max : float
        Travel of each solve as a fraction of the height; a little beyond 30 % so that the
        last comparison level is not the instant a constant-speed platen stops.
    n_out : int
        Output points along the ramp.
    strain_needed : float
        Largest strain any comparison needs: a solve that goes unstable beyond it is repeated
        to just before the instability; one that fails earlier raises
        :class:`solver.SolverInstability`.
    use_stored : bool
        Read a solve stored with the package (:mod:`calib.stored`) instead of solving it.
    """

    def __init__(self, mesh_scale: float = 1.0, strain_max: float = 0.31, n_out: int = 63,
                 strain_needed: float = 0.30, axial_ratio: float = 3.0,
                 use_stored: bool = True):
        self.mesh_scale = mesh_scale
        self.axial_ratio = axial_ratio
        self.strain_max = strain_max
        self.strain_needed = strain_needed
        self.n_out = n_out
        self._cache: dict[tuple, interpolate.CubicSpline] = {}
        self.use_stored = use_stored
        self.n_solves = 0
        self.n_stored = 0
        self.solve_s = 0.0

    def curve(self, key: CurveKey, mesh_scale: float | None = None) -> interpolate.CubicSpline:
        """Spline of the unit force (N/Pa) against travel (mm) of one solve.

        ``mesh_scale`` overrides the model's mesh density for this solve.
        """
        scale = self.mesh_scale if mesh_scale is None else mesh_scale
        spline = self._cache.get((key, scale))
        if spline is None and self.use_stored:
            from .stored import stored_solves

            stored = stored_solves().lookup(key, scale, self)
            if stored is not None:
                self.n_stored += 1
                spline = interpolate.CubicSpline(*stored)
                self._cache[(key, scale)] = spline
        if spline is None:
            material = Ogden(mu_Pa=key.fractions, alpha=key.alpha, nu=key.nu,
                             prony=Prony(g=key.g, tau_s=key.tau_s) if key.g else None)
            test = CompressionTest(
                diameter_mm=key.diameter_mm, height_mm=key.height_mm, strain=self.strain_max,
                rate_mm_per_s=key.rate_mm_per_s or 1.0, platen=key.platen,
                friction=key.friction, ramp="constant" if key.viscoelastic else "345")
            mesh = axisymmetric_cylinder(key.diameter_mm, key.height_mm,
                                         round(14 * scale), round(18 * scale),
                                         axial_ratio=self.axial_ratio)
            start = time.perf_counter()
            try:
                result = simulate(material, test, mesh, n_out=self.n_out)
            except SolverInstability as exc:
                # a run that stops beyond the last level is still good up to there
                reached = exc.travel_mm / key.height_mm - 0.002
                if reached < self.strain_needed:
                    raise
                test = dataclasses.replace(test, strain=reached)
                result = simulate(material, test, mesh, n_out=self.n_out)
            self.solve_s += time.perf_counter() - start
            self.n_solves += 1
            spline = interpolate.CubicSpline(result.displacement_mm, result.force_N)
            self._cache[(key, scale)] = spline
        return spline

    @classmethod
    def for_settings(cls, settings: FitSettings) -> ForwardModel:
        """The forward model of a fit's settings (mesh density and grading)."""
        return cls(mesh_scale=settings.mesh_scale, axial_ratio=settings.axial_ratio)

    def unit_forces(self, key: CurveKey, travel_mm) -> np.ndarray:
        """Unit forces (N/Pa) of one solve at the given travels (mm)."""
        return self.curve(key)(np.asarray(travel_mm, dtype=float))


# ============================================================================ data
@dataclasses.dataclass(frozen=True)
class CycleInfo:
    """The metadata of a cycle the fit needs."""

    file: str
    sample: str
    test: int
    rate_mm_per_s: float
    diameter_mm: float
    height_mm: float

    @property
    def area_m2(self) -> float:
        """Undeformed cross-section (m^2)."""
        return math.pi * (0.5e-3 * self.diameter_mm) ** 2


@dataclasses.dataclass(frozen=True)
class LayerData:
    """One layer's cycles at the comparison levels.

    Attributes
    ----------
    force : ndarray, shape (n_cycles, n_levels)
        Measured force (N) at each level; NaN where the cycle does not reach it.
    noise : ndarray, shape (n_cycles, n_levels)
        Standard error of that force from its local regression (N).
    """

    layer: str
    cycles: tuple[CycleInfo, ...]
    levels: np.ndarray
    force: np.ndarray
    noise: np.ndarray
    warnings: tuple[str, ...] = ()

    @property
    def valid(self) -> np.ndarray:
        """Mask of the compared points, shape (n_cycles, n_levels)."""
        return np.isfinite(self.force)

    @property
    def travel_mm(self) -> np.ndarray:
        """Platen travel of each level in each cycle (mm), shape (n_cycles, n_levels)."""
        return self.levels[None, :] * np.array([c.height_mm for c in self.cycles])[:, None]

    @property
    def samples(self) -> list[str]:
        """Sample names in order of first appearance."""
        return list(dict.fromkeys(c.sample for c in self.cycles))


def level_forces(strain, force, levels, half_width: float = LEVEL_HALF_WIDTH):
    """Force at each strain level by local linear regression of the branch.

    Parameters
    ----------
    strain, force : ndarray, shape (n,)
        Nominal strain (fraction) and force (N) of a loading branch.
    levels : ndarray, shape (n_levels,)
    half_width : float
        Half width of the regression window (strain).

    Returns
    -------
    value, stderr : ndarray, shape (n_levels,)
        Force (N) and its standard error (N), inflated for serially correlated noise; NaN
        where the branch does not reach the level (beyond ``REACH_TOLERANCE``) or the window
        holds fewer than ``MIN_LEVEL_POINTS`` points within three half widths.
    """
    strain = np.asarray(strain, float)
    force = np.asarray(force, float)
    ok = np.isfinite(strain) & np.isfinite(force)
    strain, force = strain[ok], force[ok]
    value = np.full(len(levels), np.nan)
    stderr = np.full(len(levels), np.nan)
    if len(strain) < MIN_LEVEL_POINTS:
        return value, stderr
    peak = strain.max()
    for k, level in enumerate(levels):
        if level > peak + REACH_TOLERANCE:
            continue
        distance = np.abs(strain - level)
        sel = distance <= half_width
        if sel.sum() < MIN_LEVEL_POINTS:
            # sparse sampling (fast tests) or a level at the end of the branch: the nearest
            # points, within three half widths
            nearest = np.argsort(distance)[:MIN_LEVEL_POINTS]
            if distance[nearest].max() > 3 * half_width:
                continue
            sel = np.zeros(len(strain), dtype=bool)
            sel[nearest] = True
        x = strain[sel] - level
        y = force[sel]
        A = np.column_stack([np.ones_like(x), x])
        coef, *_ = np.linalg.lstsq(A, y, rcond=None)
        resid = y - A @ coef
        n = len(y)
        rho = 0.0
        if n > 3 and np.var(resid) > 0:
            rho = float(np.clip(np.corrcoef(resid[:-1], resid[1:])[0, 1], 0.0, 0.95))
        n_eff = n * (1 - rho) / (1 + rho)
        sd = math.sqrt(np.sum(resid**2) / max(n - 2, 1))
        value[k] = coef[0]
        stderr[k] = sd / math.sqrt(max(n_eff, 1.0))
    return value, stderr


def layer_data(cycles: Sequence, levels: Sequence[float] = DEFAULT_LEVELS) -> LayerData:
    """Collect a layer's cycles (``calib.loaders.Cycle``) at the comparison levels.

    Cycles that reach fewer than three levels are left out, cycles that stop short of the last
    level are compared up to where they reach; both are reported in ``warnings``.

    Raises
    ------
    FitError
        If the cycles belong to different layers, or fewer than two usable cycles remain.
    """
    cycles = list(cycles)
    if not cycles:
        raise FitError("no cycles to fit")
    layers = sorted({c.layer for c in cycles})
    if len(layers) != 1:
        raise FitError(f"cycles of several layers given together: {layers}")
    layer = layers[0]
    levels = np.asarray(levels, float)
    warnings = []
    infos, forces, noises = [], [], []
    for c in cycles:
        value, stderr = level_forces(c.strain, c.force_N, levels)
        reached = np.isfinite(value)
        if reached.sum() < 3:
            warnings.append(f"{c.file}: left out, it reaches only {reached.sum()} of the "
                            f"{len(levels)} comparison levels (peak strain {c.peak_strain:.3f})")
            continue
        if not reached[-1]:
            warnings.append(f"{c.file}: never reaches {levels[-1]:.0%} (peak strain "
                            f"{c.peak_strain:.3f}); compared up to {levels[reached][-1]:.0%}")
        infos.append(CycleInfo(c.file, c.sample, int(c.test), float(c.rate_mm_per_s),
                               float(c.diameter_mm), float(c.height_mm)))
        forces.append(value)
        noises.append(stderr)
    if len(infos) < 2:
        raise FitError(f"layer {layer}: {len(infos)} usable cycle(s); a layer fit needs at "
                       "least two (it estimates the scatter between cycles)")
    return LayerData(layer=layer, cycles=tuple(infos), levels=levels, force=np.array(forces),
                     noise=np.array(noises), warnings=tuple(warnings))


# ============================================================================ unit models
class OgdenUnitResponse:
    """Unit forces (N/Pa) of a layer's compared points as a smooth function of alpha.

    Solves on the fixed grid ``alpha = alpha_step * k`` for every sample geometry; between
    nodes the cubic through the four surrounding nodes (interpolation error ~1e-5 of the force
    for step 0.5, below the solver's own noise). :meth:`direct` solves at the exact alpha.

    Parameters
    ----------
    points : ndarray of bool, shape (n_cycles, n_levels), optional
        Which points to predict; default the compared (valid) points.
    """

    def __init__(self, forward: ForwardModel, data: LayerData, settings: FitSettings):
        self.forward = forward
        self.data = data
        self.settings = settings
        valid = data.valid
        self.travel = data.travel_mm[valid]
        self.cycle_of_point = np.repeat(np.arange(len(data.cycles)), valid.sum(axis=1))
        geometry = [(c.diameter_mm, c.height_mm) for c in data.cycles]
        self.groups: dict[tuple, np.ndarray] = {}
        for g in dict.fromkeys(geometry):
            cycles = [i for i, x in enumerate(geometry) if x == g]
            self.groups[g] = np.flatnonzero(np.isin(self.cycle_of_point, cycles))
        self.nodes: dict[int, np.ndarray] = {}
        self._splines: dict[int, interpolate.CubicSpline] = {}
        #: mesh scale of the discretisation correction (see :meth:`set_correction`)
        self.correction_scale: float | None = None
        #: finer over fitting mesh force at the levels, at the grid node ``alpha_step * k``
        self.ratio_nodes: dict[int, np.ndarray] = {}
        self._level = np.broadcast_to(data.levels, data.valid.shape)[valid]
        self._shifts: dict[CurveKey, float] = {}

    def key(self, alpha: float, geometry) -> CurveKey:
        """The forward solve of one geometry at ``alpha``."""
        return CurveKey(alpha=(float(alpha),), diameter_mm=geometry[0], height_mm=geometry[1],
                        nu=self.settings.nu, platen=self.settings.platen)

    def contact_shift(self, key: CurveKey) -> float:
        """Travel (mm) by which the loader's contact fit would start the solve's curve late.

        Zero unless ``settings.contact_fit``; see :func:`calib.loaders.contact_fit_bias` (the
        window ends at 10 % of the force at the last level).
        """
        if not self.settings.contact_fit:
            return 0.0
        shift = self._shifts.get(key)
        if shift is None:
            from .loaders import contact_fit_bias

            shift = contact_fit_bias(self.forward.curve(key),
                                     float(self.data.levels[-1]) * key.height_mm)
            self._shifts[key] = shift
        return shift

    def _raw(self, alpha: float) -> np.ndarray:
        out = np.empty(len(self.travel))
        for g, idx in self.groups.items():
            key = self.key(alpha, g)
            out[idx] = self.forward.unit_forces(key, self.travel[idx] + self.contact_shift(key))
        return out

    def direct(self, alpha: float) -> np.ndarray:
        """Unit forces from solves at exactly this alpha, shape (n_points,)."""
        return self._raw(alpha) * np.interp(self._level, self.data.levels,
                                            self.mesh_ratio_at(alpha))

    def node(self, k: int) -> np.ndarray:
        """Uncorrected unit forces at the grid node ``alpha_step * k`` (k >= 1)."""
        if k not in self.nodes:
            self.nodes[k] = self._raw(self.settings.alpha_step * k)
        return self.nodes[k]

    def ratio_node(self, k: int) -> np.ndarray:
        """The discretisation correction at the levels at node ``alpha_step * k``.

        Finer-mesh over fitting-mesh force of a solve at the layer's median geometry, shape
        (n_levels,); ones while no correction is set.
        """
        if self.correction_scale is None:
            return np.ones(len(self.data.levels))
        if k not in self.ratio_nodes:
            d = float(np.median([c.diameter_mm for c in self.data.cycles]))
            h = float(np.median([c.height_mm for c in self.data.cycles]))
            key = self.key(self.settings.alpha_step * k, (d, h))
            travel = self.data.levels * h
            self.ratio_nodes[k] = (self.forward.curve(key, self.correction_scale)(travel)
                                   / self.forward.curve(key)(travel))
        return self.ratio_nodes[k]

    def _first_node(self, alpha: float) -> int:
        return max(1, int(math.floor(alpha / self.settings.alpha_step)) - 1)

    def _local(self, alpha: float):
        step = self.settings.alpha_step
        first = self._first_node(alpha)
        spline = self._splines.get(first)
        if spline is None:
            ks = np.arange(first, first + 4)
            corrected = [self.node(int(k)) * np.interp(self._level, self.data.levels,
                                                       self.ratio_node(int(k))) for k in ks]
            spline = interpolate.CubicSpline(ks * step, np.array(corrected), axis=0)
            self._splines[first] = spline
        return spline

    def __call__(self, alpha: float) -> np.ndarray:
        """Unit forces interpolated at ``alpha``, shape (n_points,)."""
        return self._local(alpha)(alpha)

    def derivative(self, alpha: float) -> np.ndarray:
        """d(unit force)/d(alpha) of the interpolant, shape (n_points,)."""
        return self._local(alpha)(alpha, 1)

    def mesh_ratio_at(self, alpha: float) -> np.ndarray:
        """The discretisation correction at the levels at ``alpha``, shape (n_levels,).

        The cubic through the corrections at the four surrounding nodes, as the forces are
        interpolated.
        """
        if self.correction_scale is None:
            return np.ones(len(self.data.levels))
        first = self._first_node(alpha)
        ks = np.arange(first, first + 4)
        rows = np.array([self.ratio_node(int(k)) for k in ks])
        return interpolate.CubicSpline(ks * self.settings.alpha_step, rows, axis=0)(alpha)

    def set_correction(self, alpha: float, mesh_scale: float) -> np.ndarray:
        """Apply the discretisation correction; return it at the levels at ``alpha``.

        Every unit force is multiplied by the ratio of a solve on the finer mesh
        ``mesh_scale`` to one on the fitting mesh, at the layer's median geometry, as a
        function of strain and at the force's own alpha: the ratio is solved at the
        surrogate's nodes and interpolated as the forces are. Where the bulging side lands on
        the platens node by node (beyond about 20 %) the ratio has bumps that move along the
        strain with alpha: on the nominal sample it is 1.0024 at 25 % for alpha 4.8 and
        1.0054 for 5.9, so a correction taken at one alpha put up to 0.4 % of structure into
        every refit that moved alpha (a series spring's refit moves it by 2).
        """
        self.correction_scale = mesh_scale
        self._splines.clear()
        return self.mesh_ratio_at(alpha)


def _varpro_mu(U: np.ndarray, y: np.ndarray, W: np.ndarray) -> float:
    """Closed-form best scale mu for model mu * U against data y under whitening W."""
    a = W @ U
    return float(a @ (W @ y) / (a @ a))


def _search_alpha(cost: Callable[[float], float], step: float, guess: float,
                  bounds: tuple[float, float]) -> float:
    """Minimise a smooth unimodal cost of alpha.

    Walk the grid nodes downhill from ``guess`` until the minimum is bracketed, then Brent's
    method inside the bracket.
    """
    lo_k = max(1, int(math.ceil(bounds[0] / step)))
    hi_k = int(math.floor(bounds[1] / step))
    k = min(max(int(round(guess / step)), lo_k), hi_k)
    values = {}

    def at(kk):
        if kk not in values:
            values[kk] = cost(kk * step)
        return values[kk]

    while True:
        here = at(k)
        left = at(k - 1) if k > lo_k else math.inf
        right = at(k + 1) if k < hi_k else math.inf
        if left < here and left <= right:
            k -= 1
        elif right < here:
            k += 1
        else:
            break
    lo = max(bounds[0], (k - 1) * step)
    hi = min(bounds[1], (k + 1) * step)
    res = optimize.minimize_scalar(cost, bounds=(lo, hi), method="bounded",
                                   options={"xatol": 1e-3})
    return float(res.x) if res.fun <= here else k * step


# ============================================================================ noise model
@dataclasses.dataclass(frozen=True)
class NoiseModel:
    """Noise model of a layer's residuals (see the module notes).

    Attributes
    ----------
    sample_cov : ndarray, shape (2, 2)
        Covariance of the samples' (log mu, alpha) about the layer's values.
    cycle : float
        Relative standard deviation of a cycle's force scale within its sample.
    level : float
        Relative standard deviation of independent scatter between levels.
    contact_mm : float
        Standard deviation of a cycle's contact reading (mm): the loader's contact point
        moves by a few micrometres with noise and sampling, which shifts the whole curve
        along the travel, by most (relative to the force) at the first levels.
    """

    sample_cov: np.ndarray
    cycle: float
    level: float
    contact_mm: float = 0.0

    @classmethod
    def initial(cls) -> NoiseModel:
        """Independent 5 % scatter: the weights of the first fit."""
        return cls(np.zeros((2, 2)), 0.0, 0.05)

    @classmethod
    def from_sample_fits(cls, data: LayerData, fitted: np.ndarray, per_sample: dict,
                         warnings: list) -> NoiseModel:
        """Variance components from fits of every sample on its own.

        Parameters
        ----------
        fitted : ndarray, shape (n_cycles, n_levels)
            Each cycle's prediction from its own sample's fit (N).
        per_sample : dict
            sample -> (mu_Pa, alpha) of that fit.
        warnings : list
            Appended to when the layer has a single sample.
        """
        samples = np.array([c.sample for c in data.cycles])
        q = data.force / fitted - 1.0
        valid = data.valid
        n_cyc = len(data.cycles)
        cycle_mean = np.array([q[c][valid[c]].mean() for c in range(n_cyc)])
        m = valid.sum(axis=1)
        s_e2 = sum(np.sum((q[c][valid[c]] - cycle_mean[c]) ** 2) for c in range(n_cyc))
        s_e2 /= max(int(np.sum(m - 1)), 1)
        # each sample's own fit absorbs the mean of its cycles: the cycle scatter is the spread
        # of cycle means within samples, corrected for the level scatter
        ss, dof = 0.0, 0
        for s in per_sample:
            means = cycle_mean[samples == s]
            ss += np.sum((means - means.mean()) ** 2)
            dof += len(means) - 1
        s_a2 = max(0.0, ss / dof - s_e2 / float(np.mean(m))) if dof else 0.0
        if len(per_sample) > 1:
            theta = np.array([[math.log(mu), a] for mu, a in per_sample.values()])
            cov = np.cov(theta.T)
        else:
            cov = np.zeros((2, 2))
            warnings.append("one sample only: the uncertainty cannot include the scatter "
                            "between samples")
        return cls(sample_cov=cov, cycle=math.sqrt(s_a2), level=max(math.sqrt(s_e2), 1e-4))

    def covariance(self, data: LayerData, fitted: np.ndarray, sensitivity: np.ndarray | None,
                   relative: bool, slope: np.ndarray | None = None) -> np.ndarray:
        """Covariance (n_points, n_points) of the flattened valid points' residuals.

        Block diagonal by sample; within a sample block
        ``J Sigma_s J^T + diag(F) (cycle^2 B + level^2 I) diag(F) + contact^2 B o (s s^T)
        + diag(noise^2)`` with ``J = [dF/dlog mu, dF/dalpha]`` (``sensitivity``, shape
        (n_points, 2)), ``s = dF/dtravel`` (``slope``, N/mm, shape (n_points,); the contact
        term is left out without it), ``B`` the same-cycle indicator and ``o`` the
        elementwise product; relative residuals divide everything by the measured force.
        """
        valid = data.valid
        flat_cycle = np.repeat(np.arange(len(data.cycles)), valid.sum(axis=1))
        y = data.force[valid]
        F = fitted[valid]
        noise = np.nan_to_num(data.noise[valid], nan=0.0)
        J = np.zeros((len(F), 2)) if sensitivity is None else sensitivity
        s = np.zeros(len(F)) if slope is None else slope
        if relative:
            F, noise, J, s = F / y, noise / y, J / y[:, None], s / y
        samples = np.array([data.cycles[c].sample for c in flat_cycle])
        same_sample = samples[:, None] == samples[None, :]
        same_cycle = flat_cycle[:, None] == flat_cycle[None, :]
        return (same_sample * (J @ self.sample_cov @ J.T)
                + (F[:, None] * F[None, :] * self.cycle**2
                   + s[:, None] * s[None, :] * self.contact_mm**2) * same_cycle
                + np.diag((self.level * F) ** 2 + noise**2))

    def whitener(self, data: LayerData, fitted: np.ndarray, sensitivity: np.ndarray | None,
                 relative: bool) -> np.ndarray:
        """Whitening matrix W (n_points, n_points): ``W @ r`` has unit covariance."""
        return whitener(self.covariance(data, fitted, sensitivity, relative))


def whitener(cov: np.ndarray) -> np.ndarray:
    """Inverse Cholesky factor of a covariance matrix: W with W cov W^T = I."""
    L = linalg.cholesky(cov, lower=True)
    return linalg.solve_triangular(L, np.eye(len(cov)), lower=True)


def _noise_from_samples(data: LayerData, unit: OgdenUnitResponse, W0: np.ndarray,
                        alpha0: float, prepared, warnings: list) -> tuple[NoiseModel, dict]:
    """Estimate the noise model from fits of every sample on its own.

    Fit every sample with the same unit model, take the spread of their (log mu, alpha) as the
    sample covariance and the residuals about each sample's own fit for the cycle and level
    scatter.
    """
    samples = np.array([c.sample for c in data.cycles])
    point_sample = samples[unit.cycle_of_point]
    per_sample = {}
    fitted = np.full(data.valid.shape, np.nan)
    for s in dict.fromkeys(samples):
        idx = np.flatnonzero(point_sample == s)
        Ws = W0[np.ix_(idx, idx)]

        def cost(alpha, idx=idx, Ws=Ws):
            U, target = prepared(unit(alpha))
            mu = _varpro_mu(U[idx], target[idx], Ws)
            r = Ws @ (mu * U[idx] - target[idx])
            return float(r @ r)

        alpha_s = _search_alpha(cost, unit.settings.alpha_step, alpha0,
                                unit.settings.alpha_bounds)
        U, target = prepared(unit(alpha_s))
        mu_s = _varpro_mu(U[idx], target[idx], Ws)
        per_sample[s] = (mu_s, alpha_s)
        mask = (samples == s)[:, None] & data.valid
        fitted[mask] = mu_s * unit(alpha_s)[idx]
    noise = NoiseModel.from_sample_fits(data, fitted, per_sample, warnings)
    return noise, per_sample


# ============================================================================ results
@dataclasses.dataclass(frozen=True)
class LayerFit:
    """The fit of one layer: parameters, uncertainty, diagnostics and what it cost.

    ``curves`` holds, per cycle, the simulated force-travel curve at the optimum from a direct
    solve: ``(travel_mm, force_N)``.
    """

    layer: str
    model: str
    mu_Pa: float
    alpha: float
    nu: float
    mu_stderr_Pa: float
    alpha_stderr: float
    mu_alpha_correlation: float
    rms_N: float
    n_cycles: int
    ci: dict
    aic: float
    bic: float
    chisqr: float
    redchi: float
    ndata: int
    noise: NoiseModel
    covariance: np.ndarray
    alpha_nodes: dict
    ratio_nodes: dict
    mesh_ratio: np.ndarray
    homogeneous: dict
    initial: dict
    surrogate_error: float
    data: LayerData
    predicted: np.ndarray
    curves: tuple
    report: str
    warnings: tuple[str, ...]
    n_solves: int
    solve_s: float
    wall_s: float

    def row(self) -> dict:
        """The layer's row of ``parameters.csv``."""
        row = {
            "layer": self.layer, "model": self.model, "mu_Pa": self.mu_Pa, "alpha": self.alpha,
            "nu": self.nu, "mu_stderr_Pa": self.mu_stderr_Pa, "alpha_stderr": self.alpha_stderr,
            "mu_alpha_correlation": self.mu_alpha_correlation, "rms_N": self.rms_N,
            "n_cycles": self.n_cycles,
        }
        for name in ("mu_Pa", "alpha"):
            lo, hi = self.ci.get(name, (math.nan, math.nan))
            suffix = "_Pa" if name == "mu_Pa" else ""
            base = name.removesuffix("_Pa")
            row[f"{base}_ci95_lo{suffix}"] = lo
            row[f"{base}_ci95_hi{suffix}"] = hi
        row["homogeneous_mu_Pa"] = self.homogeneous["mu_Pa"]
        row["homogeneous_alpha"] = self.homogeneous["alpha"]
        row["aic"] = self.aic
        row["bic"] = self.bic
        return row

    @property
    def residual_N(self) -> np.ndarray:
        """Measured minus predicted force at each point (N), shape (n_cycles, n_levels)."""
        return self.data.force - self.predicted


@dataclasses.dataclass(frozen=True)
class CampaignFit:
    """Fits of every layer, and the layers that could not be fitted with the reason."""

    fits: dict
    failed: dict
    settings: FitSettings
    wall_s: float

    def table(self):
        """The parameter table (one row per fitted layer) as a DataFrame."""
        import pandas as pd

        return pd.DataFrame([self.fits[k].row() for k in sorted(self.fits)])


# ============================================================================ homogeneous
def _homogeneous_unit(alpha: float, data: LayerData) -> np.ndarray:
    """Unit forces (N/Pa) of the homogeneous incompressible closed form at the valid points."""
    valid = data.valid
    lam = 1.0 - np.broadcast_to(data.levels, valid.shape)[valid]
    area = np.repeat([c.area_m2 for c in data.cycles], valid.sum(axis=1))
    nominal = 2.0 / alpha * (lam ** (alpha - 1.0) - lam ** (-0.5 * alpha - 1.0))
    return -area * nominal


def homogeneous_fit(data: LayerData, W: np.ndarray | None = None,
                    relative: bool = False) -> dict:
    """Fit of the homogeneous closed form: what a user without the FE model would do.

    F = mu * A * P(lambda; alpha) with the incompressible uniaxial Ogden nominal stress and the
    undeformed area, mu by variable projection, alpha by a bounded scalar search.

    Returns
    -------
    dict
        ``mu_Pa``, ``alpha``.
    """
    y = data.force[data.valid]
    W = np.eye(len(y)) if W is None else W

    def prepared(alpha):
        U = _homogeneous_unit(alpha, data)
        return (U / y, np.ones_like(y)) if relative else (U, y)

    def cost(alpha):
        U, target = prepared(alpha)
        mu = _varpro_mu(U, target, W)
        r = W @ (mu * U - target)
        return float(r @ r)

    res = optimize.minimize_scalar(cost, bounds=(0.5, 40.0), method="bounded",
                                   options={"xatol": 1e-5})
    U, target = prepared(res.x)
    return {"mu_Pa": _varpro_mu(U, target, W), "alpha": float(res.x)}


# ============================================================================ the fit
def _initial_mu(cycles, nu: float) -> float:
    """Median of the cycles' mu = E_material / 3 from the modulus estimator (NaN if none)."""
    from .modulus import ModulusError, initial_mu_Pa

    values = []
    for c in cycles:
        try:
            values.append(initial_mu_Pa(c, nu=nu))
        except (ModulusError, ValueError, ArithmeticError):
            continue
    values = [v for v in values if np.isfinite(v) and v > 0]
    return float(np.median(values)) if values else math.nan


def fit_layer(cycles: Sequence, settings: FitSettings | None = None,
              forward: ForwardModel | None = None) -> LayerFit:
    """Fit one-term Ogden mu and alpha of one layer to its cycles (see the module notes).

    Steps: initial guesses (modulus estimator for mu, homogeneous closed form for alpha, its
    bias corrected with one FE solve); a first fit with independent 5 % weights; every sample
    fitted on its own to estimate the noise model; the generalised least-squares fit with lmfit
    in (mu, alpha); profile intervals; the surrogate checked against direct solves.

    Parameters
    ----------
    cycles : sequence of calib.loaders.Cycle
        The layer's cycles.
    settings : FitSettings, optional
    forward : ForwardModel, optional
        Reuse a forward model (and its cache of solves).

    Returns
    -------
    LayerFit

    Raises
    ------
    FitError
        If the layer cannot be fitted (too few usable cycles, mixed layers).
    """
    import lmfit

    start = time.perf_counter()
    settings = settings or FitSettings()
    forward = forward or ForwardModel.for_settings(settings)
    solves0, solve_s0 = forward.n_solves, forward.solve_s
    data = layer_data(cycles, settings.levels)
    relative = settings.residual == "relative"
    valid = data.valid
    y_abs = data.force[valid]
    warnings = list(data.warnings)
    unit = OgdenUnitResponse(forward, data, settings)
    step = settings.alpha_step
    bounds = settings.alpha_bounds

    def prepared(U):
        return (U / y_abs, np.ones_like(y_abs)) if relative else (U, y_abs)

    def project(alpha, W, U=None):
        U, target = prepared(unit(alpha) if U is None else U)
        mu = _varpro_mu(U, target, W)
        r = W @ (mu * U - target)
        return mu, float(r @ r)

    # initial guesses: the modulus estimator for mu; the homogeneous closed form for alpha,
    # whose bias (bonded platens read as material stiffening) one FE solve measures
    mu_e = _initial_mu(cycles, settings.nu)
    W = NoiseModel.initial().whitener(data, np.where(valid, data.force, np.nan), None, relative)
    hom = homogeneous_fit(data, W, relative)
    k_h = min(max(int(round(hom["alpha"] / step)), 2), int(bounds[1] / step))
    U_h = unit.node(k_h)
    mu_h, _ = project(k_h * step, W, U_h)
    as_data = dataclasses.replace(data, force=np.where(valid, 0.0, np.nan))
    as_data.force[valid] = mu_h * U_h
    hom_of_fe = homogeneous_fit(as_data, W, relative)["alpha"]
    guess = hom["alpha"] * (k_h * step) / hom_of_fe

    # first fit with independent weights, then with the discretisation correction (at every
    # alpha, from its first alpha's nodes on), the noise model from per-sample fits, and the generalised least-squares fit
    alpha1 = _search_alpha(lambda a: project(a, W)[1], step, guess, bounds)
    if settings.mesh_correction:
        unit.set_correction(alpha1, settings.mesh_correction)
        alpha1 = _search_alpha(lambda a: project(a, W)[1], step, alpha1, bounds)
    noise, per_sample = _noise_from_samples(data, unit, W, alpha1, prepared, warnings)
    mu1, _ = project(alpha1, W)
    fitted = np.full(valid.shape, np.nan)
    fitted[valid] = mu1 * unit(alpha1)
    J = np.column_stack([fitted[valid], mu1 * unit.derivative(alpha1)])
    cov = noise.covariance(data, fitted, J, relative)
    W = whitener(cov)
    alpha2 = _search_alpha(lambda a: project(a, W)[1], step, alpha1, bounds)
    mu2, _ = project(alpha2, W)

    # lmfit in physical parameters, from the projected optimum
    params = Ogden(mu_Pa=mu2, alpha=alpha2, nu=settings.nu).parameters()
    params["alpha"].set(min=bounds[0], max=bounds[1])

    def residual(p):
        U, target = prepared(unit(p["alpha"].value))
        return W @ (p["mu_Pa"].value * U - target)

    mini = lmfit.Minimizer(residual, params, nan_policy="raise")
    # finite-difference step 1 % of each value: far above the solver noise floor
    result = mini.minimize(method="leastsq", epsfcn=1e-4)
    mu = result.params["mu_Pa"].value
    alpha = result.params["alpha"].value
    mu_se = result.params["mu_Pa"].stderr
    alpha_se = result.params["alpha"].stderr
    corr = (result.params["mu_Pa"].correl or {}).get("alpha", math.nan)
    mu_se = math.nan if mu_se is None else float(mu_se)
    alpha_se = math.nan if alpha_se is None else float(alpha_se)
    ci = {}
    if settings.profile and result.errorbars:
        try:
            raw = lmfit.conf_interval(mini, result, sigmas=[2])
            for name, rows in raw.items():
                values = [v for _, v in rows]
                ci[name] = (float(min(values)), float(max(values)))
        except (ValueError, RuntimeError, ArithmeticError, lmfit.minimizer.MinimizerException
                ) as exc:
            warnings.append(f"profile confidence intervals failed: {exc}")
    if not result.errorbars:
        warnings.append("lmfit could not estimate standard errors (singular curvature)")
    if abs(corr) > 0.95 or (alpha_se / alpha if np.isfinite(alpha_se) else 1.0) > 0.25:
        warnings.append(
            f"the data hardly separate mu from alpha (correlation {corr:+.3f}, alpha "
            f"{alpha:.2f} +- {alpha_se:.2f}): Ogden fits can be non-unique (Ogden, Saccomandi "
            "& Sgura 2004); more strain range or a second load case would help")

    # an optimum on the edge of the search is the box's, not the data's: lmfit's standard
    # error there comes from the bound's transform (alpha 1.000 +- 2e-15 on a layer whose
    # closed-form alpha was 2.25), and would read as a precise estimate
    side = next((name for name, b in (("lower", bounds[0]), ("upper", bounds[1]))
                 if abs(alpha - b) <= 1e-3 * max(1.0, abs(b))), None)
    if side is not None:
        alpha_se, corr = math.nan, math.nan
        ci.pop("alpha", None)
        warnings.append(
            f"alpha = {alpha:.3f} is at the {side} bound of the search ({bounds[0]:g} to "
            f"{bounds[1]:g}): the one-term Ogden law with these platens cannot follow the "
            "curve's shape here; the value and its uncertainty are not estimates (check the "
            "platen condition and the contact point, or try another model)")

    # the surrogate against direct solves at the optimum; the correction there is reported
    U_direct = unit.direct(alpha)
    mesh_ratio = unit.mesh_ratio_at(alpha)
    surrogate_error = float(np.max(np.abs(unit(alpha) / U_direct - 1.0)))
    if surrogate_error > 5e-3:
        warnings.append(f"alpha surrogate differs from a direct solve by {surrogate_error:.2%}")
    predicted = np.full(valid.shape, np.nan)
    predicted[valid] = mu * U_direct
    rms = float(np.sqrt(np.mean((predicted[valid] - y_abs) ** 2)))
    curves = []
    for c in data.cycles:
        key = unit.key(alpha, (c.diameter_mm, c.height_mm))
        spline = forward.curve(key)
        ratio = np.interp(spline.x / c.height_mm, data.levels, mesh_ratio)
        # travel from where the loader's contact fit would put the contact (see contact_fit)
        curves.append((spline.x - unit.contact_shift(key), mu * spline(spline.x) * ratio))
    return LayerFit(
        layer=data.layer, model="ogden", mu_Pa=float(mu), alpha=float(alpha), nu=settings.nu,
        mu_stderr_Pa=mu_se, alpha_stderr=alpha_se, mu_alpha_correlation=float(corr),
        rms_N=rms, n_cycles=len(data.cycles), ci=ci, aic=float(result.aic),
        bic=float(result.bic), chisqr=float(result.chisqr), redchi=float(result.redchi),
        ndata=int(result.ndata), noise=noise, covariance=cov, alpha_nodes=dict(unit.nodes),
        ratio_nodes=dict(unit.ratio_nodes), mesh_ratio=mesh_ratio,
        homogeneous=hom,
        initial={"mu_Pa_modulus": mu_e, "alpha_homogeneous": hom["alpha"],
                 "alpha_guess": guess, "alpha_first_fit": alpha1,
                 "per_sample": {k: {"mu_Pa": v[0], "alpha": v[1]}
                                for k, v in per_sample.items()}},
        surrogate_error=surrogate_error, data=data, predicted=predicted, curves=tuple(curves),
        report=lmfit.fit_report(result), warnings=tuple(warnings),
        n_solves=forward.n_solves - solves0, solve_s=forward.solve_s - solve_s0,
        wall_s=time.perf_counter() - start)


def _fit_layer_job(layer: str, cycles: list, settings: FitSettings):
    """Work item of :func:`fit_campaign` (top level, so a process pool can pickle it)."""
    try:
        return layer, fit_layer(cycles, settings), None
    except FitError as exc:
        return layer, None, str(exc)


def fit_campaign(campaign, settings: FitSettings | None = None, *,
                 layers: Iterable[str] | None = None, rates: Iterable[float] | None = None,
                 max_workers: int | None = None, scheduler=None,
                 progress: bool = True) -> CampaignFit:
    """Fit every layer (or the ones asked for) of a campaign, layers in parallel.

    Parameters
    ----------
    campaign : calib.loaders.Campaign
    settings : FitSettings, optional
    layers : iterable of str, optional
        Layers to fit; default all.
    rates : iterable of float, optional
        Only cycles at these platen speeds (mm/s).
    max_workers : int, optional
        Local processes (default: cores); 1 fits in this process.
    scheduler : str or distributed.Client, optional
        A Dask scheduler to fit on instead.
    progress : bool
        Show a progress bar on stderr.
    """
    from .parallel import executor

    start = time.perf_counter()
    settings = settings or FitSettings()
    wanted = campaign.layers() if layers is None else list(layers)
    rates = None if rates is None else [float(r) for r in rates]
    failed = {}
    jobs = {}
    for layer in wanted:
        cycles = campaign.select(layer=layer)
        if rates is not None:
            cycles = [c for c in cycles
                      if any(abs(c.rate_mm_per_s - r) <= 0.05 * r for r in rates)]
        if not cycles:
            failed[layer] = f"layer {layer}: no cycles" + (
                f" at rates {rates} mm/s" if rates else " in the campaign")
            continue
        jobs[layer] = cycles
    fits = {}
    with executor(len(jobs), max_workers=max_workers, scheduler=scheduler) as pool:
        futures = [pool.submit(_fit_layer_job, layer, cycles, settings)
                   for layer, cycles in jobs.items()]
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=len(futures), desc="fitting layers", unit="layer")
        import concurrent.futures as cf

        for future in cf.as_completed(futures):
            layer, fit, error = future.result()
            if fit is not None:
                fits[layer] = fit
            else:
                failed[layer] = error
            if bar is not None:
                bar.set_postfix_str(f"{layer} done" if fit else f"{layer} failed")
                bar.update(1)
        if bar is not None:
            bar.close()
    return CampaignFit(fits=fits, failed=failed, settings=settings,
                       wall_s=time.perf_counter() - start)
