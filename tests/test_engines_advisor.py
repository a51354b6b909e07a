"""ADVISOR fuel-converter files: the safe MATLAB-subset reader and the measured-engine type."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vpsim.engines import MeasuredEngine, evaluate_m_text, load_engine, read_m_file
from vpsim.engines.matlab import MAX_FILE_BYTES, InlineFunction
from vpsim.errors import EngineFileError

ENGINES = ("FC_SI41_emis", "FC_SI63_emis")


def _m_path(shared_dir: Path, name: str) -> Path:
    return shared_dir / "data" / "raw" / "advisor" / f"{name}.m"


def _json_path(shared_dir: Path, name: str) -> Path:
    return shared_dir / "data" / "engines" / f"{name}.json"


def _decimals(x: float) -> int:
    """Decimals the JSON writer used for ``x`` (from its shortest repr)."""
    text = repr(float(x))
    assert "e" not in text, text
    return len(text.split(".")[1].rstrip("0"))


# ----------------------------------------------------------------------------- real ADVISOR files


@pytest.mark.parametrize("name", ENGINES)
def test_m_file_matches_json_conversion(shared_dir: Path, name: str) -> None:
    """Every variable the .m file and its JSON conversion share agrees.

    The converter wrote rounded numbers (9 decimals for the SI41 g/s maps, 4 for the SI63 g/kWh maps,
    6 elsewhere), so a value agrees when it is within 1e-9 relative of the JSON number, or when rounding
    it to the JSON's own number of decimals gives exactly the JSON number.
    """
    values = read_m_file(_m_path(shared_dir, name))
    ref = json.loads(_json_path(shared_dir, name).read_text())
    common = [k for k in ref if k in values]
    for key in ("fc_map_spd", "fc_map_trq", "fc_fuel_map", "fc_max_trq", "fc_inertia", "fc_disp"):
        assert key in common
    assert len(common) >= 40
    for key in common:
        if isinstance(ref[key], str):
            assert values[key] == ref[key], key
            continue
        expected = np.array(ref[key], dtype=float)  # JSON null -> NaN
        got = np.asarray(values[key], dtype=float)
        assert got.shape == expected.shape, key
        known = np.isfinite(expected)
        exp, val = expected[known], got[known]
        digits = max(_decimals(x) for x in exp)
        rounded = np.array([round(float(x), digits) for x in val])
        close = np.abs(val - exp) <= 1e-9 * np.abs(exp)
        assert np.all(close | (rounded == exp)), key
        assert np.all(np.abs(val - exp) <= 0.5 * 10.0**-digits * (1 + 1e-9) + 1e-9 * np.abs(exp)), key
        if not np.all(known):  # SI63 g/kWh at zero torque: the file divides by eps, the JSON has null
            assert key == "fc_fuel_map_gpkWh" and name == "FC_SI63_emis"
            assert np.all(got[~known] > 1e15)


def test_m_file_contents(shared_dir: Path) -> None:
    si41 = read_m_file(_m_path(shared_dir, "FC_SI41_emis"))
    assert si41["fc_spd_scale"] == 1.0 and si41["fc_trq_scale"] == 1.0
    assert si41["fc_fuel_map"].shape == (9, 12)
    # the file converts g/kWh to g/s itself: fuel = bsfc * T * w / 1000 / 3600
    t, w = np.meshgrid(si41["fc_map_trq"], si41["fc_map_spd"])
    np.testing.assert_allclose(si41["fc_fuel_map"], si41["fc_fuel_map_gpkWh"] * t * w / 3.6e6, rtol=1e-15)
    assert si41["names"] == ("fc_fuel_map", "fc_hc_map", "fc_co_map", "fc_nox_map", "fc_pm_map")
    np.testing.assert_array_equal(si41["fc_fuel_map_c2h"], np.zeros((9, 12)))  # made by the file's eval
    assert isinstance(si41["fc_mass_scale_fun"], InlineFunction)
    assert si41["fc_mass_scale_fun"].args[0] == "x"
    for cleared in ("T", "w", "spd", "fc_map_kW", "fc_waste_pwr_map"):
        assert cleared not in si41
    assert si41["fc_max_pwr"] == pytest.approx(41.007, abs=1e-3)

    si63 = read_m_file(_m_path(shared_dir, "FC_SI63_emis"))
    assert si63["fc_fuel_map"].shape == (11, 8)
    assert si63["fc_map_spd"][0] == pytest.approx(701 * 2 * math.pi / 60, rel=1e-15)
    assert si63["fc_map_trq"][0] == 0.0
    assert "fuelrich" not in si63 and "i" not in si63  # removed by the file's clear statements
    assert np.all(si63["fc_fuel_map"] >= 0) and np.all(si41["fc_fuel_map"] > 0)


def test_crlf_and_latin1_are_read(tmp_path: Path) -> None:
    f = tmp_path / "crlf.m"
    f.write_bytes(b"% caf\xe9\r\nx = [1 2 ...\r\n 3];\r\ny = x(end)\r\n")
    assert read_m_file(f)["y"] == 3.0
    g = tmp_path / "crlf_bad.m"
    g.write_bytes(b"x = 1;\r\n\r\ny = q;\r\n")
    with pytest.raises(EngineFileError, match=r":3: undefined variable 'q'$"):
        read_m_file(g)


# ------------------------------------------------------------------------------- hostile input

HOSTILE = [
    ("truncated_matrix", "a = 1;\nx = [1 2 3\n4 5 6\n", 2, "never closed"),
    ("truncated_call", "a = 1;\nb = max(a, 2", 2, "never closed"),
    ("unknown_function", "a = 1;\nb = foo(3);", 2, "unknown function"),
    ("shell_bang", "a = 1;\n!ls", 2, "shell escape"),
    ("eval_expression", "eval('1+1')", 1, "eval is only supported"),
    ("eval_two_statements", "eval('a=1; b=2')", 1, "eval is only supported"),
    ("eval_nested", "eval('y = eval(''1'')')", 1, "not allowed inside eval"),
    ("eval_system", "eval('x = system(''ls'')')", 1, "'system' is not allowed"),
    ("eval_built", "n = {'a'};\neval([n{1}, '=unix(''ls'')'])", 2, "'unix' is not allowed"),
    ("evalin", "evalin('base', 'x = 1')", 1, "'evalin' is not allowed"),
    ("feval", "x = feval('sin', 1)", 1, "'feval' is not allowed"),
    ("load_function", "x = load('data.mat')", 1, "'load' is not allowed"),
    ("load_command", "x = 1;\nload data.mat", 2, "command 'load data.mat' is not supported"),
    ("python_import", "x = __import__('os')", 1, "unexpected character '_'"),
    ("python_import_stmt", "import os", 1, "command 'import os' is not supported"),
    ("python_exec", "exec('import os')", 1, "unknown function"),
    ("python_attr", "x = py.os.system('ls')", 1, "struct field access"),
    ("huge_literal", "x = 1;\ny = 1e999;", 2, "overflows to infinity"),
    ("overflow_product", "x = 1e308 * 10", 1, "overflows"),
    ("power_blowup", "x = 2^1e6", 1, "overflows"),
    ("power_blowup_elementwise", "x = 10.^(1:400)", 1, "overflows"),
    ("nan_in_map", "fc_map_spd = [1 2];\nfc_fuel_map = [1 NaN;\n 2 3];", 2, "NaN is not allowed"),
    ("nan_computed", "x = 0/0", 1, "NaN"),
    ("division_by_zero", "x = 1/0", 1, "divides by zero"),
    ("mismatched_rows", "x = [1 2; 3]", 1, "vertical concatenation"),
    ("mismatched_columns", "x = [[1; 2] [1; 2; 3]]", 1, "horizontal concatenation"),
    ("mismatched_arithmetic", "x = [1 2] + [1 2 3]", 1, "dimensions do not agree: 1x2 + 1x3"),
    ("mismatched_product", "x = [1 2] * [3 4]", 1, "inner dimensions"),
    ("undefined_variable", "x = 1;\ny = z + x;", 2, "undefined variable 'z'"),
    ("huge_range", "x = 1:1e12", 1, "more than 1000000 elements"),
    ("huge_fine_range", "x = 0:1e-9:1", 1, "more than 1000000 elements"),
    ("huge_zeros", "x = zeros(1e6, 1e6)", 1, "more than the limit"),
    ("huge_index_growth", "x(1e9) = 1", 1, "more than the limit"),
    ("endless_loops", "for i = 1:1e6\n for j = 1:1e6\n end\nend", 2, "loop passes"),
    ("while_loop", "while 1\nend", 1, "'while' is not supported"),
    ("function_definition", "function y = f(x)\ny = x;\nend", 1, "'function' is not supported"),
    ("function_handle", "f = @(t) t", 1, "function handles"),
    ("complex_literal", "x = 3i", 1, "complex"),
    ("complex_result", "x = (-1)^0.5", 1, "complex"),
    ("unclosed_string", "x = 'abc", 1, "not closed"),
    ("unclosed_block_comment", "x = 1;\n%{\nx = 2", 2, "never closed"),
    ("missing_end", "x = 1;\nif x\n y = 2;\n", 2, "no matching 'end'"),
    ("index_out_of_range", "x = [1 2 3];\ny = x(4);", 2, "exceeds the size"),
    ("index_not_integer", "x = [1 2 3]; y = x(1.5);", 1, "positive whole number"),
    ("deep_nesting", "x = " + "(" * 100 + "1" + ")" * 100, 1, "nested more than"),
    ("long_chain", "x = " + "+".join(["1"] * 5000), 1, "too long"),
    ("interp1_outside", "x = interp1([1 2], [3 4], 5)", 1, "outside the range"),
    ("text_arithmetic", "x = 'a' + 1", 1, "text arithmetic"),
    ("find_two_outputs", "x = 1;\n[i, j] = find([1 0; 0 1]);", 2, "[i, j] = find(x) is not supported"),
    ("find_count", "x = find([1 1], 1)", 1, "find takes 1 argument(s), got 2"),
    ("find_text", "x = find('ab')", 1, "text 'ab' used as a number (find)"),
    ("find_logical_index", "x = [1 2];\ny = x(x > 1);", 2, "logical indexing is not supported"),
    ("fliplr_cell", "x = fliplr({1, 2})", 1, "a cell array used as a number (fliplr)"),
    ("isempty_no_argument", "x = isempty()", 1, "isempty takes 1 argument(s), got 0"),
    ("clear_everything_pattern", "x = 1;\nclear *", 2, "only variable names"),
    ("clear_pattern_not_a_name", "x = 1;\nclear x-y*", 2, "only variable names"),
]


@pytest.mark.parametrize(("text", "line", "what"), [h[1:] for h in HOSTILE], ids=[h[0] for h in HOSTILE])
def test_hostile_input_is_refused(tmp_path: Path, text: str, line: int, what: str) -> None:
    f = tmp_path / "bad.m"
    f.write_text(text)
    with pytest.raises(EngineFileError) as info:
        read_m_file(f)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{f}:{line}: "), message
    assert what in message


@pytest.mark.parametrize(
    "template",
    [
        "x = 1;\nsystem('touch {p}');",
        "x = 1;\nsystem touch {p}",
        "x = 1;\n!touch {p}",
        "x = 1;\nunix('touch {p}');",
        "x = 1;\ndos('touch {p}');",
        "x = 1;\neval('system(''touch {p}'')');",
        "x = 1;\neval('y = system(''touch {p}'')');",
        "x = 1;\n[s, r] = system('touch {p}');",
        "x = 1;\ny = evalc('!touch {p}');",
        "x = 1;\nexec(\"__import__('os').system('touch {p}')\")",
    ],
)
def test_commands_are_never_executed(tmp_path: Path, template: str) -> None:
    marker = tmp_path / "X"
    f = tmp_path / "evil.m"
    f.write_text(template.format(p=marker))
    with pytest.raises(EngineFileError, match=rf"^{re.escape(str(f))}:2: "):
        read_m_file(f)
    assert not marker.exists()


def test_oversized_file_is_refused_before_reading(tmp_path: Path) -> None:
    f = tmp_path / "big.m"
    f.write_text("% padding padding padding padding padding padding padding padding\n" * 160_000)
    assert f.stat().st_size > 10 * 1024 * 1024 > MAX_FILE_BYTES
    with pytest.raises(EngineFileError, match=r"big\.m:1: file is \d+ bytes, more than"):
        read_m_file(f)


def test_binary_file_is_refused(tmp_path: Path) -> None:
    f = tmp_path / "cycle.m"
    f.write_bytes(b"MATLAB 5.0 MAT-file\n\x00\x01\x02")
    with pytest.raises(EngineFileError, match=r"cycle\.m:2: NUL byte"):
        read_m_file(f)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(EngineFileError, match="cannot read file"):
        read_m_file(tmp_path / "absent.m")


# ------------------------------------------------------------------------ evaluator semantics


def test_matlab_subset_semantics() -> None:
    v = evaluate_m_text(
        """
        a = [1 2 3]; c = [a' a']; d = [1 -2]; e = [1 - 2]; f = [a (1)]; g = [a [4 5]];
        h = a(2:end); k = [a; a]; kk = k(:); m = k(2, end-1); n = 1./a; o = .5; p = 1E-04;
        r = 10:-3:1; t = 2^-1; u = -2^2; v = 2^3^2; w = 'it''s'; x = ['a', 'b' 'c'];
        y = [1 2 ...  continuation comment
             3];
        mm = [1 2   % comment inside a matrix
              3 4
             ];
        [mx, ix] = max([3 9 2]); [rr, cc] = size(k); z = zeros(size(k));
        if exist('undefined_thing'), s = 2; else, s = 1; end
        g2 = zeros(2); g2(2, :) = [7 8]; g3 = []; g3(3) = 5; rn = round([-2.5 2.5]);
        cl = {'p', 'q'}; q = cl{2}; tmp = 1; clear tmp
        """
    )
    assert v["c"].shape == (3, 2)
    assert v["d"].tolist() == [1, -2] and v["e"] == -1
    assert v["f"].tolist() == [1, 2, 3, 1] and v["g"].tolist() == [1, 2, 3, 4, 5]
    assert v["h"].tolist() == [2, 3] and v["kk"].tolist() == [1, 1, 2, 2, 3, 3] and v["m"] == 2
    assert v["n"][1] == 0.5 and v["o"] == 0.5 and v["p"] == 1e-4
    assert v["r"].tolist() == [10, 7, 4, 1]
    assert (v["t"], v["u"], v["v"]) == (0.5, -4.0, 64.0)
    assert (v["w"], v["x"]) == ("it's", "abc")
    assert v["y"].tolist() == [1, 2, 3]
    assert v["mm"].tolist() == [[1, 2], [3, 4]]
    assert (v["mx"], v["ix"], v["rr"], v["cc"]) == (9, 2, 2, 3)
    assert v["z"].shape == (2, 3) and v["s"] == 1
    assert v["g2"].tolist() == [[0, 0], [7, 8]] and v["g3"].tolist() == [0, 0, 5]
    assert v["rn"].tolist() == [-3, 3]  # MATLAB rounds halves away from zero
    assert v["q"] == "q" and "tmp" not in v


def test_find_gives_matlab_positions() -> None:
    """find: 1-based column-major positions; a row for a row vector (1x0 when none), else a column."""
    v = evaluate_m_text(
        "a = find([0 3 0 -2]); b = find([0; 1; 1]); c = find([0 0]); d = find([1 0; 0 1]);\n"
        "e = find([1 2 3] > 1); f = find([]); t = [-2 -1 0 1 2]; g = t(find(t > 0));"
    )
    assert v["a"].tolist() == [2, 4] and v["b"].tolist() == [2, 3]
    assert v["c"].size == 0 and v["d"].tolist() == [1, 4] and v["e"].tolist() == [2, 3]
    assert v["f"].size == 0 and v["g"].tolist() == [1, 2]


def test_fliplr_and_flipud() -> None:
    v = evaluate_m_text(
        "m = [1 2 3; 4 5 6]; a = fliplr(m); b = flipud(m);\nc = fliplr([1 2 3]); d = fliplr(7);"
    )
    assert v["a"].tolist() == [[3, 2, 1], [6, 5, 4]] and v["b"].tolist() == [[4, 5, 6], [1, 2, 3]]
    assert v["c"].tolist() == [3, 2, 1] and v["d"] == 7


def test_isempty() -> None:
    v = evaluate_m_text(
        "a = isempty([]); b = isempty(find([0 0])); c = isempty(0);\nd = isempty(''); e = isempty({1});"
    )
    assert (v["a"], v["b"], v["c"], v["d"], v["e"]) == (1, 1, 0, 1, 0)
    # the ADVISOR idiom it serves
    v = evaluate_m_text("z = find([0 1] == 0); y = 0; if ~isempty(z)\n y = z + 1;\nend")
    assert v["y"] == 2


def test_clear_with_wildcards() -> None:
    v = evaluate_m_text("temp_a = 1; temp_b = 2; tempo = 3; keep = 4; xay = 5; xy = 6; clear temp* x*y")
    assert sorted(v) == ["keep"]


def test_eval_single_assignment_is_parsed_not_run() -> None:
    v = evaluate_m_text(
        "a = [1 2];\nnames = {'a'};\nfor i = 1:length(names)\n eval([names{i}, '_x = 2*a;'])\nend"
    )
    assert v["a_x"].tolist() == [2, 4]


# Random arithmetic of small integers, rendered with MATLAB precedence and as few parentheses as possible;
# the reference value is computed from the expression tree, never by evaluating text.

_PREC = {"+": 1, "-": 1, "*": 2, "/": 2, "neg": 3, "^": 4}
_leaf = st.integers(0, 9).map(lambda n: ("num", n))


def _extend(children: st.SearchStrategy) -> st.SearchStrategy:
    return st.one_of(
        st.tuples(st.sampled_from(["+", "-", "*", "/"]), children, children),
        st.tuples(st.just("neg"), children),
        st.tuples(st.just("^"), children, st.integers(0, 3).map(lambda n: ("num", n))),
    )


_trees = st.recursive(_leaf, _extend, max_leaves=12)


def _render(tree: tuple) -> str:
    op = tree[0]
    if op == "num":
        return str(tree[1])

    def child(sub: tuple, right: bool) -> str:
        text = _render(sub)
        p, q = _PREC.get(sub[0], 9), _PREC[op]
        if p < q or (right and p == q) or (op == "^" and sub[0] == "neg"):
            return f"({text})"
        return text

    if op == "neg":
        return "-" + child(tree[1], right=False)
    return f"{child(tree[1], right=False)} {op} {child(tree[2], right=True)}"


def _reference(tree: tuple) -> float:
    op = tree[0]
    if op == "num":
        return float(tree[1])
    if op == "neg":
        return -_reference(tree[1])
    a, b = _reference(tree[1]), _reference(tree[2])
    if op == "+":
        return a + b
    if op == "-":
        return a - b
    if op == "*":
        return a * b
    if op == "/":
        return a / b  # ZeroDivisionError: the reader must refuse too
    return a**b  # ZeroDivisionError for 0^-n


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_trees)
def test_random_arithmetic_matches_reference(tree: tuple) -> None:
    text = "x = " + _render(tree) + ";"
    try:
        expected = _reference(tree)
    except (ZeroDivisionError, OverflowError):
        with pytest.raises(EngineFileError):
            evaluate_m_text(text)
        return
    if not math.isfinite(expected):
        with pytest.raises(EngineFileError):
            evaluate_m_text(text)
        return
    assert evaluate_m_text(text)["x"] == pytest.approx(expected, rel=1e-12, abs=1e-300), text


@settings(max_examples=100, deadline=None)
@given(
    st.lists(st.lists(st.integers(-50, 50), min_size=3, max_size=3), min_size=1, max_size=4),
    st.integers(-5, 5),
)
def test_random_matrix_literal_and_ops(rows: list[list[int]], k: int) -> None:
    text = "m = [" + "; ".join(" ".join(str(x) for x in row) for row in rows) + f"];\ny = m' .* {k} - 1;"
    ref = np.array(rows, dtype=float)
    v = evaluate_m_text(text)
    np.testing.assert_array_equal(np.atleast_2d(v["m"]) if len(rows) > 1 else v["m"], ref.squeeze())
    np.testing.assert_array_equal(np.asarray(v["y"]).reshape(ref.T.shape), ref.T * k - 1)


@settings(max_examples=200, deadline=None)
@given(st.text(alphabet="x=[]();,'.:+-*/^ 0123456789e%\n{}!_end", max_size=60))
def test_garbage_never_escapes_as_another_exception(text: str) -> None:
    try:
        evaluate_m_text(text)
    except EngineFileError as e:
        assert "\n" not in str(e)


# --------------------------------------------------------------------------------- MeasuredEngine


@pytest.fixture(scope="module", params=ENGINES)
def engine_pair(request: pytest.FixtureRequest, shared_dir: Path) -> tuple[MeasuredEngine, MeasuredEngine]:
    name = request.param
    return load_engine(_m_path(shared_dir, name)), load_engine(_json_path(shared_dir, name))


def test_m_and_json_engines_agree(engine_pair: tuple[MeasuredEngine, MeasuredEngine]) -> None:
    m, j = engine_pair
    assert m.name == j.name
    np.testing.assert_allclose(m.speed_grid, j.speed_grid, rtol=1e-8)
    np.testing.assert_allclose(m.torque_grid, j.torque_grid, rtol=1e-8)
    np.testing.assert_allclose(m.fuel_flow, j.fuel_flow, rtol=0, atol=5e-13)  # JSON: g/s to 9 decimals
    np.testing.assert_allclose(m.max_torque, j.max_torque, rtol=1e-8)
    for attr in ("inertia", "displacement", "fuel_density", "fuel_lhv"):
        assert getattr(m, attr) == getattr(j, attr)
    assert m.fuel_density == pytest.approx(0.749) and m.fuel_lhv == pytest.approx(42.6e6)
    assert m.displacement in (pytest.approx(1.0e-3), pytest.approx(1.9e-3))
    assert m.fuel_flow.max() < 0.01  # kg/s, not g/s


def test_interpolation_exact_at_nodes(engine_pair: tuple[MeasuredEngine, MeasuredEngine]) -> None:
    e = engine_pair[0]
    t, w = np.meshgrid(e.torque_grid, e.speed_grid)
    flow, outside = e.fuel_flow_at(t, w, return_outside=True)
    np.testing.assert_array_equal(flow, e.fuel_flow)
    assert not outside.any()
    np.testing.assert_array_equal(e.max_torque_at(e.max_torque_speed), e.max_torque)


def test_interpolation_inside_and_outside(engine_pair: tuple[MeasuredEngine, MeasuredEngine]) -> None:
    e = engine_pair[0]
    sg, tg, f = e.speed_grid, e.torque_grid, e.fuel_flow
    # centre of a cell: mean of its corners
    t_mid, w_mid = (tg[2] + tg[3]) / 2, (sg[1] + sg[2]) / 2
    assert e.fuel_flow_at(t_mid, w_mid) == pytest.approx(f[1:3, 2:4].mean(), rel=1e-12)
    # speed outside: clamped, and flagged
    flow, out = e.fuel_flow_at([tg[3], tg[3]], [sg[0] - 50, sg[-1] + 50], return_outside=True)
    np.testing.assert_allclose(flow, [f[0, 3], f[-1, 3]], rtol=1e-15)
    assert out.tolist() == [True, True]
    # torque above the grid: linear extrapolation from the last two columns, flagged
    t_hi = tg[-1] + 0.5 * (tg[-1] - tg[-2])
    expected_hi = f[2, -1] + 0.5 * (f[2, -1] - f[2, -2])
    assert e.fuel_flow_at(t_hi, sg[2], return_outside=True) == (pytest.approx(max(expected_hi, 0.0)), True)
    # torque below the first column: linear extrapolation, never below zero
    t_lo = np.linspace(tg[0] - 40, tg[0], 9)
    flow_lo, out_lo = e.fuel_flow_at(t_lo, np.full_like(t_lo, sg[3]), return_outside=True)
    slope = (f[3, 1] - f[3, 0]) / (tg[1] - tg[0])
    np.testing.assert_allclose(flow_lo, np.maximum(f[3, 0] + slope * (t_lo - tg[0]), 0.0), atol=1e-18)
    assert np.all(flow_lo >= 0)
    assert out_lo.tolist() == [True] * 8 + [False]
    # scalars in, scalars out; broadcasting
    value, flag = e.fuel_flow_at(tg[1], sg[1], return_outside=True)
    assert isinstance(value, float) and flag is False
    assert e.fuel_flow_at(tg[:3], sg[2]).shape == (3,)
    assert e.max_torque_at(0.0) == e.max_torque[0] and e.max_torque_at(1e4) == e.max_torque[-1]


def test_geo_map_has_no_zero_torque_column(shared_dir: Path) -> None:
    e = load_engine(_m_path(shared_dir, "FC_SI41_emis"))
    assert e.torque_grid[0] == pytest.approx(6.8)
    flow, outside = e.fuel_flow_at(0.0, e.speed_grid, return_outside=True)
    assert np.all(outside) and np.all(flow >= 0)


def _toy(**changes: object) -> MeasuredEngine:
    fields: dict[str, object] = dict(
        name="toy",
        speed_grid=np.array([100.0, 200.0, 300.0]),
        torque_grid=np.array([0.0, 50.0]),
        fuel_flow=np.array([[1.0, 2.0], [2.0, 3.0], [3.0, 5.0]]) * 1e-3,
        max_torque_speed=np.array([100.0, 300.0]),
        max_torque=np.array([40.0, 60.0]),
        inertia=0.1,
        displacement=1e-3,
        fuel_density=0.749,
        fuel_lhv=42.6e6,
        source="toy",
    )
    fields.update(changes)
    return MeasuredEngine(**fields)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("changes", "what"),
    [
        ({"speed_grid": np.array([100.0, 100.0, 300.0])}, "strictly increasing"),
        ({"torque_grid": np.array([50.0, 0.0])}, "strictly increasing"),
        ({"speed_grid": np.array([100.0, np.nan, 300.0])}, "non-finite"),
        ({"fuel_flow": np.ones((2, 3))}, "shape"),
        ({"fuel_flow": np.array([[1.0, -2.0], [2.0, 3.0], [3.0, 5.0]])}, "negative"),
        ({"max_torque": np.array([0.0, 60.0])}, "positive"),
        ({"max_torque": np.array([40.0])}, "length"),
        ({"displacement": 0.0}, "displacement"),
        ({"fuel_lhv": math.inf}, "fuel_lhv"),
    ],
)
def test_validation(changes: dict, what: str) -> None:
    with pytest.raises(EngineFileError, match=what):
        _toy(**changes)


def test_toy_engine_and_immutability() -> None:
    e = _toy()
    assert e.fuel_flow_at(25.0, 150.0) == pytest.approx(2.0e-3)
    assert e.max_torque_at(200.0) == pytest.approx(50.0)
    with pytest.raises(ValueError):
        e.fuel_flow[0, 0] = 1.0
    flow, outside = e.fuel_flow_at(np.nan, 150.0, return_outside=True)
    assert math.isnan(flow) and outside


def test_load_engine_dispatch_and_json_errors(tmp_path: Path) -> None:
    with pytest.raises(EngineFileError, match="unsupported engine file type '.mat'"):
        load_engine(tmp_path / "engine.mat")
    base = {
        "fc_map_spd": [100, 200],
        "fc_map_trq": [0, 50],
        "fc_fuel_map": [[1, 2], [2, 3]],
        "fc_max_trq": [40, 60],
        "fc_inertia": 0.1,
        "fc_disp": 1.0,
        "fc_fuel_den": 749,
        "fc_fuel_lhv": 42600,
    }
    good = tmp_path / "good.json"
    good.write_text(json.dumps(base))
    e = load_engine(good)
    assert e.name == "good" and e.fuel_flow[1, 1] == pytest.approx(3e-3) and e.displacement == 1e-3
    for name, text, what in [
        ("nan.json", json.dumps(base).replace("[1, 2]", "[NaN, 2]"), "NaN is not allowed"),
        ("null.json", json.dumps(base).replace("[1, 2]", "[null, 2]"), "null"),
        ("units.json", json.dumps({**base, "units": {"fc_fuel_map": "g/kWh"}}), "expected 'g/s'"),
        ("missing.json", json.dumps({k: v for k, v in base.items() if k != "fc_max_trq"}), "fc_max_trq"),
        ("broken.json", "{", "invalid JSON"),
    ]:
        f = tmp_path / name
        f.write_text(text)
        with pytest.raises(EngineFileError, match=re.escape(what)):
            load_engine(f)


def test_load_engine_m_refuses_hostile_and_scaled_files(tmp_path: Path) -> None:
    marker = tmp_path / "X"
    bad = tmp_path / "bad.m"
    bad.write_text(f"fc_map_spd = [1 2];\nsystem('touch {marker}');\n")
    with pytest.raises(EngineFileError, match=r"bad\.m:2: "):
        load_engine(bad)
    assert not marker.exists()
    scaled = tmp_path / "scaled.m"
    scaled.write_text(
        "fc_map_spd=[100 200]; fc_map_trq=[0 50]; fc_fuel_map=[1 2; 2 3]; fc_max_trq=[40 60];\n"
        "fc_inertia=0.1; fc_disp=1; fc_fuel_den=749; fc_fuel_lhv=42600; fc_spd_scale=1.2; fc_trq_scale=1;\n"
    )
    with pytest.raises(EngineFileError, match="fc_spd_scale = 1.2"):
        load_engine(scaled)
    missing = tmp_path / "missing.m"
    missing.write_text("fc_map_spd = [100 200];\n")
    with pytest.raises(EngineFileError, match="'fc_map_trq' is not assigned"):
        load_engine(missing)
