"""The fleet: cross-validation without leakage, the CLI's files and keys, from-epa -> simulate."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from fleet_csv import write_list
from vpsim.cli.main import main
from vpsim.fleet import calibrate as cal
from vpsim.fleet.report import CSV_COLUMNS, FIGURES, STAT_KEYS, SUMMARY_KEYS
from vpsim.fleet.run import run_fleet
from vpsim.fleet.vehicle import ACCESSORY_POWER_W, read_record_block
from vpsim.params import load_parameters


def test_folds_are_deterministic_and_balanced():
    keys = [f"V{i}#0" for i in range(23)]
    a = cal.assign_folds(keys, 5)
    b = cal.assign_folds(list(reversed(keys)), 5)
    assert a == b
    sizes = np.bincount(list(a.values()))
    assert sizes.tolist() == [5, 5, 5, 4, 4]
    with pytest.raises(ValueError):
        cal.assign_folds(keys, 1)


def test_fit_recovers_the_technology_of_a_synthetic_fleet():
    # ln(fuel) = c_i - ln(eta) + 0.2 xi: the fleet's "true" technology is (0.42, 0.7) for every vehicle
    e, f = np.meshgrid(cal.GRID[0], cal.GRID[1], indexing="ij")
    base = np.linspace(1.8, 2.6, 30)
    grid = base[:, None, None] - np.log(e)[None] + 0.2 * f[None]
    meas = base - np.log(0.42) + 0.2 * 0.7
    # the two parameters act alike here, so check the fitted fuel, not the pair
    params, loss = cal.fit(grid, meas)
    assert loss < 2e-3
    assert -np.log(params[cal.TECH_PARAMS[0]]) + 0.2 * params[cal.TECH_PARAMS[1]] == pytest.approx(
        -np.log(0.42) + 0.14, abs=2e-3
    )


def test_fit_recovers_the_accessory_power_of_a_synthetic_fleet():
    """Fuel = (work + xi friction + (P - P_grid) duration / LHV) / eta: the fit finds P, eta and xi."""
    from vpsim.fleet.vehicle import ACCESSORY_POWER_W as P0

    # by hand: s / (J/kg x kg/L) per 100 km
    assert cal.fuel_per_watt(866, 6211) == pytest.approx(866 / (42.9e6 * 0.743) / 0.06211, rel=1e-12)
    rng = np.random.default_rng(3)
    n = 60
    work = rng.uniform(1.0, 6.0, n)[:, None, None]  # L/100 km at eta = 1, each vehicle and cycle its own
    friction = rng.uniform(0.1, 1.0, n)[:, None, None]  # L/100 km per unit of xi at eta = 1
    # FTP bag 2 (866 s, 6.2 km) or HWY (765 s, 16.5 km) rows
    per_watt = np.where(rng.random(n) < 0.5, cal.fuel_per_watt(866, 6211), cal.fuel_per_watt(765, 16507))

    def fuel(eta, xi, power):
        return (work + friction * xi + (power - P0) * per_watt[:, None, None]) / eta

    e, f = np.meshgrid(cal.GRID[0], cal.GRID[1], indexing="ij")
    grid = np.log(fuel(e[None], f[None], P0))
    meas = np.log(fuel(0.42, 0.7, 900.0))[:, 0, 0]
    params, loss = cal.fit(grid, meas, per_watt)
    assert params[cal.TECH_PARAMS[2]] == pytest.approx(900.0, abs=25.0)
    assert params[cal.TECH_PARAMS[0]] == pytest.approx(0.42, abs=0.01)
    assert params[cal.TECH_PARAMS[1]] == pytest.approx(0.7, abs=0.1)
    assert loss < 5e-3  # the interpolation between the nodes: here ln fuel is not linear in xi
    # without per_watt the accessories stay at the grid's power, and the fit is worse
    params0, loss0 = cal.fit(grid, meas)
    assert params0[cal.TECH_PARAMS[2]] == P0 and loss0 > 3 * loss


def _rows(df):
    return df.set_index(["vehicle_id", "configuration", "cycle"]).sort_index()


def test_a_vehicles_own_measurement_never_enters_its_fit(tmp_path):
    """Doubling one vehicle's measured mpg leaves its own prediction unchanged and moves the others'."""
    # (single-record folds: on this 13-car list a family fold can hold the whole of T006's class)
    clean = run_fleet(write_list(tmp_path / "a.csv"), folds=3, peer=False, group_by="record")
    a = _rows(clean.frame())
    # the first made-up car whose class has members in other folds (the deal depends on the records, not on
    # their measurements, so the perturbed list is dealt the same)
    target = next(
        vid
        for vid in sorted(a.index.get_level_values(0).unique())
        if vid.startswith("T")
        and (
            (a["technology_class"] == a.loc[vid, "technology_class"].iloc[0])
            & (a["fold"] != a.loc[vid, "fold"].iloc[0])
        ).any()
    )
    moved = run_fleet(write_list(tmp_path / "b.csv", perturb=target), folds=3, peer=False, group_by="record")
    b = _rows(moved.frame())
    assert np.allclose(b.loc[target, "measured_mpg"], 0.6 * a.loc[target, "measured_mpg"], rtol=1e-3)
    np.testing.assert_array_equal(a.loc[target, "predicted_mpg"], b.loc[target, "predicted_mpg"])
    own_fold = int(a.loc[target, "fold"].iloc[0])
    same_class = a["technology_class"] == a.loc[target, "technology_class"].iloc[0]
    others = a.index[(a["fold"] != own_fold) & same_class]
    assert len(others) > 0
    changed = np.abs(b.loc[others, "predicted_mpg"].to_numpy() - a.loc[others, "predicted_mpg"].to_numpy())
    assert changed.max() > 1e-3  # the vehicle is in the other folds' training set
    in_fold = a.index[(a["fold"] == own_fold)]
    np.testing.assert_array_equal(a.loc[in_fold, "predicted_mpg"], b.loc[in_fold, "predicted_mpg"])


def test_from_epa_writes_a_toml_that_simulate_runs(tmp_path, capsys):
    lst = write_list(tmp_path / "list.csv")
    car = tmp_path / "car.toml"
    assert main(["vehicle", "from-epa", str(lst), "--id", "T004", "--out", str(car)]) == 0
    out = capsys.readouterr().out
    assert "T004#0" in out and "boosted" in out
    assert main(["simulate", "--vehicle", str(car), "--cycle", "udds", "--mode", "extended", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert 3.0 < res["fuel_l_per_100km"] < 20.0
    block = read_record_block(car)
    # on a cycle the record measured, simulate sets the prediction against the measurement (hwy is hwfet)
    for cycle, test in (("ftp_bag2", "ftp_bag2"), ("hwy", "hwy")):
        assert main(["simulate", "--vehicle", str(car), "--cycle", cycle, "--json"]) == 0
        res = json.loads(capsys.readouterr().out)
        assert res["measured_mpg"] == block["record"]["measured_mpg"][test]
        assert res["measured_error_pct"] == pytest.approx(
            100.0 * (res["fuel_economy_mpg"] / res["measured_mpg"] - 1.0), rel=1e-12
        )
    assert main(["simulate", "--vehicle", str(car), "--cycle", "ftp_bag2"]) == 0
    text = capsys.readouterr().out
    assert f"{block['record']['measured_mpg']['ftp_bag2']:8.2f} mpg (the record's test on this cycle)" in text
    # a record block broken by an edit: the run stands, the comparison is left out with a one-line note
    broken = tmp_path / "broken.toml"
    broken.write_text(car.read_text().replace("# [record.measured_mpg]", "# [record.measured_mpg"))
    assert main(["simulate", "--vehicle", str(broken), "--cycle", "ftp_bag2", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["measured_mpg"] is None and "no measurement to compare with" in err
    assert block["road_load"]["a_lbf"] == 30.0
    assert block["road_load"]["a_n"] == pytest.approx(30 * 4.4482216152605, rel=1e-5)
    assert block["record"]["vehicle_id"] == "T004"


def test_from_epa_errors_are_one_line(tmp_path, capsys):
    lst = write_list(tmp_path / "list.csv")
    assert main(["vehicle", "from-epa", str(lst), "--id", "X104", "--out", str(tmp_path / "c.toml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "excluded: implausible etw_lb" in err
    assert main(["vehicle", "from-epa", str(lst), "--id", "NOPE", "--out", str(tmp_path / "c.toml")]) == 2


def _check_outputs(out, cycles):
    s = json.loads((out / "summary.json").read_text())
    assert tuple(s) == SUMMARY_KEYS  # exactly the keys the issue names
    assert s["held_out"] is True
    assert set(s["cycles"]) == set(cycles)
    for c in cycles:
        assert tuple(s["cycles"][c]) == STAT_KEYS
    fs = s["peer"]["fastsim"]
    assert set(s["peer"]) == {
        "fastsim",
        "fastsim_calibrated",
        "fastsim_calibrated_by_powertrain",
        "fastsim_by_powertrain",
        "vpsim_minus_fastsim_calibrated_by_powertrain",
    }
    diff = s["peer"]["vpsim_minus_fastsim_calibrated_by_powertrain"]
    if fs.get("measured") is False:
        assert diff == {"measured": False, "reason": fs["reason"]}
    else:
        assert set(diff) == {"conventional", "bev", "hev", "mhev"}
        for c, d in diff["conventional"].items():  # the same rows as the peer's statistics
            peer_c = s["peer"]["fastsim_calibrated"][c]
            assert d["n"] == peer_c["n"] and d["peer_median_abs_error_pct"] == peer_c["median_abs_error_pct"]
    for key, conventional in (
        ("fastsim_calibrated_by_powertrain", "fastsim_calibrated"),
        ("fastsim_by_powertrain", "fastsim"),
    ):
        assert set(s["peer"][key]) == {"conventional", "bev", "hev", "mhev"}  # fleet.ev, .hev, .mhev
        assert s["peer"][key]["conventional"] == s["peer"][conventional]
    assert s["by_powertrain"]["conventional"]["cycles"] == s["cycles"]
    for peer in (fs, s["peer"]["fastsim_calibrated"]):
        if "measured" in peer:  # FASTSim not installed: said so, nothing faked
            assert peer["measured"] is False and peer["reason"] and set(peer) == {"measured", "reason"}
        else:
            assert set(peer) == set(cycles)
            for c in cycles:
                assert tuple(peer[c]) == STAT_KEYS
    assert s["validation"]["grouping"] in cal.GROUPINGS
    info = json.loads((out / "run.json").read_text())
    assert set(info["trace_miss"]) == set(cycles) and info["n_rows"] > 0
    df = pd.read_csv(out / "vehicles.csv")
    assert tuple(df.columns[: len(CSV_COLUMNS)]) == CSV_COLUMNS
    assert info["n_rows"] == len(df)
    # every row names its family, and a family sits in one fold (what the bootstrap draws together)
    for name in ("vehicles.csv", "vehicles_ev.csv", "vehicles_hev.csv", "vehicles_mhev.csv"):
        if (out / name).exists():
            rows = pd.read_csv(out / name)
            if len(rows):
                assert rows["family"].notna().all()
                assert rows.groupby("family")["fold"].nunique().max() == 1, name
    for f in (*FIGURES, "report.md", "technology.json"):
        assert (out / f).stat().st_size > 100
    assert pd.read_csv(out / "excluded.csv").columns[-1] == "reason"
    return s, df


def test_summary_without_the_peer_says_not_measured(tmp_path, capsys):
    out = tmp_path / "o"
    lst = write_list(tmp_path / "list.csv", bad_rows=False)
    assert (
        main(
            ["fleet", str(lst), "--out", str(out), "--folds", "3", "--cycles", "hwy", "--no-peer", "--quiet"]
        )
        == 0
    )
    assert "FASTSim not measured" in capsys.readouterr().out
    s, _ = _check_outputs(out, ("hwy",))
    assert s["peer"]["fastsim"] == {"measured": False, "reason": "not run (--no-peer)"}


def test_fleet_cli_on_a_made_up_list(tmp_path, capsys):
    out = tmp_path / "fleet"
    lst = write_list(tmp_path / "list.csv")
    assert main(["fleet", str(lst), "--out", str(out), "--folds", "3", "--quiet"]) == 0
    text = capsys.readouterr().out
    # the cars, X107 (bag 3 and HWY kept) and X103 (a flex-fuel car read from its gasoline tests)
    assert "14 vehicles" in text
    s, df = _check_outputs(out, ("ftp_bag2", "ftp_bag3", "hwy", "us06"))
    diff = s["peer"]["vpsim_minus_fastsim_calibrated_by_powertrain"]
    if diff.get("measured") is not False:  # printed as the summary holds it
        d = diff["conventional"]["hwy"]
        lo, hi = d["ci95_pts"]
        assert f"hwy {d['difference_pts']:+.1f} [{lo:+.1f}, {hi:+.1f}]" in text
    assert s["n_vehicles"] == 14
    assert s["excluded"]["diesel"] == 1
    assert s["excluded"]["flex-fuel (E85 test)"] == 1  # X114: E85 tests only
    assert s["excluded"]["electric, no charge-depleting UDDS or highway test"] == 1
    assert s["cycles"]["us06"]["n"] == 6 and s["cycles"]["ftp_bag2"]["n"] == 13
    assert (df["status"] != "failed").all()
    assert np.isfinite(df["error_pct"]).all()
    # the fitted technology, accessories included, goes into a vehicle file; an older technology.json
    # without the accessories keeps the default; a file that is none gives one line
    tech = json.loads((out / "technology.json").read_text())
    fit = tech["all_vehicles"]["boosted"]
    car = tmp_path / "car.toml"
    args = ["vehicle", "from-epa", str(lst), "--id", "T004", "--out", str(car)]
    assert main([*args, "--technology", str(out / "technology.json")]) == 0
    p = load_parameters(car)
    assert p.engine.accessory_power == fit["engine.accessory_power"]
    assert p.engine.thermal_efficiency == pytest.approx(fit["engine.thermal_efficiency"], rel=1e-9)
    assert {f"engine.{c}" for c in ("thermal_efficiency", "friction_coefficient", "accessory_power")} == set(
        cal.TECH_PARAMS
    )
    assert df["accessory_power_w"].between(cal.ACCESSORY_AXIS[0], cal.ACCESSORY_AXIS[-1]).all()
    old = {
        "all_vehicles": {
            c: {k: v for k, v in t.items() if k != "engine.accessory_power"}
            for c, t in tech["all_vehicles"].items()
        }
    }
    (tmp_path / "old.json").write_text(json.dumps(old))
    assert main([*args, "--technology", str(tmp_path / "old.json")]) == 0
    assert load_parameters(car).engine.accessory_power == ACCESSORY_POWER_W
    (tmp_path / "bad.json").write_text("{}")
    capsys.readouterr()
    assert main([*args, "--technology", str(tmp_path / "bad.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a technology.json" in err


def test_a_fleet_run_prints_as_the_command_line_plots_and_is_a_dataframe(tmp_path, capsys):
    """FleetRun: print gives the lines `vpsim fleet` prints (but where it wrote), to_dataframe the engine
    cars' rows, plot the report's predicted-against-measured figure (a panel per cycle)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lst = write_list(tmp_path / "list.csv")  # with its hybrids, a mild one among them
    args = ["--folds", "3", "--cycles", "hwy,ftp_bag3", "--no-peer"]
    run = run_fleet(lst, folds=3, cycles=("hwy", "ftp_bag3"), peer=False, workers=1, progress=False)
    text = str(run)
    assert main(["fleet", str(lst), "--out", str(tmp_path / "o"), *args, "--workers", "1", "--quiet"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[-1].startswith("wrote ")
    runtime = [k for k, line in enumerate(printed) if line.startswith("runtime ")]
    mine = text.splitlines()
    # the same lines but the runtime's figures (two runs) and the output folder's
    assert len(mine) == len(printed) - 1 and runtime == [len(mine) - 1]
    assert mine[:-1] == printed[: len(mine) - 1]
    assert "FASTSim not measured" in text
    df = run.to_dataframe()
    assert list(df.columns) == list(run.frame().columns) and len(df) == len(run.rows)
    fig = run.plot()
    titles = [ax.get_title() for ax in fig.axes if ax.get_visible()]
    assert "hwy (n = " in " ".join(titles) and "ftp_bag3 (n = " in " ".join(titles)
    plt.close(fig)


def test_the_predicted_against_measured_figure_has_a_panel_per_part_and_test():
    """figure_predicted_vs_measured: a panel per engine-car cycle, EV test, full-hybrid test and mild-hybrid
    test present in the rows, each with its count; the mild hybrids' peer is FASTSim's conventional car."""
    from vpsim.fleet.report_figures import figure_predicted_vs_measured

    def rows(cycles, n, mpg, **extra):
        return pd.DataFrame(
            [
                dict(cycle=c, measured_mpg=mpg + k, predicted_mpg=mpg + k + 0.5, status="ok", **extra)
                for c in cycles
                for k in range(n)
            ]
        )

    df = rows(("hwy",), 3, 30.0, fastsim_calibrated_mpg=31.0)
    hev = rows(("udds_hot", "hwy"), 2, 50.0, fastsim_calibrated_mpg=48.0)
    mhev = rows(("ftp_bag2", "hwy", "us06"), 4, 25.0, fastsim_calibrated_mpg=26.0)
    mhev.loc[0, "status"] = "trace_miss"
    fig = figure_predicted_vs_measured(df, ("hwy",), True, None, hev, mhev)
    titles = [ax.get_title() for ax in fig.axes if ax.get_visible()]
    assert titles == [
        "hwy (n = 3)",
        "full hybrid, udds_hot (n = 2)",
        "full hybrid, hwy (n = 2)",
        "mild hybrid, ftp_bag2 (n = 4)",
        "mild hybrid, hwy (n = 4)",
        "mild hybrid, us06 (n = 4)",
    ]
    labels = fig.axes[3].get_legend_handles_labels()[1]
    assert "FASTSim 3.1 conventional car, calibrated" in labels
    assert "vpsim mild hybrid, trace miss" in labels


def test_fleet_cli_bad_options_are_one_line(tmp_path, capsys):
    lst = write_list(tmp_path / "list.csv")
    assert main(["fleet", str(lst), "--out", str(tmp_path / "o"), "--cycles", "nedc"]) == 2
    assert "unknown fleet cycle 'nedc'" in capsys.readouterr().err
    assert main(["fleet", str(lst), "--out", str(tmp_path / "o"), "--folds", "40", "--quiet"]) == 2
    assert "too few for 40 folds" in capsys.readouterr().err


def test_fleet_forward_method_runs(tmp_path):
    run = run_fleet(
        write_list(tmp_path / "l.csv", bad_rows=False),
        folds=3,
        method="forward",
        peer=False,
        cycles=("ftp_bag3",),
    )
    df = run.frame()
    assert len(df) == 12 and np.isfinite(df["predicted_mpg"]).all()
    assert "max_speed_error_mps" in df


def test_local_cluster_gives_the_same_rows_as_serial(tmp_path):
    pytest.importorskip("dask.distributed")
    lst = write_list(tmp_path / "l.csv", bad_rows=False)
    serial = run_fleet(lst, folds=3, peer=False, cycles=("ftp_bag2", "hwy"))
    dask = run_fleet(lst, folds=3, peer=False, cycles=("ftp_bag2", "hwy"), local_cluster=2)
    pd.testing.assert_frame_equal(serial.frame(), dask.frame())


def test_fleet_on_the_real_list(shared_dir, tmp_path, capsys):
    lst = shared_dir / "data" / "epa" / "22-tstcar.csv"
    if not lst.exists():
        pytest.skip(f"{lst} not found")
    out = tmp_path / "real"
    args = ["fleet", str(lst), "--out", str(out), "--limit", "25", "--cycles", "ftp_bag2,hwy", "--quiet"]
    assert main(args) == 0
    s, df = _check_outputs(out, ("ftp_bag2", "hwy"))
    assert s["n_vehicles"] == 25
    assert s["excluded"]["hybrid, no built layout"] > 10 and "electric" not in s["excluded"]  # EVs predicted
    assert "hybrid" not in s["excluded"]  # the full hybrids are read (vpsim.fleet.hev), or excluded with why
    assert s["by_powertrain"]["bev"]["n_vehicles"] == 25  # --limit: the first 25 EVs too
    hv = s["by_powertrain"]["hev"]
    assert hv["n_vehicles"] == 25 and hv["status"] == "ok"  # --limit: the first 25 hybrids
    for c in ("udds_hot", "hwy", "us06"):
        assert tuple(hv["cycles"][c]) == STAT_KEYS and hv["cycles"][c]["n"] > 5
    # the mild hybrids are read (vpsim.fleet.mhev): only those it cannot model stay out, with their reason
    assert "mild hybrid" not in s["excluded"] and s["excluded"]["mild hybrid, no known system"] == 2
    mh = s["by_powertrain"]["mhev"]
    assert mh["n_vehicles"] == 25 and mh["status"] == "ok"  # --limit: the first 25 mild hybrids
    for c in ("ftp_bag2", "ftp_bag3", "hwy"):
        assert tuple(mh["cycles"][c]) == STAT_KEYS and mh["cycles"][c]["n"] > 20
    peer = s["peer"]["fastsim_by_powertrain"]["mhev"]
    assert peer.get("measured") is False or peer["hwy"]["n"] > 20
    # FASTSim's conventional car calibrated on the mild hybrids' own folds and classes (the fair peer)
    cal = s["peer"]["fastsim_calibrated_by_powertrain"]["mhev"]
    if peer.get("measured") is False:
        assert cal["measured"] is False and cal["reason"]
    else:
        assert cal["hwy"]["n"] == mh["cycles"]["hwy"]["n"] and "conventional car" in cal["vehicle"]
        fits = json.loads((out / "technology.json").read_text())["mhev"][
            "peer_fastsim_calibrated_out_of_fold"
        ]
        assert {k.split(".")[1] for k in fits} <= {"mhev_p0", "mhev_p1"}
        assert all(
            0.6 <= t["efficiency_scale"] <= 1.6 and 0 <= t["accessory_power_w"] <= 2500 for t in fits.values()
        )
    # each hybrid part's rows carry its third technology parameter, within its search range
    import pandas as pd

    assert pd.read_csv(out / "vehicles_hev.csv")["machine_loss_scale"].between(0.01, 1.5).all()
    assert pd.read_csv(out / "vehicles_mhev.csv")["friction_coefficient"].between(0.1, 2.9).all()
    # the printed summary: each hybrid test beside its peer, calibrated then defaults, as the summary has them
    text = capsys.readouterr().out

    def trio(x):  # a test with too few rows has no figure: a dash
        keys = ("median_error_pct", "median_abs_error_pct", "p90_abs_error_pct")
        return " ".join("       –" if x[k] is None else f"{x[k]:+7.1f}%" for k in keys)

    for pt, title in (("hev", "full hybrids:"), ("mhev", "mild hybrids:")):
        lines = text.split(title, 1)[1].splitlines()
        fs = s["peer"]["fastsim_by_powertrain"][pt]
        fc = s["peer"]["fastsim_calibrated_by_powertrain"][pt]
        for c, v in s["by_powertrain"][pt]["cycles"].items():
            want = f"{c:10s} {v['n']:5d} {trio(v)}"
            if fs.get("measured") is not False:
                want += f"   {trio(fc[c])}   {trio(fs[c])}"
            assert want in lines, (pt, c)


def test_a_manual_gets_the_drivers_shift_point(tmp_path):
    """A manual shifts at the owner's manual's vehicle speeds while accelerating (15 mph to gear 2, 10 mph
    more per gear: lower gears in town, more fuel); the other transmission types keep the controller's
    rule."""
    from dataclasses import replace

    from vpsim.batch import run_batch
    from vpsim.fleet.cycles import fleet_cycle
    from vpsim.fleet.epa import read_test_car_list
    from vpsim.fleet.run import GEAR_RULE, MANUAL_GEAR_RULE, gear_rule
    from vpsim.fleet.vehicle import record_parameters
    from vpsim.gears import default_schedule

    cars = read_test_car_list(write_list(tmp_path / "a.csv"))
    auto = next(v for v in cars.vehicles if v.transmission_kind == "automatic")
    manual = replace(auto, transmission_kind="manual", transmission_code="M")
    assert gear_rule(auto) is GEAR_RULE
    assert gear_rule(manual) is MANUAL_GEAR_RULE
    mph = 0.44704
    np.testing.assert_allclose(MANUAL_GEAR_RULE.upshift_speeds(6), np.array([15, 25, 35, 45, 55]) * mph)
    assert MANUAL_GEAR_RULE.upshift_engine_speed is None
    cyc = fleet_cycle("ftp_bag2")
    p = record_parameters(manual, [cyc])
    s_auto = default_schedule(cyc, p, rule=gear_rule(auto))
    s_man = default_schedule(cyc, p, rule=gear_rule(manual))
    assert np.mean(s_man.gear < s_auto.gear) > 0.1
    fuel = [
        run_batch(cyc, None, params=p, mode="extended", gears=s)["fuel_l_per_100km"].iloc[0]
        for s in (s_auto, s_man)
    ]
    assert fuel[1] > 1.05 * fuel[0]


def test_the_vehicle_file_carries_the_fleets_gear_rule(tmp_path):
    """``vpsim vehicle from-epa`` writes the rule the fleet shifts by, so ``vpsim simulate --vehicle`` derives
    the fleet's schedule and fuel (an automatic, a manual with its shift point, a CVT)."""
    from dataclasses import replace

    import vpsim
    from vpsim.fleet.cycles import fleet_cycle
    from vpsim.fleet.epa import read_test_car_list
    from vpsim.fleet.run import gear_rule
    from vpsim.fleet.vehicle import record_parameters, vehicle_toml
    from vpsim.gears import GearRule, default_schedule
    from vpsim.params import load_parameters

    cars = read_test_car_list(write_list(tmp_path / "a.csv"))
    auto = next(v for v in cars.vehicles if v.transmission_kind == "automatic")
    cyc = fleet_cycle("ftp_bag2")
    for rec in (auto, replace(auto, transmission_kind="manual", transmission_code="M"), cars.find("T008")):
        p = record_parameters(rec)
        path = tmp_path / f"{rec.vehicle_id}-{rec.transmission_kind}.toml"
        path.write_text(vehicle_toml(rec, p))
        q = load_parameters(path)
        rule, fleet_rule = GearRule.of(q), gear_rule(rec)  # (the file rounds to 6 significant digits)
        assert rule.min_engine_speed == fleet_rule.min_engine_speed
        point = fleet_rule.upshift_engine_speed or 0.0
        assert (rule.upshift_engine_speed or 0.0) == pytest.approx(point, rel=1e-5)
        np.testing.assert_allclose(rule.upshift_speeds(6), fleet_rule.upshift_speeds(6), rtol=1e-5)
        fleet = default_schedule(cyc, p, None, rule=gear_rule(rec))
        np.testing.assert_array_equal(default_schedule(cyc, q, None).gear, fleet.gear)
        r = vpsim.simulate(cyc, "backward", q)  # the default schedule: the file's rule
        assert r.fuel_kg == pytest.approx(vpsim.simulate(cyc, "backward", q, gears=fleet).fuel_kg, rel=1e-12)
    assert GearRule.of(load_parameters("hofman2011")) == GearRule()  # the preset: the documented 200 rad/s


def test_automatics_and_cvts_get_a_converter_manuals_and_dcts_none(tmp_path):
    """The converter follows the transmission type; ``converter=False`` leaves it out."""
    from dataclasses import replace

    from vpsim.fleet.epa import read_test_car_list
    from vpsim.fleet.vehicle import (
        CONVERTER_STALL_RPM,
        RATED_SPEED_RADPS,
        converter_fields,
        record_parameters,
    )

    cars = read_test_car_list(write_list(tmp_path / "a.csv"))
    auto = next(v for v in cars.vehicles if v.transmission_kind == "automatic")
    p = record_parameters(auto)
    k = p.transmission.converter_capacity_factor
    torque = auto.rated_power_kw * 1e3 / RATED_SPEED_RADPS
    assert k * np.sqrt(torque) == pytest.approx(CONVERTER_STALL_RPM * np.pi / 30)  # stalls at 2400 rpm
    assert p.transmission.lockup_min_gear == 2 and p.transmission.lockup_min_speed == pytest.approx(25 / 3.6)
    assert record_parameters(auto, converter=False).transmission.converter_capacity_factor == 0.0
    assert converter_fields(replace(auto, transmission_kind="cvt"))["lockup_min_gear"] == 1  # by speed alone
    for kind in ("manual", "amt_dct"):
        assert converter_fields(replace(auto, transmission_kind=kind)) == {}


def test_between_manufacturers_by_hand():
    """Errors that are exactly one offset per manufacturer: the correction in sample removes them all; out
    of fold it removes those of a manufacturer with vehicles in another fold, and leaves the one whose
    vehicles are all in one fold (no correction from the other folds)."""
    from vpsim.fleet.report import between_manufacturers

    maker = ["A", "A", "A", "B", "B", "C"]
    fold = [0, 1, 2, 0, 1, 0]
    off = {"A": 10.0, "B": -20.0, "C": 30.0}
    df = pd.DataFrame(
        {
            "manufacturer": maker,
            "fold": fold,
            "cycle": "hwy",
            "error_pct": [off[m] for m in maker],
        }
    )
    r = between_manufacturers(df)["hwy"]
    assert r["manufacturers"] == 3
    assert r["in_sample"]["p90_abs_error_pct"] == pytest.approx(0.0, abs=1e-9)
    # out of fold: A and B corrected exactly, C (fold 0 only) keeps its +30 %
    assert r["out_of_fold"]["median_abs_error_pct"] == pytest.approx(0.0, abs=1e-9)
    assert r["out_of_fold"]["p90_abs_error_pct"] == pytest.approx(0.5 * 30.0, abs=1e-9)  # 5 zeros, one 30
    # ratios, not differences: +10 % and +21 % on two vehicles of one maker; their median ratio is the
    # geometric mean sqrt(1.1 x 1.21) = 1.15369, which leaves 1.1 / 1.15369 - 1 = -4.654 % and
    # 1.21 / 1.15369 - 1 = +4.881 %: median |error| 4.767 %
    two = pd.DataFrame({"manufacturer": "A", "fold": [0, 1], "cycle": "hwy", "error_pct": [10.0, 21.0]})
    left = between_manufacturers(two)["hwy"]["in_sample"]
    assert left["median_abs_error_pct"] == pytest.approx(4.767, abs=1e-3)


def test_repeatability_of_twins_by_hand():
    """Two groups of vehicles equal in every model input, one vehicle alone: the best single prediction per
    group is its geometric mean (sqrt(20.8 x 12.9) = 16.38; (30 x 31 x 36)^(1/3) = 32.23 mpg)."""
    from vpsim.fleet.report import repeatability

    meas = {"A1": 20.8, "A2": 12.9, "B1": 30.0, "B2": 31.0, "B3": 36.0, "C1": 25.0}
    df = pd.DataFrame(
        {
            "vehicle_id": list(meas),
            "configuration": 0,
            "make": "Acme",
            "model": "Twin",
            "cycle": "ftp_bag2",
            "measured_mpg": list(meas.values()),
            "error_pct": [10.0, -10.0, 1.0, 2.0, np.nan, 50.0],
        }
    )
    inputs = {f"{k}#0": ("a",) if k[0] == "A" else ("b",) if k[0] == "B" else ("c",) for k in meas}
    r = repeatability(df, inputs)["ftp_bag2"]
    assert (r["rows"], r["groups"]) == (5, 2)  # C1 has no twin
    # errors of the best prediction: 21.25, 26.98 (A); 7.43, 3.97, 10.47 % (B)
    assert r["best_possible_median_abs_error_pct"] == pytest.approx(10.472, abs=1e-3)
    assert r["best_possible_p90_abs_error_pct"] == pytest.approx(24.687, abs=1e-3)
    # within 12 % one prediction reaches one of A (20.8 / 12.9 > 1.12 / 0.88) and all of B (36 / 30 < 1.27);
    # within 5 % one of A and two of B (31 / 30 < 1.05 / 0.95 < 36 / 31)
    assert r["rows_beyond_12_pct_whatever_the_model"] == 1
    assert r["rows_beyond_5_pct_whatever_the_model"] == 2
    assert r["vpsim_median_abs_error_pct"] == pytest.approx(6.0)  # |10, -10, 1, 2|: B3 has no prediction
    assert r["widest_group"]["measured_mpg"] == [12.9, 20.8]
    assert r["widest_group"]["spread_pct"] == pytest.approx(61.2)
    # the worst list names the twin first: A1 measured 20.8 / 12.9 - 1 = +61 % against A2
    from vpsim.fleet.report import mechanisms, twin_differences

    diff = twin_differences(df, inputs)
    assert diff[("A1", 0)] == pytest.approx(61.24, abs=0.01) and diff[("A2", 0)] == pytest.approx(
        -37.98, abs=0.01
    )
    assert diff[("B3", 0)] == pytest.approx(100 * (36 / np.sqrt(30 * 31) - 1), abs=1e-9)
    assert ("C1", 0) not in diff
    df = df.assign(
        transmission="automatic",
        n_gears=6,
        boosted=False,
        power_to_mass_w_per_kg=80.0,
        specific_power_kw_per_l=60.0,
        test_mass_kg=1500.0,
        cylinders=4,
        trace_miss_s=0.0,
    )
    mech = mechanisms(df, inputs)
    assert mech[("A1", 0)].startswith("measured 61 % above a twin with the same record inputs")
    assert mech[("B2", 0)].startswith("measured 6 % below a twin")  # 31 against sqrt(30 x 36) = 32.9 mpg
    assert "same record inputs" not in mech[("C1", 0)]  # no twin
    assert "same record inputs" not in mechanisms(df)[("A1", 0)]  # without the inputs: not known
    # a trace miss names its method's cause: the backward method's engine, the forward method's PI driver
    missed = df.assign(trace_miss_s=np.where(df["vehicle_id"] == "C1", 0.024, 0.0))
    assert "trace miss 0.024 s (the engine lacks" in mechanisms(missed)[("C1", 0)]
    tracked = missed.assign(max_speed_error_mps=0.7)
    assert "trace miss 0.024 s (the PI driver outside" in mechanisms(tracked)[("C1", 0)]
    assert "trace miss" not in mechanisms(tracked)[("A1", 0)]
    # a manual names the shift speeds the model gives it
    manual = df.assign(transmission=np.where(df["vehicle_id"] == "C1", "manual", "automatic"))
    assert "manual (model: upshifts at 15/25/35/45/55 mph while accelerating" in mechanisms(manual)[("C1", 0)]


def test_fleet_reports_twins_the_record_cannot_tell_apart(tmp_path, capsys):
    """A vehicle and its twin (every field equal, measured 1.3x): one prediction for both, so one of the two
    rows misses by more than 12 % whatever the model (1.3 > 1.12 / 0.88); said on the console, in run.json,
    in report.md and in the worst-vehicle mechanism."""
    out = tmp_path / "fleet"
    lst = write_list(tmp_path / "list.csv", bad_rows=False, twin="T002")
    args = ["fleet", str(lst), "--out", str(out), "--folds", "3", "--cycles", "ftp_bag2,hwy", "--quiet"]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "cannot tell apart" in text and "ftp_bag2 2, 1" in text
    rep = json.loads((out / "run.json").read_text())["record_repeatability"]
    assert rep["ftp_bag2"]["rows"] == 2 and rep["ftp_bag2"]["groups"] == 1
    assert rep["ftp_bag2"]["rows_beyond_12_pct_whatever_the_model"] == 1
    assert rep["ftp_bag2"]["widest_group"]["spread_pct"] == pytest.approx(30.0, abs=0.2)
    report = (out / "report.md").read_text()
    assert "## How repeatable the record is" in report
    bm = json.loads((out / "run.json").read_text())["between_manufacturers"]
    assert set(bm) == {"ftp_bag2", "hwy"} and bm["hwy"]["manufacturers"] >= 1
    assert all(bm["hwy"][k]["p90_abs_error_pct"] >= 0.0 for k in ("in_sample", "out_of_fold"))
    assert "## How much of the error lies between manufacturers" in report
    # 13 vehicles, all among the 20 worst: each named against the other, 1.3 - 1 = +30 %, 1 / 1.3 - 1 = -23 %
    assert "measured 30 % above a twin with the same record inputs" in report
    assert "measured 23 % below a twin with the same record inputs" in report


def test_groups_read_in_order_mass_bins_light_to_heavy():
    from vpsim.fleet.report import MASS_LABELS, _in_order, _mass_bin

    assert [_mass_bin(m) for m in (1500, 1700, 2000, 2400, 3000)] == list(MASS_LABELS)
    assert _in_order(list(reversed(MASS_LABELS))) == list(MASS_LABELS)  # alphabetically "<1600 kg" is last
    assert _in_order(["6 cyl", "3 cyl", ">=8 cyl", "4 cyl"]) == ["3 cyl", "4 cyl", "6 cyl", ">=8 cyl"]


def test_fleet_remembers_fastsims_runs_and_the_second_run_reads_them(tmp_path, monkeypatch):
    """With FASTSim installed: a second fleet run on the same list reads every FASTSim run back and writes
    the same tables byte for byte; `--no-peer-cache` leaves the cache alone (run.json says so)."""
    pytest.importorskip("fastsim")
    from vpsim.fleet import peer

    if not peer.status()["available"]:
        pytest.skip(peer.status()["reason"])
    monkeypatch.setenv("VPSIM_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("VPSIM_PEER_CACHE", "1")  # (restored after the test: the flag below sets it)
    lst = write_list(tmp_path / "list.csv", bad_rows=False)
    args = ["--folds", "3", "--cycles", "hwy,us06", "--workers", "1", "--quiet"]
    caches = []
    for name in ("first", "second"):
        assert main(["fleet", str(lst), "--out", str(tmp_path / name), *args]) == 0
        caches.append(json.loads((tmp_path / name / "run.json").read_text())["peer"]["fastsim"]["run_cache"])
    assert caches[0]["enabled"] and caches[0]["entries_before"] is None and caches[0]["entries_after"] > 0
    assert caches[1]["entries_before"] == caches[1]["entries_after"] == caches[0]["entries_after"]
    for f in ("vehicles.csv", "summary.json", "technology.json"):
        assert (tmp_path / "first" / f).read_bytes() == (tmp_path / "second" / f).read_bytes(), f
    assert main(["fleet", str(lst), "--out", str(tmp_path / "off"), *args, "--no-peer-cache"]) == 0
    off = json.loads((tmp_path / "off" / "run.json").read_text())["peer"]["fastsim"]["run_cache"]
    assert off == {"enabled": False, "path": None, "entries_before": None, "entries_after": None}
    summary = [(tmp_path / d / "summary.json").read_bytes() for d in ("first", "off")]
    assert summary[0] == summary[1]
