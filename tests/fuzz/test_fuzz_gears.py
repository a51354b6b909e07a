"""Hostile gear schedule CSVs: a schedule inside the cycle, or one line naming the file and line."""

from __future__ import annotations

import numpy as np
import pytest
from _fuzz import run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vpsim.cycles import load_cycle
from vpsim.errors import CycleError
from vpsim.gears import load_schedule

H = b"time_s,gear\n"
CASES = [
    ("bom", b"\xef\xbb\xbf" + H + b"0,1\n100,2\n", "ok"),
    ("crlf", H.replace(b"\n", b"\r\n") + b"0,1\r\n100,2\r\n", "ok"),
    ("cr", H.replace(b"\n", b"\r") + b"0,1\r100,2\r", "ok"),
    ("semicolon", b"time_s;gear\n0;1\n100;2\n", "ok"),
    ("comments", b"# schedule\n" + H + b"# start\n0,1\n", "ok"),
    ("neutral", H + b"0,0\n10,1\n20,0\n", "ok"),
    ("nan_time", H + b"nan,1\n", "time_s is nan, expected a finite number"),
    ("inf_time", H + b"0,1\ninf,2\n", "time_s is inf"),
    ("nan_gear", H + b"0,nan\n", "gear is nan"),
    ("fractional_gear", H + b"0,1.5\n", "gear 1.5 is not a whole number"),
    ("gear_too_high", H + b"0,7\n", "gear 7 is not a whole number in 0..5"),
    ("negative_gear", H + b"0,-1\n", "gear -1 is not a whole number"),
    ("huge_gear", H + b"0,1e308\n", "is not a whole number"),
    ("text_gear", H + b"0,first\n", "gear 'first' is not a number"),
    ("underscore_gear", H + b"0,1\n10,1_0\n", "gear '1_0' is not a number"),  # float() reads 10
    ("underscore_time", H + b"0,1\n1_0,2\n", "time_s '1_0' is not a number"),
    ("unclosed_quote", H + b'0,1\n10,"2\n20,3\n', ":3: a quote opened on this line is not closed"),
    ("after_the_cycle", H + b"0,1\n5000,2\n", "outside the cycle nedc (0 to 1180 s)"),
    ("before_the_cycle", H + b"-5,1\n", "outside the cycle"),
    ("backwards", H + b"0,1\n10,2\n5,3\n", "does not increase"),
    ("latin1", H + b"0,1 \xe9\n", "not a text file in UTF-8"),
    ("utf16", "time_s,gear\n0,1\n".encode("utf-16"), "not a text file"),
    ("empty", b"", "empty file"),
    ("only_header", H, "no gear samples"),
    ("no_gear_column", b"time_s,g\n0,1\n", "header must contain time_s and gear"),
    ("duplicate_column", b"time_s,gear,gear\n0,1,1\n", "appears twice"),
    ("short_row", H + b"0\n", "expected 2 fields"),
    ("huge_field", H + b"0," + b"1" * 10_000_000 + b"\n", "malformed CSV"),
]


@pytest.mark.parametrize(("name", "data", "expect"), CASES, ids=[c[0] for c in CASES])
def test_hostile_gear_file(tmp_path, name, data, expect):
    p = tmp_path / f"{name}.csv"
    p.write_bytes(data)
    nedc = load_cycle("nedc")
    if expect == "ok":
        s = load_schedule(p, 5, cycle=nedc)
        assert np.all((s.gear >= 1) & (s.gear <= 5))
        assert s.time_s[0] >= nedc.time_s[0] and s.time_s[-1] <= nedc.time_s[-1]
    else:
        with pytest.raises(CycleError) as exc:
            load_schedule(p, 5, cycle=nedc)
        msg = str(exc.value)
        assert expect in msg and "\n" not in msg and str(p) in msg and len(msg) < 400


def test_gear_bom_accepted_like_cycles(tmp_path):
    p = tmp_path / "g.csv"
    p.write_bytes(b"\xef\xbb\xbftime_s,gear\n0,2\n")
    assert load_schedule(p, 5).gear.tolist() == [2]


def test_symlink_loop_folder_and_missing(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.symlink_to(b)
    b.symlink_to(a)
    with pytest.raises(CycleError, match="symbolic link loop"):
        load_schedule(a, 5)
    with pytest.raises(CycleError, match="is a folder"):
        load_schedule(tmp_path, 5)
    with pytest.raises(CycleError, match="no such file"):
        load_schedule(tmp_path / "none.csv", 5)


def test_cli_gear_errors_are_one_line(capsys, tmp_path):
    for name, data, expect in CASES:
        if len(data) > 1000:
            continue
        p = tmp_path / f"{name}.csv"
        p.write_bytes(data)
        code, out, err = run_cli(capsys, "simulate", "--gears", p, "--json")
        assert code == (0 if expect == "ok" else 2), (name, err)
        if expect != "ok":
            assert expect in err


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    rows=st.lists(
        st.tuples(
            st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-5, 2000)).map(str),
            st.one_of(st.floats(allow_nan=True), st.integers(-3, 9), st.text(max_size=3)).map(str),
        ),
        max_size=10,
    ),
    newline=st.sampled_from(["\n", "\r\n", "\r"]),
)
def test_random_gear_files(tmp_path, rows, newline):
    p = tmp_path / "g.csv"
    p.write_text("time_s,gear" + newline + newline.join(f"{t},{g}" for t, g in rows) + newline, "utf-8")
    nedc = load_cycle("nedc")
    try:
        s = load_schedule(p, 5, cycle=nedc)
    except CycleError as exc:
        assert "\n" not in str(exc)
        return
    assert np.all(np.isfinite(s.time_s)) and np.all(np.diff(s.time_s) > 0)
    assert np.all((s.gear >= 1) & (s.gear <= 5))
    assert nedc.time_s[0] <= s.time_s[0] and s.time_s[-1] <= nedc.time_s[-1]
