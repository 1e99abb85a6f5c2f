"""The hexahedron's kernels: spectral guards at repeated eigenvalues, NumPy twins, energy
gradient, patch test, linear stiffness, parallel = serial, and the O-grid mesh."""

import numba
import numpy as np
import pytest

from solver.kernels import (
    HexOperators,
    hex_energy,
    hex_forces,
    hex_forces_serial,
    hex_operators,
    hex_stress,
    node_slots,
    spectral_sym3,
)
from solver.materials import Ogden
from solver.mesh import Mesh, hex_block, hex_cylinder
from solver.stiffness import assemble, element_stiffness

from .checks import assert_energy_gradient
from .reference import distorted_hex_mesh, hex_energy_numpy, hex_forces_numpy, pk2_numpy

MATERIAL = Ogden(mu_Pa=1875.0, alpha=4.9, nu=0.49)
TWO_TERM = Ogden(mu_Pa=(1200.0, -300.0), alpha=(9.0, -3.0), nu=0.45)
NO_PRONY = (np.zeros((1, 0)), np.zeros((1, 0)), np.zeros((1, 0)))


def _mesh(distort=0.25, seed=0, n=(4, 3, 5)):
    rng = np.random.default_rng(seed)
    base = hex_cylinder(38.0, 24.0, *n)
    mesh = distorted_hex_mesh(base, distort, rng) if distort else base
    return mesh, hex_operators(mesh.points, mesh.cells), rng


def _kernel_args(u, mesh, ops, material, k_hg):
    mu, alpha, K, _, _ = material.kernel_arrays()
    n = mesh.n_cells
    return (u, mesh.cells, ops.bbar, ops.volume, ops.gamma, k_hg, np.zeros(n, np.int32),
            mu[None], alpha[None], np.array([K]), *NO_PRONY, np.zeros((n, 6)),
            np.zeros((n, 6, 0)), False)


def _forces(u, mesh, ops, material, k_hg, parallel=False):
    f = np.zeros_like(u)
    args = _kernel_args(u, mesh, ops, material, k_hg)
    if parallel:
        ptr, slot = node_slots(mesh.cells, mesh.n_nodes)
        status = hex_forces(*args, ptr, slot, np.zeros((mesh.n_cells, 8, 3)),
                            np.zeros(mesh.n_cells, np.int32), f)
    else:
        status = hex_forces_serial(*args, np.zeros((8, 3)), f)
    return status, f


def _energy(u, mesh, ops, material, k_hg):
    mu, alpha, K, _, _ = material.kernel_arrays()
    return hex_energy(u, mesh.cells, ops.bbar, ops.volume, ops.gamma, k_hg,
                      np.zeros(mesh.n_cells, np.int32), mu[None], alpha[None], np.array([K]))


def _random_state(points, rng, scale=0.08):
    """A smooth random finite deformation (up to ~15 % strain, with shear) plus small noise."""
    R, H = 0.019, 0.024
    x, y, z = points[:, 0] / R, points[:, 1] / R, points[:, 2] / H
    a = rng.uniform(-1, 1, 9) * scale
    u = np.column_stack([R * (a[0] * x + a[1] * x * z + a[2] * y),
                         R * (a[3] * y + a[4] * x * y + a[5] * z),
                         H * (a[6] * z + a[7] * x**2 + a[8] * y * z)])
    return u + rng.normal(0, 0.01 * scale * H, u.shape)


# ---------------------------------------------------------------------- spectral guards
def _rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


def _spectral(C):
    out = spectral_sym3(C[0, 0], C[1, 1], C[2, 2], C[0, 1], C[0, 2], C[1, 2])
    c = np.array(out[:3])
    P1 = np.array([[out[3], out[6], out[7]], [out[6], out[4], out[8]],
                   [out[7], out[8], out[5]]])
    D = np.array([[out[9], out[12], out[13]], [out[12], out[10], out[14]],
                  [out[13], out[14], out[11]]])
    return c, P1, D, out[15], out[16]


def _isotropic_function(C, s_of_c):
    """S = sum s(c_a) N_a N_a through the kernel's spectral pieces (as in _hex_pk2)."""
    c, P1, D, delta, _ = _spectral(C)
    s = s_of_c(c)
    mean = 0.5 * (s[1] + s[2])
    k = (s[1] - s[2]) / delta if delta * _spectral(C)[4] > 1e-13 * (c[1] + c[2]) else 0.0
    return mean * np.eye(3) + (s[0] - mean) * P1 + k * D


def test_spectral_all_three_equal_is_the_p2_guard():
    """C = c I exactly (the undeformed state scaled): p2 == 0, P1 = D = 0, delta = 0."""
    for c0 in (1.0, 0.81, 1.7):
        c, P1, D, delta, p = _spectral(c0 * np.eye(3))
        assert np.all(c == c0) and p == 0.0 and delta == 0.0
        assert not P1.any() and not D.any()


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("a, b", [(0.49, 1.43), (1.6, 0.8)])
def test_spectral_exactly_repeated_pair(a, b, axis):
    """Uniaxial states diag with l2 = l3 exactly: r = +-1 (the clip guard), the isolated
    eigenvalue and its projector exact, the pair's deviator zero, no NaN."""
    d = np.full(3, b)
    d[axis] = a
    c, P1, D, delta, p = _spectral(np.diag(d))
    assert c[0] == pytest.approx(a, rel=1e-14)
    assert c[1] == pytest.approx(b, rel=1e-14) and c[2] == pytest.approx(b, rel=1e-14)
    expected = np.zeros((3, 3))
    expected[axis, axis] = 1.0
    np.testing.assert_allclose(P1, expected, atol=1e-14)
    assert np.abs(D).max() < 1e-14 and delta * p < 1e-13 * (c[1] + c[2])


def test_spectral_rotated_repeated_pair_and_clip_guard():
    """Rotated uniaxial states: rounding makes the pair differ in the last digits and can
    push |r| past 1; the stress must still equal the exact isotropic function (to 1e-13 of
    its size) and never be NaN."""
    rng = np.random.default_rng(11)
    clipped = 0
    for _ in range(400):
        Q = _rotation(rng)
        a, b = rng.uniform(0.4, 1.6, 2)
        C = Q @ np.diag([a, b, b]) @ Q.T
        C = 0.5 * (C + C.T)
        B = C - np.trace(C) / 3 * np.eye(3)
        p = np.sqrt(np.sum(B * B) / 6)
        clipped += abs(0.5 * np.linalg.det(B / p)) > 1.0

        def s_of_c(c):
            return 1.0 / c + 0.3 * c**2  # any smooth isotropic principal function

        S = _isotropic_function(C, s_of_c)
        exact = Q @ np.diag(s_of_c(np.array([a, b, b]))) @ Q.T
        assert np.isfinite(S).all()
        np.testing.assert_allclose(S, exact, atol=1e-13 * np.abs(exact).max())
    assert clipped > 0, "no state exercised the clip guard"


def test_spectral_distinct_and_nearly_repeated_match_eigh():
    rng = np.random.default_rng(12)
    for gap in (0.3, 1e-4, 1e-9, 1e-12):
        for _ in range(50):
            Q = _rotation(rng)
            lam = np.sort(rng.uniform(0.4, 1.6, 3))
            lam[1] = lam[2] - gap
            C = Q @ np.diag(lam) @ Q.T
            C = 0.5 * (C + C.T)
            c, P1, *_ = _spectral(C)
            np.testing.assert_allclose(np.sort(c), np.linalg.eigvalsh(C), atol=2e-15 * 3)

            def s_of_c(c):
                return np.log(c) + c

            S = _isotropic_function(C, s_of_c)
            ev, N = np.linalg.eigh(C)
            exact = np.einsum("a,ia,ja->ij", s_of_c(ev), N, N)
            # eigh's own vectors are only accurate to ~eps / gap: compare with the
            # conditioning of the pair in mind (the isotropic function is well conditioned)
            np.testing.assert_allclose(S, exact, atol=1e-12 * np.abs(exact).max())


def test_stress_at_repeated_stretches_matches_twin():
    """Element stress at the exactly repeated states (undeformed, uniaxial in x, y and z)
    equals the eigh twin's, including the undeformed zero."""
    mesh = hex_block(2.0, 2.0, 2.0, 1, 1, 1)
    ops = hex_operators(mesh.points, mesh.cells)
    mu, alpha, K, _, _ = MATERIAL.kernel_arrays()
    for stretch in ((1.0, 1.0, 1.0), (0.7, 1.19, 1.19), (1.19, 0.7, 1.19), (1.19, 1.19, 0.7),
                    (1.05, 1.05, 1.05)):
        u = mesh.points * (np.array(stretch) - 1.0)
        out = np.zeros((1, 6))
        hex_stress(u, mesh.cells, ops.bbar, np.zeros(1, np.int32), mu[None], alpha[None],
                   np.array([K]), *NO_PRONY, np.zeros((1, 6)), np.zeros((1, 6, 0)), out)
        F = np.diag(stretch)[None]
        S = pk2_numpy(F, MATERIAL)[0]
        sigma = np.diag(stretch) @ S @ np.diag(stretch) / np.prod(stretch)
        expected = sigma[[0, 1, 2, 0, 1, 0], [0, 1, 2, 1, 2, 2]]
        np.testing.assert_allclose(out[0], expected, atol=1e-10 * MATERIAL.mu0_Pa)
        if stretch[1] == stretch[2]:
            assert out[0, 1] == out[0, 2]  # the repeated pair stays exactly repeated
        if stretch == (1.0, 1.0, 1.0):
            assert not out.any()  # u = 0: F = I exactly, the p2 guard, exactly stress-free


# ---------------------------------------------------------------------- kernels vs twins
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_force_kernel_matches_numpy_twin(seed):
    mesh, ops, rng = _mesh(seed=seed)
    k_hg = 0.1 * MATERIAL.mu0_Pa * ops.gamma_scale
    for material in (MATERIAL, TWO_TERM):
        u = _random_state(mesh.points, rng)
        status, f = _forces(u, mesh, ops, material, k_hg)
        assert status == (0, -1)
        ref = hex_forces_numpy(u, mesh.cells, ops, material, k_hg)
        np.testing.assert_allclose(f, ref, atol=1e-10 * np.abs(ref).max())
        W, Whg = _energy(u, mesh, ops, material, k_hg)
        W_ref, Whg_ref = hex_energy_numpy(u, mesh.cells, ops, material, k_hg)
        assert W == pytest.approx(W_ref, rel=1e-10)
        assert Whg == pytest.approx(Whg_ref, rel=1e-10)


def test_parallel_kernel_equals_serial_and_ignores_thread_count():
    """The race-free parallel kernel: equal to the serial one to rounding, and bit-identical
    whatever the number of threads (fixed summation order per node)."""
    mesh, ops, rng = _mesh(seed=4, n=(6, 4, 8))
    k_hg = 0.05 * MATERIAL.mu0_Pa * ops.gamma_scale
    u = _random_state(mesh.points, rng)
    _, serial = _forces(u, mesh, ops, MATERIAL, k_hg, parallel=False)
    threads = numba.get_num_threads()
    try:
        results = []
        for n in sorted({1, threads}):
            numba.set_num_threads(n)
            status, f = _forces(u, mesh, ops, MATERIAL, k_hg, parallel=True)
            assert status == (0, -1)
            results.append(f)
    finally:
        numba.set_num_threads(threads)
    np.testing.assert_array_equal(results[0], results[-1])
    # summation order differs from the serial scatter: rounding of a sum of up to 8 terms
    np.testing.assert_allclose(results[0], serial, rtol=0, atol=1e-13 * np.abs(serial).max())


def test_forces_are_the_energy_gradient():
    """Forces are the exact derivative of the energy kernel (central differences)."""
    mesh, ops, rng = _mesh(seed=5)
    k_hg = 0.1 * MATERIAL.mu0_Pa * ops.gamma_scale
    u = _random_state(mesh.points, rng)
    _, f = _forces(u, mesh, ops, MATERIAL, k_hg)

    def energy(uu):
        return sum(_energy(uu, mesh, ops, MATERIAL, k_hg))

    assert_energy_gradient(f, energy, u, rng.choice(mesh.n_nodes, 12, replace=False))


@pytest.mark.parametrize("F", [np.diag([0.7, 1.19, 1.19]), np.eye(3),
                               np.array([[1.1, 0.2, 0.0], [-0.1, 0.9, 0.15],
                                         [0.05, 0.0, 0.8]])],
                         ids=["uniaxial", "rigid-translation", "general"])
def test_patch_test_homogeneous_deformation(F):
    """Rung 2 in 3D: a homogeneous deformation of a distorted hex mesh gives zero interior
    forces (exact to rounding), also with the hourglass stiffness on (the FB vectors are
    orthogonal to linear fields). The identity case adds a rigid translation."""
    mesh, ops, _ = _mesh(distort=0.3, seed=3, n=(4, 3, 6))
    u = mesh.points @ (F - np.eye(3)).T + np.array([1e-3, -2e-3, 5e-4])
    k_hg = 0.1 * MATERIAL.mu0_Pa * ops.gamma_scale
    status, f = _forces(u, mesh, ops, MATERIAL, k_hg)
    assert status == (0, -1)
    interior = ~mesh.boundary_nodes()
    assert interior.sum() > 20
    u10 = mesh.points * np.array([0.05, 0.05, -0.1])
    scale = np.abs(_forces(u10, mesh, ops, MATERIAL, k_hg)[1]).max()
    assert np.abs(f[interior]).max() <= 1e-10 * scale
    assert _energy(u, mesh, ops, MATERIAL, k_hg)[1] <= 1e-20 * scale * 0.024
    if np.allclose(F, np.diag(np.diag(F))) and not np.allclose(F, np.eye(3)):
        # top-face reaction = the homogeneous nominal stress times the reference area
        lam = np.diag(F)
        P_zz = MATERIAL.kirchhoff_stress(lam)[2] / lam[2]
        top = mesh.node_sets()["top"]
        assert f[top, 2].sum() == pytest.approx(P_zz * mesh.bottom_area_m2, rel=1e-10)


def test_hourglass_vectors_are_orthogonal_to_linear_fields():
    mesh, ops, rng = _mesh(distort=0.3, seed=8)
    X = mesh.points[mesh.cells]  # (n, 8, 3)
    np.testing.assert_allclose(np.einsum("eki,eia->eka", ops.gamma, X), 0.0, atol=1e-15)
    np.testing.assert_allclose(ops.gamma.sum(axis=2), 0.0, atol=1e-13)
    # the mean gradient reproduces linear fields: sum_i X_i (x) b_i = I
    np.testing.assert_allclose(np.einsum("eia,eib->eab", X, ops.bbar),
                               np.broadcast_to(np.eye(3), (mesh.n_cells, 3, 3)), atol=1e-12)


def test_kernel_jacobian_matches_linear_stiffness():
    """Finite differences of the force kernel at the reference state equal the assembled
    small-strain stiffness (natural period, influence field, stable step)."""
    mesh, ops, rng = _mesh(seed=7)
    n = mesh.n_cells
    k_hg = 0.1 * MATERIAL.mu0_Pa * ops.gamma_scale
    Ke = element_stiffness(ops, np.full(n, MATERIAL.mu0_Pa), np.full(n, MATERIAL.bulk_modulus_Pa),
                           k_hg)
    K = assemble(mesh.cells, Ke, mesh.n_nodes, 3).toarray()
    h = 1e-9 * 0.024
    for dof in rng.choice(3 * mesh.n_nodes, 15, replace=False):
        up, dn = np.zeros(3 * mesh.n_nodes), np.zeros(3 * mesh.n_nodes)
        up[dof] += h
        dn[dof] -= h
        _, fp = _forces(up.reshape(-1, 3), mesh, ops, MATERIAL, k_hg)
        _, fm = _forces(dn.reshape(-1, 3), mesh, ops, MATERIAL, k_hg)
        column = (fp - fm).ravel() / (2 * h)
        np.testing.assert_allclose(column, K[:, dof], atol=1e-6 * np.abs(K).max())


@pytest.mark.parametrize("parallel", [False, True])
def test_inverted_element_is_reported(parallel):
    mesh, ops, _ = _mesh(distort=0.0)
    u = np.zeros_like(mesh.points)
    e = 17
    a, b = mesh.cells[e, 0], mesh.cells[e, 6]
    u[a] = 3.0 * (mesh.points[b] - mesh.points[a])  # node 0 far beyond its opposite corner
    status, f = _forces(u, mesh, ops, MATERIAL, np.zeros(mesh.n_cells), parallel)
    touching = set(np.flatnonzero((mesh.cells == a).any(axis=1)))
    assert status[0] == 1 and status[1] in touching


# ---------------------------------------------------------------------- meshes
@pytest.mark.parametrize("n", [(2, 1, 1), (4, 3, 6), (8, 7, 20), (5, 4, 3), (12, 10, 9)])
def test_hex_cylinder_is_valid_and_exact_in_area(n):
    mesh = hex_cylinder(38.0, 24.0, *n)
    n_core, n_ring, n_axial = n
    assert mesh.n_cells == (n_core**2 + 4 * n_core * n_ring) * n_axial
    ops = hex_operators(mesh.points, mesh.cells)  # raises on a non-positive Jacobian
    assert isinstance(ops, HexOperators)
    # exact_area: the faceted section has the circle's area, so the volume is pi R^2 H
    assert ops.volume.sum() == pytest.approx(np.pi * 0.019**2 * 0.024, rel=1e-12)
    assert mesh.radius_m == pytest.approx(0.019, rel=1e-12)
    assert mesh.outer_radius_m > mesh.radius_m
    # no degenerate element: the smallest scaled Jacobian (corner det / edge lengths) stays
    # well away from zero; the worst ring cell at a core corner is about 0.5
    assert _min_scaled_jacobian(mesh) > 0.3
    sets = mesh.node_sets()
    assert sets["axis"].any() == (n_core % 2 == 0)
    assert np.isclose(mesh.points[:, 2].max(), 0.024) and mesh.points[:, 2].min() == 0.0


def _min_scaled_jacobian(mesh):
    X = mesh.points[mesh.cells]
    corners = [(0, 1, 3, 4), (1, 2, 0, 5), (2, 3, 1, 6), (3, 0, 2, 7), (4, 7, 5, 0),
               (5, 4, 6, 1), (6, 5, 7, 2), (7, 6, 4, 3)]
    worst = np.inf
    for c, a, b, d in corners:
        e1, e2, e3 = X[:, a] - X[:, c], X[:, b] - X[:, c], X[:, d] - X[:, c]
        det = np.einsum("ei,ei->e", np.cross(e1, e2), e3)
        norm = (np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
                * np.linalg.norm(e3, axis=1))
        worst = min(worst, float((det / norm).min()))
    return worst


def test_hex_cylinder_grading_and_inscribed_option():
    mesh = hex_cylinder(38.0, 24.0, 8, 6, 12, radial_ratio=3.0, axial_ratio=4.0)
    z = np.unique(np.round(mesh.points[:, 2], 12))
    dz = np.diff(z)
    assert dz.max() / dz.min() == pytest.approx(4.0) and dz[0] == pytest.approx(dz[-1])
    # along the +x ray through the side midpoint: ring sizes shrink 3:1 towards the rim
    on_ray = (np.abs(mesh.points[:, 1]) < 1e-12) & (mesh.points[:, 0] > 0) & (
        mesh.points[:, 2] == 0)
    x = np.sort(mesh.points[on_ray, 0])
    ring = np.diff(x[-7:])
    assert ring[0] / ring[-1] == pytest.approx(3.0, rel=1e-9)
    # the core's element next to the ring matches the ring's first element
    assert np.diff(x)[-7] == pytest.approx(ring[0], rel=0.05)
    plain = hex_cylinder(38.0, 24.0, 8, 6, 12, exact_area=False)
    assert plain.outer_radius_m == pytest.approx(0.019, rel=1e-12)
    theta = 2 * np.pi / 32
    assert plain.bottom_area_m2 / (np.pi * 0.019**2) == pytest.approx(
        np.sin(theta) / theta, rel=1e-12)


def test_layers_by_height_in_cylinder_and_block():
    for mesh in (hex_cylinder(38.0, 24.0, 4, 3, 12, layer_heights_mm=(8.0, 15.5)),
                 hex_block(10.0, 10.0, 24.0, 2, 2, 12, layer_heights_mm=(8.0, 15.5))):
        zc = mesh.points[mesh.cells, 2].mean(axis=1)
        expected = (zc > 0.008).astype(int) + (zc > 0.0155)
        np.testing.assert_array_equal(mesh.cell_material, expected)
        # every element lies in one layer: the interfaces are node planes
        zmin = mesh.points[mesh.cells, 2].min(axis=1)
        zmax = mesh.points[mesh.cells, 2].max(axis=1)
        for zi in (0.008, 0.0155):
            assert not np.any((zmin < zi - 1e-12) & (zmax > zi + 1e-12))
        hex_operators(mesh.points, mesh.cells)
    with pytest.raises(ValueError, match="no node plane of its own"):
        hex_cylinder(38.0, 24.0, 4, 3, 3, layer_heights_mm=(11.0, 12.0))
    with pytest.raises(ValueError, match="not inside the sample"):
        hex_block(1, 1, 24, 1, 1, 4, layer_heights_mm=(30.0,))


def test_mesh_rejections_name_the_problem():
    with pytest.raises(ValueError, match="n_core"):
        hex_cylinder(38, 24, n_core=0)
    with pytest.raises(ValueError, match="diameter"):
        hex_cylinder(-1, 24)
    with pytest.raises(ValueError, match="nx"):
        hex_block(1, 1, 1, 1.5, 1, 1)
    bad = hex_block(1, 1, 1, 1, 1, 1)
    flipped = Mesh(points=bad.points, cells=bad.cells[:, [4, 5, 6, 7, 0, 1, 2, 3]],
                   cell_type="hexahedron")
    with pytest.raises(ValueError, match="hexahedron 0 has a non-positive Jacobian"):
        hex_operators(flipped.points, flipped.cells)


# ---------------------------------------------------------------------- hourglass scale
_G = 1.0 / np.sqrt(3.0)
_CORNERS = np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1],
                     [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], dtype=float)


def _full_deviatoric_energy(X, u, dim):
    """mu = 1 deviatoric energy int dev(eps):dev(eps) dV of the fully integrated element
    (2^dim Gauss points); the quad at large radius is nearly plane strain (hoop term kept)."""
    corners = _CORNERS[:4, :2] if dim == 2 else _CORNERS
    W = 0.0
    for gp in np.array(np.meshgrid(*[(-_G, _G)] * dim)).reshape(dim, -1).T:
        s = 1.0 + corners * gp  # (n_en, dim)
        N = np.prod(s, axis=1) / 2**dim
        dN = np.stack([corners[:, a] * np.prod(np.delete(s, a, axis=1), axis=1)
                       for a in range(dim)], axis=1) / 2**dim
        J = dN.T @ X
        H = np.zeros((3, 3))
        H[:dim, :dim] = u.T @ dN @ np.linalg.inv(J).T
        dV = np.linalg.det(J)
        if dim == 2:
            r = N @ X[:, 0]
            H[2, 2] = (N @ u[:, 0]) / r
            dV *= 2 * np.pi * r
        eps = 0.5 * (H + H.T)
        dev = eps - np.trace(eps) / 3 * np.eye(3)
        W += dV * np.sum(dev * dev)
    return W


def test_hourglass_stiffness_is_the_quads_fraction_of_the_full_element():
    """kappa means the same for both elements: the FB energy 1/2 k q^2 (kappa = 1, mu = 1)
    over the fully integrated element's deviatoric energy in the same mode is 10.29 for the
    quad (on a square far from the axis) and for the cube's bilinear modes that stretch along
    the displacement; 12 for its pure-shear bilinear ones and 21.6 for the trilinear one."""
    from solver.kernels import axisymmetric_operators

    cube = hex_block(1e3, 1e3, 1e3, 1, 1, 1)
    ops = hex_operators(cube.points, cube.cells)
    X = cube.points[cube.cells[0]]
    ratios = []
    for k in range(4):
        u = np.zeros((8, 3))
        u[:, 0] = np.prod(_CORNERS[:, [(0, 1), (1, 2), (2, 0), (0, 1)][k]], axis=1) * (
            _CORNERS[:, 2] if k == 3 else 1.0)
        q = ops.gamma[0, k] @ u[:, 0]
        ratios.append(0.5 * ops.gamma_scale[0] * q * q / _full_deviatoric_energy(X, u, 3))
    np.testing.assert_allclose(ratios, [72 / 7, 12.0, 72 / 7, 21.6], rtol=1e-12)
    square = np.array([[1e3, 0.0], [1e3 + 1, 0.0], [1e3 + 1, 1.0], [1e3, 1.0]])
    qops = axisymmetric_operators(square, np.array([[0, 1, 2, 3]]))
    u = np.zeros((4, 2))
    u[:, 0] = [1.0, -1.0, 1.0, -1.0]
    q = qops.gamma[0] @ u[:, 0]
    quad = 0.5 * qops.gamma_scale[0] * q * q / _full_deviatoric_energy(square, u, 2)
    assert quad == pytest.approx(72 / 7, rel=1e-4)  # the hoop term at r = 1000 a: ~1e-5
