"""Forward solves stored with the package: the expensive Coulomb solves of the nominal sample.

Platen slip's discretisation correction (:class:`calib.discover.PlatenSlip`) needs, at every
alpha of the campaign-wide lattice, Coulomb solves on the finer correction mesh: about 10 s
each and 40 to 50 s per alpha: 431 of the 1564 s of the embedded campaign's discovery run
in one process under a profiler (2026-12-07).
Those solves depend on nothing a campaign measures beyond the sample's aspect ratio: with
Poisson's ratio fixed, the ramp set relative to the lowest natural period and the mesh
proportional to the sample (:func:`solver.simulate`), a solve on a sample scaled by ``c`` is
the same solve with every length times ``c`` and every unit force (N/Pa) times ``c**2``
(checked to 4e-10 relative on 38 x 24 mm against 38.5 x 24.3 mm, friction 0.15). So they are
stored here as dimensionless curves, travel over height and unit force over height squared,
for the nominal sample of the rig (38 x 24 mm) on the lattice alphas, and
:meth:`calib.fit.ForwardModel.curve` reads a stored curve instead of solving it.

A stored curve is used only by the solver it was made with: the file carries a fingerprint of
the solver's source and of :class:`calib.fit.ForwardModel` (:func:`fingerprint`); on any other
the store is ignored (with a warning) and every curve is solved. ``python -m
experiments.stored_solves`` makes the file again; ``tests/test_stored.py`` checks that the
fingerprint is the current one and that stored curves equal fresh solves.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import json
import math
import warnings
from pathlib import Path

import numpy as np

__all__ = ["PATH", "StoredSolves", "fingerprint", "stored_solves", "normal_key"]

#: The file of stored solves (see :mod:`experiments.stored_solves`).
PATH = Path(__file__).parent / "data" / "stored_solves.npz"
#: Relative tolerance on the aspect ratio (diameter over height) of a stored solve.
ASPECT_RTOL = 1e-9


def fingerprint() -> str:
    """SHA-256 of the solver's source files and of :class:`calib.fit.ForwardModel`'s source."""
    from . import fit

    h = hashlib.sha256()
    root = Path(__file__).parent.parent / "solver"
    for path in sorted(root.glob("*.py")):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    h.update(inspect.getsource(fit.ForwardModel).encode())
    return h.hexdigest()


def normal_key(key, scale: float, forward) -> tuple | None:
    """What a solve depends on with the sample's size taken out, or None if it depends on it.

    Parameters
    ----------
    key : calib.fit.CurveKey
    scale : float
        Mesh density of the solve (relative to the default mesh).
    forward : calib.fit.ForwardModel
        Its grading, travel, output points and needed strain.

    A relaxing material sees the real test time, which is not scaled with the sample: such
    solves are never stored (None).
    """
    if key.viscoelastic:
        return None
    return (tuple(round(float(a), 9) for a in key.alpha),
            tuple(round(float(f), 9) for f in key.fractions),
            round(float(key.nu), 9), key.platen, round(float(key.friction), 9),
            round(float(scale), 9), round(float(forward.axial_ratio), 9),
            round(float(forward.strain_max), 9), int(forward.n_out),
            round(float(forward.strain_needed), 9))


class StoredSolves:
    """Dimensionless curves of stored solves, looked up by :func:`normal_key` and aspect.

    Parameters
    ----------
    aspects : sequence of float
        Aspect ratio (diameter / height) of each curve.
    keys : sequence of tuple
        :func:`normal_key` of each curve.
    strain, force : ndarray, shape (n_curves, n_out)
        Travel over height (1) and unit force over height squared (N/Pa/mm^2).
    """

    def __init__(self, aspects, keys, strain, force):
        self._curves = {}
        for a, k, s, f in zip(aspects, keys, np.asarray(strain), np.asarray(force)):
            self._curves.setdefault(tuple(k), []).append((float(a), s, f))
        self.aspects = sorted({float(a) for a in aspects})

    def __len__(self) -> int:
        return sum(len(v) for v in self._curves.values())

    def nearest_aspect(self, aspect: float, rtol: float) -> float | None:
        """The stored aspect ratio within ``rtol`` of ``aspect`` (the nearest), or None."""
        best = min(self.aspects, key=lambda a: abs(a / aspect - 1.0), default=None)
        if best is None or abs(best / aspect - 1.0) > rtol:
            return None
        return best

    def lookup(self, key, scale: float, forward):
        """(travel in mm, unit force in N/Pa) of a stored solve of ``key``, or None."""
        nk = normal_key(key, scale, forward)
        if nk is None:
            return None
        h = float(key.height_mm)
        aspect = float(key.diameter_mm) / h
        for a, s, f in self._curves.get(nk, ()):
            if abs(a / aspect - 1.0) <= ASPECT_RTOL:
                return s * h, f * h * h
        return None

    def has(self, key, scale: float, forward) -> bool:
        """Whether :meth:`lookup` finds ``key``."""
        return self.lookup(key, scale, forward) is not None

    @staticmethod
    def read(path=PATH) -> tuple[dict, np.ndarray, np.ndarray]:
        """The file's metadata (``fingerprint``, ``aspects``, ``keys``), strains and forces."""
        with np.load(path, allow_pickle=False) as data:
            return json.loads(str(data["meta"])), data["strain"], data["force"]

    @classmethod
    def load(cls, path=PATH, check: bool = True) -> StoredSolves:
        """Read the file; an empty store if it is missing or (``check``) made by another solver."""
        path = Path(path)
        if not path.exists():
            return cls([], [], np.zeros((0, 0)), np.zeros((0, 0)))
        meta, strain, force = cls.read(path)
        if check and meta["fingerprint"] != fingerprint():
            warnings.warn(f"{path}: stored solves were made by another version of the solver; "
                          "they are not used (make them again: python -m "
                          "experiments.stored_solves)", stacklevel=2)
            return cls([], [], np.zeros((0, 0)), np.zeros((0, 0)))
        keys = [tuple(tuple(x) if isinstance(x, list) else x for x in k) for k in meta["keys"]]
        return cls(meta["aspects"], keys, strain, force)

    @staticmethod
    def save(path, aspects, keys, strain, force) -> None:
        """Write a store (atomically), fingerprinted with the current solver."""
        from ._io import atomic_write

        meta = {"fingerprint": fingerprint(), "aspects": [float(a) for a in aspects],
                "keys": [list(k) for k in keys]}
        for a in meta["aspects"]:
            if not (math.isfinite(a) and a > 0):
                raise ValueError(f"aspect ratio {a} is not a positive number")
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(path, "wb", encoding=None) as fh:
            np.savez_compressed(fh, meta=np.array(json.dumps(meta)),
                                strain=np.asarray(strain, dtype=float),
                                force=np.asarray(force, dtype=float))


@functools.lru_cache(maxsize=1)
def stored_solves() -> StoredSolves:
    """The package's store (read once per process)."""
    return StoredSolves.load()
