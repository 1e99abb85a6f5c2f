"""Rungs 3-4 of the ladder and the explicit loop's contracts: closed form, energy balance,
quasi-static accuracy, the mu-scaling property, platen conditions and robustness."""

import numpy as np
import pytest

from solver import (
    CompressionTest,
    Ogden,
    Prony,
    SolverInstability,
    axisymmetric_cylinder,
    simulate,
)

from .checks import assert_energy_balance

MU, ALPHA = 1875.0, 4.9
MATERIAL = Ogden(mu_Pa=MU, alpha=ALPHA, nu=0.499)
AREA_M2 = np.pi * 0.019**2


@pytest.fixture(scope="module")
def bonded():
    return simulate(MATERIAL, CompressionTest())


@pytest.mark.parametrize("ramp", ["345", "constant"])
def test_frictionless_matches_closed_form(ramp):
    """Rung 3: homogeneous compression, F = P_uniaxial(lambda) * area, within 0.5 % everywhere.

    The deformation is homogeneous, so the mesh is exact (patch test); what remains is the
    inertia left after the virtual-work correction (0.1-0.3 % at the default ramp ratio). The
    closed form is the compressible one at the same nu (a root in the lateral stretch); at
    nu = 0.499 it differs from the incompressible formula by 0.06 % at 30 %.
    """
    r = simulate(MATERIAL, CompressionTest(platen="frictionless", ramp=ramp))
    lam = 1.0 - r.displacement_mm / 24.0
    exact = -MATERIAL.uniaxial_nominal_stress(lam, incompressible=False) * AREA_M2
    loaded = r.displacement_mm >= 0.01 * 24.0  # from 1 % strain on (force > 0.06 N)
    np.testing.assert_array_less(np.abs(r.force_N[loaded] / exact[loaded] - 1.0), 0.005)
    assert np.abs(r.force_N - exact).max() < 0.005 * exact.max()
    assert len(r.force_N) >= 31 and r.displacement_mm[-1] == pytest.approx(7.2)


def test_energy_balance(bonded):
    """Rung 4: platen work = stored elastic + hourglass + kinetic energy.

    The platen work and the internal work are path integrals over the run; the stored energy is
    evaluated from the state. They agree to the O(dt^2) error of the path integral (measured
    2e-4 of the final work). The kinetic energy of the quasi-static motion is a small fraction
    of the stored energy over the second half of the 3-4-5 ramp (bound 5 %, the usual explicit
    quasi-static guideline; measured 3.7 %) and vanishes at full travel (bound 1e-4).
    """
    assert_energy_balance(bonded)
    assert bonded.hourglass_ratio < 0.01  # hourglass modes hold < 1 % of the energy


@pytest.mark.slow
@pytest.mark.parametrize("ramp", ["345", "constant"])
@pytest.mark.parametrize("material", [MATERIAL, Ogden(mu_Pa=3100.0, alpha=6.5, nu=0.49)],
                         ids=["a4.9-nu0.499", "a6.5-nu0.49"])
def test_inertia_changes_the_force_well_under_one_percent(material, ramp):
    """The default ramp ratio against a 5x slower run (inertia 25x smaller).

    Run to 31 % so that 30 % is not the instant where a constant-speed platen stops dead.
    Bound 0.5 %: 'well under 1 %' (measured 0.24 % for 3-4-5, 0.13-0.31 % constant speed).
    The raw platen reaction, without the virtual-work correction, is off by tens of percent
    on the 3-4-5 ramp at this ratio, which is what the correction is for.
    """
    test = CompressionTest(ramp=ramp, strain=0.31)
    fast = simulate(material, test)
    slow = simulate(material, test, quasi_static_ratio=30.0)
    sel = (slow.displacement_mm > 0.015 * 24.0) & (slow.displacement_mm <= 7.2 + 1e-9)
    d = slow.displacement_mm[sel]
    err = np.interp(d, fast.displacement_mm, fast.force_N) / slow.force_N[sel] - 1.0
    assert np.abs(err).max() < 0.005
    if ramp == "345":
        raw = np.interp(d, fast.displacement_mm, fast.reaction_N) / slow.force_N[sel] - 1.0
        assert np.abs(raw).max() > 0.05


def test_force_scales_exactly_with_mu(bonded):
    """F(d; mu, alpha, nu) = mu f(d; alpha, nu): the calibration eliminates mu with it.

    To rounding: the same steps and times, forces within 1e-9 relative above an absolute
    floor of 1e-10 of the peak force. The floor is the rounding of the volumetric mass's
    solves (their element system has a condition number near 1e6), measured 5e-11 N
    (1e-11 of the peak) at every output; it shows as 1e-9 relative at the first output.
    """
    scaled = simulate(MATERIAL.with_mu_scaled(3100.0 / MU), CompressionTest())
    assert scaled.n_steps == bonded.n_steps
    expected = bonded.force_N * 3100.0 / MU
    np.testing.assert_allclose(scaled.force_N, expected, rtol=1e-9,
                               atol=1e-10 * expected.max())
    np.testing.assert_allclose(scaled.time_s, bonded.time_s, rtol=0, atol=0)


def test_bonded_is_stiffer_and_rolls_over(bonded):
    """Bonded platens stiffen the response and the bulging side rolls onto the platens,
    without any node passing through them."""
    free = simulate(MATERIAL, CompressionTest(platen="frictionless"))
    ratio = bonded.force_N[-1] / free.force_N[-1]
    assert 1.2 < ratio < 2.0
    assert bonded.contact_radius_mm[-1] > 19.0 + 0.2  # side surface now touches the platen
    assert free.contact_radius_mm[-1] == pytest.approx(19.0 * free.deformed_points_m[:, 0].max()
                                                       / 0.019, rel=1e-6)
    z = bonded.deformed_points_m[:, 1]
    top = 0.024 - 0.0072
    assert z.min() >= -1e-12 and z.max() <= top + 1e-12


def test_coulomb_friction_lies_between_frictionless_and_bonded(bonded):
    free = simulate(MATERIAL, CompressionTest(platen="frictionless"))
    forces = [simulate(MATERIAL, CompressionTest(platen="coulomb", friction=mu_f)).force_N[-1]
              for mu_f in (0.05, 0.3, 5.0)]
    assert free.force_N[-1] < forces[0] < forces[1] < forces[2]
    # a large coefficient sticks everywhere: the bonded answer (friction 5 never slips here)
    assert forces[2] == pytest.approx(bonded.force_N[-1], rel=2e-3)


def test_layers_take_their_own_materials():
    soft = Ogden(mu_Pa=1000.0, alpha=4.9, nu=0.499)
    stiff = Ogden(mu_Pa=3000.0, alpha=4.9, nu=0.499)
    mesh = axisymmetric_cylinder(38, 24, layer_heights_mm=(12.0,))
    assert set(mesh.cell_material) == {0, 1}
    layered = simulate([soft, stiff], CompressionTest(), mesh).force_N[-1]
    both_soft = simulate([soft, soft], CompressionTest(), mesh).force_N[-1]
    both_stiff = simulate([stiff, stiff], CompressionTest(), mesh).force_N[-1]
    assert both_soft < layered < both_stiff
    # springs in series bound a two-layer stack from below
    assert layered > 1.0 / (0.5 / both_soft + 0.5 / both_stiff) * 0.95
    with pytest.raises(ValueError, match="2 materials"):
        simulate(soft, CompressionTest(), mesh)


def test_viscoelastic_ramp_matches_convolution():
    """Frictionless constant-speed compression of a hyperviscoelastic sample against the
    hereditary integral of the homogeneous incompressible closed form."""
    from .reference import prony_convolution

    prony = Prony(g=(0.5,), tau_s=(1.5,))
    material = Ogden(mu_Pa=MU, alpha=ALPHA, nu=0.499, prony=prony)
    instantaneous = Ogden(mu_Pa=MU / prony.g_inf, alpha=ALPHA, nu=0.3)
    rate = 2.4  # mm/s: a 3 s ramp, twice tau
    r = simulate(material, CompressionTest(platen="frictionless", ramp="constant",
                                           rate_mm_per_s=rate, strain=0.31))

    def stretch(t):
        return 1.0 - rate * t / 24.0

    def s_iso(t, a):  # instantaneous isochoric PK2 of the incompressible uniaxial state
        lam = stretch(t)
        lb = np.array([lam, lam**-0.5, lam**-0.5])
        return instantaneous.kirchhoff_stress(lb)[a] / lb[a] ** 2

    t_check = np.linspace(0.3, 3.0, 10)
    S1 = prony_convolution(t_check, lambda t: s_iso(t, 0), prony.g, prony.tau_s)
    S2 = prony_convolution(t_check, lambda t: s_iso(t, 1), prony.g, prony.tau_s)
    lam = stretch(t_check)
    # lateral stress free: the pressure cancels the lateral Kirchhoff stress lam_t^2 S2
    nominal = (lam**2 * S1 - lam**-1 * S2) / lam
    expected = -nominal * AREA_M2
    got = np.interp(t_check, r.time_s, r.force_N)
    # nu = 0.499 vs incompressible (0.06 %) plus the inertia left (0.1-0.3 %)
    np.testing.assert_allclose(got, expected, rtol=5e-3)
    elastic = simulate(Ogden(mu_Pa=MU, alpha=ALPHA, nu=0.499),
                       CompressionTest(platen="frictionless", ramp="constant",
                                       rate_mm_per_s=rate, strain=0.31))
    assert got[-1] > 1.2 * np.interp(3.0, elastic.time_s, elastic.force_N)


def test_relaxation_during_hold():
    """Ramp to 10 % in 1 s, hold 4 s: the force relaxes monotonically to the long-term
    closed form (after 8 tau the Prony part is e^-8 ~ 3e-4 of the instantaneous stress)."""
    prony = Prony(g=(0.5,), tau_s=(0.5,))
    material = Ogden(mu_Pa=MU, alpha=ALPHA, nu=0.499, prony=prony)
    r = simulate(material, CompressionTest(platen="frictionless", ramp="constant",
                                           rate_mm_per_s=2.4, strain=0.1, hold_s=4.0))
    hold = r.time_s > 1.0 + 1e-9
    assert np.all(np.diff(r.force_N[hold]) < 0.0)  # monotone relaxation
    relaxed = -MATERIAL.uniaxial_nominal_stress(0.9, incompressible=False) * AREA_M2
    assert r.force_N[-1] == pytest.approx(relaxed, rel=3e-3)


def test_instability_is_reported_not_returned():
    """Far too large a time step blows up; the run stops with where and when."""
    with pytest.raises(SolverInstability) as info:
        simulate(MATERIAL, CompressionTest(strain=0.1), dt_safety=3.0)
    err = info.value
    assert err.step > 0 and err.time_s >= 0.0
    msg = str(err)
    assert "step" in msg and "t =" in msg and "element" in msg
    assert err.element is not None and 0 <= err.element < 252


def test_bad_inputs_are_rejected_by_name():
    with pytest.raises(ValueError, match="platen"):
        CompressionTest(platen="glued")
    with pytest.raises(ValueError, match="strain"):
        CompressionTest(strain=1.2)
    with pytest.raises(ValueError, match="friction"):
        CompressionTest(platen="coulomb")
    with pytest.raises(ValueError, match="mesh is"):
        simulate(MATERIAL, CompressionTest(diameter_mm=30.0), axisymmetric_cylinder(38, 24))


def test_instability_survives_a_process_pool():
    """Pickled (as a process pool returns it) with its where and when."""
    import pickle

    err = SolverInstability("NaN in the internal force", 12, 0.5, 1.25, element=7)
    back = pickle.loads(pickle.dumps(err))
    assert (back.reason, back.step, back.time_s, back.travel_mm, back.element) == (
        "NaN in the internal force", 12, 0.5, 1.25, 7)
    assert str(back) == str(err)


def test_the_force_after_a_node_lands_does_not_depend_on_the_output_count():
    """The virtual-work field belongs to a contact set: computed again when a node lands.

    A slender sample (29.9 x 15.1 mm) on Coulomb platens (friction 0.3), alpha 2.7, a mesh
    twice the fitting one's: the side lands on the platen at 27.5 % strain. With the field
    recomputed only at its ten fixed updates, the force after the landing depended on where
    those fell among the outputs: with 63 outputs it swung between -2.4 and 2.9 times the
    curve's (the landing's ringing, whose inertia a field of the former contact set leaves in
    the force), with 127 it did not. Now both agree to 0.5 % (the outputs are at other
    strains: 0.5 % covers the interpolation between them and the ramp's other steps) from the
    next output on; the output at the landing itself can still catch its transient, and is
    left out here.
    """
    material = Ogden(mu_Pa=1.0, alpha=2.6968535077160625, nu=0.499)
    test = CompressionTest(diameter_mm=29.9, height_mm=15.1, strain=0.31, platen="coulomb",
                           friction=0.3)
    mesh = axisymmetric_cylinder(29.9, 15.1, 28, 36, axial_ratio=3.0)
    sparse = simulate(material, test, mesh, n_out=63)
    dense = simulate(material, test, mesh, n_out=127)
    strain = sparse.displacement_mm / 15.1
    after = strain >= 0.2795
    assert after.sum() == 7
    reference = np.interp(sparse.displacement_mm[after], dense.displacement_mm, dense.force_N)
    np.testing.assert_allclose(sparse.force_N[after], reference, rtol=5e-3)
