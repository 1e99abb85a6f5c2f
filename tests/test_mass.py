"""The volumetric selective mass (solver.mass) and its linear algebra against dense NumPy.

Kernels: the volume gradient against the cofactor twin and finite differences, the Woodbury
inverse and the product against a dense mass matrix, the banded Cholesky against NumPy. The
stable-step tools: the element bound of the coupled pencil against scipy's generalised eigh,
Lanczos against the full spectrum. The explicit run: with the volumetric mass the bonded curve
is the lumped-mass curve to a fraction of the discretisation error, the lowest natural period
is unchanged, and the steps are an order of magnitude fewer.
"""

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse as sp

from solver import CompressionTest, Ogden, simulate
from solver.kernels import axisymmetric_operators
from solver.mass import (
    VolumetricMass,
    apply_inverse,
    apply_mass,
    assemble_band,
    band_cholesky,
    band_solve,
    volumetric_gradient,
)
from solver.mesh import axisymmetric_cylinder
from solver.stiffness import (
    _banded_solve,
    element_max_frequency_sq_coupled,
    element_stiffness,
    influence_field,
    lanczos_max,
)

from .reference import (
    distorted_axisym_mesh,
    mean_gradient,
    volumetric_gradient_numpy,
    volumetric_mass_dense,
)


def _mesh(seed=0, n=(6, 7)):
    base = axisymmetric_cylinder(38.0, 24.0, *n)
    rng = np.random.default_rng(seed)
    points = distorted_axisym_mesh(base.points, base.cells, 0.25, rng)
    return points, base.cells, axisymmetric_operators(points, base.cells), rng


def _state(points, rng, scale=0.1):
    u = rng.normal(0.0, scale * 1e-3, points.shape)
    u[points[:, 0] == 0, 0] = 0.0
    return u


@pytest.mark.parametrize("seed", [0, 1])
def test_volume_gradient_matches_cofactor_twin_and_differences(seed):
    points, cells, ops, rng = _mesh(seed)
    u = _state(points, rng)
    n = len(points)
    grad = np.zeros((len(cells), 4, 2))
    volumetric_gradient(u, cells, ops.bbar, ops.hbar, np.ones((n, 2), bool), np.ones(len(cells)),
                        grad)
    np.testing.assert_allclose(grad, volumetric_gradient_numpy(u, cells, ops), rtol=1e-12,
                               atol=1e-12 * np.abs(grad).max())
    # forward differences of J along a random direction (step 1e-9 of the height)
    du = rng.normal(size=u.shape) * 1e-9 * points[:, 1].max()
    dJ = (np.linalg.det(mean_gradient(u + du, cells, ops))
          - np.linalg.det(mean_gradient(u, cells, ops)))
    np.testing.assert_allclose(np.einsum("ead,ead->e", grad, du[cells]), dJ,
                               rtol=1e-5, atol=1e-6 * np.abs(dJ).max())
    # held DOFs and elements without added mass get zeros
    coupled = rng.uniform(size=(n, 2)) > 0.3
    coef = np.ones(len(cells))
    coef[::5] = 0.0
    masked = np.zeros_like(grad)
    volumetric_gradient(u, cells, ops.bbar, ops.hbar, coupled, coef, masked)
    np.testing.assert_array_equal(masked, grad * coupled[cells] * (coef > 0)[:, None, None])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_woodbury_inverse_and_product_match_the_dense_mass(seed):
    points, cells, ops, rng = _mesh(seed)
    n = len(points)
    u = _state(points, rng)
    coef = rng.uniform(0.5, 2.0, len(cells)) * 1e-3
    coef[::7] = 0.0  # elements without added mass drop out of the element system
    mass = rng.uniform(1.0, 2.0, n) * 1e-3
    coupled = rng.uniform(size=(n, 2)) > 0.2
    vm = VolumetricMass.for_mesh(cells, n, coef)
    volumetric_gradient(u, cells, ops.bbar, ops.hbar, coupled, vm.coefficient, vm.gradient)
    assemble_band(vm.gradient, mass, vm.coefficient, vm.position, vm.ptr, vm.slot, vm.band)
    assert band_cholesky(vm.band) == -1
    M = volumetric_mass_dense(cells, mass, vm.gradient, coef)
    r = rng.normal(size=(n, 2))
    x = np.zeros((n, 2))
    apply_inverse(r, cells, mass, vm.gradient, vm.position, vm.band, vm.work, x)
    # the mass matrix's condition number here is about 1e6: 1e-9 is rounding
    np.testing.assert_allclose(x.ravel(), np.linalg.solve(M, r.ravel()), rtol=0,
                               atol=1e-9 * np.abs(x).max())
    y = np.zeros((n, 2))
    apply_mass(r, cells, mass, vm.gradient, coef, y)
    np.testing.assert_allclose(y.ravel(), M @ r.ravel(), rtol=1e-13, atol=1e-16)


def test_band_order_is_no_wider_than_the_mesh_numbering():
    mesh = axisymmetric_cylinder(38.0, 24.0)  # 14 x 18, numbered row by row
    vm = VolumetricMass.for_mesh(mesh.cells, mesh.n_nodes, np.ones(mesh.n_cells))
    assert vm.kd == 15  # one element row plus one
    shuffled = np.random.default_rng(3).permutation(mesh.n_cells)
    assert VolumetricMass.for_mesh(mesh.cells[shuffled], mesh.n_nodes,
                                   np.ones(mesh.n_cells)).kd <= 30  # repaired by RCM


def test_band_cholesky_against_numpy_and_a_failed_pivot():
    rng = np.random.default_rng(4)
    n, kd = 40, 5
    A = np.zeros((n, n))
    for k in range(kd + 1):
        d = rng.normal(size=n - k)
        A += np.diag(d, -k) + (np.diag(d, k) if k else 0)
    A += np.eye(n) * (np.abs(A).sum(axis=1).max() + 1.0)  # diagonally dominant: SPD
    band = np.zeros((n, kd + 1))
    for k in range(kd + 1):
        band[k:, k] = np.diag(A, -k)
    assert band_cholesky(band) == -1
    L = np.linalg.cholesky(A)
    for k in range(kd + 1):
        np.testing.assert_allclose(band[k:, k], np.diag(L, -k), rtol=1e-12, atol=1e-14)
    q = rng.normal(size=n)
    y = q.copy()
    band_solve(band, y)
    np.testing.assert_allclose(y, np.linalg.solve(A, q), rtol=1e-11)
    band[:] = 0.0
    band[:, 0] = 1.0
    band[3, 0] = -1.0  # not positive definite at row 3
    assert band_cholesky(band) == 3


def test_banded_influence_solve_matches_the_dense_symmetric_solve():
    """The banded path solves the symmetric part of the block (a finite-difference tangent is
    symmetric to its differencing error, imitated here by a 1e-6 relative perturbation)."""
    from solver.stiffness import assemble

    points, cells, ops, rng = _mesh(1)
    n = len(points)
    shear = np.ones(len(cells))
    K = assemble(cells, element_stiffness(ops, shear, 50 * shear, 0.05 * ops.gamma_scale), n)
    K.data *= 1.0 + 1e-6 * rng.normal(size=K.nnz)
    free = np.ones((n, 2), bool)
    top = np.isclose(points[:, 1], points[:, 1].max())
    bottom = np.isclose(points[:, 1], 0.0)
    free[top | bottom] = False
    free[points[:, 0] == 0, 0] = False
    free = free.ravel()
    prescribed = np.zeros((n, 2))
    prescribed[top, 1] = -1.0
    prescribed = prescribed.ravel()
    w = influence_field(K, free, prescribed, banded=True)
    A = K.toarray()
    S = 0.5 * (A + A.T)
    rhs = -(A[np.ix_(free, ~free)] @ prescribed[~free])
    np.testing.assert_allclose(w[free], np.linalg.solve(S[np.ix_(free, free)], rhs),
                               rtol=1e-9, atol=1e-12 * np.abs(w).max())
    np.testing.assert_array_equal(w[~free], prescribed[~free])
    # a numbering that is not banded is left to the LU of the block as given
    perm = rng.permutation(2 * n)
    P = sp.csr_matrix((np.ones(2 * n), (np.arange(2 * n), perm)), shape=(2 * n, 2 * n))
    assert _banded_solve(sp.csr_matrix(P @ K @ P.T), free[perm], np.zeros(int(free.sum()))) \
        is None


def test_element_bound_of_the_coupled_pencil_matches_scipy():
    points, cells, ops, rng = _mesh(2)
    shear = np.ones(len(cells))
    Ke = element_stiffness(ops, shear, 500 * shear, 0.05 * ops.gamma_scale)
    grad = volumetric_gradient_numpy(_state(points, rng), cells, ops)
    coef = rng.uniform(0.0, 2.0, len(cells)) * np.median(ops.node_volume) / np.median(
        np.abs(grad)) ** 2
    got = element_max_frequency_sq_coupled(Ke, ops.node_volume, grad, coef)
    for e in rng.choice(len(cells), 8, replace=False):
        b = grad[e].ravel()
        Me = np.diag(np.repeat(ops.node_volume[e], 2)) + coef[e] * np.outer(b, b)
        assert got[e] == pytest.approx(scipy.linalg.eigh(Ke[e], Me, eigvals_only=True)[-1],
                                       rel=1e-10)


def test_lanczos_finds_the_largest_eigenvalue_from_below():
    rng = np.random.default_rng(6)
    n = 120
    Q = np.linalg.qr(rng.normal(size=(n, n)))[0]
    K = Q @ np.diag(np.geomspace(1.0, 1e4, n)) @ Q.T
    B = rng.normal(size=(n, n)) * 0.1
    M = np.eye(n) + B @ B.T
    top = scipy.linalg.eigh(K, M, eigvals_only=True)[-1]
    value, vector = lanczos_max(lambda x: K @ x, lambda x: M @ x,
                                lambda x: np.linalg.solve(M, x), rng.normal(size=n), 10)
    assert value <= top * (1 + 1e-12)
    assert value == pytest.approx(top, rel=0.05)
    again, _ = lanczos_max(lambda x: K @ x, lambda x: M @ x, lambda x: np.linalg.solve(M, x),
                           vector, 10)  # a warm start gets closer
    assert abs(again - top) <= abs(value - top) + 1e-9 * top


@pytest.fixture(scope="module")
def pair():
    material = Ogden(mu_Pa=1875.0, alpha=4.9, nu=0.499)
    return (simulate(material, CompressionTest()),
            simulate(material, CompressionTest(), volumetric_mass=0.0))


def test_volumetric_mass_keeps_the_curve_the_period_and_cuts_the_steps(pair):
    """Bonded 30 %, default mesh. The outputs are the states of the steps nearest the output
    times, so the curves are compared at the same travel (interpolated). Tolerance 0.25 %
    beyond 2 % strain, about half the default mesh's discretisation error (0.4 %): each run
    keeps 0.1-0.2 % of inertia (against a ramp 40 natural periods long: lumped 0.13 %,
    volumetric mass 0.17 %). The lowest mode is isochoric and keeps its period: 1e-3."""
    scaled, lumped = pair
    assert scaled.volumetric_mass and not lumped.volumetric_mass
    loaded = scaled.displacement_mm >= 0.02 * 24.0
    at_same_travel = np.interp(scaled.displacement_mm[loaded], lumped.displacement_mm,
                               lumped.force_N)
    np.testing.assert_allclose(scaled.force_N[loaded], at_same_travel, rtol=2.5e-3)
    assert scaled.natural_period_s == pytest.approx(lumped.natural_period_s, rel=1e-3)
    assert scaled.n_steps * 10 < lumped.n_steps
    assert scaled.kinetic_ratio < 1.5 * lumped.kinetic_ratio


def test_coulomb_and_hexahedra_keep_lumped_masses():
    from solver import hex_cylinder

    material = Ogden(mu_Pa=1875.0, alpha=4.9, nu=0.499)
    r = simulate(material, CompressionTest(strain=0.05, platen="coulomb", friction=0.3))
    assert not r.volumetric_mass
    h = simulate(material, CompressionTest(strain=0.02), hex_cylinder(38.0, 24.0, 2, 1, 2))
    assert not h.volumetric_mass
    with pytest.raises(ValueError, match="volumetric_mass"):
        simulate(material, CompressionTest(strain=0.05), volumetric_mass=-1.0)
    with pytest.raises(ValueError, match="mass_refresh_drift"):
        simulate(material, CompressionTest(strain=0.05), mass_refresh_drift=1.0)


def test_a_run_the_volumetric_mass_cannot_finish_is_run_with_lumped_masses():
    """A 38 x 10 mm disc bonded to 50 %: a rim element collapses near 48 % faster than the
    step checks follow the deviatoric frequencies (Lanczos: 10-fold, then 32-fold the start's
    highest frequency squared); the lumped masses' step, set by the pressure waves, has room
    to spare. The result says so, and its curve is the lumped run's."""
    material = Ogden(mu_Pa=1875.0, alpha=5.0, nu=0.499)
    test = CompressionTest(diameter_mm=38.0, height_mm=10.0, strain=0.5)
    result = simulate(material, test)
    assert not result.volumetric_mass
    assert len(result.notes) == 1 and "volumetric mass stopped" in result.notes[0]
    lumped = simulate(material, test, volumetric_mass=0.0)
    np.testing.assert_array_equal(result.force_N, lumped.force_N)
    assert not lumped.notes


@pytest.mark.slow
def test_bonded_default_sample_reaches_89_percent_through_the_lumped_fallback():
    """Beyond what the volumetric mass reaches (it stops between 60 and 70 %), the lumped
    fallback compresses the default sample to 89 % (experiments/reach.py: 863.8 N). It stopped
    near 80 % while the bulk viscosity was on for every lumped run, which this guards."""
    material = Ogden(mu_Pa=1875.0, alpha=4.9, nu=0.499)
    result = simulate(material, CompressionTest(strain=0.89))
    assert not result.volumetric_mass and "volumetric mass stopped" in result.notes[0]
    assert result.displacement_mm[-1] == pytest.approx(0.89 * 24.0)
    assert result.force_N[-1] > 500.0
