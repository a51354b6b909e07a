"""The battery-electric powertrain: battery, machine and inverter, single reduction, regenerative braking.

The components are written once: the battery in :mod:`vpsim.model.battery`, the machine in
:mod:`vpsim.model.machine`, the vehicle's road load in :mod:`vpsim.model.vehicle`. This module composes them
into the one operating point every method evaluates (:func:`drive_point`, :func:`battery_point`), so the
backward, forward and inverse methods differ only in where speed and acceleration come from.

Driveline (E1): machine speed w_m = i v / r (the engine's (14),(17)); the reduction's efficiency eta applies
in the direction of the power flow,

    T_m = F_w r / (i eta) + J_m dw_m/dt   (driving)       T_m = F_w r eta / i + J_m dw_m/dt   (braking)

Regenerative braking (E2): of a braking demand (T_m < 0) the machine takes the share
s(v) = regen_share x clamp((v - v_low) / (v_high - v_low), 0, 1) (``regen_share``: the driven axle's share of
the braking; the fade-out at low speed, where a real car hands over to the friction brakes), down to its
generating envelope and to what the battery may accept; the friction brakes take the rest at the wheels.

Electric power (E3): P_batt = P_el(T_m, w_m) + P_acc, the machine's DC power (its losses and the inverter's
included; negative while generating) plus the accessories. The battery's current follows from (B2) within
its limits; where it cannot give (or take) the power, the machine's torque is cut to what it can: a cut in
driving is a trace miss (backward, inverse) or a slower car (forward); a cut in braking goes to the friction
brakes.

Wall energy (E4): the energy drawn from the grid to put back what the cycle took, E_wall = E_chem / eta_ch
(``charger_efficiency``: wall to battery, the charger's and the charging's losses together); MPGe =
distance / (E_wall / 33.705 kWh) (EPA's gallon equivalent).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import battery as bt
from . import machine as mc
from . import tables as tb
from . import vehicle as vh
from .engine import equation, inline

# the energy terms of an electric powertrain, in the order the kernels book them (result.ElectricBalance)
ELECTRIC_TERMS = (
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
KWH_PER_GALLON_EQUIVALENT = 33.705  # EPA: the energy content of a gallon of gasoline, for MPGe
BISECTION_STEPS = 48  # halvings of a torque cut to the battery's limit (to 2^-48 of the demand): the
# fallback of torque_for_power's closed forms

# the electric record: the battery's scalars, the electric section and the machine's inertia
E_FIELDS = (
    "capacity_as",
    "v_min",
    "v_max",
    "i_max_discharge",
    "i_max_charge",
    "soc_min",
    "soc_max",
    "coulombic_efficiency",
    "inv_soc",
    "accessory_power",
    "charger_efficiency",
    "regen_share",
    "regen_speed_low",
    "regen_speed_high",
    "machine_inertia",
    "measured_machine",
    "inv_map_speed",
    "inv_map_torque",
    "inv_env_speed",
)
E_DTYPE = np.dtype([(n, np.float64) for n in E_FIELDS], align=True)


@dataclass(frozen=True)
class Tables:
    """The arrays a kernel reads beside the records: the pack's tables and, for a measured machine, its loss
    map and envelope (empty otherwise)."""

    soc: np.ndarray
    ocv: np.ndarray
    r_dis: np.ndarray
    r_chg: np.ndarray
    map_speed: np.ndarray
    map_torque: np.ndarray
    map_loss: np.ndarray
    env_speed: np.ndarray
    env_max: np.ndarray
    env_min: np.ndarray

    def astuple(self):
        """The arrays as the kernels take them, in the order of the ``TAB_*`` indices below."""
        return (
            self.soc,
            self.ocv,
            self.r_dis,
            self.r_chg,
            self.map_speed,
            self.map_torque,
            self.map_loss,
            self.env_speed,
            self.env_max,
            self.env_min,
        )


# positions of the arrays in Tables.astuple(), the tuple a kernel reads as ``tabs``
(
    TAB_SOC,
    TAB_OCV,
    TAB_R_DIS,
    TAB_R_CHG,
    TAB_MAP_SPEED,
    TAB_MAP_TORQUE,
    TAB_MAP_LOSS,
    TAB_ENV_SPEED,
    TAB_ENV_MAX,
    TAB_ENV_MIN,
) = range(10)


# --- equations --------------------------------------------------------------------------------------------


@equation
def regen_fraction(v, e):
    """s(v) of (E2): the share of a braking demand the machine may take."""
    if e.regen_speed_high <= e.regen_speed_low:
        fade = 1.0 if v > e.regen_speed_low else 0.0
    else:
        fade = min(max((v - e.regen_speed_low) / (e.regen_speed_high - e.regen_speed_low), 0.0), 1.0)
    return e.regen_share * fade


@equation
def shaft_torque(f_wheel, ratio, c):
    """The reduction's input torque for wheel force F_w, the efficiency in the power's direction (E1)."""
    t = f_wheel * c.wheel_radius / ratio
    if t >= 0.0:
        return t / c.efficiency
    return t * c.efficiency


@equation
def wheel_force_of_shaft(t, ratio, c):
    """The wheel force of input torque T (the inverse of :func:`shaft_torque`)."""
    if t >= 0.0:
        return t * c.efficiency * ratio / c.wheel_radius
    return t / c.efficiency * ratio / c.wheel_radius


@equation
def rotor_torque(dw, e):
    """J_m dw_m/dt: the torque that accelerates the rotor (E1)."""
    return e.machine_inertia * dw


@equation
def envelope(w, m, e, env_speed, env_max, env_min):
    """(T_min <= 0, T_max >= 0) the machine can give at w: the scalable model's, or the measured map's."""
    if e.measured_machine > 0.0:
        if w > env_speed[env_speed.size - 1]:
            return 0.0, 0.0
        return (
            tb.interp_at(w, env_speed, env_min, e.inv_env_speed),
            tb.interp_at(w, env_speed, env_max, e.inv_env_speed),
        )
    return mc.min_torque(w, m), mc.max_torque(w, m)


@equation
def map_loss_at(t, w, e, map_speed, map_torque, map_loss):
    """A measured machine's loss at (T, w) as its map interpolates it, held at the map's edges (as
    MeasuredMachine.loss_w), before the floor at 0 that :func:`machine_power` applies."""
    ws = min(max(w, map_speed[0]), map_speed[map_speed.size - 1])
    ts = min(max(t, map_torque[0]), map_torque[map_torque.size - 1])
    return tb.bilinear_at(map_speed, map_torque, map_loss, ws, ts, e.inv_map_speed, e.inv_map_torque)


@inline
def machine_power(t, w, m, e, map_speed, map_torque, map_loss):
    """The machine's DC power at (T, w) (E3): T w plus its losses (model, or the measured map's)."""
    if e.measured_machine > 0.0:
        return t * w + max(map_loss_at(t, w, e, map_speed, map_torque, map_loss), 0.0)
    return mc.electric_power(t, w, m)


@equation
def battery_state(soc, e, soc_grid, ocv, r_dis, r_chg):
    """(U_oc, R_dis, R_chg, I_low, I_high) of the pack at this state of charge (B1), (B3)."""
    u_oc = bt.open_circuit_voltage(soc, soc_grid, ocv, e.inv_soc)
    r_d = bt.resistance(1.0, soc, soc_grid, r_dis, r_chg, e.inv_soc)
    r_c = bt.resistance(-1.0, soc, soc_grid, r_dis, r_chg, e.inv_soc)
    lo, hi = bt.current_limits(
        soc, u_oc, r_d, r_c, e.v_min, e.v_max, e.i_max_discharge, e.i_max_charge, e.soc_min, e.soc_max
    )
    return u_oc, r_d, r_c, lo, hi


@equation
def pack_power(current, u_oc, r_d, r_c):
    """Terminal power at current I: (U_oc - R I) I."""
    r = r_d if current >= 0.0 else r_c
    return (u_oc - r * current) * current


@equation
def pack_current(p, u_oc, r_d, r_c):
    """Current of terminal power p (B2), the resistance of the current's direction."""
    return bt.current_for_power(p, u_oc, r_d if p >= 0.0 else r_c)


@equation
def torque_for_power(p_target, t_from, w, m, e, map_speed, map_torque, map_loss):
    """The torque between 0 and ``t_from`` whose DC power plus the accessories is ``p_target``, where the
    power rises through it: ``t_from`` is the torque asked, whose power is beyond the target. Where the
    bracket holds (the power at or below the target at its low end, above it at its high end) the root in
    closed form: the scalable machine's power is a quadratic in T at fixed w
    (:func:`vpsim.model.machine.torque_of_power`), the measured map's piecewise linear
    (:func:`map_torque_of_power`); else, or where rounding puts the root outside the bracket, the bisection
    (:func:`bisect_torque_for_power`)."""
    lo, hi = 0.0, t_from
    if t_from < 0.0:
        lo, hi = t_from, 0.0
    p_lo = machine_power(lo, w, m, e, map_speed, map_torque, map_loss) + e.accessory_power
    p_hi = machine_power(hi, w, m, e, map_speed, map_torque, map_loss) + e.accessory_power
    if p_lo <= p_target < p_hi:
        if e.measured_machine > 0.0:
            t = map_torque_of_power(p_target, lo, hi, p_lo, p_hi, w, m, e, map_speed, map_torque, map_loss)
        else:
            t = mc.torque_of_power(p_target - e.accessory_power, w, lo, hi, m)
        if t == t:  # not NaN
            return t
    return bisect_torque_for_power(p_target, t_from, w, m, e, map_speed, map_torque, map_loss)


@equation
def bisect_torque_for_power(p_target, t_from, w, m, e, map_speed, map_torque, map_loss):
    """:func:`torque_for_power` by bisection (the power rises with the torque): the fallback where no
    bracket holds (the accessories alone beyond the pack's limit) and the reference its closed forms are
    tested against. Keeps the side within the limit."""
    lo, hi = 0.0, t_from
    if t_from < 0.0:
        lo, hi = t_from, 0.0
    for _ in range(BISECTION_STEPS):
        mid = 0.5 * (lo + hi)
        if machine_power(mid, w, m, e, map_speed, map_torque, map_loss) + e.accessory_power > p_target:
            hi = mid
        else:
            lo = mid
    return lo if t_from > 0.0 else hi


@equation
def map_torque_of_power(p_target, lo, hi, p_lo, p_hi, w, m, e, map_speed, map_torque, map_loss):
    """:func:`torque_for_power` on a measured map, with the bracket [lo, hi] and its powers (p_lo <= p_target
    < p_hi, the accessories included). At fixed w the map's bilinear loss is linear in T between its torque
    nodes (and held beyond them), so the power T w + max(loss, 0) is piecewise linear: a bisection over the
    nodes inside the bracket (keeping the bracket) leaves one cell, where at most the floor at 0 bends it;
    a linear root there (after the bend's point, where the loss crosses 0) is exact. NaN where the root falls
    outside the bracket by rounding (the caller bisects)."""
    acc = e.accessory_power
    n = map_torque.size
    i0 = 0  # the first node above lo
    while i0 < n and map_torque[i0] <= lo:
        i0 += 1
    i1 = n - 1  # the last node below hi
    while i1 >= 0 and map_torque[i1] >= hi:
        i1 -= 1
    while i0 <= i1:
        k = (i0 + i1) // 2
        tk = map_torque[k]
        pk = machine_power(tk, w, m, e, map_speed, map_torque, map_loss) + acc
        if pk > p_target:
            hi, p_hi, i1 = tk, pk, k - 1
        else:
            lo, p_lo, i0 = tk, pk, k + 1
    # one cell: the raw loss is linear in T here; where it changes sign the floor bends the power once
    l_lo = map_loss_at(lo, w, e, map_speed, map_torque, map_loss)
    l_hi = map_loss_at(hi, w, e, map_speed, map_torque, map_loss)
    if (l_lo < 0.0 < l_hi) or (l_hi < 0.0 < l_lo):
        tb_ = lo + (hi - lo) * l_lo / (l_lo - l_hi)
        if lo < tb_ < hi:
            pb = machine_power(tb_, w, m, e, map_speed, map_torque, map_loss) + acc
            if pb > p_target:
                hi, p_hi = tb_, pb
            else:
                lo, p_lo = tb_, pb
    if not p_hi > p_lo:
        return math.nan
    r = lo + (hi - lo) * (p_target - p_lo) / (p_hi - p_lo)
    return min(max(r, lo), hi)


@inline
def machine_and_battery(t_ask, braking, v, w, soc, e, m, tabs):
    """What the machine gives of a torque ``t_ask`` at its shaft (speed w), the battery supplying it
    (E2), (E3), (B1)-(B3): ``braking`` (the wheels' demand is a braking one) applies the regenerative share
    s(v); the torque is held within the envelope and cut to what the battery can give or take. Returns
    (T_m, current A, U_oc V, R Ohm, P_machine W, at the machine's limit, at the battery's limit)."""
    soc_grid, ocv, r_dis, r_chg, map_speed, map_torque, map_loss, env_speed, env_max, env_min = tabs
    t_min, t_max = envelope(w, m, e, env_speed, env_max, env_min)
    return machine_and_battery_at(
        t_ask,
        braking,
        v,
        w,
        t_min,
        t_max,
        battery_state(soc, e, soc_grid, ocv, r_dis, r_chg),
        0.0,
        e,
        m,
        map_speed,
        map_torque,
        map_loss,
    )


@inline
def machine_and_battery_at(
    t_ask, braking, v, w, t_min, t_max, battery, p_other, e, m, map_speed, map_torque, map_loss
):
    """:func:`machine_and_battery` with the envelope (t_min, t_max) at w and the pack's
    :func:`battery_state` at hand: a caller that tries many torques at one speed and charge (the hybrid's
    energy management) evaluates those once. ``p_other``: the DC power of another machine on the same pack
    (a power-split hybrid's generator; 0 for one machine), served before this one's.

    Inlined, and given the machine's three map arrays rather than the whole tables tuple, for speed only:
    a compiled call passes each array by value (about seven words), so the ten-array tuple was copied onto
    the stack at every torque the energy management tried; this halved the P2 hybrid's ECMS run (UDDS,
    1.36-1.45 -> 0.67 ms on one machine) for 5-9 s more first compilation of each hybrid's kernels and
    15 s more of the install's (benchmarks/README.md, 2026-12-06)."""
    t, at_machine = machine_torque_within(t_ask, braking, v, t_min, t_max, e)
    p_machine = machine_power(t, w, m, e, map_speed, map_torque, map_loss)
    return battery_supplies(
        t, p_machine, p_other, w, battery, e, m, map_speed, map_torque, map_loss, at_machine
    )


@equation
def machine_torque_within(t_ask, braking, v, t_min, t_max, e):
    """(T, at the machine's limit): the torque asked, a braking demand's regenerative share s(v) of it (E2),
    held within the envelope (t_min, t_max)."""
    at_machine = 0.0
    t = t_ask * regen_fraction(v, e) if braking and t_ask < 0.0 else t_ask
    if t > t_max:
        t = t_max
        at_machine = 1.0
    elif t < t_min:
        t = t_min
        at_machine = 1.0
    return t, at_machine


@equation
def battery_supplies(t, p_machine, p_other, w, battery, e, m, map_speed, map_torque, map_loss, at_machine):
    """The battery (state ``battery``, :func:`battery_state`) supplying the machine's torque T at w, whose
    DC power is ``p_machine`` (:func:`machine_power`), another machine's DC power ``p_other`` and the
    accessories (E3), (B2): the current, and where it is beyond the pack's limits this machine's torque cut
    to what the pack can give or take. Returns what :func:`machine_and_battery` returns."""
    u_oc, r_d, r_c, i_lo, i_hi = battery
    p = p_machine + p_other + e.accessory_power
    i = pack_current(p, u_oc, r_d, r_c)
    at_battery = 0.0
    if i > i_hi or i < i_lo:
        at_battery = 1.0
        i = i_hi if i > i_hi else i_lo
        p_lim = pack_power(i, u_oc, r_d, r_c)
        if t != 0.0 and (t > 0.0) == (p > p_lim):
            t = torque_for_power(p_lim - p_other, t, w, m, e, map_speed, map_torque, map_loss)
            p_machine = machine_power(t, w, m, e, map_speed, map_torque, map_loss)
            i = pack_current(p_machine + p_other + e.accessory_power, u_oc, r_d, r_c)
            i = min(max(i, i_lo), i_hi)
        # the accessories (and another machine) alone beyond the limit (an empty pack): the current is the
        # limit's, the power the pack's; the rest is booked as unserved
    r = r_d if i >= 0.0 else r_c
    return t, i, u_oc, r, p_machine, at_machine, at_battery


@equation
def electric_point(f_demand, v, dw, ratio, soc, c, e, m, tabs):
    """The operating point of a wheel force demand ``f_demand`` (traction + inertia, N) at speed v with
    rotor acceleration dw: (w_m, T_m, brake force N, force missing N, current A, U_oc V, R Ohm,
    P_machine W, at the machine's limit, at the battery's limit) by (E1)-(E3), (B1)-(B3)."""
    w = vh.engine_speed(v, ratio, c)
    t_ask = shaft_torque(f_demand, ratio, c) + rotor_torque(dw, e)
    t, i, u_oc, r, p_machine, at_machine, at_battery = machine_and_battery(
        t_ask, t_ask < 0.0, v, w, soc, e, m, tabs
    )
    # the force the wheels get from the machine: what it lacks while driving is missing, what it leaves of a
    # braking demand the friction brakes take
    f_machine = wheel_force_of_shaft(t - rotor_torque(dw, e), ratio, c)
    missing = f_demand - f_machine if f_demand > f_machine else 0.0
    brake = f_machine - f_demand if f_machine > f_demand else 0.0
    return w, t, brake, missing, i, u_oc, r, p_machine, at_machine, at_battery


@equation
def wall_energy(chemical_j, e):
    """E_wall = E_chem / eta_ch (E4): the grid's energy to put back what the run drew from the pack."""
    return chemical_j / e.charger_efficiency


@equation
def rotor_mass(ratio, driving, c, e):
    """J_m (i / r)^2 through the reduction in the power's direction (E1): the rotor's inertia seen at the
    wheels as mass (times eta while driving, over eta while braking)."""
    k = ratio / c.wheel_radius
    mass = e.machine_inertia * k * k
    return mass * c.efficiency if driving else mass / c.efficiency


# --- records (built once per parameter set) --------------------------------------------------------------


def machine_spec(params):
    """The :class:`vpsim.model.machine.MachineSpec` of ``params.machine`` (the scalable loss model, its
    coefficients times ``machine.loss_scale``)."""
    p = params.machine
    coefficients = None
    if p.loss_scale != 1.0:  # machine.loss_scale: every loss term times the scale
        base = mc.DEFAULT_COEFFICIENTS[p.kind].as_dict()
        coefficients = mc.LossCoefficients(**{k: v * p.loss_scale for k, v in base.items()})
    return mc.MachineSpec(
        rated_power_w=p.rated_power,
        base_speed_radps=p.base_speed,
        max_speed_radps=p.max_speed,
        kind=p.kind,
        coefficients=coefficients,
        inertia_kgm2=p.inertia,
    )


def _measured_tables(params):
    """(loss map speed, torque, loss; envelope speed, max, min) of a measured machine, scaled to nothing:
    the file's own machine, its losses times ``machine.loss_scale``; empty arrays without a map file."""
    empty = np.array([0.0, 1.0])  # a table the kernels never read (two nodes keep its spacing finite)
    if not params.machine.map_file:
        return empty, empty, np.zeros((2, 2)), empty, empty, empty
    from ..engines.machine_map import load_machine

    mm = load_machine(params.machine.map_file)
    return (
        mm.speed_grid,
        mm.torque_grid,
        mm._loss_table * params.machine.loss_scale,
        mm.envelope_speed,
        mm.max_torque,
        mm.min_torque,
    )


def pack_of(params):
    """The pack of ``params.battery`` (:func:`vpsim.model.battery.pack`)."""
    from .record import memo

    def build(p):
        b = p.battery
        return bt.pack(bt.resolve_cell(b.cell), b.cells_in_series, b.cells_in_parallel, b.soc_min, b.soc_max)

    return memo(params, "pack", build)


def electric_records(params):
    """(e, m, tables) of a parameter set: the electric record (:data:`E_FIELDS`), the machine's record and the
    arrays (:class:`Tables`), built once per parameter set."""
    from .record import memo

    return memo(params, "electric", _electric_records)


def _electric_records(params):
    pk = pack_of(params)
    ms, mt, ml, es, emax, emin = _measured_tables(params)
    measured = 1.0 if params.machine.map_file else 0.0
    el_ = params.electric
    e = np.zeros(1, E_DTYPE).view(np.recarray)
    e[0] = (
        pk.capacity_as,
        pk.v_min,
        pk.v_max,
        pk.i_max_discharge,
        pk.i_max_charge,
        pk.soc_min,
        pk.soc_max,
        pk.coulombic_efficiency,
        tb.inverse_spacing(pk.soc),
        el_.accessory_power,
        el_.charger_efficiency,
        el_.regen_share,
        el_.regen_speed_low,
        el_.regen_speed_high,
        params.machine.inertia,
        measured,
        tb.inverse_spacing(ms),
        tb.inverse_spacing(mt),
        tb.inverse_spacing(es),
    )
    e.flags.writeable = False
    m = mc.machine_record(machine_spec(params))
    tabs = Tables(
        soc=pk.soc,
        ocv=pk.ocv_v,
        r_dis=pk.r_discharge_ohm,
        r_chg=pk.r_charge_ohm,
        map_speed=np.ascontiguousarray(ms, float),
        map_torque=np.ascontiguousarray(mt, float),
        map_loss=np.ascontiguousarray(ml, float),
        env_speed=np.ascontiguousarray(es, float),
        env_max=np.ascontiguousarray(emax, float),
        env_min=np.ascontiguousarray(emin, float),
    )
    return e[0], m, tabs


@equation
def driver_force(u, v, c):
    """The forward driver's wheel-force demand for an acceleration command u: m u plus the road load it
    feels (the PI's integral then trims what the road load model does not know)."""
    return c.mass * u + vh.road_load(v, c)


@equation
def forward_acceleration(t, brake, v, ratio, c, e):
    """dv/dt of the stiff electric driveline: the machine's wheel force less the brakes and the road load,
    over the mass with the rotor's (E1),(18)."""
    f_net = wheel_force_of_shaft(t, ratio, c) - brake - vh.road_load(v, c)
    return f_net / (c.mass + rotor_mass(ratio, t >= 0.0, c, e))


@equation
def kinetic_power(v, a, c):
    """m a v: the power that goes into the vehicle's kinetic energy."""
    return c.mass * a * v


def ratio_for_speed(machine_speed, vehicle_speed, wheel_radius):
    """i = w r / v: the total ratio at which vehicle speed v turns the machine at w   (14),(17)."""
    return machine_speed * wheel_radius / vehicle_speed


def machine_speed_for(vehicle_speed, ratio, wheel_radius):
    """w = i v / r: the machine's speed at vehicle speed v through total ratio i   (14),(17)."""
    return ratio * vehicle_speed / wheel_radius
