"""The quasi-static maps against the dynamic model they are generated from (paper section 3)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from vpsim.model import engine as en
from vpsim.model import maps
from vpsim.model.record import engine_record


def _dynamic_torque(a_eff, w_e, eng, t_end=10.0):
    """Impose constant (A_eff, w_e) on the dynamic engine model: integrate (9) for 10 s, return T_cr."""
    sol = solve_ivp(
        lambda t, p: [en.manifold_pressure_rate(float(p[0]), a_eff, w_e, engine_record(eng))],
        (0.0, t_end),
        [0.5 * eng.ambient_pressure],
        method="LSODA",
        rtol=1e-11,
        atol=1e-6,
    )
    return float(en.crank_torque(sol.y[0, -1], w_e, engine_record(eng)))


def test_fqm_matches_dynamic_engine_at_steady_state(params):
    """>= 50 grid points: the FQM torque agrees with the 10 s dynamic simulation to < 0.1 % (paper: < 1 %)."""
    eng = params.engine
    a_grid = np.geomspace(2e-5, eng.max_throttle_area, 8)
    w_grid = np.linspace(50.0, 650.0, 8)
    fqm = maps.steady_state(a_grid[:, None], w_grid[None, :], eng)
    assert fqm.converged.all()
    worst = 0.0
    for ia, a in enumerate(a_grid):
        for iw, w in enumerate(w_grid):
            t_dyn = _dynamic_torque(a, w, eng)
            t_fqm = fqm.crank_torque[ia, iw]
            # relative to the torque, or to 1 N m where the line crosses zero
            worst = max(worst, abs(t_fqm - t_dyn) / max(abs(t_dyn), 1.0))
    assert a_grid.size * w_grid.size >= 50
    assert worst < 1e-3, worst


def test_choked_and_subcritical_regions_both_covered(params):
    eng = params.engine
    ss = maps.steady_state(np.array([2e-5, eng.max_throttle_area]), 300.0, eng)
    assert ss.choked.tolist() == [True, False]
    assert ss.iterations[1] <= 10  # the paper's iteration limit


def test_round_trip_fqm_to_bqm(params):
    """(A_eff, w_e) -> FQM -> (T_cr, w_e) -> BQM returns the same p_i and fuel flow (< 1e-6 rel.)."""
    eng = params.engine
    a, w = np.meshgrid(np.geomspace(2e-5, eng.max_throttle_area, 15), np.linspace(50, 650, 15))
    ss = maps.steady_state(a, w, eng)
    p_back = en.intake_pressure_for_torque(ss.crank_torque, w, engine_record(eng))
    f_back = maps.bqm_fuel_flow(ss.crank_torque, w, eng)
    np.testing.assert_allclose(p_back, ss.intake_pressure, rtol=1e-9)
    np.testing.assert_allclose(f_back, ss.fuel_flow, rtol=1e-9)


@settings(max_examples=60, deadline=None)
@given(t=st.floats(-60.0, 190.0), w=st.floats(20.0, 700.0))
def test_bqm_inverts_torque_model(params, t, w):
    """Property: crank_torque(p_i(T, w), w) == T for any torque and speed."""
    eng = params.engine
    c = engine_record(eng)
    p = en.intake_pressure_for_torque(t, w, c)
    assert abs(float(en.crank_torque(p, w, c)) - t) < 1e-9 * max(1.0, abs(t))


@settings(max_examples=60, deadline=None)
@given(pr=st.floats(0.0, 1.2))
def test_psi_is_continuous_and_bounded(params, pr):
    c = engine_record(params.engine)
    crit = en.critical_pressure_ratio(c.specific_heat_ratio)
    choked = float(en.psi(0.0, c))
    val = float(en.psi(pr, c))
    assert 0.0 <= val <= choked + 1e-15
    if pr <= crit:
        assert val == choked
    # continuity at the critical ratio
    assert abs(float(en.psi(crit * (1 + 1e-9), c)) - choked) < 1e-6


def test_torque_monotone_in_throttle_and_max_line_bounds(params):
    eng = params.engine
    tm = maps.torque_map(eng)
    assert np.all(np.diff(tm.torque, axis=0) > 0)  # more throttle, more torque at every speed
    em = maps.cached_engine_map(eng)
    assert np.all(em.max_torque(tm.speed) >= tm.torque.max(axis=0) - 1e-3)  # line tabulated at 1 rad/s
    # the baseline's max-torque line: about 200 N m, about 120 kW: a 2.3 L naturally aspirated engine
    assert 180 < em.max_torque_values.max() < 220
    assert 100e3 < np.max(em.max_torque_values * em.max_torque_speed) < 140e3


def test_fuel_map_table_matches_closed_form(params):
    em = maps.cached_engine_map(params.engine)
    rng = np.random.default_rng(1)
    t = rng.uniform(-50, 200, 5000)
    w = rng.uniform(0, 650, 5000)
    exact = maps.bqm_fuel_flow(t, w, params.engine)
    np.testing.assert_allclose(em.fuel_flow(t, w), exact, atol=1e-5 * np.abs(exact).max())


def test_idle_flow_is_the_models_zero_torque_flow(params):
    """The reconstructed idle flow (1.3e-4 kg/s) is the model's own zero-torque flow near 80 rad/s."""
    f = float(maps.bqm_fuel_flow(0.0, 80.0, params.engine))
    assert f == pytest.approx(params.simulation.idle_fuel_flow, rel=0.02)


def test_figure2_colours_are_distinct_and_figure3_fills_up_to_the_max_torque_line(params):
    import matplotlib.pyplot as plt

    from vpsim.model.maps import cached_engine_map
    from vpsim.plots import plot_fuel_map, plot_torque_lines

    ax, tm = plot_torque_lines(params.engine)
    colours = [tuple(np.round(plt.matplotlib.colors.to_rgba(line.get_color()), 6)) for line in ax.lines[:-1]]
    assert len(colours) == len(tm.a_eff) and len(set(colours)) == len(colours)
    plt.close(ax.figure)
    ax, (w, t, fuel) = plot_fuel_map(params.engine)
    em = cached_engine_map(params.engine)
    assert np.allclose(t[:, -1], em.max_torque(w[:, 0])) and np.isfinite(fuel).all()  # no gap under the line
    plt.close(ax.figure)


@pytest.mark.parametrize("preset", ["hofman2011", "geo_metro_1l", "saturn_1_9l"])
@settings(max_examples=80, deadline=None)
@given(frac=st.floats(0.0, 1.0), below=st.floats(0.0, 2e4))
def test_full_load_screen_is_below_the_generated_line(preset, frac, below):
    """Property: a demand whose intake pressure is at or below ``full_load_screen`` at the line's last node is
    at or below the max-torque line the map generator tabulated (interpolated by numpy, not by the kernels'
    look-up), at any speed up to that node: what lets the backward methods skip reading the line there."""
    from vpsim.params import load_parameters

    eng = load_parameters(preset).engine
    em = maps.cached_engine_map(eng)
    c = engine_record(eng)
    w_line, t_line = em.max_torque_speed, em.max_torque_values
    w_end = float(w_line[-1])
    p_screen = float(en.full_load_screen(w_end, w_end / (w_line.size - 1), c))
    assert 0.9 * eng.ambient_pressure < p_screen < eng.ambient_pressure  # a bound that screens most demands
    w = np.append(np.linspace(0.0, w_end, 20001), frac * w_end)  # (a dense grid: the worst is near the top)
    t = en.crank_torque(np.full(w.size, p_screen - below), w, c)
    assert np.all(t <= np.interp(w, w_line, t_line))


def test_full_load_screen_is_off_where_the_line_is_capped_or_boosted(params):
    """No bound for a power-capped line or a boosted engine (-inf: every demand reads the line)."""
    for changes in ({"rated_power": 40e3}, {"boost_pressure": 1.8 * params.engine.ambient_pressure}):
        c = engine_record(params.with_changes(engine=changes).engine)
        assert en.full_load_screen(600.0, 1.0, c) == -np.inf, changes
