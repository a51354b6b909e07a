"""The compiled kernels (vpsim._kernels) against the NumPy reference they replace."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vpsim import _kernels as kn
from vpsim import maps
from vpsim import physics as ph
from vpsim.cycles import Cycle, load_cycle
from vpsim.gears import default_schedule
from vpsim.methods import backward

RTOL = 1e-12  # the compiled path keeps the reference's results to 1e-12 (the issue asks 1e-9)


def _launch() -> Cycle:
    """0-100 km/h in 5 s: beyond the engine, so the max-torque line cuts (trace miss)."""
    t = np.arange(0.0, 31.0)
    return Cycle("launch", t, np.minimum(t * (100 / 3.6) / 5.0, 100 / 3.6))


def _assert_results_agree(a, b, rtol=RTOL):
    assert a.fuel_kg == pytest.approx(b.fuel_kg, rel=rtol, abs=0)
    assert a.distance_m == pytest.approx(b.distance_m, rel=rtol, abs=0)
    assert a.steps == b.steps
    ta, tb = a.trace_miss, b.trace_miss
    assert ta.seconds == pytest.approx(tb.seconds, rel=rtol, abs=1e-12)
    assert ta.max_torque_shortfall_nm == pytest.approx(tb.max_torque_shortfall_nm, rel=rtol, abs=1e-9)
    assert ta.details["speed_deficit_mps"] == pytest.approx(
        tb.details["speed_deficit_mps"], rel=rtol, abs=1e-12
    )
    ea, eb = a.energy.as_dict(), b.energy.as_dict()
    scale = abs(eb["indicated"])
    for k in ea:
        if k != "relative_residual":
            assert abs(ea[k] - eb[k]) <= rtol * scale, k
    assert set(a.series) == set(b.series)
    for k, x in b.series.items():
        y = np.asarray(a.series[k], dtype=float)
        x = np.asarray(x, dtype=float)
        assert np.array_equal(np.isnan(x), np.isnan(y)), k
        ok = ~np.isnan(x)
        scale_k = max(float(np.max(np.abs(x[ok]), initial=0.0)), 1e-300)
        assert np.all(np.abs(y[ok] - x[ok]) <= rtol * np.maximum(np.abs(x[ok]), 1e-6 * scale_k)), k
    assert a.notes == b.notes


@pytest.mark.parametrize("cycle", ["nedc", "udds", "ftp75", "us06", "wltc3b", "launch"])
@pytest.mark.parametrize("mode", ["paper", "extended"])
@pytest.mark.parametrize("exact", [False, True])
def test_compiled_backward_matches_numpy_reference(params, cycle, mode, exact):
    cyc = _launch() if cycle == "launch" else load_cycle(cycle)
    em = maps.cached_engine_map(params.engine).with_exact(exact)
    compiled = backward.run(cyc, params, engine_map=em, mode=mode)
    reference = backward.run(cyc, params, engine_map=em, mode=mode, compiled=False)
    _assert_results_agree(compiled, reference)
    if cycle == "launch":
        assert compiled.trace_miss.seconds > 0


def test_compiled_backward_without_series(params):
    cyc = load_cycle("udds")
    a = backward.run(cyc, params, keep_series=False)
    b = backward.run(cyc, params, keep_series=False, compiled=False)
    assert a.series == {} and b.series == {}
    assert a.fuel_kg == pytest.approx(b.fuel_kg, rel=RTOL)


def test_other_engine_map_runs_the_reference(params):
    """A map without the generated table (e.g. a measured engine) takes the NumPy path and still works."""

    class Wrapped:
        def __init__(self, em):
            self._em = em
            self.inertia = em.inertia

        def fuel_flow(self, t, w):
            return self._em.fuel_flow(t, w)

        def max_torque(self, w):
            return self._em.max_torque(w)

    em = maps.cached_engine_map(params.engine)
    cyc = load_cycle("nedc")
    r = backward.run(cyc, params, engine_map=Wrapped(em))
    assert r.energy is None
    assert r.fuel_kg == pytest.approx(backward.run(cyc, params).fuel_kg, rel=RTOL)


@settings(max_examples=25, deadline=None)
@given(
    st.lists(st.floats(0.0, 40.0), min_size=3, max_size=60),
    st.lists(st.floats(0.2, 5.0), min_size=60, max_size=60),
    st.sampled_from(["paper", "extended"]),
)
def test_compiled_backward_matches_reference_on_random_cycles(params, speeds, steps, mode):
    speeds = [0.0] + speeds + [0.0]
    t = np.concatenate([[0.0], np.cumsum(steps[: len(speeds) - 1])])
    cyc = Cycle("random", t, np.array(speeds))
    em = maps.cached_engine_map(params.engine)
    schedule = default_schedule(cyc, params, em)
    a = backward.run(cyc, params, engine_map=em, schedule=schedule, mode=mode)
    b = backward.run(cyc, params, engine_map=em, schedule=schedule, mode=mode, compiled=False)
    _assert_results_agree(a, b)


def test_idle_speed_is_the_methods_idle_speed():
    assert kn.IDLE_SPEED == backward.IDLE_SPEED


def test_interp_matches_numpy_interp_including_nodes_and_ends():
    rng = np.random.default_rng(3)
    xp = np.linspace(0.0, 812.5, 813)
    fp = rng.standard_normal(813)
    x = np.concatenate([rng.uniform(-10, 830, 2000), xp, [xp[0], xp[-1], -1e-300, 812.5 + 1e-12]])
    inv = kn._inv_spacing(xp)
    got = np.array([kn._interp(xi, xp, fp, inv) for xi in x])
    np.testing.assert_array_equal(got, np.interp(x, xp, fp))
    # a grid far from uniform still gives numpy's answer (the walk from the guess is exact)
    xq = np.sort(rng.uniform(0, 100, 50)) ** 2
    fq = rng.standard_normal(50)
    inv = kn._inv_spacing(xq)
    x = rng.uniform(-5, 1e4 + 5, 500)
    np.testing.assert_array_equal([kn._interp(xi, xq, fq, inv) for xi in x], np.interp(x, xq, fq))


def test_bilinear_matches_maps_bilinear(params):
    em = maps.cached_engine_map(params.engine)
    rng = np.random.default_rng(4)
    w = np.concatenate([rng.uniform(-20, 900, 3000), em.speed[:50]])
    t = np.concatenate([rng.uniform(-200, 400, 3000), em.torque[:50]])
    inv_x, inv_y = kn._inv_spacing(em.speed), kn._inv_spacing(em.torque)
    got = np.array(
        [kn._bilinear(em.speed, em.torque, em.table, a, b, inv_x, inv_y) for a, b in zip(w, t, strict=True)]
    )
    np.testing.assert_array_equal(got, maps.bilinear(em.speed, em.torque, em.table, w, t))


def test_steady_pressure_and_crank_torque_match_the_fqm(params):
    eng = params.engine
    c = kn.pack_constants(params.vehicle, params.transmission, eng, params.simulation)[0]
    w = np.concatenate([[0.0, 1e-3, 1.0], np.linspace(5, 900, 200)])
    for a_eff in (eng.max_throttle_area, eng.min_throttle_area, 3e-4):
        ss = maps.steady_state(a_eff, w, eng)
        p = np.array([kn.steady_pressure(a_eff, wi, c) for wi in w])
        np.testing.assert_allclose(p, ss.intake_pressure, rtol=1e-13)
        tq = np.array([kn._crank_torque(pi, wi, c) for pi, wi in zip(p, w, strict=True)])
        np.testing.assert_allclose(tq, ss.crank_torque, rtol=1e-10, atol=1e-9)


def test_pack_constants_of_array_parameters_equals_one_set_at_a_time(params):
    bores = np.array([0.08, 0.09, 0.1])
    masses = np.array([1200.0, 1700.0, 2100.0])
    eng = replace(params.engine, bore=bores)
    veh = replace(params.vehicle, mass=masses)
    many = kn.pack_constants(veh, params.transmission, eng, params.simulation)
    assert many.shape == (3, kn.N_CONSTANTS)
    for i in range(3):
        one = kn.pack_constants(
            replace(params.vehicle, mass=float(masses[i])),
            params.transmission,
            replace(params.engine, bore=float(bores[i])),
            params.simulation,
        )[0]
        np.testing.assert_array_equal(many[i], one)
    c = many[1]
    assert c[kn.VD] == ph.displacement(params.engine)
    assert c[kn.Q] == ph._q(params.engine)
