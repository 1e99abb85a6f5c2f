"""Explicit finite element simulation of platen compression of soft cylinders.

Public surface::

    from solver import Ogden, NeoHookean, Prony          # materials (Abaqus/Miller-Chinzei Ogden)
    from solver import CompressionTest                     # what the rig does
    from solver import Mesh, axisymmetric_cylinder         # meshes: axisymmetric quads,
    from solver import hex_cylinder, hex_block             # 3D hexahedra (O-grid, block)
    from solver import simulate, SimulationResult, SolverInstability
    from solver import write_vtk, write_png                # files to look at (also methods)

``solver`` knows nothing of rig logs or fitting; :mod:`calib` builds on it.
"""

from .explicit import DEFAULT_QUASI_STATIC_RATIO, SimulationResult, SolverInstability, simulate
from .loading import PLATENS, CompressionTest
from .materials import NeoHookean, Ogden, Prony, bulk_modulus
from .mesh import Mesh, axisymmetric_cylinder, hex_block, hex_cylinder
from .output import write_png, write_vtk

__all__ = [
    "CompressionTest",
    "DEFAULT_QUASI_STATIC_RATIO",
    "Mesh",
    "NeoHookean",
    "Ogden",
    "PLATENS",
    "Prony",
    "SimulationResult",
    "SolverInstability",
    "axisymmetric_cylinder",
    "bulk_modulus",
    "hex_block",
    "hex_cylinder",
    "simulate",
    "write_png",
    "write_vtk",
]
