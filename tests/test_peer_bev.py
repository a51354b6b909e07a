"""The battery-electric peer (FASTSim 3.1's BEV): plausible, monotone, physically sound; the EV reader."""

from __future__ import annotations

import numpy as np
import pytest

from vpsim.fleet import peer_bev as pb

# a mid-size 2022 EV: 2268 kg test weight, A/B/C 151 N, 0.34 N/(m/s), 0.371 N/(m/s)^2, 250 kW
CAR = dict(
    mass_kg=2268.0,
    road_load_a_n=151.0,
    road_load_b_n_per_mps=0.34,
    road_load_c_n_per_mps2=0.371,
    rated_power_w=250e3,
)


@pytest.fixture(scope="module")
def fastsim():
    return pytest.importorskip("fastsim")


def test_one_vehicle_plausible_mpge(fastsim):
    d = pb.bev_peer_vehicle(**CAR)
    udds, hwy = pb.run_bev_peer(d, "udds"), pb.run_bev_peer(d, "hwfet")
    assert 80.0 < udds["mpge"] < 200.0
    assert 80.0 < hwy["mpge"] < 200.0
    assert udds["mpge"] > hwy["mpge"]  # an EV does better in town (braking energy recovered, less drag)
    for r in (udds, hwy):
        assert not r["trace_miss"]
        assert abs(r["trace_miss_m"]) < 1.0
        assert r["wall_wh_per_km"] == pytest.approx(r["battery_wh_per_km"] / pb.CHARGER_EFFICIENCY)
        assert r["battery_wh_per_km"] > r["terminal_wh_per_km"]  # the battery's own loss


def test_heavier_uses_more(fastsim):
    light = pb.run_bev_peer(pb.bev_peer_vehicle(**CAR), "udds")
    heavy = pb.run_bev_peer(pb.bev_peer_vehicle(**{**CAR, "mass_kg": CAR["mass_kg"] + 500.0}), "udds")
    assert heavy["mpge"] < light["mpge"]


def test_energy_matches_hand_calculation(fastsim):
    """FASTSim's road-load energy = the folded road load's work over the trace (numpy, by hand), and its
    battery energy = that work / a drivetrain efficiency in a plausible range + the accessories (on UDDS all
    braking is regenerated, so the inertia's net work returns through the drivetrain twice)."""
    from vpsim.cycles import load_cycle
    from vpsim.fleet.vehicle import AIR_DENSITY, FRONTAL_AREA_M2, fold_road_load

    for name in pb.BEV_CYCLES:
        d = pb.bev_peer_vehicle(**CAR, fold_cycles=(name,))
        r = pb.run_bev_peer(d, name)
        cyc = load_cycle(name)
        v = 0.5 * (cyc.speed_mps[1:] + cyc.speed_mps[:-1])
        dt = np.diff(cyc.time_s)
        # the fold by hand is fold_road_load's; its coefficients are those FASTSim was given
        from types import SimpleNamespace

        rec = SimpleNamespace(
            mass_kg=CAR["mass_kg"],
            road_load_si=(CAR["road_load_a_n"], CAR["road_load_b_n_per_mps"], CAR["road_load_c_n_per_mps2"]),
        )
        c_r, c_d, _ = fold_road_load(rec, [cyc])
        assert d["chassis"]["wheel_rr_coef"] == pytest.approx(c_r)
        roll = CAR["mass_kg"] * 9.80665 * c_r * v
        drag = 0.5 * AIR_DENSITY * c_d * FRONTAL_AREA_M2 * v**3
        work_wh = float(np.sum((roll + drag) * dt)) / 3600.0
        assert r["rolling_wh"] + r["drag_wh"] == pytest.approx(work_wh, rel=0.02)
        # and the record's own A + B v + C v^2 over the trace is the same work within the fold's misfit
        f_abc = CAR["road_load_a_n"] + CAR["road_load_b_n_per_mps"] * v + CAR["road_load_c_n_per_mps2"] * v**2
        assert float(np.sum(f_abc * v * dt)) / 3600.0 == pytest.approx(work_wh, rel=0.03)
        battery_wh = r["battery_wh_per_km"] * r["distance_m"] / 1e3
        eff = work_wh / (battery_wh - r["aux_wh"])
        assert 0.6 < eff < 0.95, f"{name}: wheel work / battery energy for traction {eff:.3f}"
        assert r["friction_brake_wh"] == pytest.approx(0.0, abs=1.0)


def test_technology_moves_energy_the_right_way(fastsim):
    d = pb.bev_peer_vehicle(**CAR, fold_cycles=("udds",))
    base = pb.run_bev_peer(d, "udds")["battery_wh_per_km"]
    better = pb.with_bev_technology(d, {"drivetrain_efficiency_scale": 1.05})
    more_aux = pb.with_bev_technology(d, {"accessory_power_w": 1250.0})
    assert pb.run_bev_peer(better, "udds")["battery_wh_per_km"] < base
    r = pb.run_bev_peer(more_aux, "udds")
    added = (r["battery_wh_per_km"] - base) * r["distance_m"] / 1e3
    assert added == pytest.approx(1000.0 * 1369.0 / 3600.0, rel=0.05)  # 1 kW more for the cycle's 1369 s
    with pytest.raises(ValueError):
        pb.with_bev_technology(d, {"efficiency_scale": 1.0})


def test_fit_recovers_a_known_technology():
    """Synthetic grid: ln E = ln(base) - 0.9 ln s + ln(1 + aux / p), p differing by row (the accessories
    weigh more on a slow cycle); measurements made at s = 0.95, aux = 500 W are fitted back."""
    s = np.asarray(pb.CAL_SCALE)[:, None]
    aux = np.asarray(pb.CAL_AUX)[None, :]
    base = np.array([150.0, 170.0, 190.0, 210.0])
    p = np.array([1000.0, 4000.0, 1500.0, 6000.0])
    grid = np.log(base[:, None, None]) - 0.9 * np.log(s)[None] + np.log1p(aux[None] / p[:, None, None])
    meas = np.log(base) - 0.9 * np.log(0.95) + np.log1p(500.0 / p)
    params, loss = pb.fit_bev_peer(grid, meas)
    assert params["drivetrain_efficiency_scale"] == pytest.approx(0.95, abs=0.02)  # the quadratic surrogate
    assert params["accessory_power_w"] == pytest.approx(500.0, abs=150.0)
    assert loss < 0.01


def test_ev_records_pairing(shared_dir):
    rep: dict = {}
    df = pb.ev_records(shared_dir / "data" / "epa" / "22-tstcar.csv", rep)
    assert rep["n_rows"] == 206
    assert rep["n_paired"] == len(df) == 96
    assert [why for _, why in rep["unpaired"]] == ["one test in MPGe, the other apparently in kWh/100 mi"]
    assert list(df.columns[: len(pb.EV_COLUMNS)]) == list(pb.EV_COLUMNS)
    assert not df.duplicated(["test_vehicle_id", "config"]).any()
    assert df["udds_mpge"].between(60.0, 250.0).all() and df["hwy_mpge"].between(60.0, 250.0).all()
    assert (df["n_udds"] == 2).sum() == 6  # repeated tests, averaged
    i4 = df[(df["test_vehicle_id"] == "FK96502") & (df["config"] == 0)].iloc[0]
    assert (i4["udds_mpge"], i4["hwy_mpge"]) == (156.3, 154.8)
    assert i4["mass_kg"] == pytest.approx(5000 * 0.45359237)
