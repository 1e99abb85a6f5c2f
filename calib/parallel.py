"""Executors for independent work items (layers, bootstrap replicates, profile runs).

Everything that fans out goes through :func:`executor`, which returns a
:class:`concurrent.futures.Executor`:

- by default a local process pool (one process per core, at most one per item), since each
  work item runs the numba solver many times (a layer's fit, a grid of effect solves) and
  processes sidestep the GIL;
- ``max_workers=1`` runs in this process (no pickling, easiest to debug and profile);
- with a Dask scheduler address (``"tcp://host:8786"``) or a ``distributed.Client``, the
  Dask cluster's executor (``Client.get_executor()``), so the same code scales out.

The work functions must be importable top-level functions with picklable arguments.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import os

__all__ = ["executor", "SerialExecutor"]


class SerialExecutor(cf.Executor):
    """Runs each submitted call at once in the calling process."""

    def submit(self, fn, /, *args, **kwargs):
        """Run ``fn(*args, **kwargs)`` now; return a completed future."""
        future: cf.Future = cf.Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # the future carries it, as a pool's would
            future.set_exception(exc)
        return future


@contextlib.contextmanager
def executor(n_items: int, max_workers: int | None = None, scheduler=None):
    """Context manager yielding an executor for ``n_items`` independent work items.

    Parameters
    ----------
    n_items : int
        Number of work items (caps the number of local processes).
    max_workers : int, optional
        Local processes; default the number of cores. 1 runs serially in this process.
    scheduler : str or distributed.Client, optional
        Dask scheduler address or client; overrides the local pool.
    """
    if scheduler is not None:
        try:
            from distributed import Client
        except ImportError as exc:  # pragma: no cover - depends on the installation
            raise RuntimeError("a Dask scheduler was given but 'distributed' is not installed;"
                               " install the 'dask' extra") from exc
        client = scheduler if isinstance(scheduler, Client) else Client(scheduler)
        try:
            yield client.get_executor()
        finally:
            if client is not scheduler:
                client.close()
        return
    workers = max_workers if max_workers is not None else (os.cpu_count() or 1)
    workers = max(1, min(workers, n_items))
    if workers == 1:
        yield SerialExecutor()
        return
    _load_kernels()
    with cf.ProcessPoolExecutor(max_workers=workers) as pool:
        yield pool


_kernels_loaded = False


def _load_kernels() -> None:
    """Load the solver's JIT kernels in this process before it forks a pool.

    Forked workers (the default start method on Linux) inherit the parent's compiled
    kernels; otherwise each worker of each pool loads them from numba's cache again, and a
    discovery opens a pool for every phase. Three pools of two workers, four small solves
    each: 8.1 s of the workers' CPU, 1.2 s after this (2026-12-07). A small bonded solve
    (0.1 s) loads them once per process.
    """
    global _kernels_loaded
    if _kernels_loaded:
        return
    from solver import CompressionTest, Ogden, simulate

    simulate(Ogden(mu_Pa=1000.0, alpha=2.0, nu=0.499), CompressionTest(strain=0.02))
    _kernels_loaded = True
