"""Drive cycles: the standard cycles shipped with vpsim, and user CSV files.

    >>> from vpsim.cycles import load_cycle
    >>> c = load_cycle("nedc")
    >>> round(c.distance_m / 1000, 2)
    11.01

A cycle is a speed trace sampled at strictly increasing times, piecewise linear between samples. The
shipped cycles are written by ``tools/build_cycles.py`` from public sources; ``data/SOURCES.md`` records
where each number came from.
"""

from __future__ import annotations

import csv
import functools
import io
import math
import os
import re
from array import array
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from ..errors import CycleError
from ..textio import check_path, read_text
from ..units import MPH_TO_MPS

STANDARD_CYCLES = ("nedc", "ftp75", "udds", "hwfet", "us06", "wltc3b")
# phases of a standard cycle, by name: (cycle, start s, end s), time re-based to 0. FTP-75's bags as the
# certification list reports them: bag 2 is UDDS 505-1369 s (hot stabilised), bag 3 the first 505 s again,
# driven after a 10-minute soak (the model has no engine temperature: it runs hot, like bag 2; the cold
# bag 1 is the same trace and is therefore not offered)
PHASES = {"ftp_bag2": ("udds", 505.0, 1369.0), "ftp_bag3": ("udds", 0.0, 505.0)}
_ALIASES = {
    "wltc": "wltc3b",
    "wltc_class3b": "wltc3b",
    "ftp": "ftp75",
    "ftp-75": "ftp75",
    "wltc3": "wltc3b",
    "hwy": "hwfet",  # the name of the highway test in a certification list (and vpsim fleet)
    "hfet": "hwfet",
}

_KMH = 1.0 / 3.6
_SPEED_UNITS = {"m/s": 1.0, "mps": 1.0, "km/h": _KMH, "kmh": _KMH, "kph": _KMH, "mph": MPH_TO_MPS}
_TIME_COLUMNS = ("time_s", "time", "t", "t_s")
MAX_CYCLE_BYTES = 64 * 1024 * 1024  # a cycle CSV larger than this is refused (a month of 1 Hz samples fits)
MAX_SPEED_MPS = 200.0  # 720 km/h: faster is a unit slip (speed in km/h declared as m/s) or a broken file
MAX_TIME_S = 1.0e9  # about 32 years: larger times are not a drive cycle
MIN_STEP_S = 1.0e-3  # samples closer than 1 ms (1 kHz) are not a drive cycle's: times in ms, or noise
_DELIMITERS = (",", ";", "\t")
# fuel per distance (L/100 km) is reported for cycles that drive at least this far; on less it is noise
MIN_CONSUMPTION_DISTANCE_M = 1.0
_SPEED_COLUMNS = {
    "speed_mps": "m/s",
    "speed_m_per_s": "m/s",
    "speed_kmh": "km/h",
    "speed_km_per_h": "km/h",
    "speed_kph": "km/h",
    "speed_mph": "mph",
}


@dataclass(frozen=True)
class Cycle:
    """A speed trace: ``time_s`` strictly increasing, ``speed_mps`` >= 0, piecewise linear in between."""

    name: str
    time_s: np.ndarray
    speed_mps: np.ndarray
    source: str = field(default="", compare=False)

    def __post_init__(self):
        t = np.asarray(self.time_s, dtype=float)
        v = np.asarray(self.speed_mps, dtype=float)
        t.setflags(write=False)
        v.setflags(write=False)
        object.__setattr__(self, "time_s", t)
        object.__setattr__(self, "speed_mps", v)
        _check_arrays(t, v, self.name)

    def __eq__(self, other) -> bool:
        # the generated dataclass __eq__ compares the arrays with ``==`` and fails on arrays of size > 1
        if not isinstance(other, Cycle):
            return NotImplemented
        return (
            self.name == other.name
            and np.array_equal(self.time_s, other.time_s)
            and np.array_equal(self.speed_mps, other.speed_mps)
        )

    def __hash__(self) -> int:
        return hash((self.name, self.time_s.tobytes(), self.speed_mps.tobytes()))

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])

    @property
    def distance_m(self) -> float:
        """Distance of the piecewise-linear trace (trapezoidal integral), m."""
        return float(np.sum(0.5 * (self.speed_mps[1:] + self.speed_mps[:-1]) * np.diff(self.time_s)))

    @property
    def max_speed_kmh(self) -> float:
        return float(self.speed_mps.max() * 3.6)

    def speed_at(self, t):
        """Speed of the piecewise-linear trace at times ``t`` (0 outside the cycle)."""
        return np.interp(t, self.time_s, self.speed_mps, left=0.0, right=0.0)

    def repeat(self, n: int) -> Cycle:
        """The cycle driven ``n`` times back to back (the joining sample is not duplicated).

        The last sample of one copy is the first sample of the next, so the cycle must end at the speed it
        starts with (all standard cycles start and end at standstill); otherwise :class:`CycleError`.
        """
        if isinstance(n, bool) or not isinstance(n, int | np.integer):
            raise CycleError(f"repeat count must be an integer >= 1, got {n!r}")
        if n < 1:
            raise CycleError(f"repeat count must be >= 1, got {n}")
        if n > 1 and self.speed_mps[-1] != self.speed_mps[0]:
            raise CycleError(
                f"{self.name}: cannot repeat a cycle that ends at {self.speed_mps[-1]:g} m/s but starts at "
                f"{self.speed_mps[0]:g} m/s; the copies would not join"
            )
        t, v = [self.time_s], [self.speed_mps]
        for _ in range(n - 1):
            t.append(t[-1][-1] + self.time_s[1:] - self.time_s[0])
            v.append(self.speed_mps[1:])
        return Cycle(f"{self.name}x{n}", np.concatenate(t), np.concatenate(v), self.source)

    def window(self, start_s: float, end_s: float, name: str | None = None) -> Cycle:
        """The part of the cycle on [start_s, end_s], time re-based to 0 (ends interpolated if off-grid)."""
        t, v = self.time_s, self.speed_mps
        if not (t[0] <= start_s < end_s <= t[-1]):
            raise CycleError(
                f"{self.name}: window [{start_s:g}, {end_s:g}] s is not inside the cycle "
                f"[{t[0]:g}, {t[-1]:g}] s"
            )
        inner = (t > start_s) & (t < end_s)
        tt = np.concatenate(([start_s], t[inner], [end_s]))
        vv = np.concatenate(([np.interp(start_s, t, v)], v[inner], [np.interp(end_s, t, v)]))
        return Cycle(
            name or f"{self.name}[{start_s:g}:{end_s:g}]",
            tt - start_s,
            vv,
            source=f"{self.name} from {start_s:g} s to {end_s:g} s",
        )

    def __repr__(self) -> str:
        return (
            f"Cycle({self.name!r}: {len(self.time_s)} samples, {self.duration_s:g} s, "
            f"{self.distance_m / 1000:.3f} km, max {self.max_speed_kmh:.1f} km/h)"
        )


def _check_arrays(t: np.ndarray, v: np.ndarray, where: str) -> None:
    if t.ndim != 1 or v.ndim != 1 or t.shape != v.shape:
        raise CycleError(f"{where}: time and speed must be 1-D arrays of equal length")
    if t.size < 2:
        raise CycleError(f"{where}: a cycle needs at least two samples, got {t.size}")
    for name, arr in (("time", t), ("speed", v)):
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise CycleError(f"{where}: {name} at sample {bad[0]} is {arr[bad[0]]}, expected a finite number")
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        k = bad[0] + 1
        raise CycleError(
            f"{where}: time must increase strictly; sample {k} has t = {t[k]:g} after {t[k - 1]:g}"
        )
    bad = np.flatnonzero(v < 0)
    if bad.size:
        raise CycleError(f"{where}: speed at sample {bad[0]} is {v[bad[0]]:g}, expected >= 0")


def _normalise(name: str) -> str:
    key = name.strip().lower()
    return _ALIASES.get(key, key)


def load_cycle(name_or_path: str | Path, *, speed_unit: str | None = None) -> Cycle:
    """A standard cycle by name (``nedc``, ``ftp75``, ``udds``, ``hwfet``, ``us06``, ``wltc3b``), a phase of
    one (:data:`PHASES`: ``ftp_bag2``, ``ftp_bag3``), or a CSV.

    A CSV file has a header with a time column (``time_s``) and a speed column whose name declares its unit
    (``speed_mps``, ``speed_kmh``, ``speed_mph``), or a plain ``speed`` column with ``speed_unit`` given
    (``"m/s"``, ``"km/h"``, ``"mph"``). Lines starting with ``#`` are comments. Errors name the line.
    """
    if not isinstance(name_or_path, str | os.PathLike):
        raise TypeError(
            f"a cycle is a standard cycle's name, a CSV file's path or a vpsim.cycles.Cycle, not "
            f"{type(name_or_path).__name__}; a trace held in arrays is Cycle(name, time_s, speed_mps)"
        )
    if isinstance(name_or_path, str) and _normalise(name_or_path) in STANDARD_CYCLES + tuple(PHASES):
        return _shipped(_normalise(name_or_path))
    names = ", ".join(STANDARD_CYCLES + tuple(PHASES))
    if not str(name_or_path).strip():
        raise CycleError(f"empty cycle name; standard cycles: {names} (or a CSV file)")
    path = check_path(name_or_path, CycleError, "cycle file")
    if not path.exists() and not path.is_symlink() and path.suffix == "":
        raise CycleError(f"unknown cycle {str(name_or_path)!r}; standard cycles: {names} (or a CSV file)")
    text = read_text(path, CycleError, limit=MAX_CYCLE_BYTES, what="cycle CSV file")
    return _read_csv(text, str(path), speed_unit=speed_unit, name=path.stem)


@functools.cache
def _shipped(name: str) -> Cycle:
    """A standard cycle or a phase of one, read once per process: a cycle is immutable (read-only arrays),
    so every caller can share it, and what is derived from it (kept on it) with it. Reading UDDS's CSV took
    3.7 ms, 28 times a backward run on it."""
    if name in PHASES:
        base, start, end = PHASES[name]
        return _shipped(base).window(start, end, name)
    with resources.files("vpsim.cycles").joinpath("data", f"{name}.csv").open(encoding="utf-8") as fh:
        cyc = _read_csv(fh, f"{name}.csv", speed_unit=None, name=name)
    return Cycle(
        name, cyc.time_s, cyc.speed_mps, source=f"vpsim standard cycle {name} (see cycles/data/SOURCES.md)"
    )


def _uncommented(fh):
    """The lines of ``fh`` with comment lines blanked (so a quote in a comment cannot open a CSV field)."""
    for line in fh:
        yield "\n" if line.lstrip().startswith("#") else line


def _sniff_delimiter(lines) -> str:
    """The delimiter of the first non-comment line: ``,``, else ``;`` or tab if that line holds one."""
    for line in lines:
        if line.strip() and not line.lstrip().startswith("#"):
            if "," in line:
                return ","
            for d in (";", "\t"):
                if d in line:
                    return d
            return ","
    return ","


# a decimal number as a spreadsheet writes it; Python's float() also reads "1_0" (as 10), " 1 " and "١"
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?", re.ASCII)
_NON_FINITE = {"nan", "+nan", "-nan", "inf", "+inf", "-inf", "infinity", "+infinity", "-infinity"}


def _number(text: str) -> float:
    """``text`` (stripped) as a float: digits, one point, an exponent; ``nan``/``inf`` come back as such
    for the caller's finiteness check. ValueError for anything else (``1_0``, ``0x10``, ``true``)."""
    if _NUMBER.fullmatch(text) or text.lower() in _NON_FINITE:
        return float(text)
    raise ValueError(text)


def _rows(reader, where):
    """(first line, row) of each row of a CSV ``reader``; one-line CycleError for malformed CSV or a quote
    left open (the csv module would run the field on to the next quote or the end of the file, and the
    error would name that line)."""
    start = 1
    rows = iter(reader)
    while True:
        try:
            row = next(rows)
        except StopIteration:
            return
        except csv.Error as exc:
            raise CycleError(f"{where}:{start}: malformed CSV ({exc})") from None
        if any("\n" in f or "\r" in f for f in row):
            raise CycleError(
                f"{where}:{start}: a quote opened on this line is not closed on it (the field runs on to "
                f"line {reader.line_num})"
            )
        yield start, row
        start = reader.line_num + 1


def _cut(text: str, limit: int = 40) -> str:
    """A field of a file as a short repr for a one-line message."""
    return repr(_clip(text, limit))


def _clip(text: str, limit: int = 40) -> str:
    """A field of a file cut to ``limit`` characters for a one-line message."""
    return text if len(text) <= limit else text[:limit] + "..."


def _read_csv(fh, where: str, *, speed_unit: str | None, name: str) -> Cycle:
    if speed_unit is not None and speed_unit not in _SPEED_UNITS:
        raise CycleError(f"speed unit {speed_unit!r} is not one of {', '.join(_SPEED_UNITS)}")
    text = fh if isinstance(fh, str) else fh.read()
    delim = _sniff_delimiter(io.StringIO(text))
    decimal_comma = delim == ";"  # "1,5" is 1.5 in a semicolon-separated file (European spreadsheets)
    reader = csv.reader(_uncommented(io.StringIO(text)), delimiter=delim)  # streamed: no list of lines
    header = None
    times = array("d")
    speeds = array("d")
    t_col = v_col = -1
    scale = 1.0
    for lineno, row in _rows(reader, where):
        if not row or not "".join(row).strip():
            continue
        if header is None:
            header = [h.strip().lower() for h in row]
            _check_header(header, where, lineno)
            t_col = next((header.index(c) for c in _TIME_COLUMNS if c in header), -1)
            if t_col < 0:
                raise CycleError(
                    f"{where}:{lineno}: no time column; expected one of {', '.join(_TIME_COLUMNS)} "
                    "in the header"
                )
            unit = None
            for col, u in _SPEED_COLUMNS.items():
                if col in header:
                    v_col, unit = header.index(col), u
                    break
            if v_col < 0 and "speed" in header:
                v_col = header.index("speed")
                if speed_unit is None:
                    raise CycleError(
                        f"{where}:{lineno}: column 'speed' has no declared unit; name it speed_mps / "
                        "speed_kmh / speed_mph or pass speed_unit (CLI: --speed-unit)"
                    )
                unit = speed_unit
            if v_col < 0:
                raise CycleError(
                    f"{where}:{lineno}: no speed column; expected one of {', '.join(_SPEED_COLUMNS)} "
                    "or 'speed'"
                )
            if (
                speed_unit is not None
                and _SPEED_UNITS[unit] != _SPEED_UNITS[speed_unit]
                and header[v_col] != "speed"
            ):
                raise CycleError(
                    f"{where}:{lineno}: column {header[v_col]!r} is in {unit}, but speed unit "
                    f"{speed_unit} was given"
                )
            scale = _SPEED_UNITS[unit]
            continue
        if len(row) <= max(t_col, v_col):
            raise CycleError(f"{where}:{lineno}: expected {len(header)} fields, got {len(row)}")
        vals = []
        for col, label in ((t_col, "time"), (v_col, "speed")):
            text = row[col].strip()
            try:
                x = _number(text.replace(",", ".") if decimal_comma else text)
            except ValueError:
                raise CycleError(f"{where}:{lineno}: {label} {_cut(text)} is not a number") from None
            if not math.isfinite(x):
                raise CycleError(f"{where}:{lineno}: {label} is {_clip(text)}, expected a finite number")
            vals.append(x)
        t, v = vals
        if abs(t) > MAX_TIME_S:
            raise CycleError(f"{where}:{lineno}: time {t:g} s is beyond +-{MAX_TIME_S:g} s")
        if times and t <= times[-1]:
            raise CycleError(f"{where}:{lineno}: time {t:g} does not increase (previous {times[-1]:g})")
        if times and t - times[-1] < MIN_STEP_S:
            raise CycleError(
                f"{where}:{lineno}: time {t:.10g} s is {t - times[-1]:.3g} s after the previous sample, "
                f"closer than the {MIN_STEP_S:g} s a drive cycle is sampled at (times in ms?)"
            )
        if v < 0:
            raise CycleError(f"{where}:{lineno}: speed {v:g} is negative, expected >= 0")
        if v * scale > MAX_SPEED_MPS:
            raise CycleError(
                f"{where}:{lineno}: speed {v:g} {unit} is {v * scale * 3.6:.4g} km/h, more than "
                f"{MAX_SPEED_MPS * 3.6:g} km/h (wrong unit?)"
            )
        times.append(t)
        speeds.append(v * scale)
    last = max(reader.line_num, 1)
    if header is None:
        raise CycleError(
            f"{where}:{last}: empty file (no header before the end), expected a header and samples"
        )
    if len(times) < 2:
        raise CycleError(
            f"{where}:{last}: {len(times)} sample(s) at the end of the file, a cycle needs at least two"
        )
    return Cycle(name, np.frombuffer(times, dtype=float), np.frombuffer(speeds, dtype=float), source=where)


def _check_header(header: list[str], where: str, lineno: int) -> None:
    """One time column and one speed column, each named once (otherwise the file is ambiguous)."""
    seen = set()
    for h in header:
        if h and h in seen and (h in _TIME_COLUMNS or h in _SPEED_COLUMNS or h == "speed"):
            raise CycleError(f"{where}:{lineno}: column {h!r} appears twice in the header")
        seen.add(h)
    for group, what in ((_TIME_COLUMNS, "time"), ((*_SPEED_COLUMNS, "speed"), "speed")):
        present = [h for h in group if h in seen]
        if len(present) > 1:
            raise CycleError(
                f"{where}:{lineno}: {len(present)} {what} columns ({', '.join(present)}); keep one"
            )


__all__ = ["MIN_CONSUMPTION_DISTANCE_M", "PHASES", "STANDARD_CYCLES", "Cycle", "load_cycle"]
