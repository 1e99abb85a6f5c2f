"""The rig-format writer: one loading cycle as the rig's logger or a spreadsheet export writes it.

The data contract is ``shared/RIG_LOGS.md``. A :class:`FileVariant` says how one file is
written: separator and decimal mark, column names with their units, column order, sign
conventions, where the metadata lives (a ``#`` header, the folder's ``manifest.csv``, or only
the file name), the file-name style and the line ending. :func:`draw_variant` draws one with
campaign-wide proportions; :func:`format_cycle` renders the text; :func:`cycle_file_name`
and :func:`manifest_text` give the file name and a folder's manifest.

Arrays come in the compression-positive frame in s, mm and N; the writer applies the file's
signs and units. Numbers are written with enough digits for the sensors' resolutions (0.1 ms,
0.1 um, 10 uN), so formatting adds no error of its own beyond the logger clock.
"""

from __future__ import annotations

import dataclasses
import io

import numpy as np

__all__ = [
    "FileVariant",
    "CycleMeta",
    "draw_variant",
    "format_cycle",
    "cycle_file_name",
    "rate_token",
    "manifest_text",
    "MANIFEST_COLUMNS",
    "UNIT_FACTORS",
]

#: Columns of a folder's ``manifest.csv`` (RIG_LOGS.md).
MANIFEST_COLUMNS = ("file", "layer", "sample", "test", "rate_mm_per_s", "diameter_mm",
                    "height_mm")

#: Factor from the file unit to s, mm or N: value_in_SI_unit = value_in_file * factor.
UNIT_FACTORS = {
    "time": {"s": 1.0, "ms": 1e-3},
    "displacement": {"mm": 1.0, "m": 1e3},
    "force": {"N": 1.0, "mN": 1e-3, "kN": 1e3},
}

#: Column headers by quantity and unit, as rig firmware and exports spell them.
_HEADERS = {
    "time": {"s": ("time_s", "Time [s]", "Time (s)", "time [s]"),
             "ms": ("Time (ms)", "Time [ms]", "TIME [ms]")},
    "displacement": {"mm": ("displacement_mm", "Position (mm)", "Displacement [mm]",
                            "position [mm]"),
                     "m": ("Displacement (m)", "Position [m]")},
    "force": {"N": ("force_N", "Load [N]", "Force (N)", "LOAD [N]"),
              "mN": ("Force (mN)", "Load [mN]"),
              "kN": ("Force [kN]",)},
}

#: Decimal places written per quantity and unit (resolution 0.1 ms, 0.1 um, 10 uN).
_DECIMALS = {
    "time": {"s": 4, "ms": 1},
    "displacement": {"mm": 4, "m": 7},
    "force": {"N": 5, "mN": 2, "kN": 8},
}


@dataclasses.dataclass(frozen=True)
class CycleMeta:
    """Metadata of one loading cycle as the operator records it.

    Parameters
    ----------
    layer : str
        Gel layer, ``"A"`` ... ``"F"``.
    sample : str
        Sample name, e.g. ``"A1"``.
    test : int
        Test number of this sample (1, 2, 3 in the order the tests were run).
    rate_mm_per_s : float
        Platen speed (mm/s).
    diameter_mm, height_mm : float
        Sample size as measured (mm).
    """

    layer: str
    sample: str
    test: int
    rate_mm_per_s: float
    diameter_mm: float
    height_mm: float


@dataclasses.dataclass(frozen=True)
class FileVariant:
    """How one cycle file is written.

    Parameters
    ----------
    separator : {",", "\\t", ";"}
    decimal : {".", ","}
        Decimal mark; ``","`` only with ``";"`` or tab separators.
    time_unit : {"s", "ms"}
    displacement_unit : {"mm", "m"}
    force_unit : {"N", "mN", "kN"}
    time_header, displacement_header, force_header : str
        Column names (with the unit in the name, brackets or parentheses).
    column_order : tuple of str
        Order of ``"time"``, ``"displacement"``, ``"force"``.
    displacement_sign, force_sign : {+1, -1}
        +1 logs compression as positive travel / force, -1 as negative.
    metadata : {"header", "manifest", "header+manifest", "filename"}
        Where the cycle's metadata is written: ``#`` lines, a row of the folder's
        ``manifest.csv``, both (agreeing), or nowhere but the file name.
    name_style : {"dot", "p"}
        Rate in the file name as ``0.83`` or ``0p83``.
    newline : {"\\n", "\\r\\n"}
    extra_header : bool
        Header carries extra firmware lines (rig, load cell) besides the contract keys.
    """

    separator: str = ","
    decimal: str = "."
    time_unit: str = "s"
    displacement_unit: str = "mm"
    force_unit: str = "N"
    time_header: str = "time_s"
    displacement_header: str = "displacement_mm"
    force_header: str = "force_N"
    column_order: tuple[str, str, str] = ("time", "displacement", "force")
    displacement_sign: int = 1
    force_sign: int = 1
    metadata: str = "header"
    name_style: str = "dot"
    newline: str = "\n"
    extra_header: bool = False

    def __post_init__(self):
        if self.separator not in (",", "\t", ";"):
            raise ValueError(f"separator {self.separator!r} is not ',', tab or ';'")
        if self.decimal not in (".", ","):
            raise ValueError(f"decimal mark {self.decimal!r} is not '.' or ','")
        if self.decimal == "," and self.separator == ",":
            raise ValueError("a decimal comma needs a ';' or tab separator")
        for quantity, unit in (("time", self.time_unit), ("displacement",
                               self.displacement_unit), ("force", self.force_unit)):
            if unit not in UNIT_FACTORS[quantity]:
                raise ValueError(f"{quantity} unit {unit!r} is not one of "
                                 f"{tuple(UNIT_FACTORS[quantity])}")
        if sorted(self.column_order) != ["displacement", "force", "time"]:
            raise ValueError(f"column_order {self.column_order} must order time, "
                             "displacement and force")
        if self.displacement_sign not in (1, -1) or self.force_sign not in (1, -1):
            raise ValueError("signs must be +1 or -1")
        if self.metadata not in ("header", "manifest", "header+manifest", "filename"):
            raise ValueError(f"metadata source {self.metadata!r} is unknown")
        if self.name_style not in ("dot", "p"):
            raise ValueError(f"name_style {self.name_style!r} is not 'dot' or 'p'")
        if self.newline not in ("\n", "\r\n"):
            raise ValueError("newline must be LF or CRLF")

    @property
    def has_header_metadata(self) -> bool:
        """Whether the file carries ``#`` metadata lines."""
        return self.metadata in ("header", "header+manifest")

    @property
    def in_manifest(self) -> bool:
        """Whether the folder's manifest lists this file."""
        return self.metadata in ("manifest", "header+manifest")

    def to_dict(self) -> dict:
        """JSON-ready description (tab and CRLF spelled out)."""
        out = dataclasses.asdict(self)
        out["separator"] = {"\t": "tab"}.get(self.separator, self.separator)
        out["newline"] = {"\n": "LF", "\r\n": "CRLF"}[self.newline]
        out["column_order"] = list(self.column_order)
        return out


def _pick(rng: np.random.Generator, options, weights):
    weights = np.asarray(weights, dtype=float)
    return options[int(rng.choice(len(options), p=weights / weights.sum()))]


def draw_variant(rng: np.random.Generator, metadata: str | None = None) -> FileVariant:
    """Draw how one file is written, with campaign-wide proportions.

    Parameters
    ----------
    rng : numpy.random.Generator
    metadata : str, optional
        Force the metadata source (the generator fixes ``"filename"`` per sample, because a
        file without metadata cannot carry a measured geometry); otherwise header 60 %,
        manifest 25 %, both 15 %.

    Returns
    -------
    FileVariant

    Notes
    -----
    Proportions: comma-separated 60 %, tab 15 %, semicolon with decimal comma 20 %, semicolon
    with decimal point 5 %; time in ms 30 %; displacement in m 20 %; force in mN 25 % and kN
    10 %; canonical column names in about half the files; shuffled columns 20 %; displacement
    logged negative 35 % and force negative 35 % (independently); rate as ``0p83`` 30 %;
    CRLF 15 %; extra firmware header lines 40 %.
    """
    sep, dec = _pick(rng, [(",", "."), ("\t", "."), (";", ","), (";", ".")],
                     [0.60, 0.15, 0.20, 0.05])
    units = {
        "time": _pick(rng, ["s", "ms"], [0.7, 0.3]),
        "displacement": _pick(rng, ["mm", "m"], [0.8, 0.2]),
        "force": _pick(rng, ["N", "mN", "kN"], [0.65, 0.25, 0.10]),
    }
    headers = {}
    for quantity, unit in units.items():
        names = _HEADERS[quantity][unit]
        # the canonical snake_case name (first of the s/mm/N lists) in about half the files
        weights = [1.0] * len(names)
        if unit in ("s", "mm", "N"):
            weights[0] = float(len(names) - 1)
        headers[quantity] = _pick(rng, list(names), weights)
    order = ("time", "displacement", "force")
    if rng.random() < 0.2:
        order = tuple(order[i] for i in rng.permutation(3))
    if metadata is None:
        metadata = _pick(rng, ["header", "manifest", "header+manifest"], [0.60, 0.25, 0.15])
    return FileVariant(
        separator=sep, decimal=dec,
        time_unit=units["time"], displacement_unit=units["displacement"],
        force_unit=units["force"],
        time_header=headers["time"], displacement_header=headers["displacement"],
        force_header=headers["force"], column_order=order,
        displacement_sign=-1 if rng.random() < 0.35 else 1,
        force_sign=-1 if rng.random() < 0.35 else 1,
        metadata=metadata,
        name_style="p" if rng.random() < 0.3 else "dot",
        newline="\r\n" if rng.random() < 0.15 else "\n",
        extra_header=bool(rng.random() < 0.4),
    )


def rate_token(rate_mm_per_s: float, style: str = "dot") -> str:
    """The rate as written in a file name: ``0.83`` / ``0p83``, ``6``, ``0.17`` / ``0p17``."""
    text = f"{rate_mm_per_s:g}"
    return text.replace(".", "p") if style == "p" else text


def cycle_file_name(meta: CycleMeta, style: str = "dot") -> str:
    """File name in the rig's pattern, e.g. ``A1_t2_0.83mms.csv`` or ``A1_t2_0p83mms.csv``."""
    return f"{meta.sample}_t{meta.test}_{rate_token(meta.rate_mm_per_s, style)}mms.csv"


def _number(value: float, decimal: str) -> str:
    text = f"{value:g}"
    return text.replace(".", ",") if decimal == "," else text


def format_cycle(meta: CycleMeta, time_s, displacement_mm, force_N,
                 variant: FileVariant) -> str:
    """Render one cycle file.

    Parameters
    ----------
    meta : CycleMeta
    time_s, displacement_mm, force_N : array_like, shape (n,)
        Logged samples in the compression-positive frame (s, mm, N).
    variant : FileVariant

    Returns
    -------
    str
        The file's text, with the variant's newline.
    """
    columns = {"time": np.asarray(time_s, float),
               "displacement": variant.displacement_sign * np.asarray(displacement_mm, float),
               "force": variant.force_sign * np.asarray(force_N, float)}
    n = len(columns["time"])
    if not (len(columns["displacement"]) == len(columns["force"]) == n):
        raise ValueError("time, displacement and force columns differ in length")
    units = {"time": variant.time_unit, "displacement": variant.displacement_unit,
             "force": variant.force_unit}
    headers = {"time": variant.time_header, "displacement": variant.displacement_header,
               "force": variant.force_header}
    lines = []
    if variant.has_header_metadata:
        if variant.extra_header:
            lines.append("# rig: ISML tension-compression rig, platen encoder")
            lines.append("# load_cell: Burster 8523, 20 N")
        lines += [
            f"# layer: {meta.layer}",
            f"# sample: {meta.sample}",
            f"# test: {meta.test}",
            f"# rate_mm_per_s: {_number(meta.rate_mm_per_s, variant.decimal)}",
            f"# diameter_mm: {_number(meta.diameter_mm, variant.decimal)}",
            f"# height_mm: {_number(meta.height_mm, variant.decimal)}",
        ]
    lines.append(variant.separator.join(headers[q] for q in variant.column_order))
    text_cols = []
    for q in variant.column_order:
        values = columns[q] / UNIT_FACTORS[q][units[q]]
        digits = _DECIMALS[q][units[q]]
        col = np.char.mod(f"%.{digits}f", values)
        # no "-0.0000": a rounded zero is written unsigned
        col = np.where(np.round(values, digits) == 0.0, f"{0.0:.{digits}f}", col)
        if variant.decimal == ",":
            col = np.char.replace(col, ".", ",")
        text_cols.append(col)
    sep = variant.separator
    rows = text_cols[0]
    for col in text_cols[1:]:
        rows = np.char.add(np.char.add(rows, sep), col)
    buf = io.StringIO()
    buf.write(variant.newline.join(lines))
    buf.write(variant.newline)
    if n:
        buf.write(variant.newline.join(rows.tolist()))
        buf.write(variant.newline)
    return buf.getvalue()


def manifest_text(rows: list[tuple[str, CycleMeta]]) -> str:
    """A folder's ``manifest.csv``: header then one row per (file name, metadata).

    Always comma-separated with decimal points (the lab's own bookkeeping file).
    """
    import pandas as pd

    table = pd.DataFrame(
        [{"file": name, "layer": m.layer, "sample": m.sample, "test": m.test,
          "rate_mm_per_s": m.rate_mm_per_s, "diameter_mm": m.diameter_mm,
          "height_mm": m.height_mm} for name, m in rows],
        columns=list(MANIFEST_COLUMNS))
    return table.to_csv(index=False, lineterminator="\n")
