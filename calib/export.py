r"""The per-layer parameter table (``parameters.csv``) and its exports.

The calibration writes one row per layer; this module reads and validates that table, writes it
atomically, and renders it as ``csv``, ``json``, ``markdown``, ``latex``, ``abaqus`` material
cards or ``febio`` material XML.

The table
---------
Required columns, in this order (``shared/CLI.md``)::

    layer, model, mu_Pa, alpha, nu, mu_stderr_Pa, alpha_stderr, mu_alpha_correlation,
    rms_N, n_cycles

then one column per extra parameter. ``mu_stderr_Pa``, ``alpha_stderr`` and
``mu_alpha_correlation`` may be empty (NaN) where a parameter was not identifiable; every other
required value must be finite. ``layer`` names are unique; ``n_cycles`` is a non-negative
integer.

``model`` strings
-----------------
``ogden``
    One term: ``mu_Pa``, ``alpha``.
``ogden<N>`` (``ogden2`` ... ``ogden6``)
    N terms: ``mu_Pa``, ``alpha`` are term 1, plus ``mu2_Pa``, ``alpha2``, ... ``mu<N>_Pa``,
    ``alpha<N>``. The small-strain shear modulus is ``mu_Pa + mu2_Pa + ...``.
``+prony<k>`` suffix (``ogden+prony1``, ``ogden2+prony2``, k <= 6)
    A Prony series of the isochoric stress with columns ``g1, tau1_s, ..., g<k>, tau<k>_s``.
    Then every ``mu`` is the LONG-TERM (relaxed) modulus and ``g_k`` are normalised by the
    INSTANTANEOUS modulus (Abaqus convention):

    .. math::

        \mu(t) = \mu_0 \Big(1 - \sum_k g_k (1 - e^{-t/\tau_k})\Big), \qquad
        \mu_\infty = \mu_0 \Big(1 - \sum_k g_k\Big).

A material column that the row's model does not use (``mu2_Pa`` on an ``ogden`` row of a mixed
table) must be empty. An optional ``density_kg_m3`` column sets the density written into the
material cards. Every other column (``friction``, ``offset_mm``, ``compliance_mm_per_N``,
``softening``, ...) is carried through csv / json / markdown / latex unchanged; the material
cards leave such test-setup parameters out and list them in a comment.

Convention
----------
The project's only Ogden convention (Abaqus; Miller & Chinzei 2002; FElupe's ``ogden``):

.. math::

    W = \sum_i \frac{2\mu_i}{\alpha_i^2}
        (\bar\lambda_1^{\alpha_i} + \bar\lambda_2^{\alpha_i} + \bar\lambda_3^{\alpha_i} - 3)
        + \frac{K}{2} (J - 1)^2, \qquad
    K = \frac{2\mu(1+\nu)}{3(1-2\nu)}, \quad \mu = \sum_i \mu_i \ \text{(long-term)}.

Other conventions exist only inside the card writers below:

- Abaqus ``*HYPERELASTIC, OGDEN``: the same :math:`\mu_i, \alpha_i`;
  :math:`U_{vol} = \sum_i (J-1)^{2i} / D_i` with :math:`D_1 = 2/K` and :math:`D_{i \ge 2} = 0`
  (no higher-order volumetric terms), so the card is the project's law exactly.
  ``MODULI=LONG TERM`` and ``*VISCOELASTIC, TIME=PRONY`` lines ``g_i, k_i, tau_i`` with
  :math:`k_i = 0` (the bulk response does not relax, as in :mod:`solver`).
- FEBio ``Ogden`` (uncoupled): :math:`W = \sum_i c_i/m_i^2 (\bar\lambda_1^{m_i} + \dots - 3)
  + U(J)`, so :math:`c_i = 2\mu_i`, :math:`m_i = \alpha_i`; :math:`U(J) = \tfrac{k}{2}(\ln J)^2`
  with :math:`k = K`: the isochoric response and the small-strain bulk modulus agree exactly,
  the pressures differ at second order in :math:`J - 1`. A Prony series becomes FEBio's
  ``uncoupled viscoelastic`` material, whose deviatoric stress is the elastic one times
  :math:`G(t) = g_0 + \sum_i g_i e^{-t/t_i}`; with the elastic Ogden as the long-term
  response, :math:`g_0 = 1`, :math:`g_i = g_i^{Abaqus} / (1 - \sum_k g_k^{Abaqus})`,
  :math:`t_i = \tau_i`.

References
----------
Miller K, Chinzei K (2002). Mechanical properties of brain tissue in tension. J Biomech
35:483-490. doi:10.1016/S0021-9290(01)00234-2

Abaqus Keywords Reference, ``*HYPERELASTIC`` (OGDEN, N, MODULI) and ``*VISCOELASTIC``
(TIME=PRONY); data-line order mu1, alpha1, mu2, alpha2, ..., D1, D2, ..., at most 8 per line.

FEBio User's Manual, "Ogden" (uncoupled materials) and "Uncoupled Viscoelastic"; FEBio source
``FEBioMech/FEUncoupledMaterial.h`` (``UJ = k ln(J)/J``, i.e. ``U = k/2 (ln J)^2``),
``FEOgdenMaterial.cpp`` (deviatoric Kirchhoff stress ``c/m (lb^m - mean)``) and
``FEUncoupledViscoElasticMaterial.cpp`` (``S = g0 Se + sum g_i H_i``; the wrapper's ``k`` is
added to the elastic material's ``k``).

Examples
--------
>>> import pandas as pd
>>> table = pd.DataFrame({"layer": ["A"], "model": ["ogden"], "mu_Pa": [1875.0],
...                       "alpha": [4.9], "nu": [0.499], "mu_stderr_Pa": [40.0],
...                       "alpha_stderr": [0.15], "mu_alpha_correlation": [-0.8],
...                       "rms_N": [0.012], "n_cycles": [9]})
>>> print(export(table, "markdown").splitlines()[2])
| A | ogden | 1875 ± 40 | 4.90 ± 0.15 | 0.499 | -0.800 | 0.012 | 9 |
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import os
import re
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = [
    "DEFAULT_DENSITY_KG_M3",
    "FORMATS",
    "ModelSpec",
    "ParameterTableError",
    "REQUIRED_COLUMNS",
    "export",
    "export_file",
    "format_for_path",
    "layer_materials",
    "read_parameters",
    "validate_parameters",
    "write_parameters",
]

REQUIRED_COLUMNS = (
    "layer", "model", "mu_Pa", "alpha", "nu", "mu_stderr_Pa", "alpha_stderr",
    "mu_alpha_correlation", "rms_N", "n_cycles",
)
FORMATS = ("csv", "json", "markdown", "latex", "abaqus", "febio")
DEFAULT_DENSITY_KG_M3 = 1000.0
MAX_OGDEN_TERMS = 6  # FEBio's Ogden takes c1..c6, m1..m6
MAX_PRONY_TERMS = 6  # FEBio's viscoelastic wrappers take g1..g6, t1..t6

_NULLABLE = ("mu_stderr_Pa", "alpha_stderr", "mu_alpha_correlation")
_FINITE = ("mu_Pa", "alpha", "nu", "rms_N")
_MATERIAL_COLUMN = re.compile(r"^(mu(\d+)_Pa|alpha(\d+)|g(\d+)|tau(\d+)_s)$")
_MODEL = re.compile(r"^ogden(\d*)(?:\+prony(\d+))?$")
_FORMAT_OF_SUFFIX = {".csv": "csv", ".json": "json", ".md": "markdown", ".markdown": "markdown",
                     ".tex": "latex", ".inp": "abaqus", ".feb": "febio", ".xml": "febio"}

_CONVENTION = (
    "W = sum_i 2 mu_i / alpha_i^2 (lb1^alpha_i + lb2^alpha_i + lb3^alpha_i - 3) "
    "+ K/2 (J - 1)^2, lb_a = J^(-1/3) lambda_a, K = 2 mu (1 + nu) / (3 (1 - 2 nu)), "
    "mu = sum_i mu_i (small-strain shear modulus; long-term where a Prony series is fitted)"
)
_PRONY_CONVENTION = (
    "mu(t) = mu0 (1 - sum_k g_k (1 - exp(-t/tau_k))), mu_inf = mu0 (1 - sum_k g_k) = mu_Pa "
    "(g_k normalised by the instantaneous modulus mu0, as in Abaqus); the bulk response is elastic"
)


class ParameterTableError(ValueError):
    """A parameter table that cannot be used; the message names file, layer and column.

    Attributes
    ----------
    problems : list of str
        Every problem found, one per entry.
    """

    def __init__(self, source: str, problems: list[str]):
        self.source = source
        self.problems = list(problems)
        if len(self.problems) == 1:
            message = f"{source}: {self.problems[0]}"
        else:
            message = f"{source}: {len(self.problems)} problems:\n" + "\n".join(
                f"  - {p}" for p in self.problems)
        super().__init__(message)


# ============================================================================ model strings
@dataclasses.dataclass(frozen=True)
class ModelSpec:
    """A parsed ``model`` string: the number of Ogden terms and of Prony terms.

    Parameters
    ----------
    n_terms : int
        Ogden terms, 1 to 6.
    n_prony : int
        Prony terms, 0 (hyperelastic) to 6.

    Examples
    --------
    >>> ModelSpec.parse(" Ogden2+PRONY1 ")
    ModelSpec(n_terms=2, n_prony=1)
    >>> ModelSpec(2, 1).name, ModelSpec(2, 1).material_columns
    ('ogden2+prony1', ('mu2_Pa', 'alpha2', 'g1', 'tau1_s'))
    """

    n_terms: int = 1
    n_prony: int = 0

    def __post_init__(self):
        if not 1 <= self.n_terms <= MAX_OGDEN_TERMS:
            raise ValueError(f"{self.n_terms} Ogden terms: 1 to {MAX_OGDEN_TERMS} are supported")
        if not 0 <= self.n_prony <= MAX_PRONY_TERMS:
            raise ValueError(f"{self.n_prony} Prony terms: 0 to {MAX_PRONY_TERMS} are supported")

    @classmethod
    def parse(cls, text) -> ModelSpec:
        """Parse ``ogden`` or ``ogden<N>``, optionally ``+prony<k>``; case and spaces ignored."""
        cleaned = re.sub(r"\s+", "", str(text)).lower()
        match = _MODEL.match(cleaned)
        if match is None:
            raise ValueError(
                f"unknown model {str(text)!r}: expected 'ogden' or 'ogden<N>' (N <= "
                f"{MAX_OGDEN_TERMS} terms), optionally with '+prony<k>' (k <= {MAX_PRONY_TERMS})")
        n_terms = int(match.group(1)) if match.group(1) else 1
        n_prony = int(match.group(2)) if match.group(2) is not None else 0
        if match.group(2) is not None and n_prony == 0:
            raise ValueError(f"model {str(text)!r}: '+prony0' has no Prony term; write the model "
                             "without the suffix")
        return cls(n_terms, n_prony)

    @property
    def name(self) -> str:
        """The canonical model string."""
        base = "ogden" if self.n_terms == 1 else f"ogden{self.n_terms}"
        return base + (f"+prony{self.n_prony}" if self.n_prony else "")

    @property
    def material_columns(self) -> tuple[str, ...]:
        """Columns this model needs beyond the required ones."""
        cols = []
        for i in range(2, self.n_terms + 1):
            cols += [f"mu{i}_Pa", f"alpha{i}"]
        for k in range(1, self.n_prony + 1):
            cols += [f"g{k}", f"tau{k}_s"]
        return tuple(cols)

    def term_columns(self) -> list[tuple[str, str]]:
        """``(mu column, alpha column)`` of each Ogden term."""
        return [("mu_Pa", "alpha")] + [(f"mu{i}_Pa", f"alpha{i}")
                                       for i in range(2, self.n_terms + 1)]

    def prony_columns(self) -> list[tuple[str, str]]:
        """``(g column, tau column)`` of each Prony term."""
        return [(f"g{k}", f"tau{k}_s") for k in range(1, self.n_prony + 1)]


# ============================================================================ validation
def _is_blank(value) -> bool:
    if value is None:
        return True
    if isinstance(value, str):
        return value.strip() == "" or value.strip().lower() in ("nan", "na", "n/a", "null")
    try:
        return bool(pd.isna(value))
    except (TypeError, ValueError):
        return False


def _to_float(value) -> float:
    """Convert a cell to float; blank cells are NaN; ValueError on text that is no number."""
    if _is_blank(value):
        return math.nan
    if isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{value!r} is a boolean, not a number")
    if isinstance(value, str):
        return float(value.strip())
    return float(value)


def _column_order(columns: list[str]) -> list[str]:
    """Order columns: required, material extras in canonical order, the rest as given."""
    material = [c for c in columns if c not in REQUIRED_COLUMNS and _MATERIAL_COLUMN.match(c)]

    def key(col):
        m = _MATERIAL_COLUMN.match(col)
        if m.group(2) or m.group(3):  # Ogden term
            return (0, int(m.group(2) or m.group(3)), 0 if col.startswith("mu") else 1)
        return (1, int(m.group(4) or m.group(5)), 0 if col.startswith("g") else 1)

    material.sort(key=key)
    rest = [c for c in columns if c not in REQUIRED_COLUMNS and c not in material]
    return list(REQUIRED_COLUMNS) + material + rest


def validate_parameters(frame: pd.DataFrame, source: str = "parameter table") -> pd.DataFrame:
    """Check a parameter table and return a clean copy in the stable column order.

    Parameters
    ----------
    frame : pandas.DataFrame
        One row per layer with the required columns (cells may be text, as read from CSV).
    source : str
        What the table is called in error messages (usually its file name).

    Returns
    -------
    pandas.DataFrame
        ``layer`` and ``model`` (canonical) as text, numbers as float64, ``n_cycles`` as
        int64, extras that are all numeric as float64 and other extras as text; columns in the
        order required, material extras, other extras.

    Raises
    ------
    ParameterTableError
        Listing every problem with the layer (and row) and column concerned.
    """
    if not isinstance(frame, pd.DataFrame):
        raise ParameterTableError(
            source, [f"expected a pandas DataFrame, got {type(frame).__name__}"])
    columns = [str(c).strip() for c in frame.columns]
    duplicated = sorted({c for c in columns if columns.count(c) > 1})
    if duplicated:
        raise ParameterTableError(source, [f"duplicate column name(s) {duplicated}"])
    if any(c == "" for c in columns):
        raise ParameterTableError(source, ["a column has an empty name"])
    missing = [c for c in REQUIRED_COLUMNS if c not in columns]
    if missing:
        raise ParameterTableError(source, [
            f"missing required column(s) {missing}; the table has {columns}; required: "
            f"{list(REQUIRED_COLUMNS)}"])
    frame = frame.copy()
    frame.columns = columns
    if len(frame) == 0:
        raise ParameterTableError(source, ["the table has no rows (no layers)"])

    problems: list[str] = []
    cells = {c: list(frame[c]) for c in columns}
    n = len(frame)

    # -- layer names
    layers = []
    for i, value in enumerate(cells["layer"]):
        # a layer may be called "NA"; only a missing or whitespace-only cell is empty
        if value is None or (isinstance(value, str) and not value.strip()) or (
                not isinstance(value, str) and _is_blank(value)):
            problems.append(f"row {i + 1}, column layer: empty layer name")
            layers.append(f"<row {i + 1}>")
        else:
            layers.append(str(value).strip())
    seen: dict[str, int] = {}
    for i, name in enumerate(layers):
        if name in seen:
            problems.append(f"layer {name!r} appears twice (rows {seen[name] + 1} and {i + 1}); "
                            "layer names must be unique")
        else:
            seen[name] = i

    def where(i, col):
        return f"layer {layers[i]!r} (row {i + 1}), column {col}"

    # -- model strings
    specs: list[ModelSpec | None] = []
    for i, value in enumerate(cells["model"]):
        try:
            specs.append(ModelSpec.parse("" if _is_blank(value) else value))
        except ValueError as exc:
            problems.append(f"{where(i, 'model')}: {exc}")
            specs.append(None)

    # -- numbers
    numeric: dict[str, list[float]] = {}

    def parse_column(col, allow_blank):
        out = []
        for i, value in enumerate(cells[col]):
            try:
                x = _to_float(value)
            except (TypeError, ValueError):
                problems.append(f"{where(i, col)}: {value!r} is not a number")
                out.append(math.nan)
                continue
            if math.isnan(x) and not allow_blank:
                problems.append(f"{where(i, col)}: empty; a finite value is required")
            elif not math.isfinite(x) and not math.isnan(x):
                problems.append(f"{where(i, col)}: {value!r} is not finite")
            out.append(x)
        numeric[col] = out

    for col in _FINITE:
        parse_column(col, allow_blank=False)
    for col in _NULLABLE:
        parse_column(col, allow_blank=True)
    parse_column("n_cycles", allow_blank=False)
    material_extras = [c for c in columns if c not in REQUIRED_COLUMNS
                       and _MATERIAL_COLUMN.match(c)]
    for col in material_extras:
        parse_column(col, allow_blank=True)
    if "density_kg_m3" in columns:
        parse_column("density_kg_m3", allow_blank=True)

    # -- per-row physics
    for i in range(n):
        nu = numeric["nu"][i]
        if math.isfinite(nu) and not -1.0 < nu < 0.5:
            problems.append(f"{where(i, 'nu')}: Poisson's ratio {nu} must lie in (-1, 0.5)")
        for col in ("mu_stderr_Pa", "alpha_stderr"):
            x = numeric[col][i]
            if math.isfinite(x) and x < 0.0:
                problems.append(f"{where(i, col)}: a standard error cannot be negative ({x})")
        r = numeric["mu_alpha_correlation"][i]
        if math.isfinite(r) and not -1.0 <= r <= 1.0:
            problems.append(f"{where(i, 'mu_alpha_correlation')}: correlation {r} outside [-1, 1]")
        rms = numeric["rms_N"][i]
        if math.isfinite(rms) and rms < 0.0:
            problems.append(f"{where(i, 'rms_N')}: an RMS residual cannot be negative ({rms})")
        nc = numeric["n_cycles"][i]
        if math.isfinite(nc) and (nc < 0 or nc != int(nc)):
            problems.append(f"{where(i, 'n_cycles')}: {cells['n_cycles'][i]!r} is not a "
                            "non-negative whole number")
        if "density_kg_m3" in numeric:
            rho = numeric["density_kg_m3"][i]
            if math.isfinite(rho) and rho <= 0.0:
                problems.append(f"{where(i, 'density_kg_m3')}: density {rho} must be positive")

        spec = specs[i]
        if spec is None:
            continue
        needed = set(spec.material_columns)
        for col in spec.material_columns:
            if col not in columns:
                problems.append(f"{where(i, col)}: model {spec.name!r} needs column {col}, "
                                "which the table lacks")
            elif math.isnan(numeric[col][i]):
                problems.append(f"{where(i, col)}: empty; model {spec.name!r} needs a finite value")
        for col in material_extras:
            if col not in needed and not math.isnan(numeric[col][i]):
                problems.append(
                    f"{where(i, col)}: model {spec.name!r} has no such parameter but the cell "
                    f"holds {cells[col][i]!r}; leave it empty or change the model")
        if any(c not in columns for c in spec.material_columns):
            continue
        mus = [numeric[m][i] for m, _ in spec.term_columns()]
        alphas = [numeric[a][i] for _, a in spec.term_columns()]
        if all(math.isfinite(v) for v in mus + alphas):
            for (mcol, acol), m, a in zip(spec.term_columns(), mus, alphas, strict=True):
                if a == 0.0:
                    problems.append(f"{where(i, acol)}: an Ogden exponent cannot be zero")
                elif m * a <= 0.0:
                    problems.append(
                        f"{where(i, mcol)}: {mcol}={m} and {acol}={a} must have the same sign "
                        "(mu_i alpha_i > 0, stability of the small-strain response)")
            if spec.n_terms == 1 and mus[0] <= 0.0:
                problems.append(f"{where(i, 'mu_Pa')}: shear modulus {mus[0]} must be positive")
            elif sum(mus) <= 0.0:
                problems.append(f"{where(i, 'mu_Pa')}: the shear modulus sum of mu_i = {sum(mus)}"
                                " must be positive")
        if spec.n_prony:
            gs = [numeric[g][i] for g, _ in spec.prony_columns()]
            for (gcol, tcol), g in zip(spec.prony_columns(), gs, strict=True):
                t = numeric[tcol][i]
                if math.isfinite(g) and not 0.0 <= g < 1.0:
                    problems.append(f"{where(i, gcol)}: relative modulus {g} must lie in [0, 1)")
                if math.isfinite(t) and t <= 0.0:
                    problems.append(f"{where(i, tcol)}: relaxation time {t} s must be positive")
            if all(math.isfinite(g) for g in gs) and sum(gs) >= 1.0:
                problems.append(f"{where(i, 'g1')}: sum of g_k = {sum(gs)} must be below 1 "
                                "(the long-term modulus would vanish)")

    if problems:
        raise ParameterTableError(source, problems)

    # -- assemble the clean frame
    out: dict[str, object] = {
        "layer": pd.Series(layers, dtype=object),
        "model": pd.Series([s.name for s in specs], dtype=object),
    }
    for col in _FINITE + _NULLABLE:
        out[col] = np.asarray(numeric[col], dtype=np.float64)
    out["n_cycles"] = np.asarray(numeric["n_cycles"], dtype=np.int64)
    for col in columns:
        if col in out:
            continue
        if col in numeric:
            out[col] = np.asarray(numeric[col], dtype=np.float64)
            continue
        try:
            out[col] = np.asarray([_to_float(v) for v in cells[col]], dtype=np.float64)
        except (TypeError, ValueError):  # a text column (a note, a file name): kept as text
            out[col] = pd.Series(["" if _is_blank(v) else str(v) for v in cells[col]],
                                 dtype=object)
    clean = pd.DataFrame(out)[_column_order(columns)]
    clean.attrs["source"] = source
    return clean


# ============================================================================ reading
def _read_csv_cells(path: Path) -> tuple[list[str], list[list[str]]]:
    source = str(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise ParameterTableError(source, ["no such file"]) from None
    except IsADirectoryError:
        hint = "; give its parameters.csv" if (path / "parameters.csv").is_file() else ""
        raise ParameterTableError(source, [f"is a directory, not a parameter table{hint}"]) \
            from None
    except OSError as exc:
        raise ParameterTableError(source, [f"cannot be read ({exc.strerror or exc})"]) from None
    if b"\x00" in raw:
        raise ParameterTableError(source, ["binary content (NUL bytes): not a CSV text file"])
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ParameterTableError(source, [f"not UTF-8 text (byte {exc.start})"]) from None
    try:
        rows = list(csv.reader(io.StringIO(text)))
    except csv.Error as exc:
        raise ParameterTableError(source, [f"not readable as CSV ({exc})"]) from None
    numbered = [(k + 1, r) for k, r in enumerate(rows) if any(cell.strip() for cell in r)]
    if not numbered:
        raise ParameterTableError(source, ["empty file: no header row"])
    (_, header), body = numbered[0], numbered[1:]
    header = [h.strip() for h in header]
    problems = []
    for line, row in body:
        if len(row) != len(header):
            problems.append(f"line {line} has {len(row)} fields but the header has {len(header)}")
    if problems:
        raise ParameterTableError(source, problems)
    return header, [[cell.strip() for cell in row] for _, row in body]


def _read_json_records(path: Path) -> pd.DataFrame:
    source = str(path)
    try:
        document = json.loads(path.read_text(encoding="utf-8-sig"))
    except FileNotFoundError:
        raise ParameterTableError(source, ["no such file"]) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ParameterTableError(source, [f"not readable as JSON ({exc})"]) from None
    records = document.get("parameters") if isinstance(document, dict) else document
    if not isinstance(records, list) or not all(isinstance(r, dict) for r in records):
        raise ParameterTableError(source, [
            "expected an object with a 'parameters' list of records (as written by "
            "`calib export --format json`) or a bare list of records"])
    columns: list[str] = []
    for record in records:
        columns += [k for k in record if k not in columns]
    return pd.DataFrame([[r.get(c) for c in columns] for r in records], columns=columns,
                        dtype=object)


def read_parameters(path: str | os.PathLike) -> pd.DataFrame:
    """Read and validate a per-layer parameter table.

    Parameters
    ----------
    path : str or path-like
        ``parameters.csv`` (UTF-8, comma-separated, one header row), or a ``.json`` file as
        written by :func:`export` with ``fmt="json"``.

    Returns
    -------
    pandas.DataFrame
        The validated table (see :func:`validate_parameters`); ``frame.attrs["source"]`` is
        the path.

    Raises
    ------
    ParameterTableError
        If the file is missing, unreadable or invalid; the message names the file, the layer
        (and row) and the column of every problem.
    """
    path = Path(path)
    if path.suffix.lower() == ".json":
        frame = _read_json_records(path)
    else:
        header, rows = _read_csv_cells(path)
        if len(set(header)) != len(header):
            duplicated = sorted({h for h in header if header.count(h) > 1})
            raise ParameterTableError(str(path), [f"duplicate column name(s) {duplicated}"])
        frame = pd.DataFrame(rows, columns=header, dtype=object)
    return validate_parameters(frame, source=str(path))


# ============================================================================ writing
def _csv_cell(value) -> str:
    if isinstance(value, (float, np.floating)):
        return "" if math.isnan(value) else repr(float(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return "" if _is_blank(value) else str(value)


def _to_csv(frame: pd.DataFrame) -> str:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(list(frame.columns))
    for row in frame.itertuples(index=False, name=None):
        writer.writerow([_csv_cell(v) for v in row])
    return buffer.getvalue()


def write_parameters(frame: pd.DataFrame, path: str | os.PathLike) -> Path:
    """Validate ``frame`` and write it as ``parameters.csv``, atomically.

    Columns are written in the stable order: the required columns, the material extras
    (``mu2_Pa, alpha2, ..., g1, tau1_s, ...``), then other extras as given. Floats are written
    with the shortest representation that reads back to the same number; NaN as an empty cell.

    Parameters
    ----------
    frame : pandas.DataFrame
        One row per layer (see the module docstring).
    path : str or path-like
        Target file.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    ParameterTableError
        If the table is invalid; nothing is written then.
    """
    from ._io import write_text

    clean = validate_parameters(frame, source=f"parameter table for {os.fspath(path)}")
    return write_text(path, _to_csv(clean))


# ============================================================================ materials
def _layer_density(frame: pd.DataFrame, i: int, default: float) -> float:
    if "density_kg_m3" in frame.columns:
        rho = float(frame["density_kg_m3"].iloc[i])
        if math.isfinite(rho):
            return rho
    return default


def layer_materials(frame: pd.DataFrame, density_kg_m3: float = DEFAULT_DENSITY_KG_M3) -> dict:
    """Build the :class:`solver.Ogden` material of each layer.

    Parameters
    ----------
    frame : pandas.DataFrame
        A parameter table (validated here).
    density_kg_m3 : float
        Density (kg/m^3) for layers without a ``density_kg_m3`` value.

    Returns
    -------
    dict of str to solver.Ogden
        Keyed by layer, in table order; moduli long-term where a Prony series is fitted.
    """
    from solver import Ogden, Prony

    clean = validate_parameters(frame, source=frame.attrs.get("source", "parameter table"))
    materials = {}
    for i, row in enumerate(clean.to_dict("records")):
        spec = ModelSpec.parse(row["model"])
        prony = None
        if spec.n_prony:
            prony = Prony(g=tuple(row[g] for g, _ in spec.prony_columns()),
                          tau_s=tuple(row[t] for _, t in spec.prony_columns()))
        materials[row["layer"]] = Ogden(
            mu_Pa=tuple(row[m] for m, _ in spec.term_columns()),
            alpha=tuple(row[a] for _, a in spec.term_columns()),
            nu=row["nu"], prony=prony,
            density_kg_m3=_layer_density(clean, i, density_kg_m3))
    return materials


def _non_material(clean: pd.DataFrame, row: dict) -> list[str]:
    """``name = value`` of the non-material extras of one row (for card comments)."""
    out = []
    for col in clean.columns[len(REQUIRED_COLUMNS):]:
        if _MATERIAL_COLUMN.match(col) or col == "density_kg_m3":
            continue
        value = row[col]
        if _is_blank(value):
            continue
        out.append(f"{col} = {_plain(value, 6) if isinstance(value, float) else value}")
    return out


# ============================================================================ number formats
def _plain(x: float, sig: int = 4) -> str:
    """``x`` to ``sig`` significant digits, trailing zeros dropped; 'n/a' for NaN."""
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    x = float(x)
    if math.isnan(x):
        return "n/a"
    if x == 0.0:
        return "0"
    exponent = math.floor(math.log10(abs(x)))
    if -4 <= exponent < 7:
        decimals = max(sig - 1 - exponent, 0)
        text = f"{x:.{decimals}f}"
        if "." in text:
            text = text.rstrip("0").rstrip(".")
        return text
    mantissa, exp = f"{x:.{sig - 1}e}".split("e")
    if "." in mantissa:
        mantissa = mantissa.rstrip("0").rstrip(".")
    return f"{mantissa}e{int(exp)}"


def _fixed(x: float, decimals: int) -> str:
    return f"{x:.{decimals}f}"


def _with_error(value: float, stderr: float) -> tuple[str, str | None]:
    """``value`` and its standard error rounded to the error's two significant digits."""
    if not math.isfinite(stderr) or stderr <= 0.0:
        return _plain(value, 4), (None if not math.isfinite(stderr) else "0")
    e = math.floor(math.log10(stderr))
    if abs(value) >= 1e7 or stderr < 1e-4:
        return f"{value:.3g}", f"{stderr:.2g}"
    decimals = 1 - e
    v = round(value, decimals)
    s = round(stderr, decimals)
    d = max(decimals, 0)
    return _fixed(v, d), _fixed(s, d)


# ============================================================================ text tables
def _display_columns(clean: pd.DataFrame) -> list[str]:
    return list(clean.columns[len(REQUIRED_COLUMNS):])


def _table_cells(clean: pd.DataFrame, pm: str, na: str) -> list[list[str]]:
    """Body cells of the readable table; ``pm`` joins value and error, ``na`` marks no error."""
    rows = []
    for row in clean.to_dict("records"):
        cells = [row["layer"], row["model"]]
        for value, stderr in ((row["mu_Pa"], row["mu_stderr_Pa"]),
                              (row["alpha"], row["alpha_stderr"])):
            v, s = _with_error(value, stderr)
            cells.append(f"{v}{pm}{s if s is not None else na}")
        cells.append(_plain(row["nu"], 4))
        r = row["mu_alpha_correlation"]
        cells.append(na if math.isnan(r) else f"{r:.3f}")
        cells.append(_plain(row["rms_N"], 3))
        cells.append(str(int(row["n_cycles"])))
        for col in _display_columns(clean):
            value = row[col]
            if isinstance(value, (float, np.floating)):
                cells.append("" if math.isnan(value) else _plain(value, 4))
            else:
                cells.append(str(value))
        rows.append(cells)
    return rows


def _notes(clean: pd.DataFrame) -> list[str]:
    specs = {ModelSpec.parse(m) for m in clean["model"]}
    notes = [f"Convention: {_CONVENTION}.",
             "Values are given as estimate ± one standard error; n/a: not identifiable; "
             "corr(μ, α): correlation of the two estimates; RMS: force residual of the fit."]
    if any(s.n_terms > 1 for s in specs):
        notes.append("ogden<N> rows: μ, α are term 1; mu2_Pa, alpha2, ... the further terms; "
                     "small-strain shear modulus μ + mu2_Pa + ...")
    if any(s.n_prony for s in specs):
        notes.append(f"+prony<k> rows: μ is the long-term modulus; {_PRONY_CONVENTION}.")
    return notes


def _markdown(clean: pd.DataFrame) -> str:
    header = ["layer", "model", "μ (Pa)", "α", "ν", "corr(μ, α)", "RMS (N)", "cycles"]
    header += _display_columns(clean)

    def esc(text):
        return str(text).replace("\\", "\\\\").replace("|", "\\|").replace("\n", " ")

    align = ["---", "---"] + ["--:"] * (len(header) - 2)
    lines = ["| " + " | ".join(esc(h) for h in header) + " |", "|" + "|".join(align) + "|"]
    for cells in _table_cells(clean, " ± ", "n/a"):
        lines.append("| " + " | ".join(esc(c) for c in cells) + " |")
    lines.append("")
    lines += _notes(clean)
    return "\n".join(lines) + "\n"


_LATEX_SPECIAL = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#",
                  "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}",
                  "^": r"\textasciicircum{}"}


def _latex_escape(text) -> str:
    return "".join(_LATEX_SPECIAL.get(ch, ch) for ch in str(text))


def _latex_number(text: str) -> str:
    r"""Escape a formatted number; scientific notation becomes ``$m\times10^{e}$``."""
    match = re.fullmatch(r"(-?[\d.]+)e([+-]?\d+)", text)
    if match:
        return f"${match.group(1)}\\times10^{{{int(match.group(2))}}}$"
    return _latex_escape(text)


def _latex(clean: pd.DataFrame) -> str:
    extras = _display_columns(clean)
    header = ["Layer", "Model", r"$\mu$ (Pa)", r"$\alpha$", r"$\nu$",
              r"$\rho_{\mu\alpha}$", "RMS (N)", "Cycles"] + [_latex_escape(c) for c in extras]
    numeric_extra = [clean[c].dtype.kind == "f" for c in extras]
    spec = "ll" + "r" * 6 + "".join("r" if f else "l" for f in numeric_extra)
    body = []
    for cells in _table_cells(clean, " ± ", "n/a"):
        out = [_latex_escape(cells[0]), _latex_escape(cells[1])]
        for cell in cells[2:4]:
            value, err = cell.split(" ± ")
            out.append(f"{_latex_number(value)} $\\pm$ {_latex_number(err)}")
        out += [_latex_number(c) for c in cells[4:8]]
        out += [_latex_number(c) if f else _latex_escape(c)
                for c, f in zip(cells[8:], numeric_extra, strict=True)]
        body.append("    " + " & ".join(out) + r" \\")
    caption = ("Ogden parameters per layer: estimate $\\pm$ one standard error (n/a: not "
               "identifiable). $W = \\sum_i \\frac{2\\mu_i}{\\alpha_i^2}"
               "(\\bar\\lambda_1^{\\alpha_i}"
               " + \\bar\\lambda_2^{\\alpha_i} + \\bar\\lambda_3^{\\alpha_i} - 3) + \\frac{K}{2}"
               "(J-1)^2$, $K = 2\\mu(1+\\nu)/(3(1-2\\nu))$; $\\mu$ is the small-strain shear "
               "modulus")
    specs = {ModelSpec.parse(m) for m in clean["model"]}
    if any(s.n_terms > 1 for s in specs):
        caption += " (term 1 of ogden$N$ rows, whose further terms are mu2\\_Pa, alpha2, ...)"
    if any(s.n_prony for s in specs):
        caption += (", long-term where a Prony series is fitted, with $g_k$ normalised by the "
                    "instantaneous modulus, "
                    "$\\mu(t) = \\mu_0(1 - \\sum_k g_k(1 - e^{-t/\\tau_k}))$")
    caption += r"; $\rho_{\mu\alpha}$: correlation of the estimates; RMS: force residual."
    lines = [
        "% Ogden parameters per layer, exported by `calib export`; needs \\usepackage{booktabs}",
        r"\begin{table}[htbp]",
        r"  \centering",
        f"  \\caption{{{caption}}}",
        r"  \label{tab:ogden-parameters}",
        f"  \\begin{{tabular}}{{{spec}}}",
        r"    \toprule",
        "    " + " & ".join(header) + r" \\",
        r"    \midrule",
        *body,
        r"    \bottomrule",
        r"  \end{tabular}",
        r"\end{table}",
    ]
    return "\n".join(lines) + "\n"


# ============================================================================ json
def _unit(column: str) -> str | None:
    fixed = {"layer": None, "model": None, "mu_Pa": "Pa", "alpha": "1", "nu": "1",
             "mu_stderr_Pa": "Pa", "alpha_stderr": "1", "mu_alpha_correlation": "1",
             "rms_N": "N", "n_cycles": "1"}
    if column in fixed:
        return fixed[column]
    if re.fullmatch(r"alpha\d+|g\d+", column):
        return "1"
    for suffix, unit in (("_mm_per_N", "mm/N"), ("_kg_m3", "kg/m^3"), ("_per_s", "1/s"),
                         ("_Pa", "Pa"), ("_mm", "mm"), ("_N", "N"), ("_s", "s")):
        if column.endswith(suffix):
            return unit
    return None


def _json(clean: pd.DataFrame) -> str:
    records = []
    for row in clean.to_dict("records"):
        record = {}
        for key, value in row.items():
            if isinstance(value, (float, np.floating)):
                value = float(value)
                record[key] = value if math.isfinite(value) else None
            elif isinstance(value, (int, np.integer)):
                record[key] = int(value)
            else:
                record[key] = value
        records.append(record)
    document = {
        "convention": {
            "strain_energy": _CONVENTION,
            "viscoelastic": _PRONY_CONVENTION,
            "models": "ogden: one term (mu_Pa, alpha); ogden<N>: mu_Pa, alpha are term 1, plus "
                      "mu<i>_Pa, alpha<i>; +prony<k>: g1, tau1_s, ..., mu long-term",
            "missing": "null: not identifiable / not applicable",
        },
        "units": {c: _unit(c) for c in clean.columns},
        "source": clean.attrs.get("source"),
        "parameters": records,
    }
    return json.dumps(document, indent=2, ensure_ascii=False, allow_nan=False) + "\n"


# ============================================================================ cards
def _num(x: float) -> str:
    """Format a card number: the shortest text that reads back to the same float."""
    return repr(float(x))


def _card_name(layer: str, prefix: str) -> str:
    return prefix + re.sub(r"[^A-Za-z0-9_-]", "_", layer)


def _fit_summary(row: dict) -> str:
    mu, mu_se = _with_error(row["mu_Pa"], row["mu_stderr_Pa"])
    a, a_se = _with_error(row["alpha"], row["alpha_stderr"])
    r = row["mu_alpha_correlation"]
    return (f"fit: mu_Pa = {mu} +/- {mu_se or 'n/a'} Pa, alpha = {a} +/- {a_se or 'n/a'}, "
            f"corr = {'n/a' if math.isnan(r) else f'{r:.3f}'}, RMS {_plain(row['rms_N'], 3)} N "
            f"over {int(row['n_cycles'])} cycles")


def _abaqus(clean: pd.DataFrame, density_kg_m3: float, source: str | None) -> str:
    materials = layer_materials(clean, density_kg_m3)
    names = {layer: _card_name(layer, "LAYER_") for layer in materials}
    upper: dict[str, str] = {}
    for layer, name in names.items():
        if name.upper() in upper:
            raise ParameterTableError(source or "parameter table", [
                f"layers {upper[name.upper()]!r} and {layer!r} both become the Abaqus material "
                f"name {name.upper()} (Abaqus names are case-insensitive); rename one"])
        upper[name.upper()] = layer
    lines = [
        "** Ogden material cards, one per layer, exported by calib export (format abaqus).",
        "** Units: SI (Pa, kg/m^3, s); the model's lengths must be in metres.",
        "** Abaqus Ogden potential (the project's convention, written exactly):",
        "**   U = sum_i 2 mu_i/alpha_i^2 (lb1^alpha_i + lb2^alpha_i + lb3^alpha_i - 3)"
        " + sum_i (J - 1)^(2i) / D_i",
        "**   D1 = 2/K, K = 2 mu (1 + nu) / (3 (1 - 2 nu)), mu = sum_i mu_i; D_i = 0 for i >= 2"
        " (no higher-order volumetric terms).",
        "** Viscoelastic layers: MODULI=LONG TERM (mu_i are the relaxed moduli) and",
        "**   *VISCOELASTIC, TIME=PRONY lines g_i, k_i, tau_i (s) with",
        "**   g_R(t) = 1 - sum_i g_i (1 - exp(-t/tau_i)) (g_i relative to the instantaneous "
        "modulus);",
        "**   k_i = 0: the bulk response does not relax.",
    ]
    if source:
        lines.append(f"** Source table: {source}")
    for row in clean.to_dict("records"):
        layer = row["layer"]
        material = materials[layer]
        spec = ModelSpec.parse(row["model"])
        K = material.bulk_modulus_Pa
        lines += [
            "**",
            f"** Layer {layer}: model {spec.name}; {_fit_summary(row)}",
            f"**   nu = {_num(material.nu)}, K = {_plain(K, 6)} Pa",
        ]
        ignored = _non_material(clean, row)
        if ignored:
            lines.append("**   not material parameters, left out of this card: "
                         + ", ".join(ignored))
        lines += [f"*MATERIAL, NAME={names[layer]}", "*DENSITY", f"{_num(material.density_kg_m3)},"]
        option = f"*HYPERELASTIC, OGDEN, N={material.n_terms}"
        if material.prony is not None:
            option += ", MODULI=LONG TERM"
        lines.append(option)
        values = []
        for m, a in zip(material.mu_Pa, material.alpha, strict=True):
            values += [_num(m), _num(a)]
        values += [_num(2.0 / K)] + [_num(0.0)] * (material.n_terms - 1)
        for start in range(0, len(values), 8):  # at most 8 values per data line
            lines.append(", ".join(values[start:start + 8]))
        if material.prony is not None:
            lines.append("*VISCOELASTIC, TIME=PRONY")
            for g, tau in zip(material.prony.g, material.prony.tau_s, strict=True):
                lines.append(f"{_num(g)}, {_num(0.0)}, {_num(tau)}")
    return "\n".join(lines) + "\n"


def _xml_attr(text: str) -> str:
    return (str(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
            .replace('"', "&quot;"))


def _xml_comment(text: str) -> str:
    text = str(text).replace("--", "- -")
    return text[:-1] + "- " if text.endswith("-") else text


def _febio(clean: pd.DataFrame, density_kg_m3: float, source: str | None) -> str:
    materials = layer_materials(clean, density_kg_m3)
    header = [
        "Ogden material cards, one per layer, exported by calib export (format febio),",
        "for the <Material> section of a FEBio model (febio_spec 3.0 / 4.0).",
        "Units: SI (Pa, kg/m^3, s); the model's lengths must be in metres.",
        "FEBio \"Ogden\" (uncoupled): W = sum_i c_i/m_i^2 (lb1^m_i + lb2^m_i + lb3^m_i - 3)"
        " + U(J), U(J) = k/2 (ln J)^2.",
        "From the project's convention W = sum_i 2 mu_i/alpha_i^2 (...) + K/2 (J - 1)^2:",
        "  c_i = 2 mu_i, m_i = alpha_i, k = K = 2 mu (1 + nu) / (3 (1 - 2 nu)), mu = sum_i mu_i.",
        "  The isochoric response and the small-strain bulk modulus are identical; the",
        "  volumetric terms differ at third order in (J - 1) (pressure at second order).",
        "Viscoelastic layers: \"uncoupled viscoelastic\" wrapping the long-term Ogden; FEBio",
        "  scales its deviatoric stress by G(t) = g0 + sum_i g_i exp(-t/t_i), so from the",
        "  project's (Abaqus) g_k: g0 = 1, g_i = g_i(Abaqus) / (1 - sum_k g_k), t_i = tau_i (s).",
        "  The wrapper's k is 0 because FEBio adds it to the elastic material's k; the bulk",
        "  response does not relax.",
    ]
    if source:
        header.append(f"Source table: {source}")
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<!--"]
    lines += ["  " + _xml_comment(h) for h in header]
    lines += ["-->", "<Material>"]
    for number, row in enumerate(clean.to_dict("records"), start=1):
        layer = row["layer"]
        material = materials[layer]
        spec = ModelSpec.parse(row["model"])
        K = material.bulk_modulus_Pa
        comments = [f"Layer {layer}: model {spec.name}; {_fit_summary(row)}; nu = "
                    f"{_num(material.nu)}"]
        ignored = _non_material(clean, row)
        if ignored:
            comments.append("not material parameters, left out of this card: "
                            + ", ".join(ignored))
        ogden = []
        for i, (m, a) in enumerate(zip(material.mu_Pa, material.alpha, strict=True), start=1):
            ogden += [f"<c{i}>{_num(2.0 * m)}</c{i}>", f"<m{i}>{_num(a)}</m{i}>"]
        density = f"<density>{_num(material.density_kg_m3)}</density>"
        attrs = f'id="{number}" name="{_xml_attr(layer)}"'
        lines += [f"  <!-- {_xml_comment(c)} -->" for c in comments]
        if material.prony is None:
            lines.append(f'  <material {attrs} type="Ogden">')
            lines += ["    " + density, f"    <k>{_num(K)}</k>"]
            lines += ["    " + e for e in ogden]
        else:
            g_inf = material.prony.g_inf
            lines.append(f'  <material {attrs} type="uncoupled viscoelastic">')
            lines += ["    " + density, "    <k>0</k>", "    <g0>1</g0>"]
            terms = zip(material.prony.g, material.prony.tau_s, strict=True)
            for i, (g, tau) in enumerate(terms, start=1):
                lines += [f"    <g{i}>{_num(g / g_inf)}</g{i}>", f"    <t{i}>{_num(tau)}</t{i}>"]
            lines.append('    <elastic type="Ogden">')
            lines += [f"      <k>{_num(K)}</k>"] + ["      " + e for e in ogden]
            lines.append("    </elastic>")
        lines.append("  </material>")
    lines.append("</Material>")
    return "\n".join(lines) + "\n"


# ============================================================================ public
def export(frame: pd.DataFrame, fmt: str, *, density_kg_m3: float = DEFAULT_DENSITY_KG_M3,
           source: str | None = None) -> str:
    """Render a parameter table in one of :data:`FORMATS`.

    Parameters
    ----------
    frame : pandas.DataFrame
        A parameter table (validated here).
    fmt : {"csv", "json", "markdown", "latex", "abaqus", "febio"}
        ``csv``: the table itself; ``json``: ``{"convention", "units", "source", "parameters":
        [records]}`` with ``null`` for NaN; ``markdown`` / ``latex``: a readable table (LaTeX
        with booktabs) with value ± standard error; ``abaqus``: ``*MATERIAL`` cards;
        ``febio``: ``<Material>`` XML.
    density_kg_m3 : float
        Density (kg/m^3) in the cards for layers without a ``density_kg_m3`` value.
    source : str, optional
        Named in comments; defaults to ``frame.attrs["source"]``.

    Returns
    -------
    str
        The rendered text, ending with a newline.

    Raises
    ------
    ParameterTableError
        If the table is invalid or cannot be expressed in the format.
    ValueError
        If ``fmt`` is unknown or ``density_kg_m3`` is not positive.
    """
    fmt = str(fmt).lower()
    if fmt not in FORMATS:
        raise ValueError(f"unknown export format {fmt!r}; choose one of {list(FORMATS)}")
    if not (math.isfinite(density_kg_m3) and density_kg_m3 > 0.0):
        raise ValueError(f"density_kg_m3={density_kg_m3} must be positive and finite")
    source = source if source is not None else frame.attrs.get("source")
    clean = validate_parameters(frame, source=source or "parameter table")
    if fmt == "csv":
        return _to_csv(clean)
    if fmt == "json":
        return _json(clean)
    if fmt == "markdown":
        return _markdown(clean)
    if fmt == "latex":
        return _latex(clean)
    if fmt == "abaqus":
        return _abaqus(clean, density_kg_m3, source)
    return _febio(clean, density_kg_m3, source)


def format_for_path(path: str | os.PathLike) -> str:
    """Return the export format implied by a file suffix (.csv .json .md .tex .inp .feb .xml)."""
    suffix = Path(path).suffix.lower()
    if suffix not in _FORMAT_OF_SUFFIX:
        raise ValueError(f"cannot tell the export format from the suffix {suffix!r} of {path}; "
                         f"known suffixes: {sorted(_FORMAT_OF_SUFFIX)}")
    return _FORMAT_OF_SUFFIX[suffix]


def export_file(frame: pd.DataFrame, path: str | os.PathLike, fmt: str | None = None,
                **kwargs) -> Path:
    """Render ``frame`` (see :func:`export`) and write it to ``path`` atomically.

    Parameters
    ----------
    frame : pandas.DataFrame
        A parameter table.
    path : str or path-like
        Target file.
    fmt : str, optional
        One of :data:`FORMATS`; inferred from the suffix of ``path`` if omitted.
    **kwargs
        Passed to :func:`export`.

    Returns
    -------
    pathlib.Path
        The path written.
    """
    from ._io import write_text

    text = export(frame, fmt or format_for_path(path), **kwargs)
    return write_text(path, text)
