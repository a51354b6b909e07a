#!/usr/bin/env python
"""Build the standard drive cycles shipped with vpsim from reachable public sources.

Run by a maintainer (not at install time) from the repository root::

    python tools/build_cycles.py                      # downloads the fastsim wheel with pip
    python tools/build_cycles.py --wheel /path/to/fastsim-2.1.5-cp311-...whl
    python tools/build_cycles.py --check              # verify the committed files are up to date

It writes ``src/vpsim/cycles/data/{nedc,ftp75,udds,hwfet,us06,wltc3b}.csv`` and ``SOURCES.md``:

* ``udds``, ``hwfet``, ``us06``, ``wltc3b`` are read from the CSV members
  ``fastsim/resources/cycles/*.csv`` of the PyPI wheel ``fastsim==2.1.5`` (NREL, Apache-2.0). The wheel is
  read as a zip file (fastsim is not installed) after its sha256 has been checked against the value
  recorded below.
* ``ftp75`` is the UDDS followed by a repeat of its first 505 s (bag 3 = bag 1, no hot soak).
* ``nedc`` is computed from the mode tables of UNECE Regulation No. 83 (equivalently Directive 70/220/EEC,
  Annex III), which are written out below as data.

The output is deterministic (no dates, no machine paths), so running the script again gives identical files.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import subprocess
import sys
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA_DIR = REPO / "src" / "vpsim" / "cycles" / "data"

# ----------------------------------------------------------------------------------------------------------
# fastsim wheel
# ----------------------------------------------------------------------------------------------------------
FASTSIM_VERSION = "2.1.5"
FASTSIM_WHEEL = "fastsim-2.1.5-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl"
FASTSIM_WHEEL_SHA256 = "420c98878f29bc48bf7ac94402bc6ecaa312146a6df49c12c8906a94fe68a543"
FASTSIM_URL = "https://pypi.org/project/fastsim/2.1.5/"
FASTSIM_LICENCE = (
    "Apache-2.0; Copyright 2020 Alliance for Sustainable Energy, LLC (fastsim NOTICE file); "
    "modified by vpsim (columns renamed, grade/road type dropped, rounded to 6 decimals)"
)
# vpsim name -> (member in the wheel, long name)
FASTSIM_MEMBERS = {
    "udds": (
        "fastsim/resources/cycles/udds.csv",
        "EPA Urban Dynamometer Driving Schedule (UDDS, LA-4, FTP-72)",
    ),
    "hwfet": ("fastsim/resources/cycles/hwfet.csv", "EPA Highway Fuel Economy Test (HWFET)"),
    "us06": ("fastsim/resources/cycles/us06.csv", "EPA US06 Supplemental FTP driving schedule"),
    "wltc3b": ("fastsim/resources/cycles/wltc_3b.csv", "WLTC class 3b (UN GTR No. 15; v_max >= 120 km/h)"),
}
FASTSIM_TIME_COL = "cycSecs"  # s
FASTSIM_SPEED_COL = "cycMps"  # m/s
FASTSIM_DROPPED_COLS = ("cycGrade", "cycRoadType")  # must be all zero: vpsim cycles are flat

# FTP-75 = UDDS (bag 1: 0-505 s, bag 2: 505-1369 s) + bag 3 = repeat of bag 1 (UDDS t = 1...505 s)
FTP75_BAG1_END_S = 505

# ----------------------------------------------------------------------------------------------------------
# NEDC mode tables
# ----------------------------------------------------------------------------------------------------------
# Each row: (operation, duration in s, speed in km/h at the END of the operation). The speed varies linearly
# over the operation from the end speed of the previous row. Gear changes hold the speed constant, except
# ECE operation 22, during which the speed falls from 35 to 32 km/h (operation 23 decelerates from 32 km/h).
#
# UNECE Regulation No. 83, Annex 4a, para. 6.1.1, Table 1 "Elementary urban cycle on the chassis
# dynamometer" (= Directive 70/220/EEC as amended by 98/69/EC, Annex III, Appendix 1, Table III.1.1).
# 195 s; regulation: theoretical distance 1.013 km per cycle (the piecewise-linear trace gives 1.0146 km).
ECE15_MODES: tuple[tuple[str, int, float], ...] = (
    ("1 idling", 11, 0.0),
    ("2 acceleration 0-15", 4, 15.0),
    ("3 steady speed 15", 8, 15.0),
    ("4 deceleration 15-10", 2, 10.0),
    ("5 deceleration, clutch disengaged 10-0", 3, 0.0),
    ("6 idling", 21, 0.0),
    ("7 acceleration 0-15", 5, 15.0),
    ("8 gear change", 2, 15.0),
    ("9 acceleration 15-32", 5, 32.0),
    ("10 steady speed 32", 24, 32.0),
    ("11 deceleration 32-10", 8, 10.0),
    ("12 deceleration, clutch disengaged 10-0", 3, 0.0),
    ("13 idling", 21, 0.0),
    ("14 acceleration 0-15", 5, 15.0),
    ("15 gear change", 2, 15.0),
    ("16 acceleration 15-35", 9, 35.0),
    ("17 gear change", 2, 35.0),
    ("18 acceleration 35-50", 8, 50.0),
    ("19 steady speed 50", 12, 50.0),
    ("20 deceleration 50-35", 8, 35.0),
    ("21 steady speed 35", 13, 35.0),
    ("22 gear change (35-32)", 2, 32.0),
    ("23 deceleration 32-10", 7, 10.0),
    ("24 deceleration, clutch disengaged 10-0", 3, 0.0),
    ("25 idling", 7, 0.0),
)
# UNECE Regulation No. 83, Annex 4a, para. 6.1.2, Table 2 "Extra-urban cycle (Part Two) for the Type I test"
# (= Directive 70/220/EEC as amended by 98/69/EC, Annex III, Appendix 1, Table III.1.2).
# 400 s, 6.955 km, maximum 120 km/h.
EUDC_MODES: tuple[tuple[str, int, float], ...] = (
    ("1 idling", 20, 0.0),
    ("2 acceleration 0-15", 5, 15.0),
    ("3 gear change", 2, 15.0),
    ("4 acceleration 15-35", 9, 35.0),
    ("5 gear change", 2, 35.0),
    ("6 acceleration 35-50", 8, 50.0),
    ("7 gear change", 2, 50.0),
    ("8 acceleration 50-70", 13, 70.0),
    ("9 steady speed 70", 50, 70.0),
    ("10 deceleration 70-50", 8, 50.0),
    ("11 steady speed 50", 69, 50.0),
    ("12 acceleration 50-70", 13, 70.0),
    ("13 steady speed 70", 50, 70.0),
    ("14 acceleration 70-100", 35, 100.0),
    ("15 steady speed 100", 30, 100.0),
    ("16 acceleration 100-120", 20, 120.0),
    ("17 steady speed 120", 10, 120.0),
    ("18 deceleration 120-80", 16, 80.0),
    ("19 deceleration 80-50", 8, 50.0),
    ("20 deceleration, clutch disengaged 50-0", 10, 0.0),
    ("21 idling", 20, 0.0),
)
ECE15_REPEATS = 4
NEDC_SOURCE = (
    "UNECE Regulation No. 83, Annex 4a, para. 6.1: Part One = 4 x Table 1 (elementary urban cycle, ECE-15, "
    "195 s) + Part Two = Table 2 (extra-urban cycle, EUDC, 400 s); identical to Directive 70/220/EEC "
    "(as amended by 98/69/EC), Annex III, Appendix 1, Tables III.1.1 and III.1.2"
)
NEDC_LICENCE = (
    "numbers from a public regulation (regulatory data, no copyrighted source copied); "
    "this file is part of vpsim and distributed under its licence (MIT)"
)

# Sanity limits checked after building (catch a typo in the tables or a changed source).
EXPECTED = {
    # name: (samples, distance km, tolerance km, max km/h)
    "nedc": (1181, 11.013, 0.002, 120.0),
    "ftp75": (1875, 17.77, 0.01, 91.25),
    "udds": (1370, 11.99, 0.01, 91.25),
    "hwfet": (766, 16.51, 0.01, 96.4),
    "us06": (601, 12.89, 0.01, 129.2),
    "wltc3b": (1801, 23.266, 0.002, 131.3),
}


@dataclass
class Built:
    name: str
    long_name: str
    time_s: np.ndarray  # integer seconds
    speed_mps: np.ndarray
    source: str
    short_source: str
    version: str
    conversion: str
    licence: str

    @property
    def distance_km(self) -> float:
        v = self.rounded()
        return float(np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(self.time_s))) / 1000.0

    @property
    def max_kmh(self) -> float:
        return float(self.rounded().max() * 3.6)

    def rounded(self) -> np.ndarray:
        """The speeds as written to the CSV (6 decimals)."""
        return np.array([float(f"{x:.6f}") for x in self.speed_mps])


# ----------------------------------------------------------------------------------------------------------
# sources
# ----------------------------------------------------------------------------------------------------------
def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def obtain_wheel(wheel: Path | None, tmp: Path) -> Path:
    """The fastsim wheel: ``wheel`` if given, else downloaded with pip (the exact cp311 manylinux build)."""
    if wheel is None:
        cmd = [
            sys.executable, "-m", "pip", "download", "--no-deps", f"fastsim=={FASTSIM_VERSION}",
            "-d", str(tmp), "--only-binary=:all:", "--platform", "manylinux2014_x86_64",
            "--python-version", "3.11", "--implementation", "cp", "--abi", "cp311",
        ]  # fmt: skip
        print("$", " ".join(cmd), file=sys.stderr)
        subprocess.run(cmd, check=True)
        wheel = tmp / FASTSIM_WHEEL
        if not wheel.is_file():
            found = sorted(p.name for p in tmp.glob("*.whl"))
            sys.exit(f"pip did not produce {FASTSIM_WHEEL} (got {found})")
    data = wheel.read_bytes()
    digest = sha256_bytes(data)
    if digest != FASTSIM_WHEEL_SHA256:
        sys.exit(
            f"{wheel}: sha256 {digest} does not match the recorded {FASTSIM_WHEEL_SHA256} ({FASTSIM_WHEEL})"
        )
    return wheel


def read_fastsim_member(zf: zipfile.ZipFile, member: str) -> tuple[np.ndarray, np.ndarray, str]:
    """(time_s, speed_mps, member sha256) of one cycle CSV in the wheel, checked for 1 Hz and a flat road."""
    raw = zf.read(member)
    text = raw.decode("utf-8-sig")  # wltc_3b.csv starts with a byte-order mark
    rows = list(csv.DictReader(io.StringIO(text)))
    cols = set(rows[0]) if rows else set()
    for col in (FASTSIM_TIME_COL, FASTSIM_SPEED_COL, *FASTSIM_DROPPED_COLS):
        if col not in cols:
            sys.exit(f"{member}: column {col!r} missing (columns: {sorted(cols)})")
    t = np.array([float(r[FASTSIM_TIME_COL]) for r in rows])
    v = np.array([float(r[FASTSIM_SPEED_COL]) for r in rows])
    if not np.array_equal(t, np.arange(len(t), dtype=float)):
        sys.exit(f"{member}: {FASTSIM_TIME_COL} is not 0, 1, 2, ... (1 Hz from 0)")
    if not (np.all(np.isfinite(v)) and np.all(v >= 0)):
        sys.exit(f"{member}: {FASTSIM_SPEED_COL} has negative or non-finite values")
    for col in FASTSIM_DROPPED_COLS:
        if any(float(r[col]) != 0.0 for r in rows):
            sys.exit(f"{member}: column {col} is not all zero; dropping it would lose information")
    if v[0] != 0.0 or v[-1] != 0.0:
        sys.exit(f"{member}: cycle does not start and end at standstill")
    return t.astype(np.int64), v, sha256_bytes(raw)


def build_fastsim(wheel: Path) -> dict[str, Built]:
    out = {}
    with zipfile.ZipFile(wheel) as zf:
        for name, (member, long_name) in FASTSIM_MEMBERS.items():
            t, v, digest = read_fastsim_member(zf, member)
            out[name] = Built(
                name=name,
                long_name=long_name,
                time_s=t,
                speed_mps=v,
                source=f"PyPI fastsim {FASTSIM_VERSION} (NREL), wheel member {member}",
                short_source=f"fastsim {FASTSIM_VERSION} `{member.rsplit('/', 1)[-1]}`",
                version=f"wheel {FASTSIM_WHEEL} sha256 {FASTSIM_WHEEL_SHA256}; member sha256 {digest}",
                conversion=(
                    f"{FASTSIM_TIME_COL} [s] -> time_s; {FASTSIM_SPEED_COL} [m/s] -> speed_mps unchanged, "
                    f"rounded to 6 decimals; {' and '.join(FASTSIM_DROPPED_COLS)} (all 0) dropped"
                ),
                licence=FASTSIM_LICENCE,
            )
    return out


def build_ftp75(udds: Built) -> Built:
    """UDDS t = 0...1369, then UDDS t = 1...505 at t = 1370...1874 (bag 3 = bag 1, no 600 s hot soak)."""
    t_u, v_u = udds.time_s, udds.speed_mps
    bag3 = slice(1, FTP75_BAG1_END_S + 1)
    t = np.concatenate([t_u, t_u[-1] + t_u[bag3]])
    v = np.concatenate([v_u, v_u[bag3]])
    return Built(
        name="ftp75",
        long_name="EPA FTP-75 (bag 1 + bag 2 + bag 3, without the 600 s hot soak)",
        time_s=t,
        speed_mps=v,
        source=f"built from the udds cycle: {udds.source}",
        short_source=f"udds + udds bag 1 ({udds.short_source})",
        version=udds.version,
        conversion=(
            f"UDDS t=0...{t_u[-1]} s, then UDDS t=1...{FTP75_BAG1_END_S} s placed at "
            f"t={t_u[-1] + 1}...{t_u[-1] + FTP75_BAG1_END_S} s: bag 1 (0-505 s) + bag 2 (505-1369 s) + "
            "bag 3 = repeat of bag 1; the 600 s engine-off hot soak between bags 2 and 3 is left out; "
            f"speeds as in udds ({FASTSIM_SPEED_COL} [m/s], 6 decimals)"
        ),
        licence=FASTSIM_LICENCE,
    )


def mode_nodes(modes, t0: float, v0: float) -> tuple[list[float], list[float]]:
    """Breakpoints (t, v km/h) of a mode table starting at (t0, v0), without the starting point."""
    ts, vs = [], []
    t = t0
    for _, duration, v_end in modes:
        t += duration
        ts.append(t)
        vs.append(v_end)
    return ts, vs


def build_nedc() -> Built:
    ece_s = sum(d for _, d, _ in ECE15_MODES)
    eudc_s = sum(d for _, d, _ in EUDC_MODES)
    assert ece_s == 195 and eudc_s == 400, (ece_s, eudc_s)
    assert ECE15_MODES[-1][2] == 0.0 and EUDC_MODES[-1][2] == 0.0
    nodes_t, nodes_v = [0.0], [0.0]
    for k in range(ECE15_REPEATS):
        ts, vs = mode_nodes(ECE15_MODES, k * ece_s, 0.0)
        nodes_t += ts
        nodes_v += vs
    ts, vs = mode_nodes(EUDC_MODES, ECE15_REPEATS * ece_s, 0.0)
    nodes_t += ts
    nodes_v += vs
    total = ECE15_REPEATS * ece_s + eudc_s
    t = np.arange(total + 1, dtype=np.int64)
    v_kmh = np.interp(t, nodes_t, nodes_v)
    return Built(
        name="nedc",
        long_name="New European Driving Cycle (NEDC): 4 x ECE-15 urban + EUDC extra-urban",
        time_s=t,
        speed_mps=v_kmh / 3.6,
        source=NEDC_SOURCE,
        short_source="UNECE R83 Annex 4a Tables 1 and 2 (mode tables)",
        version="mode tables written out as data in tools/build_cycles.py (ECE15_MODES, EUDC_MODES)",
        conversion=(
            "mode table (duration s, end speed km/h) -> piecewise-linear trace between the mode ends, "
            f"sampled at 1 Hz t=0...{total} s; gear changes at constant speed (ECE op. 22: 35->32 km/h); "
            "km/h / 3.6 -> m/s, rounded to 6 decimals"
        ),
        licence=NEDC_LICENCE,
    )


# ----------------------------------------------------------------------------------------------------------
# output
# ----------------------------------------------------------------------------------------------------------
def csv_text(c: Built) -> str:
    lines = [
        f"# vpsim standard drive cycle {c.name}: {c.long_name}; 1 Hz",
        f"# source: {c.source}",
        f"# version: {c.version}",
        f"# conversion: {c.conversion}",
        f"# licence: {c.licence}",
        "# written by tools/build_cycles.py; see SOURCES.md",
        "time_s,speed_mps",
    ]
    lines += [f"{int(t)},{v:.6f}" for t, v in zip(c.time_s, c.speed_mps, strict=True)]
    return "\n".join(lines) + "\n"


def sources_md(cycles: dict[str, Built]) -> str:
    out = [
        "# Sources of the standard drive cycles",
        "",
        "Written by `tools/build_cycles.py` (do not edit by hand; run `python tools/build_cycles.py`",
        "from the repository root, or `--check` to verify). Every CSV has the header `time_s,speed_mps`,",
        "1 Hz, integer time from 0, speed in m/s to 6 decimals, preceded by `#` comment lines that repeat",
        "its source, conversion and licence. Distance is the trapezoidal integral of the written file;",
        "all cycles start and end at standstill.",
        "",
        "| cycle | samples | duration s | distance km | max km/h | source |",
        "|---|---|---|---|---|---|",
    ]
    for c in cycles.values():
        out.append(
            f"| `{c.name}` | {len(c.time_s)} | {int(c.time_s[-1] - c.time_s[0])} | {c.distance_km:.3f} | "
            f"{c.max_kmh:.2f} | {c.short_source} |"
        )
    out += [
        "",
        "## fastsim wheel (udds, hwfet, us06, wltc3b, ftp75)",
        "",
        f"* Package: PyPI `fastsim=={FASTSIM_VERSION}` (NREL), {FASTSIM_URL}",
        f"* Wheel: `{FASTSIM_WHEEL}`",
        f"* Wheel sha256: `{FASTSIM_WHEEL_SHA256}` (checked by the script before reading)",
        "* Obtained with `pip download --no-deps fastsim==2.1.5` (the script pins the cp311 manylinux",
        "  build, or takes a local copy with `--wheel PATH`); read with `zipfile`, fastsim is not installed.",
        '* Licence: Apache-2.0. NOTICE: "Copyright 2020 Alliance for Sustainable Energy, LLC". The vpsim',
        "  files are modified copies: columns renamed, grade and road-type columns dropped, 6 decimals.",
        f"* Member columns: `{FASTSIM_TIME_COL}` (s, 0, 1, 2, ...), `{FASTSIM_SPEED_COL}` (m/s),",
        f"  `{'`, `'.join(FASTSIM_DROPPED_COLS)}` (all 0, checked, dropped). `wltc_3b.csv` starts",
        "  with a UTF-8 byte-order mark.",
        "* Note: fastsim's UDDS and HWFET speeds are the EPA 0.1 mph values times about 0.447047 (16 ppm",
        "  above the exact 0.44704 m/s per mph); they are kept as published. US06 uses the exact factor.",
        "",
        "## NEDC mode tables",
        "",
        f"* Source: {NEDC_SOURCE}.",
        "* The tables are written out as data in the script (`ECE15_MODES`, `EUDC_MODES`): per operation",
        "  the duration (s) and the speed at its end (km/h); the trace is linear within each operation.",
        "  Gear changes hold the speed, except ECE operation 22 (35 -> 32 km/h, before the 32 -> 10 km/h",
        "  deceleration of operation 23).",
        "* ECE-15: 195 s, 1.0146 km per trace (the regulation quotes 1.013 km); EUDC: 400 s, 6.955 km, max",
        "  120 km/h. NEDC = 4 x ECE-15 + EUDC = 1180 s, 1181 samples t=0...1180.",
        "",
        "## Per cycle",
        "",
    ]
    for c in cycles.values():
        out += [
            f"### `{c.name}.csv`: {c.long_name}",
            "",
            f"* Source: {c.source}",
            f"* Version: {c.version}",
            f"* Conversion: {c.conversion}",
            f"* Licence: {c.licence}",
            f"* {len(c.time_s)} samples, {int(c.time_s[-1] - c.time_s[0])} s, {c.distance_km:.4f} km, "
            f"max {c.max_kmh:.2f} km/h",
            "",
        ]
    return "\n".join(out)


def check_expected(c: Built) -> None:
    samples, dist, tol, vmax = EXPECTED[c.name]
    problems = []
    if len(c.time_s) != samples:
        problems.append(f"{len(c.time_s)} samples, expected {samples}")
    if abs(c.distance_km - dist) > tol:
        problems.append(f"distance {c.distance_km:.4f} km, expected {dist} +- {tol}")
    if abs(c.max_kmh - vmax) > 0.1:
        problems.append(f"max {c.max_kmh:.2f} km/h, expected {vmax}")
    if c.speed_mps[0] != 0 or c.speed_mps[-1] != 0:
        problems.append("does not start and end at 0")
    if problems:
        sys.exit(f"{c.name}: " + "; ".join(problems))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--wheel", type=Path, help=f"local copy of {FASTSIM_WHEEL} (else: pip download)")
    ap.add_argument("--out", type=Path, default=DATA_DIR, help="output folder (default: %(default)s)")
    ap.add_argument("--check", action="store_true", help="do not write; fail if the files in --out differ")
    args = ap.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        wheel = obtain_wheel(args.wheel, Path(tmp))
        fs = build_fastsim(wheel)
    cycles = {"nedc": build_nedc(), "ftp75": build_ftp75(fs["udds"]), **fs}
    for c in cycles.values():
        check_expected(c)

    files = {f"{c.name}.csv": csv_text(c) for c in cycles.values()}
    files["SOURCES.md"] = sources_md(cycles)
    stale = []
    for fname, text in files.items():
        path = args.out / fname
        if args.check:
            if not path.is_file() or path.read_text(encoding="utf-8") != text:
                stale.append(fname)
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding="utf-8", newline="\n")

    print(f"{'cycle':<8} {'samples':>7} {'duration s':>10} {'distance km':>11} {'max km/h':>9}")
    for c in cycles.values():
        print(
            f"{c.name:<8} {len(c.time_s):>7d} {int(c.time_s[-1] - c.time_s[0]):>10d} "
            f"{c.distance_km:>11.4f} {c.max_kmh:>9.2f}"
        )
    if args.check:
        if stale:
            print(f"out of date in {args.out}: {', '.join(stale)}", file=sys.stderr)
            return 1
        print(f"{args.out}: up to date")
    else:
        print(f"wrote {len(files)} files to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
