"""The backward quasi-static method (:mod:`vpsim.methods.backward`) for many design variants at once, parallel
over them (:mod:`vpsim.batch`): the exact BQM's fuel and trace miss of each variant, no series. Each variant's
engine lines are evaluated lazily, only at the nodes its operating points read."""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from ..model import engine as en
from ..model import rules
from ..model import tables as tb
from ..model import vehicle as vh
from ..model._compile import kernel
from ..model.engine import equation, inline
from ..model.maps import LINE_SPEED_STEP, MAX_SPEED_FACTOR
from .backward import MISS_TOLERANCE_NM, _deficit_after, _speed_power_at, cycle_intervals

# columns of run_variants' output
B_FUEL, B_MISS_S, B_MAX_SHORT, B_DEFICIT = range(4)
N_BATCH_OUT = 4


@inline
def _line_value(j, full, line_w, cache, c, node_cm18, node_powers):
    """The full-load line (``full``) or the closed-throttle line (the FQM at A_min) at its node j (speed
    ``line_w[j]``), computed on first use and cached in ``cache`` (NaN: not yet computed). ``node_cm18``:
    c_m^1.8 of (5) at the first node's speed; node j's is that times ``node_powers[j]`` = j^1.8, the nodes
    being j times the first one's speed (:func:`vpsim.model.engine.speed_power_scaled`)."""
    # (IR-inlined per look-up: no call, no reference counts of the arrays; the cache is written in place,
    # with no variable assigned in a branch, which Numba's inlining warns on)
    if cache[j] != cache[j]:
        if full:
            cache[j] = en.full_load_torque(line_w[j], c)
        else:
            cache[j] = en.steady_torque(c.min_throttle_area, line_w[j], c, node_cm18 * node_powers[j])
    return cache[j]


@inline
def _lazy_line(w, full, line_w, inv, cache, c, node_cm18, node_powers):
    """The generated line at w (tables.interp_at on the line's nodes ``line_w``), evaluating only the nodes
    the look-up reads."""
    j, exact = tb.interval_at(w, line_w, inv)
    _line_value(j, full, line_w, cache, c, node_cm18, node_powers)
    if not exact:
        _line_value(j + 1, full, line_w, cache, c, node_cm18, node_powers)
    return tb.interp_at(w, line_w, cache, inv)


@equation
def _variant(c, rat, gear, dt, v, a, v18, v_top_gear, extended, node_powers, out):
    """One variant: the operating points of :func:`run_kernel` with the exact BQM, each line of the
    variant's own engine evaluated lazily (a Newton solve per node actually needed), and only where it can
    matter (the max-torque line as below; the closed-throttle line: see ``p_hi``).

    The max-torque line matters only where the demanded intake pressure comes near the wide-open-throttle
    pressure p_max(w_e), which decreases with w_e: below p_max at a node above every speed of the run, less
    the largest friction rise over two node intervals (:func:`vpsim.model.engine.full_load_screen`), no
    point can reach the (interpolated) line, so it is not evaluated there.
    """
    # the lines' nodes as model.maps.generate_engine_map spaces them
    w_end = MAX_SPEED_FACTOR * c.map_speed_high
    w_top = c.idle_speed if extended else 0.0
    for g in range(rat.size):
        w_top = max(w_top, vh.engine_speed(v_top_gear[g], rat[g], c))
    n_line = int(round(w_end / LINE_SPEED_STEP)) + 1
    line_w = np.linspace(0.0, w_end, n_line)
    inv = tb.inverse_spacing(line_w)
    step = w_end / (n_line - 1)
    node_cm18 = en.speed_power(line_w[1], c)  # (c_m^1.8 is homogeneous in the speed: node j's is j^1.8 this)
    j_s = min(int(math.ceil(w_top / step)) + 2, n_line - 1)
    w_s = line_w[j_s]
    p_screen = en.full_load_screen(w_s, step, c)
    cache_max = np.full(n_line, np.nan)
    cache_min = np.full(n_line if extended else 1, np.nan)
    # The closed-throttle line matters only where the engaged engine is asked for less than it (engine
    # braking, fuel cut-off: rules.engine_braking); elsewhere its value changes nothing. It is the FQM at
    # A_min, T_cr(p_min(w_e), w_e), with p_min falling as w_e rises (the cylinders draw more), T_cr rising
    # with p_i and T_cr(p, w_e) falling with w_e (friction): on the line's nodes from below the idle speed up
    # (an engaged engine turns at least that fast) it stays below T_cr(p_min(node below idle), w_e) plus the
    # friction rise over two node intervals at the run's top speed. A demand above that needs no node.
    p_hi = math.inf
    closed_margin = 0.0
    if extended and c.torque_slope > 0.0:
        p_hi, _ = en.steady_pressure(
            c.min_throttle_area, line_w[max(int(math.floor(c.idle_speed / step)) - 1, 0)], c
        )
        d_t = en.crank_torque(0.0, max(w_s - 2.0 * step, 0.0), c) - en.crank_torque(0.0, w_s, c)
        closed_margin = abs(d_t) * (1.0 + 1e-9) + 1e-6
    fuel = 0.0
    miss_s = 0.0
    max_short = 0.0
    best = 0.0
    cur = 0.0
    # c_m^1.8 of the friction law (5) at the wheel-side engine speed, i v / r: a factor per gear times the
    # cycle's v^1.8 (shared by all variants), not a power per interval
    gear_cm18 = np.empty(rat.size)
    for g in range(rat.size):
        gear_cm18[g] = en.speed_power(vh.engine_speed(1.0, rat[g], c), c)
    for k in range(gear.size):
        i = rat[gear[k]]
        cm18_wheel = gear_cm18[gear[k]] * v18[k]
        t_closed = -math.inf  # first without the closed-throttle line (p_hi), then with it if needed
        for with_line in range(2):  # (one call site of the IR-inlined operating point)
            w, dw, w_wheel, t_req, brake, clutch, fired, _ = rules.operating_point(
                v[k], a[k], i, gear[k] + 1, t_closed, extended, c, cm18_wheel
            )
            if (
                with_line
                or not extended
                or clutch != rules.CLUTCH_ENGAGED
                or t_req >= en.crank_torque(p_hi, w_wheel, c, cm18_wheel) + closed_margin
            ):
                break
            t_closed = _lazy_line(w_wheel, False, line_w, inv, cache_min, c, node_cm18, node_powers)
        cm18 = _speed_power_at(w, w_wheel, cm18_wheel, c)
        p = en.intake_pressure_for_torque(t_req if fired >= 1.0 else t_closed, w, c, cm18)
        short = 0.0
        if not (w <= w_end and p <= p_screen):
            t_max = _lazy_line(w, True, line_w, inv, cache_max, c, node_cm18, node_powers)
            if t_req > t_max:
                short = t_req - t_max
                p = en.intake_pressure_for_torque(t_max, w, c, cm18)
        max_short = max(max_short, short)
        cur = _deficit_after(short, dt[k], i, cur, c)
        if short > MISS_TOLERANCE_NM:
            miss_s += dt[k]
            best = max(best, cur)
        mdot = rules.engine_fuel_flow(en.fuel_flow(p, w, c), clutch, fired, c)
        fuel += rules.fuel_used(mdot, fired, c) * dt[k]
    out[B_FUEL] = fuel
    out[B_MISS_S] = miss_s
    out[B_MAX_SHORT] = max_short
    out[B_DEFICIT] = best


@kernel(parallel=True)
def _variants(
    recs, ratios, schedule_of_variant, gears, v_top_gear, dt, v, a, v18, extended, node_powers, out
):
    """:func:`_variant` for each variant, parallel over them. ``v18``: the speed's part of c_m^1.8 (cycle
    intervals'), ``node_powers`` the lines' nodes' (j^1.8 of node j), shared by all variants."""
    for m in prange(recs.size):
        s = schedule_of_variant[m]
        _variant(recs[m], ratios[m], gears[s], dt, v, a, v18, v_top_gear[s], extended, node_powers, out[m])


def run_variants(cycle, recs, ratios, gears, schedule_of_variant, mode: str) -> np.ndarray:
    """The backward method for many variants (parallel over them), exact BQM; no series.

    ``recs``: record array (n_var,) (:func:`vpsim.model.record.records`); ``ratios``: (n_var, n_gears) total
    ratios; ``gears``: (n_schedules, n_samples) 1-based gear per cycle sample; ``schedule_of_variant``: row of
    ``gears`` each variant follows. Returns (n_var, N_BATCH_OUT): fuel (kg), trace-miss seconds, largest
    shortfall (N m), largest speed deficit (m/s).
    """
    dt, v, a, v18 = cycle_intervals(cycle)
    gear_idx = np.ascontiguousarray(gears[:, :-1] - 1, dtype=np.int64)
    v_top_gear = np.zeros((gear_idx.shape[0], ratios.shape[1]))  # fastest interval driven in each gear
    for s in range(gear_idx.shape[0]):
        np.maximum.at(v_top_gear[s], gear_idx[s], v)
    out = np.empty((recs.size, N_BATCH_OUT))
    w_end = MAX_SPEED_FACTOR * np.asarray(recs)["map_speed_high"]  # each variant's last node (as _variant)
    n_nodes = int(np.max(np.round(w_end / LINE_SPEED_STEP))) + 1
    _variants(
        np.asarray(recs).view(np.ndarray),
        np.ascontiguousarray(ratios, dtype=float),
        np.asarray(schedule_of_variant, dtype=np.int64),
        gear_idx,
        v_top_gear,
        dt,
        v,
        a,
        v18,
        rules.canonical_mode(mode) == "realistic",
        en.speed_power_scaled(np.arange(float(max(n_nodes, 2) + 1))),  # (one spare node)
        out,
    )
    return out
