"""Rig-log loading (calib/loaders.py) and ``calib inspect``.

One synthetic cycle with a known contact point, tare and sign convention is written in every
format the contract (shared/RIG_LOGS.md) names by the small writer below; each must load to the
same numbers as the primary form. Bad files must be rejected with their named reason while the
rest of the campaign loads, and no file content at all may make ``load_campaign`` raise.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from calib import loaders
from calib.cli import main
from calib.loaders import (
    MIN_POINTS,
    STRAIN_REJECT,
    Campaign,
    Cycle,
    CycleRejected,
    load_campaign,
    load_cycle,
)

HEIGHT, DIAMETER = 24.0, 38.0
META = {"layer": "A", "sample": "A1", "test": 2, "rate_mm_per_s": 0.83, "diameter_mm": 38.0,
        "height_mm": 24.0}


# ---------------------------------------------------------------------------- synthetic rig
def ogden_force(x_mm, mu=1875.0, alpha=4.9, bonded=1.3):
    """Compressive force (N) at travel x from contact: homogeneous incompressible one-term Ogden
    uniaxial nominal stress times a constant bonded-platen stiffening factor. Only the curve's
    shape matters here (convex, realistic magnitude), not the exact physics."""
    lam = 1.0 - np.clip(x_mm, 0.0, None) / HEIGHT
    p = 2.0 * mu / alpha * (lam ** (alpha - 1.0) - lam ** (-alpha / 2.0 - 1.0))
    return -p * math.pi * DIAMETER**2 / 4.0 * 1e-6 * bonded


@dataclasses.dataclass
class Truth:
    t: np.ndarray        # s from the start of logging
    d: np.ndarray        # platen travel from the start of logging, compression positive (mm)
    f: np.ndarray        # load cell reading with tare and noise, compression positive (N)
    contact_mm: float
    tare_N: float
    noise_N: float


def make_truth(seed=0, contact_mm=0.8, rate=0.83, hz=50.0, noise=0.003, tare=0.04, strain=0.30,
               hold_s=0.4, mu=1875.0):
    """Approach at constant speed, loading to `strain`, hold, unloading; seeded noise."""
    rng = np.random.default_rng(seed)
    peak = contact_mm + strain * HEIGHT
    t_peak = peak / rate
    t_end = t_peak + hold_s + (peak - 0.5 * contact_mm) / rate
    t = np.arange(0.0, t_end, 1.0 / hz)
    d = np.where(t <= t_peak, rate * t,
                 np.where(t <= t_peak + hold_s, peak, peak - rate * (t - t_peak - hold_s)))
    f = ogden_force(d - contact_mm, mu=mu) + tare + noise * rng.standard_normal(len(t))
    return Truth(t, d, f, contact_mm, tare, noise)


def _fmt(x):
    return f"{x:.12g}"


def write_log(path, truth, *, header=("time_s", "displacement_mm", "force_N"),
              scale=(1.0, 1.0, 1.0), sign=(1, 1), offset_mm=0.0, sep=",", decimal=".",
              meta=META, order=(0, 1, 2), newline="\n", encoding="utf-8", units_row=None,
              comment_header=False):
    """Write `truth` as a rig log. scale converts s/mm/N to the logged unit (e.g. 1e3 for ms),
    sign is the logged convention of (displacement, force), offset_mm is added to the logged
    displacement (absolute platen position)."""
    cols = [truth.t * scale[0],
            (sign[0] * truth.d + offset_mm) * scale[1],
            sign[1] * truth.f * scale[2]]
    lines = []
    if meta:
        lines += [f"# {k}: {v}" for k, v in meta.items()]
    head = sep.join(header[k] for k in order)
    lines.append(("# " + head) if comment_header else head)
    if units_row:
        lines.append(sep.join(units_row[k] for k in order))
    for row in zip(*(cols[k] for k in order), strict=True):
        cells = [_fmt(v) for v in row]
        if decimal == ",":
            cells = [c.replace(".", ",") for c in cells]
        lines.append(sep.join(cells))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_bytes((newline.join(lines) + newline).encode(encoding))
    return Path(path)


@pytest.fixture(scope="module")
def truth():
    return make_truth(seed=1)


@pytest.fixture(scope="module")
def primary(truth, tmp_path_factory):
    path = write_log(tmp_path_factory.mktemp("primary") / "A1_t2_0.83mms.csv", truth)
    return load_cycle(path)


# ---------------------------------------------------------------------------- primary form
def test_primary_form_recovers_truth(primary, truth):
    c = primary
    assert (c.layer, c.sample, c.test, c.rate_mm_per_s) == ("A", "A1", 2, 0.83)
    assert (c.diameter_mm, c.height_mm) == (38.0, 24.0)
    assert c.sign == {"displacement": 1, "force": 1}
    assert c.warnings == ()
    assert c.time_s[0] == 0.0 and c.displacement_mm[0] == 0.0
    assert np.all(np.diff(c.time_s) > 0)
    # contact: bias of the back-extrapolated two-segment fit on this convex curve is ~0.005 mm
    # and its scatter at 3 mN noise a few um (see test_contact_recovery); 0.03 mm is 0.1 % strain
    assert abs(c.contact_mm - truth.contact_mm) < 0.03
    # tare: median of ~48 approach samples of 3 mN noise -> standard error ~0.5 mN; allow 4x
    assert abs(c.tare_N - truth.tare_N) < 2e-3
    assert abs(c.peak_strain - 0.30) < 0.03 / HEIGHT + 1e-9
    # the branch follows the generating curve to within noise (5 sigma) plus the contact error
    model = ogden_force(c.displacement_mm + c.contact_mm - truth.contact_mm)
    assert np.max(np.abs(c.force_N - model)) < 5 * truth.noise_N + 0.03 * 0.5
    # nothing silently dropped: branch (less its interpolated contact point) + trimmed = rows
    assert c.n_points - 1 + sum(s.n_points for s in c.trimmed) == len(truth.t)
    assert [s.kind for s in c.trimmed] == ["approach", "hold", "unloading"]


def test_cycle_is_immutable_and_derived_quantities(primary):
    c = primary
    with pytest.raises(ValueError):
        c.force_N[0] = 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.layer = "B"
    np.testing.assert_allclose(c.strain, c.displacement_mm / 24.0)
    np.testing.assert_allclose(c.area_mm2, math.pi * 38.0**2 / 4.0)
    np.testing.assert_allclose(c.stress_Pa, c.force_N / (c.area_mm2 * 1e-6))
    assert c.peak_strain == pytest.approx(c.displacement_mm.max() / 24.0)


# ---------------------------------------------------------------------------- variants
VARIANTS = {
    "tab_brackets": dict(sep="\t", header=("Time [s]", "Position (mm)", "Load [N]")),
    "semicolon_decimal_comma_ms_m_mN": dict(
        sep=";", decimal=",", header=("Time (ms)", "Displacement (m)", "Force (mN)"),
        scale=(1e3, 1e-3, 1e3)),
    "kN_um_any_order_and_case": dict(
        header=("TIME [S]", "travel (UM)", "force [KN]"), scale=(1.0, 1e3, 1e-3),
        order=(2, 0, 1)),
    "negative_displacement_and_force": dict(sign=(-1, -1)),
    "absolute_position_decreasing": dict(sign=(-1, 1), offset_mm=150.0,
                                         header=("time", "position_mm", "load_N")),
    "extension_slash_units_crlf": dict(header=("Time / s", "Extension / mm", "Force / N"),
                                       newline="\r\n"),
    "utf8_bom": dict(encoding="utf-8-sig"),
    "utf16": dict(encoding="utf-16"),
    "units_row": dict(header=("Time", "Extension", "Load"), units_row=("(s)", "(mm)", "(N)")),
    "commented_header_savetxt": dict(comment_header=True),
    "whitespace_separated": dict(sep=" ", header=("Time [s]", "Position (absolute) [mm]",
                                                  "Force [N]")),
    "micro_sign_unit": dict(header=("t (s)", "Deflection (\u00b5m)", "F (N)"),
                            scale=(1.0, 1e3, 1.0)),
}


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_variant_loads_to_the_same_numbers(variant, truth, primary, tmp_path):
    path = write_log(tmp_path / "A1_t2_0.83mms.csv", truth, **VARIANTS[variant])
    c = load_cycle(path)
    assert (c.layer, c.sample, c.test, c.rate_mm_per_s) == ("A", "A1", 2, 0.83)
    assert c.n_points == primary.n_points
    # 12 significant digits are written and unit factors applied in float64; a 150 mm position
    # offset keeps only ~1e-10 mm of the travel, which moves the fitted contact by ~1e-9 mm, so
    # times and travels from contact agree to 1e-7 (s, mm), far below anything physical
    np.testing.assert_allclose(c.time_s, primary.time_s, rtol=1e-8, atol=1e-7)
    np.testing.assert_allclose(c.displacement_mm, primary.displacement_mm, rtol=1e-8, atol=1e-7)
    np.testing.assert_allclose(c.force_N, primary.force_N, rtol=1e-8, atol=1e-7)
    assert c.contact_mm == pytest.approx(primary.contact_mm, abs=1e-7)
    assert c.tare_N == pytest.approx(primary.tare_N, abs=1e-9)
    sign = VARIANTS[variant].get("sign", (1, 1))
    assert c.sign == {"displacement": sign[0], "force": sign[1]}


def test_units_are_reported_as_logged(truth, tmp_path):
    path = write_log(tmp_path / "A1_t2_0.83mms.csv", truth,
                     **VARIANTS["semicolon_decimal_comma_ms_m_mN"])
    assert load_cycle(path).units == {"time": "ms", "displacement": "m", "force": "mN"}


@pytest.mark.parametrize("name", ["A1_t2_0.83mms.csv", "A1_t2_0p83mms.csv"])
def test_metadata_from_file_name_with_defaults(name, truth, primary, tmp_path):
    c = load_cycle(write_log(tmp_path / name, truth, meta=None))
    assert (c.layer, c.sample, c.test, c.rate_mm_per_s) == ("A", "A1", 2, 0.83)
    assert (c.diameter_mm, c.height_mm) == (38.0, 24.0)
    assert any("diameter_mm not given" in w for w in c.warnings)
    assert any("height_mm not given" in w for w in c.warnings)
    np.testing.assert_allclose(c.force_N, primary.force_N, rtol=1e-8, atol=1e-9)


def test_manifest_wins_over_header_with_a_warning_naming_both(truth, tmp_path):
    write_log(tmp_path / "first.csv", truth, meta={**META, "rate_mm_per_s": 0.17})
    write_log(tmp_path / "second.csv", truth, meta=None)
    (tmp_path / "manifest.csv").write_text(
        "file,layer,sample,test,rate_mm_per_s,diameter_mm,height_mm\n"
        "first.csv,A,A1,2,0.83,38.0,24.0\n"
        "second.csv,B,B3,1,0.83,37.5,24.0\n")
    camp = load_campaign(tmp_path)
    assert camp.rejected == ()
    first, second = camp.cycles
    assert first.rate_mm_per_s == 0.83
    clash = [w for w in first.warnings if w.startswith("rate_mm_per_s")]
    assert len(clash) == 1 and "0.83" in clash[0] and "0.17" in clash[0]
    assert (second.layer, second.sample, second.test, second.diameter_mm) == ("B", "B3", 1, 37.5)
    assert any("manifest.csv" in n for n in camp.notes)


def test_header_wins_over_file_name_with_a_warning(truth, tmp_path):
    c = load_cycle(write_log(tmp_path / "A1_t3_0.83mms.csv", truth))
    assert c.test == 2
    assert any("test" in w and "'2'" in w and "'3'" in w for w in c.warnings)


def test_nested_layer_folders_and_semicolon_manifest(truth, tmp_path):
    for layer in "AB":
        write_log(tmp_path / layer / f"{layer}1_t1_0.83mms.csv", truth, meta=None)
    write_log(tmp_path / "C" / "x.csv", truth, meta=None)
    (tmp_path / "C" / "manifest.csv").write_text(
        "file;layer;sample;test;rate_mm_per_s;diameter_mm;height_mm\n"
        "x.csv;C;C2;3;0,83;38,0;24,0\n")
    camp = load_campaign(tmp_path)
    assert camp.rejected == ()
    assert [c.file for c in camp.cycles] == ["A/A1_t1_0.83mms.csv", "B/B1_t1_0.83mms.csv",
                                             "C/x.csv"]
    assert camp.layers() == ["A", "B", "C"]
    assert camp.cycles[2].sample == "C2" and camp.cycles[2].rate_mm_per_s == 0.83


# ---------------------------------------------------------------------------- inference
@pytest.mark.parametrize("rate,hz", [(0.17, 200.0), (0.83, 100.0), (6.0, 50.0)])
@pytest.mark.parametrize("contact_mm", [0.3, 1.5])
def test_contact_recovery(rate, hz, contact_mm, tmp_path):
    errors = []
    for seed in range(3):
        tr = make_truth(seed=seed, contact_mm=contact_mm, rate=rate, hz=hz, noise=0.004,
                        tare=-0.12, hold_s=0.2)
        c = load_cycle(write_log(tmp_path / f"A1_t1_{seed}.csv", tr,
                                 meta={**META, "rate_mm_per_s": rate}))
        errors.append(c.contact_mm - contact_mm)
        # tare: median of >= 20 approach samples at 4 mN noise; 3 mN is > 3 standard errors
        assert abs(c.tare_N - tr.tare_N) < 3e-3
    # curvature bias <= 0.01 mm on this curve (prototype study); scatter at 6 mm/s, 50 Hz is
    # ~0.12 mm between samples -> a few hundredths; 0.04 mm = 0.17 % strain of a 24 mm sample
    assert np.max(np.abs(errors)) < 0.04, errors


def test_log_starting_in_contact_is_flagged(tmp_path):
    tr = make_truth(seed=3, contact_mm=0.0)
    c = load_cycle(write_log(tmp_path / "A1_t1_0.83mms.csv", tr))
    assert c.contact_mm == 0.0
    assert any("no approach segment" in w for w in c.warnings)
    # the first reading is taken as the tare: it is the true tare plus one noise sample
    assert abs(c.tare_N - tr.tare_N) < 5 * tr.noise_N


def test_time_stamp_repairs_are_reported(truth, primary, tmp_path):
    rng = np.random.default_rng(7)
    n = len(truth.t)
    # exact duplicate rows
    idx = np.sort(np.concatenate([np.arange(n), rng.choice(n, 15, replace=False)]))
    dup = Truth(truth.t[idx], truth.d[idx], truth.f[idx], truth.contact_mm, truth.tare_N,
                truth.noise_N)
    c = load_cycle(write_log(tmp_path / "dup" / "A1_t2_0.83mms.csv", dup))
    assert any("15 exact duplicate rows" in w for w in c.warnings)
    np.testing.assert_allclose(c.force_N, primary.force_N, rtol=1e-8, atol=1e-9)
    # out-of-order rows within jitter: swap 5 pairs of neighbours
    swap = np.arange(n)
    for k in rng.choice(np.arange(10, n - 10, 7), 5, replace=False):
        swap[k], swap[k + 1] = swap[k + 1], swap[k]
    jit = Truth(truth.t[swap], truth.d[swap], truth.f[swap], truth.contact_mm, truth.tare_N,
                truth.noise_N)
    c = load_cycle(write_log(tmp_path / "jit" / "A1_t2_0.83mms.csv", jit))
    assert any("out of order" in w for w in c.warnings)
    np.testing.assert_allclose(c.force_N, primary.force_N, rtol=1e-8, atol=1e-9)
    # repeated time stamps with different readings are averaged
    t_rep = truth.t.copy()
    t_rep[101] = t_rep[100]
    c = load_cycle(write_log(tmp_path / "rep" / "A1_t2_0.83mms.csv",
                             dataclasses.replace(truth, t=t_rep)))
    assert any("repeated time stamps" in w and "averaged" in w for w in c.warnings)
    # a gap of 20 samples inside the loading branch
    keep = np.r_[0:300, 320:n]
    gap = Truth(truth.t[keep], truth.d[keep], truth.f[keep], truth.contact_mm, truth.tare_N,
                truth.noise_N)
    c = load_cycle(write_log(tmp_path / "gap" / "A1_t2_0.83mms.csv", gap))
    assert any("gaps in the time stamps" in w for w in c.warnings)


def test_isolated_glitches_are_dropped_and_listed(truth, primary, tmp_path):
    t, d, f = truth.t.copy(), truth.d.copy(), truth.f.copy()
    t[20] = 0.0            # one corrupt time stamp in the approach
    f[250] += 50.0         # one force spike in the loading branch
    d[500] = 9999.0        # one displacement spike in the unloading
    glitchy = Truth(t, d, f, truth.contact_mm, truth.tare_N, truth.noise_N)
    c = load_cycle(write_log(tmp_path / "A1_t2_0.83mms.csv", glitchy))
    assert any("out of line" in w and "(lines 28)" in w for w in c.warnings), c.warnings
    assert any("2 isolated spikes" in w for w in c.warnings), c.warnings
    # one approach sample fewer barely moves the tare; the contact fit is unchanged to ~1 um
    assert c.contact_mm == pytest.approx(primary.contact_mm, abs=1e-3)
    assert c.n_points == primary.n_points - 1
    assert c.force_N.max() < primary.force_N.max() + 1e-3


def test_sharp_peak_without_hold_is_not_a_spike(tmp_path):
    tr = make_truth(seed=3, rate=6.0, hz=50.0, hold_s=0.0, mu=3000.0)
    c = load_cycle(write_log(tmp_path / "A1_t2_6mms.csv", tr, meta={**META, "rate_mm_per_s": 6}))
    assert not any("spike" in w for w in c.warnings)
    # travel is sampled every 0.12 mm: the sampled peak is within one step of 7.2 mm
    assert c.displacement_mm.max() > 7.2 - 0.12 - 0.04


def test_only_the_first_of_several_loadings_is_used(truth, primary, tmp_path):
    t = np.concatenate([truth.t, truth.t + truth.t[-1] + 0.02])
    multi = Truth(t, np.tile(truth.d, 2), np.concatenate([truth.f, 0.95 * truth.f]),
                  truth.contact_mm, truth.tare_N, truth.noise_N)
    c = load_cycle(write_log(tmp_path / "A1_t2_0.83mms.csv", multi))
    assert any("loads again" in w for w in c.warnings)
    np.testing.assert_allclose(c.force_N, primary.force_N, rtol=1e-8, atol=1e-7)
    assert c.n_points - 1 + sum(s.n_points for s in c.trimmed) == len(t)


# ---------------------------------------------------------------------------- bad input
def _bad_campaign(folder: Path, truth) -> dict[str, str]:
    """Good files plus one file of every bad kind; returns {file: expected reason fragment}."""
    write_log(folder / "A" / "A1_t1_0.83mms.csv", truth, meta=None)
    write_log(folder / "A" / "A2_t1_0.83mms.csv", truth, meta=None)
    write_log(folder / "B1_t1_0.83mms.csv", truth, meta=None)
    expected = {}

    def bad(name, reason, **kw):
        write_log(folder / name, kw.pop("truth", truth), **kw)
        expected[name] = reason

    bad("unit.csv", "unknown unit 'lb' in column 'Force [lb]'",
        header=("time_s", "displacement_mm", "Force [lb]"))
    bad("wrongkind.csv", "is a time unit, not a force unit",
        header=("time_s", "displacement_mm", "force (ms)"))
    short = make_truth(seed=2, hz=50.0)
    keep = np.linspace(0, len(short.t) - 1, MIN_POINTS - 5).astype(int)
    bad("short.csv", f"fewer than {MIN_POINTS} points",
        truth=Truth(short.t[keep], short.d[keep], short.f[keep], 0.8, 0.04, 0.003))
    bad("flat.csv", "no loading branch",
        truth=dataclasses.replace(truth, f=0.04 + 0.003 * np.random.default_rng(5)
                                  .standard_normal(len(truth.t))))
    bad("early.csv", "peak strain", truth=make_truth(seed=4, strain=0.15))
    bad("C9_t1_0.83mms.csv", "missing required column: force",
        header=("time_s", "displacement_mm", "temperature_C"), meta=None)
    bad("mystery.csv", "missing metadata", meta=None)
    backwards = truth.t.copy()
    backwards[200:] -= 2.0
    bad("restart.csv", "non-monotonic time", truth=dataclasses.replace(truth, t=backwards))
    nan_path = folder / "nan.csv"
    text = write_log(nan_path, truth).read_text().splitlines()
    rows = [text[i] if text[i].startswith(("#", "time")) else
            ",".join(text[i].split(",")[:2] + ["nan"]) for i in range(len(text))]
    nan_path.write_text("\n".join(rows) + "\n")
    expected["nan.csv"] = "all-NaN column: force"
    (folder / "binary.csv").write_bytes(bytes(np.random.default_rng(0).integers(0, 256, 400,
                                                                              dtype=np.uint8)))
    expected["binary.csv"] = "binary"
    (folder / "latin.csv").write_bytes(b"time_s,displacement_mm,force_N\n\x81\x8d\x01\x02\n")
    expected["latin.csv"] = "undecodable"
    (folder / "empty.csv").write_bytes(b"")
    expected["empty.csv"] = "empty file"
    (folder / "truth.json").write_text("{}")
    expected["truth.json"] = "not a rig log (.json file)"
    (folder / "B" / "sheet.xlsx").parent.mkdir()
    (folder / "B" / "sheet.xlsx").write_bytes(b"PK\x03\x04")
    expected["B/sheet.xlsx"] = "export the sheet as CSV"
    (folder / "A" / "deeper").mkdir()
    write_log(folder / "A" / "deeper" / "A3_t1_0.83mms.csv", truth)
    expected["A/deeper/"] = "nested deeper than one level"
    (folder / "manifest.csv").write_text("file,layer,sample,test,rate_mm_per_s\n"
                                         "gone.csv,A,A9,1,0.83\n")
    expected["gone.csv"] = "listed in manifest.csv but no such file"
    return expected


def test_every_bad_kind_is_named_and_the_rest_loads(truth, tmp_path):
    expected = _bad_campaign(tmp_path, truth)
    camp = load_campaign(tmp_path)
    assert sorted(c.file for c in camp.cycles) == ["A/A1_t1_0.83mms.csv", "A/A2_t1_0.83mms.csv",
                                                   "B1_t1_0.83mms.csv"]
    reasons = {r.file: r.reason for r in camp.rejected}
    assert sorted(reasons) == sorted(expected)
    for name, fragment in expected.items():
        assert fragment in reasons[name], (name, reasons[name])
    assert f"+-{STRAIN_REJECT}" in reasons["early.csv"]


def test_unexpected_errors_become_rejections(truth, tmp_path, monkeypatch):
    write_log(tmp_path / "A1_t1_0.83mms.csv", truth, meta=None)

    def boom(*args, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(loaders, "_branch", boom)
    camp = load_campaign(tmp_path)
    assert camp.cycles == ()
    assert camp.rejected[0].reason == "unexpected error while loading: RuntimeError: boom"


def test_load_cycle_raises_cycle_rejected_with_reason(tmp_path):
    path = tmp_path / "x.csv"
    path.write_text("time_s,displacement_mm,force_N\n")
    with pytest.raises(CycleRejected) as info:
        load_cycle(path)
    assert info.value.reason and isinstance(info.value, Exception)


def test_missing_folder_raises(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_campaign(tmp_path / "nope")
    (tmp_path / "file.csv").write_text("x")
    with pytest.raises(NotADirectoryError):
        load_campaign(tmp_path / "file.csv")


# ---------------------------------------------------------------------------- fuzzing
_FUZZ = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                 suppress_health_check=[HealthCheck.too_slow])


def _fuzz_load(name: str, content: bytes, good: bytes) -> Campaign:
    with tempfile.TemporaryDirectory() as folder:
        Path(folder, "B1_t1_0.83mms.csv").write_bytes(good)
        Path(folder, name).write_bytes(content)
        camp = load_campaign(folder)
    assert "B1_t1_0.83mms.csv" in [c.file for c in camp.cycles]
    assert len(camp.cycles) + len(camp.rejected) == 2
    for r in camp.rejected:
        assert isinstance(r.reason, str) and r.reason
    json.dumps(camp.report(), allow_nan=True)
    return camp


@pytest.fixture(scope="module")
def small_log(tmp_path_factory):
    """A short but valid log (6 mm/s, 50 Hz) as bytes, to fuzz cheaply."""
    tr = make_truth(seed=11, rate=6.0, hz=50.0, hold_s=0.1)
    path = write_log(tmp_path_factory.mktemp("small") / "s.csv", tr, meta=None)
    return path.read_bytes()


@_FUZZ
@given(content=st.binary(max_size=3000))
def test_fuzzed_bytes_never_raise(small_log, content):
    _fuzz_load("A1_t1_0.83mms.csv", content, small_log)


@_FUZZ
@given(data=st.data())
def test_fuzzed_cells_never_raise(small_log, data):
    lines = small_log.decode().splitlines()
    n_edit = data.draw(st.integers(1, 12))
    cell = st.one_of(st.text(max_size=12), st.sampled_from(
        ["", "nan", "inf", "-inf", "1e400", "0,5", "--", "1;2", '"', "#", "\t", "1e-300"]))
    for _ in range(n_edit):
        i = data.draw(st.integers(0, len(lines) - 1))
        cells = lines[i].split(",")
        j = data.draw(st.integers(0, len(cells) - 1))
        cells[j] = data.draw(cell)
        lines[i] = ",".join(cells)
    content = "\n".join(lines).encode("utf-8", errors="surrogatepass")
    _fuzz_load("A1_t1_0.83mms.csv", content, small_log)


# ---------------------------------------------------------------------------- campaign API
def test_campaign_select_frame_and_report(truth, tmp_path):
    for sample, rate in (("A1", 0.83), ("A2", 0.17), ("B1", 0.83)):
        tr = make_truth(seed=hash(sample) % 100, rate=rate, hz=50.0 if rate > 0.5 else 20.0)
        write_log(tmp_path / f"{sample}_t1_{rate}mms.csv", tr, meta=None)
    camp = load_campaign(tmp_path)
    assert camp.layers() == ["A", "B"]
    assert [c.sample for c in camp.select(layer="A")] == ["A1", "A2"]
    assert [c.sample for c in camp.select(rate=0.8300001)] == ["A1", "B1"]
    assert camp.select(rate=0.9) == []          # 8 % away: outside the 5 % rate tolerance
    assert [c.sample for c in camp.select(layer="A", rate=0.17)] == ["A2"]
    frame = camp.to_frame()
    assert list(frame.columns) == ["layer", "sample", "test", "rate_mm_per_s", "diameter_mm",
                                   "height_mm", "file", "time_s", "displacement_mm", "force_N",
                                   "strain", "stress_Pa"]
    assert len(frame) == sum(c.n_points for c in camp.cycles)
    a2 = frame[frame["sample"] == "A2"]
    np.testing.assert_array_equal(a2["force_N"].to_numpy(), camp.select(sample="A2")[0].force_N)
    report = camp.report()
    assert set(report) == {"cycles", "rejected"}
    assert report["cycles"][0]["file"] == camp.cycles[0].file
    assert isinstance(camp.cycles[0], Cycle)


def test_empty_campaign_frame_has_the_columns(tmp_path):
    frame = load_campaign(tmp_path).to_frame()
    assert len(frame) == 0 and "stress_Pa" in frame.columns


# ---------------------------------------------------------------------------- calib inspect
REQUIRED_KEYS = {"file", "layer", "sample", "test", "rate_mm_per_s", "diameter_mm", "height_mm",
                 "sign", "tare_N", "contact_mm", "peak_strain", "n_points", "warnings"}


def test_inspect_json(truth, tmp_path, capsys):
    expected = _bad_campaign(tmp_path, truth)
    assert main(["inspect", str(tmp_path), "--json"]) == 0
    out = capsys.readouterr().out
    report = json.loads(out)
    assert set(report) == {"cycles", "rejected"}
    assert len(report["cycles"]) == 3
    for cycle in report["cycles"]:
        assert REQUIRED_KEYS <= set(cycle)
        assert set(cycle["sign"]) == {"displacement", "force"}
    assert {r["file"] for r in report["rejected"]} == set(expected)
    nested = next(c for c in report["cycles"] if c["file"] == "A/A1_t1_0.83mms.csv")
    assert nested["layer"] == "A" and nested["test"] == 1


def test_inspect_json_values_match_the_loader(truth, primary, tmp_path, capsys):
    write_log(tmp_path / "A" / "A1_t2_0.83mms.csv", truth, sign=(-1, 1), offset_mm=40.0)
    assert main(["inspect", str(tmp_path), "--json"]) == 0
    (cycle,) = json.loads(capsys.readouterr().out)["cycles"]
    assert cycle["file"] == "A/A1_t2_0.83mms.csv"
    assert cycle["sign"] == {"displacement": -1, "force": 1}
    assert cycle["tare_N"] == pytest.approx(primary.tare_N, abs=1e-9)
    assert cycle["contact_mm"] == pytest.approx(primary.contact_mm, abs=1e-8)
    assert cycle["peak_strain"] == pytest.approx(primary.peak_strain, abs=1e-9)
    assert cycle["n_points"] == primary.n_points


def test_inspect_text_table(truth, tmp_path, capsys):
    _bad_campaign(tmp_path, truth)
    assert main(["inspect", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "A/A1_t1_0.83mms.csv" in out and "Rejected (" in out
    assert "unit.csv: unknown unit 'lb'" in out


def test_inspect_exit_codes(truth, tmp_path, capsys):
    assert main(["inspect", str(tmp_path / "missing"), "--json"]) == 2
    assert capsys.readouterr().out == ""
    (tmp_path / "plain.csv").write_text("x")
    assert main(["inspect", str(tmp_path / "plain.csv")]) == 2
    only_bad = tmp_path / "bad"
    only_bad.mkdir()
    (only_bad / "x.csv").write_bytes(b"\x00\x01")
    assert main(["inspect", str(only_bad), "--json"]) == 2
    captured = capsys.readouterr()
    assert json.loads(captured.out)["rejected"][0]["reason"].startswith("binary")
    assert "no readable cycle" in captured.err


def test_contact_fit_bias_predicts_where_the_loader_finds_contact(tmp_path):
    """The loader's hinge fit on a smooth convex curve finds the contact late by a bias that
    :func:`calib.loaders.contact_fit_bias` predicts from the noise-free curve (what the fit
    uses to read its simulations the same way). Three seeds at 0.5 mN noise: their mean
    error matches the prediction within 1 um (measured: 2.9 um predicted, 3.3, 3.0 and
    3.1 um found; the noise moves a single contact by a few tenths of a um)."""
    predicted = loaders.contact_fit_bias(ogden_force, 0.30 * HEIGHT)
    assert predicted > 2e-3
    errors = []
    for seed in range(3):
        tr = make_truth(seed=seed, contact_mm=0.8, rate=0.83, hz=100.0, noise=5e-4, tare=0.0)
        errors.append(load_cycle(write_log(tmp_path / f"A1_t1_{seed}.csv", tr)).contact_mm
                      - 0.8)
    assert abs(np.mean(errors) - predicted) < 1e-3, (errors, predicted)
    with pytest.raises(ValueError, match="does not rise"):
        loaders.contact_fit_bias(lambda x: np.zeros_like(x), 7.2)


@pytest.mark.parametrize("shape", ["domed", "tilted"])
def test_a_toe_is_compensated_whatever_the_noise(shape, tmp_path):
    """The platen touches at 0.8 mm but meets the full face 0.3 mm of compression later. A
    domed face: the compression of the full face grows as s^2 / 1.2 mm over the first 0.6 mm
    of travel s (a contact area growing linearly with travel), then as s - 0.3 mm. A tilted
    face: as s^2.5 / (2.5 L^1.5) over L = 0.5 mm (a circular segment's area grows as s^1.5),
    then as s - 0.6 L.

    The contact must be the toe-compensated zero, where the hinge fit of the noise-free curve
    puts it (``contact_fit_bias``), at 1 and at 4 mN of noise: within 0.02 mm each (found
    11 um early on the domed face, about one sample at 100 Hz; the untoed curves' tolerance
    above is 0.04 mm with coarser sampling) and within 0.02 mm of each other. The toe is
    trimmed as its own span, nothing is dropped, and a warning says so. Before, the contact
    moved to where the toe rose above five noise levels: on the tilted face, over three rates,
    0.189 mm after the touch at 1 mN, 0.241 at 2 and 0.288 at 4 (now 0.290, 0.290, 0.288).
    """
    touch = 0.8

    def toed(s):
        s = np.clip(s, 0.0, None)
        if shape == "domed":
            return ogden_force(np.where(s < 0.6, s * s / 1.2, s - 0.3))
        return ogden_force(np.where(s < 0.5, s**2.5 / (2.5 * 0.5**1.5), s - 0.3))

    expected = touch + loaders.contact_fit_bias(toed, 0.30 * HEIGHT)
    assert 0.2 < expected - touch < 0.31  # the fit's zero lies in the toe, near its full face
    readings = {}
    for noise in (0.001, 0.004):
        for seed in range(3):
            tr = make_truth(seed=seed, contact_mm=touch, rate=0.83, hz=100.0, noise=noise,
                            tare=0.02)
            tr.f = toed(tr.d - touch) + tr.tare_N + (tr.f - ogden_force(tr.d - touch)
                                                     - tr.tare_N)
            c = load_cycle(write_log(tmp_path / f"A1_t1_{seed}_{noise}.csv", tr))
            readings[noise, seed] = c.contact_mm
            assert abs(c.contact_mm - expected) < 0.02, (noise, seed, c.contact_mm, expected)
            kinds = [s.kind for s in c.trimmed]
            if "toe" in kinds:
                assert kinds == ["approach", "toe", "hold", "unloading"]
                assert any(w.startswith("a toe:") for w in c.warnings), c.warnings
                assert c.force_N[0] > 0.0
            assert c.n_points - 1 + sum(s.n_points for s in c.trimmed) == len(tr.t)
    # at 1 mN the toe rises clear of five noise levels before the zero (on the domed face
    # 20 mN at the zero; at 4 mN it stays within them there): the same reading either way
    assert sum("toe" in [s.kind for s in load_cycle(tmp_path / f"A1_t1_{s}_0.001.csv").trimmed]
               for s in range(3)) == 3
    lo = np.mean([readings[0.001, s] for s in range(3)])
    hi = np.mean([readings[0.004, s] for s in range(3)])
    assert abs(hi - lo) < 0.02, readings
