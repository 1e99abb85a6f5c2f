"""The project's one JIT policy.

Every numba kernel in :mod:`solver` is decorated with :data:`njit` from here, so the flags are
set in one place:

- ``cache=True``: compiled machine code is reused by later processes. Numba's cache checks
  only the time stamp of the file that defines a kernel, not of the files it calls into or
  inlines from, and a stale entry can crash the process (a segmentation fault after an edit
  of :mod:`solver.kernels` was seen here). Unless the user sets ``NUMBA_CACHE_DIR``, the
  cache therefore lives in a folder named by a hash of every source file of this package
  (under ``$XDG_CACHE_HOME``, default ``~/.cache``, in ``ogden-calib/numba``): any change of
  the solver starts a fresh cache. CI sets its own fresh ``NUMBA_CACHE_DIR``.
- ``fastmath=False``: the kernels compare stretches for equality (repeated principal stretches)
  and check for NaN; fast-math would license the compiler to drop both.
- ``error_model="numpy"``: division by zero gives inf/NaN (which the time loop detects and
  reports) instead of raising inside the kernel, which also keeps the loops vectorisable.

``OMP_WAIT_POLICY`` defaults to ``PASSIVE`` (see below) for the parallel hexahedron kernel.

Setting the environment variable ``NUMBA_DISABLE_JIT=1`` runs every kernel as plain Python,
which the tests use once to check the kernels against their NumPy twins without compilation.
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

# The parallel kernels join their threads twice per time step (elements, then nodes). With
# OpenMP's default active waiting, a thread that finishes first spins; on a machine shared
# with other jobs the spinning steals the core its partner needs, and a fork-join measured
# 640 us instead of 9 us with passive waiting (2 cores, load 4). Passive waiting costs a few
# microseconds on a quiet machine. Set before numba loads its OpenMP layer; an explicit
# setting of the user's wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def _source_keyed_cache_dir(package: Path = Path(__file__).parent) -> str:
    """Cache folder named by the hash of the package's sources (see the module notes)."""
    digest = hashlib.sha256()
    for path in sorted(package.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return str(root / "ogden-calib" / "numba" / digest.hexdigest()[:16])


if not os.environ.get("NUMBA_CACHE_DIR"):
    os.environ["NUMBA_CACHE_DIR"] = _source_keyed_cache_dir()

import numba  # noqa: E402

# numba reads NUMBA_CACHE_DIR when it is first imported; if the user's code imported it
# before this module, set its configuration too (read when each kernel is decorated)
numba.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]

#: Decorator for every kernel in the package.
njit = functools.partial(numba.njit, cache=True, fastmath=False, error_model="numpy", nogil=True)

#: Decorator for the small per-element helpers (state, stress, spectral decomposition,
#: material law): inlined into their callers at numba's IR level. Left to LLVM, the calls with
#: a dozen array arguments (and the row views ``mu[m]``) were not inlined and cost more than
#: the arithmetic: the hexahedron's force kernel ran 1.4x faster inlined.
njit_inline = functools.partial(numba.njit, cache=True, fastmath=False, error_model="numpy",
                                nogil=True, inline="always")

#: Decorator for kernels with a ``numba.prange`` loop (parallel over elements).
njit_parallel = functools.partial(
    numba.njit, cache=True, fastmath=False, error_model="numpy", nogil=True, parallel=True
)
