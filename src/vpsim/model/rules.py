"""The rules of the realistic car (``extended`` mode) and the fuel and energy bookkeeping, written once.

The paper's model is a stiff driveline without brakes; its fuel is the model's flow floored at the idle
flow (section 5). The ``realistic`` mode (the default; ``extended`` is its earlier name) adds what a real
car has, and every method applies the same rules:

* **clutch**: below the idle speed (``c.idle_speed``) the engine cannot follow the wheels. With traction
  demanded the clutch slips: the engine is held at idle speed and the clutch passes the engine's torque if it
  is positive (a slipping clutch transmits no engine braking); without traction it opens and the engine
  idles. The slip dissipates T_clutch (w_e - w_wheel).
* **brakes**: friction brakes take what engine braking (the closed-throttle line, the FQM at A_min) cannot.
* **idle floor**: the fuel booked is max(mdot_f, mdot_idle); a declutched engine burns the idle flow.
* **torque converter** (a transmission with ``converter_capacity_factor`` > 0, quasi-static methods): while
  its lock-up clutch is open (:func:`.vehicle.converter_locked`) the converter takes the clutch's place.
  With traction the engine runs at the pump speed w_t / nu (nu from :func:`.vehicle.converter_speed_ratio`,
  slip 1 - nu > 0) and gives the pump torque T_t / mu(nu); if that speed is below idle the engine idles,
  the converter passes more than asked and the brakes hold the rest (creep). Without traction the engine
  idles, decoupled. The converter dissipates T_p w_p (1 - mu nu), booked in the driveline loss. The forward
  method, which takes the pedal rather than the wheel torque, integrates the engine speed behind the
  unlocked converter instead (:func:`converter_engine`; decoupled with the brakes on); at steady state the
  two agree.

Quasi-static methods (backward) impose the operating point (:func:`operating_point`); the dynamic methods
integrate or invert the same physics with the same clutch test (:func:`clutch_engaged`) and clutch torque
(:func:`slipping_clutch_torque`). The power of every energy term is :func:`powers`, so all methods book the
energy balance of :class:`vpsim.result.EnergyBalance` from one definition.
"""

from __future__ import annotations

from . import engine as en
from . import vehicle as vh
from .engine import equation, inline

# the two modes every method offers: the realistic car (clutch, idle, brakes) and the paper's model
MODES = ("realistic", "paper")
_MODE_ALIASES = {"extended": "realistic"}  # the realistic mode's earlier name


def canonical_mode(mode) -> str:
    """``"realistic"`` or ``"paper"`` for a mode name (``"extended"``: the realistic mode's earlier name)."""
    m = _MODE_ALIASES.get(mode, mode)
    if m not in MODES:
        from ..errors import VpsimError

        raise VpsimError(f"unknown mode {mode!r}; expected realistic or paper")
    return m


CLUTCH_OPEN, CLUTCH_ENGAGED, CLUTCH_SLIPPING, CLUTCH_CONVERTER = 0, 1, 2, 3


@equation
def fuel_with_idle_floor(mdot_f, c):
    """Fuel booked: max(mdot_f, mdot_idle) (section 5: braking and idling burn the idle flow)."""
    return mdot_f if mdot_f > c.idle_fuel_flow else c.idle_fuel_flow


@equation
def clutch_engaged(w_wheel, c):
    """The driveline is stiff at and above the idle speed (wheel-side engine speed i v / r)."""
    return w_wheel >= c.idle_speed


@equation
def slipping_clutch_torque(t_cr):
    """A slipping clutch passes the engine's torque if it drives, nothing if it would brake."""
    return t_cr if t_cr > 0.0 else 0.0


@equation
def accessories_torque(w_e, realistic, c):
    """The accessories' torque on the crank: the realistic car's (:func:`.engine.accessory_torque`);
    the paper's model has none."""
    return en.accessory_torque(w_e, c) if realistic else 0.0


@equation
def brake_force(t_demand, t_closed, ratio, c):
    """Friction-brake force taking what engine braking cannot: (T_closed - T_demand)+ i eta / r  (15),(16)."""
    excess = t_closed - t_demand
    return vh.engine_to_wheel_force(excess, ratio, c) if excess > 0.0 else 0.0


CUTOFF_RESUME_BAND = 0.2  # the cut ramps in over the 20 % above c.fuel_cutoff_speed (see cutoff_share)


@equation
def cutoff_share(w_e, c):
    """How far fuel cut-off in overrun may go at engine speed w_e: 0 below ``c.fuel_cutoff_speed`` (or with
    it 0: no cut-off), 1 from :data:`CUTOFF_RESUME_BAND` above it, linear between. Engine controls re-fire
    below a resume speed some 200-400 rpm under the cut-off speed (a hysteresis); the ramp is its continuous
    stand-in, which a dynamic method can integrate (a hard switch chatters there)."""
    w_cut = c.fuel_cutoff_speed
    if not w_cut > 0.0 or w_e <= w_cut:
        return 0.0
    x = (w_e - w_cut) / (CUTOFF_RESUME_BAND * w_cut)
    return x if x < 1.0 else 1.0


@equation
def cutoff_share_dw(w_e, c):
    """d/dw_e of :func:`cutoff_share`: the ramp's slope inside it, 0 elsewhere."""
    w_cut = c.fuel_cutoff_speed
    if not w_cut > 0.0 or w_e <= w_cut or (w_e - w_cut) / (CUTOFF_RESUME_BAND * w_cut) >= 1.0:
        return 0.0
    return 1.0 / (CUTOFF_RESUME_BAND * w_cut)


@equation
def engine_braking(t_demand, t_closed, p_closed, w_e, ratio, c, cm18=None):
    """The engaged engine asked for less than its closed-throttle torque ``t_closed`` (manifold at
    ``p_closed``). Without fuel cut-off it runs on that line and the brakes take the rest. With it the control
    cuts cylinders progressively: the fired fraction needed falls linearly from 1 at ``t_closed`` to 0 at the
    motoring torque (the unfired engine at that pressure), the cut being allowed as far as
    :func:`cutoff_share` of the engine speed; the brakes take what the engine does not. Returns (T_cr, brake
    force, fired fraction in [0, 1]). ``cm18``: :func:`.engine.speed_power` at w_e, if at hand."""
    if t_demand >= t_closed:
        return t_demand, 0.0, 1.0
    share = cutoff_share(w_e, c)
    if share <= 0.0:
        return t_closed, brake_force(t_demand, t_closed, ratio, c), 1.0
    t_motor = en.motoring_torque(p_closed, w_e, c, cm18)
    need = (t_demand - t_motor) / (t_closed - t_motor) if t_demand > t_motor else 0.0
    fired = 1.0 - share * (1.0 - need)
    t_eng = t_motor + fired * (t_closed - t_motor)
    return t_eng, brake_force(t_demand, t_eng, ratio, c), fired


@equation
def fired_fraction_of_command(u, a_min, w_e, c):
    """The fired fraction a pedal command u (m²; the forward method's PI) asks for: the pedal's floor band
    [0, A_min] (throttle closed, no brakes) is the cylinders' cut, u / A_min of them fired there, none with
    the brakes on (u <= 0), all from A_min up; the cut allowed as far as :func:`cutoff_share`. At a steady
    state the PI sets u where the torque meets the demand: the fraction of :func:`engine_braking`."""
    share = cutoff_share(w_e, c)
    if u >= a_min or share <= 0.0:
        return 1.0
    need = u / a_min if u > 0.0 else 0.0
    return 1.0 - share * (1.0 - need)


@equation
def fired_fraction_dcommand(u, a_min, w_e, c):
    """d/du of :func:`fired_fraction_of_command`: the allowed cut's share over A_min inside the floor band
    (0, A_min), 0 elsewhere."""
    share = cutoff_share(w_e, c)
    if u >= a_min or share <= 0.0 or u <= 0.0:
        return 0.0
    return share / a_min


@equation
def fired_fraction_dspeed(u, a_min, w_e, c):
    """d/dw_e of :func:`fired_fraction_of_command` at fixed u: the allowed cut's ramp (cutoff_share_dw)."""
    if u >= a_min or cutoff_share(w_e, c) <= 0.0:
        return 0.0
    need = u / a_min if u > 0.0 else 0.0
    return -(1.0 - need) * cutoff_share_dw(w_e, c)


@equation
def fuel_used(mdot_f, fired, c):
    """Fuel booked for the flow ``mdot_f`` of an engine with ``fired`` of its cylinders fired: the idle floor
    for the fired part, max(mdot_f, fired mdot_idle) (1: :func:`fuel_with_idle_floor`; 0: none)."""
    floor = fired * c.idle_fuel_flow
    return mdot_f if mdot_f > floor else floor


@equation
def engine_fuel_flow(mdot_f, clutch, fired, c):
    """The flow the engine takes at its operating point: ``mdot_f`` (the idle flow with the clutch open),
    times the fired fraction of its cylinders (fuel cut-off)."""
    return fired * (c.idle_fuel_flow if clutch == CLUTCH_OPEN else mdot_f)


@equation
def fuel_used_tangent(mdot_f, fired, d_mdot_f, d_fired, c):
    """Directional derivative of :func:`fuel_used` along (d_mdot_f, d_fired): the flow's, or the floor's
    where it holds (one-sided at the kink, as :func:`fuel_used` takes the floor there)."""
    if mdot_f > fired * c.idle_fuel_flow:
        return d_mdot_f
    return d_fired * c.idle_fuel_flow


@inline
def converter_point(f_wheel, w_wheel, dw_wheel, ratio, c):
    """The unlocked torque converter's operating point with traction (``f_wheel`` > 0, turbine speed
    ``w_wheel`` >= 0; at 0 the converter stalls): (pump speed w_e, dw_e/dt, T_cr demanded, brake force). The
    pump's acceleration is the turbine's over nu (quasi-static: the slip's own change is left out)."""
    t_t = vh.wheel_to_engine_torque(f_wheel, ratio, c)  # turbine = gearbox input torque (15),(16)
    w_p, dw_p, t_p, mu, held = vh.converter_engine_point(w_wheel, dw_wheel, t_t, c)
    if held == 0.0:
        return w_p, dw_p, t_p + c.inertia * dw_p + en.accessory_torque(w_p, c), 0.0
    # the engine idles: at idle speed the converter passes more than the wheels ask, the brakes hold it
    brake = vh.engine_to_wheel_force(mu * t_p, ratio, c) - f_wheel
    return c.idle_speed, 0.0, t_p + en.accessory_torque(c.idle_speed, c), (brake if brake > 0.0 else 0.0)


@equation
def neutral_idle_share(u, a_min):
    """The share of the unlocked converter's torque its neutral-idle clutch (between turbine and gearbox)
    passes in the forward method: 0 with the brakes on (pedal command ``u`` <= 0), rising over the pedal's
    floor band to 1 at A_min (a step there made the PI driver chatter: some 1,900 events on UDDS)."""
    if u >= a_min:
        return 1.0
    return u / a_min if u > 0.0 else 0.0


@equation
def converter_margin_at_idle(p_i, w_t, share, fired, c):
    """The engine's net torque T_cr(p_i, idle) - T_acc(idle) (``fired`` of its cylinders fired) less the
    share ``share`` of the pump's phi(w_t / idle) idle^2 that loads it: where it is not positive an engine
    at idle speed cannot turn the unlocked converter faster (it is held at idle, :func:`converter_engine`)."""
    idle = c.idle_speed
    return (
        en.fired_crank_torque(p_i, idle, fired, c)
        - en.accessory_torque(idle, c)
        - share * vh.converter_pump_torque(idle, w_t, c)
    )


@equation
def converter_idle_command(w_t, share, c):
    """The idle governor's throttle command while the converter is unlocked: the steady one that holds the
    engine at idle speed against the share ``share`` of the pump's torque there and the accessories'
    (:func:`.engine.steady_point`). As a floor under the driver's, the engine settles at idle, not below."""
    idle = c.idle_speed
    load = share * vh.converter_pump_torque(idle, w_t, c) + en.accessory_torque(idle, c)
    return en.steady_point(load, idle, c)[1]


@equation
def converter_engine(p_i, w_e, w_t, share, fired, c):
    """The engine on the unlocked torque converter, its speed w_e a state (the forward method):
    J_e dw_e/dt = T_cr(p_i, w_e) - T_acc(w_e) - s phi(nu) w_e^2, nu = w_t / w_e, with ``fired`` of the
    cylinders fired; the converter loads the engine with the share s = ``share`` of the pump's torque and
    passes s mu(nu) T_p to the gearbox (s < 1: the neutral-idle clutch between turbine and gearbox slipping,
    the forward method's pedal floor band; s = 0: the engine decoupled, the brakes on). Beyond nu = 1 (the
    turbine overrunning the engine) the pump's torque is negative (:func:`.vehicle.converter_capacity`):
    the coupling drives the engine. At idle speed an engine whose net torque is below that load is held
    there by its governor (the difference is the governor's, :func:`powers`), as :func:`converter_point`
    holds it; the governor's throttle (:func:`converter_idle_command`) brings the torque up to the load.

    Returns (engine speed, load torque s T_p, torque to the gearbox s mu T_p, dw_e/dt, held, switching
    value): the switching value is w_e - idle above idle, else :func:`converter_margin_at_idle` (positive:
    the engine speeds up from idle)."""
    idle = c.idle_speed
    w = w_e if w_e > idle else idle
    t_p = share * vh.converter_pump_torque(w, w_t, c)
    t_t = vh.converter_torque_ratio(w_t / w, c) * t_p
    net = en.fired_crank_torque(p_i, w, fired, c) - en.accessory_torque(w, c) - t_p
    sw = w_e - idle if w_e > idle else net  # at idle: converter_margin_at_idle, the same terms
    if sw <= 0.0:
        return w, t_p, t_t, 0.0, True, sw
    return w, t_p, t_t, net / c.inertia, False, sw


@inline
def operating_point(v, a, ratio, gear, t_closed, extended, c, cm18_wheel=None):
    """Engine operating point that speed v and acceleration a impose through gear ``gear`` (1-based) of
    total ratio ``ratio``.

    Paper mode: the stiff driveline (1),(14)-(18). Realistic (extended) mode: brakes below the closed-throttle
    torque ``t_closed`` (the FQM at A_min at the wheel-side speed), the clutch below idle speed, the
    accessories' torque on the crank, and fuel cut-off in overrun (:func:`engine_braking`): above
    ``c.fuel_cutoff_speed`` (if set) a demand below the closed-throttle torque cuts cylinders, all of them at
    or below the motoring torque, where the brakes take the rest. With a torque converter whose lock-up
    clutch is open, :func:`converter_point` (traction) or the idling engine (none).
    Returns (w_e, dw_e/dt, w_wheel, T_cr demanded, brake force, clutch state, fired fraction, wheel force);
    the clutch state is CLUTCH_ENGAGED, CLUTCH_SLIPPING, CLUTCH_CONVERTER or CLUTCH_OPEN. ``cm18_wheel``:
    :func:`.engine.speed_power` at the wheel-side engine speed, where the caller has it (the backward
    method: a factor per gear times the cycle's |v|^1.8); computed where needed if left out.
    """
    f_wheel = vh.wheel_force(v, a, c)  # (18)
    w_wheel = vh.engine_speed(v, ratio, c)  # (14),(17)
    dw = vh.engine_speed(a, ratio, c)
    t_cr = vh.crank_torque_demand(f_wheel, ratio, dw, c)  # (1),(15),(16)
    if not extended:
        return w_wheel, dw, w_wheel, t_cr, 0.0, CLUTCH_ENGAGED, 1.0, f_wheel
    if not vh.converter_locked(gear, v, c):
        if f_wheel > 0.0:
            w_p, dw_p, t_p, brake = converter_point(f_wheel, w_wheel, dw, ratio, c)
            return w_p, dw_p, w_wheel, t_p, brake, CLUTCH_CONVERTER, 1.0, f_wheel
        return (
            c.idle_speed,
            0.0,
            w_wheel,
            0.0,
            (-f_wheel if f_wheel < 0.0 else 0.0),
            CLUTCH_OPEN,
            1.0,
            f_wheel,
        )
    if clutch_engaged(w_wheel, c):
        t_cr = t_cr + en.accessory_torque(w_wheel, c)
        p_closed = en.intake_pressure_for_torque(t_closed, w_wheel, c, cm18_wheel) if t_cr < t_closed else 0.0
        t_cr, brake, fired = engine_braking(t_cr, t_closed, p_closed, w_wheel, ratio, c, cm18_wheel)
        return w_wheel, dw, w_wheel, t_cr, brake, CLUTCH_ENGAGED, fired, f_wheel
    if f_wheel > 0.0:  # slipping: the engine at idle passes the wheel torque, its inertia decoupled
        t_clutch = vh.wheel_to_engine_torque(f_wheel, ratio, c) + en.accessory_torque(c.idle_speed, c)
        return c.idle_speed, 0.0, w_wheel, t_clutch, 0.0, CLUTCH_SLIPPING, 1.0, f_wheel
    # open: the engine idles (accessories included in the idle flow), the brakes hold what the road load
    # does not
    return c.idle_speed, 0.0, w_wheel, 0.0, (-f_wheel if f_wheel < 0.0 else 0.0), CLUTCH_OPEN, 1.0, f_wheel


# indices of the energy terms returned by powers(), in EnergyBalance's order
ENERGY_TERMS = (
    "indicated",
    "friction",
    "pumping",
    "engine_kinetic",
    "driveline_loss",
    "vehicle_kinetic",
    "aero",
    "rolling",
    "brake",
    "trace_miss",
    "idle_control",
    "accessories",
)
N_TERMS = len(ENERGY_TERMS)


@inline
def engine_powers(p_i, w_e, t_cr, fired, c, cm18=None):
    """(indicated, friction, pumping) power (W) of the engine at intake pressure p_i, speed w_e and crank
    torque t_cr: q_hv eta_th times the burned fuel flow of the fired cylinders (4),(7); FMEP (5) at the
    engine's BMEP (fired or not) and PMEP (6), times the displacement's cycles per second. Their difference is
    the crank power T_cr w_e (2)."""
    cyc = en.cycles_per_second(w_e, c) * c.displacement  # MEP x this = power
    indicated = fired * en.burned_fuel_flow(p_i, w_e, c) * c.fuel_heating_value * c.thermal_efficiency
    friction = en.fmep_at_bmep(t_cr / c.mep_to_torque, w_e, c, cm18) * cyc
    pumping = en.pmep(p_i, c) * cyc
    return indicated, friction, pumping


@inline
def powers(p_i, w_e, dw_e, t_cr, t_missing, w_wheel, v, a, brake, clutch, fired, t_acc, passed, c, cm18=None):
    """Power (W) of every energy term at one instant, in the order of :data:`ENERGY_TERMS`.

    ``t_cr`` is the crank torque the engine makes and ``t_missing`` what the demand asked beyond it (trace
    miss of a quasi-static method; 0 otherwise). The accessories take their torque from the crank; with the
    clutch engaged the gearbox takes the rest of the flywheel torque T_e = T_cr + missing - J_e dw_e - T_acc
    (1) at w_e (through an unlocked converter, the turbine's mu nu of it, the converter's loss booked in
    the driveline term); while it slips, the clutch torque (the engine's, if positive) at the wheel-side
    speed, and the slip dissipates T_clutch (w_e - w_wheel); an idealised idle governor supplies what a
    negative crank torque of the declutched engine would take (``idle_control``). With the clutch open
    (quasi-static methods at rest, or an unlocked converter without traction) the idling engine is outside
    the balance. ``fired``: the fraction of the cylinders fired (0: fuel cut, no indicated work).
    ``t_acc``: the accessories' torque (:func:`accessories_torque`). ``passed``: the share of the unlocked
    converter's torque that loads the engine and reaches the gearbox (the forward method's neutral-idle
    clutch, :func:`converter_engine`; 1 otherwise). ``cm18``: the friction's power of the speed at w_e
    (:func:`.engine.speed_power`) where the caller has it; computed if left out.
    """
    vv = v if v > 0.0 else 0.0
    road = (c.mass * vv * a, vh.aero_force(vv, c) * vv, vh.rolling_force(vv, c) * vv, brake * vv)
    if clutch == CLUTCH_OPEN:
        return (0.0, 0.0, 0.0, 0.0, 0.0, road[0], road[1], road[2], road[3], 0.0, 0.0, 0.0)
    indicated, friction, pumping = engine_powers(p_i, w_e, t_cr, fired, c, cm18)
    t_asked = t_cr + t_missing - t_acc
    if clutch == CLUTCH_ENGAGED:
        engine_kinetic = c.inertia * w_e * dw_e
        driveline = (1.0 - c.efficiency) * (t_asked - c.inertia * dw_e) * w_e  # (1),(15)
        idle = 0.0
    elif clutch == CLUTCH_CONVERTER:  # the pump takes its torque at w_e, the turbine passes mu nu of it
        engine_kinetic = c.inertia * w_e * dw_e
        nu = w_wheel / w_e
        flywheel = t_asked - c.inertia * dw_e
        t_p = passed * vh.converter_pump_torque(w_e, w_wheel, c)
        driveline = (1.0 - c.efficiency * vh.converter_torque_ratio(nu, c) * nu) * t_p * w_e
        # the flywheel gives the pump's torque (to rounding), but the governor of an engine held at idle makes
        # up the difference (converter_engine): negative, work supplied
        idle = (flywheel - t_p) * w_e
    else:
        engine_kinetic = 0.0
        t_clutch = slipping_clutch_torque(t_asked)
        driveline = (1.0 - c.efficiency) * t_clutch * w_wheel + t_clutch * (w_e - w_wheel)
        idle = (t_asked - t_clutch) * w_e
    return (
        indicated,
        friction,
        pumping,
        engine_kinetic,
        driveline,
        road[0],
        road[1],
        road[2],
        road[3],
        t_missing * w_e,
        idle,
        t_acc * w_e,
    )


@inline
def powers_tangent(
    p_i,
    w_e,
    dw_e,
    t_cr,
    w_wheel,
    v,
    a,
    brake,
    clutch,
    fired,
    t_acc,
    d_p,
    d_w,
    d_dw,
    d_tcr,
    d_wheel,
    d_v,
    d_a,
    d_brake,
    d_fired,
    d_tacc,
    c,
    cm18=None,
):
    """Directional derivative of :func:`powers` (``t_missing`` = 0) along a change d_x of each of its
    arguments x (p_i, w_e, dw_e/dt, T_cr, w_wheel, v, a, brake force, fired fraction, accessories' torque):
    the forward method's closed-form Jacobian. Same terms and branches as :func:`powers` (at v <= 0, the
    branch of rest: no rolling resistance), except the unlocked converter's (CLUTCH_CONVERTER), where the
    forward method differences its right side instead."""
    vv = v if v > 0.0 else 0.0
    road = (
        c.mass * (d_v * a + vv * d_a),
        (vh.aero_force(vv, c) + vv * vh.aero_force_dv(vv, c)) * d_v,  # d/dv (F v) = F + v dF/dv
        (vh.rolling_force(vv, c) + vv * vh.rolling_force_dv(vv, c)) * d_v,
        d_brake * vv + brake * d_v,
    )
    if clutch == CLUTCH_OPEN:
        return (0.0, 0.0, 0.0, 0.0, 0.0, road[0], road[1], road[2], road[3], 0.0, 0.0, 0.0)
    cyc = en.cycles_per_second(w_e, c) * c.displacement
    d_flow = en.burned_fuel_flow_dp(w_e, c) * d_p  # the indicated work is the burned fuel's
    d_fmep = en.fmep_per_bmep(c) * (d_tcr / c.mep_to_torque)
    friction = 0.0
    pumping = -d_p * cyc  # (6)
    if d_w != 0.0:  # (the speed's terms, with their powers, only where the speed moves)
        d_cyc = en.cycles_per_second(d_w, c) * c.displacement
        d_flow += en.burned_fuel_flow_dw(p_i, c) * d_w
        d_fmep += en.speed_friction_dw(w_e, c, cm18) * d_w
        friction = en.fmep_at_bmep(t_cr / c.mep_to_torque, w_e, c, cm18) * d_cyc
        pumping += en.pmep(p_i, c) * d_cyc
    friction += d_fmep * cyc  # (5)
    indicated = fired * d_flow
    if d_fired != 0.0:
        indicated += d_fired * en.burned_fuel_flow(p_i, w_e, c)
    indicated *= c.fuel_heating_value * c.thermal_efficiency
    t_asked = t_cr - t_acc
    d_asked = d_tcr - d_tacc
    if clutch == CLUTCH_ENGAGED:
        engine_kinetic = c.inertia * (d_w * dw_e + w_e * d_dw)
        d_flywheel = (d_asked - c.inertia * d_dw) * w_e + (t_asked - c.inertia * dw_e) * d_w
        driveline = (1.0 - c.efficiency) * d_flywheel  # (1),(15)
        idle = 0.0
    else:
        engine_kinetic = 0.0
        t_clutch = slipping_clutch_torque(t_asked)
        d_clutch = d_asked if t_asked > 0.0 else 0.0  # slipping_clutch_torque's branch
        driveline = (
            (1.0 - c.efficiency) * (d_clutch * w_wheel + t_clutch * d_wheel)
            + d_clutch * (w_e - w_wheel)
            + t_clutch * (d_w - d_wheel)
        )
        idle = (d_asked - d_clutch) * w_e + (t_asked - t_clutch) * d_w
    return (
        indicated,
        friction,
        pumping,
        engine_kinetic,
        driveline,
        road[0],
        road[1],
        road[2],
        road[3],
        0.0,
        idle,
        d_tacc * w_e + t_acc * d_w,
    )


def stopped_at_rest(v, a, free=None):
    """Stop-start (``simulation.stop_start``): (the intervals whose engine stands, the restarts) of a cycle's
    intervals (mean speed v, acceleration a). The engine stops in every interval at rest (speed 0 at both
    ends) after the car first moved, and restarts when it moves off; stopped it burns nothing and books no
    engine term. The standstill before the first move keeps idling (the key-on start warms the engine;
    production systems stop only after the car has moved); a stop at the cycle's end needs no restart. Each
    restart costs ``hybrid.engine_start_fuel`` (the start model the hybrids use).

    ``free`` (optional, one per interval): where the engine is free of the wheels (its clutch open) over the
    interval; a method whose car may still roll, or be coupled, where the cycle rests (the forward method's)
    stops the engine only there. The backward method's car is the cycle's: at rest, it is free."""
    import numpy as np

    rest = (np.asarray(v) == 0.0) & (np.asarray(a) == 0.0)
    moving = np.flatnonzero(~rest)
    stopped = rest.copy()
    stopped[: moving[0] if moving.size else rest.size] = False
    if free is not None:
        stopped &= np.asarray(free, dtype=bool)
    return stopped, int(np.count_nonzero(stopped[:-1] & ~stopped[1:]))
