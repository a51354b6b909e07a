"""``vpsim engine import`` and ``vpsim scaling``: summaries, JSON round trip, one-line errors with exit 2."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from vpsim.cli.main import main
from vpsim.engines import MeasuredEngine, load_engine
from vpsim.model import maps
from vpsim.scaling import TABLE4_COLUMNS


def run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code, out, err, *fragments):
    assert code == 2, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vpsim: error: "), err
    assert "Traceback" not in err
    for f in fragments:
        assert f in lines[0], lines[0]


@pytest.fixture
def model_engine_json(tmp_path, params):
    """A 'measured' engine whose map is the hofman2011 model's own BQM, in vpsim's JSON form."""
    eng = params.engine
    speeds = np.linspace(60.0, 600.0, 10)
    torques = np.linspace(10.0, 150.0, 8)
    t, w = np.meshgrid(torques, speeds)
    e = MeasuredEngine(
        name="model",
        speed_grid=speeds,
        torque_grid=torques,
        fuel_flow=maps.bqm_fuel_flow(t, w, eng),
        max_torque_speed=speeds,
        max_torque=maps.max_torque(speeds, eng),
        inertia=eng.inertia,
        displacement=eng.displacement,
        fuel_density=0.745,
        fuel_lhv=44e6,
        source="test",
    )
    return e.write_json(tmp_path / "model.json")


def test_engine_import_summary_and_json_round_trip(capsys, tmp_path, model_engine_json) -> None:
    code, out, err = run(capsys, "engine", "import", model_engine_json, "--out", tmp_path / "copy.json")
    assert code == 0, err
    for text in (
        "speed grid     10 points, 60.0-600.0 rad/s",
        "torque grid    8 points",
        "peak torque",
        "peak power",
        "min BSFC",
        "no zero-torque column",
        "wrote",
    ):
        assert text in out
    a, b = load_engine(model_engine_json), load_engine(tmp_path / "copy.json")
    np.testing.assert_allclose(a.fuel_flow, b.fuel_flow, rtol=1e-14)
    code, out, _ = run(capsys, "engine", "import", tmp_path / "copy.json", "--json")
    d = json.loads(out)
    assert code == 0 and d["name"] == "model" and d["speed_grid_radps"][2] == 10


def test_engine_import_advisor_file(capsys, shared_dir, tmp_path) -> None:
    src = shared_dir / "data" / "raw" / "advisor" / "FC_SI41_emis.m"
    code, out, err = run(capsys, "engine", "import", src, "--out", tmp_path / "geo.json")
    assert code == 0, err
    assert "peak torque    80.9 N m at 364.1 rad/s (3477 rpm)" in out
    assert "peak power     41.0 kW" in out and "min BSFC       247.9 g/kWh" in out
    geo = load_engine(tmp_path / "geo.json")
    np.testing.assert_allclose(geo.fuel_flow, load_engine(src).fuel_flow, rtol=1e-14)
    assert geo.closed_throttle_torque is not None


@pytest.mark.parametrize(
    ("name", "text", "fragments"),
    [
        ("shell.m", "fc_map_spd = [1 2];\nsystem('touch {marker}');\n", ("shell.m:2:",)),
        ("bang.m", "fc_map_spd = [1 2];\n!touch {marker}\n", ("bang.m:2:",)),
        ("eval.m", "x = 1;\neval('system(''touch {marker}'')');\n", ("eval.m:2:",)),
        ("huge.m", "x = ones(1e5, 1e5);\n", ("huge.m:1:",)),
        ("nan.json", '{{"fc_map_spd": [NaN, 2]}}', ("nan.json", "NaN")),
        ("list.json", "[1, 2, 3]", ("list.json", "JSON object")),
        ("engine.mat", "binary", ("unsupported engine file type",)),
    ],
)
def test_engine_import_hostile_file(capsys, tmp_path, name, text, fragments) -> None:
    marker = tmp_path / "MARKER"
    f = tmp_path / name
    f.write_text(text.format(marker=marker))
    code, out, err = run(capsys, "engine", "import", f)
    assert_one_line_error(code, out, err, *fragments)
    assert not marker.exists()


def test_engine_import_bad_paths(capsys, tmp_path, model_engine_json) -> None:
    assert_one_line_error(*run(capsys, "engine", "import", tmp_path / "missing.m"), "missing.m")
    assert_one_line_error(*run(capsys, "engine", "import", tmp_path / "missing.json"), "missing.json")
    assert_one_line_error(
        *run(capsys, "engine", "import", model_engine_json, "--out", tmp_path / "x.m"), "must be a .json file"
    )
    code, out, err = run(capsys, "engine", "import")
    assert code == 2 and "Missing argument" in err


def test_scaling_command(capsys, tmp_path, model_engine_json) -> None:
    out_dir = tmp_path / "sc"
    code, out, err = run(
        capsys,
        "scaling",
        "--measured",
        model_engine_json,
        "--bore",
        0.09,
        "--stroke",
        0.09,
        "--cylinders",
        4,
        "--cycles",
        "nedc",
        "--calibrate",
        "--calibration-cycles",
        "udds",
        "--out",
        out_dir,
    )
    assert code == 0, err
    assert "nedc" in out and "fitted thermal_efficiency" in out
    for f in ("figure7.png", "map_comparison.csv", "map_stats.json", "fuel.csv", "calibration.json"):
        assert (out_dir / f).stat().st_size > 100, f
    with (out_dir / "fuel.csv").open() as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames[: len(TABLE4_COLUMNS)]) == TABLE4_COLUMNS
        (row,) = list(reader)
    # the model against its own map: small differences from reading the map between and outside nodes
    assert abs(float(row["error_pct"])) < 3.0 and abs(float(row["calibrated_error_pct"])) < 3.0
    stats = json.loads((out_dir / "map_stats.json").read_text())
    assert stats["nodes"]["p90_abs_pct"] < 1e-6
    cal = json.loads((out_dir / "calibration.json").read_text())
    assert cal["parameters"]["thermal_efficiency"]["value"] == pytest.approx(0.38, rel=0.02)


def test_scaling_command_errors(capsys, tmp_path, model_engine_json) -> None:
    base = [
        "scaling",
        "--measured",
        model_engine_json,
        "--stroke",
        0.077,
        "--cylinders",
        3,
        "--out",
        tmp_path,
    ]
    assert_one_line_error(*run(capsys, *base, "--bore", 74), "did you mean 0.074")
    assert_one_line_error(*run(capsys, *base, "--bore", 0.074, "--cycles", "nope"), "nope")
    assert_one_line_error(*run(capsys, *base, "--bore", 0.074, "--cycles", " , "), "--cycles")
    assert_one_line_error(
        *run(
            capsys,
            "scaling",
            "--measured",
            tmp_path / "x.m",
            "--bore",
            0.07,
            "--stroke",
            0.07,
            "--cylinders",
            3,
            "--out",
            tmp_path,
        ),
        "x.m",
    )


def test_help_texts(capsys) -> None:
    for args in (("engine", "--help"), ("engine", "import", "--help"), ("scaling", "--help")):
        code, out, _ = run(capsys, *args)
        assert code == 0 and "Usage" in out
