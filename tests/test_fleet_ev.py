"""Battery-electric records: the vehicle file from a record, its measured MPGe in vpsim simulate, and the
fleet's out-of-fold BEV technology and summary keys."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fleet_csv import EVS, write_ev_list
from vpsim.cli.main import main
from vpsim.fleet import calibrate as cal
from vpsim.fleet import ev
from vpsim.fleet.epa import read_test_car_list
from vpsim.fleet.report import STAT_KEYS, SUMMARY_KEYS
from vpsim.fleet.vehicle import top_gear_total_ratio
from vpsim.params import load_parameters


def _real_list(shared_dir):
    lst = shared_dir / "data" / "epa" / "22-tstcar.csv"
    if not lst.exists():
        pytest.skip(f"{lst} not found")
    return lst


def test_from_epa_on_a_real_ev_record_simulates_with_its_measurement(shared_dir, tmp_path, capsys):
    lst = _real_list(shared_dir)
    car = tmp_path / "bolt.toml"
    assert (
        main(["vehicle", "from-epa", str(lst), "--id", "1NFV5831", "--config", "0", "--out", str(car)]) == 0
    )
    p = load_parameters(car)
    assert p.powertrain.type == "bev"
    assert p.transmission.final_drive == pytest.approx(7.05)  # the record's single reduction
    assert p.vehicle.wheel_radius == pytest.approx(ev.nv_radius(7.05, 96.0), rel=1e-5)  # 0.313 m
    assert 0.30 < p.vehicle.wheel_radius < 0.33  # the Bolt's 215/50 R17: 0.316 m loaded
    assert p.machine.rated_power == pytest.approx(200 * 745.699871582270, rel=1e-5)
    capsys.readouterr()
    out = tmp_path / "run"
    assert main(["simulate", "--vehicle", str(car), "--cycle", "udds", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "MPGe (the record's test on this cycle); predicted" in text
    s = json.loads((out / "summary.json").read_text())
    assert 80.0 <= s["mpge"] <= 200.0
    assert s["measured_mpge"] == pytest.approx(129.0)
    assert s["measured_error_pct"] == pytest.approx(100.0 * (s["mpge"] / 129.0 - 1.0))


def test_the_real_list_reads_its_evs_and_names_why_it_leaves_some_out(shared_dir):
    cars = read_test_car_list(_real_list(shared_dir))
    assert len(cars.ev_vehicles) >= 90
    assert "electric" not in cars.excluded  # a predicted EV is no longer excluded
    why = {r["vehicle_id"]: r["reason"] for r in cars.excluded_rows if r["test_number"] == ""}
    assert why["OS9F6EU03AC"].startswith("electric, implausible rated_hp: 37")  # Kona Electric's 37 hp
    assert why["DE926EU03AC"].startswith("electric, implausible rated_hp: 38")  # Niro EV's 38 hp
    for rec in cars.ev_vehicles:
        assert ev.FINAL_DRIVE_RANGE[0] <= rec.final_drive <= ev.FINAL_DRIVE_RANGE[1]
        assert ev.WHEEL_RADIUS_RANGE[0] <= rec.wheel_radius_m <= ev.WHEEL_RADIUS_RANGE[1]
        assert set(rec.measured_mpge) == {"udds", "hwy"}
        assert all(60.0 < m < 250.0 for m in rec.measured_mpge.values())


def test_the_fleet_fits_the_bev_class_out_of_fold(tmp_path):
    """Every EV's technology was fitted without its family: its fold's fit trained on the other folds' rows
    only, and every member of a family sits in one fold."""
    from vpsim.fleet.run import run_fleet

    lst = write_ev_list(tmp_path / "ev.csv")
    run = run_fleet(lst, cycles=("hwy",), folds=3, peer=False, workers=1)
    df = run.ev_frame()
    assert set(df["vehicle_id"]) == {e[0] for e in EVS}
    assert (df["status"] == "ok").all() and np.isfinite(df["error_pct"]).all()
    fold_of, group_of = run.ev["fold_of"], run.ev["group_of"]
    for members in _groups(group_of).values():
        assert len({fold_of[k] for k in members}) == 1
    cls = {v.key: ev.ev_class(v) for v in _evs(run)}
    for r in df.itertuples():
        key = f"{r.vehicle_id}#{r.configuration}"
        fit = run.ev["technology"][f"fold{fold_of[key]}.{cls[key]}"]
        assert fit["basis"] == "class"
        n_other = sum(
            len(v.measured_mpge)
            for v in _evs(run)
            if fold_of[v.key] != fold_of[key] and cls[v.key] == cls[key]
        )
        assert fit["n_train"] == n_other  # the rows of the other folds, none of its own
        assert r.machine_loss_scale == fit["machine.loss_scale"]
        assert r.accessory_power_w == fit["electric.accessory_power"]
        assert r.drive_efficiency == fit["transmission.efficiency"]
        assert ev.DRIVE_EFFICIENCY_AXIS[0] <= r.drive_efficiency <= ev.DRIVE_EFFICIENCY_AXIS[-1]
    # the fit reproduces on the same rows: the folds are deterministic
    again = cal.assign_folds(list(fold_of), 3, groups=group_of)
    assert again == fold_of


def test_fold_seed_spread_reproduces_the_fleets_ev_figures_at_its_seed(tmp_path, benchmark_script, capsys):
    """benchmarks/fold_seed_spread.py --part bev: at the fleet's own seed it gives the figures `vpsim fleet`
    reports for the EVs (the same grid, folds, fit and runs), and another seed deals the families anew."""
    import time

    from vpsim.fleet.report import error_stats
    from vpsim.fleet.run import run_fleet

    spread = benchmark_script("fold_seed_spread")
    lst = write_ev_list(tmp_path / "ev.csv")
    table = spread.electrified(read_test_car_list(lst), "bev", [cal.SEED, 0], 1, time.perf_counter())
    assert "2 deals" in capsys.readouterr().out
    df = run_fleet(lst, folds=5, peer=False, workers=1).ev_frame()
    for c, rows in table.items():
        st = error_stats(df.loc[df["cycle"] == c, "error_pct"])
        want = (st["median_error_pct"], st["median_abs_error_pct"], st["p90_abs_error_pct"])
        assert rows[0] == pytest.approx(want, abs=1e-3)  # error_stats rounds to 3 decimals
        assert len(rows) == 2


def test_the_bev_classes_of_real_records(shared_dir, tmp_path):
    """The class split (vpsim.fleet.ev.ev_class) on named records of the 2022 list: the Audi e-tron S's
    induction machines, the Taycan's two-speed gearbox, the Model 3 AWD's two axles, the Bolt's one, the
    BMW i4's and iX's electrically excited machines; the Q4 e-tron (a permanent-magnet rear machine) is not
    an induction car, nor the e-tron GT (two gears)."""
    cars = read_test_car_list(_real_list(shared_dir))
    by_model: dict = {}
    for v in cars.ev_vehicles:
        by_model.setdefault(v.model, set()).add((ev.ev_class(v), ev.machine_kind(v)))
    assert by_model["e-tron S"] == {("bev_induction", "induction")}
    assert by_model["Audi e-tron 55 quattro Sportback"] == {("bev_induction", "induction")}
    assert by_model["Q4 e-tron 50"] == {("bev_awd", "pm")}
    assert by_model["e-tron GT"] == {("bev_two_speed", "pm")}
    assert by_model["Taycan Perf Battery"] == {("bev_two_speed", "pm")}  # rear-wheel drive, two gears
    assert by_model["Model 3 Long Range AWD"] == {("bev_awd", "pm")}
    assert by_model["BOLT EUV"] == {("bev", "pm")}
    # BMW's electrically excited machines (i4 rear- and all-wheel drive, iX), not the MINI's magnet machine
    assert by_model['i4 eDrive 40 Gran Coupe (18" Wheels)'] == {("bev_eesm", "pm")}
    assert by_model['i4 M50 Gran Coupe (20" Wheels)'] == {("bev_eesm", "pm")}
    assert by_model['iX xDrive50 (22" Wheels)'] == {("bev_eesm", "pm")}
    assert by_model["MINI COOPER SE HARDTOP 2 DOOR"] == {("bev", "pm")}
    # the vehicle file of an induction car says so, and runs
    rec = next(v for v in cars.ev_vehicles if v.model == "e-tron S")
    car = tmp_path / "etron.toml"
    args = ["vehicle", "from-epa", str(_real_list(shared_dir)), "--id", rec.vehicle_id]
    assert main([*args, "--config", str(rec.configuration), "--out", str(car)]) == 0
    p = load_parameters(car)
    assert p.machine.kind == "induction"


def _groups(group_of):
    out: dict = {}
    for k, g in group_of.items():
        out.setdefault(g, []).append(k)
    return out


def _evs(run):
    return [v for v in run.cars.ev_vehicles if v.key in run.ev["fold_of"]]


def test_the_fleet_summary_has_the_powertrains_and_the_bev_peers(tmp_path, capsys):
    pytest.importorskip("fastsim")
    lst = write_ev_list(tmp_path / "ev.csv", evs=EVS[:6])
    out = tmp_path / "fleet"
    assert main(["fleet", str(lst), "--out", str(out), "--folds", "3", "--cycles", "hwy", "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "battery-electric: 6 vehicles" in text
    s = json.loads((out / "summary.json").read_text())
    assert tuple(s) == SUMMARY_KEYS
    assert s["by_powertrain"]["conventional"]["cycles"] == s["cycles"]
    bev = s["by_powertrain"]["bev"]
    assert bev["n_vehicles"] == 6
    for c in ("udds", "hwy"):
        assert tuple(bev["cycles"][c]) == STAT_KEYS and bev["cycles"][c]["n"] == 6
        for peer in ("fastsim_by_powertrain", "fastsim_calibrated_by_powertrain"):
            assert tuple(s["peer"][peer]["bev"][c]) == STAT_KEYS
            assert s["peer"][peer]["bev"][c]["n"] == 6
    assert s["peer"]["fastsim_by_powertrain"]["conventional"] == s["peer"]["fastsim"]
    tech = json.loads((out / "technology.json").read_text())
    assert set(tech["bev"]["all_vehicles"]["bev"]) >= set(ev.TECH_PARAMS)
    assert "Errors per powertrain" in (out / "report.md").read_text()
    assert (out / "vehicles_ev.csv").exists()
    # the fitted technology goes into a BEV vehicle file
    car = tmp_path / "e.toml"
    args = ["vehicle", "from-epa", str(lst), "--id", "E001", "--out", str(car)]
    assert main([*args, "--technology", str(out / "technology.json")]) == 0
    p = load_parameters(car)
    fit = tech["bev"]["all_vehicles"]["bev"]
    assert p.machine.loss_scale == pytest.approx(fit["machine.loss_scale"])
    assert p.electric.accessory_power == pytest.approx(fit["electric.accessory_power"])
    assert p.transmission.efficiency == pytest.approx(fit["transmission.efficiency"])
    assert math.isfinite(p.battery.cells_in_parallel)


def test_made_up_evs_read_with_their_units_and_reduction(tmp_path):
    cars = read_test_car_list(write_ev_list(tmp_path / "ev.csv"))
    recs = {v.vehicle_id: v for v in cars.ev_vehicles}
    assert set(recs) == {e[0] for e in EVS}
    assert not recs["E001"].fe_in_kwh_per_100mi and recs["E001"].measured_mpge["udds"] == 170.0
    assert recs["E003"].fe_in_kwh_per_100mi  # 22 and 26: kWh per 100 miles
    assert recs["E003"].measured_mpge["udds"] == pytest.approx(3370.5 / 22.0)
    # axle 1.00 and 4.7 are no single reduction: the ratio comes from N/V at the default wheel radius
    for vid in ("E003", "E006"):
        assert recs[vid].final_drive == pytest.approx(top_gear_total_ratio(recs[vid].nv_ratio))
    assert recs["E002"].final_drive == 9.0
