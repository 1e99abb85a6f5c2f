"""Fast checks of the FElupe reference set-up (experiments.felupe_reference).

The reference is only worth something if its own set-up is right: the material convention,
FElupe's axisymmetric axes and force convention (full 2 pi), the units (mm, N, MPa inside,
Pa outside), the boundary conditions and the layered-material path. Each test uses meshes of a
few cells so the file runs in seconds; the mesh convergence and the comparison with our solver
are in test_verification_felupe.py (slow).
"""

import math

import numpy as np
import pytest

pytest.importorskip("felupe")

from experiments import felupe_reference as fr  # noqa: E402
from solver import Ogden  # noqa: E402

MU, ALPHA = 1875.0, 4.9


# ---------------------------------------------------------------- Coulomb platens
def test_coulomb_platens_without_friction_are_the_frictionless_closed_form():
    # Held by the penalty contact alone (both platens moving by half the travel, the
    # mid-height axis node pinned), frictionless faces must still give homogeneous uniaxial
    # compression; the penalty's penetration (< 1e-3 mm, against 2.4 mm of travel) is the
    # only difference, hence 1e-3.
    out = fr.compression_curve(MU, ALPHA, 0.499, platen="coulomb", friction=0.0,
                               strain=0.1, order="linear", n_radial=4, n_axial=4,
                               n_increments=4)
    ref = fr.frictionless_check(MU, ALPHA, 0.499, strains=(0.05, 0.1), n_radial=2,
                                n_axial=2)
    for strain, closed in zip(ref["strain"], ref["closed_form_N"], strict=True):
        i = int(np.argmin(np.abs(out["strain"] - strain)))
        assert out["force_N"][i] == pytest.approx(closed, rel=1e-3)


def test_coulomb_friction_lies_between_frictionless_and_bonded():
    kw = dict(strain=0.1, order="linear", n_radial=6, n_axial=6, n_increments=4)
    free = fr.compression_curve(MU, ALPHA, 0.499, platen="frictionless", **kw)["force_N"]
    some = fr.compression_curve(MU, ALPHA, 0.499, platen="coulomb", friction=0.15,
                                **kw)["force_N"]
    more = fr.compression_curve(MU, ALPHA, 0.499, platen="coulomb", friction=0.3,
                                **kw)["force_N"]
    bonded = fr.compression_curve(MU, ALPHA, 0.499, platen="bonded", **kw)["force_N"]
    assert np.all(free[1:] < some[1:]) and np.all(some[1:] < more[1:])
    assert np.all(more[1:] < bonded[1:])


# ---------------------------------------------------------------- homogeneous closed form
@pytest.mark.parametrize("order", ["quadratic", "linear"])
@pytest.mark.parametrize("nu", [0.45, 0.499])
def test_frictionless_matches_closed_form(order, nu):
    # Frictionless compression is homogeneous uniaxial stress, which every mesh represents
    # exactly; what is left is Newton's tolerance (relative residual 1.5e-8), so 1e-6 is
    # loose by two orders yet would catch a wrong 2 pi, a wrong unit or a wrong K.
    out = fr.frictionless_check(MU, ALPHA, nu, order=order)
    assert out["max_rel_error"] < 1e-6, out


def test_frictionless_two_term_ogden_matches_closed_form():
    # A two-term law with a negative exponent exercises the sum convention of both codes.
    mu, alpha = (1500.0, -200.0), (5.0, -2.0)
    out = fr.frictionless_check(mu, alpha, 0.49)
    assert out["max_rel_error"] < 1e-6, out


def test_frictionless_3d_hex_matches_closed_form_with_mesh_area():
    # The 3D disk is faceted, so the closed form uses the mesh's own cross-section; the
    # deformation is still homogeneous, hence the same Newton-limited tolerance.
    out = fr.frictionless_check(MU, ALPHA, 0.499, axisymmetric=False, n_radial=3, n_axial=2)
    assert out["max_rel_error"] < 1e-6, out
    assert 0.9 < out["area_ratio"] < 1.0  # an inscribed polygon: smaller than pi R^2


def test_force_units_small_strain():
    # Independent of the closed-form routine: at 0.5 % the nominal stress is E * strain
    # with E = 2 mu (1 + nu); the second-order term is ~(3/2) * strain relative, i.e.
    # below 1 % at this strain, so 1.5 % tolerance separates a unit slip (x1000) or a
    # missing 2 pi (x6.3) from the physics.
    nu, strain = 0.499, 0.005
    out = fr.compression_curve(MU, ALPHA, nu, platen="frictionless", strain=strain,
                               n_radial=2, n_axial=2, n_increments=1, check_strains=())
    expected = 2 * MU * (1 + nu) * strain * math.pi * 0.019**2  # N
    assert out["force_N"][-1] == pytest.approx(expected, rel=0.015)
    assert out["displacement_mm"][-1] == pytest.approx(0.12)


# ---------------------------------------------------------------- bonded set-up
@pytest.fixture(scope="module")
def coarse_bonded():
    return fr.compression_curve(MU, ALPHA, 0.499, n_radial=4, n_axial=4, grading=1.0,
                                n_increments=6)


def test_bonded_stiffer_than_frictionless(coarse_bonded):
    free = fr.compression_curve(MU, ALPHA, 0.499, platen="frictionless", n_radial=4,
                                n_axial=4, grading=1.0, n_increments=6)
    assert np.allclose(coarse_bonded["displacement_mm"], free["displacement_mm"])
    ratio = coarse_bonded["force_N"][1:] / free["force_N"][1:]
    # Bonding a 38 x 24 mm sample stiffens it by tens of percent, more at larger strain.
    assert np.all(ratio > 1.1), ratio
    assert ratio[-1] > ratio[0]


def test_bonded_curve_shape(coarse_bonded):
    d, f = coarse_bonded["displacement_mm"], coarse_bonded["force_N"]
    assert d[0] == 0.0 and f[0] == 0.0
    assert d[-1] == pytest.approx(0.3 * 24.0)
    assert np.all(np.diff(f) > 0)
    # The checked strains are solved exactly, not interpolated.
    for s in fr.CHECK_STRAINS:
        assert np.any(np.isclose(d, s * 24.0, rtol=0, atol=1e-9))
    assert coarse_bonded["n_dofs"] > coarse_bonded["n_dofs_displacement"] > 0


def test_force_scales_with_modulus_and_size():
    # Static hyperelasticity has no length or stress scale besides mu: twice mu gives twice
    # the force, and a sample scaled by 2 in every direction gives 4 x the force at the same
    # strain. Exact up to Newton's tolerance (1e-8 relative), asserted to 1e-6.
    kw = dict(n_radial=3, n_axial=3, grading=2.0, n_increments=4)
    base = fr.compression_curve(MU, ALPHA, 0.49, **kw)["force_N"][1:]
    twice_mu = fr.compression_curve(2 * MU, ALPHA, 0.49, **kw)["force_N"][1:]
    big = fr.compression_curve(MU, ALPHA, 0.49, diameter_mm=76.0, height_mm=48.0,
                               **kw)["force_N"][1:]
    np.testing.assert_allclose(twice_mu, 2 * base, rtol=1e-6)
    np.testing.assert_allclose(big, 4 * base, rtol=1e-6)


def test_rollover_detected_and_prevented_by_contact():
    # A graded 8 x 8 mesh resolves the rim fold: without contact the side nodes near the
    # rim end below z = 0 by ~0.1 mm at 30 %; the penalty contact holds them to a small
    # fraction of that (the penetration that the penalty needs to carry the load).
    kw = dict(n_radial=8, n_axial=8, grading=4.0, n_increments=10)
    free = fr.compression_curve(MU, ALPHA, 0.499, rollover_contact=False, **kw)
    held = fr.compression_curve(MU, ALPHA, 0.499, rollover_contact=True, **kw)
    assert free["rollover"]["below_bottom_mm"] > 0.02
    assert free["rollover"]["n_nodes_beyond"] > 0
    # up-down symmetry of the bonded problem
    assert free["rollover"]["above_top_mm"] == pytest.approx(
        free["rollover"]["below_bottom_mm"], rel=1e-6)
    assert held["rollover"]["below_bottom_mm"] < 0.05 * free["rollover"]["below_bottom_mm"]
    # the rolled-over surface pushes on the platen: more force, carried by contact
    assert held["force_N"][-1] > free["force_N"][-1]
    assert held["contact_force_N"][-1] > 0.0
    # before the fold forms (10 % strain) contact changes nothing
    i10 = np.argmin(np.abs(held["strain"] - 0.1))
    assert held["contact_force_N"][i10] == 0.0
    assert held["force_N"][i10] == pytest.approx(free["force_N"][i10], rel=1e-9)


# ---------------------------------------------------------------- layers and 3D
def test_layers_of_one_material_equal_the_homogeneous_sample():
    # With grading 1 and an interface at mid-height the layered mesh is the homogeneous
    # mesh; only the per-cell material path differs, so the forces agree to Newton's
    # tolerance.
    kw = dict(n_radial=3, n_axial=4, grading=1.0, n_increments=4)
    one = fr.compression_curve(MU, ALPHA, 0.499, **kw)
    two = fr.compression_curve([MU, MU], [ALPHA, ALPHA], 0.499, layers=[12.0], **kw)
    np.testing.assert_allclose(two["force_N"], one["force_N"], rtol=1e-6)


def test_layered_sample_lies_between_its_materials():
    kw = dict(n_radial=3, n_axial=4, grading=1.0, n_increments=4)
    soft = fr.compression_curve(1000.0, 4.0, 0.49, **kw)["force_N"][-1]
    stiff = fr.compression_curve(3000.0, 6.0, 0.49, **kw)["force_N"][-1]
    both = fr.compression_curve([1000.0, 3000.0], [4.0, 6.0], [0.49, 0.49], layers=[12.0],
                                **kw)["force_N"][-1]
    assert soft < both < stiff


def test_3d_bonded_hex_runs_and_is_stiffer_than_frictionless():
    kw = dict(axisymmetric=False, n_radial=3, n_axial=2, grading=1.0, n_increments=3,
              strain=0.1, check_strains=())
    bonded = fr.compression_curve(MU, ALPHA, 0.49, **kw)
    free = fr.compression_curve(MU, ALPHA, 0.49, platen="frictionless", **kw)
    assert bonded["force_N"][-1] > 1.05 * free["force_N"][-1]
    assert bonded["deformed_points_mm"].shape[1] == 3


# ---------------------------------------------------------------- helpers and errors
def test_graded_coordinates():
    x = fr.graded_coordinates(19.0, 8, grading=4.0, fine="end")
    h = np.diff(x)
    assert x[0] == 0.0 and x[-1] == 19.0
    assert np.all(h > 0) and np.all(np.diff(h) < 0)
    assert h[0] / h[-1] == pytest.approx(4.0)
    y = fr.graded_coordinates(24.0, 9, grading=3.0, fine="both")
    hy = np.diff(y)
    np.testing.assert_allclose(hy, hy[::-1], rtol=1e-12)   # symmetric about mid-height
    assert hy.max() / hy.min() == pytest.approx(3.0)
    np.testing.assert_allclose(fr.graded_coordinates(2.0, 4), [0, 0.5, 1, 1.5, 2])


def test_richardson_recovers_known_order_and_limit():
    # f(h) = 3 + 0.2 h^1.5 sampled at h = 1, 1/2, 1/4: order and limit exact.
    f = [3 + 0.2 * h**1.5 for h in (1.0, 0.5, 0.25)]
    out = fr.richardson(*f)
    assert out["order"] == pytest.approx(1.5, rel=1e-12)
    assert out["extrapolated"] == pytest.approx(3.0, rel=1e-12)
    # non-monotone differences: no order, error bar = last change
    bad = fr.richardson(1.0, 1.1, 1.05)
    assert math.isnan(bad["order"]) and bad["error_fine"] == pytest.approx(0.05 / 1.05)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(platen="sandpaper"), "platen"),
        (dict(platen="coulomb"), "friction"),
        (dict(platen="coulomb", friction=-0.1), "friction"),
        (dict(platen="bonded", friction=0.3), "friction"),
        (dict(platen="coulomb", friction=0.3, n_axial=3), "n_axial"),
        (dict(platen="coulomb", friction=0.3, axisymmetric=False), "axisymmetric"),
        (dict(platen="coulomb", friction=0.3, layers=[12.0], mu_Pa=[1.0, 2.0],
              alpha=[4.0, 4.0]), "symmetric"),
        (dict(strain=0.0), "strain"),
        (dict(nu=0.5), "nu"),
        (dict(mu_Pa=[1.0, 2.0], alpha=[4.0]), "alpha"),
        (dict(layers=[30.0], mu_Pa=[1.0, 2.0], alpha=[4.0, 4.0]), "layers"),
        (dict(layers=[12.0], mu_Pa=[1.0, 2.0, 3.0], alpha=[4.0, 4.0, 4.0]), "layers"),
        (dict(order="cubic"), "order"),
        (dict(grading=0.5), "grading"),
    ],
)
def test_bad_input_is_rejected_with_reason(kwargs, message):
    args = dict(mu_Pa=MU, alpha=ALPHA, nu=0.49, n_radial=2, n_axial=2)
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        fr.compression_curve(**args)


def test_closed_form_reference_is_the_project_material():
    # The closed form used above is the project's own Ogden (not a copy of FElupe's), so
    # the frictionless agreement ties FElupe's ogden + NearlyIncompressible to solver.Ogden.
    m = Ogden(mu_Pa=MU, alpha=ALPHA, nu=0.499)
    assert m.bulk_modulus_Pa == pytest.approx(2 * MU * 1.499 / (3 * 0.002))


def test_mesh_for_accuracy_picks_the_coarsest_sufficient_level():
    level = fr.mesh_for_accuracy(0.01)
    assert level["rel_error"] <= 0.01
    coarser = [lv for lv in fr.LADDER if lv["n_radial"] < level["n_radial"]]
    assert all(lv["rel_error"] > 0.01 for lv in coarser)
    assert fr.mesh_for_accuracy(0.005)["n_radial"] >= level["n_radial"]
    with pytest.raises(ValueError, match="accuracy"):
        fr.mesh_for_accuracy(1e-9)


def test_time_at_accuracy_reports_a_timed_curve():
    out = fr.time_at_accuracy(0.02)
    assert out["wall_s"] > 0 and out["n_dofs"] > 0
    assert out["rel_error"] <= 0.02
    assert 3.5 < out["force_N_at_max"] < 4.5  # the bonded 30 % force is ~4.08 N


def test_layers_survive_felupe_chunked_evaluation(monkeypatch):
    # FElupe evaluates materials in chunks of cells; the per-cell layer index must still
    # address the right cells. Force chunking on a small mesh by shrinking the chunk size
    # of FElupe's constitutive base class and compare with the unchunked result.
    import felupe

    kw = dict(n_radial=3, n_axial=4, grading=1.0, n_increments=3, strain=0.15)
    args = ([1000.0, 3000.0], [4.0, 6.0], 0.49)
    whole = fr.compression_curve(*args, layers=[12.0], **kw)["force_N"]
    monkeypatch.setattr(felupe.constitution._base.ConstitutiveMaterial, "chunksize", 18)
    chunked = fr.compression_curve(*args, layers=[12.0], **kw)["force_N"]
    np.testing.assert_allclose(chunked, whole, rtol=1e-9)
