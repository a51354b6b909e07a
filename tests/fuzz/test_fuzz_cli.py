"""Every command on hostile options: exit 2 with one line on stderr, or a meaningful result; never a
traceback. Most cases run in this process through ``main``; a few through the installed entry point."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from _fuzz import NAN_WORD, check_answer, check_json, child_env, run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vpsim.cli import main as cli_main

STILL = "time_s,speed_kmh\n0,0\n10,0\n"
SHORT = "time_s,speed_kmh\n0,0\n1,20\n2,20\n3,0\n"

CASES = [
    ["--nonsense"],
    ["simulate", "--method", "sideways"],
    ["simulate", "--driver", "3"],
    ["simulate", "--method", "backward", "--driver", "1"],
    ["simulate", "--cycle", ""],
    ["simulate", "--cycle", "nope"],
    ["simulate", "--cycle", "nope.csv"],
    ["simulate", "--cycle", "{d}"],
    ["simulate", "--vehicle", ""],
    ["simulate", "--vehicle", "{d}"],
    ["simulate", "--vehicle", "{d}/missing.toml"],
    ["simulate", "--gears", "{d}"],
    ["simulate", "--gears", "{d}/missing.csv"],
    ["simulate", "--speed-unit", "furlongs"],
    ["simulate", "--out", "{d}/afile"],
    ["simulate", "--out", "/proc/1/forbidden"],
    ["simulate", "--out", "{d}/afile/sub"],
    ["simulate", "--mode", "sport"],
    ["params", "--vehicle", "saab"],
    ["params", "--unknown"],
    ["maps", "--out", "{d}/afile"],
    ["maps", "--out", "/proc/1/forbidden"],
    ["maps"],
    ["engine", "import", "{d}"],
    ["engine", "import", "{d}/missing.m"],
    ["engine", "import", "{d}/still.csv"],
    ["engine", "import"],
    [
        "scaling",
        "--measured",
        "{d}/missing.m",
        "--bore",
        "0.07",
        "--stroke",
        "0.07",
        "--cylinders",
        "3",
        "--out",
        "{d}/o",
    ],
    [
        "scaling",
        "--measured",
        "{d}/e.json",
        "--bore",
        "nan",
        "--stroke",
        "0.07",
        "--cylinders",
        "3",
        "--out",
        "{d}/o",
    ],
    [
        "scaling",
        "--measured",
        "{d}/e.json",
        "--bore",
        "inf",
        "--stroke",
        "0.07",
        "--cylinders",
        "3",
        "--out",
        "{d}/o",
    ],
    [
        "scaling",
        "--measured",
        "{d}/e.json",
        "--bore",
        "0.07",
        "--stroke",
        "0.07",
        "--cylinders",
        "0",
        "--out",
        "{d}/o",
    ],
    [
        "scaling",
        "--measured",
        "{d}/e.json",
        "--bore",
        "0.07",
        "--stroke",
        "0.07",
        "--cylinders",
        "100000",
        "--out",
        "{d}/o",
    ],
    [
        "scaling",
        "--measured",
        "{d}/e.json",
        "--bore",
        "0.07",
        "--stroke",
        "0.07",
        "--cylinders",
        "x",
        "--out",
        "{d}/o",
    ],
    [
        "scaling",
        "--measured",
        "{d}/e.json",
        "--bore",
        "0.082",
        "--stroke",
        "0.09",
        "--cylinders",
        "4",
        "--cycles",
        ",",
        "--out",
        "{d}/o",
    ],
    [
        "scaling",
        "--measured",
        "{d}/e.json",
        "--bore",
        "0.082",
        "--stroke",
        "0.09",
        "--cylinders",
        "4",
        "--cycles",
        "{d}/still.csv",
        "--out",
        "{d}/o",
    ],
    [
        "scaling",
        "--measured",
        "{d}/e.json",
        "--bore",
        "0.082",
        "--stroke",
        "0.09",
        "--cylinders",
        "4",
        "--out",
        "/proc/1/x",
    ],
    ["bench", "--json", "/proc/1/x.json", "--tiny", "--no-peer"],
    ["paper", "--out", "/proc/1/x", "--repeats", "1"],
    ["paper", "--out", "{d}/p", "--repeats", "0"],
    ["paper", "--out", "{d}/p", "--repeats", "1", "--vehicle", "{d}/bad.toml"],
    ["paper", "--out", "{d}/p", "--advisor-dir", "{d}/none", "--repeats", "1"],
    ["sweep", "{d}/missing.toml", "--out", "{d}/o"],
    ["sweep", "{d}", "--out", "{d}/o"],
    ["sweep", "{d}/s.toml", "--out", "{d}/o", "--workers", "0"],
    ["sweep", "{d}/s.toml", "--out", "{d}/o", "--workers", "100000"],
    ["sweep", "{d}/s.toml", "--out", "{d}/o", "--scheduler", "nonsense"],
    ["sweep", "{d}/s.toml", "--out", "{d}/o", "--local-cluster", "100000"],
    ["sweep", "{d}/s.toml", "--out", "{d}/o", "--chunk-size", "-5"],
    ["sweep", "{d}/s.toml", "--out", "{d}/o", "--scheduler", "x", "--local-cluster", "1"],
    ["sweep", "{d}/s.toml", "--out", "{d}/afile"],
    ["charge-balance", "--vehicle", "hofman2011"],
    ["charge-balance", "--vehicle", "bev"],
    ["charge-balance", "--ems", "dp"],
    ["charge-balance", "--soc-offsets", ""],
    ["charge-balance", "--soc-offsets", "nan,0,0.1"],
    ["charge-balance", "--soc-offsets", "0,0,0"],
    ["charge-balance", "--soc-offsets", "-2,0,2"],
    ["charge-balance", "--cycle", "{d}/still.csv"],
    ["charge-balance", "--plot", "{d}/afile/sub.png"],
    ["simulate", "--vehicle", "{d}/ss.toml", "--method", "forward", "--mode", "paper"],
]


@pytest.fixture
def d(tmp_path):
    (tmp_path / "afile").write_text("x")
    (tmp_path / "still.csv").write_text(STILL)
    (tmp_path / "ss.toml").write_text('base = "hofman2011"\n[simulation]\nstop_start = true\n')
    (tmp_path / "bad.toml").write_text("[engine]\ncylinders = 0\n")
    (tmp_path / "s.toml").write_text('[parameters]\n"engine.bore" = [0.08, 0.09]\n')
    (tmp_path / "e.json").write_text(
        json.dumps(
            {
                "fc_map_spd": [100.0, 200.0, 300.0],
                "fc_map_trq": [10.0, 50.0, 100.0],
                "fc_fuel_map": [[0.5, 1.5, 3.0], [1.0, 3.0, 6.0], [1.5, 4.5, 9.0]],
                "fc_max_trq": [100.0, 100.0, 100.0],
                "fc_inertia": 0.1,
                "fc_disp": 1.9,
                "fc_fuel_den": 749.0,
                "fc_fuel_lhv": 42600.0,
            }
        )
    )
    return tmp_path


@pytest.mark.parametrize("args", CASES, ids=[" ".join(a)[:60] for a in CASES])
def test_bad_options_are_one_line_exit_2(capsys, d, args):
    code, out, err = run_cli(capsys, *[a.format(d=d) for a in args])
    assert code == 2, (out, err)


@pytest.mark.parametrize("method", ["backward", "forward", "inverse"])
@pytest.mark.parametrize("cycle", ["still", "short"])
def test_json_is_always_valid(capsys, tmp_path, method, cycle):
    p = tmp_path / f"{cycle}.csv"
    p.write_text(STILL if cycle == "still" else SHORT)
    code, out, _ = run_cli(capsys, "simulate", "--cycle", p, "--method", method, "--json")
    assert code == 0
    s = check_json(out)
    if cycle == "still":
        assert s["fuel_l_per_100km"] is None and s["fuel_l_per_100km_undefined"]
        assert s["fuel_economy_mpg"] is None and "no distance" in s["fuel_economy_mpg_undefined"]
    code, out, _ = run_cli(
        capsys, "simulate", "--cycle", p, "--method", method, "--mode", "extended", "--out", tmp_path / "o"
    )
    assert code == 0
    check_json((tmp_path / "o" / "summary.json").read_text())
    csv_text = (tmp_path / "o" / "timeseries.csv").read_text()
    assert not NAN_WORD.search(csv_text)


def test_output_helper_never_prints_nan():
    from vpsim.cli._output import dumps, number

    text = dumps({"fuel_l_per_100km": float("nan"), "x": [float("inf"), 1.0], "y": {"z": float("-inf")}})
    data = check_json(text)
    assert data["fuel_l_per_100km"] is None and "no distance" in data["fuel_l_per_100km_undefined"]
    assert data["x"] == [None, 1.0] and data["y"]["z"] is None and data["y"]["z_undefined"]
    assert number(float("nan"), ".3f", "fuel_l_per_100km").startswith("undefined (")
    assert number(1.23456, ".2f") == "1.23"


def test_unexpected_exception_is_one_line_exit_3(capsys, monkeypatch):
    from vpsim.cli import simulate as sim

    def boom(*a, **k):
        raise KeyError("boom")

    monkeypatch.setattr(sim, "_out_dir", boom)
    monkeypatch.delenv("VPSIM_DEBUG", raising=False)
    code = cli_main.main(["simulate", "--out", "x"])
    out, err = capsys.readouterr()
    assert code == 3 and err.count("\n") == 1
    assert err.startswith("vpsim: internal error: KeyError: 'boom' (please report; rerun with VPSIM_DEBUG=1")
    monkeypatch.setenv("VPSIM_DEBUG", "1")
    code = cli_main.main(["simulate", "--out", "x"])
    out, err = capsys.readouterr()
    assert code == 3 and "Traceback" in err


def test_no_arguments_prints_help(capsys):
    assert cli_main.main([]) == 0
    out, err = capsys.readouterr()
    assert "Usage" in out and err == ""


def test_entry_point_in_a_subprocess(tmp_path):
    (tmp_path / "bad.toml").write_bytes(b"[vehicle]\nmass = 1\xff\n")
    for args, status in [
        (["simulate", "--vehicle", "bad.toml"], 2),
        (["simulate", "--cycle", "nedc", "--json"], 0),
        (["--version"], 0),
        (["simulate", "--bogus"], 2),
    ]:
        p = subprocess.run(
            [sys.executable, "-m", "vpsim", *args],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=120,
            env=child_env(VPSIM_DEBUG="0"),
        )
        assert p.returncode == status, p.stderr
        check_answer(p.returncode, p.stdout, p.stderr, as_json="--json" in args)


def test_broken_stdout_pipe_is_not_a_traceback(tmp_path):
    p = subprocess.run(
        f"{sys.executable} -m vpsim params | head -c 10 > /dev/null",
        shell=True,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        env=child_env(),
    )
    assert "Traceback" not in p.stderr


def test_python_warnings_are_one_line(capsys, monkeypatch, tmp_path):
    import warnings

    from vpsim.cli import simulate as sim

    real = sim._out_dir

    def warn_then_create(out):
        warnings.warn("overflow encountered in multiply", RuntimeWarning, stacklevel=1)
        return real(out)

    monkeypatch.setattr(sim, "_out_dir", warn_then_create)
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        code = cli_main.main(["simulate", "--out", str(tmp_path / "o"), "--cycle", "nedc"])
    out, err = capsys.readouterr()
    assert code == 0
    assert err.count("\n") == 1
    assert err.startswith("vpsim: warning: RuntimeWarning: overflow encountered in multiply (test_fuzz_cli")


def test_standard_error_text_nan_becomes_null_with_a_reason():
    from vpsim.cli._output import dumps

    data = check_json(dumps({"parameters": {"eta": {"value": 0.25, "std_error": "nan"}}, "name": "nan"}))
    assert data["parameters"]["eta"]["std_error"] is None
    assert "bound" in data["parameters"]["eta"]["std_error_undefined"]
    assert data["name"] == "nan"  # a name is text, not a figure


_OPTION_VALUES = {
    "--cycle": ["nedc", "{d}/short.csv", "{d}/still.csv", "{d}", "", "nope", "{d}/afile", "NEDC", "wltc"],
    "--method": ["backward", "forward", "inverse", "x", ""],
    "--driver": ["1", "2", "0", "x"],
    "--mode": ["paper", "extended", ""],
    "--vehicle": ["hofman2011", "geo_metro_1l", "{d}/bad.toml", "{d}", "{d}/still.csv", "x"],
    "--gears": ["{d}/g.csv", "{d}/still.csv", "{d}/afile", "{d}"],
    "--speed-unit": ["m/s", "km/h", "mph", "knots"],
    "--out": ["{d}/o", "{d}/afile", "/proc/1/x"],
}


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    options=st.dictionaries(st.sampled_from(sorted(_OPTION_VALUES)), st.integers(0, 100), max_size=4),
    as_json=st.booleans(),
)
def test_random_simulate_options(capsys, d, options, as_json):
    (d / "short.csv").write_text(SHORT)
    (d / "g.csv").write_text("time_s,gear\n0,1\n1,2\n")
    args = ["simulate"]
    for opt, k in options.items():
        pool = _OPTION_VALUES[opt]
        args += [opt, pool[k % len(pool)].format(d=d)]
    if as_json:
        args.append("--json")
    run_cli(capsys, *args)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ('cycles = ["a\\u0000b.csv"]\n', "cannot hold a NUL character"),
        ('base = "a\\u0000b.toml"\n', "cannot hold a NUL character"),
        ('cycles = ["' + "a" * 5000 + '.csv"]\n', "more than 4096"),
    ],
)
def test_file_names_that_cannot_be_files(capsys, tmp_path, text, match):
    spec = tmp_path / "s.toml"
    spec.write_text(text)
    code, _, err = run_cli(capsys, "sweep", spec, "--out", tmp_path / "o")
    assert code == 2 and match in err


def test_very_long_out_folder(capsys, tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text("[parameters]\n")
    code, _, err = run_cli(capsys, "sweep", spec, "--out", tmp_path / ("a" * 300) / ("b" * 300), "--quiet")
    assert code == 2 and "File name too long" in err
