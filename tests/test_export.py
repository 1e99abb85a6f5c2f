"""The per-layer parameter table and its exports (calib.export, `calib export`).

The material cards are checked by evaluating each card's OWN strain-energy formula, with the
numbers parsed back out of the exported text, and comparing energies and (finite-difference)
stresses with the project's :class:`solver.Ogden` built directly from the table values:

- Abaqus ``*HYPERELASTIC, OGDEN``: U = sum 2 mu_i/alpha_i^2 (lb1^a + lb2^a + lb3^a - 3)
  + sum 1/D_i (J - 1)^(2i); with D1 = 2/K this is the project's law exactly.
- FEBio ``Ogden`` (uncoupled): W = sum c_i/m_i^2 (lb1^m + lb2^m + lb3^m - 3) + k/2 (ln J)^2;
  only the isochoric part and the small-strain bulk modulus agree exactly, the pressure
  differs at second order in J - 1.
- Prony series: Abaqus g_R(t) = 1 - sum g_i (1 - exp(-t/tau_i)) relative to the instantaneous
  modulus (MODULI=LONG TERM: the data line holds the long-term moduli); FEBio
  G(t) = g0 + sum g_i exp(-t/t_i) times the elastic (long-term) deviatoric stress.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from calib import cli
from calib.export import (
    FORMATS,
    REQUIRED_COLUMNS,
    ModelSpec,
    ParameterTableError,
    export,
    export_file,
    layer_materials,
    read_parameters,
    validate_parameters,
    write_parameters,
)
from solver import Ogden, Prony

REPO = Path(__file__).resolve().parents[1]

# Du Plessis (2016), Table 1: Ogden parameters of layers A-F (mu in Pa, alpha).
THESIS_TABLE_1 = {"A": (1875.0, 4.9), "B": (1875.0, 6.5), "C": (2165.0, 6.0),
                  "D": (3000.0, 6.0), "E": (3000.0, 5.7), "F": (3100.0, 5.5)}


# ============================================================================ fixtures
def _base_row(rng, layer, mu, alpha, model="ogden"):
    return {
        "layer": layer, "model": model, "mu_Pa": mu, "alpha": alpha, "nu": 0.499,
        "mu_stderr_Pa": float(rng.uniform(0.005, 0.05) * mu),
        "alpha_stderr": float(rng.uniform(0.01, 0.1) * alpha),
        "mu_alpha_correlation": float(rng.uniform(-0.95, 0.95)),
        "rms_N": float(rng.uniform(0.005, 0.05)), "n_cycles": int(rng.integers(3, 10)),
    }


@pytest.fixture
def thesis_table():
    """Table 1 of the thesis with seeded standard errors, correlations and residuals."""
    rng = np.random.default_rng(20160527)
    return pd.DataFrame([_base_row(rng, k, *v) for k, v in THESIS_TABLE_1.items()])


@pytest.fixture
def mixed_table():
    """Every model kind, extras of every sort, a text column and a per-layer density."""
    rng = np.random.default_rng(7)
    rows = [
        _base_row(rng, "A", 1875.0, 4.9),
        {**_base_row(rng, "B", 1200.0, 6.5, "ogden+prony1"), "g1": 0.45, "tau1_s": 0.8},
        {**_base_row(rng, "C", 2165.0, 6.0, "ogden2"), "mu2_Pa": -150.0, "alpha2": -2.5},
        {**_base_row(rng, "D", 2600.0, 5.0, "ogden2+prony2"), "mu2_Pa": 400.0, "alpha2": 1.5,
         "g1": 0.3, "tau1_s": 0.05, "g2": 0.2, "tau2_s": 4.0},
        {**_base_row(rng, "E", 3000.0, 5.7), "friction": 0.35, "offset_mm": -0.12,
         "compliance_mm_per_N": 0.004, "note": "toe region, two cycles trimmed"},
        {**_base_row(rng, "F", 3100.0, 5.5, "ogden+prony1"), "g1": 0.6, "tau1_s": 12.0,
         "density_kg_m3": 1050.0, "softening": 0.07},
    ]
    frame = pd.DataFrame(rows)
    frame.loc[1, ["mu_stderr_Pa", "alpha_stderr", "mu_alpha_correlation"]] = np.nan
    return frame


def reference_material(row) -> Ogden:
    """The project's material built straight from one table row (not via calib.export)."""
    spec = ModelSpec.parse(row["model"])
    mu = [row["mu_Pa"]] + [row[f"mu{i}_Pa"] for i in range(2, spec.n_terms + 1)]
    alpha = [row["alpha"]] + [row[f"alpha{i}"] for i in range(2, spec.n_terms + 1)]
    prony = None
    if spec.n_prony:
        prony = Prony(g=[row[f"g{k}"] for k in range(1, spec.n_prony + 1)],
                      tau_s=[row[f"tau{k}_s"] for k in range(1, spec.n_prony + 1)])
    return Ogden(mu_Pa=mu, alpha=alpha, nu=row["nu"], prony=prony)


def bulk_modulus(mu_total, nu):
    """K = 2 mu (1 + nu) / (3 (1 - 2 nu)), the project's convention, written out here."""
    return 2.0 * mu_total * (1.0 + nu) / (3.0 * (1.0 - 2.0 * nu))


# Principal stretches: uniaxial 30 % compression (incompressible, the repeated lateral stretch
# of the rig), the same with a volume change, equibiaxial, pure shear, simple shear gamma = 0.5
# via its principal stretches, and a general compressible state.
_G = 0.5
STATES = {
    "uniaxial_30": (0.7, 0.7 ** -0.5, 0.7 ** -0.5),
    "uniaxial_30_dilated": (0.7, 1.2, 1.2),
    "equibiaxial": (1.2, 1.2, 1.0 / 1.44),
    "pure_shear": (1.3, 1.0 / 1.3, 1.0),
    "simple_shear": (math.sqrt(1 + _G**2 / 4) + _G / 2, math.sqrt(1 + _G**2 / 4) - _G / 2, 1.0),
    "triaxial": (0.9, 1.05, 1.02),
}


def fd_kirchhoff(energy, stretches, h=1e-6):
    """Principal Kirchhoff stresses tau_a = dW/d(ln lambda_a) by central differences.

    With h = 1e-6 the truncation error is ~h^2/6 W''' (below 1e-6 Pa for these moduli) and the
    round-off ~1e-16 W / h (below 1e-6 Pa); the tolerances below leave a wide margin over both.
    """
    lam = np.asarray(stretches, dtype=float)
    tau = np.empty(3)
    for a in range(3):
        up, down = lam.copy(), lam.copy()
        up[a] *= math.exp(h)
        down[a] *= math.exp(-h)
        tau[a] = (energy(up) - energy(down)) / (2.0 * h)
    return tau


def isochoric(lam):
    lam = np.asarray(lam, dtype=float)
    return lam * np.prod(lam) ** (-1.0 / 3.0)


# ============================================================================ card parsers
def parse_abaqus(text):
    """Materials of an Abaqus input fragment: name -> options, data values, Prony lines."""
    materials, current, keyword, pending = {}, None, None, []
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith("**"):
            pending.append(line)  # a layer's comments precede its *MATERIAL line
            continue
        if line.startswith("*"):
            parts = [p.strip() for p in line[1:].split(",")]
            keyword = parts[0].upper()
            options = {}
            for p in parts[1:]:
                key, _, value = p.partition("=")
                options[key.strip().upper()] = value.strip().upper() if value else True
            if keyword == "MATERIAL":
                current = {"name": options["NAME"], "hyper": None, "visco": None,
                           "data": [], "prony": [], "density": None, "comments": pending,
                           "data_lines": []}
                pending = []
                materials[options["NAME"]] = current
            elif keyword == "HYPERELASTIC":
                current["hyper"] = options
            elif keyword == "VISCOELASTIC":
                current["visco"] = options
            continue
        values = [float(v) for v in line.split(",") if v.strip()]
        if keyword == "HYPERELASTIC":
            current["data"] += values
            current["data_lines"].append(values)
        elif keyword == "VISCOELASTIC":
            current["prony"].append(tuple(values))
        elif keyword == "DENSITY":
            current["density"] = values[0]
    return materials


class AbaqusOgden:
    """Abaqus' own Ogden potential evaluated with the numbers of one card."""

    def __init__(self, card):
        n = int(card["hyper"]["N"])
        data = card["data"]
        assert len(data) == 3 * n, f"N={n} needs {3 * n} values, card has {len(data)}"
        self.mu = np.array(data[0:2 * n:2])
        self.alpha = np.array(data[1:2 * n:2])
        self.D = np.array(data[2 * n:3 * n])
        self.long_term = card["hyper"].get("MODULI") == "LONG TERM"
        self.prony = card["prony"]

    def energy(self, lam):
        lam = np.asarray(lam, dtype=float)
        J = np.prod(lam)
        lb = isochoric(lam)
        U = sum(2 * m / a**2 * (np.sum(lb**a) - 3)
                for m, a in zip(self.mu, self.alpha, strict=True))
        # 1/D_i (J - 1)^(2i); a zero D_i (i >= 2) contributes nothing
        U += sum((J - 1.0) ** (2 * i) / d for i, d in enumerate(self.D, start=1) if d != 0.0)
        return U

    def shear_modulus(self, t):
        """mu(t): the long-term moduli on the data line, g_i relative to the instantaneous."""
        g = np.array([p[0] for p in self.prony])
        tau = np.array([p[2] for p in self.prony])
        mu_long = self.mu.sum()
        if not len(g):
            return np.full_like(np.asarray(t, dtype=float), mu_long)
        assert self.long_term, "a Prony card must say MODULI=LONG TERM"
        mu0 = mu_long / (1.0 - g.sum())
        t = np.asarray(t, dtype=float)[..., None]
        return mu0 * (1.0 - np.sum(g * (1.0 - np.exp(-t / tau)), axis=-1))


def parse_febio(text):
    root = ET.fromstring(text)  # raises on XML that is not well formed
    assert root.tag == "Material"
    return root.findall("material")


def _params(element):
    return {child.tag: float(child.text) for child in element if child.tag != "elastic"}


class FEBioOgden:
    """FEBio's uncoupled Ogden (optionally inside "uncoupled viscoelastic"), from its XML."""

    def __init__(self, element):
        self.type = element.get("type")
        top = _params(element)
        if self.type == "Ogden":
            elastic, self.g0, self.g, self.t, k_wrapper = top, 1.0, [], [], 0.0
        else:
            assert self.type == "uncoupled viscoelastic"
            elastic_el = element.find("elastic")
            assert elastic_el.get("type") == "Ogden"
            elastic = _params(elastic_el)
            self.g0 = top.get("g0", 1.0)  # FEBio's default g0 is 1
            n = sum(1 for key in top if re.fullmatch(r"g[1-9]", key))
            self.g = [top[f"g{i}"] for i in range(1, n + 1)]
            self.t = [top[f"t{i}"] for i in range(1, n + 1)]
            k_wrapper = top.get("k", 0.0)
        n_terms = sum(1 for key in elastic if re.fullmatch(r"c[1-6]", key))
        self.c = np.array([elastic[f"c{i}"] for i in range(1, n_terms + 1)])
        self.m = np.array([elastic[f"m{i}"] for i in range(1, n_terms + 1)])
        self.k = k_wrapper + elastic["k"]  # FEBio adds the wrapper's k to the elastic one's
        self.density = top.get("density")

    def energy(self, lam, long_term=True):
        """W = G sum c_i/m_i^2 (lb^m ... - 3) + k/2 (ln J)^2 with G = g0 (long term)."""
        lam = np.asarray(lam, dtype=float)
        lb = isochoric(lam)
        W = sum(c / m**2 * (np.sum(lb**m) - 3) for c, m in zip(self.c, self.m, strict=True))
        return self.g0 * W + 0.5 * self.k * math.log(np.prod(lam)) ** 2

    def shear_modulus(self, t):
        """Small-strain shear modulus of the relaxation function, sum c_i/2 G(t)."""
        t = np.asarray(t, dtype=float)
        G = np.full_like(t, self.g0)
        for g, tau in zip(self.g, self.t, strict=True):
            G = G + g * np.exp(-t / tau)
        return 0.5 * self.c.sum() * G


def _layers_by_card_order(frame):
    return [row for _, row in validate_parameters(frame).iterrows()]


# ============================================================================ Abaqus
def test_abaqus_card_is_the_project_law_exactly(mixed_table):
    cards = parse_abaqus(export(mixed_table, "abaqus"))
    assert len(cards) == len(mixed_table)
    for row in _layers_by_card_order(mixed_table):
        ref = reference_material(row)
        card = AbaqusOgden(cards[f"LAYER_{row['layer']}"])
        scale = ref.mu0_Pa
        for name, lam in STATES.items():
            # same formula evaluated twice: agreement to round-off (1e-12 of mu)
            assert card.energy(lam) == pytest.approx(float(ref.strain_energy(lam)),
                                                     abs=1e-12 * scale), (row["layer"], name)
            tau_card = fd_kirchhoff(card.energy, lam)
            tau_ref = ref.kirchhoff_stress(lam)
            # FD error < 1e-6 Pa (see fd_kirchhoff); 1e-4 Pa against stresses of 1e2-1e5 Pa
            np.testing.assert_allclose(tau_card, tau_ref, rtol=1e-8, atol=1e-4,
                                       err_msg=f"layer {row['layer']}, {name}")
        assert card.D[0] == pytest.approx(2.0 / bulk_modulus(ref.mu0_Pa, row["nu"]), rel=1e-14)


def test_abaqus_prony_relaxation_matches_project(mixed_table):
    cards = parse_abaqus(export(mixed_table, "abaqus"))
    for row in _layers_by_card_order(mixed_table):
        spec = ModelSpec.parse(row["model"])
        card = cards[f"LAYER_{row['layer']}"]
        ref = reference_material(row)
        if not spec.n_prony:
            assert card["visco"] is None and "MODULI" not in card["hyper"]
            continue
        assert card["hyper"]["MODULI"] == "LONG TERM"
        assert card["visco"] == {"TIME": "PRONY"}
        assert [p[1] for p in card["prony"]] == [0.0] * spec.n_prony  # k_i: no bulk relaxation
        taus = np.array(ref.prony.tau_s)
        times = np.concatenate([[0.0], np.outer(taus, [0.1, 1.0, 10.0]).ravel(), [1e6]])
        # reference: the table's convention, mu(t) = mu0 (1 - sum g (1 - e^-t/tau)),
        # mu_inf = mu_Pa; cross-checked with solver's Prony.relaxation
        g = np.array(ref.prony.g)
        mu0 = ref.mu0_Pa / (1.0 - g.sum())
        expected = mu0 * (1.0 - np.sum(g * (1 - np.exp(-times[:, None] / taus)), axis=1))
        np.testing.assert_allclose(expected, sum(ref.instantaneous_mu_Pa)
                                   * ref.prony.relaxation(times), rtol=1e-12)
        np.testing.assert_allclose(AbaqusOgden(card).shear_modulus(times), expected, rtol=1e-12)
        assert AbaqusOgden(card).shear_modulus(1e9) == pytest.approx(ref.mu0_Pa, rel=1e-12)


def test_abaqus_card_layout(mixed_table):
    text = export(mixed_table, "abaqus")
    cards = parse_abaqus(text)
    rows = {r["layer"]: r for r in _layers_by_card_order(mixed_table)}
    for layer, row in rows.items():
        card = cards[f"LAYER_{layer}"]
        spec = ModelSpec.parse(row["model"])
        assert card["hyper"]["OGDEN"] is True and int(card["hyper"]["N"]) == spec.n_terms
        assert all(len(line) <= 8 for line in card["data_lines"])
        expected_rho = row["density_kg_m3"] if np.isfinite(row.get("density_kg_m3", np.nan)) \
            else 1000.0
        assert card["density"] == expected_rho
    # non-material extras are named in a comment of their layer, never as data
    comments_e = " ".join(cards["LAYER_E"]["comments"])
    for extra in ("friction", "offset_mm", "compliance_mm_per_N", "note"):
        assert extra in comments_e
    assert "softening" in " ".join(cards["LAYER_F"]["comments"])
    assert "SI" in text and "D1 = 2/K" in text


def test_abaqus_data_lines_wrap_at_eight_values():
    rng = np.random.default_rng(3)
    row = {**_base_row(rng, "G", 1000.0, 4.0, "ogden3"), "mu2_Pa": 300.0, "alpha2": 2.0,
           "mu3_Pa": -50.0, "alpha3": -3.0}
    card = parse_abaqus(export(pd.DataFrame([row]), "abaqus", density_kg_m3=1020.0))["LAYER_G"]
    assert [len(v) for v in card["data_lines"]] == [8, 1]  # 3 terms x 2 + 3 D_i = 9 values
    assert card["density"] == 1020.0
    ref = reference_material(pd.Series(row))
    abaqus = AbaqusOgden(card)
    for lam in STATES.values():
        np.testing.assert_allclose(fd_kirchhoff(abaqus.energy, lam), ref.kirchhoff_stress(lam),
                                   rtol=1e-8, atol=1e-4)


# ============================================================================ FEBio
def test_febio_isochoric_part_is_exact(mixed_table):
    elements = parse_febio(export(mixed_table, "febio"))
    rows = _layers_by_card_order(mixed_table)
    assert [e.get("name") for e in elements] == [r["layer"] for r in rows]
    assert [e.get("id") for e in elements] == [str(i) for i in range(1, len(rows) + 1)]
    for row, element in zip(rows, elements, strict=True):
        ref = reference_material(row)
        card = FEBioOgden(element)
        assert card.type == ("uncoupled viscoelastic" if ModelSpec.parse(row["model"]).n_prony
                             else "Ogden")
        for name, lam in STATES.items():
            if abs(np.prod(lam) - 1.0) < 1e-14:  # isochoric states: the energies are equal
                assert card.energy(lam) == pytest.approx(float(ref.strain_energy(lam)),
                                                         abs=1e-12 * ref.mu0_Pa), name
            # every state: the deviatoric Kirchhoff stresses are equal
            tau_card = fd_kirchhoff(card.energy, lam)
            tau_ref = ref.kirchhoff_stress(lam)
            np.testing.assert_allclose(tau_card - tau_card.mean(), tau_ref - tau_ref.mean(),
                                       rtol=1e-8, atol=1e-4,
                                       err_msg=f"layer {row['layer']}, {name}")


def test_febio_bulk_modulus_exact_and_volumetric_difference_second_order(mixed_table):
    for row, element in zip(_layers_by_card_order(mixed_table),
                            parse_febio(export(mixed_table, "febio")), strict=True):
        ref = reference_material(row)
        card = FEBioOgden(element)
        K = bulk_modulus(ref.mu0_Pa, row["nu"])
        assert card.k == pytest.approx(K, rel=1e-14)

        def pressure(energy, J):  # Kirchhoff pressure of a pure dilatation, by FD
            return fd_kirchhoff(energy, np.full(3, J ** (1.0 / 3.0))).mean()

        # small-strain bulk modulus d(J p)/dJ at J = 1 (FD step 1e-5: error ~1e-10 K)
        eps = 1e-5
        for energy in (card.energy, ref.strain_energy):
            slope = (pressure(energy, 1 + eps) - pressure(energy, 1 - eps)) / (2 * eps)
            assert slope == pytest.approx(K, rel=1e-6)
        # the volumetric stresses differ at second order: log-log slope 2
        strains = np.array([2e-2, 1e-2, 5e-3, 2.5e-3])
        diff = [abs(pressure(card.energy, 1 + e) - pressure(ref.strain_energy, 1 + e))
                for e in strains]
        order = np.polyfit(np.log(strains), np.log(diff), 1)[0]
        assert order == pytest.approx(2.0, abs=0.05)


def test_febio_prony_conversion_matches_relaxation_function(mixed_table):
    for row, element in zip(_layers_by_card_order(mixed_table),
                            parse_febio(export(mixed_table, "febio")), strict=True):
        ref = reference_material(row)
        card = FEBioOgden(element)
        if ref.prony is None:
            assert card.g == []
            continue
        assert element.find("k").text.strip() in ("0", "0.0")  # wrapper: no extra bulk
        assert card.g0 == 1.0
        times = np.concatenate([[0.0], np.outer(ref.prony.tau_s, [0.1, 1.0, 10.0]).ravel()])
        g = np.array(ref.prony.g)
        mu0 = ref.mu0_Pa / (1.0 - g.sum())
        expected = mu0 * (1.0 - np.sum(g * (1 - np.exp(-times[:, None]
                                                       / np.array(ref.prony.tau_s))), axis=1))
        np.testing.assert_allclose(card.shear_modulus(times), expected, rtol=1e-12)
        assert card.shear_modulus(1e9) == pytest.approx(ref.mu0_Pa, rel=1e-12)
        np.testing.assert_allclose(card.t, ref.prony.tau_s, rtol=0)


def test_febio_density_names_and_ignored_extras(mixed_table):
    text = export(mixed_table, "febio", density_kg_m3=980.0)
    elements = {e.get("name"): e for e in parse_febio(text)}
    assert float(elements["A"].find("density").text) == 980.0
    assert float(elements["F"].find("density").text) == 1050.0  # from the density column
    assert "friction = 0.35" in text and "softening" in text
    assert "c_i = 2 mu_i" in text and "SI" in text
    for element in elements.values():
        assert element.find("friction") is None


def test_special_layer_names_are_escaped():
    rng = np.random.default_rng(11)
    frame = pd.DataFrame([_base_row(rng, "top & <1>", 1000.0, 5.0),
                          _base_row(rng, "bottom--2_x", 1500.0, 4.0)])
    names = [e.get("name") for e in parse_febio(export(frame, "febio"))]
    assert names == ["top & <1>", "bottom--2_x"]
    cards = parse_abaqus(export(frame, "abaqus"))
    assert all(re.fullmatch(r"[A-Z0-9_-]+", name) for name in cards)
    latex = export(frame, "latex")
    assert r"top \& <1>" in latex and r"bottom--2\_x" in latex


def test_abaqus_names_that_collide_are_rejected():
    rng = np.random.default_rng(12)
    frame = pd.DataFrame([_base_row(rng, "a", 1000.0, 5.0), _base_row(rng, "A", 1500.0, 4.0)])
    with pytest.raises(ParameterTableError, match="case-insensitive"):
        export(frame, "abaqus")


# ============================================================================ round trips
def test_csv_round_trip(tmp_path, mixed_table):
    path = write_parameters(mixed_table, tmp_path / "parameters.csv")
    first = read_parameters(path)
    again = tmp_path / "again.csv"
    again.write_text(export(first, "csv"), encoding="utf-8")
    second = read_parameters(again)
    pd.testing.assert_frame_equal(first, second, check_exact=True)
    # the values read back are the values written (floats written in round-trip form)
    for col in ("mu_Pa", "alpha", "g1", "tau2_s", "friction", "mu_stderr_Pa"):
        np.testing.assert_array_equal(first[col].to_numpy(),
                                      mixed_table[col].to_numpy(dtype=float))
    assert list(first["note"]) == ["", "", "", "", "toe region, two cycles trimmed", ""]


def test_json_round_trip(tmp_path, mixed_table):
    first = validate_parameters(mixed_table)
    document = json.loads(export(first, "json"))
    assert document["units"]["mu_Pa"] == "Pa" and document["units"]["tau1_s"] == "s"
    assert "2 mu_i / alpha_i^2" in document["convention"]["strain_energy"]
    assert len(document["parameters"]) == len(mixed_table)
    assert document["parameters"][1]["mu_stderr_Pa"] is None  # NaN -> null
    path = tmp_path / "parameters.json"
    export_file(first, path)
    second = read_parameters(path)
    pd.testing.assert_frame_equal(first, second, check_exact=True)


def test_column_order_is_stable(tmp_path, mixed_table):
    shuffled = mixed_table[list(np.random.default_rng(5).permutation(mixed_table.columns))]
    columns = list(read_parameters(write_parameters(shuffled, tmp_path / "p.csv")).columns)
    assert columns[:len(REQUIRED_COLUMNS)] == list(REQUIRED_COLUMNS)
    material = ["mu2_Pa", "alpha2", "g1", "tau1_s", "g2", "tau2_s"]
    assert columns[len(REQUIRED_COLUMNS):len(REQUIRED_COLUMNS) + len(material)] == material
    others = [c for c in shuffled.columns if c not in REQUIRED_COLUMNS and c not in material]
    assert columns[len(REQUIRED_COLUMNS) + len(material):] == others


def test_write_parameters_writes_nothing_for_an_invalid_table(tmp_path, thesis_table):
    path = tmp_path / "parameters.csv"
    write_parameters(thesis_table, path)
    before = path.read_bytes()
    bad = thesis_table.copy()
    bad.loc[2, "nu"] = 0.7
    with pytest.raises(ParameterTableError, match="layer 'C'"):
        write_parameters(bad, path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["parameters.csv"]  # no temporary left


def test_layer_materials_follow_the_table(mixed_table):
    materials = layer_materials(mixed_table)
    for row in _layers_by_card_order(mixed_table):
        ref = reference_material(row)
        got = materials[row["layer"]]
        assert got.mu_Pa == ref.mu_Pa and got.alpha == ref.alpha and got.prony == ref.prony
    assert materials["F"].density_kg_m3 == 1050.0 and materials["A"].density_kg_m3 == 1000.0


# ============================================================================ readable tables
def _parse_value(cell):
    """'1875 ± 40' -> (1875.0, 40.0); '6.5 ± n/a' -> (6.5, nan)."""
    value, _, err = cell.partition("±")
    return float(value), (math.nan if err.strip() in ("", "n/a") else float(err))


def _check_displayed(row, cells):
    """Displayed numbers agree with the table to the precision they are shown at."""
    assert cells[0] == row["layer"] and cells[1] == row["model"]
    for cell, col, se_col in ((cells[2], "mu_Pa", "mu_stderr_Pa"),
                              (cells[3], "alpha", "alpha_stderr")):
        v, s = _parse_value(cell)
        if np.isfinite(row[se_col]):
            # the error shown to 2 significant digits, the value to the same decimal:
            # each rounding is at most half a unit of the 2nd digit of the error, < 5 % of it
            assert abs(v - row[col]) <= 0.05 * row[se_col] and abs(s - row[se_col]) <= \
                0.05 * row[se_col]
        else:
            assert math.isnan(s) and v == pytest.approx(row[col], rel=5e-4)  # 4 digits
    assert float(cells[4]) == pytest.approx(row["nu"], rel=5e-4)
    r = row["mu_alpha_correlation"]
    assert (cells[5] == "n/a") if np.isnan(r) else abs(float(cells[5]) - r) <= 5e-4
    assert float(cells[6]) == pytest.approx(row["rms_N"], rel=5e-3)  # 3 significant digits
    assert int(cells[7]) == row["n_cycles"]


def _markdown_rows(text):
    lines = [line for line in text.splitlines() if line.startswith("|")]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    body = [[c.strip() for c in line.strip("|").split("|")] for line in lines[2:]]
    return header, body


def test_markdown_contains_every_layer_and_value(mixed_table):
    clean = validate_parameters(mixed_table)
    header, body = _markdown_rows(export(mixed_table, "markdown"))
    assert len(body) == len(clean)
    extras = list(clean.columns[len(REQUIRED_COLUMNS):])
    assert header[8:] == extras
    for (_, row), cells in zip(clean.iterrows(), body, strict=True):
        assert len(cells) == len(header)
        _check_displayed(row, cells)
        for col, cell in zip(extras, cells[8:], strict=True):
            value = row[col]
            if isinstance(value, str):
                assert cell == value
            elif np.isnan(value):
                assert cell == ""
            else:
                assert float(cell) == pytest.approx(value, rel=5e-4)


def _latex_cell(cell):
    cell = cell.replace(r"$\pm$", "±")
    match = re.fullmatch(r"\$(-?[\d.]+)\\times10\^\{(-?\d+)\}\$", cell)
    if match:
        return str(float(match.group(1)) * 10 ** int(match.group(2)))
    return cell.replace(r"\_", "_").replace(r"\&", "&")


def test_latex_is_booktabs_with_every_layer_and_value(mixed_table):
    clean = validate_parameters(mixed_table)
    text = export(mixed_table, "latex")
    for command in (r"\toprule", r"\midrule", r"\bottomrule", r"\begin{tabular}"):
        assert text.count(command) == 1
    n_columns = len(re.search(r"\\begin\{tabular\}\{([lr]+)\}", text).group(1))
    body = text.split(r"\midrule")[1].split(r"\bottomrule")[0].strip().splitlines()
    header = text.split(r"\toprule")[1].split(r"\midrule")[0].strip()
    assert "mu2\\_Pa" in header and "compliance\\_mm\\_per\\_N" in header
    assert len(body) == len(clean)
    for (_, row), line in zip(clean.iterrows(), body, strict=True):
        cells = [_latex_cell(c.strip()) for c in line.strip().removesuffix(r"\\").split(" & ")]
        assert len(cells) == n_columns
        _check_displayed(row, cells)
    # underscores outside math mode are escaped
    outside_math = re.sub(r"\$[^$]*\$", "", text.split(r"\begin{tabular}")[1])
    assert re.search(r"(?<!\\)_", outside_math) is None


@pytest.mark.parametrize("value, stderr, shown", [
    (1875.3, 40.2, "1875 ± 40"),      # the brief's style: error to 2 significant digits
    (1875.33, 4.27, "1875.3 ± 4.3"),
    (4.9, 0.15, "4.90 ± 0.15"),
    (1875.0, 1234.0, "1900 ± 1200"),  # value rounded to the error's second digit
    (1875.0, np.nan, "1875 ± n/a"),
])
def test_value_with_error_rule(value, stderr, shown):
    rng = np.random.default_rng(1)
    row = {**_base_row(rng, "A", value, 5.0), "mu_stderr_Pa": stderr}
    _, body = _markdown_rows(export(pd.DataFrame([row]), "markdown"))
    assert body[0][2] == shown


# ============================================================================ bad tables
def _write(tmp_path, frame, name="parameters.csv"):
    path = tmp_path / name
    frame.to_csv(path, index=False)
    return path


def _mutate(frame, **changes):
    frame = frame.copy()
    for key, value in changes.items():
        col, layer = key.rsplit("__", 1)
        frame[col] = frame[col].astype(object)  # any value may be set, as in a hand-edited CSV
        frame.loc[frame["layer"] == layer, col] = value
    return frame


@pytest.mark.parametrize("change, expected", [
    ({"mu_Pa__B": -5.0}, ["layer 'B'", "mu_Pa", "positive"]),
    ({"nu__C": 0.5}, ["layer 'C'", "nu", "(-1, 0.5)"]),
    ({"alpha__D": "abc"}, ["layer 'D'", "alpha", "not a number"]),
    ({"rms_N__E": np.nan}, ["layer 'E'", "rms_N", "empty"]),
    ({"mu_Pa__A": np.inf}, ["layer 'A'", "mu_Pa", "not finite"]),
    ({"alpha__A": 0.0}, ["layer 'A'", "alpha", "zero"]),
    ({"model__F": "mooney"}, ["layer 'F'", "model", "unknown model"]),
    ({"model__F": "ogden+prony0"}, ["layer 'F'", "prony0"]),
    ({"n_cycles__B": 2.5}, ["layer 'B'", "n_cycles", "whole number"]),
    ({"mu_alpha_correlation__C": 1.5}, ["layer 'C'", "correlation"]),
    ({"alpha_stderr__D": -0.1}, ["layer 'D'", "alpha_stderr", "negative"]),
    ({"model__A": "ogden+prony1"}, ["layer 'A'", "needs column g1"]),
    ({"model__A": "ogden2"}, ["layer 'A'", "mu2_Pa"]),
])
def test_bad_values_are_named(tmp_path, thesis_table, change, expected):
    path = _write(tmp_path, _mutate(thesis_table, **change))
    with pytest.raises(ParameterTableError) as info:
        read_parameters(path)
    message = str(info.value)
    assert str(path) in message
    for part in expected:
        assert part in message


@pytest.mark.parametrize("change, expected", [
    ({"g1__B": 0.0, "tau1_s__B": -1.0}, ["layer 'B'", "tau1_s", "positive"]),
    ({"g1__D": 0.7, "g2__D": 0.4}, ["layer 'D'", "sum of g_k"]),
    ({"g1__A": 0.2}, ["layer 'A'", "g1", "no such parameter"]),
    ({"mu2_Pa__C": 150.0}, ["layer 'C'", "same sign"]),
])
def test_bad_material_extras_are_named(tmp_path, mixed_table, change, expected):
    path = _write(tmp_path, _mutate(mixed_table, **change))
    with pytest.raises(ParameterTableError) as info:
        read_parameters(path)
    for part in expected:
        assert part in str(info.value)


def test_unidentifiable_errors_are_allowed(tmp_path, thesis_table):
    frame = thesis_table.copy()
    frame.loc[:, ["mu_stderr_Pa", "alpha_stderr", "mu_alpha_correlation"]] = np.nan
    table = read_parameters(_write(tmp_path, frame))
    assert table[["mu_stderr_Pa", "alpha_stderr", "mu_alpha_correlation"]].isna().all().all()


def test_every_problem_is_reported_at_once(tmp_path, thesis_table):
    path = _write(tmp_path, _mutate(thesis_table, nu__A=0.6, mu_Pa__F="x"))
    with pytest.raises(ParameterTableError) as info:
        read_parameters(path)
    assert len(info.value.problems) == 2
    assert "layer 'A'" in str(info.value) and "layer 'F'" in str(info.value)


def test_duplicate_layers_and_missing_columns(tmp_path, thesis_table):
    dup = thesis_table.copy()
    dup.loc[3, "layer"] = "B"
    with pytest.raises(ParameterTableError, match=r"layer 'B' appears twice \(rows 2 and 4\)"):
        read_parameters(_write(tmp_path, dup, "dup.csv"))
    with pytest.raises(ParameterTableError, match=r"missing required column\(s\) \['alpha'\]"):
        read_parameters(_write(tmp_path, thesis_table.drop(columns="alpha"), "missing.csv"))


@pytest.mark.parametrize("content, expected", [
    (b"", "empty file"),
    (b"layer,model,mu_Pa,alpha,nu,mu_stderr_Pa,alpha_stderr,mu_alpha_correlation,rms_N,"
     b"n_cycles\n", "no rows"),
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "binary"),
    (b"layer,model,mu_Pa,alpha,nu,mu_stderr_Pa,alpha_stderr,mu_alpha_correlation,rms_N,"
     b"n_cycles\nA,ogden,1875,4.9,0.499,,,,0.01\n", "line 2 has 9 fields"),
    (b"layer,layer,model\nA,A,ogden\n", "duplicate column"),
    (b"layer,model\n\xff\xfeA,ogden\n", "not UTF-8"),
])
def test_unreadable_files(tmp_path, content, expected):
    path = tmp_path / "parameters.csv"
    path.write_bytes(content)
    with pytest.raises(ParameterTableError, match=re.escape(expected)) as info:
        read_parameters(path)
    assert str(path) in str(info.value)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(ParameterTableError, match="no such file"):
        read_parameters(tmp_path / "nope.csv")
    with pytest.raises(ParameterTableError, match="directory, not a parameter table$"):
        read_parameters(tmp_path)
    (tmp_path / "parameters.csv").write_text("layer\n", encoding="utf-8")
    with pytest.raises(ParameterTableError, match="give its parameters.csv"):
        read_parameters(tmp_path)


def test_layer_called_na_is_a_name(tmp_path, thesis_table):
    frame = thesis_table.copy()
    frame.loc[0, "layer"] = "NA"
    assert read_parameters(_write(tmp_path, frame))["layer"].iloc[0] == "NA"


def test_unknown_format_is_rejected(thesis_table):
    with pytest.raises(ValueError, match="unknown export format"):
        export(thesis_table, "ansys")


# ============================================================================ CLI
@pytest.fixture
def table_file(tmp_path, mixed_table):
    return write_parameters(mixed_table, tmp_path / "parameters.csv")


@pytest.mark.parametrize("fmt", FORMATS)
def test_cli_prints_each_format(table_file, capsys, fmt):
    assert cli.main(["export", str(table_file), "--format", fmt]) == 0
    out, _ = capsys.readouterr()
    assert out == export(read_parameters(table_file), fmt)


def test_cli_json_is_one_object_and_out_is_written(table_file, tmp_path, capsys):
    out_file = tmp_path / "cards" / "layers.inp"
    assert cli.main(["export", str(table_file), "--out", str(out_file), "--json"]) == 0
    out, err = capsys.readouterr()
    report = json.loads(out)  # exactly one JSON document on stdout
    assert report["format"] == "abaqus" and report["out"] == str(out_file)
    assert report["layers"] == ["A", "B", "C", "D", "E", "F"]
    assert out_file.read_text() == export(read_parameters(table_file), "abaqus")
    assert "wrote 6 layer(s)" in err
    assert cli.main(["export", str(table_file), "--format", "markdown", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["content"].startswith("| layer | model |")


@pytest.mark.parametrize("args, expected", [
    (["--format", "csv"], "no such file"),
    (["--out", "x.docx"], "suffix"),
    (["--format", "abaqus", "--density", "0"], "--density"),
    ([], "give --format"),
])
def test_cli_usage_errors_exit_2(table_file, capsys, args, expected):
    source = table_file.with_name("nope.csv") if "no such" in expected else table_file
    assert cli.main(["export", str(source)] + args) == 2
    _, err = capsys.readouterr()
    assert expected in err


def test_cli_invalid_table_exit_2_names_the_problem(tmp_path, thesis_table, capsys):
    path = _write(tmp_path, _mutate(thesis_table, nu__E=0.51))
    assert cli.main(["export", str(path), "--format", "febio"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "layer 'E'" in err and str(path) in err


def test_cli_unwritable_output_exit_1(table_file, tmp_path, capsys):
    target = tmp_path / "a_directory"
    target.mkdir()
    assert cli.main(["export", str(table_file), "--format", "csv", "--out", str(target)]) == 1
    assert "cannot write" in capsys.readouterr().err


def test_python_m_calib_export(table_file):
    result = subprocess.run([sys.executable, "-m", "calib", "export", str(table_file),
                             "--format", "json"], capture_output=True, text=True, cwd=REPO,
                            timeout=300)
    assert result.returncode == 0, result.stderr
    assert len(json.loads(result.stdout)["parameters"]) == 6
