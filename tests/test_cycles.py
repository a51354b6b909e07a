"""Drive cycles: the shipped standard cycles against independent reference copies, and the CSV loader."""

from __future__ import annotations

import hashlib
import importlib.util
import math
import sys
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vpsim.cycles import PHASES, STANDARD_CYCLES, Cycle, load_cycle
from vpsim.errors import CycleError

REPO = Path(__file__).resolve().parents[1]

# vpsim name -> (reference file in ../shared/data/cycles, samples, max km/h, allowed max |dv| in m/s)
# The reference copies come from other sources (ADVISOR .mat files for the EPA cycles, the JRC wltp package
# for NEDC/WLTC). fastsim's UDDS/HWFET speeds (and so FTP-75) use mph x ~0.447047 instead of the exact 0.44704
# (16 ppm high): up to 4.4e-4 m/s at 96 km/h. The reference NEDC rounds some ramp speeds to 1e-4 km/h.
REFERENCE = {
    "nedc": ("nedc.csv", 1181, 120.0, 1.5e-4),
    "ftp75": ("ftp75.csv", 1875, 91.25, 1e-3),
    "udds": ("udds.csv", 1370, 91.25, 1e-3),
    "hwfet": ("hwfet.csv", 766, 96.40, 1e-3),
    "us06": ("us06.csv", 601, 129.23, 1e-5),
    "wltc3b": ("wltc_class3b.csv", 1801, 131.30, 1e-5),
}


def test_ftp_bags_by_name_are_udds_phases():
    """FTP-75's bags by name, against EPA's description of the test: UDDS 0-505 s is 3.59 mi (bags 1 and 3),
    505-1369 s 3.86 mi (bag 2), 7.45 mi in all; times re-based to 0, the samples UDDS's own."""
    udds = load_cycle("udds")
    bag2, bag3 = load_cycle("ftp_bag2"), load_cycle(" FTP_Bag3 ")
    assert set(PHASES) == {"ftp_bag2", "ftp_bag3"} and (bag2.name, bag3.name) == ("ftp_bag2", "ftp_bag3")
    assert bag2.distance_m == pytest.approx(3.86 * 1609.344, abs=10.0)
    assert bag3.distance_m == pytest.approx(3.59 * 1609.344, abs=10.0)
    assert bag2.distance_m + bag3.distance_m == pytest.approx(udds.distance_m, rel=1e-12)
    assert bag2.time_s[0] == 0.0 and bag2.duration_s == 864.0 and bag3.duration_s == 505.0
    assert np.array_equal(bag2.speed_mps, udds.speed_mps[505:])
    assert np.array_equal(bag3.speed_mps, udds.speed_mps[:506])
    with pytest.raises(CycleError, match="ftp_bag2, ftp_bag3"):
        load_cycle("ftp_bag1")
    assert load_cycle("hwy") == load_cycle("hwfet")  # the highway test by the list's name too


def test_window_interpolates_off_grid_ends_and_refuses_outside():
    cyc = Cycle("ramp", np.array([0.0, 10.0, 20.0]), np.array([0.0, 10.0, 0.0]))
    w = cyc.window(5.0, 12.0)
    assert w.name == "ramp[5:12]" and list(w.time_s) == [0.0, 5.0, 7.0]
    assert list(w.speed_mps) == [5.0, 10.0, 8.0]
    with pytest.raises(CycleError, match=r"window \[5, 30\] s is not inside the cycle \[0, 20\] s"):
        cyc.window(5.0, 30.0)


def _read_reference(path: Path) -> tuple[np.ndarray, np.ndarray]:
    lines = path.read_text().splitlines()
    assert lines[0].strip() == "time_s,speed_mps", f"{path}: unexpected header {lines[0]!r}"
    data = np.array([[float(x) for x in line.split(",")] for line in lines[1:] if line.strip()])
    return data[:, 0], data[:, 1]


def _data_file(name: str):
    return resources.files("vpsim.cycles").joinpath("data", name)


# ------------------------------------------------------------------------------------------------------------
# standard cycles
# ------------------------------------------------------------------------------------------------------------
def test_standard_cycle_names():
    assert set(STANDARD_CYCLES) == set(REFERENCE)


@pytest.mark.parametrize("name", STANDARD_CYCLES)
def test_standard_cycle_loads(name):
    _, samples, vmax_kmh, _ = REFERENCE[name]
    c = load_cycle(name)
    assert c.name == name
    assert len(c.time_s) == samples
    np.testing.assert_array_equal(c.time_s, np.arange(samples, dtype=float))  # 1 Hz from 0
    assert c.speed_mps[0] == 0.0 and c.speed_mps[-1] == 0.0
    assert c.max_speed_kmh == pytest.approx(vmax_kmh, abs=0.01)
    assert "SOURCES.md" in c.source


@pytest.mark.parametrize("name", STANDARD_CYCLES)
def test_standard_cycle_matches_reference(name, shared_dir):
    ref_file, _, _, dv_tol = REFERENCE[name]
    t_ref, v_ref = _read_reference(shared_dir / "data" / "cycles" / ref_file)
    c = load_cycle(name)
    d_ref = float(np.sum(0.5 * (v_ref[1:] + v_ref[:-1]) * np.diff(t_ref)))
    np.testing.assert_array_equal(c.time_s, t_ref, err_msg=f"{name}: time grid differs from {ref_file}")
    dv = float(np.max(np.abs(c.speed_mps - v_ref)))
    rel = c.distance_m / d_ref - 1.0
    msg = (
        f"{name}: distance {c.distance_m / 1000:.4f} km vs {ref_file} {d_ref / 1000:.4f} km "
        f"(rel {rel:+.2e}); max |dv| = {dv:.2e} m/s (allowed {dv_tol:.0e})"
    )
    assert abs(rel) < 1e-3, msg
    assert dv <= dv_tol, msg


def test_nedc_distance_and_phases():
    c = load_cycle("nedc")
    assert c.distance_m / 1000 == pytest.approx(11.013, abs=0.001)
    assert c.max_speed_kmh == pytest.approx(120.0, abs=1e-4)
    # four identical ECE-15 urban cycles of 195 s, 1.0146 km each, then the 400 s EUDC of 6.955 km
    v = c.speed_mps
    for k in range(1, 4):
        np.testing.assert_allclose(v[195 * k : 195 * (k + 1) + 1], v[: 195 + 1], atol=0)
    ece = Cycle("ece", c.time_s[: 195 + 1], v[: 195 + 1])
    eudc = Cycle("eudc", c.time_s[780:], v[780:])
    assert ece.distance_m / 1000 == pytest.approx(1.0146, abs=1e-4)
    assert eudc.distance_m / 1000 == pytest.approx(6.955, abs=1e-3)
    assert eudc.max_speed_kmh == pytest.approx(120.0)
    # ECE: idle 11 s, then 0 -> 15 km/h in 4 s, 8 s at 15 km/h
    np.testing.assert_allclose(v[:12], 0.0)
    np.testing.assert_allclose(v[15:24] * 3.6, 15.0, atol=1e-5)


def test_ftp75_is_udds_plus_bag1():
    ftp, udds = load_cycle("ftp75"), load_cycle("udds")
    np.testing.assert_array_equal(ftp.speed_mps[:1370], udds.speed_mps)
    np.testing.assert_array_equal(ftp.speed_mps[1370:], udds.speed_mps[1:506])
    assert ftp.distance_m == pytest.approx(
        udds.distance_m + Cycle("b1", udds.time_s[:506], udds.speed_mps[:506]).distance_m
    )


@pytest.mark.parametrize("alias, name", [("WLTC", "wltc3b"), ("ftp-75", "ftp75"), (" NEDC ", "nedc")])
def test_aliases(alias, name):
    assert load_cycle(alias).name == name


@pytest.mark.parametrize("name", STANDARD_CYCLES)
def test_shipped_csv_documents_its_source(name):
    text = _data_file(f"{name}.csv").read_text(encoding="utf-8")
    head = [line for line in text.splitlines()[:10] if line.startswith("#")]
    joined = "\n".join(head).lower()
    for word in ("source:", "conversion:", "licence:"):
        assert word in joined, f"{name}.csv: no '{word}' comment line"
    assert text.splitlines()[len(head)] == "time_s,speed_mps"


def test_sources_md_records_every_cycle():
    text = _data_file("SOURCES.md").read_text(encoding="utf-8")
    assert "420c98878f29bc48bf7ac94402bc6ecaa312146a6df49c12c8906a94fe68a543" in text
    for name in STANDARD_CYCLES:
        c = load_cycle(name)
        assert f"`{name}`" in text
        assert f"{c.distance_m / 1000:.3f}" in text


def test_shipped_files_are_not_copies_of_the_reference(shared_dir):
    ref = {hashlib.sha256(p.read_bytes()).hexdigest() for p in (shared_dir / "data" / "cycles").glob("*")}
    for name in STANDARD_CYCLES:
        digest = hashlib.sha256(_data_file(f"{name}.csv").read_bytes()).hexdigest()
        assert digest not in ref, f"{name}.csv is byte-identical to a file in ../shared"


def _build_tool(monkeypatch):
    spec = importlib.util.spec_from_file_location("build_cycles", REPO / "tools" / "build_cycles.py")
    mod = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, mod)  # dataclasses look their module up in sys.modules
    spec.loader.exec_module(mod)
    return mod


def test_build_script_reproduces_nedc(monkeypatch):
    """The NEDC is computed from the regulation's mode tables; the shipped file is the script's output."""
    tool = _build_tool(monkeypatch)
    built = tool.build_nedc()
    assert tool.csv_text(built) == _data_file("nedc.csv").read_text(encoding="utf-8")
    assert sum(d for _, d, _ in tool.ECE15_MODES) == 195
    assert sum(d for _, d, _ in tool.EUDC_MODES) == 400


# ------------------------------------------------------------------------------------------------------------
# loader validation (user CSV files)
# ------------------------------------------------------------------------------------------------------------
def _write(tmp_path: Path, text: str, name: str = "cyc.csv") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def _error(path: Path, **kw) -> str:
    with pytest.raises(CycleError) as exc:
        load_cycle(path, **kw)
    return str(exc.value)


def test_cycle_error_is_value_error():
    assert issubclass(CycleError, ValueError)


def test_minimal_file_with_comments_and_blank_lines(tmp_path):
    p = _write(tmp_path, '# a "quoted, comment\n\ntime_s,speed_mps\n# mid comment\n0,0\n1,2.5\n\n2,0\n')
    c = load_cycle(p)
    np.testing.assert_array_equal(c.time_s, [0, 1, 2])
    np.testing.assert_array_equal(c.speed_mps, [0, 2.5, 0])
    assert c.distance_m == pytest.approx(2.5)
    assert c.name == "cyc"


def test_byte_order_mark_is_accepted(tmp_path):
    p = tmp_path / "bom.csv"
    p.write_bytes(b"\xef\xbb\xbftime_s,speed_mps\r\n0,0\r\n1,1\r\n")
    assert load_cycle(p).distance_m == pytest.approx(0.5)


def test_non_increasing_time(tmp_path):
    p = _write(tmp_path, "time_s,speed_mps\n0,0\n1,1\n1,2\n")
    msg = _error(p)
    assert f"{p}:4:" in msg and "increase" in msg


def test_decreasing_time(tmp_path):
    p = _write(tmp_path, "# c\ntime_s,speed_mps\n0,0\n2,1\n1,2\n")
    assert f"{p}:5:" in _error(p)


@pytest.mark.parametrize("bad", ["nan", "NaN", "inf"])
def test_nan_speed(tmp_path, bad):
    p = _write(tmp_path, f"time_s,speed_mps\n0,0\n1,{bad}\n2,0\n")
    msg = _error(p)
    assert f"{p}:3:" in msg and "finite" in msg


def test_nan_time(tmp_path):
    p = _write(tmp_path, "time_s,speed_mps\n0,0\nnan,1\n2,0\n")
    assert f"{p}:3:" in _error(p)


def test_negative_speed(tmp_path):
    p = _write(tmp_path, "time_s,speed_kmh\n0,0\n1,-3\n2,0\n")
    msg = _error(p)
    assert f"{p}:3:" in msg and "negative" in msg


@pytest.mark.parametrize("body", ["", "0,0\n"])
def test_fewer_than_two_samples(tmp_path, body):
    p = _write(tmp_path, "# c\ntime_s,speed_mps\n" + body)
    msg = _error(p)
    assert f"{p}:" in msg and "at least two" in msg
    assert f"{p}:{2 + body.count(chr(10))}:" in msg  # the last line of the file


def test_missing_time_column(tmp_path):
    p = _write(tmp_path, "# c\nseconds,speed_mps\n0,0\n1,0\n")
    msg = _error(p)
    assert f"{p}:2:" in msg and "time column" in msg


def test_missing_speed_column(tmp_path):
    p = _write(tmp_path, "time_s,velocity\n0,0\n1,0\n")
    msg = _error(p)
    assert f"{p}:1:" in msg and "speed column" in msg


def test_short_row(tmp_path):
    p = _write(tmp_path, "time_s,speed_mps\n0,0\n1\n")
    msg = _error(p)
    assert f"{p}:3:" in msg and "fields" in msg


def test_non_numeric_field(tmp_path):
    p = _write(tmp_path, "time_s,speed_mps\n0,0\n1,fast\n2,0\n")
    msg = _error(p)
    assert f"{p}:3:" in msg and "'fast'" in msg and "not a number" in msg


def test_speed_column_without_unit(tmp_path):
    p = _write(tmp_path, "time_s,speed\n0,0\n1,1\n")
    msg = _error(p)
    assert f"{p}:1:" in msg and "unit" in msg and "speed_unit" in msg


@pytest.mark.parametrize(
    "column, factor",
    [("speed_mps", 1.0), ("speed_kmh", 1 / 3.6), ("speed_kph", 1 / 3.6), ("speed_mph", 0.44704)],
)
def test_unit_columns_are_converted(tmp_path, column, factor):
    p = _write(tmp_path, f"time_s,{column}\n0,0\n10,36\n20,0\n")
    c = load_cycle(p)
    np.testing.assert_allclose(c.speed_mps, [0, 36 * factor, 0], rtol=1e-15)
    assert c.distance_m == pytest.approx(360 * factor, rel=1e-14)


def test_kmh_and_mph_known_values(tmp_path):
    assert load_cycle(_write(tmp_path, "t,speed_kmh\n0,0\n1,90\n", "a.csv")).speed_mps[1] == pytest.approx(
        25.0
    )
    assert load_cycle(_write(tmp_path, "t,speed_mph\n0,0\n1,60\n", "b.csv")).speed_mps[1] == pytest.approx(
        26.8224
    )


@pytest.mark.parametrize(
    "unit, factor", [("m/s", 1.0), ("km/h", 1 / 3.6), ("kmh", 1 / 3.6), ("mph", 0.44704)]
)
def test_speed_unit_argument(tmp_path, unit, factor):
    p = _write(tmp_path, "time_s,speed\n0,0\n1,50\n2,0\n")
    c = load_cycle(p, speed_unit=unit)
    assert c.speed_mps[1] == pytest.approx(50 * factor, rel=1e-15)


def test_speed_unit_argument_agreeing_with_column(tmp_path):
    p = _write(tmp_path, "time_s,speed_kmh\n0,0\n1,36\n")
    assert load_cycle(p, speed_unit="km/h").speed_mps[1] == pytest.approx(10.0)
    assert load_cycle(p, speed_unit="kmh").speed_mps[1] == pytest.approx(10.0)  # alias of the same unit


def test_speed_unit_argument_contradicting_column(tmp_path):
    p = _write(tmp_path, "time_s,speed_kmh\n0,0\n1,36\n")
    msg = _error(p, speed_unit="mph")
    assert f"{p}:1:" in msg and "speed_kmh" in msg


def test_unknown_speed_unit(tmp_path):
    p = _write(tmp_path, "time_s,speed\n0,0\n1,1\n")
    assert "furlong" in _error(p, speed_unit="furlong/fortnight")


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n"])
def test_empty_file(tmp_path, text):
    p = _write(tmp_path, text)
    msg = _error(p)
    assert f"{p}:" in msg and "empty" in msg


def test_missing_file_and_unknown_name(tmp_path):
    assert "no such file" in _error(tmp_path / "nope.csv")
    with pytest.raises(CycleError, match="unknown cycle 'artemis'"):
        load_cycle("artemis")


def test_binary_file(tmp_path):
    p = tmp_path / "x.csv"
    p.write_bytes(b"\xff\xfe\x00\x81\x00")
    assert "not a text file" in _error(p)


# ------------------------------------------------------------------------------------------------------------
# Cycle object
# ------------------------------------------------------------------------------------------------------------
def test_repeat():
    c = Cycle("c", [0, 1, 3], [0, 2, 0])
    r = c.repeat(3)
    np.testing.assert_array_equal(r.time_s, [0, 1, 3, 4, 6, 7, 9])
    np.testing.assert_array_equal(r.speed_mps, [0, 2, 0, 2, 0, 2, 0])
    assert r.name == "cx3"
    assert r.distance_m == pytest.approx(3 * c.distance_m)
    assert r.duration_s == 3 * c.duration_s
    r1 = c.repeat(1)
    np.testing.assert_array_equal(r1.time_s, c.time_s)
    np.testing.assert_array_equal(r1.speed_mps, c.speed_mps)


def test_repeat_standard_cycle():
    c = load_cycle("udds")
    r = c.repeat(2)
    assert len(r.time_s) == 2 * len(c.time_s) - 1
    assert r.distance_m == pytest.approx(2 * c.distance_m, rel=1e-12)


@pytest.mark.parametrize("n", [0, -1, 2.5, True, "2"])
def test_repeat_bad_count(n):
    with pytest.raises(CycleError, match="repeat count"):
        Cycle("c", [0, 1], [0, 0]).repeat(n)


def test_repeat_needs_matching_ends():
    c = Cycle("c", [0, 1, 2], [0, 1, 2])
    r1 = c.repeat(1)
    np.testing.assert_array_equal(r1.time_s, c.time_s)
    np.testing.assert_array_equal(r1.speed_mps, c.speed_mps)
    with pytest.raises(CycleError, match="ends at 2 m/s but starts at 0 m/s"):
        c.repeat(2)


@pytest.mark.parametrize(
    "t, v, match",
    [
        ([0], [0], "at least two"),
        ([0, 1], [0], "equal length"),
        ([0, 0], [0, 0], "increase strictly"),
        ([0, 1], [0, -1], ">= 0"),
        ([0, np.nan], [0, 0], "finite"),
    ],
)
def test_cycle_array_validation(t, v, match):
    with pytest.raises(CycleError, match=match):
        Cycle("c", t, v)


def test_speed_at():
    c = Cycle("c", [0, 10], [0, 10])
    np.testing.assert_allclose(c.speed_at([-1, 0, 5, 10, 11]), [0, 0, 5, 10, 0])


# ------------------------------------------------------------------------------------------------------------
# properties
# ------------------------------------------------------------------------------------------------------------
_speeds = st.lists(st.floats(0.0, 60.0, allow_nan=False, allow_infinity=False), min_size=2, max_size=300)
_steps = st.floats(0.01, 10.0, allow_nan=False, allow_infinity=False)


@settings(max_examples=200, deadline=None)
@given(v=_speeds, dt=_steps, n=st.integers(1, 6))
def test_distance_is_trapezoid_sum_and_repeat_scales(v, dt, n):
    v = list(v)
    v[-1] = v[0]  # a cycle can only be repeated when it ends at the speed it starts with
    t = [k * dt for k in range(len(v))]
    c = Cycle("p", t, v)
    trapezoid = math.fsum(0.5 * (v[k] + v[k + 1]) * (t[k + 1] - t[k]) for k in range(len(v) - 1))
    assert c.distance_m == pytest.approx(trapezoid, rel=1e-12, abs=1e-12)
    assert c.repeat(n).distance_m == pytest.approx(n * c.distance_m, rel=1e-12, abs=1e-12)


@settings(max_examples=100, deadline=None)
@given(v=_speeds, dts=st.lists(_steps, min_size=299, max_size=299))
def test_distance_with_uneven_steps(v, dts):
    t = np.concatenate([[0.0], np.cumsum(dts[: len(v) - 1])])
    c = Cycle("p", t, v)
    trapezoid = math.fsum(0.5 * (v[k] + v[k + 1]) * (t[k + 1] - t[k]) for k in range(len(v) - 1))
    assert c.distance_m == pytest.approx(trapezoid, rel=1e-12, abs=1e-12)
    assert c.distance_m >= 0


def test_equality_and_hash():
    a = Cycle("c", [0, 1, 3], [0, 2, 0])
    b = Cycle("c", np.array([0.0, 1.0, 3.0]), [0.0, 2.0, 0.0], source="elsewhere")
    assert a == b and hash(a) == hash(b)
    assert a != Cycle("c", [0, 1, 3], [0, 2, 1])
    assert a != Cycle("d", [0, 1, 3], [0, 2, 0])
    assert a != "c"
    assert len({a, b}) == 1


def test_a_shipped_cycle_is_read_once_and_shared():
    """load_cycle of a standard cycle (or a phase) returns the one immutable Cycle each time, equal to the
    file's own reading; its arrays stay read-only."""
    from vpsim.cycles import _read_csv

    a, b = load_cycle("udds"), load_cycle("UDDS")
    assert a is b and load_cycle("ftp_bag2") is load_cycle("ftp_bag2")
    with resources.files("vpsim.cycles").joinpath("data", "udds.csv").open(encoding="utf-8") as fh:
        direct = _read_csv(fh, "udds.csv", speed_unit=None, name="udds")
    np.testing.assert_array_equal(a.speed_mps, direct.speed_mps)
    np.testing.assert_array_equal(a.time_s, direct.time_s)
    with pytest.raises(ValueError):
        a.speed_mps[3] = 1.0


def test_a_cycle_of_another_type_is_a_type_error_that_says_what_to_pass():
    """A DataFrame (or anything not a name, a path or a Cycle) is refused with what to pass instead."""
    with pytest.raises(
        TypeError, match=r"not dict; a trace held in arrays is Cycle\(name, time_s, speed_mps\)"
    ):
        load_cycle({"time_s": [0, 1], "speed_mps": [0, 1]})
