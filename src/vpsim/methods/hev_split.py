"""The power-split hybrid on the backward and inverse methods, with its energy management: rules, ECMS,
dynamic programming.

The cycle is tracked exactly, as by the P2 hybrid's backward method (:mod:`vpsim.methods.hev`): each interval
of the piecewise-linear cycle at its mean speed and constant acceleration. At each interval the management
chooses whether the engine runs and its power; the engine turns at the speed of least fuel for that power
within the gear set's limits, and the operating point (:func:`vpsim.model.split.split_choice`) gives fuel,
both machines' torques, the battery's current and every energy term; the state of charge moves on by (B3).
The management's parts are the P2's (:mod:`vpsim.model.hybrid`: the rule's on/off decision, the ECMS's
cost and equivalence factor, the DP's cost-to-go, grid and terminal cost, the J1711 fuel); only the choice
(engine power instead of torque) and the point are the layout's.

* ``rule`` and ``ecms`` decide interval by interval from what they know then (:func:`causal_kernel`).
* ``dp`` computes the least fuel-to-go J_k(soc, engine state) backward over a grid of the state of charge
  (:func:`dp_kernel`), then drives the cycle from the true state with it (:func:`causal_kernel`).

The inverse method (:func:`run_inverse`) drives the smoothing driver's trajectory with the same management
and point. The forward method calls the same per-step choice (:mod:`vpsim.methods.hev_forward`).
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..errors import VpsimError
from ..model import battery as bt
from ..model import electric as el
from ..model import hybrid as hy
from ..model import split as sp
from ..model._compile import kernel
from ..model.engine import equation
from . import _hybrid
from ._hybrid import N_COMMON_SUMS

# rows of the per-interval series
(
    R_T,
    R_V,
    R_A,
    R_WC,
    R_WS,
    R_WM,
    R_TE,
    R_TG,
    R_TM,
    R_P,
    R_MDOT,
    R_I,
    R_UOC,
    R_U,
    R_SOC,
    R_BRAKE,
    R_MISS,
    R_ON,
    R_LIM_M,
    R_LIM_B,
    R_PG,
    R_PM,
) = range(22)
N_ROWS = 22
assert R_LIM_B - R_P == 10  # R_P .. R_LIM_B: the rows methods._hybrid.store_point writes
# the running sums: the energy terms, those of methods._hybrid, then this layout's own
S_NONE_S = N_COMMON_SUMS  # seconds with no engine choice the gear set can take
N_SUMS = N_COMMON_SUMS + 1


@kernel(_nrt=False)
def dp_kernel(v, a, dt, ratio, c, e, m, g, s, tabs, h, levels, lines, best, cap, soc_grid, jcost, packs):
    """Backward: jcost[k, i, q] the least fuel (kg) from interval k to the end at charge soc_grid[i] with the
    engine in state q (0 off, 1 on) before it. jcost[K] is the terminal cost, filled by the caller; ``packs``
    (grid points x 5) is room for the pack's state at each grid charge. ``lines``: the engine's full-load
    line (speeds, torques); ``best``: the system operating line
    (powers, ring speeds, engine speeds; :func:`vpsim.model.split.system_line`); ``cap``: its full-load
    power's running maximum (speeds, powers)."""
    eng, opt, inv_cap = sp.line_tables(lines, best, cap)
    n = soc_grid.size
    soc0 = soc_grid[0]
    dsoc = soc_grid[1] - soc_grid[0]
    for i in range(n):
        st = el.battery_state(
            soc_grid[i], e, tabs[el.TAB_SOC], tabs[el.TAB_OCV], tabs[el.TAB_R_DIS], tabs[el.TAB_R_CHG]
        )
        for q in range(5):
            packs[i, q] = st[q]
    for k in range(v.size - 1, -1, -1):
        interval = sp.split_interval(v[k], a[k], ratio[k], c, e, m, g, s, tabs)
        runs = interval[9] <= interval[10]
        p_high = sp.engine_power_limit(interval[10], cap[0], cap[1], inv_cap) if runs else 0.0
        p_follow = sp.demand_power(interval, e, p_high)
        for i in range(n):
            battery = (packs[i, 0], packs[i, 1], packs[i, 2], packs[i, 3], packs[i, 4])
            best0 = math.inf
            best1 = math.inf
            fallback = math.inf
            fallback_miss = 0.0
            least_miss = math.inf  # the least trace miss's price among the feasible choices
            for u in range(levels + 2):
                if u > 0 and not runs:
                    break
                on = 1.0 if u > 0 else 0.0
                p_e = sp.engine_power_choice(u, levels, p_follow, p_high)
                pt = sp.split_choice(interval, battery, on, p_e, c, e, m, g, s, tabs, eng, opt)
                nxt = soc_grid[i] + bt.soc_rate(pt[8], e.capacity_as, e.coulombic_efficiency) * dt[k]
                base = hy.ecms_cost(pt, dt[k], False, 0.0, c, e, h) + hy.cost_to_go(
                    jcost[k + 1], 1 if u > 0 else 0, nxt, soc0, dsoc, n
                )
                if pt[sp.P_FEASIBLE] <= 0.0:
                    if u == 0:
                        fallback = base  # what the causal kernel drives if nothing is feasible
                        fallback_miss = hy.miss_cost(pt, dt[k], c)
                    if u > 1:  # levels rise: MG1 holds, and the pack takes, no more of a larger power either
                        break
                    continue
                least_miss = min(least_miss, hy.miss_cost(pt, dt[k], c))
                c0 = base + (h.engine_start_fuel if u > 0 else 0.0)  # from off: a start
                best0 = min(best0, c0)
                best1 = min(best1, base)
                if u > 1 and sp.higher_powers_dominated(pt, battery):
                    break
            if best1 < math.inf:
                jcost[k, i, 0] = hy.less_unavoidable_miss(best0, least_miss)
                jcost[k, i, 1] = hy.less_unavoidable_miss(best1, least_miss)
            else:
                jcost[k, i, 0] = hy.less_unavoidable_miss(fallback, fallback_miss)
                jcost[k, i, 1] = jcost[k, i, 0]


@kernel(_nrt=False)
def causal_kernel(
    time_s,
    speed,
    ratio,
    c,
    e,
    m,
    g,
    s,
    tabs,
    h,
    ems,
    levels,
    lines,
    best,
    cap,
    soc_grid,
    jcost,
    soc0,
    rows,
    sums,
):
    """Drive the cycle with the management ``ems`` (rule, ecms, or dp with the cost-to-go ``jcost``); fill
    ``rows`` and the sums. Returns the final state of charge."""
    eng, opt, inv_cap = sp.line_tables(lines, best, cap)
    soc = soc0
    on = 0.0
    on_time = 0.0
    for k in range(time_s.size - 1):
        dt = time_s[k + 1] - time_s[k]
        v = 0.5 * (speed[k + 1] + speed[k])
        a = (speed[k + 1] - speed[k]) / dt
        interval = sp.split_interval(v, a, ratio, c, e, m, g, s, tabs)
        runs = interval[9] <= interval[10]
        p_high = sp.engine_power_limit(interval[10], cap[0], cap[1], inv_cap) if runs else 0.0
        p_follow = sp.demand_power(interval, e, p_high)
        battery = el.battery_state(
            soc, e, tabs[el.TAB_SOC], tabs[el.TAB_OCV], tabs[el.TAB_R_DIS], tabs[el.TAB_R_CHG]
        )
        choice_on, choice_p, found = sp.split_choose(
            interval,
            battery,
            soc,
            on,
            on_time,
            dt,
            ems,
            levels,
            runs,
            p_follow,
            p_high,
            c,
            e,
            m,
            g,
            s,
            tabs,
            h,
            eng,
            opt,
            soc_grid,
            jcost,
            k + 1,
        )
        pt = sp.split_choice(interval, battery, choice_on, choice_p, c, e, m, g, s, tabs, eng, opt)
        if not found:  # no choice within the gear set's limits: the engine off, counted
            sums[S_NONE_S] += dt
        terms = sp.split_powers(pt, v, a, c, e, s)
        running, missing = _hybrid.book_step(sums, pt, terms, interval[0], dt, ratio, on, c, h)
        on_time = on_time + dt if running > 0.0 else 0.0
        on = running
        store_row(rows, k, 0.5 * (time_s[k + 1] + time_s[k]), v, a, pt, running, missing, ratio, soc, c)
        soc += bt.soc_rate(pt[8], e.capacity_as, e.coulombic_efficiency) * dt
    return soc


@equation
def store_row(rows, k, t, v, a, pt, running, missing, ratio, soc, c):
    """Row k of the series: time, speed, acceleration, the point ``pt``'s speeds, torques, intake pressure
    (NaN with the engine off), fuel flow, battery current and voltages, the charge at the step's start, the
    brakes, the torque short, the flags, the machines' powers."""
    rows[R_T, k] = t
    rows[R_V, k] = v
    rows[R_A, k] = a
    rows[R_WC, k] = pt[sp.P_WC]
    rows[R_WS, k] = pt[sp.P_WS]
    rows[R_WM, k] = pt[0]
    rows[R_TE, k] = pt[3]
    rows[R_TG, k] = pt[sp.P_TG]
    rows[R_TM, k] = pt[7]
    _hybrid.store_point(rows, k, R_P, pt, running, missing, ratio, soc, c)
    rows[R_PG, k] = pt[sp.P_PG]
    rows[R_PM, k] = pt[11]


# --- Python side ------------------------------------------------------------------------------------------


def _inputs(params):
    """The records and tables of a parameter set (built once per set)."""
    from ..model.record import memo

    return memo(params, "split_inputs", _build_inputs)


def _build_inputs(params):
    from ..model.record import kernel_records
    from ..model.record import ratios as total_ratios

    c = kernel_records(params)[0]
    e, m, tabs = el.electric_records(params)
    g, s = sp.generator_record(params), sp.split_record(params)
    lines, best, cap = sp.operating_lines(params.engine, params.machine, params.split)
    return dict(
        c=c,
        e=e,
        m=m,
        g=g,
        s=s,
        tabs=tabs.astuple(),
        h=hy.hybrid_record(params),
        ratio=float(total_ratios(params.transmission)[0]),
        lines=lines,
        best=best,
        cap=cap,
    )


def _check_ems(ems, params):
    ems = ems or params.hybrid.ems
    if ems not in hy.EMS_CODES:
        raise VpsimError(f"unknown energy management {ems!r}; expected one of {', '.join(hy.EMS_CODES)}")
    return ems


def _drive(ts, vs, params, ems, jcost, x):
    """The causal kernel over samples (ts, vs): (rows, sums, final charge)."""
    n = ts.size - 1
    rows = np.empty((N_ROWS, n))
    sums = np.zeros(N_SUMS)
    soc_end = causal_kernel(
        ts,
        vs,
        x["ratio"],
        x["c"],
        x["e"],
        x["m"],
        x["g"],
        x["s"],
        x["tabs"],
        x["h"],
        hy.EMS_CODES[ems],
        params.hybrid.torque_levels,
        x["lines"],
        x["best"],
        x["cap"],
        hy.dp_grid(params),
        jcost,
        params.battery.soc_initial,
        rows,
        sums,
    )
    return rows, sums, soc_end


def run(cycle, params, *, ems: str | None = None, mode: str = "realistic"):
    """The power-split hybrid of ``params`` on ``cycle`` (backward method) with the management ``ems``
    (default ``params.hybrid.ems``); a :class:`vpsim.result.Result`."""
    ems = _check_ems(ems, params)
    x = _inputs(params)
    t0 = time.process_time()
    ts, vs = np.asarray(cycle.time_s, float), np.asarray(cycle.speed_mps, float)
    n = ts.size - 1
    soc_start = params.battery.soc_initial
    jcost = np.zeros((1, 2, 2))
    if ems == "dp":
        grid = hy.dp_grid(params)
        dt = np.diff(ts)
        jcost = np.empty((n + 1, grid.size, 2))
        jcost[n] = hy.terminal_cost(params, grid, soc_start)
        dp_kernel(
            0.5 * (vs[1:] + vs[:-1]),
            np.diff(vs) / dt,
            dt,
            np.full(n, x["ratio"]),
            x["c"],
            x["e"],
            x["m"],
            x["g"],
            x["s"],
            x["tabs"],
            x["h"],
            params.hybrid.torque_levels,
            x["lines"],
            x["best"],
            x["cap"],
            grid,
            jcost,
            np.empty((grid.size, 5)),
        )
    rows, sums, soc_end = _drive(ts, vs, params, ems, jcost, x)
    cpu = time.process_time() - t0
    return _result(cycle, params, ems, mode, rows, sums, soc_start, soc_end, n, cpu)


_COLUMNS = {
    "speed_mps": R_V,
    "accel_mps2": R_A,
    "engine_speed_radps": R_WC,
    "generator_speed_radps": R_WS,
    "machine_speed_radps": R_WM,
    "engine_torque_nm": R_TE,
    "generator_torque_nm": R_TG,
    "machine_torque_nm": R_TM,
    "intake_pressure_pa": R_P,
    "fuel_flow_kgps": R_MDOT,
    "battery_current_a": R_I,
    "open_circuit_voltage_v": R_UOC,
    "battery_voltage_v": R_U,
    "brake_force_n": R_BRAKE,
    "torque_shortfall_nm": R_MISS,
    "engine_on": R_ON,
    "machine_at_limit": R_LIM_M,
    "battery_at_limit": R_LIM_B,
    "generator_power_w": R_PG,
    "machine_power_w": R_PM,
}


def _result(cycle, params, ems, mode, rows, sums, soc_start, soc_end, n, cpu):
    series = _hybrid.series(cycle, rows, _COLUMNS, R_SOC, soc_end, n)
    details = {"no_choice_within_gear_set_s": round(float(sums[S_NONE_S]), 6)}
    return _hybrid.result(cycle, params, ems, mode, series, sums, soc_start, soc_end, n, cpu, details)


def run_inverse(cycle, params, *, driver: str = "2", ems: str | None = None, mode: str = "realistic"):
    """The power-split hybrid on the inverse method: the smoothing driver's trajectory v_d(t) (34)-(35),
    sampled on :func:`vpsim.drivers.smoothing.inverse_grid`, driven by the same management and operating
    point as the backward method (as the P2's inverse method, :func:`vpsim.methods.hev.run_inverse`)."""
    ems = _check_ems(ems, params)
    trajectory = _hybrid.inverse_trajectory(cycle, params, driver, ems)
    ts, _, grid, smooth = trajectory
    x = _inputs(params)
    t0 = time.process_time()
    rows, sums, soc_end = _drive(grid, smooth, params, ems, np.zeros((1, 2, 2)), x)
    cpu = time.process_time() - t0

    def result_of(samples, rows_s):
        soc_0 = params.battery.soc_initial
        return _result(samples, params, ems, mode, rows_s, sums, soc_0, soc_end, ts.size - 1, cpu)

    return _hybrid.inverse_result(result_of, cycle, trajectory, rows, driver)
