"""Hostile input to the certification-list surfaces: from-epa's --out and its text, the fleet's options and
output folder, and a folder a killed fleet run left behind."""

from __future__ import annotations

import csv
import sys
import tomllib
from pathlib import Path

import pytest
from _fuzz import run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: the made-up list
from fleet_csv import write_list  # noqa: E402
from vpsim.fleet.report import INCOMPLETE  # noqa: E402
from vpsim.params import load_parameters  # noqa: E402


def _edited(src: Path, dst: Path, vehicle_id: str, field: str, value: str) -> Path:
    """The made-up list with ``field`` (a key of vpsim.fleet.epa.COL) of ``vehicle_id``'s rows set to
    ``value``."""
    from vpsim.fleet.epa import COL

    with src.open(newline="") as f:
        rows = list(csv.reader(f))
    i_id, i_field = rows[0].index("Test Vehicle ID"), rows[0].index(COL[field])
    for r in rows[1:]:
        if r[i_id] == vehicle_id:
            r[i_field] = value
    with dst.open("w", newline="") as f:
        csv.writer(f).writerows(rows)
    return dst


def test_from_epa_refuses_to_overwrite_its_input(tmp_path, capsys):
    lst = write_list(tmp_path / "list.csv")
    before = lst.read_bytes()
    code, _, err = run_cli(capsys, "vehicle", "from-epa", lst, "--id", "T004", "--out", lst)
    assert code == 2 and "an input of this command" in err
    assert lst.read_bytes() == before


@pytest.mark.parametrize(
    "model",
    [
        'Runner"\n[vehicle]\nmass = 1',  # a newline that would inject a table
        "Runner\x1b[31mRED\x1b[0m",  # an ESC sequence for the terminal
        "Runner\x00nul\x7fdel\ttab\\back",  # NUL, DEL, tab, backslash
    ],
)
def test_from_epa_writes_any_record_text_as_text(tmp_path, capsys, model):
    lst = _edited(write_list(tmp_path / "list.csv"), tmp_path / "hostile.csv", "T004", "model", model)
    car = tmp_path / "car.toml"
    code, out, _ = run_cli(capsys, "vehicle", "from-epa", lst, "--id", "T004", "--out", car)
    if code != 0:  # the reader may refuse the row (one line): then nothing is written
        assert not car.exists()
        return
    assert "\x1b" not in out and "\x00" not in out  # escaped for the terminal
    data = tomllib.loads(car.read_text())  # valid TOML: the text stayed a string
    assert set(data) >= {"base", "name", "vehicle"} and data["vehicle"].get("mass", 0) > 100
    assert model.replace("\x00", "") in data["name"] or model in data["name"]
    assert load_parameters(car).vehicle.mass == data["vehicle"]["mass"]


@pytest.mark.parametrize(
    ("args", "expect"),
    [
        (["--cycles", "ftp_bag2,ftp_bag2"], "more than once"),
        (["--limit", "-1"], "--limit -1"),
        (["--limit", "0"], "--limit 0"),
        (["--group-by", "maker"], "maker"),
    ],
)
def test_fleet_refuses_bad_options_before_any_work(tmp_path, capsys, args, expect):
    lst = write_list(tmp_path / "list.csv")
    code, _, err = run_cli(capsys, "fleet", lst, "--out", tmp_path / "o", "--no-peer", "--quiet", *args)
    assert code == 2 and expect in err


def test_fleet_refuses_an_output_it_cannot_write_before_running(tmp_path, capsys):
    lst = write_list(tmp_path / "list.csv")
    blocker = tmp_path / "afile"
    blocker.write_text("not a folder")
    code, _, err = run_cli(capsys, "fleet", lst, "--out", blocker / "sub", "--no-peer", "--quiet")
    assert code == 2 and "cannot write there" in err
    code, _, err = run_cli(capsys, "fleet", lst, "--out", tmp_path, "--no-peer", "--quiet")
    assert code == 2 and "holds an input" in err  # the input lies inside the output folder


def test_a_folder_from_an_unfinished_fleet_run_is_not_trusted(tmp_path, capsys):
    lst = write_list(tmp_path / "list.csv")
    out = tmp_path / "fleet"
    code, _, _ = run_cli(
        capsys, "fleet", lst, "--out", out, "--no-peer", "--quiet", "--cycles", "hwy", "--folds", "3"
    )
    assert code == 0 and not (out / INCOMPLETE).exists()
    car = tmp_path / "car.toml"
    args = ["vehicle", "from-epa", lst, "--id", "T004", "--out", car, "--technology", out / "technology.json"]
    assert run_cli(capsys, *args)[0] == 0
    (out / INCOMPLETE).write_text("killed while writing\n")  # as a run killed halfway leaves it
    code, _, err = run_cli(capsys, *args)
    assert code == 2 and "did not finish writing" in err


@pytest.mark.parametrize(
    ("field", "value", "reason"),
    [
        ("cylinders", "abc", "not a number: cylinders"),
        ("cylinders", "inf", "not a number: cylinders"),
        ("rated_hp", "4,000", "not a number: rated_hp"),
        ("cylinders", "2.5", "cylinders: 2.5 is not a whole number"),
        ("n_gears", "6.7", "n_gears: 6.7 is not a whole number"),
        ("displacement_l", "0", "implausible displacement_l"),
        ("displacement_l", "-2", "implausible displacement_l"),
        ("displacement_l", "0.05", "implausible displacement_l"),
        ("etw_lb", "1e300", "implausible etw_lb"),
        ("configuration", "1.9", "configuration 1.9 is not a whole number"),
    ],
)
def test_a_bad_record_field_is_named_never_routed_elsewhere(tmp_path, field, value, reason):
    """Each field checked on its own: a non-number is not 'missing', an impossible engine is not 'electric',
    a huge test weight is not a 'hybrid', a fractional count is not rounded, configuration 1.9 is not 1."""
    from vpsim.fleet.epa import read_test_car_list

    lst = _edited(
        write_list(tmp_path / "list.csv", bad_rows=False), tmp_path / "bad.csv", "T004", field, value
    )
    cars = read_test_car_list(lst)
    assert "T004" not in {v.vehicle_id for v in cars.vehicles}
    reasons = [r["reason"] for r in cars.excluded_rows if r["vehicle_id"] == "T004"]
    assert reasons and all(reason in r for r in reasons), reasons
    assert not any(r.startswith(("electric", "hybrid", "missing")) for r in reasons), reasons


@pytest.mark.parametrize(
    ("field", "value", "reason"),
    [
        ("rated_hp", "", "electric, missing rated_hp"),
        ("rated_hp", "0", "electric, implausible rated_hp"),
        ("rated_hp", "37", "electric, implausible rated_hp: 37"),  # the Kona Electric's record
        ("rated_hp", "1e9", "electric, implausible rated_hp"),
        ("rated_hp", "fast", "electric, not a number: rated_hp"),
        ("etw_lb", "", "electric, missing etw_lb"),
        ("etw_lb", "-5", "electric, implausible etw_lb"),
        ("target_c_lbf_per_mph2", "nan", "electric, not a number: target_c_lbf_per_mph2"),
        ("nv_ratio", "999.9", "electric, implausible axle_ratio and nv_ratio"),  # with axle 1.00 below
        ("axle_ratio", "x", "electric, not a number: axle_ratio"),
        ("fe", "-3", "electric, no charge-depleting UDDS or highway test"),
        ("fe", "1e6", "electric, implausible"),
    ],
)
def test_a_bad_ev_record_is_excluded_naming_the_field(tmp_path, capsys, field, value, reason):
    """A hostile EV record: one line naming the field, exit 2 from from-epa, never a silent fix."""
    from fleet_csv import EVS, write_ev_list
    from vpsim.fleet.epa import read_test_car_list

    lst = write_ev_list(tmp_path / "ev.csv", evs=[EVS[2]])  # axle 1.00: its ratio comes from N/V
    bad = _edited(lst, tmp_path / "bad.csv", "E003", field, value)
    cars = read_test_car_list(bad)
    assert "E003" not in {v.vehicle_id for v in cars.ev_vehicles}
    why = [r["reason"] for r in cars.excluded_rows if r["vehicle_id"] == "E003" and r["test_number"] == ""]
    assert len(why) == 1 and why[0].startswith(reason), why
    code, _, err = run_cli(capsys, "vehicle", "from-epa", bad, "--id", "E003", "--out", tmp_path / "c.toml")
    assert code == 2 and reason in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "c.toml").exists()


def test_an_ev_with_its_tests_in_two_units_is_excluded(tmp_path):
    from fleet_csv import EVS, ev_rows, write_list
    from vpsim.fleet.epa import COL, read_test_car_list

    rows = ev_rows(EVS[0])
    rows[0][COL["fe"]] = 25.0  # UDDS in kWh/100 mi, the highway in MPGe: which is which is unknown
    lst = write_list(tmp_path / "l.csv", bad_rows=False)
    with lst.open("a", newline="", encoding="utf-8") as f:
        with lst.open(newline="", encoding="utf-8-sig") as g:
            header = next(csv.reader(g))
        csv.DictWriter(f, fieldnames=header).writerows(rows)
    cars = read_test_car_list(lst)
    assert not cars.ev_vehicles
    assert cars.excluded["electric, tests in two units"] == 1


@pytest.mark.parametrize(
    ("edits", "reason"),
    [
        ({"target_a_lbf": "1", "target_b_lbf_per_mph": "-3"}, "implausible road load"),  # < 0 from 1 mph on
        ({"target_a_lbf": "5", "target_b_lbf_per_mph": "-1"}, "implausible road load"),  # < 0 in the middle
        ({"rated_hp": "40", "etw_lb": "9000"}, "implausible rated_hp: 40 hp at etw_lb 9000"),  # 7 W/kg
        ({"rated_hp": "1600", "etw_lb": "1500"}, "implausible rated_hp: 1600 hp at etw_lb 1500"),  # 1754 W/kg
    ],
)
@pytest.mark.parametrize("vehicle_id", ["T004", "E001"])
def test_a_record_whose_fields_do_not_fit_together_is_excluded(tmp_path, capsys, edits, reason, vehicle_id):
    """Each field plausible on its own, the record not: a road load that turns negative below the US06's top
    speed, a test weight the rated power could never move (or a rocket). One line naming the fields, values
    and what was expected; never run as ok."""
    from fleet_csv import EVS, write_ev_list
    from vpsim.fleet.epa import read_test_car_list

    lst = write_ev_list(tmp_path / "list.csv", evs=[EVS[0]])
    for i, (field, value) in enumerate(edits.items()):
        lst = _edited(lst, tmp_path / f"bad{i}.csv", vehicle_id, field, value)
    cars = read_test_car_list(lst)
    assert vehicle_id not in {v.vehicle_id for v in [*cars.vehicles, *cars.ev_vehicles]}
    rows = cars.excluded_rows
    why = [r["reason"] for r in rows if r["vehicle_id"] == vehicle_id and r["test_number"] == ""]
    assert len(why) == 1 and reason in why[0] and "expected" in why[0], why
    out = tmp_path / "c.toml"
    code, _, err = run_cli(capsys, "vehicle", "from-epa", lst, "--id", vehicle_id, "--out", out)
    assert code == 2 and reason in err
    assert not (tmp_path / "c.toml").exists()


@settings(max_examples=300)
@given(
    a=st.floats(1.0, 200.0),
    b=st.floats(-3.0, 3.0),
    c=st.floats(0.005, 0.15),
)
def test_the_road_load_check_agrees_with_the_road_load_at_every_speed(a, b, c):
    """road_load_problem is None exactly when A + B v + C v^2 > 0 from 0 to the US06's top speed."""
    import numpy as np

    from vpsim.fleet.cycles import fleet_cycle
    from vpsim.fleet.epa import MPH_TO_MPS, ROAD_LOAD_TOP_SPEED_MPH, road_load_problem

    top = fleet_cycle("us06").speed_mps.max() / MPH_TO_MPS
    assert abs(top - ROAD_LOAD_TOP_SPEED_MPH) < 0.05
    v = np.linspace(0.0, ROAD_LOAD_TOP_SPEED_MPH, 2001)
    f = a + b * v + c * v * v
    problem = road_load_problem(a, b, c)
    if f.min() > 1e-6:
        assert problem is None
    elif f.min() < -1e-6:
        assert problem is not None and problem.startswith("implausible road load")


def _technology(path: Path, **changes) -> Path:
    """A technology.json as a fleet run writes it (its fitted tables only), ``changes`` to every class."""
    import json

    fit = {
        "engine.thermal_efficiency": 0.4,
        "engine.friction_coefficient": 1.0,
        "engine.accessory_power": 500,
    }
    bev = {"machine.loss_scale": 0.4, "electric.accessory_power": 300.0}
    conv = {k: v for k, v in changes.items() if k in fit}
    ev = {k: v for k, v in changes.items() if k in bev}
    data = {
        "all_vehicles": {c: {**fit, **conv} for c in ("na", "boosted", "high_output")},
        "bev": {"all_vehicles": {"bev": {**bev, **ev}}},
    }
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize(
    ("vehicle_id", "field", "value", "expect"),
    [
        ("T004", "engine.thermal_efficiency", 1.0, "outside (0, 1)"),
        ("T004", "engine.thermal_efficiency", 1.5, "outside (0, 1)"),
        ("T004", "engine.thermal_efficiency", 0.6, "not below 0.6"),
        ("T004", "engine.thermal_efficiency", True, "true is not a number"),
        ("T004", "engine.friction_coefficient", False, "false is not a number"),
        ("T004", "engine.thermal_efficiency", "0.4", "is not a number"),
        ("T004", "engine.thermal_efficiency", None, "is not a number"),
        ("T004", "engine.thermal_efficiency", 1e400, "not a finite number"),  # json.dumps writes Infinity
        ("T004", "engine.accessory_power", -5, "outside the plausible range"),
        ("E001", "machine.loss_scale", True, "true is not a number"),
        ("E001", "electric.accessory_power", [1], "is not a number"),
    ],
)
def test_a_technology_file_value_is_a_number_in_range(tmp_path, capsys, vehicle_id, field, value, expect):
    """An efficiency of 1 or more, or a boolean, from a technology.json is refused with one line naming the
    file and field; nothing is written."""
    from fleet_csv import EVS, write_ev_list

    lst = write_ev_list(tmp_path / "list.csv", evs=[EVS[0]])
    tech = _technology(tmp_path / "technology.json", **{field: value})
    car = tmp_path / "c.toml"
    args = ["vehicle", "from-epa", lst, "--id", vehicle_id, "--out", car, "--technology", tech]
    code, _, err = run_cli(capsys, *args)
    if value == 1e400:
        expect = "Infinity is not a JSON number"
    assert code == 2 and expect in err and str(tech) in err, err
    assert not car.exists()


def _set(data: dict, dotted: str, value) -> None:
    """``data`` with the key at the dotted path (its last part the new key) set to ``value``."""
    *parents, key = dotted.split("/")
    for p in parents:
        data = data[p]
    data[key] = value


@pytest.mark.parametrize(
    ("vehicle_id", "where", "value", "expect"),
    [
        # a misspelt fit: read as absent, the default accessory power would have been used
        ("T004", "all_vehicles/boosted/engine.accesory_power", 100.0, "boosted.engine.accesory_power'"),
        ("T004", "all_vehicles/na/engine.thermal_efficiency ", 0.3, "'all_vehicles.na.engine.thermal_effic"),
        ("T004", "all_vehicle", {}, "'all_vehicle'"),  # a misspelt table beside the right one
        ("T004", "all_vehicles/NA", {}, "'all_vehicles.NA'"),  # a class no fleet run fits
        ("T004", "bev/all_vehicle", {}, "'bev.all_vehicle'"),  # the whole file is checked, not the part read
        ("T004", "all_vehicles/boosted/extra", 1.0, "'all_vehicles.boosted.extra'"),
        ("E001", "bev/all_vehicles/bev/machine.loss_scale_", 1.0, "'bev.all_vehicles.bev.machine.loss_"),
        ("E001", "bev/all_vehicles/suv", {}, "'bev.all_vehicles.suv'"),
        ("T004", "all_vehicles/na/" + "k" * 5000, 1.0, "..."),  # a long key is cut, the line stays short
        ("T004", "all_vehicles/na/\x1b[31m", 1.0, "\\x1b[31m"),  # escaped for the terminal
    ],
)
def test_a_technology_file_with_a_key_no_fleet_run_writes_is_refused(
    tmp_path, capsys, vehicle_id, where, value, expect
):
    """An unknown key anywhere in a technology.json (a misspelt key silently ignored is a wrong number): one
    line naming the file, the key and the keys expected there; nothing written."""
    import json

    from fleet_csv import EVS, write_ev_list

    lst = write_ev_list(tmp_path / "list.csv", evs=[EVS[0]])
    tech = _technology(tmp_path / "technology.json")
    data = json.loads(tech.read_text())
    _set(data, where, value)
    tech.write_text(json.dumps(data))
    car = tmp_path / "c.toml"
    args = ["vehicle", "from-epa", lst, "--id", vehicle_id, "--out", car, "--technology", tech]
    code, _, err = run_cli(capsys, *args)
    assert code == 2 and str(tech) in err and "unknown key" in err and "only:" in err, err
    assert expect in err and "\x1b" not in err, err
    assert not car.exists()


def test_a_technology_file_without_the_cars_class_says_which_it_has(tmp_path, capsys):
    import json

    lst = write_list(tmp_path / "list.csv")
    tech = _technology(tmp_path / "technology.json")
    data = json.loads(tech.read_text())
    del data["all_vehicles"]["boosted"]
    tech.write_text(json.dumps(data))
    args = ["vehicle", "from-epa", lst, "--id", "T004", "--out", tmp_path / "c.toml", "--technology", tech]
    code, _, err = run_cli(capsys, *args)
    assert code == 2 and "has no fit for this car's class boosted (the run fitted: na, high_output)" in err


def test_a_technology_file_in_range_is_used(tmp_path, capsys):
    lst = write_list(tmp_path / "list.csv")
    tech = _technology(tmp_path / "technology.json", **{"engine.thermal_efficiency": 0.45})
    car = tmp_path / "c.toml"
    code, _, _ = run_cli(
        capsys, "vehicle", "from-epa", lst, "--id", "T004", "--out", car, "--technology", tech
    )
    assert code == 0 and load_parameters(car).engine.thermal_efficiency == 0.45


@pytest.mark.parametrize("mpg", ["0.001", "1e9", "-3", "nan", "inf", "true", '"28"', "2" * 400])
def test_an_edited_measurement_is_no_comparison(tmp_path, capsys, mpg):
    """A record block's measured mpg outside the certification reader's 5-150 mpg: the run stands, without
    a comparison (never an error of +2,872,153 %), and a note says why."""
    import json

    lst = write_list(tmp_path / "list.csv")
    car = tmp_path / "car.toml"
    assert run_cli(capsys, "vehicle", "from-epa", lst, "--id", "T004", "--out", car)[0] == 0
    text = car.read_text()
    assert "\n# ftp_bag2 = " in text
    start = text.index("\n# ftp_bag2 = ") + len("\n# ftp_bag2 = ")
    car.write_text(text[:start] + mpg + text[text.index("\n", start) :])
    code, out, err = run_cli(capsys, "simulate", "--vehicle", car, "--cycle", "ftp_bag2", "--json")
    assert code == 0
    summary = json.loads(out)
    assert summary["measured_mpg"] is None and summary["measured_error_pct"] is None
    if mpg not in ("true", '"28"'):
        assert "no measurement to compare with" in err


@pytest.mark.parametrize("sep", [";", "\t"])
def test_a_list_saved_with_semicolons_or_tabs_reads_as_the_commas(tmp_path, sep):
    from vpsim.fleet.epa import read_test_car_list

    lst = write_list(tmp_path / "list.csv")
    with lst.open(newline="", encoding="utf-8-sig") as f:
        rows = list(csv.reader(f))
    other = tmp_path / "other.csv"
    with other.open("w", newline="", encoding="utf-8") as f:
        csv.writer(f, delimiter=sep).writerows(rows)
    a, b = read_test_car_list(lst), read_test_car_list(other)
    assert [v.as_dict() for v in a.vehicles] == [v.as_dict() for v in b.vehicles] and a.vehicles
    assert a.excluded == b.excluded


def test_a_record_with_a_pushing_road_load_is_listed_in_excluded_csv_never_run(tmp_path, capsys):
    lst = _edited(write_list(tmp_path / "list.csv"), tmp_path / "a.csv", "T004", "target_a_lbf", "1")
    lst = _edited(lst, tmp_path / "b.csv", "T004", "target_b_lbf_per_mph", "-3")
    out = tmp_path / "fleet"
    args = ["fleet", lst, "--out", out, "--no-peer", "--quiet", "--cycles", "hwy", "--folds", "3"]
    assert run_cli(capsys, *args)[0] == 0
    with (out / "excluded.csv").open(newline="") as f:
        why = [r["reason"] for r in csv.DictReader(f) if r["vehicle_id"] == "T004"]
    assert len(why) == 1 and why[0].startswith("implausible road load: target_a_lbf 1,"), why
    with (out / "vehicles.csv").open(newline="") as f:
        assert "T004" not in {r["vehicle_id"] for r in csv.DictReader(f)}


@pytest.mark.parametrize(
    ("value", "reason"),
    [("1.9", "configuration 1.9 is not a whole number"), ("x", "configuration 'x' is not a number")],
)
def test_from_epa_names_why_every_row_of_a_vehicle_was_left_out(tmp_path, capsys, value, reason):
    """Every test row of a vehicle excluded (configuration 1.9): from-epa says why, not "no vehicle"."""
    lst = _edited(write_list(tmp_path / "list.csv"), tmp_path / "bad.csv", "T004", "configuration", value)
    code, _, err = run_cli(capsys, "vehicle", "from-epa", lst, "--id", "T004", "--out", tmp_path / "c.toml")
    assert code == 2 and f"vehicle T004: every test row is excluded ({reason})" in err, err


@settings(max_examples=15)
@given(
    picks=st.lists(st.integers(min_value=0, max_value=10_000), min_size=1, max_size=3, unique=True),
    extra=st.integers(min_value=1, max_value=40),
    text=st.sampled_from(["x", "", '"a,b"', "1e999", ";"]),
)
def test_rows_with_extra_fields_leave_out_their_vehicles_only(tmp_path_factory, picks, extra, text):
    """Any rows given extra fields (a stray separator, junk cells): the vehicles those rows name are excluded
    as unreadable with their line, every other vehicle reads as from the clean list."""
    from vpsim.fleet.epa import read_test_car_list

    d = tmp_path_factory.mktemp("ragged")
    lst = write_list(d / "list.csv")
    with lst.open(newline="", encoding="utf-8-sig") as f:
        rows = list(csv.reader(f))
    i_id, i_cfg = rows[0].index("Test Vehicle ID"), rows[0].index("Test Veh Configuration #")
    hit = sorted({1 + p % (len(rows) - 1) for p in picks})
    for i in hit:
        rows[i] += [text] * extra
    with (d / "ragged.csv").open("w", newline="", encoding="utf-8") as f:
        csv.writer(f).writerows(rows)
    clean, ragged = read_test_car_list(lst), read_test_car_list(d / "ragged.csv")
    gone = {(rows[i][i_id], int(rows[i][i_cfg])) for i in hit}
    # (a vehicle of the same make and model as a left-out one may be classed differently without it: a
    # plug-in's gasoline-only twin is one because of the plug-in's tests)
    i_make, i_model = rows[0].index("Represented Test Veh Make"), rows[0].index("Represented Test Veh Model")
    twins = {(rows[i][i_make].lower(), rows[i][i_model].lower()) for i in hit}
    keep = lambda cars: {  # noqa: E731
        (v.vehicle_id, v.configuration): v.as_dict()
        for v in [*cars.vehicles, *cars.ev_vehicles, *cars.hev_vehicles]
        if (v.vehicle_id, v.configuration) not in gone and (v.make.lower(), v.model.lower()) not in twins
    }
    assert keep(ragged) == keep(clean)
    assert ragged.excluded["unreadable row"] == len(gone)
    said = [r["reason"] for r in ragged.excluded_rows if r["reason"].startswith("unreadable row")]
    # each vehicle is named once, at the first of its ragged rows
    first = {}
    for i in hit:
        first.setdefault((rows[i][i_id], int(rows[i][i_cfg])), i + 1)
    assert sorted(int(w.split("line ")[1].split()[0]) for w in said) == sorted(first.values())


_JSON_VALUES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.lists(st.integers(), max_size=2),
)
_CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=8),
    st.just(""),
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    seed=_JSON_VALUES,
    folds=_JSON_VALUES,
    grouping=_JSON_VALUES,
    error=_CELLS,
    peer=_CELLS,
    family=_CELLS,
    raw=st.one_of(st.none(), st.binary(max_size=64)),
)
def test_fleet_deals_answers_any_folder_in_one_line_or_with_finite_figures(
    tmp_path_factory, capsys, seed, folds, grouping, error, peer, family, raw
):
    """``vpsim fleet-deals`` on a made-up folder beside a sound one: any summary.json values, any cell in
    the per-row table, or raw bytes in place of either."""
    import json as _json

    root = tmp_path_factory.mktemp("deals")
    good, bad = root / "good", root / "bad"
    for d, validation, cells in (
        (good, {"grouping": "family", "folds": 5, "seed": 0}, ("1.5", "3.0", "F1")),
        (bad, {"grouping": grouping, "folds": folds, "seed": seed}, (error, peer, family)),
    ):
        d.mkdir()
        (d / "summary.json").write_text(_json.dumps({"n_vehicles": 2, "validation": validation}))
        with (d / "vehicles.csv").open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(
                [
                    "vehicle_id",
                    "configuration",
                    "cycle",
                    "error_pct",
                    "family",
                    "fastsim_calibrated_error_pct",
                ]
            )
            w.writerow(["V1", 0, "hwy", "2.0", "F0", "4.0"])
            w.writerow(["V2", 0, "hwy", cells[0], cells[2], cells[1]])
    if raw is not None:
        (bad / ("summary.json" if raw[:1] in (b"", b"{") else "vehicles.csv")).write_bytes(raw)
    for as_json in ((), ("--json",)):
        run_cli(capsys, "fleet-deals", good, bad, *as_json)
