r"""Independent FElupe reference solutions of the platen compression of a soft cylinder.

The verification ladder compares :func:`solver.simulate` (explicit dynamics, mean-gradient
quads) with an independent implicit code. This module solves the same *static* problem with
`FElupe <https://github.com/adtzlr/felupe>`_ by Newton's method: a cylinder of diameter
``D`` and height ``H`` squeezed between rigid platens, either bonded (bottom face fixed, top
face :math:`u_r = 0` with :math:`u_z` prescribed), frictionless (only :math:`u_z` held on
the faces) or with Coulomb friction (contact with friction, see below).

Material (the project's single convention, FElupe's ``ogden``)::

    W = sum_i 2 mu_i / alpha_i^2 (lb1^a_i + lb2^a_i + lb3^a_i - 3) + K/2 (J - 1)^2,
    lb_a = J^(-1/3) lambda_a,   K = 2 mu (1 + nu) / (3 (1 - 2 nu)),   mu = sum_i mu_i.

The isochoric part is FElupe's tensortrax ``ogden`` model (it uses the eigenvalues of
:math:`\hat C = J^{-2/3} C`, i.e. exactly :math:`\bar\lambda_a^2`); the volumetric part is
FElupe's :class:`~felupe.NearlyIncompressible` three-field (u, p, J-bar) variation with
:math:`U(\bar J) = K/2 (\bar J - 1)^2`, :math:`U' = K(\bar J - 1)`, :math:`U'' = K`. In the
continuum (and for any homogeneous deformation) :math:`\bar J = J` and this *is* the energy
above; :func:`frictionless_check` verifies it against the closed form to ~1e-9.

Discretisation
--------------
* ``axisymmetric=True`` (default): r-z half plane. FElupe's axisymmetric convention is
  **x1 = axial (z), x2 = radial (r)**; its assembled forces are for the full :math:`2\pi`
  revolution (``dV = 2 pi R dA``), so the top-face reaction is the platen force in N.
  ``order="quadratic"``: 9-node biquadratic quads with a discontinuous bilinear pressure and
  volume ratio (FElupe's dual of :class:`~felupe.RegionBiQuadraticQuad`); ``"linear"``:
  4-node quads with cell-constant pressure (Q1/P0, mean dilatation).
* ``axisymmetric=False``: a 3D hexahedral cylinder (FElupe's O-grid :class:`~felupe.Circle`
  expanded along z), hex8 with cell-constant pressure (``"linear"``) or hex27 with a
  discontinuous trilinear pressure (``"quadratic"``). Optional layers of different materials
  along z (``layers=[z_interface_mm, ...]``).
* Meshes are graded toward the bonded rim (r = R at z = 0 and z = H), where the solution is
  singular: ``grading`` is the ratio of the largest to the smallest cell size along r (one
  sided, fine at r = R) and along z (two sided, fine at both faces).

Units inside FElupe: mm, N and MPa (N/mm^2); the public functions take Pa and mm and return N.

Rollover
--------
The bulging side of a bonded sample folds onto the platens next to the rim. Without contact,
FElupe's free-surface nodes end 0.23-0.29 mm below z = 0 (and as far above the top platen)
at 30 % on the converged meshes (mu = 1875 Pa, alpha = 4.9, nu = 0.49 and 0.499). Measured on
the 32 x 32 reference mesh, holding the folded surface on the platens raises the force by
0.03 % at 10 %, 0.15-0.4 % at 15 %, 0.5-0.7 % at 20 %, 1.1-1.3 % at 25 % and 2.2-2.4 % at 30 %
(the rolled-over surface carries 0.42-0.48 N of 3.9-4.1 N at 30 %). So it matters at 30 %:
``rollover_contact=True`` (default for bonded platens) adds FElupe's penalty
:class:`~felupe.ContactRigidPlane` on both platens for the side-surface nodes, frictionless
(a sticking variant gave the same force to 6 digits: the rolled-on surface barely slides).
The penalty leaves < 1e-4 mm penetration. ``rollover`` in :func:`compression_curve`'s output
reports how far side nodes end beyond the platens.

Coulomb platens
---------------
``platen="coulomb"`` holds the faces by contact alone: FElupe's penalty
:class:`~felupe.ContactRigidPlane` with a Coulomb return mapping on every boundary node (face
and side) against both platens, which move by half the travel each while the axis node at
mid-height stays put (exact by symmetry; it removes the axial rigid-body mode). A sticking
node slides elastically by up to 0.5 % of the smallest face cell before it slips. A failed
increment is bisected with the contacts' friction history restored. Measured at friction
0.15 (mu = 1875 Pa, alpha = 4.9, nu = 0.499, bilinear cells graded 2n:1): from 8 x 8 to
24 x 24 cells the force moves by < 0.06 % up to 20 % strain and by 0.2 % at 25-30 %; 60 and
120 increments agree to 1e-6 up to 30 %, 20 and 60 up to 20 %. Limits: the Newton solve of the quadratic cells failed (a
non-finite system on 8 x 8 cells), and at friction 0.3 only the 16 x 16 mesh went through:
on 12, 20, 24 and 32 cells Newton's iterations stopped converging at one travel between 8
and 15 % strain, however small the step (ten bisections). Nor does it go through on every
sample at 0.15: on 16 x 16 cells it stopped at 23 % strain on a generated sample (alpha
4.94, 38.5 x 24.2 mm; also with a ten times softer penalty, on another sample), so the
generator's FElupe truth keeps to bonded and frictionless platens. ``friction=0`` gives the
frictionless closed form.

Public functions
----------------
:func:`compression_curve` (one static force-travel curve), :func:`graded_coordinates`,
:func:`axisymmetric_mesh`, :func:`cylinder_hex_mesh`, :func:`frictionless_check`,
:func:`convergence_study`, :func:`richardson`, :func:`mesh_for_accuracy`,
:func:`time_at_accuracy` (the benchmark's FElupe timing at a stated accuracy).

Run ``python -m experiments.felupe_reference --help`` for the convergence study.

FElupe is a test-only dependency: only ``experiments/`` and ``tests/`` import this module.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
import warnings
from collections.abc import Sequence

import numpy as np
from scipy.sparse.linalg import MatrixRankWarning, spsolve

__all__ = [
    "LADDER",
    "REFERENCE_CASE",
    "axisymmetric_mesh",
    "compression_curve",
    "convergence_study",
    "cylinder_hex_mesh",
    "frictionless_check",
    "graded_coordinates",
    "mesh_for_accuracy",
    "richardson",
    "time_at_accuracy",
]

_PA_TO_MPA = 1e-6
#: Strains at which the reference force is always solved exactly (not interpolated).
CHECK_STRAINS = (0.1, 0.2, 0.3)


def _felupe():
    try:
        import felupe
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            "experiments.felupe_reference needs FElupe and tensortrax (the 'test' extra: "
            "pip install -e '.[test]')"
        ) from exc
    return felupe


# ============================================================================== meshes
def graded_coordinates(length_mm: float, n: int, grading: float = 1.0,
                       fine: str = "end") -> np.ndarray:
    """Node coordinates of a 1D geometrically graded line from 0 to ``length_mm``.

    Parameters
    ----------
    length_mm : float
        Length of the line (mm), positive.
    n : int
        Number of cells, >= 1.
    grading : float
        Ratio of the largest to the smallest cell size, >= 1 (1 = uniform). Sizes form a
        geometric sequence.
    fine : {"end", "start", "both"}
        Where the smallest cells are: at ``length_mm``, at 0, or at both ends (the sizes are
        then mirrored about the midpoint).

    Returns
    -------
    ndarray, shape (n + 1,)
        Increasing coordinates (mm) with exact end points 0 and ``length_mm``.

    Examples
    --------
    >>> x = graded_coordinates(10.0, 4, grading=8.0, fine="end")
    >>> round(float((x[1] - x[0]) / (x[4] - x[3])), 6)
    8.0
    """
    if not (math.isfinite(length_mm) and length_mm > 0):
        raise ValueError(f"length_mm={length_mm} must be a positive number")
    if int(n) != n or n < 1:
        raise ValueError(f"n={n} cells must be a positive integer")
    if not (math.isfinite(grading) and grading >= 1.0):
        raise ValueError(f"grading={grading} must be >= 1 (largest / smallest cell size)")
    n = int(n)
    if fine == "both":
        half = (n + 1) // 2
        growth = grading ** (np.arange(half) / max(half - 1, 1))          # small -> large
        sizes = np.r_[growth, growth[::-1]] if n % 2 == 0 else np.r_[growth, growth[-2::-1]]
    elif fine in ("end", "start"):
        sizes = grading ** (np.arange(n)[::-1] / max(n - 1, 1))          # large -> small
        if fine == "start":
            sizes = sizes[::-1]
    else:
        raise ValueError(f"fine={fine!r} is not 'end', 'start' or 'both'")
    x = np.r_[0.0, np.cumsum(sizes)]
    x = length_mm * x / x[-1]
    x[-1] = length_mm
    return x


def axisymmetric_mesh(diameter_mm: float = 38.0, height_mm: float = 24.0, n_radial: int = 16,
                      n_axial: int = 16, grading: float = 4.0, order: str = "quadratic",
                      layers: Sequence[float] | None = None):
    """Structured r-z quad mesh of the half cross-section, in FElupe's axisymmetric axes.

    Parameters
    ----------
    diameter_mm, height_mm : float
        Cylinder size (mm).
    n_radial, n_axial : int
        Cells along r and along z.
    grading : float
        Largest / smallest cell size; fine at r = R (radial) and at z = 0 and z = H (axial).
    order : {"quadratic", "linear"}
        9-node biquadratic or 4-node bilinear quads.
    layers : sequence of float, optional
        Heights (mm) of material interfaces; node rows are placed exactly on them.

    Returns
    -------
    felupe.Mesh
        Points (n_points, 2) as **(z, r)** in mm: FElupe's axisymmetric fields take x1 as the
        axis of revolution and x2 as the radius.
    """
    fem = _felupe()
    z = _axial_planes(height_mm, n_axial, grading, layers)
    r = graded_coordinates(0.5 * diameter_mm, n_radial, grading, fine="end")
    mesh = fem.mesh.Grid(z, r)
    if order == "quadratic":
        mesh = fem.mesh.convert(mesh, order=2, calc_midfaces=True)
    elif order != "linear":
        raise ValueError(f"order={order!r} is not 'quadratic' or 'linear'")
    return mesh


def cylinder_hex_mesh(diameter_mm: float = 38.0, height_mm: float = 24.0, n_radial: int = 8,
                      n_axial: int = 12, grading: float = 2.0, order: str = "linear",
                      layers: Sequence[float] | None = None):
    """Hexahedral mesh of the full cylinder (O-grid disk expanded along z).

    Parameters
    ----------
    diameter_mm, height_mm : float
        Cylinder size (mm).
    n_radial : int
        Points along each edge of FElupe's :class:`~felupe.Circle` O-grid (>= 3); the disk
        has about ``4 (n_radial - 1)`` cells around and ``2 (n_radial - 1)`` across.
    n_axial : int
        Cells along z.
    grading : float
        Largest / smallest cell size, fine at the rim (radial, by a monotone remapping of the
        radius along each ray) and at both faces (axial).
    order : {"linear", "quadratic"}
        hex8, or hex27 with the side-surface mid-nodes moved onto the cylinder.
    layers : sequence of float, optional
        Heights (mm, ascending, strictly inside (0, H)) of material interfaces; node planes are
        placed exactly on them.

    Returns
    -------
    felupe.Mesh
        Points (n_points, 3) as (x, y, z) in mm, z along the axis.
    """
    fem = _felupe()
    R, H = 0.5 * diameter_mm, height_mm
    if int(n_radial) != n_radial or n_radial < 3:
        raise ValueError(f"n_radial={n_radial} must be an integer >= 3 for the O-grid disk")
    disk = fem.Circle(radius=1.0, n=int(n_radial))
    pts = disk.points.copy()
    s = np.linalg.norm(pts, axis=1)
    uniform = np.linspace(0.0, 1.0, 65)
    graded = graded_coordinates(1.0, 64, grading, fine="end")
    # monotone radial remapping s -> phi(s), phi(0) = 0, phi(1) = 1: rim cells shrink
    scale = np.where(s > 0, np.interp(s, uniform, graded) / np.where(s > 0, s, 1.0), 1.0)
    disk.update(points=R * pts * scale[:, None])
    z = _axial_planes(H, n_axial, grading, layers)
    mesh = disk.expand(n=len(z), z=1.0)
    # expand() spaces the planes uniformly in [0, 1]; map them onto the graded planes
    zeta = np.round(mesh.points[:, 2] * (len(z) - 1)).astype(int)
    mesh.points[:, 2] = z[zeta]
    if order == "quadratic":
        n_around = 4 * (int(n_radial) - 1)
        chord = R * math.cos(math.pi / n_around)       # radius of a rim edge's midpoint
        r_vertex = np.linalg.norm(mesh.points[:, :2], axis=1)
        gap = R - r_vertex[r_vertex < R * (1.0 - 1e-9)].max()   # rim to the next ring
        if R - chord >= 0.25 * gap:
            raise ValueError(
                f"cannot tell the side-surface mid-nodes from interior nodes: the chord sag "
                f"{R - chord:.3g} mm is not small against the rim cells ({gap:.3g} mm); "
                f"use more points around (n_radial) or less grading"
            )
        mesh = fem.mesh.convert(mesh, order=2, calc_midfaces=True, calc_midvolumes=True)
        r = np.linalg.norm(mesh.points[:, :2], axis=1)
        on_side = r > chord - 1e-9 * R
        mesh.points[on_side, :2] *= (R / r[on_side])[:, None]
    elif order != "linear":
        raise ValueError(f"order={order!r} is not 'quadratic' or 'linear'")
    return mesh


def _axial_planes(height_mm, n_axial, grading, layers):
    """Graded z planes (mm), fine at both faces and on both sides of every layer interface."""
    if layers is None or len(layers) == 0:
        return graded_coordinates(height_mm, n_axial, grading, fine="both")
    bounds = np.r_[0.0, np.asarray(layers, dtype=float), height_mm]
    planes = [np.zeros(1)]
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        n = max(2, round(n_axial * (b - a) / height_mm))
        planes.append(a + graded_coordinates(b - a, n, grading, fine="both")[1:])
    out = np.concatenate(planes)
    out[-1] = height_mm
    return out


# ============================================================================== materials
@dataclasses.dataclass(frozen=True)
class _Material:
    """One Ogden material in FElupe units (MPa)."""

    mu_MPa: tuple[float, ...]
    alpha: tuple[float, ...]
    bulk_MPa: float


def _material(mu_Pa, alpha, nu, where: str) -> _Material:
    mu = tuple(float(m) for m in np.atleast_1d(mu_Pa))
    al = tuple(float(a) for a in np.atleast_1d(alpha))
    if len(mu) != len(al) or not mu:
        raise ValueError(f"{where}: mu_Pa has {len(mu)} terms but alpha has {len(al)}")
    if not all(math.isfinite(v) for v in mu + al):
        raise ValueError(f"{where}: mu_Pa={mu} and alpha={al} must be finite")
    if any(a == 0.0 for a in al):
        raise ValueError(f"{where}: alpha={al} must be non-zero")
    mu0 = sum(mu)
    if any(m * a <= 0 for m, a in zip(mu, al, strict=True)) or mu0 <= 0:
        raise ValueError(f"{where}: every mu_i * alpha_i must be positive and sum(mu) > 0 "
                         f"(got mu_Pa={mu}, alpha={al})")
    nu = float(nu)
    if not -1.0 < nu < 0.5:
        raise ValueError(f"{where}: Poisson's ratio nu={nu} must lie in (-1, 0.5)")
    bulk = 2.0 * mu0 * (1.0 + nu) / (3.0 * (1.0 - 2.0 * nu))
    return _Material(tuple(m * _PA_TO_MPA for m in mu), al, bulk * _PA_TO_MPA)


class _CellwiseMaterial:
    """Isochoric Ogden laws chosen per cell (layers), with FElupe's material interface.

    ``gradient([F, statevars])`` / ``hessian([F, statevars])`` evaluate each material on its
    own cells; arrays are (3, 3, n_quadrature, n_cells) and (3, 3, 3, 3, n_q, n_cells).
    """

    parallel = False

    def __init__(self, umats, cell_material):
        self.umats = umats
        self.cell_material = np.asarray(cell_material)
        self.x = [np.eye(3), np.zeros(0)]

    def _split(self, x, what):
        F, statevars = x[0], x[-1]
        out = None
        for k, umat in enumerate(self.umats):
            sel = self.cell_material == k
            value = getattr(umat, what)([np.ascontiguousarray(F[..., sel]), statevars])[0]
            if out is None:
                out = np.zeros(value.shape[:-1] + (F.shape[-1],))
            out[..., sel] = value
        return out

    def gradient(self, x, **kwargs):
        return [self._split(x, "gradient"), x[-1]]

    def hessian(self, x, **kwargs):
        return [self._split(x, "hessian")]


def _umat(materials, cell_material):
    """FElupe (u, p, J-bar) material: isochoric Ogden + K/2 (J-bar - 1)^2 (per cell K)."""
    fem = _felupe()
    isochoric = [fem.Hyperelastic(fem.ogden, mu=list(m.mu_MPa), alpha=list(m.alpha))
                 for m in materials]
    if len(materials) == 1:
        return fem.NearlyIncompressible(isochoric[0], bulk=materials[0].bulk_MPa)
    bulk = np.array([m.bulk_MPa for m in materials])[cell_material]      # (n_cells,)
    umat = fem.NearlyIncompressible(_CellwiseMaterial(isochoric, cell_material), bulk=bulk)
    # FElupe evaluates materials in chunks of cells (8192 quadrature points each); the
    # per-cell material index and bulk modulus refer to all cells, so evaluate in one go.
    umat.chunksize = None
    return umat


# ============================================================================== the solve
def compression_curve(
    mu_Pa,
    alpha,
    nu,
    diameter_mm: float = 38.0,
    height_mm: float = 24.0,
    strain: float = 0.3,
    platen: str = "bonded",
    friction: float | None = None,
    axisymmetric: bool = True,
    n_radial: int = 16,
    n_axial: int = 16,
    order: str | None = None,
    n_increments: int = 10,
    layers: Sequence[float] | None = None,
    grading: float | None = None,
    rollover_contact: bool | None = None,
    contact_penalty: float = 1000.0,
    check_strains: Sequence[float] = CHECK_STRAINS,
) -> dict:
    """Static force-travel curve of a cylinder compressed between rigid platens (FElupe).

    Parameters
    ----------
    mu_Pa, alpha : float or sequence of float
        Ogden moduli (Pa) and exponents, one per term (W convention in the module notes).
        With ``layers``: a sequence with one entry per layer (bottom to top), each a float or
        a sequence of terms.
    nu : float or sequence of float
        Small-strain Poisson's ratio (per layer with ``layers``); sets
        K = 2 mu (1 + nu) / (3 (1 - 2 nu)).
    diameter_mm, height_mm : float
        Sample size (mm).
    strain : float
        Final nominal compression, travel / height, in (0, 0.7).
    platen : {"bonded", "frictionless", "coulomb"}
        Bonded faces (bottom fixed; top u_r = 0, u_z prescribed), frictionless faces (only
        u_z held; plus the axis, or rigid-body constraints in 3D), or Coulomb friction
        (axisymmetric only): every boundary node meets the rigid platens through FElupe's
        penalty :class:`~felupe.ContactRigidPlane` with ``friction``, a Coulomb law with an
        elastic stick and a return mapping (see "Coulomb platens" in the module notes).
    friction : float, optional
        Coulomb coefficient, >= 0; required with ``platen="coulomb"`` and only there.
    axisymmetric : bool
        r-z axisymmetric model (True) or a 3D hexahedral cylinder (False).
    n_radial, n_axial : int
        Mesh size: cells along r and z (axisymmetric); O-grid edge points and cells along z
        (3D, see :func:`cylinder_hex_mesh`).
    order : {"quadratic", "linear"}, optional
        Element order (see the module notes for the pressure interpolation). Default:
        quadratic for the axisymmetric model, linear for the 3D one.
    n_increments : int
        Equal load increments to the final travel. The solution at a given travel does not
        depend on them (static hyperelasticity with frictionless contact); they only keep
        Newton in its basin. A failed increment is bisected automatically.
    layers : sequence of float, optional
        Interface heights (mm) of a layered sample, ascending in (0, H).
    grading : float, optional
        Largest / smallest cell size of the graded mesh (1 = uniform). Default: r-z
        ``2 * max(n_radial, n_axial)`` (the family of the convergence study, whose smallest
        rim cell shrinks like 1/n^2 and restores second-order convergence of the force
        despite the rim singularity); 3D 2.
    rollover_contact : bool, optional
        Rigid-plane penalty contact of the side-surface nodes with both platens. Default:
        on for bonded and Coulomb platens, off for frictionless ones (where the side never
        meets them).
    contact_penalty : float
        FElupe's contact multiplier, relative to the mean stiffness of the contact nodes.
        The default 1000 leaves about 3e-4 mm penetration at 30 % on a 16 x 16 mesh, and
        changes the force by < 2e-4 relative to 100 with bonded platens; with Coulomb ones,
        whose faces it holds, by 0.08-0.17 % (12 x 12 cells, friction 0.15).
    check_strains : sequence of float
        Nominal strains at which the solution is computed exactly (added to the increments).

    Returns
    -------
    dict
        ``displacement_mm`` (n,), ``force_N`` (n,) (compression positive, from 0),
        ``strain`` (n,), ``wall_s`` (float, the whole setup and solve), ``n_dofs`` (int, all
        unknowns incl. pressure and volume ratio), ``n_dofs_displacement``,
        ``cross_section_mm2`` (mesh volume / H: pi R^2 up to the 3D mesh's facets), ``mesh`` (the
        undeformed FElupe mesh, mm), ``deformed_points_mm`` (final), ``newton_iterations``
        (per increment), ``contact_force_N`` (n,) (the part carried by rolled-over side
        nodes at the top platen), and ``rollover``: ``{"below_bottom_mm", "above_top_mm",
        "n_nodes_beyond"}`` - how far free-surface nodes end beyond the platens at the end
        (with contact: the penalty penetration; without: the rollover itself).

    Notes
    -----
    FElupe's axisymmetric forces are for the full revolution (assembled with
    dV = 2 pi R dA), checked against the homogeneous closed form by
    :func:`frictionless_check`.
    """
    fem = _felupe()
    t_start = time.perf_counter()
    for name, value in (("diameter_mm", diameter_mm), ("height_mm", height_mm)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name}={value} must be a positive number")
    if not 0.0 < strain < 0.7:
        raise ValueError(f"strain={strain} must lie in (0, 0.7)")
    if platen not in ("bonded", "frictionless", "coulomb"):
        raise ValueError(f"platen={platen!r} is not 'bonded', 'frictionless' or 'coulomb'")
    coulomb = platen == "coulomb"
    if coulomb:
        if friction is None or not (math.isfinite(friction) and friction >= 0.0):
            raise ValueError(f"friction={friction!r} must be a finite number >= 0 with "
                             "platen='coulomb'")
        if not axisymmetric:
            raise ValueError("platen='coulomb' is axisymmetric only (axisymmetric=True)")
        if int(n_axial) % 2:
            raise ValueError(f"n_axial={n_axial} must be even with platen='coulomb' (a node "
                             "row at mid-height holds the sample's axial position)")
        if layers:
            raise ValueError("platen='coulomb' takes no layers: the node held at mid-height "
                             "needs a sample symmetric about it")
    elif friction is not None:
        raise ValueError(f"friction={friction!r} is for platen='coulomb' only "
                         f"(platen={platen!r})")
    if int(n_increments) != n_increments or n_increments < 1:
        raise ValueError(f"n_increments={n_increments} must be a positive integer")
    if rollover_contact is None:
        rollover_contact = platen != "frictionless"
    if order is None:
        order = "quadratic" if axisymmetric else "linear"
    if grading is None:
        grading = 2.0 * max(n_radial, n_axial) if axisymmetric else 2.0

    # ---------------------------------------------------------------- materials
    if layers:
        interfaces = np.asarray(layers, dtype=float)
        if np.any(np.diff(interfaces) <= 0) or interfaces[0] <= 0 or interfaces[-1] >= height_mm:
            raise ValueError(f"layers={list(layers)} must be ascending heights inside "
                             f"(0, {height_mm}) mm")
        n_layers = len(interfaces) + 1
        per_layer = []
        for name, value in (("mu_Pa", mu_Pa), ("alpha", alpha), ("nu", nu)):
            seq = list(value) if isinstance(value, (list, tuple, np.ndarray)) else [value]
            if name == "nu" and len(seq) == 1:
                seq = seq * n_layers
            if len(seq) != n_layers:
                raise ValueError(f"{name} has {len(seq)} entries but layers={list(layers)} "
                                 f"makes {n_layers} layers")
            per_layer.append(seq)
        materials = [_material(m, a, v, f"layer {k}")
                     for k, (m, a, v) in enumerate(zip(*per_layer, strict=True))]
    else:
        interfaces = np.zeros(0)
        materials = [_material(mu_Pa, alpha, nu, "material")]

    # ---------------------------------------------------------------- mesh and fields
    R, H = 0.5 * diameter_mm, height_mm
    if axisymmetric:
        mesh = axisymmetric_mesh(diameter_mm, height_mm, n_radial, n_axial, grading, order,
                                 layers=interfaces)
        axial, dim = 0, 2
        r_body = mesh.points[:, 1].copy()
    else:
        mesh = cylinder_hex_mesh(diameter_mm, height_mm, n_radial, n_axial, grading, order,
                                 layers=interfaces if interfaces.size else None)
        axial, dim = 2, 3
        r_body = np.linalg.norm(mesh.points[:, :2], axis=1)
    n_body = mesh.npoints
    z_body = mesh.points[:, axial].copy()
    cell_z = mesh.points[mesh.cells, axial].mean(axis=1)
    cell_material = np.searchsorted(interfaces, cell_z)                  # layer index per cell

    if rollover_contact or coulomb:
        # two extra, cell-free points: the reference points of the bottom and top platens
        centre = np.zeros((2, dim))
        centre[1, axial] = H
        mesh.update(points=np.vstack([mesh.points, centre]))
    region = {
        (True, "quadratic"): fem.RegionBiQuadraticQuad,
        (True, "linear"): fem.RegionQuad,
        (False, "quadratic"): fem.RegionTriQuadraticHexahedron,
        (False, "linear"): fem.RegionHexahedron,
    }[(bool(axisymmetric), order)](mesh)
    field = fem.FieldsMixed(region, n=3, axisymmetric=bool(axisymmetric))
    solid = fem.SolidBody(_umat(materials, cell_material), field)

    # ---------------------------------------------------------------- boundary conditions
    tol = 1e-9 * max(R, H)
    index = np.arange(mesh.npoints)
    body = index < n_body
    z_all = np.r_[z_body, np.full(mesh.npoints - n_body, np.nan)]
    r_all = np.r_[r_body, np.full(mesh.npoints - n_body, np.nan)]
    bottom = body & (np.abs(z_all) < tol)
    top = body & (np.abs(z_all - H) < tol)
    only_axial = tuple(0 if k == axial else 1 for k in range(dim))      # skip flags
    all_but_axial = tuple(1 if k == axial else 0 for k in range(dim))
    bcs = {}
    if axisymmetric:
        bcs["axis"] = fem.Boundary(field[0], mask=body & (np.abs(r_all) < tol), skip=(1, 0))
    if platen == "bonded":
        bcs["bottom"] = fem.Boundary(field[0], mask=bottom)
        bcs["top_lateral"] = fem.Boundary(field[0], mask=top, skip=all_but_axial)
    elif coulomb:
        # the faces are held by contact alone: both platens move by half the travel and the
        # axis node at mid-height stays where it is (exact by symmetry), which removes the
        # axial rigid-body mode
        middle = body & (np.abs(r_all) < tol) & (np.abs(z_all - 0.5 * H) < tol)
        if middle.sum() != 1:
            raise ValueError("the mesh has no node on the axis at mid-height")
        bcs["middle"] = fem.Boundary(field[0], mask=middle, skip=only_axial)
    else:
        bcs["bottom"] = fem.Boundary(field[0], mask=bottom, skip=only_axial)
        if not axisymmetric:
            # rigid-body modes of the frictionless 3D cylinder: symmetry planes x=0 and y=0
            # (exact for the homogeneous solution and for any axisymmetric one)
            x_all = np.r_[mesh.points[:n_body, 0], np.full(mesh.npoints - n_body, np.nan)]
            y_all = np.r_[mesh.points[:n_body, 1], np.full(mesh.npoints - n_body, np.nan)]
            bcs["sym_x"] = fem.Boundary(field[0], mask=body & (np.abs(x_all) < tol),
                                        skip=(0, 1, 1))
            bcs["sym_y"] = fem.Boundary(field[0], mask=body & (np.abs(y_all) < tol),
                                        skip=(1, 0, 1))
    if not coulomb:
        bcs["move"] = fem.Boundary(field[0], mask=top, skip=only_axial)
    items = [solid]
    side = np.where(body & (np.abs(r_all - R) < tol) & ~top & ~bottom)[0]
    if rollover_contact or coulomb:
        if coulomb:
            bcs["bottom_platen_lateral"] = fem.Boundary(field[0], mask=index == n_body,
                                                        skip=all_but_axial)
            bcs["bottom_platen"] = fem.Boundary(field[0], mask=index == n_body,
                                                skip=only_axial)
        else:
            bcs["bottom_platen"] = fem.Boundary(field[0], mask=index == n_body)
        bcs["top_platen_lateral"] = fem.Boundary(field[0], mask=index == n_body + 1,
                                                 skip=all_but_axial)
        bcs["top_platen"] = fem.Boundary(field[0], mask=index == n_body + 1, skip=only_axial)
        up = np.zeros(dim)
        up[axial] = 1.0
        contact_kw = {"friction": 0.0}
        touching = side
        if coulomb:
            # every boundary node, the side rolling onto the platens included, with the
            # friction (as in the solver); a sticking node slides elastically by up to 0.5 %
            # of the smallest face cell before it slips (FElupe's advice: 0.5-1 % of a cell)
            touching = np.where(bottom | top)[0]
            if rollover_contact:
                touching = np.union1d(touching, side)
            r_face = np.unique(np.round(r_body[bottom[:n_body]], 12))
            contact_kw = {"friction": float(friction),
                          "elastic_slip": 0.005 * float(np.diff(r_face).min())
                          if friction > 0.0 else None}
        for centre_point, normal in ((n_body, up), (n_body + 1, -up)):
            items.append(fem.ContactRigidPlane(
                field, touching, centre_point, normal, multiplier=contact_penalty,
                items=[solid], **contact_kw))
    dof0, dof1 = fem.dof.partition(field, bcs)

    # ---------------------------------------------------------------- increments
    travel_mm = strain * H
    levels = np.linspace(0.0, travel_mm, int(n_increments) + 1)[1:]
    extra = [s * H for s in check_strains if 0.0 < s <= strain + 1e-12]
    levels = np.unique(np.round(np.r_[levels, extra], 12))
    done = 0.0
    disp, force, contact_force, iterations = [0.0], [0.0], [0.0], []
    for target in levels:
        f_total, f_contact, its = _advance(fem, field, items, bcs, dof0, dof1, axial,
                                           done, target, rollover_contact or coulomb,
                                           symmetric=coulomb)
        done = target
        disp.append(target)
        force.append(f_total)
        contact_force.append(f_contact)
        iterations.append(its)

    deformed = mesh.points[:n_body] + field[0].values[:n_body]
    z_side = deformed[side, axial] if side.size else np.zeros(0)
    bottom_z = 0.5 * travel_mm if coulomb else 0.0
    top_z = H - travel_mm + bottom_z
    below = float(max(0.0, bottom_z - z_side.min())) if z_side.size else 0.0
    above = float(max(0.0, z_side.max() - top_z)) if z_side.size else 0.0
    n_beyond = int(np.sum((z_side < bottom_z - tol) | (z_side > top_z + tol)))
    n_dofs = int(sum(np.asarray(v).size for v in field.values()))
    if axisymmetric:
        volume = 2.0 * np.pi * np.sum(field[0].radius * region.dV)
    else:
        volume = np.sum(region.dV)
    return {
        "displacement_mm": np.asarray(disp),
        "force_N": np.asarray(force),
        "strain": np.asarray(disp) / H,
        "contact_force_N": np.asarray(contact_force),
        "wall_s": time.perf_counter() - t_start,
        "n_dofs": n_dofs,
        "n_dofs_displacement": int(np.asarray(field[0].values[:n_body]).size),
        "cross_section_mm2": float(volume / H),
        "mesh": mesh,
        "deformed_points_mm": deformed,
        "newton_iterations": np.asarray(iterations),
        "rollover": {"below_bottom_mm": below, "above_top_mm": above,
                     "n_nodes_beyond": n_beyond},
    }


def _advance(fem, field, items, bcs, dof0, dof1, axial, start, target, contact,
             symmetric=False, max_bisections=8):
    """Newton-solve from travel ``start`` to ``target`` (mm), bisecting failed steps.

    ``symmetric``: both platens move by half the travel (Coulomb platens), otherwise the top
    face and platen move by all of it. Returns the platen force (N, compression positive),
    the part carried by contact and the Newton iterations used. A failed step restores the
    fields and the contacts' state (their friction history) before it is bisected.
    """
    done, step, iterations = start, target - start, 0
    bisections = 0
    contacts = [item for item in items if hasattr(item, "checkpoint")]
    while done < target - 1e-12 * max(1.0, target):
        trial = min(target, done + step)
        saved = [np.copy(f.values) for f in field.fields]
        saved_contacts = [c.checkpoint() for c in contacts]
        if symmetric:
            bcs["bottom_platen"].update(0.5 * trial)
            bcs["top_platen"].update(-0.5 * trial)
        else:
            bcs["move"].update(-trial)
            if contact:
                bcs["top_platen"].update(-trial)
        ext0 = fem.dof.apply(field, bcs, dof0)
        try:
            # Newton's trial states may overshoot into inverted cells, where tensortrax's
            # powers of negative eigenvalues warn and give NaN; such a step fails and is
            # bisected below, so these warnings carry no information about the answer.
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore", RuntimeWarning)
                warnings.simplefilter("ignore", MatrixRankWarning)
                res = fem.newtonraphson(field, items=items, dof1=dof1, dof0=dof0, ext0=ext0,
                                        verbose=0, solver=_finite_solve)
        except ValueError as exc:          # NewtonConvergenceError is a ValueError
            for f, v in zip(field.fields, saved, strict=True):
                f.values[:] = v
            for c, saved_c in zip(contacts, saved_contacts, strict=True):
                c.restore(saved_c)
            bisections += 1
            if bisections > max_bisections:
                raise RuntimeError(
                    f"FElupe's Newton solve failed from travel {done:.4g} mm toward "
                    f"{trial:.4g} mm even after {max_bisections} bisections: {exc}"
                ) from exc
            step *= 0.5
            continue
        iterations += res.iterations
        done = trial
    fun = res.fun
    f_plate = 0.0 if symmetric else -fem.tools.force(field, fun, bcs["move"])[axial]
    f_contact = -fem.tools.force(field, fun, bcs["top_platen"])[axial] if contact else 0.0
    return float(f_plate + f_contact), float(f_contact), int(iterations)


def _finite_solve(A, b, **kwargs):
    """FElupe's sparse solve, refusing a non-finite system.

    SuperLU crashed the process (a segmentation fault) on a system with NaN entries, from a
    Newton step of a frictional contact run into inverted cells; here such a step fails
    with a ValueError and is bisected like any other.
    """
    A = A.tocsr()
    if not (np.all(np.isfinite(A.data)) and np.all(np.isfinite(b))):
        raise ValueError("the Newton system has non-finite entries")
    return spsolve(A, b)


# ============================================================================== checks
def frictionless_check(mu_Pa: float = 1875.0, alpha: float = 4.9, nu: float = 0.499,
                       strains=(0.1, 0.2, 0.3), **kwargs) -> dict:
    """Frictionless FElupe curve against the homogeneous closed form.

    The frictionless compression of a cylinder is homogeneous uniaxial stress, so the platen
    force is :math:`P(\\lambda) \\pi R^2` with the nominal stress of the compressible
    material, :meth:`solver.Ogden.uniaxial_nominal_stress` (``incompressible=False``), at any
    mesh. This checks the material convention, the axisymmetric force convention (full 2 pi)
    and the units.

    Returns
    -------
    dict
        ``strain`` (n,), ``force_N`` (FElupe), ``closed_form_N``, ``max_rel_error``,
        ``wall_s``, ``area_ratio`` (mesh cross-section / pi R^2).
    """
    from solver import Ogden

    kwargs.setdefault("n_radial", 2)
    kwargs.setdefault("n_axial", 2)
    kwargs.setdefault("grading", 1.0)
    strains = np.asarray(strains, dtype=float)
    out = compression_curve(mu_Pa, alpha, nu, platen="frictionless", strain=float(strains.max()),
                            check_strains=tuple(strains), n_increments=len(strains), **kwargs)
    H = kwargs.get("height_mm", 24.0)
    F = np.interp(strains * H, out["displacement_mm"], out["force_N"])
    lam = 1.0 - strains
    # the mesh's own cross-section: pi R^2 exactly in r-z, the faceted disk in 3D
    area = out["cross_section_mm2"]
    closed = -Ogden(mu_Pa=mu_Pa, alpha=alpha, nu=nu).uniaxial_nominal_stress(
        lam, incompressible=False) * area * _PA_TO_MPA
    return {"strain": strains, "force_N": F, "closed_form_N": closed,
            "max_rel_error": float(np.max(np.abs(F / closed - 1.0))), "wall_s": out["wall_s"],
            "area_ratio": area / (math.pi * (0.5 * kwargs.get("diameter_mm", 38.0)) ** 2)}


def richardson(coarse: float, medium: float, fine: float, ratio: float = 2.0) -> dict:
    """Richardson extrapolation from three solutions on meshes refined by ``ratio``.

    Parameters
    ----------
    coarse, medium, fine : float
        The same quantity on meshes of size h, h/ratio, h/ratio^2.
    ratio : float
        Refinement ratio (> 1).

    Returns
    -------
    dict
        ``order`` (observed order p, NaN if the differences do not shrink monotonically),
        ``extrapolated`` (the limit estimate from the two finest), ``error_fine`` (estimated
        relative error of ``fine``: ``|fine - extrapolated| / |extrapolated|``).

    Notes
    -----
    :math:`p = \\ln(|f_1 - f_2| / |f_2 - f_3|) / \\ln r`,
    :math:`f_\\infty = f_3 + (f_3 - f_2) / (r^p - 1)`. If the differences change sign or do
    not shrink, the estimate falls back to ``|fine - medium|`` as the error bar (order NaN).

    Examples
    --------
    >>> out = richardson(1.0 + 0.04, 1.0 + 0.01, 1.0 + 0.0025)
    >>> round(out["order"], 6), round(out["extrapolated"], 9)
    (2.0, 1.0)
    """
    d1, d2 = medium - coarse, fine - medium
    if d1 == 0.0 or d2 == 0.0 or d1 * d2 < 0 or abs(d2) >= abs(d1):
        return {"order": float("nan"), "extrapolated": float(fine),
                "error_fine": abs(d2) / abs(fine)}
    p = math.log(abs(d1) / abs(d2)) / math.log(ratio)
    f_inf = fine + d2 / (ratio**p - 1.0)
    return {"order": p, "extrapolated": f_inf, "error_fine": abs(fine - f_inf) / abs(f_inf)}


# ============================================================================== convergence
#: The reference case of the convergence study (bonded, 38 x 24 mm, 30 %).
REFERENCE_CASE = {"mu_Pa": 1875.0, "alpha": 4.9, "diameter_mm": 38.0, "height_mm": 24.0,
                  "strain": 0.3, "platen": "bonded"}

#: Mesh ladder of the convergence study: quadratic r-z meshes of n x n cells graded 2n:1
#: toward the bonded rim (the default grading). ``rel_error`` is the largest relative force
#: error at 10/20/30 % strain against the Richardson limit of the 16/32/64 levels, measured
#: for the reference case (mu = 1875 Pa, alpha = 4.9, nu = 0.499, bonded with rollover
#: contact; limits 0.927021 / 2.124929 / 4.081562 N, observed orders 2.5 / 1.5 / -).
#: Re-measure with ``python -m experiments.felupe_reference --study --levels 4 6 8 ...``.
LADDER = (
    {"n_radial": 4, "n_axial": 4, "rel_error": 1.54e-2},
    {"n_radial": 6, "n_axial": 6, "rel_error": 5.75e-3},
    {"n_radial": 8, "n_axial": 8, "rel_error": 2.57e-3},
    {"n_radial": 12, "n_axial": 12, "rel_error": 1.20e-3},
    {"n_radial": 16, "n_axial": 16, "rel_error": 5.93e-4},
    {"n_radial": 24, "n_axial": 24, "rel_error": 1.29e-4},
    {"n_radial": 32, "n_axial": 32, "rel_error": 1.02e-4},
    {"n_radial": 64, "n_axial": 64, "rel_error": 2.7e-5},
)


def convergence_study(nu: float = 0.499, levels=(8, 16, 32, 64), grading: float | None = None,
                      order: str = "quadratic", log=None, **case):
    """Refine the FElupe mesh and report the force at 10/20/30 % strain per level.

    Parameters
    ----------
    nu : float
        Poisson's ratio.
    levels : sequence of int
        Cells along r and along z of each level (each should double the previous one for
        the Richardson estimate).
    grading, order : see :func:`compression_curve` (``grading=None``: 2 n per level).
    log : callable, optional
        Called with a progress line after each level (e.g. ``print`` to stderr).
    **case
        Overrides of :data:`REFERENCE_CASE` and further :func:`compression_curve` options.

    Returns
    -------
    rows : list of dict
        Per level: ``n``, ``n_dofs``, ``wall_s``, ``F10_N``, ``F20_N``, ``F30_N`` (as far as
        the strain goes), ``change`` (largest relative change from the previous level),
        ``below_bottom_mm`` (rollover penetration) and ``newton_iterations``.
    richardson_by_strain : dict
        Per check strain, :func:`richardson` of the three finest levels (with the refinement
        ratio of their cell counts) plus ``rel_error`` of every level against the limit.
    """
    params = {**REFERENCE_CASE, **case}
    mu_Pa, alpha = params.pop("mu_Pa"), params.pop("alpha")
    strains = [s for s in CHECK_STRAINS if s <= params["strain"] + 1e-12]
    rows = []
    for n in levels:
        out = compression_curve(mu_Pa, alpha, nu, n_radial=n, n_axial=n, grading=grading,
                                order=order, **params)
        H = params["height_mm"]
        row = {"n": n, "grading": grading if grading is not None else 2.0 * n,
               "n_dofs": out["n_dofs"], "wall_s": out["wall_s"],
               "below_bottom_mm": out["rollover"]["below_bottom_mm"],
               "newton_iterations": int(out["newton_iterations"].sum())}
        for s in strains:
            row[f"F{round(100 * s)}_N"] = float(np.interp(s * H, out["displacement_mm"],
                                                          out["force_N"]))
        if rows:
            row["change"] = max(abs(row[k] / rows[-1][k] - 1.0)
                                for k in row if k.startswith("F"))
        else:
            row["change"] = None
        rows.append(row)
        if log is not None:
            log(json.dumps(row))
    extrap = {}
    if len(rows) >= 3:
        ratio = levels[-1] / levels[-2]
        for s in strains:
            key = f"F{round(100 * s)}_N"
            est = richardson(rows[-3][key], rows[-2][key], rows[-1][key], ratio=ratio)
            est["rel_error"] = [abs(r[key] / est["extrapolated"] - 1.0) for r in rows]
            extrap[key] = est
    return rows, extrap


def mesh_for_accuracy(accuracy: float) -> dict:
    """Coarsest :data:`LADDER` level whose measured force error is below ``accuracy``.

    Parameters
    ----------
    accuracy : float
        Relative force error allowed (e.g. 0.005 for 0.5 %).

    Returns
    -------
    dict
        The ladder entry (``n_radial``, ``n_axial``, ``rel_error``).
    """
    if not (math.isfinite(accuracy) and accuracy > 0):
        raise ValueError(f"accuracy={accuracy} must be a positive fraction")
    for level in LADDER:
        if level["rel_error"] <= accuracy:
            return dict(level)
    raise ValueError(f"no FElupe mesh of the ladder reaches accuracy={accuracy:g}; the finest "
                     f"measured {LADDER[-1]['rel_error']:.2g}")


def time_at_accuracy(accuracy: float, mu_Pa: float = 1875.0, alpha: float = 4.9,
                     nu: float = 0.499, repeat: int = 1, **kwargs) -> dict:
    """Wall time of one FElupe reference curve at a stated accuracy (for the benchmark).

    The mesh is :func:`mesh_for_accuracy`'s (errors measured for the bonded reference case);
    the curve is the bonded 30 % compression with the default 10 increments.

    Returns
    -------
    dict
        ``accuracy`` (asked), ``rel_error`` (measured for that mesh), ``n_radial``,
        ``n_axial``, ``n_dofs``, ``wall_s`` (the best of ``repeat`` solves),
        ``force_N_at_max`` (N).
    """
    level = mesh_for_accuracy(accuracy)
    best = None
    for _ in range(max(1, int(repeat))):
        out = compression_curve(mu_Pa, alpha, nu, n_radial=level["n_radial"],
                                n_axial=level["n_axial"], **kwargs)
        if best is None or out["wall_s"] < best["wall_s"]:
            best = out
    return {"accuracy": accuracy, **level, "n_dofs": best["n_dofs"], "wall_s": best["wall_s"],
            "force_N_at_max": float(best["force_N"][-1])}


# ============================================================================== command line
def _json_safe(value):
    """NaN -> None (strict JSON), arrays -> lists, recursively."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return None if not math.isfinite(value) else float(value)
    return value


def main(argv=None) -> int:
    """Run the convergence study (``--study``) or the frictionless check; JSON on stdout."""
    parser = argparse.ArgumentParser(prog="python -m experiments.felupe_reference",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--study", action="store_true", help="run the mesh convergence study")
    parser.add_argument("--nu", type=float, default=0.499)
    parser.add_argument("--levels", type=int, nargs="+", default=[8, 16, 32, 64])
    parser.add_argument("--grading", type=float, default=None,
                        help="largest / smallest cell size (default: 2 n per level)")
    parser.add_argument("--order", choices=("quadratic", "linear"), default="quadratic")
    parser.add_argument("--no-contact", action="store_true", help="bonded without rollover")
    args = parser.parse_args(argv)

    def log(line):
        print(line, file=sys.stderr, flush=True)

    if args.study:
        rows, extrap = convergence_study(nu=args.nu, levels=tuple(args.levels),
                                         grading=args.grading, order=args.order, log=log,
                                         rollover_contact=not args.no_contact)
        print(json.dumps(_json_safe({"nu": args.nu, "grading": args.grading,
                                     "order": args.order, "contact": not args.no_contact,
                                     "rows": rows, "richardson": extrap}), indent=1))
    else:
        check = frictionless_check(nu=args.nu)
        print(json.dumps(_json_safe(check), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
