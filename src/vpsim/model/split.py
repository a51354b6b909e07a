"""The power-split hybrid: one planetary gear set between the engine, a generator and the wheels, written
once from the components (the engine of :mod:`vpsim.model.engine`, the machines and battery of
:mod:`vpsim.model.electric` and :mod:`vpsim.model.machine`) and the management's choices of
:mod:`vpsim.model.hybrid`.

Layout (the Toyota/Lexus/Ford hybrids): the engine on the planet carrier, the generator MG1 on the sun, the
ring to the wheels through the final drive (ratio i_r = ``transmission.final_drive``, efficiency eta), the
traction machine MG2 on the ring through its reduction i_m2 (``split.mg2_ratio``). With k = Z_r / Z_s (ring
over sun teeth):

    (P1) Willis:          w_s = (1 + k) w_c - k w_r             w_r = i_r v / r,  w_m2 = i_m2 w_r
    (P2) torque balance:  T_s = T_c / (1 + k),  T_r = k T_c / (1 + k)   (ideal gears, massless pinions)
                          so that T_c w_c = T_s w_s + T_r w_r (power is conserved through the set)
    (P3) machines:        T_g = -T_s + J_g dw_s                 (MG1 holds the sun: its reaction torque)
                          T_m2 = (T_ring - T_r) / i_m2 + J_m2 dw_m2,  T_ring = F_w r / (i_r eta) (E1)
    (P4) speed window:    the carrier (engine) speed w_c within [w_idle, w_e,max] and such that |w_s| <=
                          w_g,max: w_c in [(k w_r - w_g,max) / (1 + k), (k w_r + w_g,max) / (1 + k)]

The engine's speed is free within (P4): the management chooses whether the engine runs and its power P_e;
the engine then turns at the speed where engine and gear set together waste least (the system operating
line, (P6), :func:`system_line`): at ring speed w_r, the speed of least fuel per unit of the power that
reaches the ring net of the two machines' losses,

    (P6) w*(P, w_r) = argmin_w mdot_f(P / w, w) / (P - L_g(T_g, w_s) - L_m2(T_m2, w_m2))

with T_g, w_s from (P1)-(P3) at the engine's speed w and the battery idle (MG2 passes what MG1 makes, within
its envelope: T_m2 w_m2 = -T_g w_s), L the machines' loss model (:mod:`vpsim.model.machine`). The engine's
own best-efficiency line ((P5): w(P) = argmin_w mdot_f(P / w, w), :func:`best_efficiency_line`) is the
lowest speed at every power for a mean-value engine (its friction grows with speed); at highway ring speeds
that puts MG1 far below zero speed, where it motors and MG2 generates the power it takes: the recirculating
power of a split, which (P6) weighs and a real management avoids. It is held within (P4)
and at or above the speed where MG1's rated torque can hold the engine's (P / w <= (1 + k) T_g,rated). Over
an interval the engine's speed is held (dw_c = 0: its change between intervals, a fraction of a percent of
the cycle's energy, is not booked), so dw_s = -k dw_r. Both machines draw on one pack: MG1's DC power is
served first, MG2's torque cut where the pack cannot give or take the sum
(:func:`vpsim.model.electric.machine_and_battery_at`). A choice is infeasible where MG1 cannot hold the
reaction torque or turns beyond its top speed (the engine at rest at a ring speed where |k w_r| > w_g,max), or
the pack cannot take MG1's generated power.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from . import battery as bt
from . import electric as el
from . import engine as en
from . import hybrid as hy
from . import machine as mc
from . import rules
from . import tables as tb
from . import vehicle as vh
from .engine import equation, inline
from .record import fields

LINE_POINTS = 121  # powers of the best-efficiency line (uniform from 0 to the engine's top power)
LINE_SPEEDS = 931  # speeds it is searched over (0.5 rad/s apart on the preset)
SYSTEM_POWERS = 61  # powers of the system operating line (P6), uniform from 0 to the engine's top power
SYSTEM_RING_SPEEDS = 41  # its ring speeds, uniform from 0 to MG2's top speed over its reduction
SYSTEM_SPEEDS = 311  # engine speeds it is searched over (1.5 rad/s apart on the preset)
SPEED_TRIALS = 16  # speeds tried across the gear set's range where MG1 cannot hold the engine on the line

# the point's fields after the P2's (hybrid.p2_point's first 18, which the shared cost functions read)
P_WC, P_WS, P_TG, P_PG, P_DWS, P_TRING, P_FEASIBLE = range(18, 25)


@equation
def sun_speed(w_c, w_r, s):
    """(P1) Willis: the sun's (MG1's) speed of carrier speed w_c and ring speed w_r."""
    return (1.0 + s.ring_over_sun) * w_c - s.ring_over_sun * w_r


@equation
def carrier_speed(w_s, w_r, s):
    """(P1) solved for the carrier: w_c = (w_s + k w_r) / (1 + k)."""
    return (w_s + s.ring_over_sun * w_r) / (1.0 + s.ring_over_sun)


@equation
def planetary_torques(t_c, s):
    """(P2): the torques (T_s, T_r) a carrier torque T_c puts on the sun and the ring."""
    return t_c / (1.0 + s.ring_over_sun), s.ring_over_sun * t_c / (1.0 + s.ring_over_sun)


@equation
def carrier_speed_range(w_r, c, g, s):
    """(P4): the engine speeds (lowest, highest) the gear set allows at ring speed w_r: at or above idle and
    below the engine's top speed, with the sun (MG1) within its top speed either way. Empty (lowest >
    highest) where none is."""
    lo = max(c.idle_speed, carrier_speed(-g.max_speed, w_r, s))
    hi = min(s.engine_max_speed, carrier_speed(g.max_speed, w_r, s))
    return lo, hi


@equation
def engine_speed_for_power(p, w_r, dw_r, w_lo, w_hi, lines, best, g, s):
    """The engine's speed for power p at ring speed w_r: on the system operating line (P6), at or above the
    speed where MG1's rated torque holds the engine's (p / w <= (1 + k) T_g,rated), within (w_lo, w_hi)
    (P4); where MG1 cannot hold the engine there (above its base speed its torque falls as 1 / w_s), the
    nearest of ``SPEED_TRIALS`` speeds across the range where it can and the engine reaches p. Returns (the
    speed, its torque p / w, feasible)."""
    w = tb.bilinear_at(best[0], best[1], best[2], p, w_r, best[3], best[4])
    w_min = max(w_lo, p / ((1.0 + s.ring_over_sun) * g.rated_torque))
    if w_min > w_hi:
        return w_hi, p / w_hi, False
    w = min(max(w, w_min), w_hi)
    if engine_speed_holds(p, w, w_r, dw_r, lines, g, s):
        return w, p / w, True
    best_w, gap = w, math.inf
    for j in range(SPEED_TRIALS):
        wj = w_min + (w_hi - w_min) * j / (SPEED_TRIALS - 1.0)
        if abs(wj - w) < gap and engine_speed_holds(p, wj, w_r, dw_r, lines, g, s):
            best_w, gap = wj, abs(wj - w)
    return best_w, p / best_w, gap < math.inf


@equation
def engine_speed_holds(p, w_c, w_r, dw_r, lines, g, s):
    """Whether the engine gives power p at speed w_c within its full-load line, and MG1 holds its reaction
    (:func:`generator_point`)."""
    t_e = p / w_c
    if t_e > tb.interp_at(w_c, lines[0], lines[1], lines[2]) * (1.0 + 1e-9):
        return False
    return generator_point(t_e, w_c, w_r, dw_r, g, s)[4]


@equation
def demand_power(interval, e, p_high):
    """The engine power that follows the demand: the ring's power demand and the accessories, within 0 and
    the engine's top power ``p_high`` (the management's choice that leaves the battery nearly idle)."""
    return min(max(interval[4] * interval[1] + e.accessory_power, 0.0), p_high)


@equation
def engine_power_choice(u, levels, p_follow, p_high):
    """The management's u-th choice of engine power: 0 (u = 0: the engine off), the demand-following power
    (u = 1, :func:`demand_power`), then ``levels`` powers evenly from 0 to ``p_high`` (u = 2 ...)."""
    if u == 0:
        return 0.0
    if u == 1:
        return p_follow
    return hy.engine_torque_level(u - 2, levels, 0.0, p_high)


@equation
def engine_power_limit(w_hi, cap_speed, cap_power, inv_cap):
    """The most the engine may give at speeds up to w_hi: the running maximum of its full-load power."""
    return tb.interp_at(w_hi, cap_speed, cap_power, inv_cap)


@equation
def line_tables(lines, best, cap):
    """(eng, opt, inv_cap) of a kernel's line arrays, as :func:`split_choice` and :func:`engine_power_limit`
    read them: ``eng`` the full-load line (speeds, torques, inverse spacing of the speeds), ``opt`` the system
    operating line (powers, ring speeds, engine speeds, inverse spacings of powers and ring speeds),
    ``inv_cap`` the inverse spacing of the full-load power's running maximum's speeds."""
    eng = (lines[0], lines[1], tb.inverse_spacing(lines[0]))
    opt = (best[0], best[1], best[2], tb.inverse_spacing(best[0]), tb.inverse_spacing(best[1]))
    return eng, opt, tb.inverse_spacing(cap[0])


@equation
def split_interval(v, a, ratio, c, e, m, g, s, tabs):
    """What an interval (speed v, acceleration a, ring-to-wheel ratio i_r) fixes whatever the management
    chooses: (v >= 0, w_r, dw_r, wheel force F_w, ring demand T_ring (E1), w_m2, dw_m2, MG2's envelope
    (T_min, T_max) at w_m2, the engine's speed range (P4), ratio)."""
    vv = v if v > 0.0 else 0.0
    w_r = vh.engine_speed(vv, ratio, c)
    dw_r = vh.engine_speed(a, ratio, c)
    f = vh.wheel_force(vv, a, c)
    w_m2 = s.mg2_ratio * w_r
    dw_m2 = s.mg2_ratio * dw_r
    t_min, t_max = el.envelope(w_m2, m, e, tabs[el.TAB_ENV_SPEED], tabs[el.TAB_ENV_MAX], tabs[el.TAB_ENV_MIN])
    w_lo, w_hi = carrier_speed_range(w_r, c, g, s)
    return vv, w_r, dw_r, f, el.shaft_torque(f, ratio, c), w_m2, dw_m2, t_min, t_max, w_lo, w_hi, ratio


@equation
def generator_point(t_e, w_c, w_r, dw_r, g, s):
    """MG1 at the engine's torque t_e and speed w_c (P1)-(P3): (w_s, dw_s, T_g, P_g DC, within its limits,
    T_r the ring's share of the engine's torque)."""
    w_s = sun_speed(w_c, w_r, s)
    dw_s = sun_speed(0.0, dw_r, s)  # the engine's speed held over the interval
    t_s, t_r = planetary_torques(t_e, s)
    t_g = -t_s + s.generator_inertia * dw_s
    ok = abs(w_s) <= g.max_speed and mc.min_torque(w_s, g) <= t_g <= mc.max_torque(w_s, g)
    return w_s, dw_s, t_g, mc.electric_power(t_g, w_s, g), ok, t_r


@equation
def engine_choice_speed(on, p, w_r, dw_r, w_lo, w_hi, lines, best, g, s):
    """(w_c, T_e, feasible) of the management's choice: at rest (0, 0, True) or running at power p
    (:func:`engine_speed_for_power`)."""
    if on > 0.0:
        return engine_speed_for_power(p, w_r, dw_r, w_lo, w_hi, lines, best, g, s)
    return 0.0, 0.0, True


@inline
def split_choice(interval, battery, on, p_e, c, e, m, g, s, tabs, lines, best):
    """The operating point of the choice (engine ``on``, power ``p_e``) at an interval
    (:func:`split_interval`) with the pack in state ``battery``; ``lines`` the engine's full-load line
    (speeds, torques, their inverse spacing), ``best`` the system operating line (powers, ring speeds, the
    engine speeds table, the two inverse spacings; :func:`system_line`). Returns the P2 point's 18 fields
    (:func:`vpsim.model.hybrid.p2_point`; its machine is MG2, its input torque the ring's demand) and then
    (w_c, w_s, T_g, P_g, dw_s, the ring's net torque, feasible)."""
    vv, w_r, dw_r, f, t_ring, w_m2, dw_m2, t_min, t_max, w_lo, w_hi, ratio = interval
    w_c, t_e, feasible = engine_choice_speed(on, p_e, w_r, dw_r, w_lo, w_hi, lines, best, g, s)
    cm18 = en.speed_power(w_c, c)
    te, t_cr, p, mdot, running = hy.engine_choice(on, on > 0.0, t_e, w_c, 0.0, cm18, c)
    w_s, dw_s, t_g, p_g, ok, t_r = generator_point(te, w_c, w_r, dw_r, g, s)
    t_m, i, u_oc, r, p_m, at_m, at_b = el.machine_and_battery_at(
        (t_ring - t_r) / s.mg2_ratio + el.rotor_torque(dw_m2, e),
        t_ring < 0.0,
        vv,
        w_m2,
        t_min,
        t_max,
        battery,
        p_g,
        e,
        m,
        tabs[el.TAB_MAP_SPEED],
        tabs[el.TAB_MAP_TORQUE],
        tabs[el.TAB_MAP_LOSS],
    )
    t_net = t_r + s.mg2_ratio * (t_m - el.rotor_torque(dw_m2, e))
    missing, brake = hy.shortfall_and_brake(f, el.wheel_force_of_shaft(t_net, ratio, c))
    feasible = choice_feasible(
        feasible, ok, p_g + p_m + e.accessory_power - el.pack_power(i, u_oc, r, r), p_g
    )
    return (
        w_m2,
        dw_m2,
        t_ring,
        te,
        t_cr,
        p,
        mdot,
        t_m,
        i,
        u_oc,
        r,
        p_m,
        brake,
        missing,
        at_m,
        at_b,
        running,
        cm18,
        w_c,
        w_s,
        t_g,
        p_g,
        dw_s,
        t_net,
        feasible,
    )


@equation
def choice_feasible(engine_ok, generator_ok, unserved, p_g):
    """1.0 where the choice is feasible: the engine reaches its power within the gear set's limits, MG1
    holds its reaction torque, and the pack takes what MG1 generates (a negative ``unserved`` power: it
    cannot, with MG2 already cut to nothing, and the power would vanish); 0.0 otherwise."""
    return 1.0 if engine_ok and generator_ok and unserved > -1e-6 * (1.0 + abs(p_g)) else 0.0


@equation
def higher_powers_dominated(point, battery):
    """Whether every engine power above this running choice's is worse for the management: the pack is at
    its charging limit, so more engine power only makes MG2's torque smaller (or MG1's power infeasible),
    the surplus going to the friction brakes, with no trace miss to close. The ECMS and DP, trying powers
    upward, stop there."""
    if point[13] > hy.MISS_TOLERANCE_N or point[16] <= 0.0:
        return False
    return point[15] > 0.0 and point[8] <= battery[3]


@equation
def split_powers(point, v, a, c, e, s):
    """Every energy term (W) of a :func:`split_choice` point, in the order of
    :data:`vpsim.model.hybrid.HYBRID_TERMS`:

    indicated + chemical = friction + pumping + engine kinetic (0: its speed held) + battery loss
                           + accessories + machine loss (MG1 + MG2) + rotor kinetic (MG1 + MG2)
                           + driveline loss + vehicle kinetic + aero + rolling + brake - trace miss - unserved
    """
    w_m2, dw_m2, t_m, p, t_cr, running, cm18 = (
        point[0],
        point[1],
        point[7],
        point[5],
        point[4],
        point[16],
        point[17],
    )
    i, u_oc, r, p_m, brake, missing = point[8], point[9], point[10], point[11], point[12], point[13]
    w_c, w_s, t_g, p_g, dw_s, t_net = point[18], point[19], point[20], point[21], point[22], point[23]
    vv = v if v > 0.0 else 0.0
    indicated, friction, pumping, engine_accessories = 0.0, 0.0, 0.0, 0.0
    if running > 0.0:
        indicated, friction, pumping = rules.engine_powers(p, w_c, t_cr, 1.0, c, cm18)
        engine_accessories = en.accessory_torque(w_c, c) * w_c
    w_r = w_m2 / s.mg2_ratio
    f_net = vh.wheel_force(vv, a, c) + brake - missing
    return (
        indicated,
        friction,
        pumping,
        0.0,
        bt.chemical_power(u_oc, i, e.coulombic_efficiency),
        bt.battery_loss(u_oc, r, i, e.coulombic_efficiency),
        e.accessory_power + engine_accessories,
        (p_g - t_g * w_s) + (p_m - t_m * w_m2),
        s.generator_inertia * dw_s * w_s + el.rotor_torque(dw_m2, e) * w_m2,
        t_net * w_r - f_net * vv,
        el.kinetic_power(vv, a, c),
        vh.aero_force(vv, c) * vv,
        vh.rolling_force(vv, c) * vv,
        brake * vv,
        missing * vv,
        p_g + p_m + e.accessory_power - el.pack_power(i, u_oc, r, r),
    )


# --- records and tables (built once per parameter set) -----------------------------------------------------

S_FIELDS = ("ring_over_sun", "mg2_ratio", "engine_max_speed", "generator_inertia")


def split_record(params):
    """The gear set's record (:data:`S_FIELDS`) of ``params.split``."""
    sp = params.split
    r = np.zeros(1, np.dtype([(n, np.float64) for n in S_FIELDS], align=True)).view(np.recarray)
    r[0] = (sp.ring_teeth / sp.sun_teeth, sp.mg2_ratio, sp.engine_max_speed, sp.generator_inertia)
    r.flags.writeable = False
    return r[0]


def generator_record(params):
    """MG1's machine record: the scalable loss model (:mod:`vpsim.model.machine`) at its rating, its losses
    times ``machine.loss_scale`` as MG2's (one drive technology: the two machines share the transaxle, the
    inverter and the pack)."""
    sp = params.split
    scale = params.machine.loss_scale
    coefficients = None
    if scale != 1.0:
        base = mc.DEFAULT_COEFFICIENTS["pm"].as_dict()
        coefficients = mc.LossCoefficients(**{k: v * scale for k, v in base.items()})
    return mc.machine_record(
        mc.MachineSpec(
            rated_power_w=sp.generator_rated_power,
            base_speed_radps=sp.generator_base_speed,
            max_speed_radps=sp.generator_max_speed,
            kind="pm",
            coefficients=coefficients,
            inertia_kgm2=sp.generator_inertia,
        )
    )


def best_efficiency_line(engine_map, w_lo, w_hi):
    """(P5) The engine's best-efficiency line over speeds [w_lo, w_hi] of its map: (powers, speeds) with
    powers uniform from 0 to its top power, each at the speed of least fuel flow (0 W: w_lo), and its
    full-load power's running maximum (speeds, powers), both as the kernels read them."""
    speeds = np.linspace(w_lo, w_hi, LINE_SPEEDS)
    t_full = np.asarray(engine_map.max_torque(speeds), float)
    p_full = np.maximum(t_full * speeds, 0.0)
    top = float(p_full.max())
    powers = np.linspace(0.0, top, LINE_POINTS)
    # every power at every speed in one evaluation (elementwise: the same numbers as power by power)
    t = powers[1:, None] / speeds[None, :]
    ok = t <= t_full[None, :] * (1.0 + 1e-12)
    fuel = np.asarray(engine_map.fuel_flow(np.where(ok, t, 0.0), speeds[None, :]), float)
    best = np.empty(LINE_POINTS)
    best[0] = w_lo
    best[1:] = speeds[np.argmin(np.where(ok, fuel, np.inf), axis=1)]
    return powers, best, speeds, np.maximum.accumulate(p_full)


def shaft_lines(engine_map, cap_speed, cap_power, c):
    """The full-load line (speeds, torques) and its power's running maximum (speeds, powers) at the engine's
    shaft, as :func:`split_choice` and :func:`engine_power_limit` read them: the crank's
    (:func:`best_efficiency_line`) less what the engine's own accessories take
    (:func:`vpsim.model.engine.accessory_torque`; none by default: the crank's lines unchanged)."""
    speeds = engine_map.max_torque_speed
    c = fields(c)
    t_acc = np.array([en.accessory_torque(float(w), c) for w in speeds])
    p_acc = np.array([en.accessory_torque(float(w), c) * w for w in cap_speed])
    return (speeds, engine_map.max_torque_values - t_acc), (cap_speed, np.maximum(cap_power - p_acc, 0.0))


# --- the management's choice at one step (every method's power split calls it) ---------------------------

RULE_TRIES = 12  # the rule's engine power, a fifth less each time the gear set cannot take it


@equation
def split_choose(
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
    k1,
):
    """The management's choice at one step of the power split (:func:`split_interval`, the
    pack in state ``battery``): (engine on, its power, whether any choice is within the gear set's limits),
    from what it knows then (the DP's cost-to-go ``jcost[k1]`` for ``ems`` dp). Every method calls it."""
    n_grid = soc_grid.size
    choice_on = 0.0
    choice_p = 0.0
    found = False
    if ems == hy.EMS_RULE:
        demand = interval[4] * interval[1]  # the ring's power demand
        if hy.rule_wants_engine(on, on_time, demand, soc, h) and runs:
            # the demand plus the charging power of the rule's load-point shift, as a torque at unit
            # speed (a power), within 0 and the engine's top power; where the gear set cannot take
            # it, a fifth less, up to RULE_TRIES times
            p_try = hy.rule_engine_torque(demand, 1.0, soc, 0.0, p_high, h)
            for _ in range(RULE_TRIES):
                pt = split_choice(interval, battery, 1.0, p_try, c, e, m, g, s, tabs, eng, opt)
                if pt[P_FEASIBLE] > 0.0:
                    choice_on, choice_p, found = 1.0, p_try, True
                    break
                p_try *= 0.8
        if not found:
            pt = split_choice(interval, battery, 0.0, 0.0, c, e, m, g, s, tabs, eng, opt)
            found = pt[P_FEASIBLE] > 0.0
        if runs:  # the trace first: where the rule's choice (pt) falls short, the power that misses least
            short = pt[13] if pt[P_FEASIBLE] > 0.0 else math.inf
            if short > hy.MISS_TOLERANCE_N:
                for u in range(1, levels + 2):
                    p_e = engine_power_choice(u, levels, p_follow, p_high)
                    q = split_choice(interval, battery, 1.0, p_e, c, e, m, g, s, tabs, eng, opt)
                    if q[P_FEASIBLE] > 0.0 and q[13] < short * (1.0 - 1e-9) - hy.MISS_TOLERANCE_N:
                        short = q[13]
                        choice_on, choice_p, found = 1.0, p_e, True
    else:
        s_factor = hy.equivalence_factor(soc, h)
        keep = ems == hy.EMS_ECMS and runs and hy.must_keep_running(on, on_time, h)
        share = hy.start_share(dt, h) if ems == hy.EMS_ECMS else 1.0
        cheapest = math.inf
        for u in range(levels + 2):
            if u > 0 and not runs:
                break
            o = 1.0 if u > 0 else 0.0
            p_e = engine_power_choice(u, levels, p_follow, p_high)
            pt = split_choice(interval, battery, o, p_e, c, e, m, g, s, tabs, eng, opt)
            if pt[P_FEASIBLE] <= 0.0:
                if u > 1:  # levels rise: MG1 holds, and the pack takes, no more of a larger power either
                    break
                continue
            if keep and u == 0:
                continue
            start = share if (u > 0 and on == 0.0) else 0.0
            if ems == hy.EMS_DP:
                nxt = soc + bt.soc_rate(pt[8], e.capacity_as, e.coulombic_efficiency) * dt
                cost = hy.ecms_cost(pt, dt, start, 0.0, c, e, h) + hy.cost_to_go(
                    jcost[k1], 1 if u > 0 else 0, nxt, soc_grid[0], soc_grid[1] - soc_grid[0], n_grid
                )
            else:
                cost = hy.ecms_cost(pt, dt, start, s_factor, c, e, h)
                if u == 0:
                    cost += hy.stop_price(on, interval[0] > 0.0, dt, h)
            if cost < cheapest:
                cheapest = cost
                choice_on = o
                choice_p = p_e
                found = True
            if u > 1 and higher_powers_dominated(pt, battery):
                break
    return choice_on, choice_p, found


@functools.lru_cache(maxsize=128)
def operating_lines(engine, machine, split):
    """The lines the power split's kernels read, from the parameter sections they depend on (``engine``,
    ``machine``, ``split`` of :class:`vpsim.params.Parameters`): the engine's shaft full-load line, the
    system operating line (powers, ring speeds, engine speeds) and its full-load power's running maximum, as
    :func:`shaft_lines` and :func:`system_line` give them, on the exact BQM fuel flow (19) the kernels burn.

    Cached per sections: a parameter set that differs only in what these lines do not read (the vehicle,
    the battery, the electric network's load, the management) reuses them. Building them takes most of a
    power split's first run (about 10 ms of NumPy against 1-2 ms for the cycle). Shared by every caller
    and left writable (a read-only array is another signature of the compiled kernels): nobody writes
    into them."""
    from types import SimpleNamespace

    from .electric import machine_spec
    from .maps import cached_engine_map
    from .record import engine_record

    p = SimpleNamespace(engine=engine, machine=machine, split=split)  # what the records below read
    engine_map = cached_engine_map(engine)
    exact = engine_map.with_exact()
    w_lo, w_hi = float(engine_record(engine).idle_speed), split.engine_max_speed
    _, _, cap_speed, cap_power = best_efficiency_line(exact, w_lo, w_hi)
    m, g, s = mc.machine_record(machine_spec(p)), generator_record(p), split_record(p)
    best = system_line(exact, w_lo, w_hi, m, g, s)
    lines, cap = shaft_lines(engine_map, cap_speed, cap_power, engine_record(engine))
    return lines, best, cap


def system_line(engine_map, w_lo, w_hi, m, g, s):
    """(P6) The system operating line: (powers, ring speeds, engine speed table[power, ring speed]) with
    powers uniform from 0 to the engine's top power and ring speeds from 0 to MG2's top speed over its
    reduction; each the engine speed in [w_lo, w_hi] of least fuel per unit of net power,
    mdot_f(P / w, w) / (P - L_g - L_m2), among the speeds where the engine reaches P, MG1 turns within its
    top speed and holds its reaction torque (P2)-(P4). The battery is taken idle (MG2 passes MG1's power,
    within its envelope; at low ring speed its torque is held at the envelope). Where no speed delivers a
    positive net power (P near 0), or none is within MG1's limits, the engine's own best-efficiency speed
    (P5). ``m``, ``g``, ``s``: MG2's and MG1's machine records and the gear set's (:func:`split_record`)."""
    m, g, s = fields(m), fields(g), fields(s)
    k = float(s.ring_over_sun)
    speeds = np.linspace(w_lo, w_hi, SYSTEM_SPEEDS)
    t_full = np.asarray(engine_map.max_torque(speeds), float)
    top = float(np.max(np.maximum(t_full * speeds, 0.0)))
    powers = np.linspace(0.0, top, SYSTEM_POWERS)
    ring = np.linspace(0.0, float(m.max_speed) / float(s.mg2_ratio), SYSTEM_RING_SPEEDS)
    p2 = powers[:, None]
    t_e = p2 / speeds[None, :]
    reach = t_e <= t_full[None, :] * (1.0 + 1e-12)
    fuel = np.asarray(engine_map.fuel_flow(np.where(reach, t_e, 0.0), speeds[None, :]), float)
    fuel = np.where(reach, fuel, np.inf)
    own = speeds[np.argmin(fuel, axis=1)]  # (P5) on this grid
    own[0] = w_lo
    t_g = -t_e / (1.0 + k)  # (P2)-(P3), the engine's speed held
    table = np.empty((powers.size, ring.size))
    for j, w_r in enumerate(ring):
        w_s = sun_speed(speeds[None, :], w_r, s)
        loss_g = mc.loss_w(t_g, w_s, g)
        w_m2 = float(s.mg2_ratio) * w_r
        t_cap = float(mc.max_torque(w_m2, m))
        p_m2 = -t_g * w_s  # the battery idle: MG2 passes what MG1 makes
        t_m2 = np.clip(p_m2 / max(w_m2, 1e-9), -t_cap, t_cap)
        net = p2 - loss_g - mc.loss_w(t_m2, w_m2, m)
        ok = reach & (np.abs(w_s) <= g.max_speed) & (np.abs(t_g) <= mc.max_torque(w_s, g)) & (net > 0.0)
        cost = np.where(ok, fuel / np.where(ok, net, 1.0), np.inf)
        best = np.argmin(cost, axis=1)
        table[:, j] = np.where(np.isfinite(cost[np.arange(powers.size), best]), speeds[best], own)
    return powers, ring, table
