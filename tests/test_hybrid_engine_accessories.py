"""A hybrid engine's own accessories (``engine.accessory_power``: belt-driven pumps and compressor, on the
crank while the engine turns), beside the electric loads (``electric.accessory_power``): every layout and
method books them, the balance closes, and the booked energy is the hand value P x the engine's turning
time. Until 2026-12-07 the hybrids ignored the field without a word (the same fuel at 0 and 1 kW)."""

from __future__ import annotations

import numpy as np
import pytest

import vpsim
from vpsim.params import load_parameters

LAYOUTS = ("hev_p2", "hev_split", "mhev")
METHODS = ("backward", "inverse", "forward")
P_ACC = 800.0  # W on the crank


def _runs(layout, method, cycle="udds"):
    p = load_parameters(layout)
    q = p.with_changes(engine={"accessory_power": P_ACC})
    return p, q, vpsim.simulate(cycle, method, p, ems="ecms"), vpsim.simulate(cycle, method, q, ems="ecms")


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("method", METHODS)
def test_the_engines_accessories_cost_fuel_and_close_the_balance(layout, method):
    p, q, r0, r1 = _runs(layout, method)
    assert r1.electric["fuel_l_per_100km_cs"] > r0.electric["fuel_l_per_100km_cs"]
    assert abs(r1.energy.relative_residual) < 1e-12, r1.energy
    assert r1.electric["engine_on_s"] > 0.0


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("method", METHODS)
def test_the_booked_accessories_are_p_times_the_engines_turning_time(layout, method):
    """accessories = P_electric x the run's time + P_engine x the time the engine turns (a running engine
    turns at or above its idle speed, where the accessories' torque is P / w): a hand value from the run's
    own counters, on UDDS and US06."""
    for cycle in ("udds", "us06"):
        p, q, _, r1 = _runs(layout, method, cycle)
        duration = float(r1.series["time_s"][-1] - r1.series["time_s"][0])
        expected = q.electric.accessory_power * duration + P_ACC * r1.electric["engine_on_s"]
        got = r1.energy.terms["accessories"]
        assert got == pytest.approx(expected, rel=1e-9), (cycle, got, expected)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_without_engine_accessories_only_the_electric_load_is_booked(layout):
    """The presets' 0 W on the crank: the accessories term is the electric load x the run's time alone, on
    every method (the engine's share adds exactly nothing; the fuel is the parent's to the bit, checked by
    benchmarks/electric_fuel_matrix.py --against)."""
    p = load_parameters(layout)
    assert p.engine.accessory_power == 0.0
    for method in METHODS:
        r = vpsim.simulate("udds", method, p, ems="ecms")
        duration = float(r.series["time_s"][-1] - r.series["time_s"][0])
        electric_only = p.electric.accessory_power * duration
        assert r.energy.terms["accessories"] == pytest.approx(electric_only, rel=1e-12), method


@pytest.mark.parametrize("layout", ["hev_p2", "mhev"])
def test_the_management_keeps_the_crank_within_its_full_load_line(layout):
    """With 6 kW on the crank the engine's shaft torque tops out that much below its full-load line: the
    crank's torque (shaft + accessories + its inertia's) never asks more than the line by more than the
    inertia's share, so the intake pressure stays where the engine can make it."""
    from vpsim.model.maps import cached_engine_map

    q = load_parameters(layout).with_changes(engine={"accessory_power": 6000.0})
    em = cached_engine_map(q.engine)
    r = vpsim.simulate("us06", "backward", q, ems="ecms")
    s = r.series
    on = s["engine_on"] & (s["fuel_flow_kgps"] > 0.0)
    w = s["engine_speed_radps"][on]
    t_shaft = s["engine_torque_nm"][on]
    t_line = np.asarray(em.max_torque(w), float)
    acc = 6000.0 / w  # (a running engine turns at or above its idle speed)
    assert np.all(t_shaft + acc <= t_line + 1e-6 * np.abs(t_line) + 1e-9)
