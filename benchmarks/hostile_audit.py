"""Hostile-input audit (issue 31): every case the issue lists, run through the real CLI, classified.

    PYTHONPATH=src python benchmarks/hostile_audit.py [--json audit.json] [--only SURFACE] [--no-kill]

Each case runs ``python -m vpsim ARGS`` in a fresh temporary folder holding copies of the inputs it needs
(a made-up certification list from tests/fleet_csv.py, a CVT and an electric car's vehicle file written from
it, a technology.json, cycle and ADVISOR files; the ADVISOR ones are read from ../shared and their cases
skipped when it is absent), with HOME pointed into that folder, under a 4 GB address-space limit. Its
answer is classified:

* ``clean``: exit 2 and exactly one line ``vpsim: error: ...`` holding the expected words (a case whose
  input must be refused), or exit 0 with a valid result (no ``nan``/``inf`` printed, ``--json`` valid JSON,
  and the case's own check, e.g. a measured mpg left out, a trace miss that is not negative);
* otherwise the first of: ``hang`` (over the case's time limit, 10 s unless it simulates a whole fleet),
  ``memory`` (peak resident set over 1 GiB), ``exit 3`` / ``traceback``, ``input overwritten`` (a file that
  was there before changed), ``written outside --out`` (a new file anywhere but the outputs the case names,
  HOME included), ``silent result`` (exit 0 where the input had to be refused), ``misleading`` (refused, but
  the line misses the expected words), ``not one line``.

A fleet killed at every stage (while computing, as it starts writing, halfway through writing) and rerun is
audited too: a folder from an unfinished run must carry the marker and ``from-epa --technology`` must refuse
it; a rerun must leave a finished folder whose technology.json is read.

Exit status 1 if any case is not clean. The table (cases per surface, clean count, the unclean ones) is
printed; ``--json`` keeps every case's class, exit status, time, peak memory and first stderr line.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import math
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("VPSIM_SHARED", REPO.parent / "shared"))
ADVISOR = SHARED / "data" / "raw" / "advisor"
sys.path.insert(0, str(REPO / "tests"))  # the made-up certification list
sys.path.insert(0, str(REPO / "src"))

TIME_LIMIT_S = 10.0
MEMORY_LIMIT_BYTES = 1024**3  # peak resident set
ADDRESS_LIMIT_BYTES = 4 * 1024**3  # hard stop, so a runaway case cannot take the machine
NAN_WORD = re.compile(r"(?<![\w.])-?(nan|inf|infinity)(?![\w])", re.IGNORECASE)
WRAPPER = (
    "import resource, sys\n"
    f"resource.setrlimit(resource.RLIMIT_AS, ({ADDRESS_LIMIT_BYTES}, {ADDRESS_LIMIT_BYTES}))\n"
    "from vpsim.cli.main import main\n"
    "sys.exit(main(sys.argv[1:]))\n"
)


@dataclass
class Case:
    surface: str
    name: str
    args: list  # "{d}" in an argument is the case's folder
    expect: str = "refuse"  # "refuse", "ok" or "either"
    match: str = ""  # words the error line must hold (refuse), or stdout (ok)
    outs: tuple = ()  # paths (relative to the folder) the command may write
    setup: object = None  # callable(folder) making the case's hostile input
    check: object = None  # callable(folder, stdout) -> problem or None, for an ok answer
    limit_s: float = TIME_LIMIT_S
    needs_shared: bool = False


@dataclass
class Outcome:
    case: Case
    verdict: str
    code: int | None
    seconds: float
    peak_mib: float
    line: str
    detail: str = ""
    extra: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------- inputs


def _edit_csv(src: Path, dst: Path, vehicle_id: str, changes: dict, *, extra_cells: int = 0) -> None:
    from vpsim.fleet.epa import COL

    with src.open(newline="", encoding="utf-8-sig") as f:
        rows = list(csv.reader(f))
    i_id = rows[0].index("Test Vehicle ID")
    for r in rows[1:]:
        if r[i_id] == vehicle_id:
            for k, v in changes.items():
                r[rows[0].index(COL[k])] = v
            r.extend(["x"] * extra_cells)
    with dst.open("w", newline="", encoding="utf-8") as f:
        csv.writer(f).writerows(rows)


def build_base(base: Path) -> None:
    """The inputs every case copies: list.csv (gasoline cars and one EV), car.toml (T001, a CVT), ev.toml
    (E001), tech.json (a technology.json as a fleet run writes its fitted tables), cycle.csv."""
    from fleet_csv import EVS, write_ev_list

    write_ev_list(base / "list.csv", evs=[EVS[0]])
    for vid, name in (("T001", "car.toml"), ("E001", "ev.toml")):
        p = _vpsim(["vehicle", "from-epa", "list.csv", "--id", vid, "--out", name], base, 120)
        if p.returncode != 0:
            raise SystemExit(f"cannot build the audit's inputs: {p.stderr.strip()}")
    fit = {
        "engine.thermal_efficiency": 0.4,
        "engine.friction_coefficient": 1.0,
        "engine.accessory_power": 500.0,
    }
    tech = {
        "all_vehicles": {c: dict(fit, train_loss=0.02, n_train=9) for c in ("na", "boosted", "high_output")},
        "bev": {"all_vehicles": {"bev": {"machine.loss_scale": 0.4, "electric.accessory_power": 300.0}}},
    }
    (base / "tech.json").write_text(json.dumps(tech, indent=2))
    (base / "cycle.csv").write_text("time_s,speed_kmh\n0,0\n1,10\n2,20\n3,10\n4,0\n")


def _vpsim(args, cwd: Path, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "vpsim", *map(str, args)],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=_env(cwd),
    )


def _env(folder: Path) -> dict:
    env = dict(os.environ)
    env.update(
        PYTHONPATH=str(REPO / "src"),
        HOME=str(folder / ".home"),
        MPLCONFIGDIR=str(Path(tempfile.gettempdir()) / "vpsim-audit-mpl"),
        OMP_NUM_THREADS="1",
        OPENBLAS_NUM_THREADS="1",
        NUMBA_NUM_THREADS="1",
    )
    env.setdefault("NUMBA_CACHE_DIR", str(Path(tempfile.gettempdir()) / "vpsim-audit-numba"))
    return env


def _write(name: str, data, *, mode: str = "text"):
    def setup(d: Path):
        p = d / name
        if isinstance(data, bytes):
            p.write_bytes(data)
        else:
            p.write_text(data)

    return setup


def _fifo(name: str):
    return lambda d: os.mkfifo(d / name)


def _replace(src: str, dst: str, old: str, new: str, count: int = 1):
    def setup(d: Path):
        text = (d / src).read_text() if (d / src).exists() else Path(src).read_text()
        if old not in text:
            raise RuntimeError(f"audit setup: {old!r} not in {src}")
        (d / dst).write_text(text.replace(old, new, count))

    return setup


def _list_edit(vehicle_id: str, changes: dict, dst: str = "bad.csv", extra_cells: int = 0):
    return lambda d: _edit_csv(d / "list.csv", d / dst, vehicle_id, changes, extra_cells=extra_cells)


def _tech(edit):
    def setup(d: Path):
        data = json.loads((d / "tech.json").read_text())
        edit(data)
        (d / "bad.json").write_text(json.dumps(data))

    return setup


def _tech_raw(text: str):
    return _write("bad.json", text)


def _record_mpg(value: str):
    """car.toml with the record block's bag-2 measurement replaced by ``value`` (as text)."""

    def setup(d: Path):
        text = (d / "car.toml").read_text()
        key = "\n# ftp_bag2 = "
        start = text.index(key) + len(key)
        (d / "rec.toml").write_text(text[:start] + value + text[text.index("\n", start) :])

    return setup


def _sep_list(sep: str):
    def setup(d: Path):
        with (d / "list.csv").open(newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
        with (d / "sep.csv").open("w", newline="", encoding="utf-8") as f:
            csv.writer(f, delimiter=sep).writerows(rows)

    return setup


# ---------------------------------------------------------------------------------------------- checks


def _json_out(out: str):
    def no_constant(token):
        raise ValueError(token)

    return json.loads(out, parse_constant=no_constant)


def _no_measurement(d: Path, out: str):
    s = _json_out(out)
    if s.get("measured_mpg") is not None or s.get("measured_error_pct") is not None:
        return (
            f"compared with an edited measurement: {s.get('measured_mpg')} -> {s.get('measured_error_pct')} %"
        )
    return None


def _trace_miss_not_negative(d: Path, out: str):
    s = _json_out(out)
    miss = s.get("trace_miss_s")
    if miss is None or not miss >= 0.0:
        return f"trace_miss_s = {miss}"
    return None


def _toml_valid_named(d: Path, out: str):
    import tomllib

    if "\x1b" in out or "\x00" in out:
        return "a control character reached the terminal"
    data = tomllib.loads((d / "c.toml").read_text())
    if set(data.get("vehicle", {})) & {"mass"} and data["vehicle"]["mass"] < 100:
        return "an injected [vehicle] table"
    return None


def _tech_used(d: Path, out: str):
    from vpsim.params import load_parameters

    te = load_parameters(d / "c.toml").engine.thermal_efficiency
    return None if te == 0.4 else f"thermal efficiency {te}, the technology file says 0.4"


def _same_vehicles_as_commas(d: Path, out: str):
    return (
        None if "wrote c.toml: Bolt&Nut Coupe" in out else f"not the comma list's T004: {out.strip()[:120]}"
    )


# ---------------------------------------------------------------------------------------------- cases


def cases() -> list[Case]:
    from vpsim.fleet.report import INCOMPLETE

    C: list[Case] = []
    fe = ["vehicle", "from-epa"]

    # --- the certification-list reader (from-epa on one record; the fleet reads it the same way)
    S = "epa list"
    C += [
        Case(
            S,
            "FIFO",
            [*fe, "in.csv", "--id", "T004", "--out", "c.toml"],
            match="not a regular file",
            setup=_fifo("in.csv"),
        ),
        Case(
            S, "/dev/zero", [*fe, "/dev/zero", "--id", "T004", "--out", "c.toml"], match="not a regular file"
        ),
        Case(
            S,
            "empty file",
            [*fe, "e.csv", "--id", "T004", "--out", "c.toml"],
            match="e.csv",
            setup=_write("e.csv", ""),
        ),
        Case(
            S,
            "binary",
            [*fe, "b.csv", "--id", "T004", "--out", "c.toml"],
            match="b.csv",
            setup=_write("b.csv", bytes(range(256)) * 64),
        ),
        Case(
            S,
            "UTF-16",
            [*fe, "u.csv", "--id", "T004", "--out", "c.toml"],
            match="u.csv",
            setup=lambda dd: (dd / "u.csv").write_bytes((dd / "list.csv").read_text().encode("utf-16")),
        ),
        Case(
            S,
            "20 MB of junk after the rows",
            [*fe, "big.csv", "--id", "T004", "--out", "c.toml"],
            expect="either",
            outs=("c.toml",),
            setup=lambda dd: (dd / "big.csv").write_text((dd / "list.csv").read_text() + "x" * 20_000_000),
        ),
        Case(
            S,
            "semicolons",
            [*fe, "sep.csv", "--id", "T004", "--out", "c.toml"],
            expect="ok",
            outs=("c.toml",),
            setup=_sep_list(";"),
            check=_same_vehicles_as_commas,
        ),
        Case(
            S,
            "tabs",
            [*fe, "sep.csv", "--id", "T004", "--out", "c.toml"],
            expect="ok",
            outs=("c.toml",),
            setup=_sep_list("\t"),
            check=_same_vehicles_as_commas,
        ),
        Case(
            S,
            "extra fields on a row",
            [*fe, "bad.csv", "--id", "T004", "--out", "c.toml"],
            match="T004 is excluded: unreadable row: line 9",  # only the vehicle the row names is left out
            setup=_list_edit("T004", {}, extra_cells=3),
        ),
        Case(
            S,
            "extra fields on another vehicle's row",
            [*fe, "bad.csv", "--id", "T001", "--out", "c.toml"],
            expect="ok",
            outs=("c.toml",),
            setup=_list_edit("T004", {}, extra_cells=3),
        ),
        Case(S, "unknown --id", [*fe, "list.csv", "--id", "NOPE", "--out", "c.toml"], match="NOPE"),
    ]
    for field_, value, words in [
        ("cylinders", "abc", "not a number: cylinders"),
        ("cylinders", "V8", "not a number: cylinders"),
        ("cylinders", "inf", "not a number: cylinders"),
        ("rated_hp", "4,000", "not a number: rated_hp"),
        ("rated_hp", "9" * 300, "rated_hp"),
        ("cylinders", "2.5", "cylinders: 2.5 is not a whole number"),
        ("n_gears", "6.7", "n_gears: 6.7 is not a whole number"),
        ("displacement_l", "0", "implausible displacement_l"),
        ("displacement_l", "-2", "implausible displacement_l"),
        ("displacement_l", "0.05", "implausible displacement_l"),
        ("etw_lb", "1e300", "implausible etw_lb"),
        ("etw_lb", "0.000001", "implausible etw_lb"),
        ("configuration", "1.9", "configuration 1.9 is not a whole number"),
    ]:
        C.append(
            Case(
                S,
                f"{field_} = {value[:12]}",
                [*fe, "bad.csv", "--id", "T004", "--out", "c.toml"],
                match=words,
                setup=_list_edit("T004", {field_: value}),
            )
        )
    for edits, words in [
        ({"target_a_lbf": "1", "target_b_lbf_per_mph": "-3"}, "implausible road load"),
        ({"target_a_lbf": "5", "target_b_lbf_per_mph": "-1"}, "implausible road load"),
        ({"rated_hp": "40", "etw_lb": "9000"}, "implausible rated_hp"),
        ({"rated_hp": "1600", "etw_lb": "1500"}, "implausible rated_hp"),
    ]:
        name = ", ".join(f"{k} {v}" for k, v in edits.items())
        C.append(
            Case(
                S,
                name,
                [*fe, "bad.csv", "--id", "T004", "--out", "c.toml"],
                match=words,
                setup=_list_edit("T004", edits),
            )
        )
        C.append(
            Case(
                S,
                "EV " + name,
                [*fe, "bad.csv", "--id", "E001", "--out", "c.toml"],
                match=words,
                setup=_list_edit("E001", edits),
            )
        )
    for text in ['Runner"\n[vehicle]\nmass = 1', "Runner\x1b[31mRED\x1b[0m", "Runner\x00nul\x7fdel\ttab\\"]:
        C.append(
            Case(
                S,
                f"model {text[:10]!r}",
                [*fe, "bad.csv", "--id", "T004", "--out", "c.toml"],
                expect="ok",
                outs=("c.toml",),
                setup=_list_edit("T004", {"model": text}),
                check=_toml_valid_named,
            )
        )
    for field_, value, words in [
        ("rated_hp", "0", "electric, implausible rated_hp"),
        ("etw_lb", "-5", "electric, implausible etw_lb"),
        ("target_c_lbf_per_mph2", "nan", "electric, not a number"),
        ("axle_ratio", "x", "electric, not a number: axle_ratio"),
        ("fe", "1e6", "electric, implausible"),
    ]:
        C.append(
            Case(
                S,
                f"EV {field_} = {value}",
                [*fe, "bad.csv", "--id", "E001", "--out", "c.toml"],
                match=words,
                setup=_list_edit("E001", {field_: value}),
            )
        )

    # --- from-epa's --out
    S = "from-epa --out"
    C += [
        Case(
            S,
            "--out is the list",
            [*fe, "list.csv", "--id", "T004", "--out", "list.csv"],
            match="an input of this command",
        ),
        Case(
            S,
            "--out is the technology file",
            [*fe, "list.csv", "--id", "T004", "--out", "tech.json", "--technology", "tech.json"],
            match="an input of this command",
        ),
        Case(
            S,
            "--out is the list by another path",
            [*fe, "list.csv", "--id", "T004", "--out", "./sub/../list.csv"],
            match="an input of this command",
            setup=lambda dd: (dd / "sub").mkdir(),
        ),
        Case(S, "--out is a folder", [*fe, "list.csv", "--id", "T004", "--out", "."], match="--out"),
        Case(
            S,
            "--out under a file",
            [*fe, "list.csv", "--id", "T004", "--out", "car.toml/x.toml"],
            match="x.toml",
        ),
        Case(
            S, "--out in /proc", [*fe, "list.csv", "--id", "T004", "--out", "/proc/1/x.toml"], match="x.toml"
        ),
        Case(
            S,
            "--out with a control character",
            [*fe, "list.csv", "--id", "T004", "--out", "a\x01b.toml"],
            expect="either",
            outs=("a\x01b.toml",),
        ),
    ]

    # --- technology files
    S = "technology file"
    fetech = [*fe, "list.csv", "--id", "T004", "--out", "c.toml", "--technology", "bad.json"]
    fetech_ev = [*fe, "list.csv", "--id", "E001", "--out", "c.toml", "--technology", "bad.json"]

    def setv(cls, key, value):
        return _tech(lambda t: t["all_vehicles"][cls].__setitem__(key, value))

    te = "engine.thermal_efficiency"
    C += [
        Case(S, "efficiency 1.0", fetech, match="outside (0, 1)", setup=setv("boosted", te, 1.0)),
        Case(S, "efficiency 0.6", fetech, match="not below 0.6", setup=setv("boosted", te, 0.6)),
        Case(S, "efficiency true", fetech, match="true is not a number", setup=setv("boosted", te, True)),
        Case(S, 'efficiency "0.4"', fetech, match="is not a number", setup=setv("boosted", te, "0.4")),
        Case(S, "efficiency null", fetech, match="is not a number", setup=setv("boosted", te, None)),
        Case(
            S,
            "friction false",
            fetech,
            match="false is not a number",
            setup=setv("boosted", "engine.friction_coefficient", False),
        ),
        Case(
            S,
            "accessories -5 W",
            fetech,
            match="outside the plausible range",
            setup=setv("boosted", "engine.accessory_power", -5),
        ),
        Case(
            S,
            "efficiency Infinity",
            fetech,
            match="Infinity is not a JSON number",
            setup=_tech_raw('{"all_vehicles": {"boosted": {"engine.thermal_efficiency": Infinity}}}'),
        ),
        Case(
            S,
            "efficiency NaN",
            fetech,
            match="NaN is not a JSON number",
            setup=_tech_raw('{"all_vehicles": {"boosted": {"engine.thermal_efficiency": NaN}}}'),
        ),
        Case(
            S,
            "a 300-digit efficiency",
            fetech,
            match="engine.thermal_efficiency",
            setup=_tech_raw(
                '{"all_vehicles": {"boosted": {"engine.thermal_efficiency": ' + "9" * 300 + "}}}"
            ),
        ),
        Case(
            S,
            "a 5000-digit efficiency",
            fetech,
            match="bad.json",
            setup=_tech_raw(
                '{"all_vehicles": {"boosted": {"engine.thermal_efficiency": ' + "9" * 5000 + "}}}"
            ),
        ),
        Case(
            S,
            "nested 100,000 deep",
            fetech,
            match="nested too deeply",
            setup=_tech_raw('{"all_vehicles": ' + "[" * 100_000 + "]" * 100_000 + "}"),
        ),
        Case(
            S,
            "misspelt fit key",
            fetech,
            match="engine.accesory_power",
            setup=setv("boosted", "engine.accesory_power", 100.0),
        ),
        Case(
            S,
            "misspelt table",
            fetech,
            match="'all_vehicle'",
            setup=_tech(lambda t: t.__setitem__("all_vehicle", {})),
        ),
        Case(
            S,
            "unknown class",
            fetech,
            match="'all_vehicles.NA'",
            setup=_tech(lambda t: t["all_vehicles"].__setitem__("NA", {})),
        ),
        Case(
            S,
            "the car's class not fitted",
            fetech,
            match="has no fit for this car's class boosted",
            setup=_tech(lambda t: t["all_vehicles"].pop("boosted")),
        ),
        Case(
            S,
            "EV loss scale true",
            fetech_ev,
            match="true is not a number",
            setup=_tech(lambda t: t["bev"]["all_vehicles"]["bev"].__setitem__("machine.loss_scale", True)),
        ),
        Case(
            S,
            "EV misspelt key",
            fetech_ev,
            match="machine.loss_scal'",
            setup=_tech(lambda t: t["bev"]["all_vehicles"]["bev"].__setitem__("machine.loss_scal", 0.3)),
        ),
        Case(S, "EV no bev part", fetech_ev, match="no bev", setup=_tech(lambda t: t.pop("bev"))),
        Case(S, "a list, not an object", fetech, match="bad.json", setup=_tech_raw("[1, 2]")),
        Case(S, "not JSON", fetech, match="not valid JSON", setup=_tech_raw("{'all_vehicles': 1}")),
        Case(S, "empty", fetech, match="bad.json", setup=_tech_raw("")),
        Case(S, "FIFO", fetech, match="not a regular file", setup=_fifo("bad.json")),
        Case(S, "/dev/zero", [*fetech[:-1], "/dev/zero"], match="not a regular file"),
        Case(
            S,
            "from an unfinished run",
            fetech,
            match="did not finish writing",
            setup=lambda dd: (
                shutil.copy(dd / "tech.json", dd / "bad.json"),
                (dd / INCOMPLETE).write_text("killed\n"),
            ),
        ),
        Case(
            S,
            "a valid file",
            fetech,
            expect="ok",
            outs=("c.toml",),
            setup=lambda dd: shutil.copy(dd / "tech.json", dd / "bad.json"),
            check=_tech_used,
        ),
    ]

    # --- a vehicle file's record block (the measurement simulate compares with)
    S = "record block"
    sim_rec = ["simulate", "--vehicle", "rec.toml", "--cycle", "ftp_bag2", "--json"]
    for value in ["0.001", "1e9", "-3", "nan", "inf", "true", '"28"', "2" * 400, "[" * 5000 + "]" * 5000]:
        C.append(
            Case(
                S,
                f"measured {value[:12]}",
                sim_rec,
                expect="ok",
                setup=_record_mpg(value),
                check=_no_measurement,
            )
        )

    # --- the fleet's options and output folder
    S = "fleet"
    fl = ["fleet", "list.csv", "--no-peer", "--quiet"]
    C += [
        Case(
            S,
            "--cycles duplicated",
            [*fl, "--out", "o", "--cycles", "ftp_bag2,ftp_bag2"],
            match="more than once",
        ),
        Case(S, "--cycles empty", [*fl, "--out", "o", "--cycles", ""], match="cycle"),
        Case(S, "--cycles unknown", [*fl, "--out", "o", "--cycles", "udds"], match="udds"),
        Case(S, "--limit -1", [*fl, "--out", "o", "--limit", "-1"], match="--limit -1"),
        Case(S, "--limit 0", [*fl, "--out", "o", "--limit", "0"], match="--limit 0"),
        Case(S, "--folds 0", [*fl, "--out", "o", "--folds", "0"], match="--folds"),
        Case(S, "--folds -3", [*fl, "--out", "o", "--folds", "-3"], match="--folds"),
        Case(S, "--workers 0", [*fl, "--out", "o", "--workers", "0"], match="workers"),
        Case(
            S, "--seed twice", [*fl, "--out", "o", "--seed", "3", "--seed", "3"], match="given more than once"
        ),
        Case(
            S, "--seed -1 among several", [*fl, "--out", "o", "--seed", "3", "--seed", "-1"], match="--seed"
        ),
        Case(S, "--deal unknown", [*fl, "--out", "o", "--deal", "deck"], match="deck"),
        Case(
            S,
            "--deal hash by manufacturer",
            [*fl, "--out", "o", "--deal", "hash", "--group-by", "manufacturer"],
            match="each manufacturer is its own fold",
        ),
        Case(
            S,
            "--deal hash on too few families",
            [*fl, "--out", "o", "--deal", "hash", "--limit", "6"],
            match="empty",
        ),
        Case(
            S,
            "--deal blocks by manufacturer",
            [*fl, "--out", "o", "--deal", "blocks", "--group-by", "manufacturer"],
            match="each manufacturer is its own fold",
        ),
        Case(
            S,
            "--deal blocks on too few families",
            [*fl, "--out", "o", "--deal", "blocks", "--limit", "3"],
            match="fold",
        ),
        Case(S, "--out under a file", [*fl, "--out", "car.toml/sub"], match="cannot write there"),
        Case(S, "--out holds the list", [*fl, "--out", "."], match="holds an input"),
        Case(S, "--out is the list", [*fl, "--out", "list.csv"], match="list.csv"),
        Case(S, "--out in /proc", [*fl, "--out", "/proc/1/o"], match="/proc/1/o"),
        Case(
            S,
            "a FIFO list",
            ["fleet", "in.csv", "--out", "o", "--no-peer"],
            match="not a regular file",
            setup=_fifo("in.csv"),
            outs=("o",),
        ),
        Case(
            S,
            "a list with no usable vehicle",
            ["fleet", "e.csv", "--out", "o", "--no-peer", "--quiet"],
            match="e.csv",
            setup=_write("e.csv", "Test Vehicle ID\nX\n"),
            outs=("o",),
        ),
    ]

    # --- fleet-deals: the output folders of several fleet runs
    S = "fleet-deals"

    def deal(name: str, seed: int = 0, summary=None, table: bytes | None = None):
        """A made-up fleet output folder ``name``: a summary of the deal and a small vehicles.csv."""

        def setup(d: Path):
            f = d / name
            f.mkdir()
            s = {"n_vehicles": 2, "validation": {"grouping": "family", "folds": 5, "seed": seed}}
            data = summary if summary is not None else json.dumps(s)
            (f / "summary.json").write_bytes(data if isinstance(data, bytes) else data.encode())
            rows = (
                b"vehicle_id,configuration,cycle,error_pct,family,fastsim_calibrated_error_pct\n"
                b"V1,0,hwy,2.0,F0,4.0\nV2,0,hwy,-3.0,F1,5.0\n"
            )
            (f / "vehicles.csv").write_bytes(rows if table is None else table)

        return setup

    def both(*setups):
        return lambda d: [setup(d) for setup in setups]

    fd = ["fleet-deals", "a", "b"]
    C += [
        Case(S, "one folder", ["fleet-deals", "a"], match="two or more", setup=deal("a")),
        Case(S, "the same deal twice", fd, match="same deal", setup=both(deal("a"), deal("b"))),
        Case(
            S,
            "a file as a folder",
            ["fleet-deals", "a", "car.toml"],
            match="is a file",
            setup=deal("a"),
        ),
        Case(
            S,
            "summary.json nested deeply",
            fd,
            match="nested too deeply",
            setup=both(deal("a"), deal("b", 1, summary="[" * 100_000 + "]" * 100_000)),
        ),
        Case(
            S,
            "summary.json NaN seed",
            fd,
            match="NaN is not a JSON number",
            setup=both(
                deal("a"),
                deal("b", 1, summary=('{"validation": {"grouping": "family", "folds": 5, "seed": NaN}}')),
            ),
        ),
        Case(
            S,
            "summary.json deal not a name",
            fd,
            match="validation.deal",
            setup=both(
                deal("a"),
                deal(
                    "b",
                    1,
                    summary='{"validation": {"grouping": "family", "folds": 5, "seed": 1, "deal": [1]}}',
                ),
            ),
        ),
        Case(
            S,
            "summary.json binary",
            fd,
            match="summary.json",
            setup=both(deal("a"), deal("b", 1, summary=b"\x00\xff" * 40)),
        ),
        Case(
            S,
            "vehicles.csv binary",
            fd,
            match="vehicles.csv",
            setup=both(deal("a"), deal("b", 1, table=b"\x00\xff" * 40)),
        ),
        Case(
            S,
            "vehicles.csv a word for an error",
            fd,
            match="expected a number",
            setup=both(
                deal("a"),
                deal("b", 1, table=b"vehicle_id,configuration,cycle,error_pct,family\nV1,0,hwy,x,F0\n"),
            ),
        ),
        Case(
            S,
            "--plot unknown format",
            [*fd, "--plot", "d.xyz"],
            match="cannot write",
            setup=both(deal("a"), deal("b", 1)),
        ),
        Case(
            S,
            "two deals",
            [*fd, "--json"],
            expect="ok",
            match="deals",
            setup=both(deal("a"), deal("b", 1)),
            check=lambda d, out: None if "conventional" in _json_out(out)["tests"] else "no test compared",
        ),
    ]

    # --- parameter (vehicle) files: the old surface's remaining cases
    S = "vehicle file"
    sim = ["simulate", "--vehicle", "v.toml", "--cycle", "cycle.csv"]
    for text, words in [
        ("[engine]\nthermal_efficiency = 1.0\n", "engine.thermal_efficiency"),
        ("[engine]\nthermal_efficiency = 0.6\n", "not below 0.6"),
        ("[engine]\nthermal_efficiency = true\n", "engine.thermal_efficiency"),
        ("[vehicle]\nmass = 1e-6\n", "vehicle.mass"),
        ('[vehicle]\nmass = { value = 1, unit = "mg" }\n', "vehicle.mass"),
        ("[vehicle]\nmass = nan\n", "vehicle.mass"),
        ("[vehicle]\nmass = inf\n", "vehicle.mass"),
        ('[vehicle]\nmass = "1200"\n', "vehicle.mass"),
        ("[vehicle]\nmas = 1200\n", "mas"),
        ("[vehicle]\nmass = " + "9" * 300 + "\n", "vehicle.mass"),
        ("[transmission]\ngearbox_ratios = [0.8, 1.2, 2.0, 3.5]\n", "descend"),
        ("[vehicle]\nroad_load_a = 5\nroad_load_b = -3\nroad_load_c = 0.05\n", "road load"),
        ("[vehicle]\nmass = " + "[" * 100_000 + "]" * 100_000 + "\n", "nested too deeply"),
        ("[vehicle]\nname = 'x\nmass = 1200\n", "at line 2, where it opens"),  # the unclosed quote's line
        ("[transmission]\nn_gears = 2.5\n", "transmission"),
    ]:
        C.append(
            Case(S, text.strip().replace("\n", " ")[:40], sim, match=words, setup=_write("v.toml", text))
        )

    # --- cycle files
    S = "cycle file"
    simc = ["simulate", "--cycle", "c.csv"]
    for data, words in [
        (b"time_s,speed_kmh\n0,0\n1,1_0\n2,0\n", "1_0"),
        (b'time_s,speed_kmh\n0,0\n1,"10\n2,0\n3,0\n', "c.csv:3"),  # the unclosed quote opens on line 3
        (b"time_s,speed_kmh\n0,0\n1,nan\n2,0\n", "c.csv"),
        (b"time_s,speed_kmh\n0,0\n1,-5\n2,0\n", "c.csv"),
        (b"time_s,speed_kmh\n0,0\n1,10\n1,10\n2,0\n", "c.csv"),
        (b"time_s,speed_kmh\n0,0\n1," + b"9" * 300 + b"\n2,0\n", "c.csv"),
        (b"time_s,speed_kmh\n0,0\n1,true\n2,0\n", "c.csv"),
        (b"", "c.csv"),
    ]:
        C.append(
            Case(
                S,
                data.decode()[17:40].replace("\n", " ") or "empty",
                simc,
                match=words,
                setup=_write("c.csv", data),
            )
        )
    C.append(Case(S, "FIFO", simc, match="not a regular file", setup=_fifo("c.csv")))

    # --- engine files (.json and ADVISOR .m) and scaling --calibrate
    S = "engine file"
    fc41 = str(ADVISOR / "FC_SI41_emis.m")

    def engine_json(edit):
        def setup(dd: Path):
            p = _vpsim(["engine", "import", fc41, "--out", "fc.json"], dd, 60)
            assert p.returncode == 0, p.stderr
            data = json.loads((dd / "fc.json").read_text())
            edit(data)
            (dd / "e.json").write_text(json.dumps(data))
            (dd / "fc.json").unlink()

        return setup

    def hostile_m(dd: Path):
        # 5 MB of statements that each build a large temporary: bounded by the reader's limits
        (dd / "h.m").write_text("a = zeros(1, 999999); b = [a a a a]; c = {b b b b};\n" * 100_000)

    C += [
        Case(
            S,
            "JSON fc_disp true",
            ["engine", "import", "e.json"],
            match="fc_disp",
            needs_shared=True,
            setup=engine_json(lambda e: e.__setitem__("fc_disp", True)),
        ),
        Case(
            S,
            "JSON fuel map x 1e300",
            ["engine", "import", "e.json"],
            expect="either",
            needs_shared=True,
            setup=engine_json(
                lambda e: e.__setitem__("fc_fuel_map", [[v * 1e300 for v in r] for r in e["fc_fuel_map"]])
            ),
        ),
        Case(
            S,
            "JSON nested deep",
            ["engine", "import", "e.json"],
            match="nested too deeply",
            setup=_write("e.json", '{"fc_map_spd": ' + "[" * 100_000 + "]" * 100_000 + "}"),
        ),
        Case(S, "5 MB hostile .m", ["engine", "import", "h.m"], match="h.m", setup=hostile_m),
        Case(
            S,
            ".m unclosed quote on line 3",
            ["engine", "import", "q.m"],
            match="q.m:3",
            setup=_write("q.m", "a = 1;\nb = 2;\nc = 'unclosed;\nd = 4;\n"),
        ),
        Case(
            S,
            ".m cell doubling",
            ["engine", "import", "q.m"],
            match="limit",
            setup=_write("q.m", "c = {1}; for k=1:100, c = {c c}; end\n"),
        ),
        Case(
            S,
            ".m system()",
            ["engine", "import", "q.m"],
            match="system",
            setup=_write("q.m", "system('touch pwned')\n"),
        ),
        Case(S, ".m FIFO", ["engine", "import", "q.m"], match="not a regular file", setup=_fifo("q.m")),
        Case(
            S,
            "scaling --calibrate, fuel x 1e300",
            [
                "scaling",
                "--measured",
                "e.json",
                "--bore",
                "0.074",
                "--stroke",
                "0.077",
                "--cylinders",
                "3",
                "--calibrate",
                "--cycles",
                "nedc",
                "--out",
                "s",
            ],
            match="e.json",
            needs_shared=True,
            outs=("s",),
            setup=engine_json(
                lambda e: e.__setitem__("fc_fuel_map", [[v * 1e300 for v in r] for r in e["fc_fuel_map"]])
            ),
        ),
        Case(
            S,
            "scaling --calibrate, fuel 300 digits",
            [
                "scaling",
                "--measured",
                "e.json",
                "--bore",
                "0.074",
                "--stroke",
                "0.077",
                "--cylinders",
                "3",
                "--calibrate",
                "--cycles",
                "nedc",
                "--out",
                "s",
            ],
            match="e.json",
            needs_shared=True,
            outs=("s",),
            setup=engine_json(
                lambda e: e.__setitem__(
                    "fc_fuel_map", [[int("9" * 300) for v in r] for r in e["fc_fuel_map"]]
                )
            ),
        ),
    ]

    # --- the forward method's trace miss with dopri5 on a CVT
    S = "forward dopri5 CVT"
    for cyc in ("udds", "hwfet", "ftp_bag2", "us06"):
        C.append(
            Case(
                S,
                f"trace_miss_s on {cyc}",
                [
                    "simulate",
                    "--vehicle",
                    "car.toml",
                    "--method",
                    "forward",
                    "--solver",
                    "dopri5",
                    "--cycle",
                    cyc,
                    "--json",
                ],
                expect="ok",
                check=_trace_miss_not_negative,
                limit_s=30,
            )
        )

    # --- battery-electric and hybrid vehicle files, ADVISOR machine and cell files
    S = "bev / hev file"
    simb = ["simulate", "--vehicle", "b.toml", "--cycle", "cycle.csv"]
    for base, text, words in [
        ("bev", "[battery]\nsoc_initial = 1.5\n", "battery.soc_initial"),
        ("bev", "[battery]\nsoc_initial = -0.1\n", "battery.soc_initial"),
        ("bev", "[battery]\nsoc_initial = nan\n", "battery.soc_initial"),
        ("bev", "[battery]\nsoc_initial = true\n", "battery.soc_initial"),
        ("bev", "[battery]\nsoc_min = 0.9\nsoc_max = 0.5\n", "soc_m"),
        ("bev", "[battery]\ncells_in_parallel = 0\n", "cells_in_parallel"),
        ("bev", "[battery]\ncells_in_series = -4\n", "cells_in_series"),
        ("bev", "[machine]\nrated_power = 0\n", "machine.rated_power"),
        ("bev", "[machine]\nrated_power = -150\n", "machine.rated_power"),
        ("bev", "[machine]\nkind = true\n", "machine.kind"),
        ("bev", "[electric]\ncharger_efficiency = 1.5\n", "electric.charger_efficiency"),
        ("bev", "[battery]\ncell = 'ESS_none.m'\n", "ESS_none.m"),
        ("bev", "[machine]\nmap_file = 'MC_none.m'\n", "MC_none.m"),
        ("bev", "[battery]\ncells_in_series = " + "[" * 100_000 + "]" * 100_000 + "\n", "nested too deeply"),
        ("bev", "[powertrain]\ntype = 'fcev'\n", "powertrain.type"),
        ("hev_p2", "[battery]\nsoc_initial = 1.5\n", "battery.soc_initial"),
        ("hev_p2", "[machine]\nrated_power = 0\n", "machine.rated_power"),
        ("hev_p2", "[hybrid]\nems = 'magic'\n", "hybrid.ems"),
        ("hev_p2", "[hybrid]\nems = true\n", "hybrid.ems"),
        ("hev_p2", "[battery]\ncells_in_parallel = 0.5\n", "cells_in_parallel"),
    ]:
        C.append(
            Case(
                S,
                f"{base}: {text.strip().replace(chr(10), ' ')[:34]}",
                simb,
                match=words,
                setup=_write("b.toml", f'base = "{base}"\n{text}'),
            )
        )
    C.append(
        Case(
            S,
            "bev preset runs",
            ["simulate", "--vehicle", "bev", "--cycle", "udds", "--json"],
            expect="ok",
            limit_s=30,
        )
    )
    C.append(
        Case(
            S,
            "hev_p2 preset runs",
            ["simulate", "--vehicle", "hev_p2", "--cycle", "udds", "--json"],
            expect="ok",
            limit_s=30,
        )
    )

    S = "ADVISOR MC_/ESS_ file"
    pm49, ess = str(ADVISOR / "MC_PM49.m"), str(ADVISOR / "ESS_NIMH60_OVONIC.m")

    def trunc(src, dst, frac):
        def setup(dd: Path):
            t = Path(src).read_text(errors="replace")
            (dd / dst).write_text(t[: int(len(t) * frac)])

        return setup

    def mutate(src, dst, pattern, repl):
        def setup(dd: Path):
            t = Path(src).read_text(errors="replace")
            new, n = re.subn(pattern, repl, t, count=1)
            if not n:
                raise RuntimeError(f"audit setup: {pattern} not in {src}")
            (dd / dst).write_text(new)

        return setup

    for frac in (0.1, 0.5, 0.9):
        C.append(
            Case(
                S,
                f"MC_PM49 cut at {frac:.0%}",  # a cut in the trailing comments leaves a valid file
                ["machine", "import", "MC_X.m"],
                match="MC_X.m",
                setup=trunc(pm49, "MC_X.m", frac),
                needs_shared=True,
                expect="either",
            )
        )
    C += [
        Case(
            S,
            "MC_PM49 cut inside its efficiency map",
            ["machine", "import", "MC_X.m"],
            match="MC_X.m",
            needs_shared=True,
            setup=lambda dd: (dd / "MC_X.m").write_text(
                (t := Path(pm49).read_text(errors="replace"))[: t.index("mc_eff_map") + 200]
            ),
        ),
        Case(
            S,
            "MC efficiency NaN",
            ["machine", "import", "MC_X.m"],
            match="MC_X.m",
            needs_shared=True,
            setup=mutate(pm49, "MC_X.m", r"mc_max_trq\s*=\s*\[", "mc_max_trq=[NaN "),
        ),
        Case(
            S,
            "MC system()",
            ["machine", "import", "MC_X.m"],
            match="system",
            needs_shared=True,
            setup=mutate(pm49, "MC_X.m", r"mc_inertia\s*=", "system('touch pwned'); mc_inertia="),
        ),
        Case(
            S,
            "MC 5 MB hostile",
            ["machine", "import", "MC_X.m"],
            match="MC_X.m",
            setup=lambda dd: (dd / "MC_X.m").write_text("a = zeros(1, 999999); b = {a a a a};\n" * 100_000),
        ),
        Case(
            S,
            "MC compare FIFO",
            ["machine", "compare", "MC_X.m"],
            match="not a regular file",
            setup=_fifo("MC_X.m"),
        ),
        Case(S, "MC compare /dev/zero", ["machine", "compare", "/dev/zero"], match="not a regular file"),
        Case(
            S,
            "MC --plot onto its input",
            ["machine", "import", "MC_X.m", "--plot", "MC_X.m"],
            match="MC_X.m",
            needs_shared=True,
            setup=lambda dd: shutil.copy(pm49, dd / "MC_X.m"),
        ),
    ]
    for frac in (0.2, 0.6):
        C.append(
            Case(
                S,
                f"ESS cut at {frac:.0%}",  # a cut in the trailing thermal data leaves a valid cell
                simb,
                expect="either",
                match="ESS_X.m",
                needs_shared=True,
                setup=lambda dd, f=frac: (
                    trunc(ess, "ESS_X.m", f)(dd),
                    _write(
                        "b.toml",
                        'base = "bev"\n[battery]\ncell = "ESS_X.m"\ncells_in_series = 50\n'
                        "cells_in_parallel = 4\n",
                    )(dd),
                ),
            )
        )
    C.extend(
        [
            Case(
                S,
                "ESS cut inside its voltage table",
                simb,
                match="ESS_X.m",
                needs_shared=True,
                setup=lambda dd: (
                    (dd / "ESS_X.m").write_text(
                        (t := Path(ess).read_text(errors="replace"))[: t.index("\ness_voc=") + 30]
                    ),
                    _write("b.toml", 'base = "bev"\n[battery]\ncell = "ESS_X.m"\n')(dd),
                ),
            ),
            Case(
                S,
                "ESS capacity negative",
                simb,
                match="ESS_X.m",
                needs_shared=True,
                setup=lambda dd: (
                    mutate(ess, "ESS_X.m", r"ess_max_ah_cap\s*=\s*", "ess_max_ah_cap=-1*")(dd),
                    _write(
                        "b.toml",
                        'base = "bev"\n[battery]\ncell = "ESS_X.m"\n'
                        "cells_in_series = 50\ncells_in_parallel = 4\n",
                    )(dd),
                ),
            ),
        ]
    )
    C.append(
        Case(
            S,
            "ESS FIFO",
            simb,
            match="not a regular file",
            setup=lambda dd: (
                _fifo("ESS_X.m")(dd),
                _write("b.toml", 'base = "bev"\n[battery]\ncell = "ESS_X.m"\n')(dd),
            ),
        )
    )
    for c in C:
        c.args = [str(a) for a in c.args]
    return C


# ---------------------------------------------------------------------------------------------- running


def _snapshot(folder: Path) -> dict[str, tuple]:
    """Every entry under ``folder``: (kind, size, digest) for regular files, kind for the rest (never
    opening a FIFO or device)."""
    out = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            p = Path(root) / name
            rel = str(p.relative_to(folder))
            st = os.lstat(p)
            if stat.S_ISREG(st.st_mode):
                out[rel] = ("file", st.st_size, hashlib.sha256(p.read_bytes()).hexdigest())
            elif stat.S_ISDIR(st.st_mode):
                out[rel] = ("dir",)
            else:
                out[rel] = ("other", st.st_mode)
    return out


def _allowed(rel: str, outs) -> bool:
    return any(rel == o or rel.startswith(o.rstrip("/") + "/") for o in outs)


def _outs(case: Case) -> tuple:
    """What the case's command may write: its --out / --plot / --json FILE arguments and ``case.outs``."""
    outs = list(case.outs)
    for flag in ("--out", "--plot"):
        if flag in case.args:
            outs.append(case.args[case.args.index(flag) + 1])
    return tuple(o[2:] if o.startswith("./") else o for o in outs)


def run_case(case: Case, base: Path) -> Outcome:
    with tempfile.TemporaryDirectory(prefix="vpsim-audit-") as tmp:
        d = Path(tmp)
        for p in base.iterdir():
            shutil.copy(p, d / p.name)
        (d / ".home").mkdir()
        if case.setup:
            case.setup(d)
        before = _snapshot(d)
        args = [a.replace("{d}", str(d)) for a in case.args]
        t0 = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, "-c", WRAPPER, *args],
            cwd=d,
            env=_env(d),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        hung = False
        try:
            out, err = proc.communicate(timeout=case.limit_s)
        except subprocess.TimeoutExpired:
            hung = True
            os.killpg(proc.pid, signal.SIGKILL)
            out, err = proc.communicate()
        seconds = time.perf_counter() - t0
        # the child's peak resident set (KiB on Linux), read from the kernel's accounting of this child
        peak_mib = _peak_mib(proc)
        after = _snapshot(d)
        code = proc.returncode
        line = err.strip().splitlines()[0][:300] if err.strip() else ""
        verdict, detail = _classify(case, d, code, out, err, hung, seconds, peak_mib, before, after)
        return Outcome(case, verdict, code, seconds, peak_mib, line, detail)


_RUSAGE: dict[int, float] = {}


def _peak_mib(proc) -> float:
    return _RUSAGE.get(proc.pid, float("nan"))


def _install_reaper():
    """Popen reaps its child with waitpid; patch it to wait4 so each child's own peak memory is known."""
    orig = subprocess.Popen._try_wait

    def _try_wait(self, wait_flags):
        try:
            pid, sts, ru = os.wait4(self.pid, wait_flags)
        except ChildProcessError:
            return orig(self, wait_flags)
        if pid == self.pid:
            _RUSAGE[pid] = ru.ru_maxrss / 1024.0
        return (pid, sts)

    subprocess.Popen._try_wait = _try_wait


def _classify(case, d, code, out, err, hung, seconds, peak_mib, before, after) -> tuple[str, str]:
    if hung:
        return "hang", f"over {case.limit_s:.0f} s"
    if peak_mib * 1024**2 > MEMORY_LIMIT_BYTES or "out of memory" in err:
        return "memory", f"{peak_mib:.0f} MiB"
    if code == 3 or "internal error" in err:
        return "exit 3", err.strip()[-300:]
    if "Traceback" in err or "Traceback" in out:
        return "traceback", err.strip()[-300:]
    outs = _outs(case)
    changed = [k for k, v in before.items() if k in after and after[k] != v and v[0] == "file"]
    changed += [k for k in before if k not in after]
    if changed:
        return "input overwritten", ", ".join(changed[:5])
    new = [k for k in after if k not in before and not _allowed(k, outs)]
    if new:
        return "written outside --out", ", ".join(new[:5])
    if code == 0:
        if case.expect == "refuse":
            return "silent result", out.strip()[:300]
        if NAN_WORD.search(out):
            return "silent result", "nan/inf printed"
        if "--json" in case.args:
            try:
                _json_out(out)
            except ValueError as exc:
                return "silent result", f"invalid JSON ({exc})"
        if case.check:
            problem = case.check(d, out)
            if problem:
                return "silent result", problem
        return "clean", ""
    if code == 2:
        if case.expect == "ok":
            return "misleading", f"refused a valid input: {err.strip()[:300]}"
        if err.count("\n") != 1 or not err.startswith("vpsim: error: "):
            return "not one line", err[:300]
        if case.match and case.match not in err:
            return "misleading", f"expected {case.match!r}"
        return "clean", ""
    return f"exit {code}", err.strip()[-300:]


# ---------------------------------------------------------------------------------------------- killed fleet


def kill_cases(base: Path) -> list[Outcome]:
    """A fleet killed while computing, as it starts writing and halfway through writing, then rerun: the
    folder must say it is unfinished (and from-epa --technology refuse it) or hold one run; the rerun a
    finished folder that is read."""
    from vpsim.fleet.report import INCOMPLETE

    out: list[Outcome] = []
    with tempfile.TemporaryDirectory(prefix="vpsim-audit-kill-") as tmp:
        d = Path(tmp)
        for p in base.iterdir():
            shutil.copy(p, d / p.name)
        (d / ".home").mkdir()
        fleet = ["fleet", "list.csv", "--out", "o", "--no-peer", "--quiet", "--cycles", "hwy", "--folds", "3"]
        t0 = time.perf_counter()
        first = _vpsim(fleet, d, 300)
        full_s = time.perf_counter() - t0
        assert first.returncode == 0, first.stderr
        tech0 = (d / "o" / "technology.json").read_bytes()
        read = [
            *fleet[:0],
            "vehicle",
            "from-epa",
            "list.csv",
            "--id",
            "T004",
            "--out",
            "c.toml",
            "--technology",
            "o/technology.json",
        ]
        for stage in ("computing", "starts writing", "halfway writing"):
            case = Case("fleet killed and rerun", f"killed {stage}", fleet)
            proc = subprocess.Popen(
                [sys.executable, "-m", "vpsim", *fleet],
                cwd=d,
                env=_env(d),
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                start_new_session=True,
            )
            marker = d / "o" / INCOMPLETE
            t1 = time.perf_counter()
            if stage == "computing":
                time.sleep(min(3.0, full_s / 3))
            else:
                while not marker.exists() and proc.poll() is None and time.perf_counter() - t1 < 300:
                    time.sleep(0.002)
                if stage == "halfway writing":  # the tables are written, the report not yet
                    tech = d / "o" / "technology.json"
                    while proc.poll() is None and time.perf_counter() - t1 < 300:
                        if tech.exists() and tech.stat().st_mtime > time.time() - (time.perf_counter() - t1):
                            break
                        time.sleep(0.002)
            finished_anyway = proc.poll() is not None
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:  # it finished (and poll() reaped it) before the kill: a finished run
                pass
            proc.wait()
            unfinished = marker.exists()
            r = _vpsim(read, d, 60)
            problems = []
            if unfinished and (r.returncode != 2 or "did not finish writing" not in r.stderr):
                problems.append(f"an unfinished folder read: exit {r.returncode} {r.stderr.strip()[:200]}")
            if not unfinished and r.returncode != 0:
                problems.append(f"a finished folder refused: {r.stderr.strip()[:200]}")
            if (
                not unfinished
                and stage == "computing"
                and (d / "o" / "technology.json").read_bytes() != tech0
            ):
                problems.append("the earlier run's technology.json changed without a marker")
            rerun = _vpsim(fleet, d, 300)
            r2 = _vpsim(read, d, 60)
            if rerun.returncode != 0 or marker.exists() or r2.returncode != 0:
                problems.append(
                    f"rerun: exit {rerun.returncode}, marker {marker.exists()}, read {r2.returncode}"
                )
            verdict = "clean" if not problems else "stale trusted"
            detail = "; ".join(problems) or (
                f"unfinished marker {'present' if unfinished else 'absent'}"
                f"{' (finished before the kill)' if finished_anyway else ''}"
            )
            out.append(
                Outcome(
                    case,
                    verdict,
                    r.returncode,
                    time.perf_counter() - t1,
                    float("nan"),
                    r.stderr.strip()[:200],
                    detail,
                )
            )
    return out


# ---------------------------------------------------------------------------------------------- main


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", help="write every case's outcome here")
    ap.add_argument("--only", help="only the surfaces whose name contains this")
    ap.add_argument("--no-kill", action="store_true", help="leave out the killed-fleet cases (3 fleet runs)")
    args = ap.parse_args(argv)
    _install_reaper()
    with tempfile.TemporaryDirectory(prefix="vpsim-audit-base-") as tmp:
        base = Path(tmp)
        build_base(base)
        # warm the compiled kernels once (a first compile is not a hostile input's cost)
        for v in ("car.toml", "bev", "hev_p2"):
            _vpsim(["simulate", "--vehicle", v, "--cycle", "udds"], base, 600)
        for m in ("forward",):
            _vpsim(
                ["simulate", "--vehicle", "car.toml", "--method", m, "--solver", "dopri5", "--cycle", "udds"],
                base,
                600,
            )
        todo = [c for c in cases() if not args.only or args.only in c.surface]
        results: list[Outcome] = []
        for c in todo:
            if c.needs_shared and not ADVISOR.is_dir():
                results.append(Outcome(c, "skipped", None, 0.0, float("nan"), "", f"{ADVISOR} absent"))
                continue
            o = run_case(c, base)
            results.append(o)
            mark = "  " if o.verdict == "clean" else "!!"
            print(
                f"{mark} {o.verdict:22s} {o.seconds:5.1f} s {o.peak_mib:6.0f} MiB  {c.surface}: {c.name}"
                f"{'  -- ' + o.detail if o.detail else ''}",
                flush=True,
            )
        if not args.no_kill and (not args.only or args.only in "fleet killed and rerun"):
            for o in kill_cases(base):
                results.append(o)
                print(
                    f"{'  ' if o.verdict == 'clean' else '!!'} {o.verdict:22s} {o.seconds:5.1f} s"
                    f"             {o.case.surface}: {o.case.name}  -- {o.detail}",
                    flush=True,
                )
    _table(results)
    if args.json:
        Path(args.json).write_text(
            json.dumps(
                [
                    {
                        "surface": o.case.surface,
                        "case": o.case.name,
                        "verdict": o.verdict,
                        "exit": o.code,
                        "seconds": round(o.seconds, 2),
                        "peak_mib": None if math.isnan(o.peak_mib) else round(o.peak_mib),
                        "line": o.line,
                        "detail": o.detail,
                    }
                    for o in results
                ],
                indent=1,
            )
            + "\n"
        )
    return 0 if all(o.verdict in ("clean", "skipped") for o in results) else 1


def _table(results: list[Outcome]) -> None:
    surfaces: dict[str, list[Outcome]] = {}
    for o in results:
        surfaces.setdefault(o.case.surface, []).append(o)
    print("\n| surface | cases | clean | not clean | slowest s | peak MiB |")
    print("|---|---|---|---|---|---|")
    for s, os_ in surfaces.items():
        ran = [o for o in os_ if o.verdict != "skipped"]
        bad = [o for o in ran if o.verdict != "clean"]
        mem = [o.peak_mib for o in ran if not math.isnan(o.peak_mib)]
        print(
            f"| {s} | {len(ran)} | {len(ran) - len(bad)} | "
            f"{', '.join(sorted({o.verdict for o in bad})) or '-'} | "
            f"{max((o.seconds for o in ran), default=0):.1f} | {f'{max(mem):.0f}' if mem else '-'} |"
        )
    ran = [o for o in results if o.verdict != "skipped"]
    clean = sum(o.verdict == "clean" for o in ran)
    skipped = len(results) - len(ran)
    print(
        f"\n{clean} of {len(ran)} clean ({100 * clean / max(len(ran), 1):.0f} %)"
        f"{f'; {skipped} skipped (no reference data)' if skipped else ''}"
    )


if __name__ == "__main__":
    sys.exit(main())
