"""Solves stored with the package (calib.stored): the current solver's, equal to fresh ones."""

import dataclasses
import json
import warnings

import numpy as np
import pytest

from calib.discover import (
    MESH_GEOMETRY_TOLERANCE,
    _grid_keys,
    _lattice_geometry,
    _mesh_keys,
    _mesh_stored,
    make_effect,
)
from calib.fit import CurveKey, FitSettings, ForwardModel
from calib.stored import PATH, StoredSolves, fingerprint, stored_solves

NOMINAL = (38.0, 24.0)


def test_the_stored_solves_are_this_solvers():
    """Made by the solver and forward model of this checkout; if not, run
    ``python -m experiments.stored_solves`` (else every discovery solves them again)."""
    meta, strain, force = StoredSolves.read(PATH)
    assert meta["fingerprint"] == fingerprint()
    assert strain.shape == force.shape and strain.shape[0] == len(meta["keys"]) > 0
    assert np.all(np.diff(strain, axis=1) > 0) and np.all(np.isfinite(force))
    assert len(stored_solves()) == len(meta["keys"])


def test_every_lattice_alpha_of_slip_is_stored_for_the_nominal_sample():
    """Each solve of slip's correction on the fitting and the correction mesh, alphas 1-14."""
    settings = FitSettings()
    forward = ForwardModel.for_settings(settings)
    slip = make_effect("platen_slip")
    for alpha in range(1, 15):
        assert _mesh_stored(forward, settings, slip, float(alpha), NOMINAL), alpha
        # a sample of the same shape, of another size
        assert _mesh_stored(forward, settings, slip, float(alpha), (30.0, 30.0 * 24 / 38)), alpha
        # and the rest of slip's table on the lattice (its other frictions, fitting mesh)
        for key in _grid_keys(settings, slip, float(alpha), NOMINAL).values():
            assert stored_solves().has(key, settings.mesh_scale, forward), (alpha, key)
    assert not _mesh_stored(forward, settings, slip, 15.0, NOMINAL)
    assert not _mesh_stored(forward, settings, slip, 5.0, (38.0, 20.0))
    assert not _mesh_stored(forward, settings, slip, 5.5, NOMINAL)
    # nor for other settings (a finer correction mesh, another nu) or a reader that declines
    assert not _mesh_stored(forward, dataclasses.replace(settings, mesh_correction=3.0), slip,
                            5.0, NOMINAL)
    assert not _mesh_stored(forward, dataclasses.replace(settings, nu=0.49), slip, 5.0, NOMINAL)
    assert not _mesh_stored(ForwardModel(use_stored=False), settings, slip, 5.0, NOMINAL)


@pytest.mark.parametrize("platen, friction, scale", [("coulomb", 0.15, 1.0),
                                                     ("frictionless", 0.0, 2.0),
                                                     ("bonded", 0.0, 2.0)])
def test_a_stored_curve_equals_a_fresh_solve_of_any_size(platen, friction, scale):
    """Scaled to a sample of the stored aspect ratio but another size, a stored curve is the
    fresh solve there: the solver's runs are exactly similar (see calib.stored), to rounding;
    1e-7 of the force is far below the solver's own noise (3e-5 relative per 0.001 in alpha)."""
    d = 31.7
    key = CurveKey(alpha=(6.0,), diameter_mm=d, height_mm=d * NOMINAL[1] / NOMINAL[0],
                   platen=platen, friction=friction)
    stored = ForwardModel()
    fresh = ForwardModel(use_stored=False)
    a = stored.curve(key, scale)
    b = fresh.curve(key, scale)
    assert stored.n_solves == 0 and stored.n_stored == 1 and fresh.n_solves == 1
    travel = np.linspace(0.01, 0.30, 59) * key.height_mm
    np.testing.assert_allclose(a(travel), b(travel), rtol=1e-7)


def test_the_correction_lattice_takes_the_stored_aspect_within_the_tolerance():
    """Within MESH_GEOMETRY_TOLERANCE of the stored aspect ratio the lattice is solved (read) at
    that ratio and the campaign's median diameter; beyond, at the campaign's median."""
    aspect = NOMINAL[0] / NOMINAL[1]
    d = 38.3
    near = (d, d / (aspect * (1 + 0.8 * MESH_GEOMETRY_TOLERANCE)))
    snapped = _lattice_geometry(near)
    assert snapped[0] == d and snapped[0] / snapped[1] == pytest.approx(aspect, rel=1e-12)
    far = (d, d / (aspect * (1 + 1.5 * MESH_GEOMETRY_TOLERANCE)))
    assert _lattice_geometry(far) == far
    assert _lattice_geometry(None) is None


def test_a_store_made_by_another_solver_is_not_used(tmp_path):
    settings = FitSettings()
    forward = ForwardModel.for_settings(settings)
    keys = _mesh_keys(settings, make_effect("platen_slip"), 5.0, NOMINAL)
    from calib.stored import normal_key

    k = normal_key(keys[0.15], 1.0, forward)
    strain = np.linspace(0.0, 0.31, 63)[None]
    path = tmp_path / "s.npz"
    StoredSolves.save(path, [NOMINAL[0] / NOMINAL[1]], [k], strain, strain ** 2)
    assert len(StoredSolves.load(path)) == 1
    with np.load(path) as data:
        meta = json.loads(str(data["meta"]))
    meta["fingerprint"] = "another solver"
    np.savez(path, meta=np.array(json.dumps(meta)), strain=strain, force=strain ** 2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        store = StoredSolves.load(path)
    assert len(store) == 0
    assert any("another version of the solver" in str(w.message) for w in caught)
    assert len(StoredSolves.load(tmp_path / "missing.npz")) == 0
