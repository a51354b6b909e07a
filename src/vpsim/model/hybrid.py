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
  start adds its fuel.
* ``dp``: dynamic programming on the backward model over a state-of-charge grid (and the engine's on/off
  state, for the starts' fuel): the least fuel that ends the cycle at or above its starting charge, the lower
  bound the causal controllers are judged against.
"""

from __future__ import annotations

from . import battery as bt
from . import electric as el
from . import engine as en
from . import rules
from . import tables as tb
from . import vehicle as vh
from .engine import equation

EMS_RULE, EMS_ECMS, EMS_DP = 0, 1, 2
MISS_PENALTY = 1.0e3  # the price of a trace miss in the ECMS and DP: its wheel work's fuel, a thousand times
MISS_TOLERANCE_N = 1e-9
EMS_CODES = {"rule": EMS_RULE, "ecms": EMS_ECMS, "dp": EMS_DP}


@equation
def engine_lines(w, line_speed, line_max, line_min, inv_line):
    """(lowest, highest) torque the management may ask of the running engine at speed w: from zero (below it
    a real engine would cut its fuel, and a hybrid opens its clutch instead: the engine off) or its
    closed-throttle line if that is higher, to its full-load line (the generated map's lines)."""
    t_closed = tb.interp_at(w, line_speed, line_min, inv_line)
    return max(t_closed, 0.0), tb.interp_at(w, line_speed, line_max, inv_line)


@equation
def can_run(w, c):
    """The engine may run (clutch closed) at or above its idle speed."""
    return w >= c.idle_speed


@equation
def p2_point(v, a, ratio, soc, on, t_e, c, e, m, tabs):
    """The P2 hybrid's operating point at speed v, acceleration a in the gear of total ratio i, with the
    engine on (``on`` > 0, crank torque from ``t_e``, its torque at the shaft) or off (H1). Returns
    (w, dw, T_in, T_e, T_cr, p_i, mdot_f, T_m, I, U_oc, R, P_machine, brake N, missing N, at the machine's
    limit, at the battery's limit, engine on, c_m^1.8)."""
    vv = v if v > 0.0 else 0.0
    w = vh.engine_speed(vv, ratio, c)
    dw = vh.engine_speed(a, ratio, c)
    f = vh.wheel_force(vv, a, c)
    t_in = el.shaft_torque(f, ratio, c)
    running = on > 0.0 and can_run(w, c)
    cm18 = en.speed_power(w, c)
    t_cr = 0.0
    p = 0.0
    mdot = 0.0
    te = 0.0
    if running:
        te = t_e
        t_cr = te + vh.inertia_torque(dw, c)
        p = en.intake_pressure_for_torque(t_cr, w, c, cm18)
        mdot = en.fuel_flow(p, w, c)
    t_m, i, u_oc, r, p_m, at_m, at_b = el.machine_and_battery(
        t_in - te + el.rotor_torque(dw, e), t_in < 0.0, vv, w, soc, e, m, tabs
    )
    t_net = te + t_m - el.rotor_torque(dw, e)
    f_net = el.wheel_force_of_shaft(t_net, ratio, c)
    missing = f - f_net if f > f_net else 0.0
    brake = f_net - f if f_net > f else 0.0
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
        1.0 if running else 0.0,
        cm18,
    )


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
def fuel_equivalent(energy_j, efficiency, c):
    """The fuel (kg) whose heating value at ``efficiency`` is ``energy_j``."""
    return energy_j / (efficiency * c.fuel_heating_value)


@equation
def ecms_cost(point, dt, start, s_factor, c, h):
    """The cost of one choice over dt (kg of fuel): its fuel, the battery's chemical energy at the
    equivalence factor s (0 for the DP, whose cost-to-go prices the charge), a start's fuel, and a trace
    miss at a prohibitive price."""
    mdot = point[6]
    missing = point[13]
    chem = bt.chemical_power(point[9], point[8], 1.0)
    cost = mdot * dt + s_factor * fuel_equivalent(chem * dt, 1.0, c)
    if start:
        cost += h.engine_start_fuel
    if missing > MISS_TOLERANCE_N:  # the machine's speed stands in for the vehicle's (same sign, > 0 moving)
        cost += MISS_PENALTY * fuel_equivalent(missing * (point[0] + 1.0) * dt, 1.0, c)
    return cost


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
    if running > 0.0:
        indicated, friction, pumping = rules.engine_powers(p, w, t_cr, 1.0, c, cm18)
        engine_kinetic = vh.inertia_torque(dw, c) * w
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
        e.accessory_power,
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


HYBRID_TERMS = (
    "indicated",
    "friction",
    "pumping",
    "engine_kinetic",
    "chemical",
    "battery_loss",
    "accessories",
    "machine_loss",
    "rotor_kinetic",
    "driveline_loss",
    "vehicle_kinetic",
    "aero",
    "rolling",
    "brake",
    "trace_miss",
    "unserved",
)


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
)


def hybrid_record(params):
    """The record of ``params.hybrid``'s numbers (:data:`H_FIELDS`)."""
    import numpy as np

    h = np.zeros(1, np.dtype([(n, np.float64) for n in H_FIELDS], align=True)).view(np.recarray)
    h[0] = tuple(float(getattr(params.hybrid, n)) for n in H_FIELDS)
    h.flags.writeable = False
    return h[0]
