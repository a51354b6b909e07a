"""Inverse dynamic method: smoothing on the grid, the inversion (30)-(33), infeasible throttle, modes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vpsim.cycles import Cycle, load_cycle
from vpsim.drivers.smoothing import SmoothingDriver
from vpsim.errors import VpsimError
from vpsim.methods import backward, inverse
from vpsim.model import IDLE_SPEED
from vpsim.model import engine as en
from vpsim.model import vehicle as vh
from vpsim.model.record import record
from vpsim.simulation import resolve_inputs, simulate
from vpsim.study import inversion_check


@pytest.fixture(scope="module")
def prepared():
    return {name: resolve_inputs(name, "hofman2011") for name in ("nedc", "ftp75")}


@pytest.fixture(scope="module")
def runs(prepared):
    res = {}
    for name, (c, p, s) in prepared.items():
        for mode in ("paper", "extended"):
            res[name, mode] = backward.run(c, p, schedule=s, mode=mode)
            for d in ("1", "2"):
                res[name, d, mode] = inverse.run(c, p, driver=d, schedule=s, mode=mode)
    return res


def _compiled_smoothing(c, a):
    """(v_d, dv_d/dt, d2v_d/dt2) at the samples as the inverse method's compiled pass computes them."""
    from vpsim.gears import GearSchedule

    s = GearSchedule(c.time_s.copy(), np.ones(c.time_s.size, dtype=np.int64))
    taps = inverse._sample_taps(a, float(c.time_s[1] - c.time_s[0]))
    F, _ = inverse._grid_and_smoothing(c.time_s, c.speed_mps, s.time_s, s.gear, *taps)
    n = c.time_s.size
    return F[1, :n], F[2, :n], F[3, :n]


@pytest.mark.parametrize("name", ["nedc", "ftp75", "udds", "short"])
@pytest.mark.parametrize("a", [5.0, 1.0, 2.5, 0.7])
def test_smoothing_on_samples_equals_the_smoothing_driver(name, a):
    """The compiled convolution on the samples against the smoothing driver's windowed evaluation (another
    algorithm, itself checked against quadrature in tests/test_smoothing.py)."""
    c = (
        Cycle("short", np.arange(4.0), np.array([0.0, 1.0, 3.0, 2.0]))
        if name == "short"
        else load_cycle(name)
    )
    fast = _compiled_smoothing(c, a)
    ref = SmoothingDriver(c.time_s, c.speed_mps, a).evaluate(c.time_s)
    for f, r in zip(fast, ref, strict=True):
        np.testing.assert_allclose(f, r, rtol=0, atol=1e-12)


def test_inversion_satisfies_the_model(params, prepared):
    """Plugging x2 and u_d back into (21): dx1/dt is the demanded acceleration, and the manifold equation
    gives the time derivative of x2 along the trajectory (checked by finite differences within one gear)."""
    c, p, s = prepared["nedc"]
    t = np.linspace(130.0, 138.0, 8001)  # accelerating in one gear
    gear = s.gear_at(t)
    assert np.all(gear == gear[0])
    v, dv, ddv = SmoothingDriver(c.time_s, c.speed_mps, 1.0).evaluate(t)
    inv = inverse.invert(v, dv, ddv, gear, p, "paper")
    x2, u = inv["intake_pressure_pa"], inv["throttle_demand_m2"]
    ratio = p.transmission.ratios[gear[0] - 1]
    c1, c2, c3, c4, c5, c6, c7 = vh.statespace_coefficients(ratio, record(p))
    np.testing.assert_allclose(c1 * v**2 + c2 * v**1.8 + c3 * x2 + c4, dv, atol=1e-9)
    psi = en.psi_array(x2 / p.engine.ambient_pressure, record(p))
    rate = c5 * v + c6 * v * x2 + c7 * psi * u
    np.testing.assert_allclose(np.gradient(x2, t)[1:-1], rate[1:-1], rtol=1e-4, atol=5.0)


@pytest.mark.parametrize("name", ["nedc", "ftp75"])
@pytest.mark.parametrize("driver", ["1", "2"])
def test_open_loop_check_reproduces_the_smoothed_speed(params, prepared, name, driver):
    c, p, s = prepared[name]
    for feasible in (True, False):
        chk = inversion_check(c, p, driver, s, feasible_only=feasible)
        assert chk["max_speed_error_mps"] < 0.05
        assert chk["windows"] > 20 and chk["checked_s"] > 0.7 * chk["moving_s"]


@pytest.mark.parametrize("name", ["nedc", "ftp75"])
@pytest.mark.parametrize("driver", ["1", "2"])
def test_fuel_within_four_percent_of_backward(runs, name, driver):
    for mode in ("paper", "extended"):
        r, b = runs[name, driver, mode], runs[name, mode]
        assert abs(r.fuel_l_per_100km / b.fuel_l_per_100km - 1) < 0.04
        assert r.distance_m == pytest.approx(b.distance_m, rel=1e-4)  # smoothing keeps the distance


@pytest.mark.parametrize("name", ["nedc", "ftp75"])
def test_tighter_driver_uses_more_fuel(runs, name):
    assert runs[name, "2", "paper"].fuel_kg > runs[name, "1", "paper"].fuel_kg


@pytest.mark.parametrize("name", ["nedc", "ftp75"])
@pytest.mark.parametrize("driver", ["1", "2"])
def test_trapezoid_on_the_samples_is_accurate(prepared, runs, name, driver):
    """The fuel on the 1 s grid agrees with Simpson's rule on a 0.05 s grid to 0.1 %."""
    c, p, s = prepared[name]
    a = p.driver(driver).inverse_a
    n = 20
    t = c.time_s[:-1, None] + np.diff(c.time_s)[:, None] * (np.arange(n + 1) / n)[None, :]
    g = np.repeat(s.on_cycle(c)[:-1, None], n + 1, axis=1)  # each interval with its own gear at both ends
    v, dv, ddv = SmoothingDriver(c.time_s, c.speed_mps, a).evaluate(t.ravel())
    inv = inverse.invert(v, dv, ddv, g.ravel(), p, "paper")
    f = np.maximum(inv["fuel_flow_kgps"], p.simulation.idle_fuel_flow).reshape(t.shape)
    h = np.diff(c.time_s) / n
    ref = np.sum(h / 3 * (f[:, 0] + f[:, -1] + 4 * f[:, 1:-1:2].sum(1) + 2 * f[:, 2:-1:2].sum(1)))
    assert runs[name, driver, "paper"].fuel_kg == pytest.approx(ref, rel=1e-3)


def test_steps_are_evaluation_points(prepared, runs):
    c, _, s = prepared["nedc"]
    n_shifts = int(np.sum(s.shift_times < c.time_s[-1]))
    assert runs["nedc", "1", "paper"].steps == c.time_s.size + n_shifts


@pytest.mark.parametrize("name", ["nedc", "ftp75"])
def test_energy_balance_closes(runs, name):
    for key in ((name, "1", "paper"), (name, "2", "extended")):
        e = runs[key].energy
        assert e.relative_residual < 1e-9
    assert runs[name, "2", "extended"].energy.brake > 0


def test_infeasible_throttle_is_reported(runs):
    """Paper mode: decelerations beyond engine braking need u_d < A_min; standstill (u_d = 0) is apart.
    Extended mode: the brakes take those stretches; what is left is small."""
    paper = runs["nedc", "2", "paper"].trace_miss
    d = paper.details
    assert paper.infeasible_throttle_s == paper.seconds == d["below_min_throttle_s"] > 60.0
    assert d["above_max_throttle_s"] == 0.0 and d["min_throttle_demand_m2"] < 0.0
    assert d["standstill_s"] > 200.0
    ext = runs["nedc", "2", "extended"].trace_miss
    assert ext.details["braked_s"] > 100.0
    assert ext.infeasible_throttle_s < 0.1 * paper.infeasible_throttle_s


def test_series(runs, prepared):
    r, b = runs["ftp75", "1", "paper"], runs["ftp75", "paper"]
    assert set(b.series) <= set(r.series)
    c, p, _ = prepared["ftp75"]
    s = r.series
    assert s["time_s"].size == c.time_s.size
    np.testing.assert_array_equal(s["reference_speed_mps"], c.speed_mps)
    thr = s["throttle_area_m2"]
    assert np.all((thr >= p.engine.min_throttle_area) & (thr <= p.engine.max_throttle_area))
    assert np.any(s["throttle_demand_m2"] < p.engine.min_throttle_area)
    assert r.trace_miss.max_speed_error_mps == pytest.approx(np.max(np.abs(s["speed_mps"] - c.speed_mps)))


def test_extended_mode_clutch_and_idle(runs, params):
    s = runs["nedc", "1", "extended"].series
    rest = s["speed_mps"] == 0
    assert np.all(s["engine_speed_radps"][rest] == IDLE_SPEED)
    assert not np.any(s["clutch_engaged"][rest])
    assert np.all(s["fuel_flow_used_kgps"][rest] >= params.simulation.idle_fuel_flow)


def test_non_uniform_cycle_uses_the_smoothing_driver(params):
    base = load_cycle("nedc")
    keep = np.r_[True, np.diff(base.speed_mps, 2) != 0, True]  # drop samples inside straight pieces
    c = Cycle("nedc_sparse", base.time_s[keep], base.speed_mps[keep])
    r = simulate(c, method="inverse", driver=1)
    sd = SmoothingDriver(c.time_s, c.speed_mps, 5.0)
    np.testing.assert_allclose(r.series["speed_mps"], sd.v_d(c.time_s), atol=1e-12)
    full = simulate(base, method="inverse", driver=1)
    assert r.fuel_kg == pytest.approx(full.fuel_kg, rel=0.02)


def test_bad_input(params, prepared):
    c, p, s = prepared["nedc"]
    with pytest.raises(VpsimError):
        inverse.run(c, p, schedule=s, mode="fast")
    with pytest.raises(VpsimError):
        inverse.invert(np.ones(2), np.zeros(2), np.zeros(2), np.array([0, 9]), p)
    with pytest.raises(VpsimError):
        inverse.run(c, p, schedule=s, a=-1.0)


@pytest.mark.parametrize("name", ["nedc", "ftp75", "udds"])
@pytest.mark.parametrize("a", [5.0, 1.0, 0.7])
def test_compiled_grid_and_smoothing_match_numpy(name, a):
    """The compiled grid, gear lookup and smoothing equal evaluation_grid and the smoothing driver."""
    c, p, s = resolve_inputs(name, "hofman2011")
    taps = inverse._sample_taps(a, float(c.time_s[1] - c.time_s[0]))
    assert inverse._is_uniform_compiled(c.time_s)
    F, I = inverse._grid_and_smoothing(c.time_s, c.speed_mps, s.time_s, s.gear, *taps)
    n = c.time_s.size - 1
    got = (F[0], I[0], I[1, :n], I[2, :n], I[3], F[1], F[2], F[3], I[4, : n + 1], F[5, :n], F[4])
    t, gear, left, right, sample = inverse.evaluation_grid(c, s)
    for g, r in zip(got[:5], (t, gear, left, right, sample), strict=True):
        np.testing.assert_array_equal(g, r)
    ref = SmoothingDriver(c.time_s, c.speed_mps, a).evaluate(c.time_s)
    for g, r in zip(got[5:8], ref, strict=True):
        np.testing.assert_allclose(g, r[sample], rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(got[8], s.gear_at(c.time_s))
    np.testing.assert_array_equal(got[9], np.diff(c.time_s))
    np.testing.assert_array_equal(got[10], c.speed_mps[sample])
    assert not inverse._is_uniform_compiled(np.array([0.0, 1.0, 2.5]))


@settings(max_examples=80, deadline=None)
@given(
    speeds=st.lists(st.floats(0.0, 40.0), min_size=2, max_size=40),
    step=st.sampled_from([0.5, 1.0, 2.0]),
    a=st.floats(0.3, 12.0),
)
def test_compiled_smoothing_matches_the_driver_on_short_cycles(speeds, step, a):
    """The compiled convolution (four windows at a time inside the cycle, one at a time near its ends and
    where the window is wider than the cycle) against the smoothing driver's own evaluation."""
    t = np.arange(len(speeds)) * step
    v = np.asarray(speeds)
    taps = inverse._sample_taps(a, step)
    one_gear = (np.array([0.0]), np.array([1]))
    F, _ = inverse._grid_and_smoothing(t, v, *one_gear, *taps)
    ref = SmoothingDriver(t, v, a).evaluate(t)
    for got, want in zip(F[1:4], ref, strict=True):
        np.testing.assert_allclose(got[: t.size], want, rtol=1e-12, atol=1e-12)  # seen: 5e-14


def test_runs_on_one_schedule_share_the_trajectory_and_match_a_fresh_one():
    """The smoothing driver's trajectory is kept on the schedule per half-width (no car parameter changes
    it): a second design's run on the same schedule reads it and gives what a run on a fresh copy of the
    schedule computes; the shared arrays are read-only, so no result can write into the next run's."""
    from vpsim.gears import GearSchedule
    from vpsim.params import load_parameters

    cyc, p, shared_sched = resolve_inputs("udds", "hofman2011")
    sched = GearSchedule(shared_sched.time_s, shared_sched.gear, shared_sched.source)  # (this test's own)
    heavy = p.with_changes(vehicle={"mass": 1900.0})
    first = inverse.run(cyc, p, schedule=sched, mode="realistic")
    shared = inverse.run(cyc, heavy, schedule=sched, mode="realistic")
    kept = sched._derived["inverse_trajectories"]
    assert set(kept) == {p.driver("1").inverse_a}
    fresh = GearSchedule(sched.time_s.copy(), sched.gear.copy(), sched.source)
    alone = inverse.run(cyc, heavy, schedule=fresh, mode="realistic")
    assert shared.fuel_kg == alone.fuel_kg and shared.fuel_kg != first.fuel_kg
    for key in ("speed_mps", "engine_speed_radps", "throttle_demand_m2"):
        np.testing.assert_array_equal(shared.series[key], alone.series[key])
    with pytest.raises(ValueError, match="read-only"):
        shared.series["speed_mps"][0] = 1.0
    inverse.run(cyc, p, driver="2", schedule=sched, mode="realistic")
    assert set(kept) == {p.driver("1").inverse_a, load_parameters("hofman2011").driver("2").inverse_a}


def test_every_path_calls_the_kernels_with_one_signature():
    """Numba compiles a kernel anew for each argument type, writability included: the uniform grid's kept
    (read-only) trajectory, a non-uniform grid, ``invert`` and the backward method with and without the kept
    interval gears must all reach one compiled version each, the one ``pip install .`` builds (a second
    one compiled `vpsim paper`'s inversion check at its first run: 8 s). In a process of its own, so that no
    other test's calls (a measured map's arrays, say) count."""
    import subprocess
    import sys

    code = """
import numpy as np
from vpsim.cycles import Cycle
from vpsim.gears import GearSchedule
from vpsim.methods import backward, inverse
from vpsim.simulation import resolve_inputs

cyc, p, sched = resolve_inputs("udds", "hofman2011")
inverse.run(cyc, p, schedule=sched, mode="realistic")
t = np.array([0.0, 1.0, 2.0, 3.5, 5.0, 6.0, 8.0, 9.0, 10.0])
gappy = Cycle("gappy", t, np.array([0.0, 1.0, 2.0, 3.0, 3.0, 2.0, 1.0, 0.5, 0.0]))
inverse.run(gappy, p, mode="paper")
inverse.invert(np.array([1.0, 2.0]), np.zeros(2), np.zeros(2), np.array([1, 2]), p, "paper")
backward.run(cyc, p, schedule=sched, mode="realistic")  # the interval gears kept on the schedule
other = GearSchedule(sched.time_s[::2].copy(), sched.gear[::2].copy(), "every other sample")
backward.run(cyc, p, schedule=other, mode="realistic")  # looked up per interval
for k in (inverse.invert_points, inverse.account, inverse.speed_powers, backward.run_kernel):
    print(k.__name__, len(k.signatures))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    counts = dict(line.split() for line in out.stdout.split("\n") if line.strip())
    assert counts == {"invert_points": "1", "account": "1", "speed_powers": "1", "run_kernel": "1"}, counts
