"""The command line: output contract, JSON keys, one-line errors with exit status 2."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

import vpsim
from vpsim.cli.main import main

JSON_KEYS = {
    "method",
    "cycle",
    "driver",
    "fuel_l_per_100km",
    "fuel_kg",
    "distance_km",
    "cpu_time_s",
    "steps",
    "trace_miss_s",
}


def run(capsys, *args):
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def test_simulate_json_backward(capsys):
    code, out, err = run(capsys, "simulate", "--cycle", "nedc", "--method", "backward", "--json")
    assert code == 0, err
    d = json.loads(out)
    assert JSON_KEYS <= set(d)
    assert d["method"] == "backward" and d["cycle"] == "nedc" and d["driver"] is None
    # the command prints what the library computes (whose level tests/test_backward.py checks against a
    # hand calculation)
    assert d["fuel_l_per_100km"] == pytest.approx(
        vpsim.simulate("nedc", method="backward").fuel_l_per_100km, rel=1e-12
    )
    assert d["steps"] == 1180 and d["trace_miss_s"] == 0
    # US mpg: 100 km / 3.785411784 L per 1.609344 km = 235.2145833 / (L/100 km); a preset has no measurement
    assert d["fuel_economy_mpg"] == pytest.approx(235.2145833 / d["fuel_l_per_100km"], rel=1e-9)
    assert d["measured_mpg"] is None and d["measured_error_pct"] is None


@pytest.mark.parametrize("command", ["simulate", "params"])
def test_preset_is_another_name_for_vehicle(capsys, command):
    """The documents call the built-in cars presets, so --preset names the same option as --vehicle."""
    by_vehicle = run(capsys, command, "--vehicle", "mhev", "--json")
    by_preset = run(capsys, command, "--preset", "mhev", "--json")
    assert by_vehicle[0] == by_preset[0] == 0, by_preset[2]
    a, b = json.loads(by_vehicle[1]), json.loads(by_preset[1])
    if command == "simulate":
        a.pop("cpu_time_s"), b.pop("cpu_time_s")
        assert a["vehicle"] == "mhev"
    assert a == b


def test_simulate_runs_an_ftp_bag_by_name(capsys):
    """The fleet's cycles are cycles of `vpsim simulate` too: bag 2 of FTP-75 is UDDS 505-1369 s (864
    intervals), 3.86 mi (EPA's FTP description: 7.45 mi in all, bag 1 3.59 mi)."""
    code, out, err = run(capsys, "simulate", "--cycle", "ftp_bag2", "--method", "backward", "--json")
    assert code == 0, err
    d = json.loads(out)
    assert d["cycle"] == "ftp_bag2" and d["steps"] == 864
    assert d["distance_km"] == pytest.approx(3.86 * 1.609344, abs=0.01)


def test_simulate_text_and_out(capsys, tmp_path):
    code, out, _ = run(capsys, "simulate", "--cycle", "ftp75", "--out", str(tmp_path / "o"))
    assert code == 0
    assert "L/100 km" in out
    for f in ("timeseries.csv", "summary.json", "timeseries.png"):
        assert (tmp_path / "o" / f).stat().st_size > 100


def test_simulate_json_driver_is_a_number_and_paths_are_clean(capsys, tmp_path):
    code, out, err = run(capsys, "simulate", "--method", "inverse", "--driver", "2", "--json")
    assert code == 0, err
    assert json.loads(out)["driver"] == 2
    code, out, err = run(capsys, "simulate", "--method", "inverse", "--out", f"{tmp_path / 'res'}/")
    assert code == 0, err
    assert f"wrote {tmp_path / 'res' / 'timeseries.csv'}\n" in out and "//" not in out
    assert json.loads((tmp_path / "res" / "summary.json").read_text())["driver"] == 2  # the realistic default
    # numbers to meaningful digits: no float noise such as 852.5000000000008 in the CSV
    rows = (tmp_path / "res" / "timeseries.csv").read_text().splitlines()[1:]
    mantissas = (x.lower().split("e")[0].lstrip("-").replace(".", "") for r in rows for x in r.split(","))
    assert max(len(m.lstrip("0")) for m in mantissas) <= 10


def test_maps_writes_figures_and_csv(capsys, tmp_path):
    code, out, _ = run(capsys, "maps", "--out", str(tmp_path))
    assert code == 0
    for f in (
        "figure2_torque_lines.png",
        "figure2_torque_lines.csv",
        "figure3_fuel_map.png",
        "figure3_fuel_map.csv",
    ):
        assert (tmp_path / f).stat().st_size > 100


@pytest.mark.parametrize(
    ("args", "match", "files"),
    [
        (["simulate", "--cycle", "nope"], "unknown cycle 'nope'", {}),
        (
            ["simulate", "--cycle", "{d}/bad.csv"],
            "bad.csv:4: time 1 does not increase",
            {"bad.csv": "time_s,speed_mps\n0,0\n1,1\n1,2\n"},
        ),
        (
            ["simulate", "--cycle", "{d}/nan.csv"],
            "nan.csv:3: speed is nan",
            {"nan.csv": "time_s,speed_mps\n0,0\n1,nan\n"},
        ),
        (
            ["simulate", "--cycle", "{d}/neg.csv"],
            "neg.csv:3: speed -1 is negative",
            {"neg.csv": "time_s,speed_kmh\n0,0\n1,-1\n"},
        ),
        (
            ["simulate", "--cycle", "{d}/one.csv"],
            "a cycle needs at least two",
            {"one.csv": "time_s,speed_mps\n0,0\n"},
        ),
        (
            ["simulate", "--vehicle", "{d}/car.toml"],
            "vehicle.mass = -1",
            {"car.toml": "[vehicle]\nmass = -1.0\n"},
        ),
        (
            ["simulate", "--vehicle", "{d}/car.toml"],
            "engine.bore = 90",
            {"car.toml": "[engine]\nbore = 90.0\n"},
        ),
        (["simulate", "--method", "backward", "--driver", "1"], "--driver applies to", {}),
    ],
)
def test_bad_input_is_one_line_exit_2(capsys, tmp_path, args, match, files):
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    args = [a.format(d=tmp_path) for a in args]
    code, out, err = run(capsys, *args)
    assert code == 2
    assert match in err, err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_console_script_exit_status():
    """The installed entry point: error on stderr, status 2, no traceback."""
    p = subprocess.run(
        [sys.executable, "-m", "vpsim", "simulate", "--cycle", "nope"], capture_output=True, text=True
    )
    assert p.returncode == 2
    assert p.stderr.startswith("vpsim: error: unknown cycle") and "Traceback" not in p.stderr
