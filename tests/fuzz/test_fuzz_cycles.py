"""Hostile cycle CSV files: every one is read into a valid cycle or refused with one line naming the file."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _fuzz import run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vpsim.cycles import load_cycle
from vpsim.errors import CycleError

HEADER = b"time_s,speed_kmh\n"
GOOD = b"0,0\n1,10\n2,20\n3,0\n"

# (name, bytes, expected: "ok" or a fragment of the one-line error)
CASES = [
    ("empty", b"", "empty file"),
    ("only_header", HEADER, "0 sample(s)"),
    ("only_comments", b"# a\n# b\n", "empty file"),
    ("one_sample", HEADER + b"0,0\n", "1 sample(s)"),
    ("bom", b"\xef\xbb\xbf" + HEADER + GOOD, "ok"),
    ("crlf", (HEADER + GOOD).replace(b"\n", b"\r\n"), "ok"),
    ("cr_only", (HEADER + GOOD).replace(b"\n", b"\r"), "ok"),
    ("semicolon_decimal_comma", b"time_s;speed_kmh\n0;0\n1;10,5\n2;0\n", "ok"),
    ("tab", b"time_s\tspeed_kmh\n0\t0\n1\t10\n2\t0\n", "ok"),
    ("no_newline_at_end", HEADER + b"0,0\n1,10", "ok"),
    ("latin1", HEADER + b"0,0\n1,10 \xe9\n", "not a text file in UTF-8"),
    ("utf16", "time_s,speed_kmh\n0,0\n1,1\n".encode("utf-16"), "not a text file"),
    ("nul", HEADER + b"0,0\x00\n", "not a text file"),
    ("huge_field", HEADER + b"0,0\n1," + b"9" * 10_000_000 + b"\n", "malformed CSV"),
    ("huge_quoted_field", HEADER + b'0,0\n1,"' + b"x" * 10_000_000 + b'"\n', "malformed CSV"),
    # the quote opens on line 3: the error names that line, not the one the field runs on to
    ("unclosed_quote", HEADER + b'0,0\n1,"10\n2,0\n3,0\n', ":3: a quote opened on this line is not closed"),
    ("quoted_ok", HEADER + b'0,0\n1,"10"\n2,0\n', "ok"),
    ("underscore", HEADER + b"0,0\n1,1_0\n2,0\n", "speed '1_0' is not a number"),  # float() reads 10
    ("underscore_time", HEADER + b"0,0\n1_0,1\n", "time '1_0' is not a number"),
    ("hex", HEADER + b"0,0\n1,0x10\n", "is not a number"),
    ("arabic_digits", HEADER + "0,0\n1,\u0661\u0660\n".encode(), "is not a number"),  # float() reads 10
    ("inner_space", HEADER + b"0,0\n1,1 0\n", "is not a number"),
    ("duplicate_speed", b"time_s,speed_kmh,speed_kmh\n0,0,0\n1,1,1\n", "appears twice"),
    ("two_speed_units", b"time_s,speed_kmh,speed_mps\n0,0,0\n1,1,1\n", "2 speed columns"),
    ("no_time", b"speed_kmh\n0\n1\n", "no time column"),
    ("no_speed", b"time_s,x\n0,0\n1,1\n", "no speed column"),
    ("speed_no_unit", b"time_s,speed\n0,0\n1,1\n", "no declared unit"),
    ("nan_speed", HEADER + b"0,0\n1,nan\n", "speed is nan"),
    ("inf_time", HEADER + b"0,0\ninf,1\n", "time is inf"),
    ("huge_speed", HEADER + b"0,0\n1,1e308\n", "km/h"),
    ("huge_time", HEADER + b"0,0\n1e300,1\n", "beyond"),
    ("negative_speed", HEADER + b"0,0\n1,-1\n", "negative"),
    ("time_backwards", HEADER + b"0,0\n2,1\n1,1\n", "does not increase"),
    ("time_repeats", HEADER + b"0,0\n1,1\n1,1\n", "does not increase"),
    ("step_1e-7", HEADER + b"0,0\n0.0000001,1\n0.0000002,0\n", "closer than the 0.001 s"),
    ("text_value", HEADER + b"0,0\n1,fast\n", "is not a number"),
    ("short_row", HEADER + b"0,0\n1\n", "expected 2 fields"),
    ("bool_value", HEADER + b"0,0\n1,true\n", "is not a number"),
    ("zero_distance", HEADER + b"0,0\n10,0\n", "ok"),
    ("exponent_ok", HEADER + b"0,0\n1e1,1E1\n", "ok"),
    ("extra_columns", b"time_s,speed_kmh,note\n0,0,a\n1,1,b,c\n", "ok"),
]


@pytest.mark.parametrize(("name", "data", "expect"), CASES, ids=[c[0] for c in CASES])
def test_hostile_cycle_file(tmp_path, name, data, expect):
    p = tmp_path / f"{name}.csv"
    p.write_bytes(data)
    if expect == "ok":
        c = load_cycle(p)
        assert np.all(np.isfinite(c.time_s)) and np.all(c.speed_mps >= 0) and c.time_s.size >= 2
    else:
        with pytest.raises(CycleError) as exc:
            load_cycle(p)
        msg = str(exc.value)
        assert expect in msg and "\n" not in msg and str(p) in msg and len(msg) < 400


def test_symlink_loop_is_reported_as_a_loop(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.symlink_to(b)
    b.symlink_to(a)
    with pytest.raises(CycleError, match="symbolic link loop"):
        load_cycle(a)


def test_dangling_symlink_folder_and_fifo(tmp_path):
    import os

    d = tmp_path / "d.csv"
    d.symlink_to(tmp_path / "nowhere.csv")
    with pytest.raises(CycleError, match="dangling"):
        load_cycle(d)
    with pytest.raises(CycleError, match="is a folder"):
        load_cycle(tmp_path)
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    with pytest.raises(CycleError, match="not a regular file"):
        load_cycle(fifo)  # must not block


def test_zero_distance_cycle_in_the_cli_is_undefined_not_nan(capsys, tmp_path):
    p = tmp_path / "still.csv"
    p.write_bytes(HEADER + b"0,0\n10,0\n")
    code, out, _ = run_cli(capsys, "simulate", "--cycle", p, "--json")
    assert code == 0
    import json

    s = json.loads(out)
    assert s["fuel_l_per_100km"] is None and "no distance" in s["fuel_l_per_100km_undefined"]
    code, out, _ = run_cli(capsys, "simulate", "--cycle", p)
    assert code == 0 and "undefined (the cycle drives no distance" in out


def test_cli_cycle_errors_are_one_line(capsys, tmp_path):
    for name, data, expect in CASES:
        if expect == "ok" or len(data) > 1000:
            continue
        p = tmp_path / f"{name}.csv"
        p.write_bytes(data)
        code, _, err = run_cli(capsys, "simulate", "--cycle", p)
        assert code == 2 and expect in err


_cell = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(10**30), 10**30).map(str),
    st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=8),
    st.sampled_from(["", " ", "nan", "-0", "1e999", '"', "#", "true", "1,5"]),
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    header=st.sampled_from(["time_s,speed_kmh", "t,speed_mps", "time,speed_mph", "time_s;speed_kmh", "x,y"]),
    rows=st.lists(st.lists(_cell, min_size=0, max_size=4), max_size=12),
    newline=st.sampled_from(["\n", "\r\n", "\r"]),
    bom=st.booleans(),
)
def test_random_cycle_files_give_a_cycle_or_one_line(tmp_path, header, rows, newline, bom):
    sep = ";" if ";" in header else ","
    text = newline.join([header] + [sep.join(r) for r in rows]) + newline
    p = tmp_path / "random.csv"
    p.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode("utf-8", "surrogatepass"))
    try:
        c = load_cycle(p)
    except CycleError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 600
        return
    assert np.all(np.isfinite(c.time_s)) and np.all(np.isfinite(c.speed_mps))
    assert np.all(np.diff(c.time_s) > 0) and np.all(c.speed_mps >= 0)
    assert math.isfinite(c.distance_m)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=300))
def test_random_bytes_give_a_cycle_or_one_line(tmp_path, data):
    p = tmp_path / "bytes.csv"
    p.write_bytes(data)
    try:
        load_cycle(p)
    except CycleError as exc:
        assert "\n" not in str(exc)


def test_micrometre_cycle_has_no_fuel_per_distance(capsys, tmp_path):
    """Three samples 1 ms apart drive 3 micrometres: tens of millions of L/100 km would be noise."""
    import json

    p = tmp_path / "tiny.csv"
    p.write_bytes(HEADER + b"0,0\n0.001,0.01\n0.002,0\n")
    for method in ("backward", "forward", "inverse"):
        code, out, _ = run_cli(capsys, "simulate", "--cycle", p, "--method", method, "--json")
        assert code == 0 and json.loads(out)["fuel_l_per_100km"] is None
