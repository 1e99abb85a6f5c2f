"""The project's one JIT policy.

Every numba kernel in :mod:`solver` is decorated with :data:`njit` from here, so the flags are
set in one place:

- ``cache=True``: compiled machine code is stored beside the sources (or in
  ``NUMBA_CACHE_DIR``) and reused by later processes. Numba's cache does not notice changes in
  *other* files a kernel calls into; CI therefore runs with a fresh ``NUMBA_CACHE_DIR``.
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
import os

# The parallel kernels join their threads twice per time step (elements, then nodes). With
# OpenMP's default active waiting, a thread that finishes first spins; on a machine shared
# with other jobs the spinning steals the core its partner needs, and a fork-join measured
# 640 us instead of 9 us with passive waiting (2 cores, load 4). Passive waiting costs a few
# microseconds on a quiet machine. Set before numba loads its OpenMP layer; an explicit
# setting of the user's wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba  # noqa: E402

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
