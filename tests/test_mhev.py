"""The 48 V mild hybrid (the P2's kernel with the machine on the crank) and an engine car's stop-start:
conservation, the mild hybrid between the engine car and the full hybrid, the managements against each other,
and stop-start's saving against the hand value idle flow x time at rest - starts x start fuel."""

from __future__ import annotations

import numpy as np
import pytest

import vpsim
from vpsim.batch import run_batch
from vpsim.cycles import load_cycle
from vpsim.errors import ParameterError, VpsimError
from vpsim.model import electric as el
from vpsim.model import hybrid as hy
from vpsim.params import load_parameters

MHEV = load_parameters("mhev")
EMS = ("rule", "ecms", "dp")
CYCLES = ("udds", "hwfet", "us06")
# the same car as an engine car: no machine or battery, its 300 W of accessories on the crank through a 12 V
# alternator (about 0.6 efficient), idling at the flow of the fleet's rule for this engine
CONVENTIONAL = MHEV.with_changes(
    powertrain={"type": "conventional"},
    engine={"accessory_power": 500.0},
    simulation={"idle_fuel_flow": 1.25e-4},
)
# the same car as a full P2 hybrid: a 40 kW machine behind the clutch and a 1.5 kWh, 240 V pack
FULL = MHEV.with_changes(
    powertrain={"type": "hev_p2"},
    machine={"rated_power": 40e3, "base_speed": 200.0, "max_speed": 700.0, "inertia": 0.03},
    battery={"cells_in_series": 64, "cells_in_parallel": 1, "soc_min": 0.2},
    hybrid={"soc_low": 0.5, "charge_power": 5e3},
)


@pytest.fixture(scope="module")
def runs():
    return {(c, m): vpsim.simulate(c, "backward", MHEV, ems=m) for c in CYCLES for m in EMS}


def test_energy_balance_closes_with_the_belt_and_the_dragged_engine(runs):
    """indicated + chemical = every loss: the belt's loss booked with the machine's, the dragged engine's
    friction and pumping with no indicated work, the slipping clutch's in the driveline's."""
    for key, r in runs.items():
        assert abs(r.energy.relative_residual) < 1e-12, (key, r.energy)
    inv = vpsim.simulate("udds", "inverse", MHEV, ems="ecms")
    assert abs(inv.energy.relative_residual) < 1e-12


@pytest.mark.parametrize("method", ["backward", "inverse", "forward"])
def test_a_system_without_assist_never_motors_and_burns_more(method):
    """``mild.assist_share`` 0 (a system that recuperates, starts and stops the engine and gives no torque):
    the machine never drives on any method, the balance still closes, the ECMS burns more than with the
    whole envelope as assist and less than the engine car (recuperation and stops stay); share 1 is the
    preset to the bit."""
    none = MHEV.with_changes(mild={"assist_share": 0.0})
    half = MHEV.with_changes(mild={"assist_share": 0.5})
    r0, r5, r1 = (vpsim.simulate("udds", method, p, ems="ecms") for p in (none, half, MHEV))
    assert np.nanmax(r0.series["machine_torque_nm"]) <= 0.0
    assert np.nanmax(r1.series["machine_torque_nm"]) > 1.0  # (the preset assists)
    # the envelope's top (below base speed) through the belt: the series is the machine's torque at the crank
    rated = el.electric_records(MHEV)[1].rated_torque * MHEV.mild.belt_ratio * MHEV.mild.belt_efficiency
    assert 0.0 < np.nanmax(r5.series["machine_torque_nm"]) <= 0.5 * rated * (1 + 1e-12)
    assert abs(r0.energy.relative_residual) < 1e-12
    cs = [r.electric["fuel_l_per_100km_cs"] for r in (r0, r1)]
    assert cs[1] < cs[0] < vpsim.simulate("udds", method, CONVENTIONAL).fuel_l_per_100km
    same = vpsim.simulate("udds", method, MHEV.with_changes(mild={"assist_share": 1.0}), ems="ecms")
    assert same.fuel_kg == r1.fuel_kg


def test_mild_hybrid_between_the_engine_car_and_the_full_hybrid(runs):
    """Same engine, gearbox and road load: stop, recuperation and a little assist save on every cycle, and a
    full hybrid (electric driving, a larger machine and pack) saves more."""
    for cycle in CYCLES:
        conv = vpsim.simulate(cycle, "backward", CONVENTIONAL).fuel_l_per_100km
        full = vpsim.simulate(cycle, "backward", FULL, ems="ecms").electric["fuel_l_per_100km_cs"]
        mild = runs[cycle, "ecms"].electric["fuel_l_per_100km_cs"]
        assert full < mild < conv, (cycle, full, mild, conv)
    # the city cycle: a 48 V system saves some 8-15 % against the engine car (its makers' and the
    # literature's range for belt starter-generators); here 11.7 %
    conv = vpsim.simulate("udds", "backward", CONVENTIONAL).fuel_l_per_100km
    assert 0.05 < 1.0 - runs["udds", "ecms"].electric["fuel_l_per_100km_cs"] / conv < 0.2


def test_dynamic_programming_bounds_the_causal_managements(runs):
    """DP (the optimum on its grid) < ECMS and < the rule on every cycle; ECMS <= rule on UDDS and US06.
    On HWFET this ECMS (the P2's equivalence factor, untuned for this car) ends 0.05 above its start charge,
    within J1711's 1 % that needs no correction, and its single-run figure reads 0.4 % above the rule's;
    at zero net change (J1711's regression, tests/test_charge_balance.py) it is below. (With 24 torque
    levels the DP's HWFET read 7.210 against the rule's 7.213 and this test allowed 0.1 %; the preset's 48
    converge the DP to 0.1 %, docs/model.md.)"""
    for cycle in CYCLES:
        cs = {m: runs[cycle, m].electric["fuel_l_per_100km_cs"] for m in EMS}
        assert cs["dp"] < min(cs["ecms"], cs["rule"]), (cycle, cs)
        e = runs[cycle, "dp"].electric
        assert e["soc_end"] >= e["soc_start"] - 1e-3 and abs(e["net_energy_change_ratio"]) <= 0.01
    for cycle in ("udds", "us06"):
        cs = {m: runs[cycle, m].electric["fuel_l_per_100km_cs"] for m in EMS}
        assert cs["ecms"] <= cs["rule"], (cycle, cs)


def test_the_engine_turns_whenever_the_clutch_is_closed_and_stops_at_rest(runs):
    """No electric driving: wherever the car moves with the engine's speed at or above idle, the engine
    turns (fired, or dragged with its fuel cut); at rest it stands and burns nothing; it cuts its fuel on
    some of the deceleration."""
    for m in EMS:
        df = runs["udds", m].to_dataframe()
        # a sample shows the interval that starts at it: at rest where that interval is
        rest = (df["speed_mps"] == 0.0) & (df["speed_mps"].shift(-1) == 0.0)
        assert not df.loc[rest, "engine_on"].any(), m
        assert (df.loc[rest, "fuel_flow_kgps"] == 0.0).all(), m
        series = runs["udds", m].series
        ratios = np.asarray(MHEV.transmission.ratios)[series["gear"].astype(int) - 1]
        w_wheel = ratios * series["speed_mps"] / MHEV.vehicle.wheel_radius
        # the samples whose two intervals both have the clutch closed (speed and ratio from the samples)
        closed = (w_wheel >= 80.0 + 5.0) & (np.roll(w_wheel, 1) >= 85.0) & (np.roll(w_wheel, -1) >= 85.0)
        assert df.loc[closed, "engine_on"].all(), m
        cut = df["engine_on"] & (df["fuel_flow_kgps"] == 0.0)
        assert cut.sum() > 30, m
        assert runs["udds", m].electric["engine_starts"] > 10


def test_the_belt_turns_the_machine_faster_and_costs_its_loss():
    """The machine turns at the belt ratio times the crank (the series); a belt of lower efficiency costs
    fuel on the optimum (DP), and a P1 (ratio 1, efficiency 1, the machine on the crank) runs and closes."""
    r = vpsim.simulate("udds", "backward", MHEV, ems="ecms")
    s = r.series
    on = s["engine_on"] & (s["engine_speed_radps"] > 0.0)
    np.testing.assert_allclose(s["machine_speed_radps"][on], 2.7 * s["engine_speed_radps"][on], rtol=1e-12)
    lossy = MHEV.with_changes(mild={"belt_efficiency": 0.85})
    dp = vpsim.simulate("udds", "backward", MHEV, ems="dp").electric["fuel_l_per_100km_cs"]
    dp_lossy = vpsim.simulate("udds", "backward", lossy, ems="dp").electric["fuel_l_per_100km_cs"]
    assert dp_lossy > dp
    p1 = MHEV.with_changes(mild={"belt_ratio": 1.0, "belt_efficiency": 1.0}, machine={"base_speed": 90.0})
    r1 = vpsim.simulate("udds", "backward", p1, ems="ecms")
    assert abs(r1.energy.relative_residual) < 1e-12


def test_belt_conversions_invert_each_other_and_lose_both_ways():
    h = hy.hybrid_record(MHEV)
    for t in (-40.0, -1.0, 0.0, 2.0, 50.0):
        crank = hy.belt_to_crank(t, h)
        assert hy.crank_to_belt(crank, h) == pytest.approx(t, rel=1e-15, abs=1e-15)
        # the crank gets k eta T driving; gives k T / eta generating: |crank| vs k |T|
        assert abs(crank) * (1 if t > 0 else 0.95**2) <= 2.7 * abs(t) + 1e-12


def test_inverse_within_3_percent_of_backward(runs):
    for cycle in CYCLES:
        inv = vpsim.simulate(cycle, "inverse", MHEV, ems="ecms").electric["fuel_l_per_100km_cs"]
        bwd = runs[cycle, "ecms"].electric["fuel_l_per_100km_cs"]
        assert abs(inv / bwd - 1.0) < 0.03, (cycle, inv, bwd)


def test_a_mild_field_out_of_range_is_one_line():
    with pytest.raises(ParameterError, match="mild.belt_efficiency"):
        MHEV.with_changes(mild={"belt_efficiency": 1.2})
    with pytest.raises(ParameterError, match="mild.belt_ratio"):
        MHEV.with_changes(mild={"belt_ratio": 0.0})


# --- stop-start for an engine car -------------------------------------------------------------------------

HOFMAN = load_parameters("hofman2011")
STOP_START = HOFMAN.with_changes(simulation={"stop_start": True})


def _rest_after_first_move(cycle):
    """(seconds at rest after the car first moved, restarts) counted from the cycle's samples alone."""
    t, v = np.asarray(cycle.time_s), np.asarray(cycle.speed_mps)
    rest = (v[1:] == 0.0) & (v[:-1] == 0.0)
    first = np.flatnonzero(~rest)[0]
    rest[:first] = False
    seconds = float(np.sum(np.diff(t)[rest]))
    restarts = int(np.sum(rest[:-1] & ~rest[1:]))
    return seconds, restarts


@pytest.mark.parametrize("name", ["udds", "ftp75", "nedc"])
def test_stop_start_saves_the_idle_fuel_less_the_restarts(name):
    """The hand value: idle flow x time at rest (after the first move) - restarts x start fuel."""
    cycle = load_cycle(name)
    base = vpsim.simulate(cycle, "backward", HOFMAN)
    ss = vpsim.simulate(cycle, "backward", STOP_START)
    seconds, restarts = _rest_after_first_move(cycle)
    hand = HOFMAN.simulation.idle_fuel_flow * seconds - restarts * HOFMAN.hybrid.engine_start_fuel
    assert base.fuel_kg - ss.fuel_kg == pytest.approx(hand, rel=1e-9)
    assert ss.summary()["engine_starts"] == restarts > 5
    assert base.summary()["engine_starts"] is None
    assert abs(ss.energy.relative_residual) < 1e-12
    # a few per cent on the city cycles (the literature reports some 3-8 % on urban cycles; this car's idle
    # flow is 0.13 g/s, its UDDS 18 % at rest)
    assert 0.02 < 1.0 - ss.fuel_kg / base.fuel_kg < 0.08


@pytest.mark.parametrize("name", ["udds", "nedc"])
def test_stop_start_on_the_forward_and_inverse_methods(name):
    """The forward car and the smoothing driver's stop and restart as the backward car does: the same
    restarts, the car's motion untouched, the balance closed, and the saving the idle fuel of the stops less
    the restarts'. The forward's idling engine burns the idle floor or a little more (its governor's
    transient as the clutch opens): its saving within 2 % above the hand value. The smoothed car comes to
    rest up to a after the cycle and leaves up to a before it (driver 2: a = 1 s): its saving within the
    hand value less 2a of idling per stop, and no more than the hand value."""
    cycle = load_cycle(name)
    seconds, restarts = _rest_after_first_move(cycle)
    idle, start = HOFMAN.simulation.idle_fuel_flow, HOFMAN.hybrid.engine_start_fuel
    hand = idle * seconds - restarts * start
    for method in ("forward", "inverse"):
        base = vpsim.simulate(cycle, method, HOFMAN)
        ss = vpsim.simulate(cycle, method, STOP_START)
        saved = base.fuel_kg - ss.fuel_kg
        assert ss.summary()["engine_starts"] == restarts, method
        assert ss.distance_m == base.distance_m and ss.trace_miss == base.trace_miss, method
        assert np.array_equal(ss.series["speed_mps"], base.series["speed_mps"])
        assert abs(ss.energy.relative_residual) < 1e-12, method
        stands = ss.series["engine_speed_radps"] == 0.0
        assert stands.sum() > 0.1 * cycle.time_s.size
        assert np.all(ss.series["fuel_flow_used_kgps"][stands] == 0.0)
        assert np.all(np.isnan(ss.series["intake_pressure_pa"][stands]))
        if method == "forward":
            assert hand <= saved <= 1.02 * hand
        else:
            a = HOFMAN.driver("2").inverse_a
            assert hand - (restarts + 1) * 2.0 * a * idle <= saved <= hand
    quiet = vpsim.simulate(cycle, "forward", STOP_START, keep_series=False)
    assert quiet.fuel_kg == vpsim.simulate(cycle, "forward", STOP_START).fuel_kg and not quiet.series


def test_stop_start_off_by_default_and_refused_where_not_modelled():
    assert HOFMAN.simulation.stop_start is False
    with pytest.raises(VpsimError, match="stop_start needs the realistic mode's clutch"):
        vpsim.simulate("udds", "forward", STOP_START, mode="paper")
    with pytest.raises(VpsimError, match="stop_start"):
        vpsim.simulate("udds", "forward", STOP_START, output_times=[1.0, 2.0])
    with pytest.raises(VpsimError, match="stop_start is modelled by the backward batch only"):
        run_batch("udds", None, "forward", STOP_START)


@pytest.mark.parametrize("mode", ["realistic", "paper"])
def test_stop_start_in_the_backward_batch_saves_what_a_single_run_saves(mode):
    """Variant by variant (the idle flow one of the varied fields), the batch's saving is the single run's."""
    var = {
        "vehicle.mass": [1200.0, 1650.0],
        "simulation.idle_fuel_flow": [1.0e-4, 1.6e-4],
        "transmission.final_drive": [3.8, 4.6],
    }
    plain = run_batch("udds", var, "backward", HOFMAN, mode=mode, gears="per_variant")
    ss = run_batch("udds", var, "backward", STOP_START, mode=mode, gears="per_variant")
    assert "engine_starts" not in plain and list(ss["engine_starts"]) == [14, 14]
    for i in range(2):
        changes = {
            "vehicle": {"mass": var["vehicle.mass"][i]},
            "simulation": {"idle_fuel_flow": var["simulation.idle_fuel_flow"][i]},
            "transmission": {"final_drive": var["transmission.final_drive"][i]},
        }
        one = vpsim.simulate("udds", "backward", HOFMAN.with_changes(**changes), mode=mode)
        one_ss = vpsim.simulate("udds", "backward", STOP_START.with_changes(**changes), mode=mode)
        saved = plain["fuel_kg"][i] - ss["fuel_kg"][i]
        assert saved == pytest.approx(one.fuel_kg - one_ss.fuel_kg, rel=1e-12)


def test_stop_start_takes_true_or_false_only(tmp_path):
    path = tmp_path / "car.toml"
    path.write_text('base = "hofman2011"\n[simulation]\nstop_start = 1\n')
    with pytest.raises(ParameterError, match="stop_start = 1 is not a true or false"):
        load_parameters(path)


def test_cli_reports_the_restarts_and_the_mild_hybrids_figures(tmp_path, capsys):
    from vpsim.cli.main import main

    path = tmp_path / "car.toml"
    path.write_text('base = "hofman2011"\n[simulation]\nstop_start = true\n')
    assert main(["simulate", "--vehicle", str(path), "--cycle", "udds"]) == 0
    assert "stop-start        14 engine restarts" in capsys.readouterr().out
    assert main(["simulate", "--vehicle", "mhev", "--cycle", "udds", "--ems", "dp", "--json"]) == 0
    import json

    s = json.loads(capsys.readouterr().out)
    assert s["engine_starts"] > 10 and abs(s["energy_relative_residual"]) < 1e-9
    assert s["fuel_l_per_100km_cs"] < s["fuel_l_per_100km"] * 1.01


def test_the_forward_method_runs_the_mild_hybrid_within_3_percent_of_the_backward():
    """The forward kernel is the P2's with the mild hybrid's record (belt, clutch, dragged engine)."""
    import vpsim

    for cycle in ("udds", "hwfet"):
        back = vpsim.simulate(cycle, "backward", "mhev", ems="ecms").summary()
        fwd = vpsim.simulate(cycle, "forward", "mhev", ems="ecms").summary()
        assert abs(fwd["fuel_l_per_100km_cs"] / back["fuel_l_per_100km_cs"] - 1.0) < 0.03
        assert abs(fwd["energy_relative_residual"]) < 1e-9


# --- a torque converter between the crank and the gearbox (the mild hybrids' automatics) -----------------

MILD_CONVERTER = {"converter_capacity_factor": 15.0, "lockup_min_gear": 2, "lockup_min_speed": 7.0}


def test_converter_engine_point_by_hand():
    """vehicle.converter_engine_point worked by hand (mu_s = 2, nu_c = 0.85, phi = 1/K^2 = 1/225): above idle
    the pump point of nu = 0.425 (mu = 1.5); a pump below idle speed held at idle, passing mu phi idle^2 at
    nu = w_t / idle, more than asked; a standing turbine at the stall, T_t = mu_s phi w_p^2."""
    from vpsim.model import vehicle as vh
    from vpsim.model.record import record

    c = record(MHEV.with_changes(transmission=MILD_CONVERTER))
    w_p = 100.0 / 0.425
    t_p = w_p * w_p / 225.0
    got = vh.converter_engine_point(100.0, 2.0, 1.5 * t_p, c)
    assert got == pytest.approx((w_p, 2.0 / 0.425, t_p, 1.5, 0.0), rel=1e-12)
    idle = c.idle_speed
    nu = 20.0 / idle
    mu = 2.0 - nu / 0.85
    held = vh.converter_engine_point(20.0, 1.0, 1.0, c)
    assert held == pytest.approx((idle, 0.0, idle * idle / 225.0, mu, 1.0), rel=1e-12)
    assert held[3] * held[2] > 1.0  # passes more than the 1 N m asked: the brakes hold the rest
    stall = vh.converter_engine_point(0.0, 0.0, 2.0 * 400.0**2 / 225.0, c)  # 400 rad/s > idle
    assert stall == pytest.approx((400.0, 0.0, 400.0**2 / 225.0, 2.0, 0.0), rel=1e-12)


@pytest.mark.parametrize("method", ["backward", "forward"])
def test_mild_converter_slips_recovers_less_and_closes_the_balance(method):
    """The mild hybrid with a converter after its crank: below lock-up the crank turns faster than the gearbox
    input while it drives (the pump), the converter passes no braking (less recuperated), its loss is booked
    as driveline loss (the balance closes to rounding) and the car burns more than with a clutch."""
    q = MHEV.with_changes(transmission=MILD_CONVERTER)
    base = vpsim.simulate("udds", method, MHEV, ems="ecms")
    conv = vpsim.simulate("udds", method, q, ems="ecms")
    assert abs(conv.energy.relative_residual) < 1e-9
    assert conv.energy.terms["driveline_loss"] > base.energy.terms["driveline_loss"]
    assert conv.electric["regen_wh"] < base.electric["regen_wh"]
    assert conv.electric["fuel_l_per_100km_cs"] > base.electric["fuel_l_per_100km_cs"]
    if method == "backward":
        from vpsim.model.record import ratios as total_ratios

        df = conv.to_dataframe()
        ratios = np.asarray(total_ratios(q.transmission))
        w_in = ratios[df["gear"].astype(int) - 1] * df["speed_mps"] / q.vehicle.wheel_radius
        unlocked = ((df["gear"] == 1) | (df["speed_mps"] < 7.0)) & (df["speed_mps"] > 0.5)
        driving = unlocked & (df["accel_mps2"] > 0.0) & (df["engine_speed_radps"] > 0.0)
        assert driving.sum() > 50
        assert (df.loc[driving, "engine_speed_radps"] > w_in[driving]).all()
        # no traction below lock-up: the machine takes nothing from the wheels (it may charge from the engine)
        coasting = unlocked & (df["accel_mps2"] < 0.0) & ~df["engine_on"].astype(bool)
        assert coasting.sum() > 20
        assert (df.loc[coasting, "machine_torque_nm"] == 0.0).all()


def test_mild_converter_locked_everywhere_is_the_clutch_car_bit_for_bit():
    locked = MHEV.with_changes(transmission={**MILD_CONVERTER, "lockup_min_gear": 1, "lockup_min_speed": 0.0})
    for ems in ("rule", "ecms"):
        a = vpsim.simulate("udds", "backward", MHEV, ems=ems)
        b = vpsim.simulate("udds", "backward", locked, ems=ems)
        assert a.fuel_kg == b.fuel_kg
        np.testing.assert_array_equal(a.series["machine_torque_nm"], b.series["machine_torque_nm"])
