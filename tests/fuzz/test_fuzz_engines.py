"""Hostile ADVISOR .m and JSON engine files: bounded work, one line, sanity against the file's metadata."""

from __future__ import annotations

import json
import time

import pytest
from _fuzz import SHARED as SHARED_ROOT
from _fuzz import run_cli, run_limited
from hypothesis import given, settings
from hypothesis import strategies as st

from vpsim.engines import load_engine
from vpsim.engines.matlab import evaluate_m_text
from vpsim.errors import EngineFileError

SHARED = SHARED_ROOT / "data"
GEO_M = SHARED / "raw" / "advisor" / "FC_SI41_emis.m"
GEO_JSON = SHARED / "engines" / "FC_SI41_emis.json"

M_CASES = [
    ("c = {1}; for k=1:100, c = {c c}; end", "cell array would hold"),
    ("c = {1};\nfor k=1:10000\n c = {c};\nend", "cell arrays nested 33 deep"),
    ("c = {1}; for k=1:30, c = {c c c}; end; d = c(ones(1, 100000));", "cell array would hold"),
    ("a = zeros(1, 999999);\n" + "".join(f"b{k} = a;\n" for k in range(20)), "the variables left at the end"),
    ("x = 1:1e12;", "more than 1000000 elements"),
    ("x = zeros(1e6, 1e6);", "elements"),
    ("for k = 1:1e6, for j = 1:1e6, end, end", "more than"),
    ("x = " + "(" * 200 + "1" + ")" * 200 + ";", "nested more than 32 deep"),
    ("x = " + "+".join(["1"] * 5000) + ";", "too long or too deeply nested"),
    ("x = 1e400;", "overflow"),
    ("x = NaN;", "NaN"),
    ("system('rm -rf /')", "system"),
    ("!ls", "shell"),
    ("x = @(t) t;", "@"),
    ("eval('x = 1; system(1)')", "eval"),
    ("x = [1 2; 3];", "dimensions"),
    ("x = 'unclosed", "not closed"),
    ("x = y + 1;", "y"),
    ("x = find(ones(1, 1e12));", "more than"),
    ("x = fliplr(zeros(1e6, 1e6));", "more than"),
    ("a = ones(1, 999999); for k = 1:200, b = find(a); end", "too much computation"),
    ("[i, j] = find(1);", "find"),
    ("x = isempty(1, 2);", "isempty"),
    ("clear *", "only variable names"),
]


@pytest.mark.parametrize(("text", "match"), M_CASES, ids=[f"m{k}" for k in range(len(M_CASES))])
def test_hostile_m_text_is_bounded_and_one_line(text, match):
    t0 = time.perf_counter()
    with pytest.raises(EngineFileError) as exc:
        evaluate_m_text(text, "f.m")
    msg = str(exc.value)
    assert msg.startswith("f.m:") and "\n" not in msg and len(msg) < 400
    assert match.lower() in msg.lower(), msg
    assert time.perf_counter() - t0 < 30


def test_cell_doubling_of_the_issue_in_a_memory_limited_process(tmp_path):
    (tmp_path / "cells.m").write_text("c = {1}; for k=1:100, c = {c c}; end\n")
    (tmp_path / "deep.m").write_text("c = {1};\nfor k=1:10000\n  c = {c};\nend\n")
    for name in ("cells.m", "deep.m"):
        p = run_limited(["engine", "import", name], cwd=tmp_path, timeout=60)
        assert p.returncode == 2 and "limit" in p.stderr


@pytest.mark.parametrize(
    "text",
    [
        "a = zeros(1, 999999); b = [a a a a]; c = {b b b b};\n" * 100_000,  # 5 MB: 35 s and 560 MB before
        "x = 1;\n" * 700_000,  # 30 s before
        "x = [" + "1 " * 2_500_000 + "];\n",  # one line: 50 s and 900 MB before
        "x = [" + "\n" * 4_000_000 + "];\n",  # rows without a token between them
    ],
    ids=["statements", "assignments", "one_row", "newlines"],
)
def test_a_5_mb_hostile_m_file_is_refused_in_seconds(tmp_path, text):
    """The issue's 5 MB hostile .m (30 s and 900 MB to refuse): the token bound stops it in a few seconds,
    under a 1 GB address-space limit in a process of its own."""
    (tmp_path / "h.m").write_text(text[: 5 * 1024 * 1024 - 16])
    t0 = time.perf_counter()
    p = run_limited(["engine", "import", "h.m"], cwd=tmp_path, timeout=60, memory=1024**3)
    assert p.returncode == 2 and "tokens" in p.stderr, p.stderr
    assert time.perf_counter() - t0 < 10


def _atoms():
    return st.sampled_from(
        [
            "x",
            "y",
            "c",
            "1",
            "2.5",
            "1e308",
            "-1",
            "[1 2 3]",
            "{1, 'a'}",
            "'t'",
            "zeros(3)",
            "ones(2,2)",
            "1:5",
            "c{1}",
            "x(2)",
            "x(end)",
            "size(x)",
            "length(c)",
            "pi",
            "Inf",
            "[x; x]",
            "{c c}",
            "x'",
        ]
    )


_expr = st.recursive(
    _atoms(),
    lambda inner: st.one_of(
        st.tuples(inner, st.sampled_from(["+", "-", "*", "/", ".*", "./", "^", "==", "&", ":"]), inner).map(
            lambda t: f"({t[0]} {t[1]} {t[2]})"
        ),
        inner.map(lambda e: "{" + e + "}"),
        inner.map(lambda e: "[" + e + " " + e + "]"),
    ),
    max_leaves=12,
)
_stmt = st.one_of(
    st.tuples(st.sampled_from(["x", "y", "c"]), _expr).map(lambda t: f"{t[0]} = {t[1]};"),
    st.tuples(st.integers(0, 40), st.sampled_from(["x", "c"]), _expr).map(
        lambda t: f"for k = 1:{t[0]}, {t[1]} = {t[2]}; end"
    ),
    st.text(alphabet="xyc=(){}[];:'+-*/\n %.1", max_size=30),
)


@settings(max_examples=200, deadline=None)
@given(program=st.lists(_stmt, max_size=6))
def test_random_m_programs_are_bounded(program):
    text = "x = [1 2 3]; y = 2; c = {1};\n" + "\n".join(program)
    t0 = time.perf_counter()
    try:
        evaluate_m_text(text, "r.m")
    except EngineFileError as exc:
        assert "\n" not in str(exc)
    assert time.perf_counter() - t0 < 20


JSON_BASE = {
    "fc_map_spd": [100.0, 200.0, 300.0],
    "fc_map_trq": [10.0, 50.0, 100.0],
    "fc_fuel_map": [[0.5, 1.5, 3.0], [1.0, 3.0, 6.0], [1.5, 4.5, 9.0]],
    "fc_max_trq": [100.0, 100.0, 100.0],
    "fc_inertia": 0.1,
    "fc_disp": 1.9,
    "fc_fuel_den": 749.0,
    "fc_fuel_lhv": 42600.0,
}


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"fc_fuel_den": 749e6}, "fuel_density"),
        ({"fc_fuel_lhv": 42.6}, "fuel_lhv"),
        ({"fc_disp": 1900.0}, "displacement"),
        ({"fc_fuel_map": [[0.005, 0.015, 0.03]] * 3}, "brake efficiency"),
        ({"fc_map_spd": [100.0, None, 300.0]}, "null or non-numeric"),
        ({"fc_map_spd": [100.0, 10**400, 300.0]}, "must be numeric"),
        ({"fc_map_spd": [300.0, 200.0, 100.0]}, "strictly increasing"),
        ({"fc_fuel_map": [[1.0, 2.0], [3.0, 4.0]]}, "shape"),
        ({"fc_fuel_type": ["x"]}, "fc_fuel_type"),
        ({"fc_inertia": "heavy"}, "must be numeric"),
        ({"units": {"fc_disp": "cc"}}, "expected 'L'"),
        ({"fc_disp": True}, "'fc_disp' holds true, expected numbers"),  # numpy reads true as 1
        ({"fc_fuel_map": [[0.5, 1.5, 3.0], [1.0, False, 6.0], [1.5, 4.5, 9.0]]}, "'fc_fuel_map' holds false"),
    ],
)
def test_hostile_engine_json(tmp_path, change, match):
    p = tmp_path / "e.json"
    p.write_text(json.dumps(JSON_BASE | change))
    with pytest.raises(EngineFileError) as exc:
        load_engine(p)
    assert match in str(exc.value) and "\n" not in str(exc.value)


@pytest.mark.parametrize(
    "raw",
    [
        b"",
        b"{",
        b"[1, 2]",
        b"NaN",
        b'{"fc_map_spd": NaN}',
        b"\xff\xfe{",
        b"[" * 100000,
        b'{"a": 1' + b"0" * 5000 + b"}",
    ],
)
def test_garbage_engine_json_is_one_line(capsys, tmp_path, raw):
    p = tmp_path / "g.json"
    p.write_bytes(raw)
    code, _, err = run_cli(capsys, "engine", "import", p)
    assert code == 2


def test_engine_json_with_bom_is_read(tmp_path):
    p = tmp_path / "e.json"
    p.write_bytes(b"\xef\xbb\xbf" + json.dumps(JSON_BASE).encode())
    assert load_engine(p).displacement == pytest.approx(1.9e-3)


def test_diesel_and_cng_maps_are_not_compared_in_litres_of_gasoline(capsys, tmp_path):
    for fuel, den, lhv in (("Diesel", 850.0, 42800.0), ("CNG", 0.75, 47000.0)):
        p = tmp_path / f"{fuel}.json"
        p.write_text(json.dumps(JSON_BASE | {"fc_fuel_type": fuel, "fc_fuel_den": den, "fc_fuel_lhv": lhv}))
        code, out, _ = run_cli(capsys, "engine", "import", p, "--json")
        assert code == 0 and json.loads(out)["fuel_type"] == fuel
        code, _, err = run_cli(
            capsys,
            "scaling",
            "--measured",
            p,
            "--bore",
            0.082,
            "--stroke",
            0.09,
            "--cylinders",
            4,
            "--out",
            tmp_path / "o",
        )
        assert code == 2 and f"fuel type '{fuel}'" in err


@pytest.mark.skipif(not GEO_JSON.exists(), reason=f"engine file not found at {GEO_JSON}")
@pytest.mark.parametrize(
    ("scale", "match"),
    [
        (1e300, "minimum BSFC 2.479e+302 g/kWh is more than 10000 g/kWh"),
        (1e3, "minimum BSFC 2.479e+05 g/kWh is more than 10000 g/kWh"),  # mg/s written as g/s
        (1e306, "no measured node below full load gives a finite, positive BSFC"),  # the BSFC overflows
        ("digits", "minimum BSFC"),  # every entry a 300-digit integer
        (1e-3, "brake efficiency"),  # g/s read as kg/s the other way round: refused when the map is read
    ],
)
def test_scaling_refuses_a_map_no_piston_engine_has(capsys, tmp_path, scale, match):
    """A measured map in the wrong units: scaling --calibrate fitted it and printed a cycle fuel of 300
    digits (with a warning); now one line, and nothing written into --out."""
    data = json.loads(GEO_JSON.read_text())
    fuel = data["fc_fuel_map"]
    data["fc_fuel_map"] = [[int("9" * 300) if scale == "digits" else v * scale for v in r] for r in fuel]
    p = tmp_path / "e.json"
    p.write_text(json.dumps(data))
    out = tmp_path / "o"
    args = ["--bore", 0.074, "--stroke", 0.077, "--cylinders", 3, "--calibrate", "--out", out]
    code, _, err = run_cli(capsys, "scaling", "--measured", p, *args)
    assert code == 2 and match in err, err
    assert not out.exists() or not any(out.iterdir())


def test_engine_metadata_warnings(capsys, tmp_path):
    p = tmp_path / "odd.json"
    p.write_text(json.dumps(JSON_BASE | {"fc_fuel_type": "Gasoline", "fc_fuel_den": 850.0}))
    code, out, _ = run_cli(capsys, "engine", "import", p)
    assert code == 0 and "warning: fuel density 0.85 kg/L is not that of gasoline" in out


@pytest.mark.skipif(not GEO_M.exists(), reason=f"ADVISOR file not found at {GEO_M}")
def test_scaled_displacement_contradicting_fc_disp_is_flagged(capsys, tmp_path):
    code, out, _ = run_cli(
        capsys,
        "scaling",
        "--measured",
        GEO_M,
        "--bore",
        0.08,
        "--stroke",
        0.09,
        "--cylinders",
        4,
        "--cycles",
        "nedc",
        "--out",
        tmp_path / "o",
    )
    assert code == 0 and "differs from the measured engine's fc_disp 1.000 L by +81 %" in out
    code, out, _ = run_cli(
        capsys,
        "scaling",
        "--measured",
        GEO_M,
        "--bore",
        0.074,
        "--stroke",
        0.077,
        "--cylinders",
        3,
        "--cycles",
        "nedc",
        "--out",
        tmp_path / "o2",
    )
    assert code == 0 and "warning" not in out


@pytest.mark.skipif(not GEO_JSON.exists(), reason=f"engine JSON not found at {GEO_JSON}")
def test_real_engine_has_no_warnings(capsys):
    code, out, _ = run_cli(capsys, "engine", "import", GEO_JSON, "--json")
    assert code == 0 and json.loads(out)["warnings"] == []


def test_displacement_and_bsfc_flagged_without_reference_data(capsys, tmp_path):
    p = tmp_path / "toy.json"
    p.write_text(json.dumps(JSON_BASE))  # fc_disp 1.9 L; its BSFC is 1080 g/kWh at best
    code, out, _ = run_cli(
        capsys,
        "scaling",
        "--measured",
        p,
        "--bore",
        0.074,
        "--stroke",
        0.077,
        "--cylinders",
        3,
        "--cycles",
        "nedc",
        "--out",
        tmp_path / "o",
    )
    assert code == 0
    assert "warning: the scaled displacement 0.993 L (B 0.074 m, S 0.077 m, z 3) differs from" in out
    assert "fc_disp 1.900 L by -48 %" in out
    assert "warning: minimum BSFC 1080 g/kWh is outside the 150-1000 g/kWh" in out


def test_engine_file_symlink_loop_is_named(tmp_path):
    for suffix in (".m", ".json"):
        a, b = tmp_path / f"a{suffix}", tmp_path / f"b{suffix}"
        a.symlink_to(b)
        b.symlink_to(a)
        with pytest.raises(EngineFileError, match="symbolic link loop"):
            load_engine(a)
