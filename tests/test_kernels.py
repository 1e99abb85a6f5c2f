"""JIT kernels against their NumPy twins, the patch test, and the linearised stiffness."""

import numpy as np
import pytest

from solver.kernels import axisym_energy, axisym_forces, axisymmetric_operators
from solver.materials import Ogden
from solver.mesh import axisymmetric_cylinder, graded_spacing
from solver.stiffness import assemble, element_stiffness

from .checks import assert_energy_gradient
from .reference import axisym_energy_numpy, axisym_forces_numpy, distorted_axisym_mesh

MATERIAL = Ogden(mu_Pa=1875.0, alpha=4.9, nu=0.49)


def _setup(distort=0.25, seed=0, n=(6, 7)):
    base = axisymmetric_cylinder(38.0, 24.0, *n)
    rng = np.random.default_rng(seed)
    points = distorted_axisym_mesh(base.points, base.cells, distort, rng)
    ops = axisymmetric_operators(points, base.cells)
    return points, base.cells, ops, rng


def _kernel_forces(u, cells, ops, material, k_hg):
    mu, alpha, K, _, _ = material.kernel_arrays()
    n = len(cells)
    f = np.zeros_like(u)
    status = axisym_forces(u, cells, ops.bbar, ops.hbar, ops.volume, ops.gamma, k_hg,
                           np.zeros(n, np.int32), mu[None], alpha[None], np.array([K]),
                           np.zeros((1, 0)), np.zeros((1, 0)), np.zeros((1, 0)),
                           np.zeros((n, 4)), np.zeros((n, 4, 0)), False, f)
    return status, f


def _random_state(points, rng, scale=0.08):
    """A smooth random finite deformation (up to ~15 % strain) plus small noise."""
    R, H = points[:, 0].max(), points[:, 1].max()
    r, z = points[:, 0] / R, points[:, 1] / H
    a = rng.uniform(-1, 1, 6) * scale
    ur = R * r * (a[0] + a[1] * z + a[2] * z**2)
    uz = H * (a[3] * z + a[4] * r**2 + a[5] * r * z)
    u = np.column_stack([ur, uz])
    u += rng.normal(0, 0.01 * scale * H, u.shape) * (points[:, [0]] > 0)
    u[points[:, 0] == 0, 0] = 0.0
    return u


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_force_kernel_matches_numpy_twin(seed):
    points, cells, ops, rng = _setup(seed=seed)
    k_hg = 0.1 * MATERIAL.mu0_Pa * ops.gamma_scale
    for material in (MATERIAL, Ogden(mu_Pa=(1200.0, -300.0), alpha=(9.0, -3.0), nu=0.45)):
        u = _random_state(points, rng)
        status, f = _kernel_forces(u, cells, ops, material, k_hg)
        assert status == (0, -1)
        ref = axisym_forces_numpy(u, cells, ops, material, k_hg)
        np.testing.assert_allclose(f, ref, atol=1e-10 * np.abs(ref).max())
        mu, alpha, K, _, _ = material.kernel_arrays()
        W, Whg = axisym_energy(u, cells, ops.bbar, ops.hbar, ops.volume, ops.gamma, k_hg,
                               np.zeros(len(cells), np.int32), mu[None], alpha[None],
                               np.array([K]))
        W_ref, Whg_ref = axisym_energy_numpy(u, cells, ops, material, k_hg)
        assert W == pytest.approx(W_ref, rel=1e-10)
        assert Whg == pytest.approx(Whg_ref, rel=1e-10)


def test_forces_are_the_energy_gradient():
    """The kernel's forces are the exact derivative of the energy kernel (central differences)."""
    points, cells, ops, rng = _setup(seed=5)
    k_hg = 0.1 * MATERIAL.mu0_Pa * ops.gamma_scale
    u = _random_state(points, rng)
    _, f = _kernel_forces(u, cells, ops, MATERIAL, k_hg)
    mu, alpha, K, _, _ = MATERIAL.kernel_arrays()

    def energy(uu):
        W, Whg = axisym_energy(uu, cells, ops.bbar, ops.hbar, ops.volume, ops.gamma, k_hg,
                               np.zeros(len(cells), np.int32), mu[None], alpha[None],
                               np.array([K]))
        return W + Whg

    assert_energy_gradient(f, energy, u,
                           rng.choice(np.flatnonzero(points[:, 0] > 0), 12, replace=False))


@pytest.mark.parametrize("stretch", [(0.7, 1.18), (1.0, 1.0), (1.1, 0.8)])
def test_patch_test_homogeneous_deformation(stretch):
    """Rung 2: a homogeneous deformation on a distorted mesh gives zero interior forces.

    The deformation u_r = (l_r - 1) r, u_z = (l_z - 1) z also stretches the hoop direction by
    l_r; (1.0, 1.0) with a rigid translation in z checks that a rigid motion is force-free.
    """
    points, cells, ops, _ = _setup(distort=0.3, seed=3, n=(7, 8))
    lr, lz = stretch
    u = np.column_stack([(lr - 1) * points[:, 0], (lz - 1) * points[:, 1] + 1e-3])
    k_hg = 0.1 * MATERIAL.mu0_Pa * ops.gamma_scale
    _, f = _kernel_forces(u, cells, ops, MATERIAL, k_hg)
    from solver.mesh import Mesh

    interior = ~Mesh(points=points, cells=cells, cell_type="quad").boundary_nodes()
    assert interior.sum() > 20
    # force scale: the boundary forces of a 10 % compression of the same mesh
    u10 = np.column_stack([0.05 * points[:, 0], -0.1 * points[:, 1]])
    scale = np.abs(_kernel_forces(u10, cells, ops, MATERIAL, k_hg)[1]).max()
    # exact up to rounding: every term cancels algebraically
    assert np.abs(f[interior]).max() <= 1e-10 * scale
    # the top-face reaction equals the closed-form stress times the area
    if stretch == (0.7, 1.18):
        tau = MATERIAL.kirchhoff_stress([lr, lz, lr])
        P_zz = tau[1] / lz
        top = np.isclose(points[:, 1], points[:, 1].max())
        area = np.pi * points[:, 0].max() ** 2
        assert f[top, 1].sum() == pytest.approx(P_zz * area, rel=1e-10)


def test_kernel_jacobian_matches_linear_stiffness():
    """Finite differences of the force kernel at the reference state equal the assembled
    small-strain stiffness used for the natural period and the influence field."""
    points, cells, ops, rng = _setup(seed=7)
    shear = np.full(len(cells), MATERIAL.mu0_Pa)
    bulk = np.full(len(cells), MATERIAL.bulk_modulus_Pa)
    k_hg = 0.1 * MATERIAL.mu0_Pa * ops.gamma_scale
    K = assemble(cells, element_stiffness(ops, shear, bulk, k_hg), len(points)).toarray()
    u0 = np.zeros_like(points)
    h = 1e-9 * points[:, 1].max()
    for dof in rng.choice(np.flatnonzero(np.repeat(points[:, 0] > 0, 2)), 15, replace=False):
        up, dn = u0.copy().ravel(), u0.copy().ravel()
        up[dof] += h
        dn[dof] -= h
        _, fp = _kernel_forces(up.reshape(-1, 2), cells, ops, MATERIAL, k_hg)
        _, fm = _kernel_forces(dn.reshape(-1, 2), cells, ops, MATERIAL, k_hg)
        column = (fp - fm).ravel() / (2 * h)
        np.testing.assert_allclose(column, K[:, dof], atol=1e-6 * np.abs(K).max())


def test_inverted_element_is_reported():
    points, cells, ops, _ = _setup(distort=0.0)
    u = np.zeros_like(points)
    e = 10
    a, b = cells[e, 0], cells[e, 2]
    u[a] = points[b] - points[a] + 1e-3  # push node 0 beyond node 2: the element folds
    status, _ = _kernel_forces(u, cells, ops, MATERIAL, np.zeros(len(cells)))
    assert status[0] == 1 and e in {status[1]} | set(
        np.flatnonzero((cells == a).any(axis=1)))


def test_graded_spacing():
    x = graded_spacing(1.0, 6, 4.0)
    h = np.diff(x)
    assert x[0] == 0 and x[-1] == pytest.approx(1.0)
    assert h[0] / h[-1] == pytest.approx(4.0) and np.all(np.diff(h) < 0)
    y = graded_spacing(2.0, 7, 3.0, two_sided=True)
    hy = np.diff(y)
    np.testing.assert_allclose(hy, hy[::-1])
    assert hy.max() / hy.min() == pytest.approx(3.0)


def test_tangent_probe_matches_single_column_differences():
    """The coloured finite differences give every column of the tangent stiffness, at the
    reference state (the assembled small-strain matrix) and at a deformed one."""
    from solver.stiffness import TangentProbe

    points, cells, ops, rng = _setup(seed=9)
    k_hg = 0.1 * MATERIAL.mu0_Pa * ops.gamma_scale
    probe = TangentProbe(cells, len(points), 2)
    # no two nodes of a colour share a neighbour (a distance-2 colouring)
    for c in range(probe.n_colours):
        nodes = np.flatnonzero(probe.colour == c)
        touched = np.concatenate([np.unique(cells[(cells == n).any(axis=1)]) for n in nodes])
        assert len(touched) == len(np.unique(touched))

    def forces(u):
        return _kernel_forces(u, cells, ops, MATERIAL, k_hg)[1]

    h = 1e-9 * points[:, 1].max()
    K0 = probe.stiffness(forces, np.zeros_like(points), h).toarray()
    shear = np.full(len(cells), MATERIAL.mu0_Pa)
    bulk = np.full(len(cells), MATERIAL.bulk_modulus_Pa)
    K_lin = assemble(cells, element_stiffness(ops, shear, bulk, k_hg), len(points)).toarray()
    np.testing.assert_allclose(K0, K_lin, atol=1e-6 * np.abs(K_lin).max())
    u = _random_state(points, rng)
    Kt = probe.stiffness(forces, u, h).toarray()
    f0 = forces(u)
    for dof in rng.choice(np.flatnonzero(np.repeat(points[:, 0] > 0, 2)), 10, replace=False):
        up = u.copy().ravel()
        up[dof] += h
        column = ((forces(up.reshape(-1, 2)) - f0) / h).ravel()
        np.testing.assert_allclose(Kt[:, dof], column, atol=1e-9 * np.abs(Kt).max())


def test_jit_cache_folder_follows_every_solver_source(tmp_path, monkeypatch):
    """An edit of any solver file (not only the kernel's own) selects a fresh numba cache."""
    import shutil
    from pathlib import Path

    import solver
    from solver._jit import _source_keyed_cache_dir

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    package = tmp_path / "solver"
    shutil.copytree(Path(solver.__file__).parent, package,
                    ignore=shutil.ignore_patterns("__pycache__"))
    first = _source_keyed_cache_dir(package)
    assert first.startswith(str(tmp_path / "cache" / "ogden-calib" / "numba"))
    assert _source_keyed_cache_dir(package) == first
    (package / "materials.py").write_text((package / "materials.py").read_text() + "\n# edit\n")
    assert _source_keyed_cache_dir(package) != first


_CACHE_SCRIPT = """
import numpy as np
from solver._jit import njit

@njit
def twice(x):
    return x + x

assert twice(np.arange(3)).sum() == 6
"""


def test_jit_cache_writes_wait_for_the_folder_lock(tmp_path):
    """A process saving a compiled kernel waits while another holds the cache folder's lock.

    Unlocked, two processes compiling different signatures of one kernel at once can give
    both data files the same number and leave the index mapping one signature to the other's
    code (numba #4807): a cache folder poisoned this way crashed a hexahedral solve here on
    every run until it was deleted. Here the test holds the lock
    (:func:`solver._jit._cache_lock`) while a subprocess compiles into a cold cache: no index
    may appear until the lock is released, then the subprocess completes.
    """
    import fcntl
    import os
    import subprocess
    import sys
    import time
    from pathlib import Path

    cache = tmp_path / "cache"
    cache.mkdir()
    script = tmp_path / "kernel.py"
    script.write_text(_CACHE_SCRIPT)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache),
           "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    with open(cache / ".ogden-calib.lock", "a+b") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        child = subprocess.Popen([sys.executable, str(script)], env=env,
                                 stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 6.0  # import and compile take 2-5 s here
            while time.monotonic() < deadline and child.poll() is None:
                time.sleep(0.2)
            assert child.poll() is None, "the kernel's process did not wait for the lock"
            assert not list(cache.rglob("*.nbi")), "an index was written under the lock"
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)
    _, err = child.communicate(timeout=120)
    assert child.returncode == 0, err[-2000:]
    assert list(cache.rglob("*.nbi")) and list(cache.rglob("*.nbc"))


def test_every_solver_kernel_saves_its_cache_under_the_lock():
    import numba

    import solver.explicit
    import solver.kernels
    import solver.loading
    import solver.mass
    import solver.stiffness
    import solver.viscosity

    found = 0
    for module in (solver.explicit, solver.kernels, solver.loading, solver.mass,
                   solver.stiffness, solver.viscosity):
        for name, obj in vars(module).items():
            if isinstance(obj, numba.core.registry.CPUDispatcher) \
                    and obj.__module__ == module.__name__:
                found += 1
                assert "_locked_cache" in obj._cache.save_overload.__qualname__, name
                assert "_locked_cache" in obj._cache.load_overload.__qualname__, name
    assert found >= 20


def test_table_interp_is_numpy_interp_at_one_point():
    """The JIT piecewise-linear table (the constant-speed ramp's travel, the discrepancy
    workflow's discretisation correction) against its twin, np.interp: inside, on the grid's
    points, beyond both ends, NaN. 1e-15: the same two-point formula, written differently."""
    from solver.loading import table_interp

    rng = np.random.default_rng(3)
    grid = np.sort(rng.uniform(0.0, 1.0, 40))
    values = rng.normal(size=40)
    t = np.concatenate([rng.uniform(-0.2, 1.2, 200), grid, [np.nan, -1e9, 1e9]])
    got = np.array([table_interp(x, grid, values) for x in t])
    twin = np.interp(t, grid, values)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(twin))
    np.testing.assert_allclose(got, twin, rtol=1e-15, atol=1e-15)
