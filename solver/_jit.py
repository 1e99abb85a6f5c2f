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

Setting the environment variable ``NUMBA_DISABLE_JIT=1`` runs every kernel as plain Python,
which the tests use once to check the kernels against their NumPy twins without compilation.
"""

from __future__ import annotations

import functools

import numba

#: Decorator for every kernel in the package.
njit = functools.partial(numba.njit, cache=True, fastmath=False, error_model="numpy", nogil=True)

#: Decorator for kernels with a ``numba.prange`` loop (parallel over elements).
njit_parallel = functools.partial(
    numba.njit, cache=True, fastmath=False, error_model="numpy", nogil=True, parallel=True
)
