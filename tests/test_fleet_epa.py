"""Vehicles from certification records: unit conversions, exclusions, the record -> parameters mapping."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fleet_csv import CARS, write_list
from vpsim.errors import VpsimError
from vpsim.fleet import epa
from vpsim.fleet.cycles import fleet_cycle, time_window
from vpsim.fleet.epa import read_test_car_list
from vpsim.fleet.vehicle import (
    AIR_DENSITY,
    FRONTAL_AREA_M2,
    bore_stroke,
    fold_road_load,
    gear_ratios,
    record_parameters,
    top_gear_total_ratio,
)


def test_unit_conversions_against_hand_values():
    # 3500 lb x 0.45359237 kg/lb
    assert 3500 * epa.LB_TO_KG == pytest.approx(1587.573295, rel=1e-9)
    # 1 lbf = 0.45359237 kg x 9.80665 m/s^2 = 4.448222 N
    assert epa.LBF_TO_N == pytest.approx(0.45359237 * 9.80665, rel=1e-12)
    assert 40 * epa.LBF_TO_N == pytest.approx(177.9289, rel=1e-6)
    # 1 lbf/mph = 4.448222 N / 0.44704 m/s = 9.950388 N/(m/s)
    assert epa.lbf_per_mph_to_si(1.0) == pytest.approx(9.950388, rel=1e-6)
    # 1 lbf/mph^2 = 4.448222 N / (0.44704 m/s)^2 = 22.25840 N/(m/s)^2
    assert epa.lbf_per_mph2_to_si(0.02) == pytest.approx(0.445168, rel=1e-5)
    # 10 L/100 km = 23.52 mpg
    assert epa.mpg_from_l_per_100km(10.0) == pytest.approx(23.5215, rel=1e-5)


def test_an_empty_cylinder_count_is_filled_only_where_the_list_agrees(tmp_path):
    """fill_cylinders: the engine code's tests first, else two or more other test vehicles of the same make
    and displacement that all agree; otherwise the car stays out as ``missing cylinders``."""
    import csv

    from fleet_csv import EXTRA, car_rows
    from vpsim.fleet.epa import COL
    from vpsim.fleet.vehicle import record_parameters, vehicle_toml

    acme, cogs, bolt, dyna = CARS[1], CARS[9], CARS[3], CARS[10]  # 2.0 L x4, 2.0 L x4, 2.0 L x4, 1.6 L x4
    assert (acme[3], cogs[3], bolt[3], dyna[3]) == (2.0, 2.0, 2.0, 1.6)
    rows = []
    for car in (acme, cogs, bolt, dyna):
        rows += car_rows(car)
    rows += car_rows(("W001",) + acme[1:])  # a second Acme 2.0 L with 4 cylinders
    rows += car_rows(("W002",) + bolt[1:], cylinders=3)  # a Bolt&Nut 2.0 L with 3: the make disagrees
    rows += car_rows(("W003", "Other") + acme[2:], engine_code="ENG1", cylinders=5)
    rows += car_rows(("F001",) + acme[1:], cylinders="")  # two Acme witnesses: filled
    rows += car_rows(("F002",) + cogs[1:], cylinders="")  # one Cogs 2.0 L only: not filled
    rows += car_rows(("F003",) + dyna[1:], cylinders="", engine_code="ENG1")  # its engine code: 5
    rows += car_rows(("F004",) + bolt[1:], cylinders="")  # Bolt&Nut 2.0 L: 4 and 3, not filled
    rows += car_rows(("F005",) + acme[1:], cylinders="4-ish")  # not a number: not filled
    path = tmp_path / "list.csv"
    with path.open("w", newline="", encoding="utf-8-sig") as fh:
        w = csv.DictWriter(fh, fieldnames=list(EXTRA) + list(COL.values()))
        w.writeheader()
        w.writerows(rows)
    cars = read_test_car_list(path)
    got = {v.vehicle_id: (v.cylinders, v.cylinders_source) for v in cars.vehicles}
    assert got["F001"] == (4, "the field is empty; 4 from 2 other test vehicles of Acme with 2.00 L")
    assert got["F003"] == (5, "the field is empty; 5 from 3 other test(s) of engine code ENG1")
    assert got["W001"] == (4, "")  # a given count keeps its value and says nothing
    reasons = {r["vehicle_id"]: r["reason"] for r in cars.excluded_rows if r["test_number"] == ""}
    assert reasons["F002"] == "missing cylinders"
    assert reasons["F004"] == "missing cylinders"
    assert reasons["F005"] == "not a number: cylinders = '4-ish'"
    f001 = next(v for v in cars.vehicles if v.vehicle_id == "F001")
    text = vehicle_toml(f001, record_parameters(f001))
    assert "4 cyl., S/B" in text and "(cylinders: the field is empty; 4 from 2 other test vehicles" in text


def test_bad_rows_are_excluded_with_their_reason(tmp_path):
    cars = read_test_car_list(write_list(tmp_path / "list.csv"))
    # X107 keeps its bag 3 and HWY tests; X103, a flex-fuel car, its gasoline tests (its E85 ones, at 0.75
    # of the mpg, are skipped, not averaged in)
    assert len(cars.vehicles) == len(CARS) + 2
    x103 = next(v for v in cars.vehicles if v.vehicle_id == "X103")
    base = next(v for v in cars.vehicles if v.vehicle_id == CARS[1][0])
    assert x103.measured_mpg == base.measured_mpg
    assert cars.excluded == {
        # made-up makes: no layout of vpsim.fleet.hev fits them
        "hybrid, no built layout": 5,
        "plug-in hybrid": 2,
        # a made-up make: no mild-hybrid system of vpsim.fleet.mhev is known for it
        "mild hybrid, no known system": 1,
        "diesel": 1,
        # an electric car without the two charge-depleting tests (vpsim.fleet.ev)
        "electric, no charge-depleting UDDS or highway test": 1,
        "flex-fuel (E85 test)": 1,
        "implausible etw_lb": 1,
        "missing target_a_lbf": 1,
    }
    reasons = {r["vehicle_id"]: r["reason"] for r in cars.excluded_rows if r["test_number"] == ""}
    assert reasons["X104"] == "implausible etw_lb: 150 outside [1500, 10000]"
    assert reasons["X105"] == "missing target_a_lbf"
    assert reasons["X100"].startswith("hybrid, no built layout: ")
    assert reasons["X100"].endswith("(screened: " + "hybrid" + ")")
    assert reasons["X106"].startswith("hybrid, no built layout: ")
    assert reasons["X106"].endswith("(screened: " + "hybrid: city mpg >= highway mpg" + ")")
    assert reasons["X110"].startswith("hybrid, no built layout: ")
    assert reasons["X110"].endswith("(screened: hybrid: hot town (FTP bag 2) mpg >= 0.86 x highway mpg)")
    assert reasons["X111"].startswith("hybrid, no built layout: ")
    assert reasons["X111"].endswith("(screened: " + "hybrid" + ")")
    assert reasons["X113"].startswith("mild hybrid, no known system: ")
    assert reasons["X113"].endswith("(screened: mild hybrid: FTP with a fourth bag)")
    assert "(screened: hybrid: wheel work / fuel energy on HWY 0." in reasons["X112"]
    assert reasons["X109"] == "plug-in hybrid"
    assert reasons["X108"] == "plug-in hybrid: another test vehicle of this model is a plug-in hybrid"
    bag = [r for r in cars.excluded_rows if r["vehicle_id"] == "X107"]
    assert len(bag) == 1 and bag[0]["reason"] == "FTP test: FE Bag 2 999 mpg outside [5, 150]"
    x107 = cars.find("X107")
    assert set(x107.measured_mpg) == {"ftp_bag3", "hwy", "us06"}  # no ftp_bag2
    with pytest.raises(VpsimError, match="X104 is excluded: implausible etw_lb"):
        cars.find("X104")


def test_a_row_with_extra_fields_leaves_out_its_vehicle_not_the_list(tmp_path):
    """A stray separator in one row (more fields than the header) used to refuse the whole list; now only the
    vehicle that row names is left out, with the line, and every other vehicle reads as before."""
    good = read_test_car_list(write_list(tmp_path / "list.csv", bad_rows=False))
    lines = (tmp_path / "list.csv").read_text().splitlines()
    victim = CARS[1][0]
    at = next(i for i, line in enumerate(lines) if f",{victim}," in line and ",HWY," in line)
    lines[at] += ",x,y"  # two fields too many
    lines.append("Ghost,,,," + ",".join(["z"] * (lines[0].count(",") + 2)))  # ragged, no vehicle
    (tmp_path / "ragged.csv").write_text("\n".join(lines) + "\n")
    cars = read_test_car_list(tmp_path / "ragged.csv")
    assert {v.vehicle_id for v in cars.vehicles} == {v.vehicle_id for v in good.vehicles} - {victim}
    kept = {v.vehicle_id: v.measured_mpg for v in good.vehicles if v.vehicle_id != victim}
    assert {v.vehicle_id: v.measured_mpg for v in cars.vehicles} == kept
    assert cars.excluded == {"unreadable row": 1}
    ncols = lines[0].count(",") + 1
    why = {r["vehicle_id"]: r["reason"] for r in cars.excluded_rows}
    assert why[victim] == f"unreadable row: line {at + 1} has {ncols + 2} fields where the header has {ncols}"
    ghost = [r for r in cars.excluded_rows if r["line"] == len(lines)]
    assert len(ghost) == 1 and ghost[0]["reason"].startswith("unreadable row")
    with pytest.raises(VpsimError, match=f"{victim} is excluded: unreadable row: line {at + 1}"):
        cars.find(victim)
    # the other vehicles' rows keep their own line numbers
    assert [r["line"] for r in cars.excluded_rows if r["vehicle_id"] == victim] == [
        next(i for i, line in enumerate(lines) if f",{victim}," in line) + 1
    ]


def test_implied_highway_efficiency_by_hand(tmp_path):
    # steady 60 mph on a made-up "cycle" would give F v / (fuel power); here the HWFET itself: check the
    # conventional made-up cars stay well below the hybrid limit and scale as 1/mpg
    cars = read_test_car_list(write_list(tmp_path / "list.csv", bad_rows=False))
    rec = cars.find("T002")
    t = {
        "target_a_lbf": rec.target_a_lbf,
        "target_b_lbf_per_mph": rec.target_b_lbf_per_mph,
        "target_c_lbf_per_mph2": rec.target_c_lbf_per_mph2,
        "etw_lb": rec.etw_lb,
    }
    e38 = epa.implied_hwy_efficiency(t, 38.0)
    assert 0.15 < e38 < 0.35
    assert epa.implied_hwy_efficiency(t, 76.0) == pytest.approx(2 * e38)
    assert math.isnan(epa.implied_hwy_efficiency(dict(t, etw_lb=math.nan), 38.0))


def test_record_fields_and_rules(tmp_path):
    cars = read_test_car_list(write_list(tmp_path / "list.csv", bad_rows=False))
    cvt = cars.find("T001")
    assert cvt.transmission_kind == "cvt" and cvt.n_gears == 1
    assert not cvt.boosted  # 110 hp / 1.5 L = 54.7 kW/L
    coupe = cars.find("T004")
    assert coupe.boosted and coupe.transmission_kind == "amt_dct"  # 250 hp / 2 L = 93 kW/L
    assert coupe.mass_kg == pytest.approx(3625 * 0.45359237)
    a, b, c = coupe.road_load_si
    assert (a, b, c) == pytest.approx((30 * 4.4482216152605, 0.2 * 9.950388, 0.019 * 22.258397), rel=1e-6)
    fam = cars.find("T002")
    assert fam.measured_mpg == pytest.approx({"ftp_bag2": 27, "ftp_bag3": 29, "hwy": 38, "us06": 24})


def test_unreadable_list_is_one_line_error(tmp_path):
    with pytest.raises(VpsimError, match="no such file"):
        read_test_car_list(tmp_path / "none.csv")
    p = tmp_path / "other.csv"
    p.write_text("a,b\n1,2\n")
    with pytest.raises(VpsimError, match="not an EPA test car list; missing column"):
        read_test_car_list(p)


def test_bore_stroke_and_top_gear():
    b, s = bore_stroke(2.0, 4, 1.05)
    assert 4 * math.pi / 4 * b * b * s == pytest.approx(2.0e-3, rel=1e-12)
    assert s / b == pytest.approx(1.05)
    # 25 rpm per mph with r = 0.33 m: w_e = 25 x 2 pi / 60 rad/s at 0.44704 m/s -> i = w_e r / v
    assert top_gear_total_ratio(25.0, 0.33) == pytest.approx(25 * 2 * math.pi / 60 * 0.33 / 0.44704)


def test_gear_ratios_follow_the_record(tmp_path):
    cars = read_test_car_list(write_list(tmp_path / "list.csv", bad_rows=False))
    for vid in ("T002", "T005", "T007", "T008"):
        rec = cars.find(vid)
        ratios, final = gear_ratios(rec)
        assert final == pytest.approx(rec.axle_ratio)
        assert ratios[-1] * final == pytest.approx(top_gear_total_ratio(rec.nv_ratio))
        assert all(np.diff(ratios) < 0)
        assert len(ratios) == (2 if rec.transmission_kind == "cvt" else rec.n_gears)  # a CVT: its range


def test_a_cvt_record_is_a_cvt_over_its_range(tmp_path):
    """A CVT record: range [6.5 x overdrive, overdrive], ratio grid of 2 % steps, lock-up by speed alone;
    the TOML of ``vpsim vehicle from-epa`` reads back to the same CVT."""
    from vpsim.fleet.vehicle import CVT_RATIO_STEP, CVT_SPREAD, record_parameters, vehicle_toml
    from vpsim.params import load_parameters

    cars = read_test_car_list(write_list(tmp_path / "list.csv", bad_rows=False))
    rec = cars.find("T008")
    assert rec.transmission_kind == "cvt"
    p = record_parameters(rec)
    tr = p.transmission
    assert tr.is_cvt and tr.cvt_ratio_step == CVT_RATIO_STEP and tr.lockup_min_gear == 1
    launch, overdrive = tr.gearbox_ratios
    assert launch / overdrive == pytest.approx(CVT_SPREAD)
    steps = np.asarray(tr.gearbox_steps)
    assert steps[0] == launch and steps[-1] == pytest.approx(overdrive, rel=1e-12)
    # ln 6.5 / ln 1.02 = 94.5: 96 points, equal steps of 6.5^(1/95) - 1 = 1.99 %
    assert tr.n_gears == 96
    assert np.allclose(steps[:-1] / steps[1:], CVT_SPREAD ** (1 / 95), rtol=1e-12)
    path = tmp_path / "cvt.toml"
    path.write_text(vehicle_toml(rec, p))
    q = load_parameters(path).transmission  # (the file rounds to 6 significant digits)
    assert q.cvt_ratio_step == tr.cvt_ratio_step and q.n_gears == tr.n_gears and q.lockup_min_gear == 1
    np.testing.assert_allclose(q.ratios, tr.ratios, rtol=1e-5)


def test_road_load_fold_is_exact_without_b_term(tmp_path):
    from dataclasses import replace

    cars = read_test_car_list(write_list(tmp_path / "list.csv", bad_rows=False))
    rec = replace(cars.find("T003"), target_b_lbf_per_mph=0.0)
    a, _, c = rec.road_load_si
    c_r, c_d, misfit = fold_road_load(rec, [fleet_cycle("hwy")])
    assert c_r == pytest.approx(a / (rec.mass_kg * 9.81), rel=1e-6)
    assert c_d == pytest.approx(c / (0.5 * AIR_DENSITY * FRONTAL_AREA_M2), rel=1e-6)
    assert misfit < 1e-6
    # with a B term the fold is a compromise: the road-load work of the cycle is kept within a few percent
    rec_b = cars.find("T003")
    c_r, c_d, _ = fold_road_load(rec_b, [fleet_cycle("hwy")])
    cyc = fleet_cycle("hwy")
    v = 0.5 * (cyc.speed_mps[1:] + cyc.speed_mps[:-1])
    a, b, c = rec_b.road_load_si
    work_record = np.sum((a + b * v + c * v * v) * v)
    work_fold = np.sum((rec_b.mass_kg * 9.81 * c_r + 0.5 * AIR_DENSITY * FRONTAL_AREA_M2 * c_d * v * v) * v)
    assert work_fold == pytest.approx(work_record, rel=0.01)


def test_record_parameters_validate(tmp_path):
    cars = read_test_car_list(write_list(tmp_path / "list.csv", bad_rows=False))
    for rec in cars.vehicles:
        p = record_parameters(rec, technology={"engine.thermal_efficiency": 0.41})
        assert p.engine.displacement == pytest.approx(rec.displacement_l * 1e-3, rel=1e-9)
        assert p.engine.cylinders == rec.cylinders
        assert p.vehicle.mass == pytest.approx(rec.mass_kg)
        assert p.engine.thermal_efficiency == 0.41


def test_boosted_record_gets_enrichment_and_a_pedal_scaled_driver(tmp_path):
    """A boosted record: the full-load enrichment of lambda 0.87 and the PI gains scaled with the pedal's
    range (2 A_max with boost, A_max aspirated) over the preset's A_max; an aspirated one neither."""
    from vpsim.params import load_parameters

    base = load_parameters("hofman2011")
    cars = read_test_car_list(write_list(tmp_path / "list.csv", bad_rows=False))
    for rec, pedal in ((cars.find("T004"), 2.0), (cars.find("T001"), 1.0)):
        p = record_parameters(rec)
        assert (p.engine.boost_pressure > p.engine.ambient_pressure) == rec.boosted
        assert p.engine.boost_enrichment == (pytest.approx(1 / 0.87 - 1) if rec.boosted else 0.0)
        k = pedal * p.engine.max_throttle_area / base.engine.max_throttle_area
        for key, d in base.drivers.items():
            assert p.drivers[key].forward_kp == pytest.approx(k * d.forward_kp, rel=1e-12)
            assert p.drivers[key].forward_ki == pytest.approx(k * d.forward_ki, rel=1e-12)


def test_bag_cycles_are_udds_windows():
    bag2, bag3 = fleet_cycle("ftp_bag2"), fleet_cycle("ftp_bag3")
    assert bag2.time_s[0] == 0 and bag2.duration_s == 864 and bag3.duration_s == 505
    assert bag2.distance_m / 1e3 == pytest.approx(6.211, abs=1e-3)  # PROVENANCE: FTP-75 bag 2 6.211 km
    assert bag3.distance_m / 1e3 == pytest.approx(5.779, abs=1e-3)
    udds = fleet_cycle("hwy")
    part = time_window(udds, 10.5, 20.5)
    assert part.time_s[0] == 0 and part.duration_s == 10
    assert part.speed_mps[0] == pytest.approx(udds.speed_at(10.5))
    with pytest.raises(VpsimError, match="not inside"):
        time_window(udds, 0, 1e4)


def test_model_inputs_are_all_the_builder_reads(tmp_path):
    """Records equal in MODEL_INPUTS build one vehicle (the repeatability report relies on it): changing every
    other field leaves the parameters, the gear rule and the technology class as they were; changing an input
    changes the vehicle."""
    import dataclasses

    from vpsim.fleet.calibrate import vehicle_class
    from vpsim.fleet.run import gear_rule
    from vpsim.fleet.vehicle import MODEL_INPUTS, model_inputs
    from vpsim.params import as_dict

    cars = read_test_car_list(write_list(tmp_path / "list.csv", bad_rows=False))
    cycles = [fleet_cycle("hwy")]
    for rec in (cars.find("T002"), cars.find("T004")):

        def changed(v):
            if isinstance(v, bool):
                return not v
            if isinstance(v, str):
                return v + " (other)"
            if isinstance(v, int):
                return v + 7
            if isinstance(v, float):
                return 1.0 if math.isnan(v) else 1.5 * v
            return {k: 2 * x for k, x in v.items()}  # measured mpg, test counts

        fields = [f.name for f in dataclasses.fields(rec) if f.name not in MODEL_INPUTS]
        other = {name: changed(getattr(rec, name)) for name in fields}
        assert {"vehicle_id", "configuration", "make", "lockup", "drive", "measured_mpg"} <= set(other)
        twin = dataclasses.replace(rec, **other)
        assert model_inputs(twin) == model_inputs(rec)

        def built(r):
            d = as_dict(record_parameters(r, cycles))
            d.pop("name", None)
            return d, gear_rule(r), vehicle_class(r)

        assert built(twin) == built(rec)
        heavier = dataclasses.replace(rec, etw_lb=rec.etw_lb + 500)
        assert model_inputs(heavier) != model_inputs(rec) and built(heavier) != built(rec)


def test_idle_fuel_flow_from_the_measured_idle_and_the_accessories(tmp_path):
    """A 2.0 L car idles on 0.16 gal/h without load (Argonne: 0.16 x 3.785 L x 0.743 kg/L / 3600 s =
    0.1250 g/s), plus its accessories' 300 W at the engine's marginal efficiency (between 20 and 50 %)."""
    from vpsim.fleet.vehicle import ACCESSORY_POWER_W, FUEL_LHV_J_PER_KG, idle_fuel_flow

    cars = read_test_car_list(write_list(tmp_path / "list.csv", bad_rows=False))
    rec = cars.find("T004")  # 2.0 L
    p = record_parameters(rec, [fleet_cycle("hwy")])
    assert p.engine.displacement == pytest.approx(2.0e-3)
    extra = p.simulation.idle_fuel_flow - 0.12500e-3
    assert (
        ACCESSORY_POWER_W / (0.5 * FUEL_LHV_J_PER_KG) < extra < ACCESSORY_POWER_W / (0.2 * FUEL_LHV_J_PER_KG)
    )
    assert p.simulation.idle_fuel_flow == pytest.approx(idle_fuel_flow(p.engine), rel=1e-12)
    # no accessories: the measured no-load idle alone
    bare = p.with_changes(engine={"accessory_power": 0.0})
    assert idle_fuel_flow(bare.engine) == pytest.approx(0.12500e-3, rel=1e-4)
    # an explicit technology value wins
    q = record_parameters(rec, [fleet_cycle("hwy")], {"simulation.idle_fuel_flow": 2e-4})
    assert q.simulation.idle_fuel_flow == 2e-4


def test_a_make_field_without_a_name_is_read_from_the_manufacturer():
    """The 2022 list gives "2022" as the make of its Lucid Air records: the make is then the manufacturer
    name's first word; a make that names one is kept as written."""
    from vpsim.fleet.epa import named_make

    assert named_make("2022", "Lucid USA, Inc") == "Lucid"
    assert named_make("", "Tesla Inc.") == "Tesla"
    assert named_make("2022", "") == "2022"  # nothing better to say: left as written
    assert named_make("Land Rover", "Jaguar Land Rover L.P.") == "Land Rover"
    assert named_make("MINI", "BMW") == "MINI"


def test_the_reader_names_a_record_by_its_manufacturer_where_the_make_field_holds_a_year(tmp_path):
    """Through the reader: an EV whose make field reads "2022" is listed under its manufacturer's name."""
    from fleet_csv import EVS, write_ev_list

    lst = write_ev_list(tmp_path / "ev.csv", evs=EVS[:1], make="2022")  # (manufacturer "VOLT&AMP")
    with lst.open(encoding="utf-8-sig") as f:
        assert ",2022," in f.read()
    evs = read_test_car_list(lst).ev_vehicles
    assert [(e.vehicle_id, e.make) for e in evs] == [("E001", "VOLT&AMP")]
