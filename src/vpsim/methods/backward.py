"""Backward quasi-static method (BQM), paper section 3.

The cycle is tracked exactly by construction: from the cycle's speed and acceleration on each interval
(piecewise-linear cycle, so constant acceleration and mean speed per interval) follow the wheel force (18),
wheel torque and speed (16),(17), engine torque and speed through the prescribed gear (14),(15) and the
crank torque with the engine inertia (1) — :func:`vpsim.model.rules.operating_point`, which also applies
the realistic car's clutch and brakes in ``extended`` mode. The crank torque is limited by the max-torque
line; what is cut off is reported as a trace miss, never clipped silently. The fuel flow is looked up in the
engine's fuel map (generated from the physics by :mod:`vpsim.model.maps`, or measured) and floored at the
idle flow (section 5).

One compiled pass over the intervals (:func:`run_kernel`): the operating point and its fuel flow, then the
sums (fuel, distance, the energy balance from :func:`vpsim.model.rules.powers`, trace miss). For a measured
map the fuel flow comes from the map itself between that pass and the sums (:func:`account`).
:func:`vpsim.methods.backward_variants.run_variants` is the same method for many design variants at once
(:mod:`vpsim.batch`).

Modes:
* ``paper``: no clutch, no brakes; the engine stays coupled at standstill (w_e = 0, idle fuel).
* ``extended``: the rules of :mod:`vpsim.model.rules` (clutch slips or opens below idle speed, brakes).
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..gears import GearSchedule, default_schedule, gearbox_steps, schedule_for
from ..model import engine as en
from ..model import rules
from ..model import tables as tb
from ..model import vehicle as vh
from ..model._compile import compiled, kernel
from ..model.engine import inline
from ..model.maps import (
    LINE_SPEED_STEP,
    MAX_SPEED_FACTOR,
    EngineMap,
    GeneratedEngineMap,
    cached_engine_map,
)
from ..model.record import kernel_records, memo, readonly
from ..model.record import ratios as total_ratios
from ..model.tables import gear_index
from ..result import EnergyBalance, Result, TraceMiss, limits_of

# how the fuel flow of an operating point is found
FUEL_EXACT, FUEL_TABLE, FUEL_GIVEN = 0, 1, 2

# rows of the per-interval array
(R_TIME, R_V, R_A, R_W, R_DW, R_WWHEEL, R_TCR, R_SHORT, R_BRAKE, R_CLUTCH, R_P, R_MDOT, R_THR, R_FIRED) = (
    range(14)
)
N_ROWS = 14
# results of account(): the energy terms (rules.ENERGY_TERMS order), then these
A_FUEL = rules.N_TERMS
A_DIST, A_MISS_S, A_MAX_SHORT, A_DEFICIT = A_FUEL + 1, A_FUEL + 2, A_FUEL + 3, A_FUEL + 4
N_ACC = A_FUEL + 5
MISS_TOLERANCE_NM = 1e-9  # a shortfall below this is rounding, not a trace miss


@inline
def _point(
    dt_s,
    speed,
    accel,
    speed18,
    k,
    g,
    ratios,
    f18,
    c,
    extended,
    fuel_kind,
    map_speed,
    map_torque,
    table,
    line_speed,
    line_max,
    line_min,
    slope_max,
    slope_min,
    inv_line,
    inv_ms,
    inv_mt,
    p_screen,
):
    """The operating point interval k imposes in gear index g, limited by the max-torque line; its intake
    pressure and (``fuel_kind`` exact or table) fuel flow. Returns the values of one row (R_V .. R_MDOT).
    ``slope_max``, ``slope_min``: the lines' slopes between their nodes (``tables.interval_slopes``).

    ``dt_s``, ``speed``, ``accel``, ``speed18``: the cycle's intervals (:func:`cycle_intervals`); ``f18``:
    :func:`vpsim.model.engine.speed_power` of gear g's engine speed per unit of vehicle speed, so that the
    engaged engine's c_m^1.8 is ``f18 * speed18[k]`` (no power per interval)."""
    i = ratios[g]
    v = speed[k]
    a = accel[k]
    t_closed = 0.0
    if extended:
        t_closed = tb.interp_sloped_at(vh.engine_speed(v, i, c), line_speed, line_min, slope_min, inv_line)
    cm18_wheel = f18 * speed18[k]
    w, dw, w_wheel, t_req, brake, clutch, fired, _ = rules.operating_point(
        v, a, i, g + 1, t_closed, extended, c, cm18_wheel
    )
    # the friction law's power of the speed (5): the gear's factor times the cycle's |v|^1.8 where the engine
    # turns with the wheels, else at its own speed (idle, a converter's pump)
    cm18 = _speed_power_at(w, w_wheel, cm18_wheel, c)
    # cylinders cut: the throttle is closed (manifold, fuel); the demand is then below t_closed
    p = en.intake_pressure_for_torque(t_req if fired >= 1.0 else t_closed, w, c, cm18)
    short = 0.0
    if not (w <= line_speed[line_speed.size - 1] and p <= p_screen):  # (else below the line)
        t_max = tb.interp_sloped_at(w, line_speed, line_max, slope_max, inv_line)
        if t_req > t_max:
            short = t_req - t_max
            if fired >= 1.0:
                p = en.intake_pressure_for_torque(t_req - short, w, c, cm18)
    t_cr = t_req - short
    if fuel_kind == FUEL_EXACT:
        mdot = en.fuel_flow(p, w, c)
    elif fuel_kind == FUEL_TABLE:
        mdot = tb.bilinear_at(
            map_speed, map_torque, table, w, t_cr if fired >= 1.0 else t_closed, inv_ms, inv_mt
        )
    else:
        mdot = math.nan
    mdot = rules.engine_fuel_flow(mdot, clutch, fired, c)  # idle with the clutch open; fuel cut-off
    return v, a, w, dw, w_wheel, t_cr, short, brake, clutch, fired, p, mdot, cm18


@inline
def _speed_power_at(w, w_wheel, cm18_wheel, c):
    """c_m^1.8 of (5) at the engine speed w of an operating point: ``cm18_wheel`` where the engine turns with
    the wheels (w_wheel), the record's at idle, else :func:`vpsim.model.engine.speed_power` (a converter's
    pump speed)."""
    if w == w_wheel:
        return cm18_wheel
    if w == c.idle_speed:
        return c.idle_speed_power
    return en.speed_power(w, c)


@inline
def _store(rows, k, time_s, v, a, w, dw, w_wheel, t_cr, short, brake, clutch, fired, p, mdot, thr):
    rows[R_TIME, k] = 0.5 * (time_s[k + 1] + time_s[k])
    rows[R_V, k] = v
    rows[R_A, k] = a
    rows[R_W, k] = w
    rows[R_DW, k] = dw
    rows[R_WWHEEL, k] = w_wheel
    rows[R_TCR, k] = t_cr
    rows[R_SHORT, k] = short
    rows[R_BRAKE, k] = brake
    rows[R_CLUTCH, k] = clutch
    rows[R_FIRED, k] = fired
    rows[R_P, k] = p
    rows[R_MDOT, k] = mdot
    rows[R_THR, k] = thr


@inline
def _steady_throttle(p, w, c):
    """The FQM's steady throttle at (p_i, w_e): its area (a boosted engine's command beyond A_max is
    boost)."""
    return en.throttle_upstream(en.command_for_flow(p, en.cylinder_air_flow(p, w, c), w, c), w, c)[0]


@inline
def _kahan(total, comp, x):
    """(total + x, its new compensation) with Kahan's compensation ``comp``."""
    y = x - comp
    t = total + y
    return t, (t - total) - y


# the running sums of a pass: the N_ACC sums of account()'s results, then the Kahan compensations of fuel,
# distance and miss seconds, then the speed deficit of the current contiguous miss (kept in registers: as an
# array the sums went through memory every interval)
ZERO_SUMS = (0.0,) * (N_ACC + 4)


@inline
def _book(
    sums,
    dt,
    i,
    v,
    a,
    w,
    dw,
    w_wheel,
    t_cr,
    short,
    brake,
    clutch,
    fired,
    p,
    mdot,
    c,
    with_engine,
    realistic,
    cm18,
):
    """The sums (:data:`ZERO_SUMS` to start) with the interval's fuel, distance, energy terms and trace miss
    added. ``cm18``: :func:`vpsim.model.engine.speed_power` at w."""
    # fmt: off
    (e0, e1, e2, e3, e4, e5, e6, e7, e8, e9, e10, e11,  # rules.ENERGY_TERMS, then account()'s, then these
     fuel, dist, miss, max_short, deficit, fuel_c, dist_c, miss_c, cur) = sums  # (a slice: slower)
    # fmt: on
    fuel, fuel_c = _kahan(fuel, fuel_c, rules.fuel_used(mdot, fired, c) * dt)
    dist, dist_c = _kahan(dist, dist_c, v * dt)
    pw = rules.powers(
        p,
        w,
        dw,
        t_cr,
        short,
        w_wheel,
        v,
        a,
        brake,
        clutch,
        fired,
        rules.accessories_torque(w, realistic, c),
        1.0,
        c,
        cm18,
    )
    if with_engine:  # the engine's terms need the model's physics at the operating point (plain sums: their
        # rounding, ~1e-13 of the balance, is far below what the balance is checked to)
        e0 += pw[0] * dt
        e1 += pw[1] * dt
        e2 += pw[2] * dt
        e3 += pw[3] * dt
        e4 += pw[4] * dt
        e9 += pw[9] * dt
        e10 += pw[10] * dt
        e11 += pw[11] * dt
    e5 += pw[5] * dt
    e6 += pw[6] * dt
    e7 += pw[7] * dt
    e8 += pw[8] * dt
    if short > max_short:
        max_short = short
    cur = _deficit_after(short, dt, i, cur, c)
    if short > MISS_TOLERANCE_NM:
        miss, miss_c = _kahan(miss, miss_c, dt)
        if cur > deficit:
            deficit = cur
    # fmt: off
    return (e0, e1, e2, e3, e4, e5, e6, e7, e8, e9, e10, e11,
            fuel, dist, miss, max_short, deficit, fuel_c, dist_c, miss_c, cur)
    # fmt: on


@inline
def _store_sums(acc, sums):
    """account()'s results (the first N_ACC of the sums) into ``acc``."""
    for q in range(N_ACC):
        acc[q] = sums[q]


@inline
def _deficit_after(short, dt, i, cur, c):
    """The speed the engine could not give, accumulated over a contiguous trace miss (0 once it ends)."""
    if short > MISS_TOLERANCE_NM:
        return cur + vh.acceleration_shortfall(short, i, c) * dt
    return 0.0


# _nrt=False: no reference counting (each call of an equation with array arguments would otherwise pay for
# atomic increments and decrements); the kernels allocate nothing
@kernel(_nrt=False)
def run_kernel(
    time_s,
    dt_s,
    speed,
    accel,
    speed18,
    sched_t,
    sched_gear,
    ratios,
    recs,
    extended,
    fuel_kind,
    map_speed,
    map_torque,
    table,
    line_speed,
    line_max,
    line_min,
    slope_max,
    slope_min,
    with_engine,
    own_lines,
    interval_gear,
    gear,
    rows,
    acc,
):
    """The BQM over the cycle's intervals: operating points (and their fuel flow, unless ``fuel_kind`` is
    FUEL_GIVEN: then only ``rows`` are filled, for :func:`account` after the map gave the fuel), and the
    sums of :func:`account` in the same pass. ``rows`` may have no columns (no series wanted). ``time_s``:
    the cycle's samples; ``dt_s``, ``speed``, ``accel``, ``speed18``: its intervals (:func:`cycle_intervals`);
    ``slope_max``, ``slope_min``: the lines' slopes (:func:`_map_arrays`). ``own_lines``: the lines are the
    model's of this engine (:func:`vpsim.model.maps.generate_engine_map`), so the max-torque line is read only
    where :func:`vpsim.model.engine.full_load_screen` cannot rule it out. ``interval_gear``: the gear index
    (0-based) of every interval where the schedule's samples are the cycle's (:func:`_interval_gears`), else
    empty (looked up in the schedule).
    """
    c = recs[0]
    p_screen = -math.inf
    if own_lines:
        w_end = line_speed[line_speed.size - 1]
        p_screen = en.full_load_screen(w_end, w_end / (line_speed.size - 1), c)
    given = interval_gear.size == gear.size
    inv_line = tb.inverse_spacing(line_speed)
    inv_ms = tb.inverse_spacing(map_speed)
    inv_mt = tb.inverse_spacing(map_torque)
    keep = rows.shape[1] == gear.size
    book = fuel_kind != FUEL_GIVEN
    j = 0
    sums = ZERO_SUMS
    g_f18 = -1  # the gear whose factor f18 is at hand (gears change every few seconds, intervals every one)
    f18 = 0.0
    for k in range(gear.size):
        if given:
            g = interval_gear[k]
        else:
            g, j = gear_index(time_s, k, sched_t, sched_gear, j)
        gear[k] = g + 1
        if g != g_f18:
            f18 = en.speed_power(vh.engine_speed(1.0, ratios[g], c), c)
            g_f18 = g
        v, a, w, dw, w_wheel, t_cr, short, brake, clutch, fired, p, mdot, cm18 = _point(
            dt_s,
            speed,
            accel,
            speed18,
            k,
            g,
            ratios,
            f18,
            c,
            extended,
            fuel_kind,
            map_speed,
            map_torque,
            table,
            line_speed,
            line_max,
            line_min,
            slope_max,
            slope_min,
            inv_line,
            inv_ms,
            inv_mt,
            p_screen,
        )
        if keep:
            _store(rows, k, time_s, v, a, w, dw, w_wheel, t_cr, short, brake, clutch, fired, p, mdot, 0.0)
        if book:
            sums = _book(
                sums,
                dt_s[k],
                ratios[g],
                v,
                a,
                w,
                dw,
                w_wheel,
                t_cr,
                short,
                brake,
                clutch,
                fired,
                p,
                mdot,
                c,
                with_engine,
                extended,
                cm18,
            )
    _store_sums(acc, sums)
    if keep:
        _steady_throttles(rows, c)


@inline
def _steady_throttles(rows, c):
    """The steady throttle of every interval's (p_i, w_e) into ``rows``: a loop of its own after the pass,
    whose iterations do not wait on each other (in the pass each waited on the operating point's long chain:
    10 us of a 66 us UDDS pass there)."""
    p_thr = math.nan  # the point whose steady throttle thr is at hand
    w_thr = math.nan
    thr = math.nan
    for k in range(rows.shape[1]):
        p = rows[R_P, k]
        w = rows[R_W, k]
        if p != p_thr or w != w_thr:  # (the idling engine's point repeats: its throttle is at hand)
            thr = _steady_throttle(p, w, c)
            p_thr = p
            w_thr = w
        rows[R_THR, k] = thr


@kernel(_nrt=False)
def account(time_s, rows, ratios, gear, recs, with_engine, extended, acc):
    """Fuel and distance (compensated sums over the intervals), the energy terms and the trace miss: seconds
    beyond the max-torque line, the largest shortfall and the largest speed deficit accumulated over a
    contiguous miss, from the rows of :func:`run_kernel` (with the fuel flow of a measured map filled in)."""
    c = recs[0]
    sums = ZERO_SUMS
    for k in range(gear.size):
        sums = _book(
            sums,
            time_s[k + 1] - time_s[k],
            ratios[gear[k] - 1],
            rows[R_V, k],
            rows[R_A, k],
            rows[R_W, k],
            rows[R_DW, k],
            rows[R_WWHEEL, k],
            rows[R_TCR, k],
            rows[R_SHORT, k],
            rows[R_BRAKE, k],
            int(rows[R_CLUTCH, k]),
            rows[R_FIRED, k] != 0.0,
            rows[R_P, k],
            rows[R_MDOT, k],
            c,
            with_engine,
            extended,
            en.speed_power(rows[R_W, k], c),
        )
    _store_sums(acc, sums)


def cycle_intervals(cycle) -> tuple:
    """The cycle's intervals as the backward method takes them (piecewise-linear speed: constant
    acceleration, mean speed): (dt, mean speed, acceleration, |mean speed|^1.8), read-only arrays computed
    once per cycle and kept on it (a cycle is immutable), like a gear schedule prepared for it: every run on
    the cycle, of any design, shares them. |v|^1.8 is :func:`vpsim.model.engine.speed_power_scaled`: the
    engaged engine's c_m^1.8 is a factor per gear times it."""
    return memo(cycle, "backward_intervals", _intervals)


def _intervals(cycle) -> tuple:
    t, vs = cycle.time_s, cycle.speed_mps
    dt = t[1:] - t[:-1]
    v = 0.5 * (vs[1:] + vs[:-1])
    a = (vs[1:] - vs[:-1]) / dt
    return readonly((dt, v, a, en.speed_power_scaled(v)))


def _prepared(params) -> tuple:
    """(engine map, its kernel arrays, kernel records, total ratios, gearbox steps) of a parameter set run on
    the model's own map: the look-ups every run of it makes, done once and kept on the (frozen) set."""
    engine_map = cached_engine_map(params.engine)
    return (
        engine_map,
        _map_arrays(engine_map, params),
        kernel_records(params),
        total_ratios(params.transmission),
        gearbox_steps(params.transmission),
    )


def _map_arrays(engine_map, params):
    """(fuel kind, table speed, table torque, table, line speeds, max line, min line, max line's slopes, min
    line's slopes) for the kernels; a generated map's once per map."""
    if isinstance(engine_map, GeneratedEngineMap):
        return memo(engine_map, "backward_arrays", _generated_arrays)
    # any other map: its lines tabulated at 1 rad/s over its speed range, its fuel flow asked for directly
    w_top = MAX_SPEED_FACTOR * params.engine.map_speed_range[1]
    w = np.linspace(0.0, w_top, int(round(w_top / LINE_SPEED_STEP)) + 1)
    none = np.zeros(2)
    l_max = np.asarray(engine_map.max_torque(w), float)
    l_min = np.asarray(engine_map.min_torque(w), float)
    return (
        FUEL_GIVEN,
        none,
        none,
        np.zeros((2, 2)),
        w,
        l_max,
        l_min,
        tb.interval_slopes(w, l_max),
        tb.interval_slopes(w, l_min),
    )


def _generated_arrays(engine_map) -> tuple:
    w, l_max, l_min = engine_map.max_torque_speed, engine_map.max_torque_values, engine_map.min_torque_values
    s_max, s_min = readonly((tb.interval_slopes(w, l_max), tb.interval_slopes(w, l_min)))  # (as the map's)
    kind = FUEL_EXACT if engine_map.exact else FUEL_TABLE
    return (kind, engine_map.speed, engine_map.torque, engine_map.table, w, l_max, l_min, s_max, s_min)


(NO_GEARS,) = readonly((np.empty(0, dtype=np.int64),))  # (read-only, as the kept gears: one kernel signature)


def _interval_gears(schedule, cycle) -> np.ndarray:
    """The gear index (0-based) of each of ``cycle``'s intervals where ``schedule`` was made on the cycle's
    own samples (a schedule from :func:`vpsim.gears.schedule_for` or :func:`vpsim.gears.default_schedule`:
    equal times, compared once per cycle object), kept on the schedule; else empty: the kernel then looks
    each up (:func:`vpsim.model.tables.gear_index`, the same gear). Read-only either way."""
    kept = memo(schedule, "interval_gears", _no_interval_gears)
    time_s = cycle.time_s
    hit = kept.get(id(time_s))
    if hit is not None and hit[0] is time_s:
        return hit[1]
    same = schedule.time_s.shape == time_s.shape and bool(np.array_equal(schedule.time_s, time_s))
    gears = NO_GEARS
    if same:
        (gears,) = readonly((schedule.gear[:-1] - 1,))
    if len(kept) < 16:  # (the cycles a schedule is run on: normally one)
        kept[id(time_s)] = (time_s, gears)
    return gears


def _no_interval_gears(schedule) -> dict:
    return {}


def run(
    cycle,
    params,
    *,
    engine_map: EngineMap | None = None,
    schedule: GearSchedule | None = None,
    mode: str = "paper",
    keep_series: bool = True,
    _rows: bool = False,
) -> Result:
    """Run the BQM on ``cycle``. ``engine_map`` defaults to the map generated from ``params.engine``."""
    mode = rules.canonical_mode(mode)
    own = engine_map is None
    if own:  # the model's own map: what the run takes from the parameter set, prepared once
        engine_map, arrays, recs, ratios, steps = memo(params, "backward_prepared", _prepared)
        if schedule is None:
            schedule = schedule_for(cycle, params)
    else:
        if not isinstance(engine_map, GeneratedEngineMap) and not isinstance(engine_map, EngineMap):
            raise TypeError(
                f"engine_map must implement vpsim.model.maps.EngineMap, got {type(engine_map).__name__}"
            )
        arrays = _map_arrays(engine_map, params)
        recs, ratios, steps = kernel_records(params), total_ratios(params.transmission), None
    if schedule is None:
        schedule = default_schedule(cycle, params, engine_map)
    extended = mode == "realistic"
    kind, m_speed, m_torque, table, l_speed, l_max, l_min, s_max, s_min = arrays
    generated = isinstance(engine_map, GeneratedEngineMap)
    # the lines generated from this engine (the model's own map, or one generated from an equal engine)
    own_lines = own or (
        generated and (engine_map.engine is params.engine or engine_map.engine == params.engine)
    )
    n = cycle.time_s.size - 1
    interval_gear = _interval_gears(schedule, cycle)

    def passes(time_s, intervals, keep):
        dt_s, speed, accel, speed18 = intervals
        n_k = time_s.size - 1
        gear = np.empty(n_k, dtype=np.int64)
        rows = np.empty((N_ROWS, n_k if keep or kind == FUEL_GIVEN else 0))
        acc = np.empty(N_ACC)
        run_kernel(
            time_s,
            dt_s,
            speed,
            accel,
            speed18,
            schedule.time_s,
            schedule.gear,
            ratios,
            recs,
            extended,
            kind,
            m_speed,
            m_torque,
            table,
            l_speed,
            l_max,
            l_min,
            s_max,
            s_min,
            generated,
            own_lines,
            interval_gear if n_k == n else NO_GEARS,
            gear,
            rows,
            acc,
        )
        if kind == FUEL_GIVEN:
            flow = np.asarray(engine_map.fuel_flow(rows[R_TCR], rows[R_W]), dtype=float)
            rows[R_MDOT] = np.where(
                rows[R_CLUTCH] == rules.CLUTCH_OPEN, params.simulation.idle_fuel_flow, flow
            )
            rows[R_MDOT] = np.where(rows[R_FIRED] != 0.0, rows[R_MDOT], 0.0)  # fuel cut-off
            account(time_s, rows, ratios, gear, recs, generated, extended, acc)
        return gear, rows, acc

    intervals = cycle_intervals(cycle)
    if not compiled(run_kernel):  # compile (or load) outside the timing
        passes(cycle.time_s[:2], tuple(x[:1] for x in intervals), keep_series)
    stop_start = params.simulation.stop_start
    t0 = time.process_time()
    gear, rows, acc = passes(cycle.time_s, intervals, keep_series or _rows or stop_start)
    starts = 0
    if stop_start:  # the stopped intervals' rows become the standing engine's (no speed, torque or fuel)
        stopped, starts = rules.stopped_at_rest(intervals[1], intervals[2])
        for row in (R_W, R_DW, R_TCR, R_MDOT, R_FIRED, R_P, R_THR, R_SHORT, R_BRAKE):
            rows[row, stopped] = 0.0
        rows[R_CLUTCH, stopped] = rules.CLUTCH_OPEN
        account(cycle.time_s, rows, ratios, gear, recs, generated, extended, acc)
        acc[A_FUEL] += starts * params.hybrid.engine_start_fuel
    cpu = time.process_time() - t0
    sums = acc.tolist()
    trace = TraceMiss(
        seconds=sums[A_MISS_S],
        max_torque_shortfall_nm=sums[A_MAX_SHORT],
        details={"speed_deficit_mps": sums[A_DEFICIT]},
    )
    # positional: rules.ENERGY_TERMS is EnergyBalance's field order (tests/test_result.py holds them
    # equal); the keyword form cost 2 us of a 100 us run
    energy = EnergyBalance(*sums[: rules.N_TERMS]) if generated else None
    series = _sample_series(cycle, params, rows, gear, generated, steps, recs) if keep_series else {}
    trace.details["torque_beyond_full_load_s"] = trace.seconds
    r = _result(cycle, params, mode, series, sums[A_FUEL], sums[A_DIST], cpu, n, trace, energy)
    if stop_start:
        r.solver.update(engine_starts=starts)
    if _rows:
        r.solver.update(rows=rows, gear=gear)
    return r


def intervals(
    cycle, params, *, engine_map: EngineMap | None = None, schedule=None, mode: str = "realistic"
) -> dict:
    """The operating point of every interval of ``cycle`` as the backward method computes it (the quantities
    the per-sample series of :func:`run` average): ``dt_s``, ``crank_torque_nm``, ``engine_speed_radps``,
    ``fuel_flow_kgps``, ``torque_shortfall_nm``, ``gear``; for analyses that weigh operating points by time
    (the engine-map comparisons of :mod:`vpsim.scaling` and :mod:`vpsim.calibration`)."""
    r = run(cycle, params, engine_map=engine_map, schedule=schedule, mode=mode, keep_series=False, _rows=True)
    rows, gear = r.solver["rows"], r.solver["gear"]
    return {
        "time_s": rows[R_TIME],
        "dt_s": np.diff(cycle.time_s),
        "crank_torque_nm": rows[R_TCR],
        "engine_speed_radps": rows[R_W],
        "fuel_flow_kgps": rows[R_MDOT],
        "torque_shortfall_nm": rows[R_SHORT],
        "gear": gear,
    }


# columns of the per-sample series (the core columns of vpsim.result, at the cycle's samples) of float type;
# the gear and the clutch's state have arrays of their own types (integer, boolean)
(S_ACC, S_RATIO, S_W, S_TCR, S_TE, S_P, S_THR, S_MDOT, S_USED, S_BRAKE, S_SHORT) = range(11)
N_SAMPLE_ROWS = 11


@inline
def _pair_mean(rows, r, k):
    """The mean of row r's two intervals adjacent to sample k (k in 1 .. n-1)."""
    return 0.5 * (rows[r, k - 1] + rows[r, k])


@kernel(_nrt=False)
def sample_rows(rows, gear, steps, recs, generated, out, gear_out, engaged_out):
    """The per-interval rows at the cycle's samples (``out``: N_SAMPLE_ROWS x samples; ``gear_out`` the gear,
    ``engaged_out`` whether the clutch is engaged, one per sample); ``steps``: the
    gearbox ratio of each gear (:func:`vpsim.gears.gearbox_ratio_series` for the gears the method engaged,
    which are within 1..len(steps)).

    A sample shows the mean of its two adjacent intervals (the first and last sample their one interval);
    gear and clutch state are those engaged from the sample on (right-continuous, as the other methods
    report them); the torque shortfall is the larger of the two intervals'; the intake pressure and the
    steady throttle (the FQM inverted) exist where the clutch is engaged and the map is the model's.

    One loop per column over the inner samples (simple loops the compiler vectorises), then the two ends.
    """
    c = recs[0]
    n = gear.size
    for k in range(1, n):
        out[S_ACC, k] = _pair_mean(rows, R_A, k)
    for k in range(1, n):
        out[S_W, k] = _pair_mean(rows, R_W, k)
    for k in range(1, n):
        out[S_TCR, k] = _pair_mean(rows, R_TCR, k)
    for k in range(1, n):
        out[S_TE, k] = vh.engine_torque(out[S_TCR, k], _pair_mean(rows, R_DW, k), c)  # (1)
    for k in range(1, n):
        out[S_MDOT, k] = _pair_mean(rows, R_MDOT, k)
    for k in range(1, n):
        out[S_USED, k] = rules.fuel_used(out[S_MDOT, k], _pair_mean(rows, R_FIRED, k), c)
    for k in range(1, n):
        out[S_BRAKE, k] = _pair_mean(rows, R_BRAKE, k)
    for k in range(1, n):
        out[S_SHORT, k] = max(rows[R_SHORT, k - 1], rows[R_SHORT, k])
    for k in range(1, n):
        engaged_out[k] = rows[R_CLUTCH, k] != rules.CLUTCH_OPEN
    for k in range(1, n):
        out[S_P, k] = _pair_mean(rows, R_P, k) if generated and engaged_out[k] else math.nan
    for k in range(1, n):
        out[S_THR, k] = _pair_mean(rows, R_THR, k) if generated and engaged_out[k] else math.nan
    for k in range(1, n):
        gear_out[k] = gear[k]
        out[S_RATIO, k] = steps[gear[k] - 1]
    for k in (0, n):  # the ends: their one interval
        own = k if k < n else n - 1
        engaged = rows[R_CLUTCH, own] != rules.CLUTCH_OPEN
        ok = generated and engaged
        out[S_ACC, k] = rows[R_A, own]
        gear_out[k] = gear[own]
        out[S_RATIO, k] = steps[gear[own] - 1]
        out[S_W, k] = rows[R_W, own]
        out[S_TCR, k] = rows[R_TCR, own]
        out[S_TE, k] = vh.engine_torque(rows[R_TCR, own], rows[R_DW, own], c)  # (1)
        out[S_P, k] = rows[R_P, own] if ok else math.nan
        out[S_THR, k] = rows[R_THR, own] if ok else math.nan
        out[S_MDOT, k] = rows[R_MDOT, own]
        out[S_USED, k] = rules.fuel_used(rows[R_MDOT, own], rows[R_FIRED, own], c)
        out[S_BRAKE, k] = rows[R_BRAKE, own]
        out[S_SHORT, k] = rows[R_SHORT, own]
        engaged_out[k] = engaged


def _sample_series(cycle, params, rows, gear, generated, steps=None, recs=None) -> dict:
    """The series at the cycle's samples, the time base of every method (:func:`sample_rows`); ``steps`` and
    ``recs`` the parameter set's gearbox steps and kernel records where the caller has them at hand."""
    out = np.empty((N_SAMPLE_ROWS, gear.size + 1))
    gear_s = np.empty(gear.size + 1, dtype=np.int64)
    engaged = np.empty(gear.size + 1, dtype=np.bool_)
    if steps is None:
        steps, recs = gearbox_steps(params.transmission), kernel_records(params)
    sample_rows(rows, gear, steps, recs, generated, out, gear_s, engaged)
    acc, ratio, w, t_cr, t_e, p, thr, mdot, used, brake, short = out  # (one view each)
    return {
        "time_s": cycle.time_s,
        "reference_speed_mps": cycle.speed_mps,
        "speed_mps": cycle.speed_mps,
        "accel_mps2": acc,
        "gear": gear_s,
        "gearbox_ratio": ratio,
        "engine_speed_radps": w,
        "crank_torque_nm": t_cr,
        "engine_torque_nm": t_e,
        "intake_pressure_pa": p,
        "throttle_area_m2": thr,
        "fuel_flow_kgps": mdot,
        "fuel_flow_used_kgps": used,
        "brake_force_n": brake,
        "torque_shortfall_nm": short,
        "clutch_engaged": engaged,
    }


def _result(cycle, params, mode, series, fuel_kg, distance, cpu, steps, trace, energy) -> Result:
    notes = []
    if trace.seconds:
        notes.append(
            f"trace miss: the cycle asks more torque than the max-torque line for {trace.seconds:g} s "
            f"(largest shortfall {trace.max_torque_shortfall_nm:.1f} N m); fuel is computed at the line"
        )
    return Result(
        method="backward",
        cycle=cycle.name,
        driver=None,
        mode=mode,
        series=series,
        fuel_kg=fuel_kg,
        distance_m=distance,
        fuel_density_kg_per_l=params.simulation.fuel_density,
        cpu_time_s=cpu,
        steps=steps,
        trace_miss=trace,
        energy=energy,
        vehicle=params.name,
        notes=tuple(notes),
        limits=limits_of(params),
    )
