"""The power-split hybrid: the planetary gear set against hand values, conservation through it, the
managements against each other, its figures and its refusals."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

import vpsim
from vpsim.errors import ParameterError, VpsimError
from vpsim.model import split as sp
from vpsim.params import load_parameters

SPLIT = load_parameters("hev_split")
EMS = ("rule", "ecms", "dp")
S = sp.split_record(SPLIT)
G = sp.generator_record(SPLIT)


@pytest.fixture(scope="module")
def runs():
    cycles = ("udds", "hwfet", "us06")
    return {(c, m): vpsim.simulate(c, "backward", SPLIT, ems=m) for c in cycles for m in EMS}


# --- the gear set ------------------------------------------------------------------------------------------


def test_willis_equation_against_a_hand_value():
    """Z_s = 30, Z_r = 78 (k = 2.6): engine 2,000 rpm (209.44 rad/s) and ring 3,000 rpm (314.16 rad/s) turn
    the sun at 3.6 x 209.44 - 2.6 x 314.16 = -62.83 rad/s (-600 rpm) by hand; Willis:
    Z_s w_s + Z_r w_r = (Z_s + Z_r) w_c."""
    w_c, w_r = 2000 * math.pi / 30, 3000 * math.pi / 30
    w_s = sp.sun_speed(w_c, w_r, S)
    assert w_s == pytest.approx(-600 * math.pi / 30, rel=1e-12)
    assert 30 * w_s + 78 * w_r == pytest.approx(108 * w_c, rel=1e-12)
    assert sp.carrier_speed(w_s, w_r, S) == pytest.approx(w_c, rel=1e-12)
    # ring held (car at rest): the sun turns 3.6 times the engine; carrier held: the sun turns -2.6 x the ring
    assert sp.sun_speed(100.0, 0.0, S) == pytest.approx(360.0)
    assert sp.sun_speed(0.0, 100.0, S) == pytest.approx(-260.0)


def test_torque_balance_against_a_hand_value_and_power_through_the_set_is_conserved():
    """An engine torque of 108 N m puts 108 / 3.6 = 30 N m on the sun and 108 x 2.6 / 3.6 = 78 N m on the ring
    (the teeth's proportions); at any speeds the carrier's power equals the sun's plus the ring's."""
    t_s, t_r = sp.planetary_torques(108.0, S)
    assert (t_s, t_r) == (pytest.approx(30.0), pytest.approx(78.0))
    rng = np.random.default_rng(29)
    for w_c, w_r, t_c in rng.uniform([0.0, -50.0, -50.0], [550.0, 500.0, 180.0], size=(200, 3)):
        t_s, t_r = sp.planetary_torques(t_c, S)
        assert t_s * sp.sun_speed(w_c, w_r, S) + t_r * w_r == pytest.approx(t_c * w_c, rel=1e-12, abs=1e-9)


def test_engine_speed_window_keeps_the_generator_within_its_top_speed():
    """(P4): at a ring speed where the engine's lowest speed is set by MG1's top speed, MG1 turns at exactly
    -w_g,max there; the highest engine speed is the engine's own top speed."""
    from vpsim.model.record import kernel_records

    c = kernel_records(SPLIT)[0]
    w_r = 1200.0  # rad/s, beyond any car's: MG1 at rest would turn at -3,120 rad/s
    lo, hi = sp.carrier_speed_range(w_r, c, G, S)
    assert sp.sun_speed(lo, w_r, S) == pytest.approx(-G.max_speed)
    assert hi == S.engine_max_speed
    lo, hi = sp.carrier_speed_range(0.0, c, G, S)  # at rest: idle to the engine's top speed (MG1 allows 494)
    assert lo == c.idle_speed and hi == pytest.approx(min(S.engine_max_speed, G.max_speed / 3.6))


def test_best_efficiency_line_burns_least_at_each_power():
    """(P5): at each power of the line, no other speed of the engine's map burns less (checked on a finer grid
    of speeds than the line's own search, against the exact BQM fuel flow the kernels burn), to 1e-3: where
    the least fuel lies on the full-load line, the line's speed grid (0.5 rad/s) stops short of it by up to a
    step."""
    from vpsim.model.maps import cached_engine_map

    emap = cached_engine_map(SPLIT.engine).with_exact()
    powers, speeds, _, _ = sp.best_efficiency_line(emap, 80.0, 545.0)
    w = np.linspace(80.0, 545.0, 2000)
    full = emap.max_torque(w)
    for p, w_best in zip(powers[5::10], speeds[5::10], strict=True):
        ok = p / w <= full
        best = float(np.min(emap.fuel_flow(p / w[ok], w[ok])))
        assert float(emap.fuel_flow(p / w_best, w_best)) <= best * (1.0 + 1e-3), p


def _net_cost(emap, p, w, w_r, m):
    """fuel / (p - L_g - L_m2) of the engine at power p and speed w at ring speed w_r, the battery idle,
    written out here from Willis and the torque balance (P1)-(P3), as (P6) defines it; inf where MG1 is out
    of its limits or nothing is left."""
    from vpsim.model import machine as mc

    t_e = p / w
    w_s = 3.6 * w - 2.6 * w_r
    t_g = -t_e / 3.6
    w_m2 = S.mg2_ratio * w_r
    cap = float(mc.max_torque(w_m2, m))
    t_m2 = min(max(-t_g * w_s / w_m2, -cap), cap)
    net = p - float(mc.loss_w(t_g, w_s, G)) - float(mc.loss_w(t_m2, w_m2, m))
    if t_e > float(emap.max_torque(w)) or abs(w_s) > G.max_speed or abs(t_g) > float(mc.max_torque(w_s, G)):
        return math.inf
    return float(emap.fuel_flow(t_e, w)) / net if net > 0.0 else math.inf


def test_system_line_wastes_least_at_each_power_and_ring_speed():
    """(P6): at powers and ring speeds of the table, no engine speed of a finer grid gives less fuel per unit
    of the net power (the cost written out in the test from (P1)-(P3)), to 1e-3 (the line's grid is 1.5
    rad/s); at a highway ring speed (ring 300 rad/s: about 95 km/h on the preset) and a road-load power
    (10 kW) the line keeps MG1 nearer rest than the engine's own best-efficiency line (P5), which turns it
    backwards, and wastes less."""
    from vpsim.model import electric as el
    from vpsim.model.maps import cached_engine_map

    emap = cached_engine_map(SPLIT.engine).with_exact()
    m = el.electric_records(SPLIT)[1]
    powers, ring, table = sp.system_line(emap, 80.0, 545.0, m, G, S)
    w = np.linspace(80.0, 545.0, 3000)
    checked = 0
    for i in range(6, powers.size, 9):
        for j in range(4, ring.size, 6):
            got = _net_cost(emap, powers[i], table[i, j], ring[j], m)
            best = min(_net_cost(emap, powers[i], x, ring[j], m) for x in w)
            if math.isfinite(best):
                assert got <= best * (1.0 + 1e-3), (powers[i], ring[j])
                checked += 1
    assert checked >= 20
    own = sp.best_efficiency_line(emap, 80.0, 545.0)
    w_own = float(np.interp(10e3, own[0], own[1]))
    w_sys = float(sp.tb.bilinear(powers, ring, table, np.array([10e3]), np.array([300.0]))[0])
    assert abs(sp.sun_speed(w_sys, 300.0, S)) < abs(sp.sun_speed(w_own, 300.0, S))
    assert _net_cost(emap, 10e3, w_sys, 300.0, m) < _net_cost(emap, 10e3, w_own, 300.0, m)


def test_operating_lines_are_shared_by_parameter_sets_that_differ_where_they_do_not_read():
    """sp.operating_lines depends on the engine, machine and split sections only: a car that differs in its
    mass and electric load takes the same lines (the same arrays), one with another engine its own; the
    cached lines are those built afresh from their parts, and a run on them burns what a run after the
    cache is emptied burns."""
    from vpsim.methods import hev_split
    from vpsim.model import electric as el
    from vpsim.model.maps import cached_engine_map
    from vpsim.model.record import engine_record

    lines, best, cap = sp.operating_lines(SPLIT.engine, SPLIT.machine, SPLIT.split)
    other = SPLIT.with_changes(electric={"accessory_power": 650.0}, vehicle={"mass": SPLIT.vehicle.mass + 80})
    assert hev_split._inputs(other)["best"] is best
    hot = SPLIT.with_changes(engine={"thermal_efficiency": SPLIT.engine.thermal_efficiency + 0.02})
    assert hev_split._inputs(hot)["best"] is not best
    emap = cached_engine_map(SPLIT.engine).with_exact()
    w_lo = float(engine_record(SPLIT.engine).idle_speed)
    fresh = sp.system_line(emap, w_lo, SPLIT.split.engine_max_speed, el.electric_records(SPLIT)[1], G, S)
    for a, b in zip(best, fresh, strict=True):
        assert a.tobytes() == b.tobytes()
    first = vpsim.simulate("udds", "backward", other, ems="ecms").fuel_kg
    sp.operating_lines.cache_clear()
    again = SPLIT.with_changes(electric={"accessory_power": 650.0}, vehicle={"mass": SPLIT.vehicle.mass + 80})
    assert vpsim.simulate("udds", "backward", again, ems="ecms").fuel_kg == first


# --- the car on cycles -------------------------------------------------------------------------------------


def test_energy_balance_closes_with_the_engine_both_machines_and_the_battery(runs):
    for key, r in runs.items():
        assert abs(r.energy.relative_residual) < 1e-12, (key, r.energy)


def test_dynamic_programming_bounds_ecms_and_the_rules(runs):
    """Charge-sustaining fuel: DP (the optimum on its grid) <= ECMS and DP <= rules on every cycle where the
    rules follow the trace as well as the DP (on all three since the rules' choice falls shortest where it
    falls short). ECMS <= rules holds on UDDS (-7.0 %); on HWFET and US06 the ECMS (its equivalence factor
    the P2's, its engine kept on 5 s once started) ends 1.1 % and 1.7 % above the demand-following rules (the
    gap is reported, not hidden: docs/model.md), bounded here at 1.5 % and 2.5 %."""
    assert all(
        runs[c, "rule"].trace_miss.seconds <= runs[c, "dp"].trace_miss.seconds
        for c in ("udds", "hwfet", "us06")
    )
    for cycle in ("udds", "hwfet", "us06"):
        cs = {m: runs[cycle, m].electric["fuel_l_per_100km_cs"] for m in EMS}
        assert cs["dp"] <= cs["ecms"], (cycle, cs)
        if runs[cycle, "rule"].trace_miss.seconds <= runs[cycle, "dp"].trace_miss.seconds:
            assert cs["dp"] <= cs["rule"], (cycle, cs)
    bound = {"udds": 1.0, "hwfet": 1.015, "us06": 1.025}
    for cycle, factor in bound.items():
        cs = {m: runs[cycle, m].electric["fuel_l_per_100km_cs"] for m in EMS}
        assert cs["ecms"] <= factor * cs["rule"], (cycle, cs)


def test_the_ecms_keeps_a_started_engine_on_for_its_minimum_on_time(runs):
    """With ``ecms_min_on_time`` (the preset's 5 s) every run of the engine the ECMS starts lasts at least
    that long (the last may be cut by the cycle's end); without it, on US06 it made 56 starts, 37 of its stops
    3 s or less."""
    assert SPLIT.hybrid.ecms_min_on_time == 5.0
    for cycle in ("udds", "hwfet", "us06"):
        s = runs[cycle, "ecms"].series
        t, on = s["time_s"], s["engine_on"].astype(int)
        edges = np.diff(np.r_[0, on, 0])
        starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        inside = stops < t.size
        assert inside.sum() >= 10, cycle
        assert (t[stops[inside]] - t[starts[inside]] >= 5.0 - 1e-9).all(), cycle
    assert runs["us06", "ecms"].electric["engine_starts"] <= 40


def test_the_start_and_the_stop_priced_over_the_minimum_on_time():
    """The ECMS's start share and stop price by hand: with T = 5 s over a 1 s step, a fifth of the start's
    0.3 g each (the restart a stop while moving commits to); none at rest or with the engine off; without T,
    the whole start at the start and nothing at a stop."""
    from vpsim.model import hybrid as hy

    h = hy.hybrid_record(SPLIT)
    fuel = SPLIT.hybrid.engine_start_fuel
    assert hy.start_share(1.0, h) == pytest.approx(0.2)
    assert hy.start_share(10.0, h) == 1.0
    assert hy.stop_price(1.0, True, 1.0, h) == pytest.approx(0.2 * fuel)
    assert hy.stop_price(1.0, False, 1.0, h) == 0.0 and hy.stop_price(0.0, True, 1.0, h) == 0.0
    assert hy.must_keep_running(1.0, 4.0, h) and not hy.must_keep_running(1.0, 5.0, h)
    h0 = hy.hybrid_record(SPLIT.with_changes(hybrid={"ecms_min_on_time": 0.0}))
    assert hy.start_share(1.0, h0) == 1.0 and hy.stop_price(1.0, True, 1.0, h0) == 0.0
    assert not hy.must_keep_running(1.0, 0.0, h0)


def test_ecms_prices_the_charge_the_pack_keeps():
    """The ECMS's battery term is the stored energy's change as the state of charge counts it (B3): charging
    at 40 A with U_oc = 200 V for 1 s at s = 2.5, the pack (eta_c = 0.95) keeps 0.95 x 40 A s, so the term is
    -2.5 x 0.95 x 200 x 40 / q_hv by hand; discharging, the whole U_oc I. Priced at U_oc I when charging, the
    ECMS was credited with the charge the pack does not keep and cycled the pack."""
    from vpsim.model import battery as bt
    from vpsim.model import electric as el
    from vpsim.model import hybrid as hy
    from vpsim.model.record import kernel_records

    c = kernel_records(SPLIT)[0]
    e = el.electric_records(SPLIT)[0]
    h = hy.hybrid_record(SPLIT)
    assert e.coulombic_efficiency == pytest.approx(0.95)
    q = SPLIT.engine.fuel_heating_value
    for current, kept in ((-40.0, 0.95), (40.0, 1.0)):
        point = [0.0] * 25
        point[0], point[8], point[9] = 100.0, current, 200.0  # machine speed, battery current, U_oc
        cost = hy.ecms_cost(tuple(point), 1.0, 0.0, 2.5, c, e, h)
        assert cost == pytest.approx(2.5 * kept * 200.0 * current / q, rel=1e-12)
        # the same energy as the state of charge's change times the charge it holds at U_oc
        dsoc = bt.soc_rate(current, e.capacity_as, e.coulombic_efficiency) * 1.0
        assert cost == pytest.approx(-2.5 * dsoc * e.capacity_as * 200.0 / q, rel=1e-12)


def test_dp_ends_charge_sustaining(runs):
    """At or above its start (the terminal cost), and within J1711's 1 % band, so its figure is its own run's,
    not a correction: on US06 the DP once charged to its grid's top (0.60 -> 0.70, 2.3 % of its fuel's
    energy) to buy a higher pack voltage for a miss no choice avoids."""
    for cycle in ("udds", "hwfet", "us06"):
        e = runs[cycle, "dp"].electric
        assert e["soc_end"] >= e["soc_start"] - 1e-3
        assert abs(e["net_energy_change_ratio"]) <= 0.01, (cycle, e["soc_end"])
        assert e["fuel_l_per_100km_cs"] == runs[cycle, "dp"].fuel_l_per_100km


def test_dp_takes_the_unavoidable_miss_out_of_its_cost_to_go():
    """By hand: the least miss's price comes off a state's cost; nothing where every choice follows."""
    from vpsim.model import hybrid as hy
    from vpsim.model.record import kernel_records

    assert hy.less_unavoidable_miss(5.0, 2.0) == 3.0
    assert hy.less_unavoidable_miss(5.0, 0.0) == 5.0
    assert hy.less_unavoidable_miss(5.0, math.inf) == 5.0  # no choice was tried
    c = kernel_records(SPLIT)[0]
    point = [0.0] * 25
    point[0], point[13] = 99.0, 2.0  # machine speed (rad/s), torque missing (N m)
    want = hy.MISS_PENALTY * 2.0 * 100.0 * 0.5 / c.fuel_heating_value  # N m x (rad/s + 1) x dt / q_hv
    assert hy.miss_cost(tuple(point), 0.5, c) == pytest.approx(want, rel=1e-12)
    point[13] = 0.0
    assert hy.miss_cost(tuple(point), 0.5, c) == 0.0


def test_engine_off_at_rest_and_its_speed_within_the_gear_set(runs):
    df = runs["udds", "ecms"].to_dataframe()
    rest = df["speed_mps"] == 0.0
    assert not df.loc[rest, "engine_on"].any()
    on = df["engine_on"]
    assert (df.loc[on, "engine_speed_radps"] >= 80.0 - 1e-9).all()
    assert (df.loc[on, "engine_speed_radps"] <= SPLIT.split.engine_max_speed + 1e-9).all()
    assert (df["generator_speed_radps"].abs() <= SPLIT.split.generator_max_speed + 1e-9).all()
    assert (df.loc[~on, "engine_speed_radps"] == 0.0).all()
    assert runs["udds", "ecms"].electric["engine_starts"] > 0


def test_the_gear_set_and_the_machines_obey_willis_along_the_run(runs):
    """Every sample: MG1's speed is (P1) of the engine's and the ring's (MG2's over its reduction)."""
    df = runs["us06", "ecms"].to_dataframe()
    w_r = df["machine_speed_radps"] / SPLIT.split.mg2_ratio
    expect = 3.6 * df["engine_speed_radps"] - 2.6 * w_r
    np.testing.assert_allclose(df["generator_speed_radps"], expect, rtol=1e-12, atol=1e-9)


def test_the_hybrid_saves_fuel_against_the_same_engine_alone(runs):
    """The same engine and road load in a conventional car (the hofman2011 5-speed gearbox, engine always
    on): the split hybrid burns far less on the city cycle."""
    conv = SPLIT.with_changes(
        powertrain={"type": "conventional"},
        engine={"accessory_power": 300.0},
        transmission={"gearbox_ratios": [3.38, 1.76, 1.12, 0.89, 0.70], "final_drive": 4.05},
    )
    c = vpsim.simulate("udds", "backward", conv)
    assert runs["udds", "ecms"].electric["fuel_l_per_100km_cs"] < 0.75 * c.fuel_l_per_100km


def test_the_rule_falls_short_of_the_trace_no_more_than_any_engine_power_would():
    """At US06-like demands beyond what MG1 and the pack let the engine and MG2 give, the rule's choice (its
    demand plus charging, a fifth less while the gear set cannot take it) falls short by at most what the
    best of the ECMS's engine powers does: the rule may not miss what another choice delivers. (Before
    2026-12-07 it fell short by 5-72 % more at four of these five points.)"""
    from vpsim.methods import hev_split as hs
    from vpsim.model import electric as el
    from vpsim.model import hybrid as hy

    x = hs._inputs(SPLIT)
    c, e, m, g, s, tabs, h = x["c"], x["e"], x["m"], x["g"], x["s"], x["tabs"], x["h"]
    eng, opt, inv_cap = sp.line_tables(x["lines"], x["best"], x["cap"])
    soc = 0.55
    battery = el.battery_state(
        soc, e, tabs[el.TAB_SOC], tabs[el.TAB_OCV], tabs[el.TAB_R_DIS], tabs[el.TAB_R_CHG]
    )
    levels = SPLIT.hybrid.torque_levels
    for v, a in ((10.0, 3.0), (15.0, 2.5), (20.0, 2.0), (25.0, 1.5), (30.0, 1.2)):
        iv = sp.split_interval(v, a, x["ratio"], c, e, m, g, s, tabs)
        assert iv[9] <= iv[10]  # the engine may run
        p_high = sp.engine_power_limit(iv[10], x["cap"][0], x["cap"][1], inv_cap)
        p_follow = sp.demand_power(iv, e, p_high)
        on, p_e, found = sp.split_choose(
            iv, battery, soc, 1.0, 10.0, 1.0, hy.EMS_RULE, levels, True, p_follow, p_high,
            c, e, m, g, s, tabs, h, eng, opt, hy.dp_grid(SPLIT), np.zeros((2, 2, 2)), 1,
        )  # fmt: skip
        assert found and on == 1.0
        short = sp.split_choice(iv, battery, on, p_e, c, e, m, g, s, tabs, eng, opt)[13]
        others = []
        for u in range(1, levels + 2):
            p_u = sp.engine_power_choice(u, levels, p_follow, p_high)
            q = sp.split_choice(iv, battery, 1.0, p_u, c, e, m, g, s, tabs, eng, opt)
            if q[sp.P_FEASIBLE] > 0.0:
                others.append(q[13])
        assert short > 100.0  # the demand is beyond the powertrain here
        assert short <= min(others) * (1.0 + 1e-9), (v, a, short, min(others))


def test_trace_misses_are_counted(runs):
    """US06's hardest accelerations ask more than MG1 (23 kW) lets the engine give plus what the pack (97.5 A)
    gives: counted as a trace miss, never hidden."""
    r = runs["us06", "dp"]
    assert 0.0 < r.trace_miss.seconds < 30.0
    assert r.summary()["battery_at_limit_s"] > 0


@pytest.mark.parametrize("cycle", ["udds", "hwfet", "us06"])
def test_inverse_method_near_backward(runs, cycle):
    """The smoothing driver's trajectory with the same management and point: the rules within 3 % of the
    backward method (they achieve 2.1 %), the ECMS too (it achieves -1.0 % UDDS, -0.1 % HWFET, -2.7 % US06:
    its on/off decisions move with the smoothed trajectory)."""
    for ems, tol in (("rule", 0.03), ("ecms", 0.03)):
        inv = vpsim.simulate(cycle, "inverse", SPLIT, ems=ems)
        back = runs[cycle, ems].electric["fuel_l_per_100km_cs"]
        assert inv.electric["fuel_l_per_100km_cs"] == pytest.approx(back, rel=tol)
        assert abs(inv.energy.relative_residual) < 1e-12
        assert inv.method == "inverse" and inv.summary()["speed_not_followed_s"] <= 2.0


def test_dp_on_ftp75_within_its_time_target():
    """DP over 121 SOC points on FTP-75 (1,874 intervals): target <= 20 s on 2 cores (measured 1.2 s of CPU,
    2.5-5 s wall on a loaded machine)."""
    vpsim.simulate("udds", "backward", SPLIT, ems="dp")  # compiled
    t0 = time.perf_counter()
    r = vpsim.simulate("ftp75", "backward", SPLIT, ems="dp")
    assert time.perf_counter() - t0 <= 20.0
    assert r.electric["soc_end"] >= r.electric["soc_start"] - 1e-3


# --- refusals ----------------------------------------------------------------------------------------------


def test_a_gear_set_that_locks_is_refused_in_one_line():
    for changes, match in (
        ({"ring_teeth": 30}, "split.ring_teeth = 30 must exceed split.sun_teeth = 30"),
        ({"ring_teeth": 20}, "gear set locks"),
        ({"ring_teeth": 77}, "must be even"),
    ):
        with pytest.raises(ParameterError, match=match) as err:
            SPLIT.with_changes(split=changes)
        assert "\n" not in str(err.value)


def test_an_empty_soc_window_is_refused_in_one_line():
    with pytest.raises(ParameterError, match="battery.soc_min = 0.6 must be below battery.soc_max = 0.6"):
        SPLIT.with_changes(battery={"soc_min": 0.6, "soc_max": 0.6, "soc_initial": 0.6})
    with pytest.raises(ParameterError, match="hybrid.soc_target = 0.85 is outside the battery's window"):
        SPLIT.with_changes(hybrid={"soc_target": 0.85})
    with pytest.raises(ParameterError, match="gearbox_ratios must hold one ratio"):
        SPLIT.with_changes(transmission={"gearbox_ratios": [2.0, 1.0]})


def test_a_dp_off_the_backward_method_is_refused():
    with pytest.raises(VpsimError, match="backward method only"):
        vpsim.simulate("udds", "forward", SPLIT, ems="dp")
    with pytest.raises(VpsimError, match="backward method only"):
        vpsim.simulate("udds", "inverse", SPLIT, ems="dp")
    with pytest.raises(VpsimError, match="unknown energy management"):
        vpsim.simulate("udds", "backward", SPLIT, ems="magic")


def test_cli_simulate_hev_split_ecms_and_refuses_a_forward_dp(tmp_path, capsys):
    from vpsim.cli.main import main

    assert main(["simulate", "--vehicle", "hev_split", "--cycle", "udds", "--ems", "ecms", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["ems"] == "ecms" and math.isfinite(s["fuel_l_per_100km_cs"]) and s["engine_starts"] > 0
    args = ["simulate", "--vehicle", "hev_split", "--cycle", "udds", "--method", "forward", "--ems", "dp"]
    assert main(args) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("vpsim: error")]
    assert len(err) == 1 and "backward method only" in err[0]
