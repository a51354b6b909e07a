"""The parallel P2 hybrid: the engine, a disconnect clutch and the machine on the gearbox's input shaft,
written once from the components (the engine of :mod:`vpsim.model.engine`, the machine and battery of
:mod:`vpsim.model.electric`), and its energy management's choices.

Layout (the Hyundai/Kia hybrids): engine -> clutch -> machine -> stepped gearbox -> wheels. With the clutch
closed the engine and the machine turn at the gearbox's input speed w = i v / r ((14), (17)); with it open the
engine stands still and the car drives (or brakes) on the machine alone. The engine runs only at or above
its idle speed (below it the car launches electrically: what P2 hybrids do).

At each instant the management chooses whether the engine runs and, if so, its torque T_e between its
closed-throttle and full-load lines (the generated map's). The input shaft needs (H1)

    T_in = F_w r / (i eta) (driving) or F_w r eta / i (braking)      (E1 through the gearbox)

and the machine gives the rest, T_m = T_in - T_e + J_m dw (its rotor's inertia; the engine's, J_e dw, is in
its crank torque T_cr = T_e + J_e dw, (1)), within its envelope and the battery's limits
(:func:`vpsim.model.electric.machine_and_battery`; a braking demand's regenerative share). What the two give
short of a driving demand is a trace miss; what they give beyond a braking demand the friction brakes take.
The engine's fuel is the model's own at its crank torque (the BQM (19), as the backward method's). An engine
start costs ``hybrid.engine_start_fuel`` of fuel (cranking and enrichment, a documented constant) and is
counted.

Energy management (``hybrid.ems``):

* ``rule``: the engine starts when the input power demand exceeds ``engine_on_power`` or the charge falls
  below ``soc_low``, and stops below ``engine_off_power`` once it ran ``min_on_time`` and the charge is back
  above ``soc_low + soc_hysteresis``; running, it gives the demand plus a charging power that grows from 0 at
  ``soc_target`` to ``charge_power`` at ``soc_low`` (a load-point shift).
* ``ecms``: at each step the choice (engine off, or one of ``torque_levels`` torques between its lines)
  that minimises mdot_f + s P_chem / q_hv, the battery's chemical power made fuel by the equivalence factor
  s = ``ecms_factor`` + ``ecms_gain`` (soc_target - soc) (causal: what a car's controller can run); a
  start adds its fuel. With ``ecms_min_on_time`` T > 0 an engine it starts stays on for T, the start adds
  dt / T of its fuel and a stop while moving the same (the restart it commits to).
* ``dp``: dynamic programming on the backward model over a state-of-charge grid (and the engine's on/off
  state, for the starts' fuel): the least fuel that ends the cycle at or above its starting charge, the lower
  bound the causal controllers are judged against.
"""

from __future__ import annotations

import math

from . import battery as bt
from . import electric as el
from . import engine as en
from . import rules
from . import tables as tb
from . import vehicle as vh
from .engine import equation, inline

EMS_RULE, EMS_ECMS, EMS_DP = 0, 1, 2
MISS_PENALTY = 1.0e3  # the price of a trace miss in the ECMS and DP: its wheel work's fuel, a thousand times
MISS_TOLERANCE_N = 1e-9
EMS_CODES = {"rule": EMS_RULE, "ecms": EMS_ECMS, "dp": EMS_DP}


@equation
def engine_lines(w, line_speed, line_max, line_min, inv_line, c):
    """(lowest, highest) torque the management may ask of the running engine at speed w, at its shaft: from
    zero (below it a real engine would cut its fuel, and a hybrid opens its clutch instead: the engine off)
    or its closed-throttle line if that is higher, to its full-load line (the generated map's lines) less
    what its own accessories take (:func:`vpsim.model.engine.accessory_torque`; 0 by default)."""
    t_closed = tb.interp_at(w, line_speed, line_min, inv_line)
    return max(t_closed, 0.0), tb.interp_at(w, line_speed, line_max, inv_line) - en.accessory_torque(w, c)


@equation
def can_run(w, c):
    """The engine may run (clutch closed) at or above its idle speed."""
    return w >= c.idle_speed


@equation
def p2_point(v, a, ratio, gear, soc, on, t_e, c, e, m, tabs, h):
    """The P2 hybrid's operating point at speed v, acceleration a in the gear ``gear`` (1-based) of total
    ratio i, with the
    engine on (``on`` > 0, crank torque from ``t_e``, its torque at the shaft) or off (H1). Returns
    (w, dw, T_in, T_e, T_cr, p_i, mdot_f, T_m, I, U_oc, R, P_machine, brake N, missing N, at the machine's
    limit, at the battery's limit, engine on, c_m^1.8).

    Written as its two parts: what the interval fixes (:func:`p2_interval`, and the pack's state at this
    charge, :func:`vpsim.model.electric.battery_state`), and what the management's choice adds
    (:func:`p2_choice`); the management, trying many choices at one interval, evaluates the first once."""
    soc_grid, ocv, r_dis, r_chg = tabs[el.TAB_SOC], tabs[el.TAB_OCV], tabs[el.TAB_R_DIS], tabs[el.TAB_R_CHG]
    battery = el.battery_state(soc, e, soc_grid, ocv, r_dis, r_chg)
    return p2_choice(p2_interval(v, a, ratio, gear, c, e, m, tabs, h), battery, on, t_e, c, e, m, tabs, h)


@equation
def p2_interval(v, a, ratio, gear, c, e, m, tabs, h):
    """What an interval (speed v, acceleration a, total ratio i of the 1-based ``gear``) fixes whatever the
    management chooses: (v >= 0, w, dw, wheel force F_w, input-shaft demand T_in (H1), the engine may run,
    c_m^1.8 at w, the machine's envelope (T_min, T_max) at its own speed, the ratio i, the clutch's state,
    the torque ratio from the machine's shaft to the gearbox's input).

    The P2 (``h.mild`` 0): w is the machine's speed, the clutch always closed for the machine. Without a
    torque converter, or with its lock-up clutch closed (:func:`vpsim.model.vehicle.converter_locked`), the
    machine turns at the gearbox input's speed and the ratio is 1. With a converter between machine and
    gearbox (the longitudinal 10-speed P2s of Ford and Toyota) and its lock-up clutch open, the machine (and
    the engine with it) is the pump (:func:`vpsim.model.vehicle.converter_pump_point`): w the pump's speed,
    T_in the pump's torque, the ratio mu(nu); it passes traction only (the clutch's state "slipping"), a
    braking demand goes to the friction brakes. The mild hybrid (``h.mild`` 1, :func:`mild_clutch`): w is
    the crank's speed (the machine turns at ``h.belt_ratio`` w), held at the idle speed while the clutch
    slips or is open. A mild hybrid with a torque converter (the automatics of BMW, Mercedes, RAM, Volvo,
    Jaguar Land Rover) has it in the clutch's place while its lock-up is open: with traction the crank is
    the pump (:func:`vpsim.model.vehicle.converter_engine_point`, the engine car's converter: w the pump's
    speed, at idle or above, T_in its torque, the ratio mu(nu); the clutch's state "converter"), without
    the converter passes nothing (the state "open"): no recuperation below lock-up."""
    vv = v if v > 0.0 else 0.0
    w = vh.engine_speed(vv, ratio, c)
    dw = vh.engine_speed(a, ratio, c)
    f = vh.wheel_force(vv, a, c)
    t_in = el.shaft_torque(f, ratio, c)
    clutch = CLUTCH_CLOSED
    mu = 1.0
    unlocked = not vh.converter_locked(gear, vv, c)
    if h.mild == 0.0 and unlocked:
        w, dw, t_in, mu, _ = vh.converter_pump_point(w, dw, t_in, c)
        clutch = CLUTCH_SLIPPING  # the open converter passes a driving torque only
    runs = can_run(w, c)
    if h.mild > 0.0:
        runs = True  # on the crank, the engine may idle at rest (the clutch open)
        if unlocked and t_in > 0.0:  # the crank drives the converter's pump, at idle speed or above
            w, dw, t_in, mu, _ = vh.converter_engine_point(w, dw, t_in, c)
            clutch = CLUTCH_CONVERTER
        elif unlocked:  # no traction: the unlocked converter passes none, the crank is free
            clutch = CLUTCH_OPEN
        else:
            clutch = mild_clutch(vv, w, t_in, c)
        if clutch == CLUTCH_OPEN or clutch == CLUTCH_SLIPPING:
            w = c.idle_speed
            dw = 0.0
    t_min, t_max = el.envelope(
        h.belt_ratio * w, m, e, tabs[el.TAB_ENV_SPEED], tabs[el.TAB_ENV_MAX], tabs[el.TAB_ENV_MIN]
    )
    t_max *= h.assist_share  # the mild hybrid's assist: a share of the motoring envelope (1: all of it)
    return vv, w, dw, f, t_in, runs, en.speed_power(w, c), t_min, t_max, ratio, clutch, mu


@inline
def p2_choice(interval, battery, on, t_e, c, e, m, tabs, h):
    """The operating point (as :func:`p2_point` returns it) of the choice (engine ``on``, torque ``t_e``) at
    an interval (:func:`p2_interval`) with the pack in state ``battery``
    (:func:`vpsim.model.electric.battery_state`). The mild hybrid's engine with ``on`` 0 is dragged with its
    fuel cut (``t_e`` then its closed-throttle crank torque) while the clutch is closed, else stopped
    (:func:`mild_engine_choice`); its machine acts on the crank through the belt (:func:`belt_to_crank`)."""
    vv, w0, dw0, f, t_in, runs, cm18, t_min, t_max, ratio, clutch, mu = interval
    te, t_cr, p, mdot, running, w, dw = engine_of_choice(on, runs, clutch, t_e, w0, dw0, cm18, c, h)
    passing = clutch_passing(clutch, running)
    t_pass = clutch_passes(t_in, passing)  # the demand the clutch passes to the crank's side
    t_ask = crank_to_belt(t_pass - te + el.rotor_torque(dw, e), h)
    t_mb, i, u_oc, r, p_m, at_m, at_b = el.machine_and_battery_at(
        t_ask,
        t_pass < 0.0,
        vv,
        h.belt_ratio * w,
        t_min,
        t_max,
        battery,
        0.0,
        e,
        m,
        tabs[el.TAB_MAP_SPEED],
        tabs[el.TAB_MAP_TORQUE],
        tabs[el.TAB_MAP_LOSS],
    )
    t_m = belt_to_crank(t_mb, h)
    t_net = te + t_m - el.rotor_torque(dw, e)
    t_net_passed = clutch_passes(t_net, passing)
    missing, brake = shortfall_and_brake(f, el.wheel_force_of_shaft(mu * t_net_passed, ratio, c))
    return (
        w,
        dw,
        t_in,
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
    )


@equation
def engine_of_choice(on, runs, clutch, t_e, w, dw, cm18, c, h):
    """(T_e, T_cr, p_i, mdot_f, turning, w, dw) of the choice: the P2's engine (:func:`engine_choice`) or
    the mild hybrid's (:func:`mild_engine_choice`), with the crank's speed and acceleration (0 where the
    mild hybrid's engine, and the machine on its crank, stand)."""
    if h.mild > 0.0:
        te, t_cr, p, mdot, running = mild_engine_choice(on, clutch, t_e, w, dw, cm18, c)
        if running <= 0.0:
            return te, t_cr, p, mdot, running, 0.0, 0.0
        return te, t_cr, p, mdot, running, w, dw
    te, t_cr, p, mdot, running = engine_choice(on, runs, t_e, w, dw, cm18, c)
    return te, t_cr, p, mdot, running, w, dw


@equation
def clutch_passing(clutch, running):
    """The clutch's state for the torque it passes with the engine ``running`` (1) or stopped (0): a mild
    hybrid's stopped crank turns no pump, so its unlocked converter passes nothing ("open")."""
    if clutch == CLUTCH_CONVERTER and running <= 0.0:
        return CLUTCH_OPEN
    return clutch


@equation
def clutch_passes(t_net, clutch):
    """The torque the clutch passes of ``t_net`` (the net torque on its engine side, or the gearbox's
    demand): all of it closed, none open, only a driving torque slipping (a slipping clutch passes no
    braking)."""
    if clutch == CLUTCH_OPEN:
        return 0.0
    if clutch == CLUTCH_SLIPPING or clutch == CLUTCH_CONVERTER:
        return t_net if t_net > 0.0 else 0.0
    return t_net


# the clutch between the mild hybrid's crank and its gearbox (the P2's machine is always behind it: closed);
# CLUTCH_CONVERTER: a mild hybrid's unlocked torque converter with traction, the crank its pump
CLUTCH_OPEN, CLUTCH_CLOSED, CLUTCH_SLIPPING, CLUTCH_CONVERTER = 0, 1, 2, 3


@equation
def mild_clutch(v, w, t_in, c):
    """The mild hybrid's clutch (as the engine car's, :mod:`vpsim.model.rules`): closed at and above the
    idle speed while moving; below it slipping with traction demanded (the engine held at idle), open
    without (and at rest)."""
    if v > 0.0 and w >= c.idle_speed:
        return CLUTCH_CLOSED
    if v > 0.0 and t_in > 0.0:
        return CLUTCH_SLIPPING
    return CLUTCH_OPEN


@equation
def mild_engine_choice(on, clutch, t_e, w, dw, cm18, c):
    """(T_e, T_cr, p_i, mdot_f, turning) of the mild hybrid's engine: fired (``on`` > 0) with torque ``t_e``
    as :func:`engine_choice`; not fired with the clutch closed, dragged by the wheels with its fuel cut (crank
    torque the motoring torque (2)-(6) without (4) at the closed-throttle line's pressure, ``t_e`` then that
    line's crank torque at w, :func:`closed_line`; turning, no fuel; the wheels drive its accessories too);
    not fired with the clutch open or slipping, stopped."""
    if on > 0.0:
        return engine_choice(on, True, t_e, w, dw, cm18, c)
    if clutch != CLUTCH_CLOSED:
        return 0.0, 0.0, 0.0, 0.0, 0.0
    p = en.intake_pressure_for_torque(t_e, w, c, cm18)
    t_cr = en.motoring_torque(p, w, c, cm18)
    return t_cr - vh.inertia_torque(dw, c) - en.accessory_torque(w, c), t_cr, p, 0.0, 1.0


@equation
def closed_line(w, line_speed, line_min, inv_line):
    """The engine's closed-throttle crank torque at w (the generated map's line)."""
    return tb.interp_at(w, line_speed, line_min, inv_line)


@equation
def belt_to_crank(t_machine, h):
    """The machine's torque at the crank through a belt of ratio k and efficiency eta (k = 1, eta = 1: on the
    crank, or the P2's shaft): k eta T driving, k T / eta generating."""
    k = h.belt_ratio
    return t_machine * k * h.belt_efficiency if t_machine > 0.0 else t_machine * k / h.belt_efficiency


@equation
def crank_to_belt(t_crank, h):
    """The machine torque that gives ``t_crank`` at the crank (:func:`belt_to_crank` inverted)."""
    k = h.belt_ratio
    return t_crank / (k * h.belt_efficiency) if t_crank > 0.0 else t_crank * h.belt_efficiency / k


@equation
def engine_choice(on, runs, t_e, w, dw, cm18, c):
    """(T_e, T_cr, p_i, mdot_f, 1.0) of the engine asked to run (``on`` > 0, and it ``runs`` at w: its
    idle speed) with torque ``t_e`` at speed w (``cm18`` its c_m^1.8): its crank torque (1) with what the
    engine's own accessories take (``engine.accessory_power``: belt-driven pumps and compressor, turning
    with the engine only; the hybrids' electric loads are ``electric.accessory_power``), the BQM's intake
    pressure and fuel (19); all zero if it stands."""
    if not (on > 0.0 and runs):
        return 0.0, 0.0, 0.0, 0.0, 0.0
    t_cr = t_e + vh.inertia_torque(dw, c) + en.accessory_torque(w, c)
    p = en.intake_pressure_for_torque(t_cr, w, c, cm18)
    return t_e, t_cr, p, en.fuel_flow(p, w, c), 1.0


@equation
def shortfall_and_brake(f_demand, f_given):
    """(force missing, force the friction brakes take) of a wheel-force demand met by ``f_given``."""
    return max(f_demand - f_given, 0.0), max(f_given - f_demand, 0.0)


@equation
def higher_torques_dominated(point, battery):
    """Whether every engine torque above this running choice's is worse for the management (a
    :func:`p2_choice` point, the pack in state ``battery``): the machine is held at its charging side's
    limit (its generating envelope, or the torque whose current is the pack's charging limit), so a larger
    engine torque leaves the machine's torque and the battery's current as they are (up to the rounding of
    the limit's root, :func:`vpsim.model.electric.torque_for_power`) and only burns more fuel (the fuel
    rises with the torque), its surplus going to the friction brakes; with no trace miss to close. The ECMS
    and the DP, trying torques upward, stop there."""
    t_m, i, at_m, at_b, missing = point[7], point[8], point[14], point[15], point[13]
    if missing > MISS_TOLERANCE_N or point[16] <= 0.0:
        return False
    return (at_m > 0.0 and t_m < 0.0) or (at_b > 0.0 and i <= battery[3])


@equation
def follow_torque(interval, t_low, t_high):
    """The demand-following engine torque: the input demand at the crank (:func:`p2_interval`), within the
    engine's lines, so that the machine gives or takes nothing beyond what the lines leave (the rule's
    choice at its target charge; the power split's demand-following power, :func:`.split.demand_power`).
    The ECMS and the DP try it beside their evenly spaced levels: a step between two levels costs the
    machine's and the pack's losses both ways where following the demand costs none."""
    return min(max(interval[4], t_low), t_high)


@equation
def engine_choice_torque(u, levels, t_low, t_high, t_off, interval):
    """The management's u-th choice of engine torque: ``t_off`` (u = 0: the engine not fired), the
    demand-following torque (u = 1, :func:`follow_torque`), then ``levels`` torques evenly between its
    lowest and highest (u = 2 ...)."""
    if u == 0:
        return t_off
    if u == 1:
        return follow_torque(interval, t_low, t_high)
    return engine_torque_level(u - 2, levels, t_low, t_high)


@equation
def engine_torque_level(j, levels, t_low, t_high):
    """The j-th (0-based) of ``levels`` engine torques evenly between its lowest and highest torque
    (:func:`engine_lines`)."""
    return t_low + (t_high - t_low) * j / (levels - 1.0)


@equation
def equivalence_factor(soc, h):
    """s = s0 + k (soc_target - soc): the ECMS's price of battery energy in fuel energy."""
    return h.ecms_factor + h.ecms_gain * (h.soc_target - soc)


@equation
def start_share(dt, h):
    """The share of a start's fuel the ECMS charges to the step that starts the engine: all of it, or, with a
    minimum on time T (the engine kept running for T once started), dt / T of it (the start amortised over
    the run it commits to)."""
    if h.ecms_min_on_time > 0.0:
        return min(dt / h.ecms_min_on_time, 1.0)
    return 1.0


@equation
def stop_price(on, moving, dt, h):
    """The ECMS's price of stopping a running engine while the car moves, with a minimum on time T: the
    restart the stop commits to, its fuel amortised over T as a start's is (:func:`start_share`); 0 without
    T, at rest, or with the engine already off."""
    if on > 0.0 and moving and h.ecms_min_on_time > 0.0:
        return h.engine_start_fuel * min(dt / h.ecms_min_on_time, 1.0)
    return 0.0


@equation
def must_keep_running(on, on_time, h):
    """The ECMS keeps an engine it started running until it has run ``ecms_min_on_time``."""
    return on > 0.0 and on_time < h.ecms_min_on_time


@equation
def fuel_equivalent(energy_j, efficiency, c):
    """The fuel (kg) whose heating value at ``efficiency`` is ``energy_j``."""
    return energy_j / (efficiency * c.fuel_heating_value)


@equation
def ecms_cost(point, dt, start, s_factor, c, e, h):
    """The cost of one choice over dt (kg of fuel): its fuel, the battery's chemical energy at the
    equivalence factor s (0 for the DP, whose cost-to-go prices the charge), ``start`` times a start's fuel
    (1 or 0 for the DP; the ECMS's share, :func:`start_share`), and a trace miss at a prohibitive price.

    The chemical energy is the stored energy's change, charge counted at the pack's coulombic efficiency
    (B3), as the state of charge (and the DP's cost-to-go) counts it: priced at U_oc I instead, a charging
    current would be credited with the 1 - eta_c of it the pack does not keep, and the ECMS, paid for a
    round trip's loss, would cycle the pack (at eta_c = 0.95, the power-split's, it pulsed the engine: it
    charged hard and glided on the battery, 0.57 MJ of battery loss on HWFET against the DP's 0.17)."""
    mdot = point[6]
    chem = bt.chemical_power(point[9], point[8], e.coulombic_efficiency)
    cost = mdot * dt + s_factor * fuel_equivalent(chem * dt, 1.0, c) + start * h.engine_start_fuel
    if point[13] > MISS_TOLERANCE_N:
        cost += miss_cost(point, dt, c)
    return cost


@equation
def miss_cost(point, dt, c):
    """The trace miss's part of :func:`ecms_cost` (kg): the wheel work the choice leaves undone over dt, its
    fuel at the heating value, MISS_PENALTY times over; 0 without a miss."""
    missing = point[13]
    if missing > MISS_TOLERANCE_N:  # the machine's speed stands in for the vehicle's (same sign, > 0 moving)
        return MISS_PENALTY * fuel_equivalent(missing * (point[0] + 1.0) * dt, 1.0, c)
    return 0.0


@equation
def less_unavoidable_miss(cost, least_miss):
    """The DP's cost-to-go at one state less the price of the least trace miss any choice there leaves (0
    where one follows the trace). The choice at the state is the same (the price is a constant there); what
    changes is that a charge is not worth more for shrinking a miss no choice can avoid. With the price in,
    the DP bought a smaller unavoidable miss with fuel: on the power split's US06, where MG1 and the pack's
    current cap the hardest accelerations at any charge, it charged to the top of its grid (0.60 -> 0.70)
    for a higher pack voltage there, and was no longer the lower bound of the fuel the causal managements
    are judged against (docs/model.md, "Energy management")."""
    if least_miss < math.inf and least_miss > 0.0:
        return cost - least_miss
    return cost


@equation
def running_cost_convex(c, e):
    """Whether the ECMS's cost of the running choices is convex in the engine's torque, so that the cheapest
    of its levels is found by walking downhill (:func:`ecms_cheapest_level`) instead of trying them all.

    It is where the fuel is affine in the torque (the BQM (19): p_i affine in T_cr, the fuel (7) affine in
    p_i; not with a boosted engine's enrichment, whose cap bends it down) and the machine's DC power convex
    in its torque (the scalable loss model: k0 + k_sw |tau| + k_cu tau^2 ..., not a measured map's
    bilinear table): the machine's torque is the demand less the engine's (linear; a braking demand's
    regenerative share makes it piecewise linear and convex), the pack's current convex and increasing in
    its power (B2) and the chemical power convex and increasing in the current (B3, charge at eta_c < 1),
    and where the machine or the pack is at its limit the cost is the fuel plus a constant, or a trace
    miss's price falling steeper than the fuel rises."""
    return c.enrichment_slope == 0.0 and e.measured_machine <= 0.0


@equation
def pack_covers_no_drive(interval, battery, e, m, map_speed, map_torque, map_loss):
    """Whether the pack's discharge limit covers the accessories and what the machine draws at any torque
    from its generating limit to zero at this step's speed (its DC power is convex in the torque, so the
    most is at one end). Where it does not (a pack at its empty end), a generating choice can leave the
    accessories unserved and its current clamped, and the ECMS's cost is no longer convex: the step takes
    the exhaustive search."""
    w, t_min = interval[1], interval[7]
    u_oc, r_d, r_c, i_lo, i_hi = battery
    draw = max(
        el.machine_power(0.0, w, m, e, map_speed, map_torque, map_loss),
        el.machine_power(t_min, w, m, e, map_speed, map_torque, map_loss),
    )
    return el.pack_power(i_hi, u_oc, r_d, r_c) > (e.accessory_power + max(draw, 0.0)) * (1.0 + 1e-9) + 1e-6


@inline
def ecms_level_cost(j, interval, battery, start, s_factor, dt, levels, t_low, t_high, c, e, m, tabs, h):
    """(ECMS cost, higher torques dominated, the point) of the running choice at torque level j."""
    pt = p2_choice(interval, battery, 1.0, engine_torque_level(j, levels, t_low, t_high), c, e, m, tabs, h)
    return ecms_cost(pt, dt, start, s_factor, c, e, h), higher_torques_dominated(pt, battery), pt


@equation
def ecms_cheapest_level(
    interval, battery, start, s_factor, dt, levels, t_low, t_high, guess, c, e, m, tabs, h
):
    """(cost, level, its point) of the cheapest running choice of the ECMS where its cost is convex in the
    engine's torque (:func:`running_cost_convex`): from the level ``guess``, downhill to the first level
    whose neighbours cost no less. The level the exhaustive search (every level upward, the first strict
    minimum, none above a dominated one) finds: ties go to the lower level, and no walk goes above a
    dominated one."""
    j = min(max(guess, 0), levels - 1)
    cj, dom, pj = ecms_level_cost(
        j, interval, battery, start, s_factor, dt, levels, t_low, t_high, c, e, m, tabs, h
    )
    if j + 1 < levels and not dom:
        cu, du, pu = ecms_level_cost(
            j + 1, interval, battery, start, s_factor, dt, levels, t_low, t_high, c, e, m, tabs, h
        )
        if cu < cj:
            j, cj, dom, pj = j + 1, cu, du, pu
            while j + 1 < levels and not dom:
                cu, du, pu = ecms_level_cost(
                    j + 1, interval, battery, start, s_factor, dt, levels, t_low, t_high, c, e, m, tabs, h
                )
                if not cu < cj:
                    break
                j, cj, dom, pj = j + 1, cu, du, pu
            return cj, j, pj
    while j > 0:
        cd, _, pd = ecms_level_cost(
            j - 1, interval, battery, start, s_factor, dt, levels, t_low, t_high, c, e, m, tabs, h
        )
        if cd > cj:
            break
        j, cj, pj = j - 1, cd, pd
    return cj, j, pj


@equation
def rule_engine_torque(t_in, w, soc, t_low, t_high, h):
    """The rule's engine torque: the input demand plus a charging power that grows from 0 at soc_target to
    charge_power at soc_low (a load-point shift), within the engine's lines."""
    span = h.soc_target - h.soc_low
    share = (h.soc_target - soc) / span if span > 0.0 else 1.0
    share = min(max(share, 0.0), 1.0)
    t = t_in + share * h.charge_power / w
    return min(max(t, t_low), t_high)


@equation
def mild_rule(interval, soc, t_low, t_high, h):
    """The mild hybrid's rule: (engine fired, its torque). At rest, or slowing below the idle speed (the
    clutch open), the engine stops unless the charge is below ``soc_low`` (then it idles and charges at
    :func:`rule_engine_torque`'s power). With the clutch closed and no traction demanded it is dragged with
    its fuel cut while the machine recuperates. Otherwise it is fired: the demand plus the charging power of
    :func:`rule_engine_torque` below ``soc_target``; above it, less the same share of ``charge_power`` (the
    machine's assist: the charge above the target spent); within its lines (the machine gives the rest)."""
    w, t_in, clutch = interval[1], interval[4], interval[10]
    if clutch == CLUTCH_OPEN:
        if soc < h.soc_low:
            return 1.0, rule_engine_torque(0.0, w, soc, t_low, t_high, h)
        return 0.0, 0.0
    if clutch == CLUTCH_CLOSED and t_in <= 0.0 and soc >= h.soc_low:
        return 0.0, 0.0
    if soc <= h.soc_target:
        return 1.0, rule_engine_torque(t_in, w, soc, t_low, t_high, h)
    span = h.soc_target - h.soc_low
    share = (soc - h.soc_target) / span if span > 0.0 else 1.0
    share = min(share, 1.0)
    t = t_in - share * h.charge_power / w
    return 1.0, min(max(t, t_low), t_high)


@equation
def hybrid_powers(point, v, a, c, e):
    """(indicated, friction, pumping, engine kinetic, chemical, battery loss, accessories, machine loss,
    rotor kinetic, driveline loss, vehicle kinetic, aero, rolling, brake, trace miss, unserved) power (W) of
    a :func:`p2_point`:

    indicated + chemical = friction + pumping + engine kinetic + battery loss + accessories + machine loss
                           + rotor kinetic + driveline loss + vehicle kinetic + aero + rolling + brake
                           - trace miss - unserved
    """
    w, dw, t_in, te, t_cr, p, mdot, t_m, i, u_oc, r, p_m, brake, missing, at_m, at_b, running, cm18 = point
    vv = v if v > 0.0 else 0.0
    indicated, friction, pumping = 0.0, 0.0, 0.0
    engine_kinetic = 0.0
    engine_accessories = 0.0
    if running > 0.0:  # fired, or (a mild hybrid's) dragged with its fuel cut: no fuel, no indicated work
        indicated, friction, pumping = rules.engine_powers(p, w, t_cr, 1.0 if mdot != 0.0 else 0.0, c, cm18)
        engine_kinetic = vh.inertia_torque(dw, c) * w
        engine_accessories = en.accessory_torque(w, c) * w
    rotor = el.rotor_torque(dw, e) * w
    f_net = vh.wheel_force(vv, a, c) + brake - missing
    t_net = te + t_m - el.rotor_torque(dw, e)
    p_terminal = el.pack_power(i, u_oc, r, r)
    return (
        indicated,
        friction,
        pumping,
        engine_kinetic,
        bt.chemical_power(u_oc, i, e.coulombic_efficiency),
        bt.battery_loss(u_oc, r, i, e.coulombic_efficiency),
        e.accessory_power + engine_accessories,
        p_m - t_m * w,
        rotor,
        t_net * w - f_net * vv,
        el.kinetic_power(vv, a, c),
        vh.aero_force(vv, c) * vv,
        vh.rolling_force(vv, c) * vv,
        brake * vv,
        missing * vv,
        p_m + e.accessory_power - p_terminal,
    )


# the engine's terms, then the electric powertrain's (hybrid_powers returns them in this order)
HYBRID_TERMS = ("indicated", "friction", "pumping", "engine_kinetic", *el.ELECTRIC_TERMS)


# the management's settings as a record compiled code reads (numbers of params.hybrid)
H_FIELDS = (
    "soc_target",
    "engine_on_power",
    "engine_off_power",
    "soc_low",
    "soc_hysteresis",
    "charge_power",
    "min_on_time",
    "ecms_factor",
    "ecms_gain",
    "engine_start_fuel",
    "ecms_min_on_time",
)
# the layout's numbers the same record carries: the mild hybrid's (1) or not (0), the belt between its machine
# and the crank (params.mild; ratio and efficiency 1 for the P2's machine on the gearbox's shaft)
# and the share of its motoring envelope the mild hybrid's system uses as assist (params.mild; 1 for the P2)
H_LAYOUT_FIELDS = ("mild", "belt_ratio", "belt_efficiency", "assist_share")


def rotor_at_crank(params):
    """The parameters whose machine's rotor inertia is referred to the shaft the kernel turns: a mild
    hybrid's belt of ratio k makes J_m k^2 at the crank (the P2's and a P1's: J_m)."""
    if params.powertrain.type != "mhev" or params.mild.belt_ratio == 1.0:
        return params
    from .record import memo

    return memo(
        params,
        "rotor_at_crank",
        lambda p: p.with_changes(machine={"inertia": p.machine.inertia * p.mild.belt_ratio**2}),
    )


def hybrid_record(params):
    """The record of ``params.hybrid``'s numbers (:data:`H_FIELDS`) and the layout's
    (:data:`H_LAYOUT_FIELDS`)."""
    import numpy as np

    names = H_FIELDS + H_LAYOUT_FIELDS
    h = np.zeros(1, np.dtype([(n, np.float64) for n in names], align=True)).view(np.recarray)
    mild = params.powertrain.type == "mhev"
    ml = params.mild
    layout = (1.0, ml.belt_ratio, ml.belt_efficiency, ml.assist_share) if mild else (0.0, 1.0, 1.0, 1.0)
    h[0] = tuple(float(getattr(params.hybrid, n)) for n in H_FIELDS) + tuple(float(x) for x in layout)
    h.flags.writeable = False
    return h[0]


# --- the energy management's parts every hybrid layout shares ----------------------------------------------


@equation
def rule_wants_engine(on, on_time, demand, soc, h):
    """The rule's engine state: it starts when the demand power exceeds ``engine_on_power`` or the charge
    falls below ``soc_low``; it stops below ``engine_off_power`` once it ran ``min_on_time`` and the charge is
    back above ``soc_low + soc_hysteresis`` (hysteresis both in power and in charge)."""
    if on > 0.0:
        return not (
            demand < h.engine_off_power and on_time >= h.min_on_time and soc > h.soc_low + h.soc_hysteresis
        )
    return demand > h.engine_on_power or soc < h.soc_low


@equation
def cost_to_go(jnext, s_on, soc, soc0, dsoc, n):
    """The DP's cost-to-go J_{k+1}(soc, s_on), linear on the grid; beyond it, the end value plus a steep slope
    (beyond the top: no gain; below the bottom: the grid's steepest slope, times 10)."""
    x = (soc - soc0) / dsoc
    if x <= 0.0:
        slope = (jnext[0, s_on] - jnext[1, s_on]) / dsoc
        return jnext[0, s_on] + 10.0 * max(slope, 0.0) * (-x * dsoc) + 1e-3 * (-x)
    if x >= n - 1.0:
        return jnext[n - 1, s_on]
    j = int(x)
    f = x - j
    return jnext[j, s_on] * (1.0 - f) + jnext[j + 1, s_on] * f


def dp_grid(params):
    """The DP's state-of-charge grid: ``dp_soc_points`` over ``soc_target`` +- ``dp_soc_span`` / 2, within the
    battery's window."""
    import numpy as np

    h, b = params.hybrid, params.battery
    lo = max(b.soc_min, h.soc_target - 0.5 * h.dp_soc_span)
    hi = min(b.soc_max, h.soc_target + 0.5 * h.dp_soc_span)
    return np.linspace(lo, hi, h.dp_soc_points)


def terminal_cost(params, grid, soc_start):
    """J_K(soc): no cost at or above the start's charge; below it, the charge's energy made fuel at a fifth of
    the heating value, ten times over (steep enough that the optimum ends charge-sustaining)."""
    import numpy as np

    from .electric import pack_of
    from .record import kernel_records

    pk = pack_of(params)
    u_mid = float(np.interp(soc_start, pk.soc, pk.ocv_v))
    per_soc = fuel_equivalent(pk.capacity_as * u_mid, 0.2, kernel_records(params)[0])
    deficit = np.maximum(soc_start - grid, 0.0)
    return np.repeat((10.0 * per_soc * deficit)[:, None], 2, axis=1)


def charge_sustaining_fuel(fuel_kg, terms, q_hv) -> tuple[float, float]:
    """(fuel corrected for the battery's net energy change, that change relative to the fuel's energy).

    SAE J1711's charge-balance rule: a net energy change within 1 % of the fuel's energy needs no correction;
    beyond it the fuel is corrected (:func:`battery_corrected_fuel`)."""
    import math

    fuel_energy = fuel_kg * q_hv
    if fuel_energy <= 0.0:
        return fuel_kg, math.nan
    ratio = terms["chemical"] / fuel_energy  # energy the battery gave (negative: it was charged)
    if abs(ratio) <= 0.01:
        return fuel_kg, ratio
    return battery_corrected_fuel(fuel_kg, terms, q_hv), ratio


def battery_corrected_fuel(fuel_kg, terms, q_hv) -> float:
    """The fuel corrected for the battery's net energy change whatever its size (no 1 % band): the figure
    that varies smoothly with a run's end charge, to compare runs whose changes fall on either side of
    J1711's band. J1711 corrects by the slope of fuel against energy change over several tests; from one
    run, the engine's own average efficiency over it (crank work over fuel energy) times a charging path
    of 0.9 (machine generating and battery charging) stands for that slope, documented in docs/model.md."""
    import math

    fuel_energy = fuel_kg * q_hv
    if fuel_energy <= 0.0:
        return fuel_kg
    crank = terms["indicated"] - terms["friction"] - terms["pumping"]
    eta = crank / fuel_energy * 0.9
    if not eta > 0.0:
        return math.nan
    return fuel_kg + terms["chemical"] / (q_hv * eta)


def electric_figures(params, terms, fuel_kg, distance_m, soc_start, soc_end, regen_j, starts, on_s, ems):
    """The charge-sustaining and electric figures of a hybrid's run (its ``Result.electric``): the
    J1711-corrected fuel (:func:`charge_sustaining_fuel`), the battery's net energy per km, the charge at
    both ends, the regenerated energy, the engine's starts and running time."""
    import math

    q_hv, density = params.engine.fuel_heating_value, params.simulation.fuel_density
    fuel_cs, nec = charge_sustaining_fuel(fuel_kg, terms, q_hv)
    km = distance_m / 1e3
    litres_cs = fuel_cs / density
    litres_corrected = battery_corrected_fuel(fuel_kg, terms, q_hv) / density
    return {
        "electric_wh_per_km": terms["chemical"] / 3.6e3 / km if km > 1e-3 else math.nan,
        "wall_wh_per_km": math.nan,
        "mpge": math.nan,
        "soc_start": float(soc_start),
        "soc_end": float(soc_end),
        "regen_wh": float(regen_j) / 3600.0,
        "fuel_l_per_100km_cs": litres_cs / (km / 100.0) if km > 1e-3 else math.nan,
        "fuel_l_per_100km_corrected": litres_corrected / (km / 100.0) if km > 1e-3 else math.nan,
        "net_energy_change_ratio": nec,
        "engine_starts": int(starts),
        "engine_on_s": float(on_s),
        "ems": ems,
    }


@equation
def boost_torque(w, soc, e, m, tabs):
    """The most torque the P2 machine adds at the gearbox input speed w: its motoring envelope T_max(w), cut
    to what the pack can give at charge ``soc`` beside the accessories (E3), (B1)-(B3) through
    :func:`vpsim.model.electric.machine_and_battery`. What a full-throttle run adds to the engine's torque."""
    env_speed, env_max, env_min = tabs[el.TAB_ENV_SPEED], tabs[el.TAB_ENV_MAX], tabs[el.TAB_ENV_MIN]
    t_min, t_max = el.envelope(w, m, e, env_speed, env_max, env_min)
    return el.machine_and_battery(t_max, False, 0.0, w, soc, e, m, tabs)[0]


# --- the P2's choice at one step, and what a forward run's car does with it -------------------------------


@equation
def p2_choose(
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
    k1,
):
    """The management's choice (engine fired, its torque) at one step of the P2 or the mild hybrid
    (:func:`p2_interval`, the pack in state ``battery``), from what it knows then: the charge, the engine's
    state and running time, the step dt; the DP's cost-to-go ``jcost[k1]`` on ``soc_grid`` (``ems`` dp
    only). ``t_off``: the torque of the engine not fired (0; the mild hybrid's engine dragged with its fuel
    cut: its closed-throttle line, :func:`closed_line`). Every method's P2 calls it per step."""
    w, t_in, runs = interval[1], interval[4], interval[5]
    choice_on = 0.0
    choice_te = t_off
    if ems == EMS_RULE:
        if h.mild > 0.0:
            choice_on, choice_te = mild_rule(interval, soc, t_low, t_high, h)
            if choice_on == 0.0:
                choice_te = t_off
        elif rule_wants_engine(on, on_time, t_in * w, soc, h) and runs:
            choice_on = 1.0
            choice_te = rule_engine_torque(t_in, w, soc, t_low, t_high, h)
        return choice_on, choice_te
    s_factor = equivalence_factor(soc, h)
    keep = ems == EMS_ECMS and runs and must_keep_running(on, on_time, h)
    share = start_share(dt, h) if ems == EMS_ECMS else 1.0
    best = math.inf
    for u in range(levels + 2):
        if u > 0 and not runs:
            break
        o = 1.0 if u > 0 else 0.0
        te = engine_choice_torque(u, levels, t_low, t_high, t_off, interval)
        pt = p2_choice(interval, battery, o, te, c, e, m, tabs, h)
        if keep and pt[16] <= 0.0:
            continue
        start = share if (pt[16] > 0.0 and on == 0.0) else 0.0
        extra = stop_price(on, interval[0] > 0.0, dt, h) if (ems == EMS_ECMS and pt[16] <= 0.0) else 0.0
        if ems == EMS_DP:
            nxt = soc + bt.soc_rate(pt[8], e.capacity_as, e.coulombic_efficiency) * dt
            cost = ecms_cost(pt, dt, start, 0.0, c, e, h) + cost_to_go(
                jcost[k1],
                1 if pt[16] > 0.0 else 0,
                nxt,
                soc_grid[0],
                soc_grid[1] - soc_grid[0],
                soc_grid.size,
            )
        else:
            cost = ecms_cost(pt, dt, start, s_factor, c, e, h) + extra
        if cost < best:
            best = cost
            choice_on = o
            choice_te = te
        if u > 1 and higher_torques_dominated(pt, battery):  # (the levels rise from u = 2)
            break
    return choice_on, choice_te


@equation
def walk_guess(share, t_in, levels, t_low, t_high):
    """The torque level an ECMS walk (:func:`ecms_cheapest_level`) starts from: the one nearest the engine
    torque that leaves the demand at the crank ``t_in`` the same engine share as the last step's choice
    (``share`` = its engine torque less its demand: the machine's torque held, which moves less from step
    to step than the level does when the demand changes); level 0 without a last choice (``share`` NaN)."""
    if share != share or t_high <= t_low:
        return 0
    j = math.floor((t_in + share - t_low) * (levels - 1.0) / (t_high - t_low) + 0.5)
    return int(min(max(j, 0.0), levels - 1.0))


@equation
def p2_ecms_walk(interval, battery, soc, on, on_time, dt, levels, t_low, t_high, share, c, e, m, tabs, h):
    """The P2 ECMS's choice as :func:`p2_choose` makes it, found by a walk (:func:`ecms_cheapest_level`)
    instead of trying every level, from the level :func:`walk_guess` makes of the last step's ``share``: for a
    cost convex in the engine's torque (:func:`running_cost_convex`, a pack not at its empty end:
    :func:`pack_covers_no_drive`) the walk ends where the exhaustive search does, whatever its start. Returns
    the chosen point and the share the next step's walk starts from (the running choice's, chosen or not)."""
    s_factor = equivalence_factor(soc, h)
    pt = p2_choice(interval, battery, 0.0, 0.0, c, e, m, tabs, h)
    best = ecms_cost(pt, dt, 0.0, s_factor, c, e, h) + stop_price(on, interval[0] > 0.0, dt, h)
    if interval[5]:
        if must_keep_running(on, on_time, h):
            best = math.inf
        start = start_share(dt, h) if on == 0.0 else 0.0
        p_follow = p2_choice(interval, battery, 1.0, follow_torque(interval, t_low, t_high), c, e, m, tabs, h)
        cost_follow = ecms_cost(p_follow, dt, start, s_factor, c, e, h)
        if cost_follow < best:  # (p2_choose's order: off, the demand followed, then the levels)
            best = cost_follow
            pt = p_follow
        guess = walk_guess(share, interval[4], levels, t_low, t_high)
        cost, level, p_run = ecms_cheapest_level(
            interval, battery, start, s_factor, dt, levels, t_low, t_high, guess, c, e, m, tabs, h
        )
        share = engine_torque_level(level, levels, t_low, t_high) - interval[4]
        if cost < best:
            pt = p_run
    return pt, share


@equation
def delivered_acceleration(a, missing, c):
    """The acceleration of a car whose wheels get ``missing`` newtons less than the demand m a + road load
    of acceleration a (18): a - F_miss / m (a forward run's car, where the powertrain falls short)."""
    return a - missing / c.mass
