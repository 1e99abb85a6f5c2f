"""Rig force-displacement logs -> validated loading cycles (the contract is ``shared/RIG_LOGS.md``).

A rig log is one loading cycle of one sample as the rig recorded it: approach, loading to 30 %
of the height, an optional hold, unloading. :func:`load_cycle` turns one file into a
:class:`Cycle` (the loading branch only, in s, mm and N, compression positive) or raises
:class:`CycleRejected` with the reason; :func:`load_campaign` does it for a folder and never
raises on a bad file: every file it cannot use becomes a :class:`Rejection` with its reason.

What one file goes through, in order:

1. **Bytes -> text.** UTF-8 (with or without BOM) or UTF-16 with a BOM. Text that is not UTF-8
   but decodes as Windows-1252 without control characters (an old spreadsheet export with
   ``µm`` in a header) is accepted with a warning; anything else with NUL or control bytes is
   binary and rejected.
2. **Text -> table.** ``#`` lines are comments; ``# key: value`` (or ``key = value``) lines are
   metadata. The separator (tab, ``;``, ``,``, ``|`` or white space) is the one under which the
   first lines split into a consistent number of numeric fields. A cell with a comma and no
   point is a decimal comma (``0,0083``). The header is the last non-numeric line before the
   data (a ``#``-commented header as ``numpy.savetxt`` writes it is accepted); a row of bare
   units under the header (``s, mm, N``) is merged into it. Rows that do not parse are
   dropped and listed in the warnings.
3. **Columns and units.** Roles are found by name: time (``time``, ``t``), displacement
   (``displacement``, ``position``, ``travel``, ``extension``, ``deflection``, ``stroke``,
   ...), force (``force``, ``load``). Units come in brackets, parentheses or braces, after a
   slash, or as a name suffix (``time_s``, ``force_mN``), in any case; see :data:`UNITS`. A
   role whose column has an unknown unit, or a unit of the wrong kind, rejects the file; a
   column without any unit is taken in s, mm or N and the cycle carries a warning. A role
   not found by name may be found by the unit of an unnamed column (with a warning).
4. **Metadata.** A ``manifest.csv`` row wins over the file's ``#`` header, which wins over the
   file name (``A1_t2_0.83mms.csv``, ``0p83`` for ``0.83``). Disagreements are warnings
   naming both values. The layer defaults to the letters of the sample name (``A1`` -> ``A``),
   then to the layer folder; a missing rate is measured from the data (warning); a missing
   diameter or height defaults to 38 mm or 24 mm (warning). A missing sample or test number
   cannot be inferred and rejects the file.
5. **Time base and glitches.** Rows with a missing value in a used column are dropped
   (warning). A lone time stamp out of line with both neighbours (which agree) is a corrupt
   stamp and its row is dropped (warning). Rows are put in time order when the time steps back
   by no more than twice the median sampling interval (jitter, warning); a larger step back
   (a restarted clock, two logs in one file) rejects the file. Rows sharing a time stamp are
   averaged (exact duplicates dropped), and gaps longer than five sampling intervals are
   listed (warnings). A lone displacement or force sample that jumps away from both neighbours
   by more than 20 noise levels and five neighbouring steps, and straight back, is a sensor
   spike and is dropped (warning); more than 1 % of such rows rejects the file.
6. **Sign convention.** The force reading furthest from its starting value (after a
   5-sample running median, so one spike cannot decide) is the peak of compression: its sign
   relative to the start gives the force convention, and the direction the platen moved from
   the start of logging to that moment gives the displacement convention. Both are normalised
   to compression-positive and reported as logged (+1 = compression was logged positive).
7. **Peak travel.** The loading branch ends at the first sample within noise of the largest
   travel of the first excursion above 90 % of the maximum travel; samples after it are the
   hold (travel within 0.2 % of the peak) and the unloading, listed as trimmed spans. A log
   that loads again afterwards gets a warning.
8. **Contact, tare and noise.** A two-segment (hinge) least-squares fit of force against
   travel, ``F = tare + k max(x - x_c, 0)``, over the samples up to where the force has risen
   by 10 % of its peak (at least 25 noise levels), gives the contact point ``x_c``: the
   initial rise back-extrapolated to the approach level. The tare is the median force of the
   approach samples before ``x_c`` and the noise level the scaled median absolute deviation
   of those samples (of the second differences of the whole record when the approach has
   fewer than 10 samples). The force must then rise above 5 noise levels and stay there until
   the peak (persistence). If the fit put the contact after that point, the curve has a toe
   (a domed or tilted face, slack taken up): the force rose gradually before the initial rise
   that the fit back-extrapolates. The contact stays where the fit put it, the
   toe-compensated zero of ASTM practice (D695), the toe's samples are trimmed as a span of
   their own, the tare is read before them, and a warning gives the toe's length and the
   force at contact (until 2026-12 the contact moved to the start of the toe, which depends
   on the noise level: on a generated campaign with domed faces, layers A and D, the
   readings' standard deviation was 42 um, against 6 um at the toe-compensated zero). On
   the bonded Ogden curves of this project the fit recovers a known contact to about
   0.01 mm (tests/test_loaders.py). A log whose force is
   already above the noise at its first sample has no approach: the contact is its first
   sample and the tare its first reading (warning).
9. **Loading branch.** The contact point itself (time and force interpolated linearly between
   the two samples that straddle it), then every sample after it up to peak travel; time and
   travel are measured from contact, the tare is removed from the force.
10. **Checks.** At least :data:`MIN_POINTS` samples in the branch; the peak strain (travel /
    height) within :data:`STRAIN_REJECT` of the stated strain (``# strain:`` or 30 %), and
    a warning beyond :data:`STRAIN_WARN`; a warning when the mean platen speed over the
    branch differs from the stated rate by more than 25 %.
"""

from __future__ import annotations

import codecs
import csv
import dataclasses
import math
import os
import re
import shlex
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.ndimage import median_filter

__all__ = [
    "Cycle",
    "Campaign",
    "Rejection",
    "Span",
    "CycleRejected",
    "load_cycle",
    "load_campaign",
    "contact_fit_bias",
    "MIN_POINTS",
    "TARGET_STRAIN",
    "STRAIN_REJECT",
    "STRAIN_WARN",
    "DEFAULT_DIAMETER_MM",
    "DEFAULT_HEIGHT_MM",
    "UNITS",
]

#: Fewest samples a loading branch may have. The modulus is read from the initial linear
#: region (about 1-5 % strain); 20 samples over 30 % strain put three samples in it.
MIN_POINTS = 20
#: The rig compresses every sample to 30 % of its height unless the file says otherwise.
TARGET_STRAIN = 0.30
#: Peak strain further than this from the stated strain rejects the cycle (absolute strain).
#: 0.05 is 1.2 mm of a 24 mm sample: far more than the contact uncertainty, so a cycle this
#: far off was stopped early, logged in the wrong unit or measured against the wrong height.
STRAIN_REJECT = 0.05
#: Peak strain further than this from the stated strain is accepted with a warning.
STRAIN_WARN = 0.02
#: Sample size the rig uses, applied (with a warning) when a file and manifest omit it.
DEFAULT_DIAMETER_MM = 38.0
DEFAULT_HEIGHT_MM = 24.0
#: Files larger than this are not read (a rig log of a 40 s test at 200 Hz is about 0.3 MB).
MAX_FILE_BYTES = 200_000_000

#: Relative tolerance when :meth:`Campaign.select` matches a rate.
RATE_RTOL = 0.05
#: The contact fit uses the samples up to where the force has risen by this fraction of its
#: peak: the bonded curves stiffen beyond it, which would bias the back-extrapolation.
_CONTACT_WINDOW = 0.10
#: ... but at least this many noise levels, so that a noisy, soft cycle has a rise to fit.
_CONTACT_WINDOW_NOISE = 25.0
#: The force is "clearly above the noise" beyond this many noise levels.
_THRESHOLD_NOISE = 5.0
#: A cycle whose net peak force is below this many noise levels has no loading branch.
_MIN_SIGNAL_NOISE = 10.0
#: Fewest approach samples for the tare to be measured from the approach.
_MIN_APPROACH = 3
#: Fewest approach samples for the noise level to be measured from the approach.
_MIN_APPROACH_NOISE = 10
#: Mean platen speed more than this far (relative) from the stated rate gives a warning.
_RATE_WARN = 0.25

#: Unit conversion factors to s, mm and N, by kind; keys are lower case.
UNITS: dict[str, dict[str, float]] = {
    "time": {
        "s": 1.0, "sec": 1.0, "secs": 1.0, "second": 1.0, "seconds": 1.0,
        "ms": 1e-3, "msec": 1e-3, "millisecond": 1e-3, "milliseconds": 1e-3,
        "us": 1e-6, "\u00b5s": 1e-6, "\u03bcs": 1e-6, "microsecond": 1e-6,
        "microseconds": 1e-6,
        "min": 60.0, "mins": 60.0, "minute": 60.0, "minutes": 60.0,
        "h": 3600.0, "hr": 3600.0, "hour": 3600.0, "hours": 3600.0,
    },
    "displacement": {
        "mm": 1.0, "millimeter": 1.0, "millimeters": 1.0, "millimetre": 1.0,
        "millimetres": 1.0,
        "m": 1e3, "meter": 1e3, "meters": 1e3, "metre": 1e3, "metres": 1e3,
        "cm": 10.0,
        "um": 1e-3, "\u00b5m": 1e-3, "\u03bcm": 1e-3, "micron": 1e-3, "microns": 1e-3,
        "micrometer": 1e-3, "micrometers": 1e-3, "micrometre": 1e-3, "micrometres": 1e-3,
        "in": 25.4, "inch": 25.4, "inches": 25.4,
    },
    "force": {
        "n": 1.0, "newton": 1.0, "newtons": 1.0,
        "mn": 1e-3, "millinewton": 1e-3, "millinewtons": 1e-3,
        "kn": 1e3, "kilonewton": 1e3, "kilonewtons": 1e3,
        "un": 1e-6, "\u00b5n": 1e-6, "\u03bcn": 1e-6, "cn": 1e-2,
        "gf": 9.80665e-3, "kgf": 9.80665, "lbf": 4.4482216152605,
    },
}
_BASE_UNIT = {"time": "s", "displacement": "mm", "force": "N"}
_ROLES = ("time", "displacement", "force")
_ROLE_WORDS = {
    "time": {"time", "zeit", "elapsed", "t"},
    "displacement": {"displacement", "disp", "position", "pos", "travel", "extension",
                     "deflection", "stroke", "crosshead", "deformation", "compression",
                     "distance", "elongation", "d", "x", "z", "u"},
    "force": {"force", "load", "kraft", "f"},
}
#: Words that make a column something else even if it also names a role (a strain, a rate).
_NOT_A_ROLE = {"strain", "stress", "rate", "speed", "velocity", "temperature", "temp",
               "setpoint", "target", "command", "cycle", "count", "index", "step"}
_DATA_SUFFIXES = {".csv", ".tsv", ".txt", ".dat", ".log", ".asc", ".prn", ".tab"}
#: Suffixes of files that are certainly not rig logs: listed as rejected without being parsed.
_NOT_LOGS = {".json", ".md", ".rst", ".html", ".htm", ".png", ".jpg", ".jpeg", ".gif", ".svg",
             ".pdf", ".py", ".ipynb", ".yaml", ".yml", ".toml", ".zip", ".gz", ".docx", ".doc",
             ".pptx"}
_WORKBOOKS = {".xlsx", ".xls", ".xlsm", ".ods"}
_SEPARATORS = ("\t", ";", ",", "|", None)   # None: runs of white space
_SEP_NAMES = {"\t": "tab", ";": "semicolon", ",": "comma", "|": "pipe", None: "white space"}
_META_FIELDS = ("layer", "sample", "test", "rate_mm_per_s", "diameter_mm", "height_mm")


# ============================================================================ records
class CycleRejected(Exception):
    """A file cannot be read as a loading cycle; ``reason`` says why, in words."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


@dataclasses.dataclass(frozen=True)
class Span:
    """A stretch of a log left out of the loading branch.

    Parameters
    ----------
    kind : str
        ``"approach"`` (before contact), ``"toe"`` (between a gradual first rise of the
        force and the contact back-extrapolated from the initial rise), ``"hold"`` (at peak
        travel) or ``"unloading"`` (everything after the hold).
    start_s, end_s : float
        First and last time stamp of the span, in the file's time base (s).
    n_points : int
        Samples in the span.
    """

    kind: str
    start_s: float
    end_s: float
    n_points: int

    def to_dict(self) -> dict:
        """Return the span as JSON-ready values."""
        return {"kind": self.kind, "start_s": float(self.start_s), "end_s": float(self.end_s),
                "n_points": int(self.n_points)}


def _frozen(a) -> np.ndarray:
    a = np.array(a, dtype=np.float64, copy=True)
    a.setflags(write=False)
    return a


@dataclasses.dataclass(frozen=True, eq=False)
class Cycle:
    """One validated loading branch of one rig log.

    Parameters
    ----------
    file : str
        Path of the log relative to the campaign root, ``/``-separated.
    layer, sample : str
        Layer (``"A"``) and sample (``"A1"``) names.
    test : int
        Test order of this sample (1, 2, 3, ...).
    rate_mm_per_s : float
        Stated platen speed (mm/s); measured from the data only when no source states it.
    diameter_mm, height_mm : float
        Sample size (mm).
    time_s : ndarray, shape (n,)
        Time from contact (s), starts at 0.
    displacement_mm : ndarray, shape (n,)
        Platen travel from contact (mm), compression positive, starts at 0.
    force_N : ndarray, shape (n,)
        Load-cell force with the tare removed (N), compression positive.
    sign : dict
        ``{"displacement": +1 | -1, "force": +1 | -1}``: the convention as logged,
        +1 meaning compression was logged positive.
    tare_N : float
        Load-cell offset removed (N, compression-positive frame).
    contact_mm : float
        Platen travel from the start of logging at which contact was found (mm,
        compression-positive frame).
    warnings : tuple of str
        What the loader noticed but accepted.
    trimmed : tuple of Span
        The parts of the log outside the loading branch.
    units : dict
        Unit of each used column as logged, e.g. ``{"time": "ms", "displacement": "m",
        "force": "mN"}``.
    columns : dict
        Header of each used column as logged.

    Notes
    -----
    The arrays are read-only copies. ``strain = displacement_mm / height_mm`` and
    ``stress_Pa = force_N / area`` are nominal (engineering) values on the stated geometry.
    """

    file: str
    layer: str
    sample: str
    test: int
    rate_mm_per_s: float
    diameter_mm: float
    height_mm: float
    time_s: np.ndarray
    displacement_mm: np.ndarray
    force_N: np.ndarray
    sign: dict
    tare_N: float
    contact_mm: float
    warnings: tuple[str, ...] = ()
    trimmed: tuple[Span, ...] = ()
    units: dict = dataclasses.field(default_factory=dict)
    columns: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        for name in ("time_s", "displacement_mm", "force_N"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))
        n = {len(self.time_s), len(self.displacement_mm), len(self.force_N)}
        if len(n) != 1:
            raise ValueError(f"{self.file}: time_s, displacement_mm and force_N differ in length")
        object.__setattr__(self, "sign", dict(self.sign))
        object.__setattr__(self, "warnings", tuple(self.warnings))
        object.__setattr__(self, "trimmed", tuple(self.trimmed))
        object.__setattr__(self, "units", dict(self.units))
        object.__setattr__(self, "columns", dict(self.columns))

    @property
    def area_mm2(self) -> float:
        """Nominal cross-section, pi d^2 / 4 (mm^2)."""
        return math.pi * self.diameter_mm**2 / 4.0

    @property
    def strain(self) -> np.ndarray:
        """Nominal compressive strain, travel / height (fraction), shape (n,)."""
        return self.displacement_mm / self.height_mm

    @property
    def stress_Pa(self) -> np.ndarray:
        """Nominal compressive stress, force / undeformed area (Pa), shape (n,)."""
        return self.force_N / (self.area_mm2 * 1e-6)

    @property
    def peak_strain(self) -> float:
        """Largest nominal strain of the branch (fraction)."""
        return float(np.max(self.strain)) if len(self.strain) else float("nan")

    @property
    def n_points(self) -> int:
        """Samples in the loading branch."""
        return int(len(self.time_s))

    def report(self) -> dict:
        """Return the cycle's entry of the ``calib inspect --json`` object."""
        return {
            "file": self.file,
            "layer": self.layer,
            "sample": self.sample,
            "test": int(self.test),
            "rate_mm_per_s": float(self.rate_mm_per_s),
            "diameter_mm": float(self.diameter_mm),
            "height_mm": float(self.height_mm),
            "sign": {k: int(v) for k, v in self.sign.items()},
            "tare_N": float(self.tare_N),
            "contact_mm": float(self.contact_mm),
            "peak_strain": self.peak_strain,
            "n_points": self.n_points,
            "warnings": list(self.warnings),
            "units": dict(self.units),
            "trimmed": [s.to_dict() for s in self.trimmed],
        }


@dataclasses.dataclass(frozen=True)
class Rejection:
    """A file (or manifest entry, or folder) that was not loaded, and why."""

    file: str
    reason: str


_FRAME_COLUMNS = ["layer", "sample", "test", "rate_mm_per_s", "diameter_mm", "height_mm",
                  "file", "time_s", "displacement_mm", "force_N", "strain", "stress_Pa"]


@dataclasses.dataclass(frozen=True)
class Campaign:
    """Every cycle of a folder of rig logs, and every file that was not loaded.

    Parameters
    ----------
    root : str
        The campaign folder.
    cycles : tuple of Cycle
        Loaded cycles, sorted by file.
    rejected : tuple of Rejection
        Files, manifest entries and folders not loaded, each with its reason.
    notes : tuple of str
        Campaign-level notes (manifests used, defaults applied, duplicates).
    """

    root: str
    cycles: tuple[Cycle, ...]
    rejected: tuple[Rejection, ...] = ()
    notes: tuple[str, ...] = ()

    def layers(self) -> list[str]:
        """Layer names present, sorted."""
        return sorted({c.layer for c in self.cycles})

    def select(self, layer=None, sample=None, rate=None, rtol: float = RATE_RTOL) -> list[Cycle]:
        """Cycles matching every given criterion.

        Parameters
        ----------
        layer, sample : str, optional
            Exact names.
        rate : float, optional
            Platen speed (mm/s), matched within the relative tolerance ``rtol``.
        rtol : float
            Relative tolerance of the rate match (default 5 %).
        """
        out = []
        for c in self.cycles:
            if layer is not None and c.layer != layer:
                continue
            if sample is not None and c.sample != sample:
                continue
            if rate is not None and not abs(c.rate_mm_per_s - rate) <= rtol * abs(rate):
                continue
            out.append(c)
        return out

    def to_frame(self) -> pd.DataFrame:
        """All loading branches in long form, one row per sample.

        Columns ``layer, sample, test, rate_mm_per_s, diameter_mm, height_mm, file, time_s,
        displacement_mm, force_N, strain, stress_Pa``.
        """
        if not self.cycles:
            return pd.DataFrame({k: [] for k in _FRAME_COLUMNS})
        n = [c.n_points for c in self.cycles]
        cols = {}
        for key in ("layer", "sample", "test", "rate_mm_per_s", "diameter_mm", "height_mm",
                    "file"):
            cols[key] = np.repeat(np.array([getattr(c, key) for c in self.cycles]), n)
        for key in ("time_s", "displacement_mm", "force_N", "strain", "stress_Pa"):
            cols[key] = np.concatenate([getattr(c, key) for c in self.cycles])
        return pd.DataFrame(cols, columns=_FRAME_COLUMNS)

    def report(self) -> dict:
        """Exactly the ``calib inspect --json`` object: ``{"cycles": [...], "rejected": [...]}``."""
        return {
            "cycles": [c.report() for c in self.cycles],
            "rejected": [{"file": r.file, "reason": r.reason} for r in self.rejected],
        }


# ============================================================================ text
def _decode(raw: bytes) -> tuple[str, list[str]]:
    """Bytes to text, or :class:`CycleRejected` for binary or undecodable content."""
    if not raw.strip():
        raise CycleRejected("empty file")
    if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        try:
            return raw.decode("utf-16"), []
        except UnicodeDecodeError as exc:
            raise CycleRejected(f"undecodable content: bad UTF-16 ({exc.reason})") from None
    if b"\x00" in raw:
        at = raw.index(b"\x00")
        raise CycleRejected(f"binary content: NUL byte at offset {at}")
    try:
        text = raw.decode("utf-8-sig")
        warnings = []
    except UnicodeDecodeError as exc:
        bad = exc.start
        try:
            text = raw.decode("cp1252")
        except UnicodeDecodeError:
            raise CycleRejected(
                f"undecodable content: not UTF-8 (byte 0x{raw[bad]:02x} at offset {bad})"
            ) from None
        if _control_chars(text):
            raise CycleRejected(
                f"binary or undecodable content: not UTF-8 (byte 0x{raw[bad]:02x} at offset "
                f"{bad}) and control characters present"
            ) from None
        warnings = [f"not UTF-8 (byte 0x{raw[bad]:02x} at offset {bad}); read as Windows-1252"]
    n_ctrl = _control_chars(text)
    if n_ctrl:
        raise CycleRejected(f"binary content: {n_ctrl} control characters")
    return text, warnings


_CONTROL = re.compile(r"[\x00-\x08\x0e-\x1f\x7f]")


def _control_chars(text: str) -> int:
    return len(_CONTROL.findall(text))


def _split(line: str, sep) -> list[str]:
    if sep is None:
        return line.split()
    if '"' in line or "'" in line:
        try:
            return next(csv.reader([line], delimiter=sep, skipinitialspace=True))
        except (csv.Error, StopIteration):
            return line.split(sep)
    return line.split(sep)


def _cell(cell: str) -> float | None:
    """Read a cell as a number: ``nan`` if empty or NaN, ``None`` if it is not a number."""
    s = cell.strip().strip("\"'").strip()
    if not s or s.lower() in ("nan", "na", "n/a", "null", "none", "-"):
        return math.nan
    if "," in s and "." not in s:
        s = s.replace(",", ".")
    try:
        v = float(s)
    except ValueError:
        return None
    return v if math.isfinite(v) else None


def _numeric_fields(line: str, sep) -> int:
    """Count the fields if every non-empty field is a number (at least two), else 0."""
    fields = _split(line, sep)
    while fields and not fields[-1].strip():
        fields.pop()
    if len(fields) < 2:
        return 0
    n_num = 0
    for f in fields:
        if not f.strip():
            continue
        v = _cell(f)
        if v is None:
            return 0
        n_num += 1
    return len(fields) if n_num >= 2 else 0


_META_LINE = re.compile(r"^\s*([A-Za-z\u00b5\u03bc][\w .\-/()\[\]\u00b5\u03bc]*?)\s*[:=]\s*(.*?)\s*$")


@dataclasses.dataclass
class _Table:
    meta: dict
    header: list
    values: np.ndarray          # (n_rows, n_columns), NaN where a cell is missing or bad
    lines: np.ndarray           # (n_rows,) 1-based line numbers
    warnings: list
    bad_lines: list             # 1-based numbers of data lines that did not parse
    separator: str


def _parse_table(text: str) -> _Table:
    """Split a log into metadata, header and numeric rows (see the module docstring, step 2)."""
    lines = text.splitlines()
    warnings: list[str] = []
    meta: dict[str, str] = {}
    comments: list[tuple[int, str]] = []
    content: list[int] = []
    for i, line in enumerate(lines):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            body = s.lstrip("#").strip()
            comments.append((i, body))
            m = _META_LINE.match(body)
            if m:
                _put_meta(meta, m.group(1), m.group(2), warnings, i + 1)
            continue
        content.append(i)
    if not content:
        raise CycleRejected("no data rows: the file holds only comments or blank lines")

    # separator: the one under which the first lines give the most numeric rows of one width
    probe = content[:200]
    best = None
    for rank, sep in enumerate(_SEPARATORS):
        widths = [_numeric_fields(lines[i], sep) for i in probe]
        counted = [w for w in widths if w]
        if not counted:
            continue
        width = max(set(counted), key=counted.count)
        score = counted.count(width)
        if best is None or score > best[0] or (score == best[0] and rank < best[3]):
            best = (score, sep, width, rank)
    if best is None:
        raise CycleRejected("no numeric data rows found (checked tab, semicolon, comma, pipe "
                            "and white-space separators)")
    _, sep, width, _ = best

    first = next(i for i in content if _numeric_fields(lines[i], sep))
    before = [i for i in content if i < first]
    header_line = None
    header_text = None
    units_row = None
    if before:
        header_line = before[-1]
        cells = [c.strip().strip("\"'") for c in _split(lines[header_line], sep)]
        if len(before) >= 2 and all(_bare_unit(c) is not None for c in cells if c) \
                and any(cells):
            units_row = cells
            header_line = before[-2]
        preamble = [i for i in before if i < header_line]
    else:
        preamble = []
        # a '#'-commented header right before the data, as numpy.savetxt writes it: the
        # nearest comment line that names at least two of the three roles
        earlier = [body for i, body in comments if i < first]
        if earlier:
            cells = [c.strip().strip("\"'") for c in _split(earlier[-1], sep)]
            roles = {_role_of(_split_unit(c)[0]) for c in cells if c}
            if len(cells) >= 2 and len(roles & set(_ROLES)) >= 2:
                header_text = earlier[-1]
        if header_text is None:
            raise CycleRejected(
                "missing required column names: no header row before the first data row "
                f"(line {first + 1})"
            )
    for i in preamble:
        m = _META_LINE.match(lines[i].strip())
        fields = [c.strip() for c in _split(lines[i], sep)]
        if m:
            _put_meta(meta, m.group(1), m.group(2), warnings, i + 1)
        elif len(fields) == 2 and fields[0]:
            _put_meta(meta, fields[0], fields[1], warnings, i + 1)
        else:
            warnings.append(f"ignored line {i + 1} before the header: {lines[i].strip()[:60]!r}")

    if header_text is None:
        header_text = lines[header_line]
    header = [c.strip().strip("\"'").strip() for c in _split(header_text, sep)]
    if sep is None and len(header) != width:
        header = _regroup(header_text)
    while header and not header[-1] and len(header) > width:
        header.pop()
    if units_row is not None:
        for k, u in enumerate(units_row[: len(header)]):
            if u and _split_unit(header[k])[1] is None:
                header[k] = f"{header[k]} [{_bare_unit(u)}]"
    n_col = len(header)

    rows: list[list[float]] = []
    line_no: list[int] = []
    bad: list[int] = []
    n_comment = 0
    for i in range(first, len(lines)):
        s = lines[i].strip()
        if not s:
            continue
        if s.startswith("#"):
            n_comment += 1
            continue
        fields = _split(lines[i], sep)
        while len(fields) > n_col and not fields[-1].strip():
            fields.pop()
        vals = [_cell(f) for f in fields[:n_col]]
        if len(fields) != n_col or any(v is None for v in vals):
            bad.append(i + 1)
            vals = [math.nan if v is None else v for v in vals] + [math.nan] * (n_col - len(vals))
        rows.append(vals)
        line_no.append(i + 1)
    if n_comment:
        warnings.append(f"{n_comment} comment lines among the data rows skipped")
    values = np.array(rows, dtype=np.float64).reshape(len(rows), n_col)
    return _Table(meta, header, values, np.array(line_no, dtype=np.int64), warnings, bad,
                  _SEP_NAMES[sep])


def _regroup(text: str) -> list[str]:
    """Split a white-space separated header, keeping units with their names (``Time [s]``)."""
    try:
        tokens = shlex.split(text)
    except ValueError:
        tokens = text.split()
    out: list[str] = []
    for tok in tokens:
        if out and (tok[:1] in "[({<" or tok in ("/",) or out[-1].endswith("/")):
            out[-1] = f"{out[-1]} {tok}"
        else:
            out.append(tok)
    return out


def _put_meta(meta: dict, key: str, value: str, warnings: list, line: int) -> None:
    k = _norm_key(key)
    if not k:
        return
    if k in meta and meta[k] != value:
        warnings.append(f"metadata {key.strip()!r} given twice ({meta[k]!r}, then {value!r} "
                        f"on line {line}); used the first")
        return
    meta.setdefault(k, value.strip())


def _norm_key(key: str) -> str:
    return re.sub(r"[^0-9a-z]+", "_", key.strip().lower()).strip("_")


# ============================================================================ columns
_BRACKET = re.compile(r"[\[\(\{<]\s*([^\[\(\{<\]\)\}>]*?)\s*[\]\)\}>]")


def _bare_unit(cell: str) -> str | None:
    """Return the unit of a units-row cell (``s``, ``(mm)``, ``[N]``), or None if unknown."""
    s = cell.strip()
    m = re.fullmatch(r"[\[\(\{<]?\s*([^\]\)\}>]*?)\s*[\]\)\}>]?", s)
    u = m.group(1) if m else s
    key = _unit_key(u)
    if any(key in table for table in UNITS.values()):
        return u
    return None


def _unit_key(unit: str) -> str:
    return unit.strip().lower().replace(" ", "").rstrip(".")


def _split_unit(header: str) -> tuple[str, str | None]:
    """``'Force (mN)'`` -> ``('Force', 'mN')``; ``'time_s'`` -> ``('time', 's')``."""
    h = header.strip()
    groups = list(_BRACKET.finditer(h))
    if groups:
        # the bracket holding a known unit; otherwise the last one (an unknown unit)
        known = [g for g in groups if _unit_kind(g.group(1))]
        g = known[-1] if known else groups[-1]
        name = " ".join((h[: g.start()] + " " + h[g.end():]).split())
        return name, g.group(1).strip()
    if "/" in h:
        name, _, unit = h.rpartition("/")
        if name.strip() and unit.strip() and " " not in unit.strip():
            return name.strip(), unit.strip()
    for sep in ("_", " ", "-"):
        if sep in h:
            name, _, unit = h.rpartition(sep)
            key = _unit_key(unit)
            if name.strip() and any(key in table for table in UNITS.values()):
                return name.strip(), unit.strip()
    return h, None


def _role_of(name: str) -> str | None:
    words = [w for w in re.split(r"[^0-9a-z\u00b5\u03bc]+", name.lower()) if w]
    if not words or any(w in _NOT_A_ROLE for w in words):
        return None
    for role in ("force", "displacement", "time"):
        for w in words:
            if w in _ROLE_WORDS[role] and (len(w) > 1 or len(words) == 1):
                return role
    return None


def _unit_kind(unit: str) -> str | None:
    key = _unit_key(unit)
    for kind, table in UNITS.items():
        if key in table:
            return kind
    return None


def _columns(header: list[str]) -> tuple[dict, list[str]]:
    """Map each role to ``(column index, header, unit, factor)`` (module docstring, step 3)."""
    warnings: list[str] = []
    parsed = [_split_unit(h) for h in header]
    found: dict[str, list[int]] = {r: [] for r in _ROLES}
    for k, (name, _unit) in enumerate(parsed):
        role = _role_of(name)
        if role:
            found[role].append(k)
    used = {k for ks in found.values() for k in ks}
    for role in _ROLES:
        if found[role]:
            continue
        by_unit = [k for k, (name, unit) in enumerate(parsed)
                   if k not in used and unit and _unit_kind(unit) == role
                   and _role_of(name) is None and not _has_other_word(name)]
        if len(by_unit) == 1:
            found[role] = by_unit
            used.add(by_unit[0])
            warnings.append(f"column {header[by_unit[0]]!r} taken as the {role} by its unit")
    missing = [r for r in _ROLES if not found[r]]
    if missing:
        raise CycleRejected(
            f"missing required column: {', '.join(missing)} (columns found: "
            f"{', '.join(repr(h) for h in header)})"
        )
    out = {}
    for role in _ROLES:
        ks = found[role]
        if len(ks) > 1:
            warnings.append(f"several columns could be the {role} "
                            f"({', '.join(repr(header[k]) for k in ks)}); used {header[ks[0]]!r}")
        k = ks[0]
        name, unit = parsed[k]
        if unit is None or not unit.strip():
            warnings.append(f"column {header[k]!r} states no unit; taken as {_BASE_UNIT[role]}")
            out[role] = (k, header[k], _BASE_UNIT[role], 1.0)
            continue
        kind = _unit_kind(unit)
        if kind is None:
            raise CycleRejected(f"unknown unit {unit!r} in column {header[k]!r}")
        if kind != role:
            raise CycleRejected(f"unit {unit!r} in column {header[k]!r} is a {kind} unit, "
                                f"not a {role} unit")
        out[role] = (k, header[k], unit, UNITS[role][_unit_key(unit)])
    return out, warnings


def _has_other_word(name: str) -> bool:
    words = [w for w in re.split(r"[^0-9a-z]+", name.lower()) if w]
    return any(w in _NOT_A_ROLE for w in words)


# ============================================================================ metadata
_NUMBER = r"[+-]?(?:\d+(?:[.,]\d*)?|[.,]\d+)(?:[eE][+-]?\d+)?"
_QUANTITY = re.compile(rf"^\s*({_NUMBER})\s*(.*?)\s*$")
_RATE_UNITS = {"mm/s": 1.0, "mms": 1.0, "mm/sec": 1.0, "mms-1": 1.0, "mm*s-1": 1.0,
               "mm/min": 1 / 60, "mmmin-1": 1 / 60, "m/s": 1e3, "um/s": 1e-3,
               "\u00b5m/s": 1e-3, "\u03bcm/s": 1e-3, "cm/s": 10.0, "mm/ms": 1e3}
_KEY_FIELD = {
    "layer": "layer", "layer_name": "layer",
    "sample": "sample", "specimen": "sample", "sample_id": "sample", "specimen_id": "sample",
    "sample_name": "sample",
    "test": "test", "test_number": "test", "test_no": "test", "test_order": "test",
    "test_index": "test", "run": "test",
    "rate_mm_per_s": "rate_mm_per_s", "rate": "rate_mm_per_s", "speed": "rate_mm_per_s",
    "rate_mm_s": "rate_mm_per_s", "speed_mm_per_s": "rate_mm_per_s",
    "speed_mm_s": "rate_mm_per_s", "platen_speed": "rate_mm_per_s",
    "platen_speed_mm_per_s": "rate_mm_per_s", "loading_rate": "rate_mm_per_s",
    "crosshead_speed": "rate_mm_per_s", "velocity": "rate_mm_per_s",
    "rate_mm_per_min": "rate_mm_per_min", "speed_mm_per_min": "rate_mm_per_min",
    "rate_mm_min": "rate_mm_per_min",
    "diameter_mm": "diameter_mm", "diameter": "diameter_mm", "d_mm": "diameter_mm",
    "height_mm": "height_mm", "height": "height_mm", "h_mm": "height_mm",
    "thickness": "height_mm", "thickness_mm": "height_mm",
    "strain": "strain", "target_strain": "strain", "nominal_strain": "strain",
    "max_strain": "strain", "compression": "strain",
}


def _quantity(text, kind: str, what: str) -> float:
    """Read a metadata value with an optional unit, in mm, mm/s or a strain fraction."""
    if isinstance(text, (int, float, np.integer, np.floating)) and not isinstance(text, bool):
        return float(text)
    m = _QUANTITY.match(str(text))
    if not m:
        raise CycleRejected(f"bad metadata: {what} = {text!r} is not a number")
    value = float(m.group(1).replace(",", "."))
    unit = _unit_key(m.group(2))
    if not unit:
        return value
    if kind == "length" and unit in UNITS["displacement"]:
        return value * UNITS["displacement"][unit]
    if kind == "rate" and unit.replace(" ", "") in _RATE_UNITS:
        return value * _RATE_UNITS[unit]
    if kind == "strain" and unit == "%":
        return value / 100.0
    raise CycleRejected(f"bad metadata: unknown unit {m.group(2)!r} in {what} = {text!r}")


def _metadata_from(source: Mapping) -> dict:
    """Canonical metadata fields from a header or manifest mapping (values left as given)."""
    out: dict = {}
    for key, value in source.items():
        field = _KEY_FIELD.get(_norm_key(str(key)))
        if field is None or value is None:
            continue
        if isinstance(value, float) and math.isnan(value):
            continue
        if isinstance(value, str) and not value.strip():
            continue
        if field == "rate_mm_per_min":
            field, value = "rate_mm_per_s", f"{value} mm/min" if _plain(value) else value
        out.setdefault(field, value)
    return out


def _plain(value) -> bool:
    return bool(re.fullmatch(_NUMBER, str(value).strip()))


_NAME_RATE = re.compile(
    r"(?<![0-9.])(\d+(?:[.p]\d+)?)[\s_\-]*mm[\s_\-]*(?:/|per|p)?[\s_\-]*s(?:ec)?(?![a-z])",
    re.IGNORECASE,
)
_NAME_TEST = re.compile(r"(?:^|[_\-\s.])t(?:est)?[\s_\-]?(\d+)(?=$|[_\-\s.])", re.IGNORECASE)


def _metadata_from_name(name: str) -> dict:
    """Metadata from a file name such as ``A1_t2_0.83mms.csv`` or ``A1_t2_0p83mms.csv``."""
    stem = name
    suffix = Path(name).suffix
    if suffix.lower() in _DATA_SUFFIXES:
        stem = name[: -len(suffix)]
    out: dict = {}
    m = _NAME_RATE.search(stem)
    if m:
        out["rate_mm_per_s"] = m.group(1).replace("p", ".").replace("P", ".")
    m = _NAME_TEST.search(stem)
    if m:
        out["test"] = m.group(1)
    for token in re.split(r"[_\-\s]+", stem):
        if re.fullmatch(r"[A-Za-z]{1,3}\d+", token) and not re.fullmatch(r"(?i)t(est)?\d+",
                                                                          token):
            out["sample"] = token
            break
    return out


def _layer_from_folder(folder: str) -> str:
    return re.sub(r"(?i)^layer[\s_\-]*", "", folder).strip() or folder


def _same(a, b) -> bool:
    try:
        x, y = float(str(a).replace(",", ".")), float(str(b).replace(",", "."))
        return math.isclose(x, y, rel_tol=1e-9, abs_tol=1e-12)
    except ValueError:
        return str(a).strip() == str(b).strip()


def _resolve_metadata(header: dict, manifest: dict | None, name: dict, folder: str | None,
                      manifest_name: str) -> tuple[dict, list[str], list[str]]:
    """Merge metadata sources: manifest > file header > file name > inference/defaults.

    Returns the chosen raw values, the warnings, and the fields still missing.
    """
    warnings: list[str] = []
    chosen: dict = {}
    sources = [(f"{manifest_name} row", manifest or {}), ("file header", header),
               ("file name", name)]
    for field in _META_FIELDS + ("strain",):
        given = [(label, src[field]) for label, src in sources if field in src]
        if not given:
            continue
        label0, value0 = given[0]
        chosen[field] = value0
        for label, value in given[1:]:
            if not _same(value0, value):
                warnings.append(f"{field}: {label0} gives {value0!r}, {label} gives {value!r}; "
                                f"used the {label0}'s")
    if "layer" not in chosen:
        sample = str(chosen.get("sample", ""))
        m = re.match(r"^([A-Za-z]+)\d", sample)
        if m:
            chosen["layer"] = m.group(1)
        elif folder:
            chosen["layer"] = _layer_from_folder(folder)
            warnings.append(f"layer taken from the folder name {folder!r}")
    if folder and "layer" in chosen:
        hint = _layer_from_folder(folder)
        if len(hint) <= 3 and hint.lower() != str(chosen["layer"]).strip().lower():
            warnings.append(f"file is in folder {folder!r} but its layer is {chosen['layer']!r}")
    missing = [f for f in ("sample", "test") if f not in chosen]
    return chosen, warnings, missing


# ============================================================================ signals
def _mad_sigma(x: np.ndarray) -> float:
    if len(x) == 0:
        return 0.0
    return 1.4826 * float(np.median(np.abs(x - np.median(x))))


def _noise(x: np.ndarray) -> float:
    """Noise level of a sampled signal from its second differences (robust, trend-free).

    For white noise of standard deviation sigma, x[i+1] - 2 x[i] + x[i-1] has standard
    deviation sqrt(6) sigma; a smooth signal sampled densely adds little to it. A quantised,
    noise-free signal gets a quarter of its smallest step, so thresholds never collapse to 0.
    """
    if len(x) < 5:
        return _floor(x)
    d2 = np.diff(x, 2)
    s = _mad_sigma(d2) / math.sqrt(6.0)
    return max(s, _floor(x))


def _floor(x: np.ndarray) -> float:
    steps = np.abs(np.diff(x))
    steps = steps[steps > 0]
    scale = float(np.max(np.abs(x))) if len(x) else 0.0
    tiny = 1e-12 * (1.0 + scale)
    return max(float(steps.min()) / 4.0, tiny) if len(steps) else tiny


def _clean_time(t, d, f, lines):
    """Drop incomplete rows, order by time within jitter, merge repeated stamps, list gaps."""
    warnings: list[str] = []
    ok = np.isfinite(t) & np.isfinite(d) & np.isfinite(f)
    if not ok.all():
        dropped = lines[~ok]
        warnings.append(f"dropped {len(dropped)} rows with a missing or non-numeric value "
                        f"(lines {_listed(dropped)})")
        t, d, f, lines = t[ok], d[ok], f[ok], lines[ok]
    if len(t) < MIN_POINTS:
        raise CycleRejected(f"fewer than {MIN_POINTS} points: {len(t)} complete data rows")
    dt = np.diff(t)
    forward = dt[dt > 0]
    if len(forward) == 0:
        raise CycleRejected("time does not advance: every time stamp is the same")
    h = float(np.median(forward))
    glitch = _time_glitches(t, 2.0 * h)
    if len(glitch) and len(glitch) <= max(2, len(t) // 100):
        warnings.append(f"dropped {len(glitch)} rows whose time stamp is out of line with both "
                        f"neighbours (lines {_listed(lines[glitch])})")
        keep = np.ones(len(t), dtype=bool)
        keep[glitch] = False
        t, d, f, lines = t[keep], d[keep], f[keep], lines[keep]
        dt = np.diff(t)
    back = np.flatnonzero(dt < 0)
    if len(back):
        worst = back[np.argmin(dt[back])]
        if -dt[worst] > 2.0 * h:
            raise CycleRejected(
                f"non-monotonic time: time steps back {-dt[worst]:.6g} s (from {t[worst]:.6g} "
                f"to {t[worst + 1]:.6g} s) at line {lines[worst + 1]}, more than twice the "
                f"sampling interval {h:.3g} s"
            )
        order = np.argsort(t, kind="stable")
        t, d, f, lines = t[order], d[order], f[order], lines[order]
        warnings.append(f"{len(back)} time stamps out of order by less than two sampling "
                        f"intervals (jitter); rows put in time order")
    uniq, first, counts = np.unique(t, return_index=True, return_counts=True)
    if len(uniq) < len(t):
        inverse = np.repeat(np.arange(len(uniq)), counts)
        d_mean = np.bincount(inverse, weights=d) / counts
        f_mean = np.bincount(inverse, weights=f) / counts
        same = (d == d_mean[inverse]) & (f == f_mean[inverse])
        group_same = np.bincount(inverse, weights=(~same).astype(float)) == 0
        multi = counts > 1
        n_dup = int(np.sum(counts[multi & group_same] - 1))
        n_avg = int(np.sum(multi & ~group_same))
        if n_dup:
            warnings.append(f"dropped {n_dup} exact duplicate rows")
        if n_avg:
            warnings.append(f"{n_avg} repeated time stamps with differing readings; "
                            f"readings averaged")
        t, d, f, lines = uniq, d_mean, f_mean, lines[first]
    if len(t) < MIN_POINTS:
        raise CycleRejected(f"fewer than {MIN_POINTS} points: {len(t)} distinct time stamps")
    spikes = np.union1d(_spikes(d), _spikes(f))
    if len(spikes) > max(2, len(t) // 100):
        raise CycleRejected(f"too many isolated spikes to be a rig log: {len(spikes)} samples "
                            f"jump away from both neighbours and back")
    if len(spikes):
        warnings.append(f"dropped {len(spikes)} isolated spikes in the displacement or force "
                        f"(lines {_listed(lines[spikes])})")
        keep = np.ones(len(t), dtype=bool)
        keep[spikes] = False
        t, d, f, lines = t[keep], d[keep], f[keep], lines[keep]
    dt = np.diff(t)
    gaps = np.flatnonzero(dt > 5.0 * h)
    if len(gaps):
        shown = "; ".join(f"{dt[g]:.4g} s after t = {t[g]:.6g} s" for g in gaps[:3])
        more = f" and {len(gaps) - 3} more" if len(gaps) > 3 else ""
        warnings.append(f"{len(gaps)} gaps in the time stamps longer than five sampling "
                        f"intervals ({h:.3g} s): {shown}{more}")
    return t, d, f, lines, warnings


def _listed(values, limit=5) -> str:
    shown = ", ".join(str(v) for v in values[:limit])
    return shown + (" ..." if len(values) > limit else "")


def _time_glitches(t: np.ndarray, jitter: float) -> np.ndarray:
    """Rows whose time stamp is out of line with both neighbours while those agree.

    A sample is a glitch when it lies more than ``jitter`` before its predecessor or after its
    successor while the predecessor and successor are themselves in order (within jitter):
    one corrupt stamp, not a restart of the clock.
    """
    n = len(t)
    if n < 3:
        return np.array([], dtype=np.int64)
    i = np.arange(1, n - 1)
    out_of_line = (t[i] < t[i - 1] - jitter) | (t[i] > t[i + 1] + jitter)
    neighbours_ok = t[i - 1] <= t[i + 1] + jitter
    bad = list(i[out_of_line & neighbours_ok])
    if t[0] > t[1] + jitter and t[1] <= t[2] + jitter:
        bad.insert(0, 0)
    if t[-1] < t[-2] - jitter and t[-3] <= t[-2] + jitter:
        bad.append(n - 1)
    return np.array(bad, dtype=np.int64)


def _spikes(x: np.ndarray) -> np.ndarray:
    """Find samples that jump away from both neighbours (same direction) and straight back.

    The jump on both sides must exceed 20 noise levels and five times the larger of the two
    neighbouring steps (``x[i-1] - x[i-2]``, ``x[i+2] - x[i+1]``): at a sharp peak of the
    travel or force the jump is about one neighbouring step, at a sensor glitch many.
    """
    n = len(x)
    if n < 7:
        return np.array([], dtype=np.int64)
    i = np.arange(2, n - 2)
    up, down = x[i] - x[i - 1], x[i] - x[i + 1]
    jump = np.minimum(np.abs(up), np.abs(down))
    beside = np.maximum(np.abs(x[i - 1] - x[i - 2]), np.abs(x[i + 2] - x[i + 1]))
    spike = (np.sign(up) == np.sign(down)) & (jump > 20.0 * _noise(x)) & (jump > 5.0 * beside)
    return i[spike]


def _hinge_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Least-squares ``y = a + k max(x - c, 0)``: the kink ``c``, level ``a`` and slope ``k``.

    The best kink at the sample abscissae comes from suffix sums in O(n log n); it is then
    refined continuously between its neighbours. Returns ``k = 0`` if no rising fit exists.
    """
    order = np.argsort(x, kind="stable")
    x0 = float(x[order[0]])
    y0 = float(np.median(y))
    xs = x[order] - x0
    ys = y[order] - y0
    n = len(xs)
    if n < 4 or xs[-1] <= 0:
        return x0, y0, 0.0

    def suffix(a):
        return np.concatenate([np.cumsum(a[::-1])[::-1], [0.0]])

    s1, s2, sxy, sy_ = suffix(xs), suffix(xs * xs), suffix(xs * ys), suffix(ys)
    m = np.arange(n - 2)               # kink at xs[m]; at least two samples after it
    c = xs[m]
    nr = n - m - 1
    sz = s1[m + 1] - c * nr
    szz = s2[m + 1] - 2.0 * c * s1[m + 1] + c * c * nr
    szy = sxy[m + 1] - c * sy_[m + 1]
    sy, syy = ys.sum(), (ys * ys).sum()
    var_z = szz - sz * sz / n
    cov = szy - sz * sy / n
    good = var_z > 1e-12 * max(float(np.max(var_z)), 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = np.where(good, cov / np.where(good, var_z, 1.0), 0.0)
        sse = np.where(good & (slope > 0), syy - sy * sy / n - cov * slope, np.inf)
    if not np.isfinite(sse).any():
        return x0, y0, 0.0
    best = int(np.argmin(sse))

    def fit(cc):
        z = np.maximum(xs - cc, 0.0)
        zm = z.mean()
        vz = float(np.sum((z - zm) ** 2))
        if vz <= 0:
            return np.inf, float(ys.mean()), 0.0
        k = float(np.sum((z - zm) * (ys - ys.mean()))) / vz
        a = float(ys.mean() - k * zm)
        r = ys - a - k * z
        return float(r @ r), a, k

    lo = c[max(best - 1, 0)]
    hi = c[min(best + 1, len(c) - 1)]
    cc = float(c[best])
    if hi > lo:
        # golden-section search on the continuous kink between the neighbouring samples
        g = (math.sqrt(5.0) - 1.0) / 2.0
        a_, b_ = float(lo), float(hi)
        p, q = b_ - g * (b_ - a_), a_ + g * (b_ - a_)
        fp, fq = fit(p)[0], fit(q)[0]
        for _ in range(60):
            if fp <= fq:
                b_, q, fq = q, p, fp
                p = b_ - g * (b_ - a_)
                fp = fit(p)[0]
            else:
                a_, p, fp = p, q, fq
                q = a_ + g * (b_ - a_)
                fq = fit(q)[0]
            if b_ - a_ < 1e-12 * (1.0 + abs(b_)):
                break
        cand = (a_ + b_) / 2.0
        if fit(cand)[0] <= fit(cc)[0]:
            cc = cand
    _, a, k = fit(cc)
    return cc + x0, a + y0, k


def contact_fit_bias(force_of_travel: Callable[[np.ndarray], np.ndarray], peak_travel_mm: float,
                     approach_mm: float = 0.2, n_rise: int = 200) -> float:
    """Where step 8's contact fit puts the contact of a noise-free curve (mm after its touch).

    The hinge fit draws a straight rise through the start of a curve that is not straight
    (a bonded Ogden sample stiffens from its first strain on), so on a smooth curve it finds
    the contact a few micrometres late (3.6-4.2 um for the default sample, alpha 4.9, as
    finely as its curve is resolved; 7.5 um at alpha 2; 17 um on a 12 mm tall sample), and
    every travel measured from it is short by as much. ``calib.fit`` can read its
    simulations through the same fit (``FitSettings.contact_fit``). The fit is invariant to
    the scale of the force; the window is 10 % of the force at ``peak_travel_mm`` (the noise
    floor of the window, 25 noise levels, is left out: it matters only for cycles whose peak
    force is below 250 noise levels). Noise and coarse sampling add their own error, not
    modelled here: at 6 mm/s and 200 Hz with 3 mN of white noise the contact came out 11 um
    early on average (30 seeded logs), at 0.17 mm/s and 50 Hz 2.4 um late.

    Parameters
    ----------
    force_of_travel : callable
        Force (any unit) of the travel from the touch (mm), zero at zero travel, rising.
    peak_travel_mm : float
        Peak travel of the branch (mm).
    approach_mm : float
        Length of the flat approach before the touch that the fit sees (the result moves by
        1e-4 mm between 0.05 and 2 mm).
    n_rise : int
        Samples along the rise up to the window's end.
    """
    grid = np.linspace(0.0, peak_travel_mm, 2001)
    force = np.asarray(force_of_travel(grid), float)
    level = _CONTACT_WINDOW * float(force[-1])
    if not (np.isfinite(level) and level > 0.0):
        raise ValueError("contact_fit_bias: the curve does not rise")
    end = float(grid[int(np.argmax(force >= level))])
    step = end / n_rise
    x = np.arange(-approach_mm, end + 0.5 * step, step)
    y = np.where(x > 0.0, np.asarray(force_of_travel(np.maximum(x, 0.0)), float), 0.0)
    return _hinge_fit(x, y)[0]


def _branch(t, d, f, lines):
    """Sign convention, peak travel, contact, tare and the loading branch (steps 6-9)."""
    warnings: list[str] = []
    n = len(t)
    k0 = max(3, min(n // 20, 25))
    fs = median_filter(f, size=5, mode="nearest")
    ds = median_filter(d, size=5, mode="nearest")
    f_start = float(np.median(f[:k0]))
    i_fpk = int(np.argmax(np.abs(fs - f_start)))
    if fs[i_fpk] == f_start:
        raise CycleRejected("no loading branch: the force never changes")
    s_f = 1 if fs[i_fpk] > f_start else -1
    moved = float(ds[i_fpk] - d[0])
    excursion = ds - d[0]
    i_far = int(np.argmax(np.abs(excursion)))
    if moved == 0.0:
        if excursion[i_far] == 0.0:
            raise CycleRejected("no loading branch: the platen does not move")
        moved = float(excursion[i_far])
        warnings.append("the force peak is where the platen started; the direction of "
                        "compression was taken from the largest platen excursion")
    s_d = 1 if moved > 0 else -1
    D = s_d * (d - d[0])
    F = s_f * f
    Ds = s_d * (ds - d[0])
    sigma_d = _noise(D)

    d_max = float(Ds.max())
    if d_max <= 10.0 * sigma_d:
        raise CycleRejected(f"no loading branch: the platen travel ({d_max:.3g} mm) is within "
                            f"the displacement noise ({sigma_d:.2g} mm)")
    if float(-Ds.min()) > 0.5 * d_max:
        warnings.append(f"the platen also moves {float(-Ds.min()):.3g} mm away from the "
                        f"sample, more than half the compression travel")
    high = Ds >= 0.9 * d_max
    i_hi0 = int(np.argmax(high))
    below = np.flatnonzero(~high[i_hi0:])
    run_end = i_hi0 + (int(below[0]) if len(below) else n - i_hi0)
    local_max = float(D[i_hi0:run_end].max())
    tol = max(4.0 * sigma_d, 1e-9 * (1.0 + abs(local_max)))
    i_pk = i_hi0 + int(np.argmax(D[i_hi0:run_end] >= local_max - tol))
    if run_end < n:
        after = Ds[run_end:]
        dropped_low = np.flatnonzero(after < 0.5 * d_max)
        if len(dropped_low) and (after[dropped_low[0]:] >= 0.9 * d_max).any():
            j = run_end + dropped_low[0] + int(np.argmax(after[dropped_low[0]:] >= 0.9 * d_max))
            warnings.append(f"the log loads again after unloading (back above 90 % of the peak "
                            f"travel at t = {t[j]:.6g} s); only the first loading was used, the "
                            f"rest is in the unloading span")

    # contact: two-segment fit over the start of the rise
    Fw, Dw = F[: i_pk + 1], D[: i_pk + 1]
    Fws = s_f * fs[: i_pk + 1]
    base = float(np.median(Fw[: min(k0, len(Fw))]))
    sigma_glob = _noise(F)
    rise = float(Fws.max()) - base
    if rise <= 0:
        raise CycleRejected("no loading branch: the force does not rise while the platen "
                            "advances")
    level = max(_CONTACT_WINDOW * rise, min(_CONTACT_WINDOW_NOISE * sigma_glob, 0.5 * rise))
    i_win = int(np.argmax(Fws - base >= level))
    i_win = min(max(i_win, 6), i_pk)
    c, a, k = _hinge_fit(Dw[: i_win + 1], Fw[: i_win + 1])
    if k <= 0:
        raise CycleRejected("no loading branch: the force does not rise with platen travel")
    # first sample past contact: after the last sample whose smoothed travel is at or before
    # it, so displacement noise near a slow contact cannot cut the approach short
    Dws = Ds[: i_pk + 1]
    not_past = np.flatnonzero(Dws[: i_win + 1] <= c)
    i_c = int(not_past[-1]) + 1 if len(not_past) else 0
    if i_c >= _MIN_APPROACH:
        approach = F[:i_c]
        tare = float(np.median(approach))
        sigma = _mad_sigma(approach) if i_c >= _MIN_APPROACH_NOISE else sigma_glob
        sigma = max(sigma, _floor(F))
    else:
        tare = float(F[0])
        sigma = sigma_glob
    net = Fw - tare
    peak_net = float(np.max(s_f * fs[: i_pk + 1] - tare))
    if peak_net < _MIN_SIGNAL_NOISE * sigma:
        raise CycleRejected(f"no loading branch: force never rises clearly above the noise "
                            f"(peak {peak_net:.3g} N above the tare, noise {sigma:.2g} N)")
    quiet = np.flatnonzero(net <= _THRESHOLD_NOISE * sigma)
    i_thr = int(quiet[-1]) + 1 if len(quiet) else 0
    if i_thr > i_pk:
        raise CycleRejected("no loading branch: force never rises persistently above the "
                            "noise before peak travel")
    i_toe = i_c  # first sample of a toe (none: the approach ends at contact)
    if i_c >= _MIN_APPROACH and i_thr >= 1 and c > Dws[i_thr]:
        # a toe: the force rose for good before the back-extrapolated contact (a domed or
        # tilted face, slack). Travel is measured from that contact, the toe-compensated zero
        # of ASTM practice (D695), which a noise-free curve's reading shares
        # (contact_fit_bias); the toe is trimmed, and the tare and noise are read before it
        i_toe = i_thr
        tare = float(np.median(F[:i_toe]))
        if i_toe >= _MIN_APPROACH_NOISE:
            sigma = max(_mad_sigma(F[:i_toe]), _floor(F))

    if i_c >= _MIN_APPROACH:
        j = i_c
        dx = D[j] - D[j - 1]
        w = (c - D[j - 1]) / dx if dx > 0 else 1.0
        w = min(max(w, 0.0), 1.0)
        t_c = t[j - 1] + w * (t[j] - t[j - 1])
        f_c = (F[j - 1] + w * (F[j] - F[j - 1])) - tare
        time = np.concatenate([[0.0], t[j: i_pk + 1] - t_c])
        disp = np.concatenate([[0.0], D[j: i_pk + 1] - c])
        force = np.concatenate([[f_c], F[j: i_pk + 1] - tare])
        contact = c
        trimmed = [Span("approach", float(t[0]), float(t[i_toe - 1]), i_toe)]
        if i_toe < j:
            trimmed.append(Span("toe", float(t[i_toe]), float(t[j - 1]), j - i_toe))
            warnings.append(
                f"a toe: the force rose above five noise levels {c - Dws[i_toe - 1]:.3f} mm "
                f"before the contact back-extrapolated from the initial rise, and is "
                f"{f_c:.3g} N there; travel is measured from that contact (the toe-compensated "
                f"zero) and the toe's {j - i_toe} samples are trimmed")
    else:
        warnings.append(f"no approach segment: the force is already above the noise near the "
                        f"first sample, so contact was taken at the first sample and the tare "
                        f"({tare:.4g} N) is the first force reading, not a measured offset")
        contact = 0.0
        time = t[: i_pk + 1] - t[0]
        disp = D[: i_pk + 1]
        force = F[: i_pk + 1] - tare
        trimmed = []
    hold_tol = max(5.0 * sigma_d, 0.002 * local_max)
    if i_pk + 1 < n:
        rest = D[i_pk + 1:]
        leaving = np.flatnonzero(rest < local_max - hold_tol)
        n_hold = int(leaving[0]) if len(leaving) else len(rest)
        if n_hold:
            trimmed.append(Span("hold", float(t[i_pk + 1]), float(t[i_pk + n_hold]), n_hold))
        if i_pk + 1 + n_hold < n:
            trimmed.append(Span("unloading", float(t[i_pk + 1 + n_hold]), float(t[-1]),
                                n - (i_pk + 1 + n_hold)))
    return {
        "time": time, "disp": disp, "force": force, "tare": tare, "contact": float(contact),
        "sign": {"displacement": s_d, "force": s_f}, "trimmed": trimmed, "warnings": warnings,
        "noise_N": sigma,
    }


# ============================================================================ one file
def _relative(path: Path, root: Path | None) -> str:
    if root is not None:
        try:
            return path.resolve().relative_to(root.resolve()).as_posix()
        except ValueError:
            pass
    return path.name


def load_cycle(path, root=None, manifest_row: Mapping | None = None) -> Cycle:
    """Load one rig log as a validated loading branch.

    Parameters
    ----------
    path : str or path-like
        The log file.
    root : str or path-like, optional
        The campaign folder; ``Cycle.file`` is relative to it (default: the file's folder).
        A file in a sub-folder of ``root`` may take its layer from the folder's name.
    manifest_row : mapping, optional
        The file's row of a ``manifest.csv`` (keys ``layer, sample, test, rate_mm_per_s,
        diameter_mm, height_mm``; values as text or numbers). It wins over the file's header.

    Returns
    -------
    Cycle

    Raises
    ------
    CycleRejected
        The file cannot be read as a cycle; ``.reason`` says why.

    Notes
    -----
    The steps and their thresholds are listed in the module docstring.
    """
    path = Path(path)
    root = Path(root) if root is not None else path.parent
    rel = _relative(path, root)
    parts = rel.split("/")
    folder = parts[-2] if len(parts) >= 2 else None
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise CycleRejected(f"cannot read the file: {exc.strerror or exc}") from None
    if size > MAX_FILE_BYTES:
        raise CycleRejected(f"file too large to be a rig log ({size} bytes)")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise CycleRejected(f"cannot read the file: {exc.strerror or exc}") from None
    text, warnings = _decode(raw)
    table = _parse_table(text)
    warnings += table.warnings
    cols, col_warnings = _columns(table.header)
    warnings += col_warnings

    meta, meta_warnings, missing = _resolve_metadata(
        _metadata_from(table.meta), _metadata_from(manifest_row) if manifest_row else None,
        _metadata_from_name(path.name), folder, "manifest.csv")
    warnings += meta_warnings
    if missing:
        raise CycleRejected(
            f"missing metadata that cannot be inferred: {', '.join(missing)} (no '# "
            f"{missing[0]}:' header line, no manifest.csv row, and the file name does not "
            f"follow the pattern A1_t2_0.83mms.csv)")

    values = {}
    for role in _ROLES:
        k, header, unit, factor = cols[role]
        column = table.values[:, k]
        if len(column) and np.isnan(column).all():
            raise CycleRejected(f"all-NaN column: {role} ({header!r}) has no numeric value")
        values[role] = column * factor
    if len(table.values) < MIN_POINTS:
        raise CycleRejected(f"fewer than {MIN_POINTS} points: {len(table.values)} data rows")
    if len(table.bad_lines) > len(table.values) // 2:
        raise CycleRejected(f"mostly unreadable rows: {len(table.bad_lines)} of "
                            f"{len(table.values)} data rows do not parse")
    t, d, f, lines, time_warnings = _clean_time(values["time"], values["displacement"],
                                                values["force"], table.lines)
    warnings += time_warnings

    b = _branch(t, d, f, lines)
    warnings += b["warnings"]

    sample = str(meta["sample"]).strip()
    layer = str(meta["layer"]).strip()
    test_raw = str(meta["test"]).strip()
    m = re.fullmatch(r"(?i)(?:t|test)?\s*(\d+)(?:\.0*)?", test_raw)
    if not m:
        raise CycleRejected(f"bad metadata: test = {meta['test']!r} is not a whole number")
    test = int(m.group(1))
    diameter = _field(meta, "diameter_mm", "length", DEFAULT_DIAMETER_MM, warnings)
    height = _field(meta, "height_mm", "length", DEFAULT_HEIGHT_MM, warnings)
    target = TARGET_STRAIN
    if "strain" in meta:
        target = _quantity(meta["strain"], "strain", "strain")
        if target > 1.0:
            warnings.append(f"strain {meta['strain']!r} read as a percentage")
            target /= 100.0
        if not 0.0 < target < 1.0:
            raise CycleRejected(f"bad metadata: strain = {meta['strain']!r} is not a fraction "
                                f"between 0 and 1")

    time, disp, force = b["time"], b["disp"], b["force"]
    if len(time) < MIN_POINTS:
        raise CycleRejected(f"fewer than {MIN_POINTS} points in the loading branch "
                            f"({len(time)} from contact to peak travel)")
    duration = float(time[-1] - time[0])
    if duration <= 0:
        raise CycleRejected("no loading branch: time does not advance from contact to peak")
    speed = float(disp[-1] - disp[0]) / duration
    if "rate_mm_per_s" in meta:
        rate = _quantity(meta["rate_mm_per_s"], "rate", "rate_mm_per_s")
        if not (rate > 0 and math.isfinite(rate)):
            raise CycleRejected(f"bad metadata: rate_mm_per_s = {meta['rate_mm_per_s']!r} must "
                                f"be positive")
        if abs(speed - rate) > _RATE_WARN * rate:
            warnings.append(f"mean platen speed over the loading branch is {speed:.4g} mm/s, "
                            f"stated rate {rate:.4g} mm/s")
    else:
        rate = float(f"{speed:.3g}")
        warnings.append(f"rate_mm_per_s not given; measured mean platen speed {rate:.3g} mm/s "
                        f"used")
    peak = float(disp.max()) / height
    off = abs(peak - target)
    if off > STRAIN_REJECT:
        raise CycleRejected(
            f"peak strain {peak:.3f} far from the stated {target:.2f} (tolerance "
            f"+-{STRAIN_REJECT}; travel {disp.max():.3f} mm from contact, height {height:g} mm)")
    if off > STRAIN_WARN:
        warnings.append(f"peak strain {peak:.3f} differs from the stated {target:.2f} by more "
                        f"than {STRAIN_WARN}")
    return Cycle(
        file=rel, layer=layer, sample=sample, test=test, rate_mm_per_s=rate,
        diameter_mm=diameter, height_mm=height, time_s=time, displacement_mm=disp,
        force_N=force, sign=b["sign"], tare_N=b["tare"], contact_mm=b["contact"],
        warnings=tuple(warnings), trimmed=tuple(b["trimmed"]),
        units={r: cols[r][2] for r in _ROLES}, columns={r: cols[r][1] for r in _ROLES},
    )


def _field(meta: dict, key: str, kind: str, default: float, warnings: list) -> float:
    if key not in meta:
        warnings.append(f"{key} not given; default {default:g} mm used")
        return default
    value = _quantity(meta[key], kind, key)
    if not (value > 0 and math.isfinite(value)):
        raise CycleRejected(f"bad metadata: {key} = {meta[key]!r} must be positive")
    return value


# ============================================================================ campaign
def _read_manifest(path: Path) -> list[dict]:
    """Rows of a ``manifest.csv`` as dicts of text; raises CycleRejected if unreadable."""
    text, _ = _decode(path.read_bytes())
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise CycleRejected("empty manifest")
    for sep in ("\t", ";", ",", "|"):
        header = [_norm_key(c) for c in _split(lines[0], sep)]
        if "file" in header:
            break
    else:
        raise CycleRejected("manifest has no 'file' column")
    rows = []
    for ln in lines[1:]:
        cells = [c.strip().strip("\"'").strip() for c in _split(ln, sep)]
        row = {h: (cells[i] if i < len(cells) else "") for i, h in enumerate(header) if h}
        if row.get("file"):
            rows.append(row)
    return rows


def _discover(root: Path) -> tuple[list[Path], list[Rejection], list[str]]:
    files: list[Path] = []
    rejected: list[Rejection] = []
    hidden: list[str] = []

    def entries(folder: Path):
        try:
            return sorted(folder.iterdir(), key=lambda p: p.name)
        except OSError as exc:
            rejected.append(Rejection(_relative(folder, root) + "/",
                                      f"cannot list the folder: {exc.strerror or exc}"))
            return []

    for p in entries(root):
        if p.name.startswith("."):
            hidden.append(p.name)
        elif p.is_dir():
            for q in entries(p):
                if q.name.startswith("."):
                    hidden.append(f"{p.name}/{q.name}")
                elif q.is_dir():
                    rejected.append(Rejection(f"{p.name}/{q.name}/",
                                              "folder nested deeper than one level; its files "
                                              "were not read"))
                elif q.is_file():
                    files.append(q)
        elif p.is_file():
            files.append(p)
    return files, rejected, hidden


def load_campaign(path) -> Campaign:
    """Load every rig log in a folder (and its sub-folders, one level deep).

    Parameters
    ----------
    path : str or path-like
        The campaign folder.

    Returns
    -------
    Campaign
        Cycles sorted by file; every file, manifest entry or folder that was not loaded is in
        ``rejected`` with its reason. Hidden files (``.name``) are skipped and named in
        ``notes``.

    Raises
    ------
    FileNotFoundError, NotADirectoryError
        ``path`` does not exist or is not a folder. Nothing else: a file that cannot be
        loaded, for any reason, becomes a :class:`Rejection`.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> load_campaign(folder).report()
    {'cycles': [], 'rejected': []}
    """
    root = Path(path)
    if not root.exists():
        raise FileNotFoundError(f"{root}: no such folder")
    if not root.is_dir():
        raise NotADirectoryError(f"{root}: not a folder")
    files, rejected, hidden = _discover(root)
    notes: list[str] = []
    if hidden:
        notes.append(f"skipped {len(hidden)} hidden entries: {', '.join(hidden[:5])}"
                     + (" ..." if len(hidden) > 5 else ""))

    manifest_rows: dict[str, dict] = {}
    data_files = []
    by_name: dict[str, list[str]] = {}
    for p in files:
        rel = _relative(p, root)
        if p.name.lower() == "manifest.csv":
            continue
        data_files.append(p)
        by_name.setdefault(p.name, []).append(rel)
    data_rel = {_relative(q, root) for q in data_files}
    for p in files:
        if p.name.lower() != "manifest.csv":
            continue
        mrel = _relative(p, root)
        base = mrel.rpartition("/")[0]
        try:
            rows = _read_manifest(p)
        except CycleRejected as exc:
            rejected.append(Rejection(mrel, f"manifest not used: {exc.reason}"))
            continue
        except Exception as exc:  # noqa: BLE001 - a bad manifest must not stop the campaign
            rejected.append(Rejection(mrel, f"manifest not used: unexpected error "
                                            f"{type(exc).__name__}: {exc}"))
            continue
        matched = 0
        for row in rows:
            listed = row["file"].replace("\\", "/").strip("/")
            target = f"{base}/{listed}" if base else listed
            if target not in data_rel:
                candidates = by_name.get(listed.rpartition("/")[2], [])
                if len(candidates) == 1:
                    target = candidates[0]
                else:
                    rejected.append(Rejection(target, f"listed in {mrel} but no such file"))
                    continue
            if target in manifest_rows:
                notes.append(f"{target}: listed twice in manifests; the first row used")
                continue
            manifest_rows[target] = row
            matched += 1
        notes.append(f"{mrel}: {matched} of {len(rows)} rows matched a file and were used as "
                     f"metadata (a manifest row wins over the file header)")

    cycles: list[Cycle] = []
    for p in data_files:
        rel = _relative(p, root)
        suffix = p.suffix.lower()
        if suffix in _WORKBOOKS:
            rejected.append(Rejection(rel, f"spreadsheet workbook ({suffix}) not read: export "
                                           f"the sheet as CSV"))
            continue
        if suffix in _NOT_LOGS:
            rejected.append(Rejection(rel, f"not a rig log ({suffix} file); not read"))
            continue
        try:
            cycle = load_cycle(p, root=root, manifest_row=manifest_rows.get(rel))
        except CycleRejected as exc:
            rejected.append(Rejection(rel, exc.reason))
            continue
        except Exception as exc:  # noqa: BLE001 - any file, however broken, is a rejection
            rejected.append(Rejection(rel, f"unexpected error while loading: "
                                           f"{type(exc).__name__}: {exc}"))
            continue
        cycles.append(cycle)

    defaults = sum(1 for c in cycles
                   if any(w.startswith(("diameter_mm not given", "height_mm not given"))
                          for w in c.warnings))
    if defaults:
        notes.append(f"{defaults} cycles use the default sample size "
                     f"{DEFAULT_DIAMETER_MM:g} mm x {DEFAULT_HEIGHT_MM:g} mm")
    keys: dict[tuple, list[str]] = {}
    for c in cycles:
        keys.setdefault((c.sample, c.test, round(c.rate_mm_per_s, 6)), []).append(c.file)
    for (sample, test, rate), fs in keys.items():
        if len(fs) > 1:
            notes.append(f"sample {sample} test {test} at {rate:g} mm/s appears in "
                         f"{len(fs)} files: {', '.join(fs)}")
    cycles.sort(key=lambda c: c.file)
    rejected.sort(key=lambda r: r.file)
    return Campaign(root=os.fspath(root), cycles=tuple(cycles), rejected=tuple(rejected),
                    notes=tuple(notes))
