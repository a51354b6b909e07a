"""The P2 hybrid on the backward method, with its energy management: rules, ECMS, dynamic programming.

The cycle is tracked exactly, as by the engine car's backward method: each interval of the piecewise-linear
cycle at its mean speed and constant acceleration, in the gear the schedule gives (the conventional gear rule
of :mod:`vpsim.gears`). At each interval the management chooses the engine's state and torque
(:mod:`vpsim.model.hybrid`); the operating point (:func:`vpsim.model.hybrid.p2_point`) gives fuel, battery
current and every energy term; the state of charge moves on by (B3).

* ``rule`` and ``ecms`` decide interval by interval from what they know then (:func:`causal_kernel`).
* ``dp`` first computes the least fuel-to-go J_k(soc, engine state) backward over a grid of the state of
  charge (:func:`dp_kernel`; linear interpolation between grid points; a terminal cost on any charge below
  the start's, steep enough that the optimum sustains the charge), then drives the cycle forward from the
  true state, choosing at each interval the control that minimises its cost plus the interpolated J_{k+1}
  (:func:`causal_kernel` with the cost-to-go).

The inverse method (:func:`run_inverse`) drives the smoothing driver's trajectory with the same management
and operating point; the forward method calls the same per-step choice (:mod:`vpsim.methods.hev_forward`).
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..errors import VpsimError
from ..model import battery as bt
from ..model import electric as el
from ..model import hybrid as hy
from ..model import tables as tb
from ..model._compile import kernel
from ..model.engine import equation
from ..model.tables import gear_index
from . import _hybrid
from ._hybrid import N_COMMON_SUMS

# rows of the per-interval series
(
    H_T,
    H_V,
    H_A,
    H_GEAR,
    H_W,
    H_TE,
    H_TM,
    H_P,
    H_MDOT,
    H_I,
    H_UOC,
    H_U,
    H_SOC,
    H_BRAKE,
    H_MISS,
    H_ON,
    H_LIM_M,
    H_LIM_B,
    H_TCR,
) = range(19)
N_ROWS = 19
assert H_LIM_B - H_P == 10  # H_P .. H_LIM_B: the rows methods._hybrid.store_point writes
N_SUMS = N_COMMON_SUMS  # the running sums: the energy terms, then those of methods._hybrid
MISS_TOLERANCE_N = 1e-9


@kernel(_nrt=False)
def dp_kernel(
    v, a, dt, ratio, gear, c, e, m, tabs, h, levels, line_speed, line_max, line_min, soc_grid, jcost, packs
):
    """Backward: jcost[k, i, s] the least fuel (kg) from interval k to the end at charge soc_grid[i] with the
    engine in state s (0 off, 1 on) before it. jcost[K] is the terminal cost, filled by the caller; ``packs``
    (grid points x 5) is room for the pack's state at each grid charge."""
    inv_line = tb.inverse_spacing(line_speed)
    n = soc_grid.size
    soc0 = soc_grid[0]
    dsoc = soc_grid[1] - soc_grid[0]
    # the pack's state at each grid charge, once for the whole cycle
    for i in range(n):
        st = el.battery_state(
            soc_grid[i], e, tabs[el.TAB_SOC], tabs[el.TAB_OCV], tabs[el.TAB_R_DIS], tabs[el.TAB_R_CHG]
        )
        for q in range(5):
            packs[i, q] = st[q]
    for k in range(v.size - 1, -1, -1):
        interval = hy.p2_interval(v[k], a[k], ratio[k], gear[k], c, e, m, tabs, h)
        w = interval[1]  # the engine's speed were it to run
        t_low, t_high = hy.engine_lines(w, line_speed, line_max, line_min, inv_line, c)
        runs = interval[5]
        t_off = hy.closed_line(w, line_speed, line_min, inv_line) if h.mild > 0.0 else 0.0
        for i in range(n):
            battery = (packs[i, 0], packs[i, 1], packs[i, 2], packs[i, 3], packs[i, 4])
            best0 = math.inf
            best1 = math.inf
            least_miss = math.inf  # the least trace miss's price among the choices
            for u in range(levels + 2):
                on = 1.0 if u > 0 else 0.0
                if u > 0 and not runs:
                    break
                te = hy.engine_choice_torque(u, levels, t_low, t_high, t_off, interval)
                pt = hy.p2_choice(interval, battery, on, te, c, e, m, tabs, h)
                least_miss = min(least_miss, hy.miss_cost(pt, dt[k], c))
                nxt = soc_grid[i] + bt.soc_rate(pt[8], e.capacity_as, e.coulombic_efficiency) * dt[k]
                s_next = 1 if pt[16] > 0.0 else 0  # the engine turning after the interval
                base = hy.ecms_cost(pt, dt[k], False, 0.0, c, e, h) + hy.cost_to_go(
                    jcost[k + 1], s_next, nxt, soc0, dsoc, n
                )
                c0 = base + (h.engine_start_fuel if s_next == 1 else 0.0)  # from standing: a start
                if c0 < best0:
                    best0 = c0
                if base < best1:
                    best1 = base
                if u > 1 and hy.higher_torques_dominated(pt, battery):  # (the levels rise from u = 2)
                    break
            jcost[k, i, 0] = hy.less_unavoidable_miss(best0, least_miss)
            jcost[k, i, 1] = hy.less_unavoidable_miss(best1, least_miss)


@kernel(_nrt=False)
def causal_kernel(
    time_s,
    speed,
    sched_t,
    sched_gear,
    ratios,
    c,
    e,
    m,
    tabs,
    h,
    ems,
    levels,
    line_speed,
    line_max,
    line_min,
    soc_grid,
    jcost,
    soc_start,
    rows,
    sums,
    exhaustive,
):
    """Drive the cycle with the management ``ems`` (rule, ecms, or dp with the cost-to-go ``jcost``); fill
    ``rows`` and the sums. Returns the final state of charge. ``exhaustive``: the ECMS tries every torque
    level even where a walk finds the same one (:func:`vpsim.model.hybrid.ecms_cheapest_level`; the
    reference the walk is tested against)."""
    inv_line = tb.inverse_spacing(line_speed)
    soc = soc_start
    on = 0.0
    on_time = 0.0
    j = 0
    share = math.nan  # the last walk's engine share of the demand (hybrid.walk_guess): none yet
    walk = hy.running_cost_convex(c, e) and not exhaustive and h.mild == 0.0  # (mild: convexity not shown)
    for k in range(time_s.size - 1):
        dt = time_s[k + 1] - time_s[k]
        v = 0.5 * (speed[k + 1] + speed[k])
        a = (speed[k + 1] - speed[k]) / dt
        g, j = gear_index(time_s, k, sched_t, sched_gear, j)
        ratio = ratios[g]
        # what the interval and the charge fix, once for all the choices
        interval = hy.p2_interval(v, a, ratio, g + 1, c, e, m, tabs, h)
        w = interval[1]  # the engine's speed were it to run
        t_low, t_high = hy.engine_lines(w, line_speed, line_max, line_min, inv_line, c)
        t_off = hy.closed_line(w, line_speed, line_min, inv_line) if h.mild > 0.0 else 0.0
        battery = el.battery_state(
            soc, e, tabs[el.TAB_SOC], tabs[el.TAB_OCV], tabs[el.TAB_R_DIS], tabs[el.TAB_R_CHG]
        )
        if (
            ems == hy.EMS_ECMS
            and walk
            and hy.pack_covers_no_drive(
                interval,
                battery,
                e,
                m,
                tabs[el.TAB_MAP_SPEED],
                tabs[el.TAB_MAP_TORQUE],
                tabs[el.TAB_MAP_LOSS],
            )
        ):
            # the exhaustive search's choice by a walk from the last step's share, where the cost is convex
            pt, share = hy.p2_ecms_walk(
                interval, battery, soc, on, on_time, dt, levels, t_low, t_high, share, c, e, m, tabs, h
            )
        else:
            choice_on, choice_te = hy.p2_choose(
                interval,
                battery,
                soc,
                on,
                on_time,
                dt,
                ems,
                levels,
                t_low,
                t_high,
                t_off,
                c,
                e,
                m,
                tabs,
                h,
                soc_grid,
                jcost,
                k + 1,
            )
            pt = hy.p2_choice(interval, battery, choice_on, choice_te, c, e, m, tabs, h)
        terms = hy.hybrid_powers(pt, v, a, c, e)
        running, missing = _hybrid.book_step(sums, pt, terms, interval[0], dt, ratio, on, c, h)
        on_time = on_time + dt if running > 0.0 else 0.0
        on = running
        store_row(rows, k, 0.5 * (time_s[k + 1] + time_s[k]), v, a, g, pt, running, missing, ratio, soc, c)
        soc += bt.soc_rate(pt[8], e.capacity_as, e.coulombic_efficiency) * dt
    return soc


@equation
def store_row(rows, k, t, v, a, g, pt, running, missing, ratio, soc, c):
    """Row k of the series: time, speed, acceleration, gear g (0-based), the point ``pt``'s machine speed,
    torques, intake pressure (NaN with the engine off), fuel flow, battery current and voltages, the charge
    at the step's start, the brakes, the torque short, the flags."""
    rows[H_T, k] = t
    rows[H_V, k] = v
    rows[H_A, k] = a
    rows[H_GEAR, k] = g + 1.0
    rows[H_W, k] = pt[0]
    rows[H_TE, k] = pt[3]
    rows[H_TM, k] = pt[7]
    _hybrid.store_point(rows, k, H_P, pt, running, missing, ratio, soc, c)
    rows[H_TCR, k] = pt[4]


# --- Python side ------------------------------------------------------------------------------------------


def _inputs(cycle, params, schedule=None):
    from ..gears import schedule_for
    from ..model.maps import cached_engine_map
    from ..model.record import memo

    engine_map = cached_engine_map(params.engine)
    if schedule is None:
        schedule = schedule_for(cycle, params)
    return (engine_map, schedule, *memo(params, "p2_records", _records))


def _records(params):
    """(c, e, m, tables, h, total ratios, DP grid) of a parameter set, built once per set (as the power
    split's inputs): a run on a prepared schedule then spends no time rebuilding them."""
    from ..model.record import kernel_records
    from ..model.record import ratios as total_ratios

    e, m, tabs = el.electric_records(hy.rotor_at_crank(params))
    return (
        kernel_records(params)[0],
        e,
        m,
        tabs.astuple(),
        hy.hybrid_record(params),
        np.asarray(total_ratios(params.transmission), float),
        hy.dp_grid(params),
    )


def run(
    cycle, params, *, ems: str | None = None, mode: str = "realistic", schedule=None, exhaustive: bool = False
):
    """The P2 hybrid of ``params`` on ``cycle`` (backward method) with the management ``ems`` (default
    ``params.hybrid.ems``); a :class:`vpsim.result.Result`. ``schedule``: the gear rule's schedule of this
    cycle and car (:func:`vpsim.gears.default_schedule`) if already at hand (a benchmark's prepared inputs,
    as the engine car's backward method takes them); derived here otherwise. ``exhaustive``: the ECMS tries
    every torque level (the reference its walk is tested against; the same choices)."""
    ems = ems or params.hybrid.ems
    if ems not in hy.EMS_CODES:
        raise VpsimError(f"unknown energy management {ems!r}; expected one of {', '.join(hy.EMS_CODES)}")
    engine_map, schedule, c, e, m, tabs, h, ratios, grid = _inputs(cycle, params, schedule)
    t0 = time.process_time()
    ts, vs = np.asarray(cycle.time_s, float), np.asarray(cycle.speed_mps, float)
    n = ts.size - 1
    soc_start = params.battery.soc_initial
    levels = params.hybrid.torque_levels
    lines = (engine_map.max_torque_speed, engine_map.max_torque_values, engine_map.min_torque_values)
    if ems == "dp":
        dt = np.diff(ts)
        v = 0.5 * (vs[1:] + vs[:-1])
        a = np.diff(vs) / dt
        gear = schedule.gear_at(0.5 * (ts[1:] + ts[:-1])).astype(np.int64)
        ratio = ratios[gear - 1]
        jcost = np.empty((n + 1, grid.size, 2))
        jcost[n] = hy.terminal_cost(params, grid, soc_start)
        dp_kernel(
            v, a, dt, ratio, gear, c, e, m, tabs, h, levels, *lines, grid, jcost, np.empty((grid.size, 5))
        )
    else:
        jcost = np.zeros((1, 2, 2))
    rows = np.empty((N_ROWS, n))
    sums = np.zeros(N_SUMS)
    soc_end = causal_kernel(
        ts,
        vs,
        schedule.time_s,
        schedule.gear,
        ratios,
        c,
        e,
        m,
        tabs,
        h,
        hy.EMS_CODES[ems],
        levels,
        *lines,
        grid,
        jcost,
        soc_start,
        rows,
        sums,
        exhaustive,
    )
    cpu = time.process_time() - t0
    return _result(cycle, params, ems, mode, rows, sums, soc_start, soc_end, n, cpu)


_COLUMNS = {
    "speed_mps": H_V,
    "accel_mps2": H_A,
    "gear": H_GEAR,
    "machine_speed_radps": H_W,
    "engine_torque_nm": H_TE,
    "crank_torque_nm": H_TCR,
    "machine_torque_nm": H_TM,
    "intake_pressure_pa": H_P,
    "fuel_flow_kgps": H_MDOT,
    "battery_current_a": H_I,
    "open_circuit_voltage_v": H_UOC,
    "battery_voltage_v": H_U,
    "brake_force_n": H_BRAKE,
    "torque_shortfall_nm": H_MISS,
    "engine_on": H_ON,
    "machine_at_limit": H_LIM_M,
    "battery_at_limit": H_LIM_B,
}


def _result(cycle, params, ems, mode, rows, sums, soc_start, soc_end, n, cpu):
    series = _hybrid.series(cycle, rows, _COLUMNS, H_SOC, soc_end, n)
    # the engine turns with the input shaft while it runs, and stands still while its clutch is open (the
    # mild hybrid's row is the crank's speed, its machine's the belt's ratio times it)
    series["engine_speed_radps"] = np.where(series["engine_on"], series["machine_speed_radps"], 0.0)
    if params.powertrain.type == "mhev":
        series["machine_speed_radps"] = series["machine_speed_radps"] * params.mild.belt_ratio
    return _hybrid.result(cycle, params, ems, mode, series, sums, soc_start, soc_end, n, cpu)


def run_inverse(
    cycle,
    params,
    *,
    driver: str = "2",
    ems: str | None = None,
    mode: str = "realistic",
    exhaustive: bool = False,
):
    """The P2 hybrid on the inverse method: the smoothing driver's trajectory v_d(t) (34)-(35), sampled on
    :func:`vpsim.drivers.smoothing.inverse_grid`, driven by the same management and operating point as the
    backward method (each grid interval at its mean speed and constant acceleration, to second order in the
    step the smoothed trajectory's). The engine's fuel depends on its intake pressure and speed only, which
    the torque fixes through the BQM (19); the manifold's dynamics set the throttle that holds that pressure,
    which this method does not compute (so it does not check the throttle's range, as the engine car's
    inverse method does). Gears follow the cycle's schedule."""
    ems = ems or params.hybrid.ems
    trajectory = _hybrid.inverse_trajectory(cycle, params, driver, ems)
    ts, _, grid, smooth = trajectory
    engine_map, schedule, c, e, m, tabs, h, ratios, soc_grid = _inputs(cycle, params)
    t0 = time.process_time()
    n = grid.size - 1
    rows = np.empty((N_ROWS, n))
    sums = np.zeros(N_SUMS)
    lines = (engine_map.max_torque_speed, engine_map.max_torque_values, engine_map.min_torque_values)
    soc_end = causal_kernel(
        grid,
        smooth,
        schedule.time_s,
        schedule.gear,
        ratios,
        c,
        e,
        m,
        tabs,
        h,
        hy.EMS_CODES[ems],
        params.hybrid.torque_levels,
        *lines,
        soc_grid,
        np.zeros((1, 2, 2)),
        params.battery.soc_initial,
        rows,
        sums,
        exhaustive,
    )
    cpu = time.process_time() - t0

    def result_of(samples, rows_s):
        soc_0 = params.battery.soc_initial
        return _result(samples, params, ems, mode, rows_s, sums, soc_0, soc_end, ts.size - 1, cpu)

    return _hybrid.inverse_result(result_of, cycle, trajectory, rows, driver)
