"""Compile the solver's kernels once, before pytest-xdist starts its workers.

Numba's on-disk cache is not safe against several processes compiling and writing the same
kernels at once (numba issues #4807 and #10128): with a cold cache and ``-n 2``, a
``calib simulate --mesh hex`` subprocess segfaulted once in six runs here while a worker was
writing the hexahedral kernels. The controlling process therefore runs one small solve of
every path first, so that the workers and their subprocesses only read the cache.
"""


def pytest_configure(config):
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return  # an xdist worker (the controller warmed the cache), or a serial run
    from solver import CompressionTest, Ogden, hex_cylinder, simulate

    material = Ogden(mu_Pa=1875.0, alpha=4.9, nu=0.499)
    small = CompressionTest(strain=0.02)
    simulate(material, small)  # volumetric mass
    simulate(material, small, volumetric_mass=0.0)  # lumped masses
    simulate(material, CompressionTest(strain=0.02, platen="coulomb", friction=0.3))
    hexa = hex_cylinder(38.0, 24.0, 2, 2, 2)
    for parallel in (True, False):
        simulate(material, small, hexa, parallel=parallel)
    simulate(material, CompressionTest(strain=0.02, platen="coulomb", friction=0.3), hexa)
