"""The machine's torque cut to the battery's power limit (vpsim.model.electric.torque_for_power): its closed
forms (the scalable machine's quadratic, the measured map's piecewise-linear root) against an independent
root finder (scipy's brentq on the same machine_power) and against the bisection they replace."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq

from vpsim.model import electric as el
from vpsim.model import machine as mc
from vpsim.params import load_parameters

PRESETS = {name: el.electric_records(load_parameters(name)) for name in ("hev_p2", "bev")}


def _power(t, w, m, e, tabs):
    return el.machine_power(t, w, m, e, tabs.map_speed, tabs.map_torque, tabs.map_loss) + e.accessory_power


def _case(records, w_frac, t_frac, p_frac):
    """(target, t_from, w, lo, hi) with the bracket the callers give: the power at t_from beyond the target,
    the target between the powers at 0 and at t_from."""
    e, m, tabs = records
    w_top = tabs.env_speed[-1] if e.measured_machine > 0.0 else m.max_speed
    w = w_frac * w_top
    t_min, t_max = el.envelope(w, m, e, tabs.env_speed, tabs.env_max, tabs.env_min)
    t_from = t_frac * (t_max if t_frac > 0.0 else -t_min)
    lo, hi = (0.0, t_from) if t_from > 0.0 else (t_from, 0.0)
    p_lo, p_hi = _power(lo, w, m, e, tabs), _power(hi, w, m, e, tabs)
    return p_lo + p_frac * (p_hi - p_lo), t_from, w, lo, hi, p_lo, p_hi


def _independent(target, w, lo, hi, records):
    e, m, tabs = records
    eps = np.finfo(float).eps
    return brentq(lambda t: _power(t, w, m, e, tabs) - target, lo, hi, xtol=1e-300, rtol=4 * eps)


def _cut(target, t_from, w, records, fn=el.torque_for_power):
    e, m, tabs = records
    return fn(target, t_from, w, m, e, tabs.map_speed, tabs.map_torque, tabs.map_loss)


@settings(max_examples=200, deadline=None)
@given(
    name=st.sampled_from(sorted(PRESETS)),
    w_frac=st.floats(0.002, 1.0),
    t_frac=st.floats(0.01, 1.0) | st.floats(-1.0, -0.01),
    p_frac=st.floats(0.0, 0.999999),
)
def test_scalable_machine_closed_form_is_the_root(name, w_frac, t_frac, p_frac):
    """The quadratic's root (no bisection taken: torque_of_power gives a number) is brentq's on the same
    machine_power to a few ulps of the torque, and the bisection's to its 2^-48 of the bracket."""
    records = PRESETS[name]
    e, m, _ = records
    target, t_from, w, lo, hi, p_lo, p_hi = _case(records, w_frac, t_frac, p_frac)
    if not p_lo <= target < p_hi:  # the power does not rise through the target (low speed, braking)
        return
    if target == p_lo and lo < 0.0:
        # generating at low speed the power is a parabola in the torque with its minimum inside the
        # bracket: the bracket's end is then a root itself (brentq returns it) and the closed form gives
        # the other, where the power comes back up: the cut's answer for any target above p_lo
        return
    assert not math.isnan(mc.torque_of_power(target - e.accessory_power, w, lo, hi, m))
    t = _cut(target, t_from, w, records)
    assert lo <= t <= hi
    scale = abs(t_from)
    assert abs(t - _independent(target, w, lo, hi, records)) <= 1e-13 * scale
    assert abs(t - _cut(target, t_from, w, records, el.bisect_torque_for_power)) <= 1e-13 * scale


def test_loss_polynomial_is_loss_w():
    """a T^2 + b T + c reproduces loss_w on both torque branches, below and above the base speed."""
    _, m, _ = PRESETS["hev_p2"]
    for w in (0.0, 0.5 * m.base_speed, m.base_speed, 2.5 * m.base_speed, m.max_speed):
        for t in (0.0, 0.3 * m.rated_torque, -0.7 * m.rated_torque, m.rated_torque):
            a, b, c = mc.loss_polynomial(w, 1.0 if t >= 0.0 else -1.0, m)
            assert a * t * t + b * t + c == pytest.approx(mc.loss_w(t, w, m), rel=1e-14)


def test_without_a_bracket_it_is_the_bisection():
    """Where the accessories alone exceed the target (an empty pack) no torque meets it: the closed form is
    not taken and the answer is the bisection's (no torque while driving)."""
    records = PRESETS["hev_p2"]
    e, m, tabs = records
    w = 300.0
    t_from = 100.0
    target = _power(0.0, w, m, e, tabs) - 50.0
    assert _cut(target, t_from, w, records) == 0.0
    assert _cut(target, t_from, w, records, el.bisect_torque_for_power) == 0.0


@pytest.fixture(scope="module")
def measured(shared_dir):
    path = shared_dir / "data" / "raw" / "advisor" / "MC_PM32.m"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    return el.electric_records(load_parameters("hev_p2").with_changes(machine={"map_file": str(path)}))


def test_measured_map_root_is_the_root(measured):
    """On a measured map (MC_PM32) the cell-wise linear root is brentq's to a few ulps and the bisection's to
    its 2^-48, in both quadrants over the map's speeds."""
    rng = np.random.default_rng(7)
    e, m, tabs = measured
    n = 0
    for _ in range(1500):
        w_frac, p_frac = rng.uniform(0.002, 1.0), rng.uniform(0.0, 0.999999)
        t_frac = rng.uniform(0.01, 1.0) * rng.choice((-1.0, 1.0))
        target, t_from, w, lo, hi, p_lo, p_hi = _case(measured, w_frac, t_frac, p_frac)
        if not p_lo <= target < p_hi:
            continue
        t_map = el.map_torque_of_power(
            target, lo, hi, p_lo, p_hi, w, m, e, tabs.map_speed, tabs.map_torque, tabs.map_loss
        )
        assert not math.isnan(t_map)
        t = _cut(target, t_from, w, measured)
        scale = abs(t_from)
        assert abs(t - _independent(target, w, lo, hi, measured)) <= 1e-12 * scale
        assert abs(t - _cut(target, t_from, w, measured, el.bisect_torque_for_power)) <= 1e-12 * scale
        n += 1
    assert n > 500
