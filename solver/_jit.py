"""The project's one JIT policy.

Every numba kernel in :mod:`solver` is decorated with :data:`njit` from here, so the flags are
set in one place:

- ``cache=True``: compiled machine code is reused by later processes. Numba's cache checks
  only the time stamp of the file that defines a kernel, not of the files it calls into or
  inlines from, and a stale entry can crash the process (a segmentation fault after an edit
  of :mod:`solver.kernels` was seen here). Unless the user sets ``NUMBA_CACHE_DIR``, the
  cache therefore lives in a folder named by a hash of every source file of this package
  (under ``$XDG_CACHE_HOME``, default ``~/.cache``, in ``ogden-calib/numba``): any change of
  the solver starts a fresh cache. CI sets its own fresh ``NUMBA_CACHE_DIR``. Cache writes
  and reads hold a lock on the folder (:func:`_locked_cache`), so that processes compiling
  at once (a cold cache and a pool of fitting workers) cannot corrupt it.
- ``fastmath=False``: the kernels compare stretches for equality (repeated principal stretches)
  and check for NaN; fast-math would license the compiler to drop both.
- ``error_model="numpy"``: division by zero gives inf/NaN (which the time loop detects and
  reports) instead of raising inside the kernel, which also keeps the loops vectorisable.

``OMP_WAIT_POLICY`` defaults to ``PASSIVE`` (see below) for the parallel hexahedron kernel.

Setting the environment variable ``NUMBA_DISABLE_JIT=1`` runs every kernel as plain Python,
which the tests use once to check the kernels against their NumPy twins without compilation.
"""

from __future__ import annotations

import contextlib
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


@contextlib.contextmanager
def _cache_lock(exclusive: bool):
    """Hold an inter-process lock on the cache folder (POSIX ``flock``; no-op elsewhere)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    folder = Path(numba.config.CACHE_DIR)
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / ".ogden-calib.lock", "a+b") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _locked_cache(dispatcher):
    """Make a kernel's cache reads and writes safe against other processes.

    Numba numbers a kernel's data files by the entries its index holds when it saves one: two
    processes compiling different signatures of one kernel at once can both write file 1
    and leave an index that maps one signature to the other's machine code (numba issues
    #4807 and #10128), which crashes every later process that loads it. A cache folder
    poisoned this way crashed a hexahedral solve here on every run until it was deleted.
    Saves therefore hold an exclusive lock on the cache folder, loads a shared one.
    """
    cache = getattr(dispatcher, "_cache", None)
    if cache is None or not hasattr(cache, "save_overload"):  # NUMBA_DISABLE_JIT, no cache
        return dispatcher
    save, load = cache.save_overload, cache.load_overload

    def save_overload(sig, data):
        with _cache_lock(exclusive=True):
            return save(sig, data)

    def load_overload(sig, target_context):
        with _cache_lock(exclusive=False):
            return load(sig, target_context)

    cache.save_overload, cache.load_overload = save_overload, load_overload
    return dispatcher


def _decorator(**flags):
    def decorate(func):
        return _locked_cache(numba.njit(cache=True, fastmath=False, error_model="numpy",
                                        nogil=True, **flags)(func))
    return decorate


#: Decorator for every kernel in the package.
njit = _decorator()

#: Decorator for the small per-element helpers (state, stress, spectral decomposition,
#: material law): inlined into their callers at numba's IR level. Left to LLVM, the calls with
#: a dozen array arguments (and the row views ``mu[m]``) were not inlined and cost more than
#: the arithmetic: the hexahedron's force kernel ran 1.4x faster inlined.
njit_inline = _decorator(inline="always")

#: Decorator for kernels with a ``numba.prange`` loop (parallel over elements).
njit_parallel = _decorator(parallel=True)
