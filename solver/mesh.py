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

__all__ = ["Mesh", "axisymmetric_cylinder", "graded_spacing"]


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
        """Outer radius of the sample (m)."""
        if self.cell_type == "quad":
            return float(self.points[:, 0].max())
        return float(np.hypot(self.points[:, 0], self.points[:, 1]).max())

    def node_sets(self, tol_m: float | None = None) -> dict[str, np.ndarray]:
        """Boolean node masks: ``bottom``, ``top``, ``axis`` (axisymmetric only), ``side``.

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
            out["axis"] = np.zeros(self.n_nodes, dtype=bool)
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
