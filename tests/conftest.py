"""Compile the solver's kernels once, before pytest-xdist starts its workers.

Numba's on-disk cache is not safe against several processes compiling and writing the same
kernels at once (numba issues #4807 and #10128): with a cold cache and ``-n 2``, a
``calib simulate --mesh hex`` subprocess segfaulted once in six runs here while a worker was
writing the hexahedral kernels. The controlling process therefore runs one small solve of
every path first, so that the workers and their subprocesses only read the cache (the cache
now also locks its folder, see :func:`solver._jit._locked_cache`; the warm-up still saves
each worker compiling everything itself).

The slow tests run first. The four longest (the README's run of the whole discrepancy
workflow, 12 minutes in CI on 2026-12-07 and 20 before slip's costliest solves were stored
with the package, the notebook's on one layer, 2-5 minutes, and the two campaigns made by
FElupe, 2-8 minutes in CI) come in an order that xdist's
``--maxschedchunk 2`` (two tests per worker at the start) hands out as README + FElupe clean
to one worker and notebook + FElupe slip to the other; the rest follows as workers come
free. In collection order both workflow runs fell late and the run ended on one worker. When
the FElupe tests lost their magnitude parameter (ids ``[clean-1.0]`` to ``[clean]``) this
list kept the old ids, and the README and notebook runs went to the same worker, one after
the other; since then ``tests/test_readme.py::test_the_tests_started_first_for_ci_exist``
checks the list against the collection. pytest keeps both cores busy either way (CI at
502e00b: 2342 s of CPU over a 1283 s run, 1098 s of it pytest, the rest mostly the
single-core install), so the order shortens a run only where one worker would otherwise sit
idle.
"""

#: The longest tests, in the order they are started (see the module notes).
_FIRST = ("test_quickstart_main_job_runs",
          "test_campaigns_made_by_an_independent_code[clean]",
          "test_notebook_executes[03_discover]",
          "test_campaigns_made_by_an_independent_code[platen_slip]")


def pytest_collection_modifyitems(config, items):
    def rank(item):
        if item.name in _FIRST:
            return (0, _FIRST.index(item.name))
        return (1 if item.get_closest_marker("slow") else 2, 0)

    items.sort(key=rank)  # stable: the order within each rank is kept


def pytest_configure(config):
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return  # an xdist worker (the controller warmed the cache), or a serial run
    import subprocess
    import sys

    # the hexahedral paths in a second process while this one compiles the axisymmetric
    # ones (their kernels hardly overlap: 40 and 34 s here, each alone or one after the
    # other; the cache's lock makes saving the few they share safe, see solver._jit)
    hexa = subprocess.Popen([sys.executable, "-c", _WARM_HEX])
    from solver import CompressionTest, Ogden, simulate

    material = Ogden(mu_Pa=1875.0, alpha=4.9, nu=0.499)
    small = CompressionTest(strain=0.02)
    simulate(material, small)  # volumetric mass
    simulate(material, small, volumetric_mass=0.0)  # lumped masses
    simulate(material, CompressionTest(strain=0.02, platen="coulomb", friction=0.3))
    if hexa.wait() != 0:  # the hexahedral tests will show why
        print(f"conftest: warming the hexahedral kernels failed ({hexa.returncode})",
              file=sys.stderr)


_WARM_HEX = """
from solver import CompressionTest, Ogden, hex_cylinder, simulate

material = Ogden(mu_Pa=1875.0, alpha=4.9, nu=0.499)
small = CompressionTest(strain=0.02)
hexa = hex_cylinder(38.0, 24.0, 2, 2, 2)
for parallel in (True, False):
    simulate(material, small, hexa, parallel=parallel)
simulate(material, CompressionTest(strain=0.02, platen="coulomb", friction=0.3), hexa)
"""
