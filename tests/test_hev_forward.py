"""The hybrids (P2 and power split) on the forward method: a PI driver and the causal management drive the
car, whose speed is integrated from the force its powertrain delivers."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import vpsim
from vpsim.cycles import Cycle, load_cycle
from vpsim.errors import VpsimError
from vpsim.params import load_parameters
from vpsim.result import BAND_KMH

CARS = {name: load_parameters(name) for name in ("hev_p2", "hev_split")}
CYCLES = ("udds", "hwfet", "us06")
EMS = ("rule", "ecms")


@pytest.fixture(scope="module")
def runs():
    out = {}
    for car, p in CARS.items():
        for cyc in CYCLES:
            for ems in EMS:
                out[car, cyc, ems] = (
                    vpsim.simulate(cyc, "backward", p, ems=ems),
                    vpsim.simulate(cyc, "forward", p, ems=ems),
                )
    return out


def test_energy_balance_closes_and_the_kinetic_term_is_the_speed_left_at_the_end(runs):
    """The terms booked step by step close to rounding; and the vehicle's kinetic energy booked, sum m a v dt,
    is what the integrated speed says: 1/2 m v_end^2 (the cycle starts at rest), the energy the driver's
    speed error leaves in the car."""
    for key, (_, fwd) in runs.items():
        assert fwd.method == "forward"
        assert abs(fwd.energy.relative_residual) < 1e-12, (key, fwd.energy)
        v_end = fwd.series["speed_mps"][-1]
        mass = CARS[key[0]].vehicle.mass
        assert fwd.energy.terms["vehicle_kinetic"] == pytest.approx(0.5 * mass * v_end**2, abs=1e-6), key


@pytest.mark.parametrize("car", sorted(CARS))
@pytest.mark.parametrize("cycle", CYCLES)
def test_forward_within_3_percent_of_backward(runs, car, cycle):
    """The fuel corrected for the battery's energy change (at any size of it: J1711's 1 % band makes the
    charge-sustaining figure jump between runs whose changes fall on either side of it) within 3 % of the
    backward method's, and the end charge within 0.03, on every car, cycle and management; the power split
    on US06 included, where both methods miss the trace at full power (measured 2026-12-06: at most 2.0 %
    apart, the P2's UDDS ECMS 1.0 % where its J1711 figures are 3.8 % apart)."""
    for ems in EMS:
        back, fwd = runs[car, cycle, ems]
        assert fwd.electric["fuel_l_per_100km_corrected"] == pytest.approx(
            back.electric["fuel_l_per_100km_corrected"], rel=0.03
        ), ems
        assert fwd.electric["engine_starts"] > 0
        assert abs(fwd.electric["soc_end"] - back.electric["soc_end"]) < 0.03


def test_the_corrected_fuel_is_the_charge_sustaining_one_beyond_the_band(runs):
    """fuel_l_per_100km_corrected applies J1711's correction at any size of the battery's energy change: equal
    to the charge-sustaining figure where the change exceeds 1 % of the fuel's energy, and where it does not
    the fuel moved by the change's fuel equivalent (lower where the battery was charged)."""
    for key, pair in runs.items():
        for r in pair:
            e = r.electric
            nec, cs, corrected = (
                e["net_energy_change_ratio"],
                e["fuel_l_per_100km_cs"],
                e["fuel_l_per_100km_corrected"],
            )
            if abs(nec) > 0.01:
                assert corrected == cs, key
            else:
                assert cs == pytest.approx(r.fuel_l_per_100km, rel=1e-12), key
                assert math.copysign(1.0, corrected - cs) == math.copysign(1.0, nec) or nec == 0.0, key


def test_the_speed_stays_in_the_band_where_the_powertrain_can_follow(runs):
    """Outside the +-2 km/h band only while the powertrain was at its limit (the driver asked more than it
    gives); on UDDS and HWFET never, with the largest error within the band."""
    band = BAND_KMH / 3.6
    for key, (_, fwd) in runs.items():
        s = fwd.summary()
        assert s["speed_not_followed_s"] <= fwd.solver["powertrain_limited_s"], key
        err = np.abs(fwd.series["speed_mps"] - fwd.series["reference_speed_mps"])
        # the largest error over every step, at least the largest at the cycle's samples
        assert s["max_speed_error_mps"] == pytest.approx(fwd.solver["max_speed_error_mps"])
        assert s["max_speed_error_mps"] >= err.max() - 1e-12
        if key[1] != "us06":
            assert s["speed_not_followed_s"] == 0.0 and fwd.solver["max_speed_error_mps"] < band, key
        if fwd.solver["powertrain_limited_s"] == 0.0:  # the driver reads the trace's step ahead: on it
            assert fwd.solver["max_speed_error_mps"] < 1e-9, key


def test_a_demand_the_powertrain_cannot_give_is_counted(runs):
    """Where the driver asked more than the powertrain gives (the split's MG1 and pack on US06's hardest
    accelerations), the time is the run's demand not deliverable; the P2 on UDDS never."""
    s = runs["hev_split", "us06", "ecms"][1].summary()
    assert s["demand_not_deliverable_s"] > 5.0 and s["max_torque_shortfall_nm"] > 0.0
    assert s["torque_beyond_full_load_s"] == s["demand_not_deliverable_s"]
    assert runs["hev_p2", "udds", "ecms"][1].summary()["demand_not_deliverable_s"] == 0.0


def test_same_summary_keys_as_the_backward_method(runs):
    back, fwd = runs["hev_p2", "udds", "ecms"]
    assert set(fwd.summary()) == set(back.summary())
    assert fwd.summary()["ems"] == "ecms" and math.isfinite(fwd.summary()["fuel_l_per_100km_cs"])


@pytest.mark.parametrize("car", sorted(CARS))
def test_the_controller_is_causal(car):
    """A run on the first 300 s of UDDS is the full run's first 300 s, bit for bit: nothing later in the cycle
    reaches the driver or the management (the P2's gears are given as the full cycle's schedule)."""
    from vpsim.gears import default_schedule
    from vpsim.methods import hev_forward
    from vpsim.model.maps import cached_engine_map

    full = load_cycle("udds")
    cut = Cycle("udds-300", full.time_s[:301], full.speed_mps[:301])
    p = CARS[car]
    sched = default_schedule(full, p, cached_engine_map(p.engine))
    a = hev_forward.run(full, p, ems="ecms", schedule=sched)
    b = hev_forward.run(cut, p, ems="ecms", schedule=sched)
    for k in ("speed_mps", "soc", "engine_on", "machine_torque_nm", "fuel_flow_kgps"):
        np.testing.assert_array_equal(a.series[k][:300], b.series[k][:300], err_msg=k)


def test_dp_and_a_driver_are_refused_with_one_line():
    with pytest.raises(VpsimError, match="backward method only"):
        vpsim.simulate("udds", "forward", CARS["hev_p2"], ems="dp")
    with pytest.raises(VpsimError, match="forward_kp"):
        vpsim.simulate("udds", "forward", CARS["hev_split"], driver=2)


def test_cli_runs_the_forward_hybrid(capsys):
    from vpsim.cli.main import main

    args = ["simulate", "--vehicle", "hev_p2", "--cycle", "hwfet", "--method", "forward", "--ems", "rule"]
    assert main([*args, "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["method"] == "forward" and s["ems"] == "rule" and s["engine_starts"] > 0


@pytest.mark.parametrize("cycle", ["udds", "us06"])
def test_forward_ecms_walk_finds_the_exhaustive_searchs_choices(cycle):
    """The forward P2's ECMS walks from the last step's torque level (as the backward method's) and makes the
    choices trying every level makes, at every step (bit for bit)."""
    from vpsim.methods import hev_forward

    cyc = load_cycle(cycle)
    p = load_parameters("hev_p2")
    walk = hev_forward.run(cyc, p, ems="ecms")
    every = hev_forward.run(cyc, p, ems="ecms", exhaustive=True)
    assert walk.fuel_kg == every.fuel_kg
    for k in ("engine_on", "engine_torque_nm", "machine_torque_nm", "soc", "speed_mps"):
        assert np.array_equal(walk.series[k], every.series[k]), k


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    car=st.sampled_from(sorted(CARS)),
    speeds=st.lists(st.floats(0.0, 25.0), min_size=2, max_size=30),
    ems=st.sampled_from(EMS),
)
def test_the_driver_stays_on_any_trace_the_powertrain_can_follow(car, speeds, ems):
    """On a trace of gentle steps (at most 1.5 m/s^2, from and back to rest), wherever the powertrain was
    never at its limit the forward car is on the trace to rounding at every step (the driver adds the
    trace's acceleration over the step to its PI law), and the balance closes."""
    v = [0.0]
    for target in speeds:  # each sample moves towards the drawn speed by at most 1.5 m/s in its second
        v.append(v[-1] + float(np.clip(target - v[-1], -1.5, 1.5)))
    while v[-1] > 0.0:
        v.append(max(v[-1] - 1.5, 0.0))
    cyc = Cycle("gentle", np.arange(len(v), dtype=float), np.array(v))
    r = vpsim.simulate(cyc, "forward", CARS[car], ems=ems)
    assert abs(r.energy.relative_residual) < 1e-12
    if r.solver["powertrain_limited_s"] == 0.0:
        assert r.solver["max_speed_error_mps"] < 1e-9
