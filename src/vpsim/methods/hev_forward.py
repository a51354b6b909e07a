"""The hybrids on the forward method: a driver and a causal energy management drive the car, whose speed is
integrated from the force its powertrain delivers (what hardware-in-the-loop runs).

Time advances on a grid that steps on every cycle sample and at most ``electric.forward_max_step`` apart
(:func:`step_grid`). At each step, from what is known at its start:

* the **driver** (the battery-electric car's PI driver: gains ``electric.forward_kp``, ``forward_ki``, the
  law :func:`vpsim.drivers.pi.pi_law` with back-calculation anti-windup, tracking time half the integral
  time) turns the speed error e = v_cycle(t) - v into an acceleration command u (a wheel force m u + road
  load), added to the trace's own acceleration over the step, (v_cycle(t + dt) - v_cycle(t)) / dt: the
  driver reads the trace over the step ahead, as a test driver reads the driver's aid (:func:`driver_command`;
  on the trace and within what the powertrain gives, the car stays on it to rounding); it holds the car at
  rest while the cycle stands over the step, and the car does not roll back;
* the **energy management** (the backward method's own per-step choice, :func:`vpsim.model.hybrid.p2_choose`
  or :func:`vpsim.model.split.split_choose`, rule or ECMS; the P2's ECMS found, as on the backward method,
  by a walk from the last step's engine share, :func:`vpsim.model.hybrid.p2_ecms_walk`, where its cost is
  convex) splits that demand between the engine and the
  machines, with the engine's state, its running time and the state of charge it has at that moment; the
  ECMS prices a choice over the cycle's sample period, as on the backward method (priced over the 0.25 s
  step, a start's fuel outweighs the running cost fourfold and UDDS came out 5 % higher);
* the **car** is held at constant acceleration over the step (the controller's zero-order hold). The
  operating point (:func:`vpsim.model.hybrid.p2_choice`, :func:`vpsim.model.split.split_choice`) at the
  step's mean speed gives the wheel force; where the powertrain falls short of the command, the
  acceleration is the one at which the delivered force balances the demand m a + road load (a secant on
  the shortfall, :func:`vpsim.model.hybrid.delivered_acceleration` its first step), and the driver's
  integral is told so (anti-windup). Speed, the driver's integral and the state of charge (B3) move on.

So the speed is v_{k+1} = v_k + a dt and the operating point is taken at (v_k + v_{k+1}) / 2: the vehicle's
kinetic energy booked, sum m a v dt, is exactly 1/2 m (v_end^2 - v_0^2), the energy the driver's speed error
leaves in the car at the end. Starts are counted and cost their fuel, and every energy term is booked, as in
the backward method (:func:`vpsim.methods._hybrid.book_step`), so the balance closes to rounding. Gears (P2)
follow the cycle's schedule in time, as the inverse method's. ``dp`` needs the whole cycle: backward only.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ..drivers.pi import pi_law
from ..errors import VpsimError
from ..model import battery as bt
from ..model import electric as el
from ..model import hybrid as hy
from ..model import split as sp
from ..model import tables as tb
from ..model._compile import kernel
from ..model.engine import equation
from ..model.tables import gear_index
from . import _hybrid, hev, hev_split

SECANT_STEPS = 8  # at most, for the acceleration the powertrain delivers where it falls short
BALANCE_N = 1e-6  # N: the delivered force balances the demand to within this
# the forward run's own figures, after the layout's sums
F_LIMITED_S, F_MAX_ERROR, F_MAX_SHORT = 0, 1, 2


@equation
def driven_acceleration(u, v, v_ref, dt):
    """The acceleration the driver's command u gives the car over a step dt from speed v: no rolling back
    (the brakes stop it at the step's end at most), and held at rest while the cycle stands."""
    if v <= 0.0 and v_ref <= 0.0:
        return 0.0
    return no_rollback(u, v, dt)


@equation
def no_rollback(a, v, dt):
    """An acceleration over a step dt from speed v that does not take the car backwards."""
    return max(a, -v / dt)


@equation
def driver_command(err, z, ff, drv):
    """The driver's acceleration command over a step: the trace's own acceleration over it, ``ff`` (the driver
    reads the trace ahead), plus the PI law on the speed error, the sum within the command's range."""
    kp, ki, u_lo, u_hi, aw = drv
    return ff + pi_law(err, z, kp, ki, u_lo - ff, u_hi - ff, aw)[0]


@equation
def driver_step(err, z, a, u, ff, drv, dt):
    """The driver's integral after a step: the PI law's rate with the delivered acceleration a as the limit
    its command met (back-calculation anti-windup, :func:`vpsim.drivers.pi.pi_law`); ``ff`` as in
    :func:`driver_command`."""
    kp, ki, u_lo, u_hi, aw = drv
    lo, hi = u_lo - ff, u_hi - ff
    if a < u:
        hi = a - ff
    elif a > u:
        lo = a - ff
    return z + dt * pi_law(err, z, kp, ki, lo, hi, aw)[1]


@equation
def secant(a0, g0, a1, g1):
    """The next acceleration of the secant on the force balance g(a) = demand - delivered."""
    if g1 == g0:
        return a1
    return a1 - g1 * (a1 - a0) / (g1 - g0)


@kernel(_nrt=False)
def p2_kernel(
    grid,
    v_ref,
    period,
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
    drv,
    rows,
    speeds,
    sums,
    extra,
    exhaustive,
):
    """The P2 forward: fill ``rows`` (one per step), ``speeds`` (at the grid's points), the sums; returns the
    final state of charge. ``exhaustive``: the ECMS tries every torque level even where a walk finds the same
    one (as the backward method's :func:`vpsim.methods.hev.causal_kernel`)."""
    inv_line = tb.inverse_spacing(line_speed)
    v, z, soc, on, on_time, j = v_ref[0], 0.0, soc_start, 0.0, 0.0, 0
    share = math.nan  # the last walk's engine share of the demand (hybrid.walk_guess): none yet
    walk = hy.running_cost_convex(c, e) and not exhaustive and h.mild == 0.0  # as the backward method's
    speeds[0] = v
    for k in range(grid.size - 1):
        dt = grid[k + 1] - grid[k]
        err = v_ref[k] - v
        ff = (v_ref[k + 1] - v_ref[k]) / dt
        u = driver_command(err, z, ff, drv)
        a = driven_acceleration(u, v, max(v_ref[k], v_ref[k + 1]), dt)
        g, j = gear_index(grid, k, sched_t, sched_gear, j)
        ratio = ratios[g]
        battery = el.battery_state(
            soc, e, tabs[el.TAB_SOC], tabs[el.TAB_OCV], tabs[el.TAB_R_DIS], tabs[el.TAB_R_CHG]
        )
        vm = v + 0.5 * a * dt
        interval = hy.p2_interval(vm, a, ratio, g + 1, c, e, m, tabs, h)
        w = interval[1]  # the engine's speed were it to run
        t_low, t_high = hy.engine_lines(w, line_speed, line_max, line_min, inv_line, c)
        t_off = hy.closed_line(w, line_speed, line_min, inv_line) if h.mild > 0.0 else 0.0
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
            # (as the backward method); the choice (engine on, its torque) is the point's
            pt, share = hy.p2_ecms_walk(
                interval, battery, soc, on, on_time, period[k], levels, t_low, t_high, share, c, e, m, tabs, h
            )
            on_c, te = pt[16], pt[3]
        else:
            on_c, te = hy.p2_choose(
                interval, battery, soc, on, on_time, period[k], ems, levels, t_low, t_high, t_off, c, e, m,
                tabs, h, soc_grid, jcost, 0,
            )  # fmt: skip
            pt = hy.p2_choice(interval, battery, on_c, te, c, e, m, tabs, h)
        if pt[13] > hy.MISS_TOLERANCE_N:  # the powertrain falls short: the acceleration it delivers
            extra[F_LIMITED_S] += dt
            extra[F_MAX_SHORT] = max(extra[F_MAX_SHORT], el.shaft_torque(pt[13], ratio, c))
            a0, g0 = a, pt[13]
            a = no_rollback(hy.delivered_acceleration(a, pt[13], c), v, dt)
            for _ in range(SECANT_STEPS):
                vm = v + 0.5 * a * dt
                interval = hy.p2_interval(vm, a, ratio, g + 1, c, e, m, tabs, h)
                pt = hy.p2_choice(interval, battery, on_c, te, c, e, m, tabs, h)
                g1 = pt[13] - pt[12]
                if abs(g1) <= BALANCE_N:
                    break
                a0, g0, a = a, g1, no_rollback(secant(a0, g0, a, g1), v, dt)
        terms = hy.hybrid_powers(pt, vm, a, c, e)
        running, missing = _hybrid.book_step(sums, pt, terms, interval[0], dt, ratio, on, c, h)
        on_time = on_time + dt if running > 0.0 else 0.0
        on = running
        hev.store_row(rows, k, grid[k], v, a, g, pt, running, missing, ratio, soc, c)
        z = driver_step(err, z, a, u, ff, drv, dt)
        soc += bt.soc_rate(pt[8], e.capacity_as, e.coulombic_efficiency) * dt
        v = max(v + a * dt, 0.0)
        speeds[k + 1] = v
        extra[F_MAX_ERROR] = max(extra[F_MAX_ERROR], abs(v_ref[k + 1] - v))
    return soc


@kernel(_nrt=False)
def split_kernel(
    grid,
    v_ref,
    period,
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
    soc_start,
    drv,
    rows,
    speeds,
    sums,
    extra,
):
    """The power-split forward: as :func:`p2_kernel`, on the power split's choice and point."""
    eng, opt, inv_cap = sp.line_tables(lines, best, cap)
    v, z, soc, on, on_time = v_ref[0], 0.0, soc_start, 0.0, 0.0
    speeds[0] = v
    for k in range(grid.size - 1):
        dt = grid[k + 1] - grid[k]
        err = v_ref[k] - v
        ff = (v_ref[k + 1] - v_ref[k]) / dt
        u = driver_command(err, z, ff, drv)
        a = driven_acceleration(u, v, max(v_ref[k], v_ref[k + 1]), dt)
        battery = el.battery_state(
            soc, e, tabs[el.TAB_SOC], tabs[el.TAB_OCV], tabs[el.TAB_R_DIS], tabs[el.TAB_R_CHG]
        )
        vm = v + 0.5 * a * dt
        interval = sp.split_interval(vm, a, ratio, c, e, m, g, s, tabs)
        runs = interval[9] <= interval[10]
        p_high = sp.engine_power_limit(interval[10], cap[0], cap[1], inv_cap) if runs else 0.0
        p_follow = sp.demand_power(interval, e, p_high)
        on_c, p_e, found = sp.split_choose(
            interval, battery, soc, on, on_time, period[k], ems, levels, runs, p_follow, p_high, c, e, m, g,
            s, tabs, h, eng, opt, soc_grid, jcost, 0,
        )  # fmt: skip
        pt = sp.split_choice(interval, battery, on_c, p_e, c, e, m, g, s, tabs, eng, opt)
        if pt[13] > hy.MISS_TOLERANCE_N:  # the powertrain falls short: the acceleration it delivers
            extra[F_LIMITED_S] += dt
            extra[F_MAX_SHORT] = max(extra[F_MAX_SHORT], el.shaft_torque(pt[13], ratio, c))
            a0, g0 = a, pt[13]
            a = no_rollback(hy.delivered_acceleration(a, pt[13], c), v, dt)
            for _ in range(SECANT_STEPS):
                vm = v + 0.5 * a * dt
                interval = sp.split_interval(vm, a, ratio, c, e, m, g, s, tabs)
                pt = sp.split_choice(interval, battery, on_c, p_e, c, e, m, g, s, tabs, eng, opt)
                g1 = pt[13] - pt[12]
                if abs(g1) <= BALANCE_N:
                    break
                a0, g0, a = a, g1, no_rollback(secant(a0, g0, a, g1), v, dt)
        if not found:  # no choice within the gear set's limits: the engine off, counted
            sums[hev_split.S_NONE_S] += dt
        terms = sp.split_powers(pt, vm, a, c, e, s)
        running, missing = _hybrid.book_step(sums, pt, terms, interval[0], dt, ratio, on, c, h)
        on_time = on_time + dt if running > 0.0 else 0.0
        on = running
        hev_split.store_row(rows, k, grid[k], v, a, pt, running, missing, ratio, soc, c)
        z = driver_step(err, z, a, u, ff, drv, dt)
        soc += bt.soc_rate(pt[8], e.capacity_as, e.coulombic_efficiency) * dt
        v = max(v + a * dt, 0.0)
        speeds[k + 1] = v
        extra[F_MAX_ERROR] = max(extra[F_MAX_ERROR], abs(v_ref[k + 1] - v))
    return soc


# --- Python side ------------------------------------------------------------------------------------------


def driver_record(params) -> tuple[float, float, float, float, float]:
    """(K_p, K_i, command low, command high, 1 / T_t) of the forward driver: the battery-electric car's gains
    (``electric.forward_kp``, ``forward_ki``, per unit mass), a command range of +-1 g (the pedal's full
    range, as the engine car's driver), tracking time T_t half the integral time K_p / K_i. Refused (one line)
    where the driver, sampled every step, would be unstable (:func:`sampled_loop_radius`)."""
    ep = params.electric
    radius = sampled_loop_radius(ep.forward_kp, ep.forward_ki, ep.forward_max_step)
    if not radius < 1.0:
        raise VpsimError(
            f"electric.forward_kp = {ep.forward_kp:g} 1/s and forward_ki = {ep.forward_ki:g} 1/s^2 with "
            f"forward_max_step = {ep.forward_max_step:g} s: the hybrid's forward driver, deciding once a "
            f"step, is unstable (its loop's largest |eigenvalue| {radius:.3g} >= 1); lower forward_max_step "
            "or the gains"
        )
    g = float(params.vehicle.gravity)
    return (
        float(ep.forward_kp),
        float(ep.forward_ki),
        -g,
        g,
        2.0 * float(ep.forward_ki) / float(ep.forward_kp),
    )


def sampled_loop_radius(kp: float, ki: float, h: float) -> float:
    """The largest |eigenvalue| of the driver's speed loop sampled every h (the car an integrator of the
    command held over the step, the PI's integral moved on by Euler): e' = (1 - kp h) e - h z,
    z' = z + ki h e. Below 1 the loop settles (0.5, a double root, at the defaults 4 1/s, 4 1/s^2, 0.25 s)."""
    a = np.array([[1.0 - kp * h, -h], [ki * h, 1.0]])
    return float(np.max(np.abs(np.linalg.eigvals(a))))


def step_grid(time_s, max_step: float) -> np.ndarray:
    """The forward method's steps: the cycle's samples, each interval split into equal parts at most
    ``max_step`` long (the points of :func:`vpsim.drivers.smoothing.inverse_grid`, to rounding, without its
    Python loop over the intervals: a tenth of the run's time on UDDS)."""
    dt = np.diff(time_s)
    parts = np.maximum(1, np.ceil(dt / max_step - 1e-12).astype(np.int64))
    start = np.repeat(np.arange(dt.size), parts)  # the interval each point lies in
    j = np.arange(start.size) - np.repeat(np.cumsum(parts) - parts, parts)  # its place within the interval
    return np.append(time_s[start] + dt[start] * (j / parts[start]), time_s[-1])


def _check_ems(ems, params):
    ems = ems or params.hybrid.ems
    if ems == "dp":
        raise VpsimError(
            "the dynamic programming management runs on the backward method only (a known cycle); "
            "the forward method takes --ems rule or ecms"
        )
    if ems not in hy.EMS_CODES:
        raise VpsimError(f"unknown energy management {ems!r}; expected rule or ecms on the forward method")
    return ems


def run(
    cycle, params, *, ems: str | None = None, mode: str = "realistic", schedule=None, exhaustive: bool = False
):
    """The hybrid of ``params`` (P2 or power split) on ``cycle`` by the forward method with the management
    ``ems`` (rule or ecms; default ``params.hybrid.ems``); a :class:`vpsim.result.Result`. ``schedule``: the
    P2's gear schedule in time (default: the gear rule's on ``cycle``,
    :func:`vpsim.gears.default_schedule`). ``exhaustive``: the P2's ECMS tries every torque level (the
    reference its walk is tested against; the same choices)."""
    ems = _check_ems(ems, params)
    ts, vs = np.asarray(cycle.time_s, float), np.asarray(cycle.speed_mps, float)
    grid = step_grid(ts, params.electric.forward_max_step)
    v_ref = np.interp(grid, ts, vs)
    at = np.searchsorted(grid, ts)  # the samples are grid points
    # the management's cost horizon at each step: the cycle's sample period the step lies in
    period = np.diff(ts)[np.searchsorted(ts, grid[:-1], side="right") - 1]
    soc_start = params.battery.soc_initial
    drv = driver_record(params)
    n = grid.size - 1
    speeds = np.empty(grid.size)
    extra = np.zeros(3)
    no_cost = np.zeros((1, 2, 2))
    split = params.powertrain.type == "hev_split"
    if split:
        x = hev_split._inputs(params)
        t0 = time.process_time()
        rows = np.empty((hev_split.N_ROWS, n))
        sums = np.zeros(hev_split.N_SUMS)
        soc_end = split_kernel(
            grid,
            v_ref,
            period,
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
            no_cost,
            soc_start,
            drv,
            rows,
            speeds,
            sums,
            extra,
        )
        result_of = hev_split._result
    else:
        engine_map, schedule, c, e, m, tabs, h, ratios, soc_grid = hev._inputs(cycle, params, schedule)
        t0 = time.process_time()
        rows = np.empty((hev.N_ROWS, n))
        sums = np.zeros(hev.N_SUMS)
        soc_end = p2_kernel(
            grid,
            v_ref,
            period,
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
            engine_map.max_torque_speed,
            engine_map.max_torque_values,
            engine_map.min_torque_values,
            soc_grid,
            no_cost,
            soc_start,
            drv,
            rows,
            speeds,
            sums,
            extra,
            exhaustive,
        )
        result_of = hev._result
    cpu = time.process_time() - t0
    r = result_of(
        cycle,
        params,
        ems,
        mode,
        rows[:, at[:-1]],
        sums,
        soc_start,
        soc_end,
        ts.size - 1,
        cpu,
    )
    series = dict(r.series)
    series["speed_mps"] = speeds[at]
    solver = {
        **r.solver,
        "steps": int(n),
        "max_step_s": float(params.electric.forward_max_step),
        "max_speed_error_mps": float(extra[F_MAX_ERROR]),
        "powertrain_limited_s": round(float(extra[F_LIMITED_S]), 6),
        "vehicle_speed_end_mps": float(speeds[-1]),
    }
    # the demand not deliverable: the time the powertrain gave less than the driver asked (the car then
    # behind its command), and the largest torque short then (at the P2's input shaft, the split's ring, as
    # the backward method counts it)
    limited = round(float(extra[F_LIMITED_S]), 6)
    trace = dataclasses.replace(
        r.trace_miss,
        seconds=limited,
        max_torque_shortfall_nm=float(extra[F_MAX_SHORT]),
        max_speed_error_mps=float(extra[F_MAX_ERROR]),
        details={**r.trace_miss.details, "torque_beyond_full_load_s": limited},
    )
    return dataclasses.replace(
        r, method="forward", driver=None, series=series, steps=int(n), solver=solver, trace_miss=trace
    )
