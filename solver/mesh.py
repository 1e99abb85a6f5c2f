"""Meshes of the compression sample.

A :class:`Mesh` is a small frozen record that cleans its inputs once: float64 C-contiguous
point coordinates in metres, int32 C-contiguous connectivity, and one material index per cell
(the layer it belongs to). Two cell types exist:

``"quad"``
    4-node quadrilaterals in the axisymmetric r-z half-plane, counter-clockwise; coordinate 0
    is the radius r >= 0, coordinate 1 the height z.
``"hexahedron"``
    8-node hexahedra in x-y-z (VTK node order), z along the cylinder axis.

The sample always stands on the plane z = 0 and its top face is the plane z = height.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["Mesh", "axisymmetric_cylinder", "graded_spacing", "hex_block", "hex_cylinder"]


@dataclasses.dataclass(frozen=True)
class Mesh:
    """Finite element mesh of the sample.

    Parameters
    ----------
    points : array_like, shape (n_nodes, dim)
        Node coordinates (m); ``dim`` is 2 for ``"quad"`` (r, z) and 3 for ``"hexahedron"``.
    cells : array_like, shape (n_cells, n_cell_nodes)
        Connectivity (0-based node indices).
    cell_type : {"quad", "hexahedron"}
    cell_material : array_like of int, shape (n_cells,), optional
        Index of each cell's material (layer); zeros if omitted.
    """

    points: np.ndarray
    cells: np.ndarray
    cell_type: str
    cell_material: np.ndarray | None = None

    def __post_init__(self):
        points = np.ascontiguousarray(self.points, dtype=np.float64)
        cells = np.ascontiguousarray(self.cells, dtype=np.int32)
        expected = {"quad": (2, 4), "hexahedron": (3, 8)}
        if self.cell_type not in expected:
            raise ValueError(f"cell_type {self.cell_type!r} is not 'quad' or 'hexahedron'")
        dim, nn = expected[self.cell_type]
        if points.ndim != 2 or points.shape[1] != dim:
            raise ValueError(f"{self.cell_type} mesh needs points of shape (n, {dim}), "
                             f"got {points.shape}")
        if cells.ndim != 2 or cells.shape[1] != nn:
            raise ValueError(f"{self.cell_type} mesh needs cells of shape (n, {nn}), "
                             f"got {cells.shape}")
        if cells.size and (cells.min() < 0 or cells.max() >= len(points)):
            raise ValueError("cell connectivity refers to nodes that do not exist")
        if self.cell_type == "quad" and np.any(points[:, 0] < -1e-12):
            raise ValueError("axisymmetric mesh has nodes at negative radius")
        if self.cell_material is None:
            mat = np.zeros(len(cells), dtype=np.int32)
        else:
            mat = np.ascontiguousarray(self.cell_material, dtype=np.int32)
            if mat.shape != (len(cells),):
                raise ValueError("cell_material needs one entry per cell")
        for name, value in (("points", points), ("cells", cells), ("cell_material", mat)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @property
    def dim(self) -> int:
        """Spatial dimension of the point coordinates."""
        return self.points.shape[1]

    @property
    def n_nodes(self) -> int:
        """Number of nodes."""
        return self.points.shape[0]

    @property
    def n_cells(self) -> int:
        """Number of cells."""
        return self.cells.shape[0]

    @property
    def height_m(self) -> float:
        """Height of the sample (m)."""
        return float(self.points[:, -1].max() - self.points[:, -1].min())

    @property
    def radius_m(self) -> float:
        r"""Outer radius of the sample (m).

        For a hexahedral mesh: the radius of the circle with the area of the bottom face,
        :math:`\sqrt{A/\pi}` (a faceted cylinder's nodes may lie slightly outside it, see
        :func:`hex_cylinder`); :attr:`outer_radius_m` is the largest nodal radius.
        """
        if self.cell_type == "quad":
            return float(self.points[:, 0].max())
        return float(np.sqrt(self.bottom_area_m2 / np.pi))

    @property
    def outer_radius_m(self) -> float:
        """Largest distance of a node from the axis (m)."""
        if self.cell_type == "quad":
            return float(self.points[:, 0].max())
        return float(np.hypot(self.points[:, 0], self.points[:, 1]).max())

    @property
    def bottom_area_m2(self) -> float:
        """Area of the face that stands on the bottom platen (m^2)."""
        z = self.points[:, -1]
        if self.cell_type == "quad":
            return float(np.pi * self.points[:, 0].max() ** 2)
        bottom = self.cells[:, :4]  # VTK order: the bottom face of every hexahedron
        on = np.all(np.abs(z[bottom] - z.min()) <= 1e-9 * self.height_m, axis=1)
        xy = self.points[bottom[on], :2]  # (n_faces, 4, 2)
        x, y = xy[..., 0], xy[..., 1]
        # shoelace formula per quadrilateral
        area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y,
                                   axis=1))
        return float(area.sum())

    def node_sets(self, tol_m: float | None = None) -> dict[str, np.ndarray]:
        """Boolean node masks: ``bottom``, ``top``, ``axis`` (x = y = 0 for hexahedra), ``side``.

        Parameters
        ----------
        tol_m : float, optional
            Geometric tolerance (m); default 1e-9 of the sample height.
        """
        tol = 1e-9 * self.height_m if tol_m is None else tol_m
        z = self.points[:, -1]
        out = {"bottom": np.abs(z - z.min()) <= tol, "top": np.abs(z - z.max()) <= tol}
        if self.cell_type == "quad":
            r = self.points[:, 0]
            out["axis"] = r <= tol
        else:
            r = np.hypot(self.points[:, 0], self.points[:, 1])
            out["axis"] = r <= tol
        out["side"] = np.abs(r - r.max()) <= max(tol, 1e-6 * r.max())
        return out

    def boundary_nodes(self) -> np.ndarray:
        """Boolean mask of the nodes on the boundary (faces used by one cell only)."""
        if self.cell_type == "quad":
            faces = np.concatenate([self.cells[:, [i, (i + 1) % 4]] for i in range(4)])
        else:
            local = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6],
                     [3, 0, 4, 7]]
            faces = np.concatenate([self.cells[:, f] for f in local])
        key = np.sort(faces, axis=1)
        _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        on_boundary = counts[inverse.ravel()] == 1
        mask = np.zeros(self.n_nodes, dtype=bool)
        mask[faces[on_boundary].ravel()] = True
        return mask

    def with_points(self, points) -> Mesh:
        """The same topology with new coordinates (e.g. a deformed configuration)."""
        return dataclasses.replace(self, points=np.asarray(points, dtype=float))


def graded_spacing(length: float, n: int, ratio: float, two_sided: bool = False) -> np.ndarray:
    """Node positions on [0, length] with geometric grading.

    Parameters
    ----------
    length : float
        Interval length.
    n : int
        Number of intervals (elements), at least 1.
    ratio : float
        Size of the largest element over the smallest, >= 1.
    two_sided : bool
        ``False``: elements shrink towards ``length``. ``True``: they shrink towards both ends,
        symmetric about the middle.

    Returns
    -------
    ndarray, shape (n + 1,)
        Increasing positions from 0 to ``length``.
    """
    if n < 1:
        raise ValueError(f"need at least one element, got n={n}")
    if ratio < 1.0:
        raise ValueError(f"grading ratio {ratio} must be >= 1")
    if two_sided:
        half = n // 2
        if n % 2:  # odd: a middle element of the largest size
            sizes_half = _geometric_sizes(half + 1, ratio)[::-1]  # small ... large
            sizes = np.concatenate([sizes_half[:-1], sizes_half[-1:], sizes_half[:-1][::-1]])
        else:
            sizes_half = _geometric_sizes(half, ratio)[::-1]
            sizes = np.concatenate([sizes_half, sizes_half[::-1]])
    else:
        sizes = _geometric_sizes(n, ratio)  # large ... small
    x = np.concatenate([[0.0], np.cumsum(sizes)])
    return x * (length / x[-1])


def _geometric_sizes(n: int, ratio: float) -> np.ndarray:
    """Sizes decreasing geometrically from ``ratio`` to 1 over n elements."""
    if n == 1:
        return np.ones(1)
    q = ratio ** (-1.0 / (n - 1))
    return ratio * q ** np.arange(n)


def axisymmetric_cylinder(
    diameter_mm: float = 38.0,
    height_mm: float = 24.0,
    n_radial: int = 14,
    n_axial: int = 18,
    radial_ratio: float = 3.0,
    axial_ratio: float = 3.0,
    layer_heights_mm: tuple[float, ...] | None = None,
) -> Mesh:
    """Structured r-z quad mesh of a cylinder, graded towards the bonded rims.

    Elements shrink geometrically towards the outer radius and towards both platens, where
    the bonded rim concentrates the strain.

    Parameters
    ----------
    diameter_mm, height_mm : float
        Sample size (mm).
    n_radial, n_axial : int
        Elements along the radius and along the height.
    radial_ratio, axial_ratio : float
        Largest over smallest element size along each direction (1 = uniform).
    layer_heights_mm : tuple of float, optional
        Heights (mm) of material interfaces; cells between consecutive interfaces get
        consecutive material indices from the bottom. Interfaces are snapped to the nearest
        node row.

    Returns
    -------
    Mesh
        ``cell_type="quad"``, coordinates in metres.
    """
    if diameter_mm <= 0 or height_mm <= 0:
        raise ValueError(f"sample size must be positive: diameter {diameter_mm} mm, "
                         f"height {height_mm} mm")
    R = 0.5e-3 * diameter_mm
    H = 1e-3 * height_mm
    r = graded_spacing(R, n_radial, radial_ratio)
    z = graded_spacing(H, n_axial, axial_ratio, two_sided=True)
    rr, zz = np.meshgrid(r, z, indexing="xy")  # (n_axial+1, n_radial+1)
    points = np.column_stack([rr.ravel(), zz.ravel()])
    nr = n_radial + 1
    j, i = np.meshgrid(np.arange(n_axial), np.arange(n_radial), indexing="ij")
    n0 = (j * nr + i).ravel()
    cells = np.column_stack([n0, n0 + 1, n0 + 1 + nr, n0 + nr])
    material = np.zeros(len(cells), dtype=np.int32)
    if layer_heights_mm:
        zc = 0.5 * (z[:-1] + z[1:])[j.ravel()]
        for interface in sorted(layer_heights_mm):
            material += zc > 1e-3 * interface
    return Mesh(points=points, cells=cells, cell_type="quad", cell_material=material)


def _layer_planes(z: np.ndarray, layer_heights_mm, height_m: float) -> np.ndarray:
    """Move the node plane nearest to each interface onto it (exactly)."""
    z = z.copy()
    used = set()
    for interface in sorted(layer_heights_mm):
        zi = 1e-3 * interface
        if not 0.0 < zi < height_m:
            raise ValueError(f"layer interface at {interface} mm is not inside the sample "
                             f"(0, {1e3 * height_m:g}) mm")
        k = int(np.argmin(np.abs(z - zi)))
        if k in (0, len(z) - 1) or k in used:
            raise ValueError(f"layer interface at {interface} mm has no node plane of its own "
                             f"among {len(z) - 1} axial elements; use more (n_axial)")
        used.add(k)
        z[k] = zi
    return z


def _extrude(section: np.ndarray, quads: np.ndarray, z: np.ndarray):
    """Hexahedra from a counter-clockwise quad section and increasing node planes ``z``."""
    n2 = len(section)
    nz = len(z) - 1
    points = np.column_stack([np.tile(section, (nz + 1, 1)), np.repeat(z, n2)])
    layer = (np.arange(nz) * n2)[:, None, None]  # (nz, 1, 1)
    bottom = quads[None, :, :] + layer  # (nz, n_quads, 4)
    cells = np.concatenate([bottom, bottom + n2], axis=2).reshape(-1, 8)
    return points, cells


def _materials_by_height(points, cells, layer_heights_mm) -> np.ndarray:
    zc = points[cells, 2].mean(axis=1)
    material = np.zeros(len(cells), dtype=np.int32)
    for interface in sorted(layer_heights_mm or ()):
        material += zc > 1e-3 * interface
    return material


def hex_cylinder(
    diameter_mm: float = 38.0,
    height_mm: float = 24.0,
    n_core: int = 6,
    n_ring: int = 5,
    n_axial: int = 14,
    radial_ratio: float = 2.5,
    axial_ratio: float = 3.0,
    layer_heights_mm: tuple[float, ...] | None = None,
    exact_area: bool = True,
    core_rounding: float = 0.3,
) -> Mesh:
    r"""O-grid ("butterfly") hexahedral mesh of a cylinder, graded towards the bonded rims.

    The cross-section is a square core of ``n_core x n_core`` quads (slightly rounded, by
    blending the square with the elliptical square-to-disc map) surrounded by a ring of
    ``n_ring`` quads from the core to the outer surface, ``4 n_core`` around; no element is
    degenerate and no node is singular on the axis. The ring's elements shrink geometrically
    towards the outer surface and the axial layers towards both faces (the bonded rims,
    where the strain concentrates); the core's element size matches the ring's first row.
    The section is extruded along z through ``n_axial`` element layers.

    The default (2184 hexahedra) puts the bonded 30 % force of the 38 x 24 mm sample within
    about 0.5 % of the converged value, like the axisymmetric default mesh; 8, 7, 20 (5760
    hexahedra, the thesis's size) within 0.4 % (see tests/test_hex_convergence.py).

    Parameters
    ----------
    diameter_mm, height_mm : float
        Sample size (mm).
    n_core : int
        Elements along a side of the core square (>= 1); ``4 n_core`` around the
        circumference. Even values put nodes on the axis and on the x and y planes.
    n_ring : int
        Elements across the ring (>= 1): from the axis to the surface there are about
        ``n_core / 2 + n_ring`` elements.
    n_axial : int
        Elements along the height.
    radial_ratio, axial_ratio : float
        Largest over smallest element size across the ring and along the height (>= 1).
    layer_heights_mm : tuple of float, optional
        Heights (mm) of material interfaces. The node plane nearest to each is moved onto
        it, so every element lies in one layer; cells get consecutive material indices from
        the bottom (``cell_material``).
    exact_area : bool
        ``True``: the outer nodes lie on a circle slightly larger than the sample, by the
        factor :math:`\sqrt{\theta / \sin\theta}` (:math:`\theta = 2\pi/(4 n_{core})`),
        so that the faceted cross-section has exactly the sample's area :math:`\pi R^2` (an
        inscribed polygon of 32 sides is 0.64 % short, which would show up one to one in
        the force). ``False``: the outer nodes lie on the circle.
    core_rounding : float
        Blend (0 to 1) of the core square towards a disc; rounding opens the ring elements'
        135 degree angles at the core corners.

    Returns
    -------
    Mesh
        ``cell_type="hexahedron"``, coordinates in metres, z along the axis from 0 to H.

    Examples
    --------
    >>> mesh = hex_cylinder(38.0, 24.0, n_core=4, n_ring=3, n_axial=6)
    >>> mesh.n_cells, round(mesh.radius_m * 2e3, 9)
    (384, 38.0)
    """
    if diameter_mm <= 0 or height_mm <= 0:
        raise ValueError(f"sample size must be positive: diameter {diameter_mm} mm, "
                         f"height {height_mm} mm")
    for name, value in (("n_core", n_core), ("n_ring", n_ring), ("n_axial", n_axial)):
        if int(value) != value or value < 1:
            raise ValueError(f"{name}={value} must be a positive integer")
    if not 0.0 <= core_rounding < 1.0:
        raise ValueError(f"core_rounding={core_rounding} must lie in [0, 1)")
    n_core, n_ring, n_axial = int(n_core), int(n_ring), int(n_axial)
    R = 0.5e-3 * diameter_mm
    H = 1e-3 * height_mm
    n_around = 4 * n_core
    theta = 2.0 * np.pi / n_around
    R_nodes = R * np.sqrt(theta / np.sin(theta)) if exact_area else R
    # ring spacing, fine at the surface; core half-width s so that the core element size
    # 2 s / n_core equals the ring's first (largest) element (R - s) * f0
    t = graded_spacing(1.0, n_ring, radial_ratio)
    f0 = t[1] - t[0]
    s = R * f0 / (f0 + 2.0 / n_core)

    # core: (n_core + 1)^2 points, index i along x, j along y
    xi = np.linspace(-1.0, 1.0, n_core + 1)
    XI, ETA = np.meshgrid(xi, xi, indexing="ij")  # (i, j)
    disc_x = XI * np.sqrt(1.0 - 0.5 * ETA**2)
    disc_y = ETA * np.sqrt(1.0 - 0.5 * XI**2)
    w = core_rounding
    core = s * np.stack([(1 - w) * XI + w * disc_x, (1 - w) * ETA + w * disc_y], axis=-1)
    core_id = np.arange((n_core + 1) ** 2).reshape(n_core + 1, n_core + 1)
    i, j = np.meshgrid(np.arange(n_core), np.arange(n_core), indexing="ij")
    core_quads = np.stack([core_id[i, j], core_id[i + 1, j], core_id[i + 1, j + 1],
                           core_id[i, j + 1]], axis=-1).reshape(-1, 4)
    # the core's boundary, counter-clockwise from the corner (1, -1)
    n = n_core
    ring0 = np.concatenate([core_id[n, :n], core_id[n:0:-1, n], core_id[0, n:0:-1],
                            core_id[:n, 0]])
    angles = -0.25 * np.pi + theta * np.arange(n_around)
    rim = R_nodes * np.column_stack([np.cos(angles), np.sin(angles)])
    inner = core.reshape(-1, 2)[ring0]  # (n_around, 2)
    ring_pts = [(1.0 - tj) * inner + tj * rim for tj in t[1:]]  # rows 1..n_ring
    n_core_pts = (n_core + 1) ** 2
    ring_id = np.vstack([ring0[None, :]] + [n_core_pts + k * n_around + np.arange(n_around)
                                            [None, :] for k in range(n_ring)])
    k = np.arange(n_around)
    kp = (k + 1) % n_around
    ring_quads = np.concatenate([np.column_stack([ring_id[r, k], ring_id[r + 1, k],
                                                  ring_id[r + 1, kp], ring_id[r, kp]])
                                 for r in range(n_ring)])
    section = np.vstack([core.reshape(-1, 2)] + ring_pts)
    quads = np.vstack([core_quads, ring_quads])

    z = graded_spacing(H, n_axial, axial_ratio, two_sided=True)
    if layer_heights_mm:
        z = _layer_planes(z, layer_heights_mm, H)
    points, cells = _extrude(section, quads, z)
    material = _materials_by_height(points, cells, layer_heights_mm)
    return Mesh(points=points, cells=cells, cell_type="hexahedron", cell_material=material)


def hex_block(
    width_mm: float,
    depth_mm: float,
    height_mm: float,
    nx: int,
    ny: int,
    nz: int,
    layer_heights_mm: tuple[float, ...] | None = None,
) -> Mesh:
    """Uniform hexahedral mesh of a rectangular block centred on the z axis.

    Parameters
    ----------
    width_mm, depth_mm, height_mm : float
        Size along x, y and z (mm); the block spans ``[-w/2, w/2] x [-d/2, d/2] x [0, h]``.
    nx, ny, nz : int
        Elements along x, y and z (even ``nx`` and ``ny`` put nodes on the axis).
    layer_heights_mm : tuple of float, optional
        Material interfaces (mm), as in :func:`hex_cylinder`.

    Returns
    -------
    Mesh
        ``cell_type="hexahedron"``; :attr:`Mesh.radius_m` is the radius of equal area.
    """
    for name, value in (("width_mm", width_mm), ("depth_mm", depth_mm),
                        ("height_mm", height_mm)):
        if not value > 0:
            raise ValueError(f"{name}={value} must be positive")
    for name, value in (("nx", nx), ("ny", ny), ("nz", nz)):
        if int(value) != value or value < 1:
            raise ValueError(f"{name}={value} must be a positive integer")
    x = 1e-3 * width_mm * np.linspace(-0.5, 0.5, nx + 1)
    y = 1e-3 * depth_mm * np.linspace(-0.5, 0.5, ny + 1)
    H = 1e-3 * height_mm
    z = np.linspace(0.0, H, nz + 1)
    if layer_heights_mm:
        z = _layer_planes(z, layer_heights_mm, H)
    X, Y = np.meshgrid(x, y, indexing="ij")
    section = np.column_stack([X.ravel(), Y.ravel()])
    ids = np.arange(len(section)).reshape(nx + 1, ny + 1)
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    quads = np.stack([ids[i, j], ids[i + 1, j], ids[i + 1, j + 1], ids[i, j + 1]],
                     axis=-1).reshape(-1, 4)
    points, cells = _extrude(section, quads, z)
    material = _materials_by_height(points, cells, layer_heights_mm)
    return Mesh(points=points, cells=cells, cell_type="hexahedron", cell_material=material)
