"""Files a person can look at: the deformed mesh as VTK, a PNG of the section and the curve.

:func:`write_vtk` writes the final deformed mesh of a :class:`~solver.SimulationResult` through
meshio (``.vtu`` XML or ``.vtk`` legacy; ParaView opens both) with

- point data ``displacement_m`` (n_nodes, 3);
- cell data ``cauchy_stress_Pa`` (n_cells, 6; xx, yy, zz, xy, yz, xz, which ParaView reads as
  a symmetric tensor), ``sigma_zz_Pa`` (axial Cauchy stress, compression negative),
  ``von_mises_Pa`` and ``material`` (layer index).

An axisymmetric result is written as its r-z section in the x-z plane (x = r, y = hoop).

:func:`write_png` draws the deformed section (the y = 0 plane of a hexahedral mesh, mirrored
r-z section of an axisymmetric one) coloured by the axial Cauchy stress, beside the force
against platen travel.

Both write atomically: to a temporary file beside the target, then moved over it.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["vtk_mesh", "write_vtk", "write_png", "section_polygons"]

_VTK_FORMATS = {".vtu": "vtu", ".vtk": "vtk"}

#: Local faces of a VTK hexahedron.
_HEX_FACES = ((0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6),
              (3, 0, 4, 7))


@contextlib.contextmanager
def _atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside ``path`` (same suffix); move it over ``path`` on success."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=target.suffix,
                               dir=target.parent)
    os.close(fd)
    try:
        yield tmp
        # mkstemp creates the file private (0600); give it the usual permissions
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def vtk_mesh(result):
    """The deformed mesh of ``result`` with its fields, as a :class:`meshio.Mesh`.

    Parameters
    ----------
    result : SimulationResult

    Returns
    -------
    meshio.Mesh
        Points in metres (deformed), cell and point data as in the module notes.
    """
    import meshio

    mesh = result.mesh
    u = result.displacement_m
    if mesh.cell_type == "quad":
        # the r-z section in the x-z plane: x = r, y = 0 (hoop), z = z
        points = np.column_stack([mesh.points[:, 0] + u[:, 0], np.zeros(mesh.n_nodes),
                                  mesh.points[:, 1] + u[:, 1]])
        displacement = np.column_stack([u[:, 0], np.zeros(mesh.n_nodes), u[:, 1]])
    else:
        points = mesh.points + u
        displacement = u
    stress = result.cell_stress_Pa
    if stress is None:
        raise ValueError("the result carries no cell stress (cell_stress_Pa is None)")
    return meshio.Mesh(
        points=points,
        cells=[(mesh.cell_type, mesh.cells)],
        point_data={"displacement_m": displacement},
        cell_data={"cauchy_stress_Pa": [stress], "sigma_zz_Pa": [stress[:, 2]],
                   "von_mises_Pa": [result.von_mises_Pa()],
                   "material": [mesh.cell_material.astype(np.int32)]},
    )


def write_vtk(result, path: str | os.PathLike) -> Path:
    """Write the deformed mesh and its fields to ``path`` (``.vtu`` or ``.vtk``), atomically.

    Raises
    ------
    ValueError
        If the suffix is neither ``.vtu`` nor ``.vtk``.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in _VTK_FORMATS:
        raise ValueError(f"{path}: VTK output needs a .vtu or .vtk file name, not "
                         f"{suffix or 'no suffix'!r}")
    import meshio

    data = vtk_mesh(result)
    with _atomic_path(path) as tmp:
        meshio.write(tmp, data, file_format=_VTK_FORMATS[suffix])
    return Path(path)


def section_polygons(result) -> tuple[np.ndarray, np.ndarray]:
    """Deformed polygons of the section through the axis, and their axial Cauchy stress.

    Hexahedra: the faces lying in the reference plane y = 0 (there is one when ``n_core`` of
    :func:`~solver.mesh.hex_cylinder` is even), drawn in (x, z). Quads: the r-z section and
    its mirror image at -r.

    Returns
    -------
    polygons : ndarray, shape (n, 4, 2)
        Corner coordinates (mm).
    sigma_zz : ndarray, shape (n,)
        Axial Cauchy stress of the element each polygon belongs to (Pa).

    Raises
    ------
    ValueError
        If a hexahedral mesh has no faces in the plane y = 0.
    """
    mesh = result.mesh
    x = 1e3 * result.deformed_points_m
    s_zz = result.cell_stress_Pa[:, 2]
    if mesh.cell_type == "quad":
        poly = x[mesh.cells]  # (n, 4, 2) in (r, z)
        mirror = poly * np.array([-1.0, 1.0])
        return np.concatenate([poly, mirror]), np.concatenate([s_zz, s_zz])
    tol = 1e-9 * mesh.height_m
    on_plane = np.abs(mesh.points[:, 1]) <= tol
    polys, values = [], []
    for face in _HEX_FACES:
        nodes = mesh.cells[:, face]  # (n_cells, 4)
        hit = on_plane[nodes].all(axis=1)
        polys.append(x[nodes[hit]][:, :, [0, 2]])
        values.append(s_zz[hit])
    polygons = np.concatenate(polys)
    if not len(polygons):
        raise ValueError("the hexahedral mesh has no faces in the plane y = 0 to draw "
                         "(use an even n_core)")
    return polygons, np.concatenate(values)


def write_png(result, path: str | os.PathLike, title: str | None = None) -> Path:
    """Draw the deformed section (axial Cauchy stress) and the force curve to a PNG.

    Parameters
    ----------
    result : SimulationResult
    path : str or path-like
        Target file (``.png``), written atomically.
    title : str, optional
        Figure title; default: mesh kind, element count and final force.
    """
    if Path(path).suffix.lower() != ".png":
        raise ValueError(f"{path}: the picture is written as PNG; name it *.png")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure

    polygons, s_zz = section_polygons(result)
    fig = Figure(figsize=(11.0, 4.6), layout="constrained")
    FigureCanvasAgg(fig)
    ax_sec, ax_curve = fig.subplots(1, 2, width_ratios=(1.35, 1.0))
    coll = PolyCollection(polygons, array=1e-3 * s_zz, cmap="viridis", edgecolors="0.25",
                          linewidths=0.3)
    ax_sec.add_collection(coll)
    radius, height = 1e3 * result.mesh.radius_m, 1e3 * result.mesh.height_m
    ax_sec.plot([-radius, radius, radius, -radius, -radius], [0, 0, height, height, 0], "--",
                color="0.5", lw=0.8)
    ax_sec.autoscale_view()
    ax_sec.set_aspect("equal")
    ax_sec.set_xlabel("x (mm)" if result.mesh.cell_type != "quad" else "r (mm), mirrored")
    ax_sec.set_ylabel("z (mm)")
    ax_sec.set_title("deformed section at full travel (dashed: undeformed)")
    fig.colorbar(coll, ax=ax_sec, label="axial Cauchy stress (kPa)", shrink=0.85)
    ax_curve.plot(result.displacement_mm, result.force_N, "-", color="C1")
    ax_curve.set_xlabel("platen travel (mm)")
    ax_curve.set_ylabel("platen force (N)")
    ax_curve.grid(alpha=0.3)
    ax_curve.set_title("force against travel")
    kind = "hexahedra" if result.mesh.cell_type == "hexahedron" else "axisymmetric quads"
    fig.suptitle(title or f"{result.mesh.n_cells} {kind}: {result.force_N[-1]:.3f} N at "
                 f"{result.displacement_mm[-1]:.2f} mm")
    with _atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    return Path(path)
