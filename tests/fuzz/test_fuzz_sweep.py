"""Hostile sweep specs and damaged sweep stores: one line, and on --resume the damage is recomputed."""

from __future__ import annotations

import os

import pandas as pd
import pytest
from _fuzz import run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vpsim.sweep import SpecError, load_results, load_spec

SPEC = 'acceleration = false\nbaseline = false\n[parameters]\n"engine.bore" = [0.08, 0.085, 0.09]\n'

SPEC_CASES = [
    (
        '[parameters]\n"engine.bore" = { range = [0.08, 0.09], n = 1000000000000000000 }\n',
        "n = 1000000000000000000",
    ),
    ('[parameters]\n"engine.bore" = { range = [0.08, 0.09] }\n', "needs n = N levels"),
    ('[parameters]\n"engine.bore" = [0.08, true]\n', "True is not a number"),
    ('[parameters]\n"engine.bore" = [0.08, nan]\n', "nan is not a number"),
    ('[parameters]\n"engine.bore" = { range = [0.08, inf], n = 2 }\n', "low < high"),
    ('[parameters]\n"engine.cylinders" = [4, 100000]\n', "outside the plausible range [1, 16]"),
    ('[parameters]\n"engine.map_speed_range" = [[50, 300, 650]]\n', "cannot be swept"),
    (
        '[parameters]\n"transmission.gearbox_ratios" = { values = [[3.0, true, 1, 0.9, 0.7]] }\n',
        "list of gear",
    ),
    (
        '[parameters]\n"engine.bore" = { range = [0.08, 0.09], n = 3000 }\n'
        '"vehicle.mass" = { range = [1000, 2000], n = 3000 }\n',
        "more than the limit",
    ),
    ('sampling = "lhs"\nsamples = 0\n', "samples = 0"),
    ("cycles = []\n", "non-empty list"),
    ('cycles = ["missing.csv"]\n', "no such file"),
    ('cycles = ["still.csv"]\n', "still.csv drives no distance"),
    ('methods = ["sideways"]\n', "unknown method"),
    ("drivers = [7]\n", "driver '7' is not defined"),
    ('base = "missing.toml"\n', "base: "),
    ("base = 3\n", "base = 3"),
    ("seed = -1\n", "seed"),
    ("name = 3\n", "name = 3"),
    ("unknown = 1\n", "unknown key"),
    ("[acceleration]\nshift_fraction = 2\n", "at most 1"),
    ("[acceleration]\nshift_speed = 5000\nlaunch_speed = 100\n", "rad/s, not rpm"),
    ("[parameters\n", "not valid TOML"),
]


@pytest.mark.parametrize(("text", "match"), SPEC_CASES, ids=[f"spec{k}" for k in range(len(SPEC_CASES))])
def test_hostile_spec(tmp_path, text, match):
    (tmp_path / "still.csv").write_text("time_s,speed_kmh\n0,0\n10,0\n")
    p = tmp_path / "s.toml"
    p.write_text(text)
    with pytest.raises(SpecError) as exc:
        load_spec(p)
    assert match in str(exc.value) and "\n" not in str(exc.value) and "s.toml" in str(exc.value)


@pytest.mark.parametrize("raw", [b"name = '\xff'\n", "name = 'x'\n".encode("utf-16"), b"\x00"])
def test_spec_encodings_in_the_cli(capsys, tmp_path, raw):
    p = tmp_path / "s.toml"
    p.write_bytes(raw)
    code, _, err = run_cli(capsys, "sweep", p, "--out", tmp_path / "o", "--quiet")
    assert code == 2 and "not a text file" in err


def _sweep(capsys, tmp_path, *extra):
    spec = tmp_path / "s.toml"
    spec.write_text(SPEC)
    return run_cli(
        capsys,
        "sweep",
        spec,
        "--out",
        tmp_path / "o",
        "--quiet",
        "--no-plots",
        "--workers",
        "1",
        "--chunk-size",
        "1",
        *extra,
    )


@pytest.mark.parametrize(
    "damage",
    ["truncate", "empty", "garble"],
)
def test_damaged_parquet_part_is_named_and_recomputed(capsys, tmp_path, damage):
    assert _sweep(capsys, tmp_path)[0] == 0
    parts = sorted((tmp_path / "o" / "results.parquet").glob("part-*.parquet"))
    assert len(parts) == 3
    data = parts[1].read_bytes()
    if damage == "truncate":
        parts[1].write_bytes(data[: len(data) // 2])
    elif damage == "empty":
        parts[1].write_bytes(b"")
    else:
        parts[1].write_bytes(data[:200] + bytes(b ^ 0x55 for b in data[200:260]) + data[260:])
    with pytest.raises(SpecError, match=f"{parts[1].name}: damaged sweep result part") as exc:
        load_results(tmp_path / "o")
    assert "\n" not in str(exc.value)
    code, out, _ = _sweep(capsys, tmp_path, "--resume")
    assert code == 0 and f"found 1 damaged result part(s) in {tmp_path / 'o'}" in out
    assert "3 rows: 1 computed now, 2 already present" in out
    df = load_results(tmp_path / "o")
    assert len(df) == 3 and df["point_id"].is_unique and df["error"].isna().all()


@pytest.mark.parametrize("damage", ["half_row", "empty", "garble_middle", "cut_tail"])
def test_damaged_csv_rows_are_not_counted_as_done(capsys, tmp_path, damage):
    assert _sweep(capsys, tmp_path, "--format", "csv")[0] == 0
    f = tmp_path / "o" / "results.csv"
    data = f.read_bytes()
    lines = data.split(b"\n")
    if damage == "half_row":  # a row cut in half, the next one intact
        lines[2] = lines[2][: len(lines[2]) // 2]
        f.write_bytes(b"\n".join(lines))
    elif damage == "empty":
        f.write_bytes(b"")
    elif damage == "garble_middle":
        lines[2] = lines[2].replace(b"nedc", b"nedx")
        f.write_bytes(b"\n".join(lines))
    else:  # the last write cut short by a kill: not a damaged block, an unfinished one
        f.write_bytes(data[:-10])
    if damage != "cut_tail":
        with pytest.raises(SpecError, match="damaged sweep results"):
            load_results(tmp_path / "o")
    code, out, _ = _sweep(capsys, tmp_path, "--resume")
    assert code == 0
    df = load_results(tmp_path / "o")
    assert len(df) == 3 and df["point_id"].is_unique
    assert not df["cycle"].eq("nedx").any()
    assert pd.api.types.is_float_dtype(df["fuel_l_per_100km"]) and df["fuel_l_per_100km"].notna().all()


def test_garbled_sweep_record_is_one_line(capsys, tmp_path):
    assert _sweep(capsys, tmp_path)[0] == 0
    for text in ("garbage", "[1, 2]", '{"schema": 3}', ""):
        (tmp_path / "o" / "sweep.json").write_text(text)
        code, _, err = _sweep(capsys, tmp_path, "--resume")
        assert code == 2 and "sweep.json" in err


def test_out_is_a_file(capsys, tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text(SPEC)
    (tmp_path / "file").write_text("x")
    code, _, err = run_cli(capsys, "sweep", spec, "--out", tmp_path / "file", "--quiet")
    assert code == 2


def test_csv_store_of_an_earlier_version_is_kept_when_resumed_twice(capsys, tmp_path):
    """A results.csv without the block manifest: verified by reading it, then recorded, so that the rows
    appended by a resume (and a second resume) follow it instead of being taken for damage."""
    spec = tmp_path / "s.toml"
    spec.write_text(SPEC)
    assert _sweep(capsys, tmp_path, "--format", "csv")[0] == 0
    out = tmp_path / "o"
    (out / ".results.csv.sums").unlink()  # as written before the manifest existed
    lines = (out / "results.csv").read_bytes().split(b"\n")
    (out / "results.csv").write_bytes(b"\n".join(lines[:3]) + b"\n")  # header + 2 of the 3 rows
    code, out_text, _ = _sweep(capsys, tmp_path, "--resume")
    assert code == 0 and "1 computed now, 2 already present" in out_text and "damaged" not in out_text
    code, out_text, _ = _sweep(capsys, tmp_path, "--resume")
    assert code == 0 and "0 computed now, 3 already present" in out_text and "damaged" not in out_text
    assert len(load_results(out)) == 3


_num = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**20), 10**20),
    st.booleans(),
    st.text(max_size=4),
)
_param = st.sampled_from(
    [
        "engine.bore",
        "engine.cylinders",
        "vehicle.mass",
        "transmission.gearbox_ratios[2]",
        "engine.lambda",
        "engine.map_speed_range",
        "drivers.1.inverse_a",
        "nonsense.x",
        "transmission.gearbox_ratios",
    ]
)
_axis = st.one_of(
    st.lists(_num, max_size=4),
    st.fixed_dictionaries({"range": st.lists(_num, max_size=3)}, optional={"n": _num}),
    st.fixed_dictionaries({"values": st.lists(st.one_of(_num, st.lists(_num, max_size=5)), max_size=3)}),
    _num,
)
_top = st.fixed_dictionaries(
    {},
    optional={
        "sampling": st.sampled_from(["factorial", "lhs", "grid", ""]),
        "samples": _num,
        "seed": _num,
        "cycles": st.one_of(st.lists(st.sampled_from(["nedc", "udds", "nope", "", 3]), max_size=3), _num),
        "methods": st.lists(st.sampled_from(["backward", "forward", "inverse", "sideways"]), max_size=3),
        "drivers": st.lists(st.one_of(st.integers(-1, 4), st.text(max_size=2)), max_size=3),
        "mode": st.sampled_from(["paper", "extended", "x"]),
        "gears": st.sampled_from(["baseline", "per_design", "x"]),
        "baseline": _num,
        "acceleration": st.one_of(
            st.booleans(),
            st.dictionaries(
                st.sampled_from(["enabled", "shift_speed", "shift_fraction", "launch_speed", "x"]),
                _num,
                max_size=3,
            ),
        ),
    },
)


def _toml_value(v) -> str:
    import json
    import math

    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(v)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(top=_top, params=st.dictionaries(_param, _axis, max_size=3))
def test_random_specs_are_valid_or_one_line(tmp_path, top, params):
    text = "".join(f"{k} = {_toml_value(v)}\n" for k, v in top.items())
    text += "[parameters]\n" + "".join(f'"{k}" = {_toml_value(v)}\n' for k, v in params.items())
    p = tmp_path / "r.toml"
    p.write_text(text)
    try:
        spec = load_spec(p)
    except SpecError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 1000
        return
    assert 1 <= spec.n_designs <= 5_000_000
    if spec.n_designs <= 1000:
        assert len(spec.designs()) == spec.n_designs + (1 if spec.baseline else 0)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_a_fifo_in_the_output_folder_does_not_block_a_resume(capsys, tmp_path):
    """A sweep record or result part that is a FIFO: one line or a damaged part, never a read that blocks."""
    pytest.importorskip("pyarrow")
    assert _sweep(capsys, tmp_path, "--format", "parquet")[0] == 0
    out = tmp_path / "o"
    parts = sorted((out / "results.parquet").glob("part-*.parquet"))
    assert parts
    parts[0].unlink()
    os.mkfifo(parts[0])
    _sweep(capsys, tmp_path, "--format", "parquet", "--resume")  # recomputed, or refused in one line
    parts[0].unlink(missing_ok=True)
    (out / "sweep.json").unlink()
    os.mkfifo(out / "sweep.json")
    code, _, err = _sweep(capsys, tmp_path, "--format", "parquet", "--resume")
    assert code == 2 and "sweep.json" in err and "not a regular file" in err
