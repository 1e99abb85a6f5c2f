"""Rungs 6 and 7 of the verification ladder: our explicit solver against FElupe.

FElupe (experiments.felupe_reference) solves the same static problem - same Ogden law and
volumetric term, bonded platens, rollover contact of the bulging side - with Newton's method
on a graded quadratic mixed (u, p, J) mesh. Its own mesh error was measured by the
convergence study in that module (``python -m experiments.felupe_reference --study`` and the
report): on the 16 x 16 mesh graded 32:1 toward the rim it is about 0.1 % at 10 % strain and
0.02 % at 20-30 %, far below the tolerances here; :func:`test_felupe_reference_is_converged`
re-checks that on every run.

Tolerances are those of the verification plan: 1 % at 10-20 % strain and 2 % at 30 % for
the 38 x 24 mm samples; 2 % along the whole curve for the thesis's 100 x 100 mm neo-Hookean
case (whose two codes were 30 % apart). Our curve is interpolated at the travels where
FElupe solved exactly.
"""

import numpy as np
import pytest

pytest.importorskip("felupe")

from experiments import felupe_reference as fr  # noqa: E402
from solver import CompressionTest, NeoHookean, Ogden, simulate  # noqa: E402

pytestmark = pytest.mark.slow

#: FElupe mesh of the reference for the 38 x 24 mm sample (see the module docstring).
REFERENCE_MESH = {"n_radial": 16, "n_axial": 16, "grading": 32.0}
#: Strain -> allowed relative force difference (ours vs FElupe).
TOLERANCE = {0.1: 0.01, 0.2: 0.01, 0.3: 0.02}

CASES = [
    (1875.0, 4.9, 0.49),
    (1875.0, 4.9, 0.499),
    (3100.0, 5.5, 0.49),
    (3100.0, 5.5, 0.499),
]


def _ours_at(result, travel_mm):
    return np.interp(travel_mm, result.displacement_mm, result.force_N)


@pytest.mark.parametrize("mu, alpha, nu", CASES)
def test_bonded_sample_matches_felupe(mu, alpha, nu):
    ref = fr.compression_curve(mu, alpha, nu, **REFERENCE_MESH)
    ours = simulate(Ogden(mu_Pa=mu, alpha=alpha, nu=nu), CompressionTest(platen="bonded"))
    lines, failed = [], []
    for strain, tol in TOLERANCE.items():
        i = int(np.argmin(np.abs(ref["strain"] - strain)))
        assert abs(ref["strain"][i] - strain) < 1e-9  # solved there, not interpolated
        f_ref = ref["force_N"][i]
        f_ours = float(_ours_at(ours, ref["displacement_mm"][i]))
        rel = f_ours / f_ref - 1.0
        lines.append(f"{strain:.0%}: ours {f_ours:.5f} N, FElupe {f_ref:.5f} N, {rel:+.3%}")
        if abs(rel) > tol:
            failed.append(lines[-1] + f" (tolerance {tol:.0%})")
    assert not failed, f"mu={mu} alpha={alpha} nu={nu}: " + "; ".join(failed)


def test_thesis_verification_case_matches_felupe_along_the_curve():
    # du Plessis (2016): neo-Hookean E = 3000 Pa, nu = 0.495, 100 mm x 100 mm, bonded,
    # 30 mm travel. mu = E / (2 (1 + nu)). The mesh keeps the 38 x 24 reference's cells
    # per unit length in r and twice the cells along the twice-as-slender height.
    nu = 0.495
    mu = 3000.0 / (2.0 * (1.0 + nu))
    ref = fr.compression_curve(mu, 2.0, nu, diameter_mm=100.0, height_mm=100.0, strain=0.3,
                               n_radial=16, n_axial=32, grading=32.0, n_increments=10)
    ours = simulate(NeoHookean(mu, nu=nu),
                    CompressionTest(diameter_mm=100.0, height_mm=100.0, strain=0.3,
                                    platen="bonded"))
    keep = ref["strain"] >= 0.03 - 1e-12     # every FElupe level from 3 mm on
    f_ref = ref["force_N"][keep]
    f_ours = _ours_at(ours, ref["displacement_mm"][keep])
    rel = f_ours / f_ref - 1.0
    worst = int(np.argmax(np.abs(rel)))
    assert np.all(np.abs(rel) < 0.02), (
        f"largest difference {rel[worst]:+.3%} at {ref['displacement_mm'][keep][worst]:.1f} mm; "
        f"all: {np.round(100 * rel, 3).tolist()} %"
    )


def test_felupe_reference_is_converged():
    # The reference mesh must be much better than the tolerances above: halving its cells
    # (8 x 8, graded 16:1, the same family) may move the force by at most 0.5 % - the
    # study found ~0.2 % for that step and a further ~4x smaller error on 16 x 16.
    coarse = fr.compression_curve(1875.0, 4.9, 0.499, n_radial=8, n_axial=8, grading=16.0)
    fine = fr.compression_curve(1875.0, 4.9, 0.499, **REFERENCE_MESH)
    np.testing.assert_allclose(coarse["displacement_mm"], fine["displacement_mm"])
    rel = np.abs(coarse["force_N"][1:] / fine["force_N"][1:] - 1.0)
    assert rel.max() < 0.005, rel


def test_ladder_error_table_is_current():
    # experiments.felupe_reference.LADDER records measured mesh errors, which the benchmark
    # uses to pick FElupe's mesh for a stated accuracy. Re-measure one entry against the
    # reference mesh: the change from 6 x 6 to 16 x 16 must be the table's error of 6 x 6
    # minus (at most) that of 16 x 16, to within a factor 1.5 either way (the table is from
    # a Richardson limit; a FElupe or set-up change would move it by much more).
    six = next(lv for lv in fr.LADDER if lv["n_radial"] == 6)
    sixteen = next(lv for lv in fr.LADDER if lv["n_radial"] == 16)
    coarse = fr.compression_curve(1875.0, 4.9, 0.499, n_radial=6, n_axial=6)
    fine = fr.compression_curve(1875.0, 4.9, 0.499, n_radial=16, n_axial=16)
    at = np.isin(np.round(fine["strain"], 9), fr.CHECK_STRAINS)      # 10, 20, 30 %
    change = np.max(np.abs(coarse["force_N"][at] / fine["force_N"][at] - 1.0))
    expected = six["rel_error"] - sixteen["rel_error"]
    assert expected / 1.5 < change < 1.5 * six["rel_error"], (change, expected)


#: FElupe mesh of the Coulomb reference: bilinear cells (its Newton solve of frictional
#: contact failed on quadratic ones), 12 x 12 graded 24:1; 20 increments to 20 % give the
#: force of 60 to 1e-6 in a third of the time.
COULOMB_MESH = {"n_radial": 12, "n_axial": 12, "order": "linear", "n_increments": 20}


def test_coulomb_platens_match_felupe():
    """Coulomb platens (friction 0.15, the slip scenario's) against FElupe's frictional contact.

    FElupe: penalty rigid-plane contact of every boundary node with a Coulomb return mapping
    (elastic stick up to 0.5 % of the smallest face cell); our solver: kinematic stick-slip
    with lumped masses and bulk viscosity on the fitting mesh. FElupe's own mesh error at
    10-20 % is below 0.06 % (8 x 8 against 12 x 12 cells moves it by 0.01 %, checked here;
    24 x 24 by 0.05 %), so the verification plan's 1 % is left almost whole to ours, whose
    measured difference is 0.01 %; a friction of 0.13 or 0.17 instead of 0.15 is 1.4-1.7 %
    off.

    Not asserted, measured: once the bulging side meets the platens (from 22-25 % at this
    friction, between 10 and 15 % at 0.3) the fitting mesh's curve departs from FElupe's by up to
    2.8 % (-2.4 % at 30 %, where FElupe moves by 0.2 % from 8 x 8 to 24 x 24 cells), in a
    pattern that changes with the mesh and with the hourglass stiffness (-1.8, -2.4, -0.06 %
    at 30 % for 0.02, 0.05, 0.15), not with the ramp's speed: a discretisation effect of the
    one-point quads at the fold. That is the README's limit on identifying partial slip.
    """
    ref = fr.compression_curve(1875.0, 4.9, 0.499, strain=0.2, platen="coulomb",
                               friction=0.15, **COULOMB_MESH)
    coarse = fr.compression_curve(1875.0, 4.9, 0.499, strain=0.2, platen="coulomb",
                                  friction=0.15, **{**COULOMB_MESH, "n_radial": 8,
                                                    "n_axial": 8})
    ours = simulate(Ogden(mu_Pa=1875.0, alpha=4.9, nu=0.499),
                    CompressionTest(strain=0.2, platen="coulomb", friction=0.15))
    lines, failed = [], []
    for strain in (0.1, 0.2):
        i = int(np.argmin(np.abs(ref["strain"] - strain)))
        assert abs(ref["strain"][i] - strain) < 1e-9  # solved there, not interpolated
        f_ref = ref["force_N"][i]
        assert coarse["force_N"][i] == pytest.approx(f_ref, rel=5e-4)  # FElupe converged
        f_ours = float(_ours_at(ours, ref["displacement_mm"][i]))
        rel = f_ours / f_ref - 1.0
        lines.append(f"{strain:.0%}: ours {f_ours:.5f} N, FElupe {f_ref:.5f} N, {rel:+.3%}")
        if abs(rel) > TOLERANCE[strain]:
            failed.append(lines[-1] + f" (tolerance {TOLERANCE[strain]:.0%})")
    assert not failed, "; ".join(failed)
