"""The mean-value spark-ignition engine, equations (1)-(13) and (19) of Hofman et al. (2011), written once.

Every function here is the one definition of its equation. Each is a plain function of scalars and the
parameter record ``c`` (:mod:`vpsim.model.record`), marked :func:`equation`: compiled kernels (the three
methods, the batch runs, the maps) inline it, and Python calls it as it is, which for the branch-free
equations works on NumPy arrays too (broadcasting, also over a record array of design variants). The few
equations with branches (the flow function Psi, the FQM solve) have array views made from the same scalar
function by a compiled loop (:func:`psi_array`, :func:`steady_pressure_array`).

Symbols follow the paper: p_i intake manifold pressure, w_e engine speed, A_eff effective throttle area,
T_cr crank (combustion) torque, m_ac / m_f air / fuel charge per cycle. SI units throughout.
"""

from __future__ import annotations

import math

import numpy as np
from numba.extending import register_jitable

from ._compile import kernel


def equation(fn):
    """Mark a model equation: compiled into every kernel that calls it, plain Python otherwise."""
    fn._vpsim_inline = False  # part of the kernels' cache stamp (vpsim.model._compile)
    return register_jitable(fn)


def inline(fn):
    """Like :func:`equation`, and inlined at Numba IR level into its callers: for the per-step glue of a
    kernel, whose calls (arrays and long tuples in and out) would otherwise cost more than their work."""
    fn._vpsim_inline = True  # part of the kernels' cache stamp: a kernel compiled either way is another
    return register_jitable(inline="always")(fn)


TWO_PI = 2.0 * math.pi


# --- derived constants (evaluated once per parameter set by vpsim.model.record) -------------------------


@equation
def displacement(c):
    """V_d = z (pi/4) B^2 S."""
    return c.cylinders * math.pi / 4.0 * c.bore**2 * c.stroke


@equation
def friction_factor(c):
    """k_f = xi_aux (0.075 / B)^0.5, the bore scaling of Soltic's friction law (5)."""
    return c.friction_coefficient * np.sqrt(0.075 / c.bore)


@equation
def bmep_divisor(c):
    """1 + 0.0215 k_f: FMEP (5) contains BMEP, so solving (2)-(6) for BMEP divides by this."""
    return 1.0 + 0.0215 * friction_factor(c)


@equation
def bmep_per_net_mep(c):
    """1 / (1 + 0.0215 k_f): BMEP per unit of IMEP - speed friction - PMEP, (2)-(6) solved for BMEP (the
    record's ``bmep_per_net_mep``; the equations multiply by it)."""
    return 1.0 / bmep_divisor(c)


@equation
def heat_factor(c):
    """Q = q_hv eta_th / ((A/F)_s lambda R T_i): IMEP (4) per unit of (s_i p_i - y_i) via (7),(8)."""
    return (
        c.fuel_heating_value
        * c.thermal_efficiency
        / (c.stoich_air_fuel_ratio * c.lambda_ * c.gas_constant * c.intake_temperature)
    )


@equation
def intake_rt(c):
    """R T_i: the intake air's pressure per density, (8)-(10)."""
    return c.gas_constant * c.intake_temperature


@equation
def ambient_rt_sqrt(c):
    """sqrt(R T_a): the throttle flow's (10) temperature factor."""
    return np.sqrt(c.gas_constant * c.ambient_temperature)


@equation
def air_fuel_ratio(c):
    """(A/F)_s lambda: air per fuel of the charge (7)."""
    return c.stoich_air_fuel_ratio * c.lambda_


@equation
def fuel_per_air(c):
    """1 / ((A/F)_s lambda): fuel per air of the charge (7) (the record's ``fuel_per_air``)."""
    return 1.0 / air_fuel_ratio(c)


@equation
def cycles_per_radian(c):
    """1 / (2 pi n_r): engine cycles per radian of the crank (the record's ``cycles_per_radian``)."""
    return 1.0 / (TWO_PI * c.revolutions_per_cycle)


@equation
def air_per_charge_pressure(c):
    """V_d / (R T_i): the cylinder air charge per unit of charge pressure (8)."""
    return displacement(c) / intake_rt(c)


@equation
def mep_to_torque(mep, c):
    """Torque of a mean effective pressure: T = MEP V_d / (2 pi n_r)   (3)."""
    return mep * displacement(c) / (TWO_PI * c.revolutions_per_cycle)


@equation
def critical_pressure_ratio(gamma):
    """p_r* = (2/(gamma+1))^(gamma/(gamma-1))   (11)."""
    return (2.0 / (gamma + 1.0)) ** (gamma / (gamma - 1.0))


@equation
def psi_choked(gamma):
    """Psi in the choked region, sqrt(gamma (2/(gamma+1))^((gamma+1)/(gamma-1)))   (12)."""
    return np.sqrt(gamma * (2.0 / (gamma + 1.0)) ** ((gamma + 1.0) / (gamma - 1.0)))


# --- cylinder air and fuel charge --------------------------------------------------------------------------


@equation
def charge_pressure(p_i, c):
    """s_i p_i - y_i: eta_vol p_i, the pressure that fills the cylinders (8)."""
    return c.air_charge_slope * p_i - c.air_charge_intercept


@equation
def air_charge(p_i, c):
    """m_ac = eta_vol p_i V_d / (R T_i) = (s_i p_i - y_i) V_d / (R T_i)   (8)."""
    return charge_pressure(p_i, c) * c.air_per_charge


@equation
def cycles_per_second(w_e, c):
    """Engine cycles per second, w_e / (2 pi n_r)."""
    return w_e * c.cycles_per_radian


@equation
def cylinder_air_flow(p_i, w_e, c):
    """Air mass flow into the cylinders, w_e m_ac / (2 pi n_r) (the outflow term of (9))."""
    return cycles_per_second(w_e, c) * air_charge(p_i, c)


@equation
def burned_fuel_flow(p_i, w_e, c):
    """Fuel mass flow that burns, mdot_f = m_f w_e / (2 pi n_r), m_f = m_ac / ((A/F)_s lambda)   (7): what
    IMEP (4) is made of. Negative where p_i < y_i / s_i (no air charge): the caller decides what that
    means."""
    return cylinder_air_flow(p_i, w_e, c) * c.fuel_per_air


def enrichment_slope(c):
    """d(enrichment)/dp_i above ambient: ``boost_enrichment`` over the boost range, 0 for an aspirated
    engine (scalars or arrays of variants; evaluated once per parameter set by vpsim.model.record)."""
    span = np.asarray(c.boost_pressure - c.ambient_pressure, dtype=float)
    slope = np.where(span > 0.0, c.boost_enrichment / np.where(span > 0.0, span, 1.0), 0.0)
    return slope if slope.ndim else float(slope)


@equation
def enrichment(p_i, c):
    """Full-load enrichment of a boosted engine: the fuel supplied beyond (7), as a fraction of it.

    Turbocharged SI engines run rich at high boost to cool the exhaust valves, turbine and catalyst
    (component protection; Heywood 1988, sec. 7.1 and 13.7; Guzzella & Onder 2010, sec. 2.3): lambda falls
    from 1 at ambient intake pressure to 1 / (1 + ``boost_enrichment``) at full boost, linearly in p_i. The
    extra fuel leaves unburned (rich combustion is limited by the air), so IMEP (4) and the torque are those
    of the air charge. 0 for an aspirated engine and at or below ambient pressure. Written without branches
    (min and max from abs), so it serves scalars in kernels and arrays alike.
    """
    d = p_i - c.ambient_pressure
    rich = c.enrichment_slope * 0.5 * (d + abs(d))
    return 0.5 * (rich + c.boost_enrichment - abs(rich - c.boost_enrichment))


@equation
def fuel_flow(p_i, w_e, c):
    """Fuel mass flow supplied: (7) with the full-load enrichment of a boosted engine (:func:`enrichment`),
    the flow every method books. Negative where p_i < y_i / s_i (no air charge).

    Without enrichment (an aspirated engine) (7) alone: the same number (times 1 + 0), without the
    enrichment's arithmetic on the path from a demand to its fuel, which bounds the backward kernels."""
    burned = burned_fuel_flow(p_i, w_e, c)
    if c.boost_enrichment == 0.0:
        return burned
    return burned * (1.0 + enrichment(p_i, c))


# --- mean effective pressures and torque (2)-(6) -----------------------------------------------------------


@equation
def imep(p_i, c):
    """Gross indicated mean effective pressure IMEP_g = m_f q_hv eta_th / V_d   (4)."""
    return c.heat_factor * charge_pressure(p_i, c)


@equation
def pmep(p_i, c):
    """Pumping mean effective pressure PMEP = p_e - p_i   (6)."""
    return c.exhaust_pressure - p_i


@equation
def speed_power_scaled(x):
    """|x|^1.8, the power of Soltic's law (5): c_m^1.8 is homogeneous in the speed, so where the engine
    speed is a factor times a vehicle speed (w_e = i v / r, engaged) c_m^1.8 is the factor's
    :func:`speed_power` times this of v. A caller with many speeds and few factors (the backward method:
    one factor per gear, the cycle's speeds shared by every run on it) takes the power once per speed."""
    return abs(x) ** 1.8


@equation
def speed_power(w_e, c):
    """c_m^1.8 of (5), c_m = S |w_e| / pi: the one power of the speed in Soltic's law. The equations below
    that need it take it as ``cm18`` where a compiled caller has it already at this speed (one power per
    evaluation of the forward method's right side instead of three); left out, they compute it."""
    return speed_power_scaled(c.stroke * w_e / math.pi)


@equation
def speed_friction(w_e, c, cm18=None):
    """The speed-dependent part of FMEP (5): k_f (0.464 + 0.0072 c_m^1.8) pi_bl 1e5, c_m = S |w_e| / pi."""
    if cm18 is None:
        cm18 = speed_power(w_e, c)
    return c.friction_factor * (0.464 + 0.0072 * cm18) * c.boost_layout * 1e5


@equation
def speed_friction_dw(w_e, c, cm18=None):
    """d/dw_e of :func:`speed_friction`: k_f 0.0072 x 1.8 c_m^1.8 / w_e pi_bl 1e5 (c_m^0.8 S / pi = c_m^1.8 /
    |w_e|: the friction's own power, :func:`speed_power`)."""
    if w_e == 0.0:
        return 0.0
    if cm18 is None:
        cm18 = speed_power(w_e, c)
    return c.friction_factor * 0.0072 * 1.8 * cm18 / w_e * c.boost_layout * 1e5


@equation
def bmep_from_pressure(p_i, w_e, c, cm18=None):
    """BMEP from (2)-(6): IMEP - FMEP - PMEP with FMEP = speed part + 0.0215 k_f BMEP."""
    return (imep(p_i, c) - speed_friction(w_e, c, cm18) - pmep(p_i, c)) * c.bmep_per_net_mep


@equation
def fmep_per_bmep(c):
    """dFMEP/dBMEP of (5): 0.0215 k_f."""
    return c.friction_factor * 0.0215


@equation
def fmep_at_bmep(bmep, w_e, c, cm18=None):
    """Friction mean effective pressure FMEP (5) at a given BMEP: Soltic's law with the factor xi_aux."""
    return speed_friction(w_e, c, cm18) + fmep_per_bmep(c) * bmep


@equation
def fmep(p_i, w_e, c):
    """FMEP (5) of the fired engine at (p_i, w_e)."""
    return fmep_at_bmep(bmep_from_pressure(p_i, w_e, c), w_e, c)


@equation
def crank_torque(p_i, w_e, c, cm18=None):
    """T_cr = BMEP V_d / (2 pi n_r)   (2),(3)."""
    return bmep_from_pressure(p_i, w_e, c, cm18) * c.mep_to_torque


@equation
def motoring_torque(p_i, w_e, c, cm18=None):
    """Crank torque with the fuel cut (IMEP = 0): the engine turned by the wheels brakes with its friction
    and pumping, (2)-(6) without (4)."""
    return crank_torque(p_i, w_e, c, cm18) - imep(p_i, c) * c.bmep_per_net_mep * c.mep_to_torque


@equation
def partly_fired_torque(p_i, w_e, fired, c, cm18=None):
    """Crank torque with the fraction ``fired`` of the cylinders fired (fuel cut-off in overrun): the
    motoring torque plus that fraction of what the fuel adds, (2)-(6) with IMEP (4) scaled."""
    t_motor = motoring_torque(p_i, w_e, c, cm18)
    return t_motor + fired * (crank_torque(p_i, w_e, c, cm18) - t_motor)


@equation
def fired_crank_torque(p_i, w_e, fired, c, cm18=None):
    """Crank torque with ``fired`` of the cylinders fired: :func:`crank_torque` when all fire, else
    :func:`partly_fired_torque`."""
    return partly_fired_torque(p_i, w_e, fired, c, cm18) if fired < 1.0 else crank_torque(p_i, w_e, c, cm18)


@equation
def imep_per_pressure(c):
    """dIMEP/dp_i of (4),(8): Q s_i."""
    return c.heat_factor * c.air_charge_slope


@equation
def burned_fuel_flow_dp(w_e, c):
    """d/dp_i of :func:`burned_fuel_flow`, (7),(8) at fixed w_e (the flow is affine in p_i)."""
    return cycles_per_second(w_e, c) * c.air_per_charge * c.air_charge_slope * c.fuel_per_air


@equation
def burned_fuel_flow_dw(p_i, c):
    """d/dw_e of :func:`burned_fuel_flow`, (7),(8) at fixed p_i (the flow is linear in w_e)."""
    return cylinder_air_flow(p_i, 1.0, c) * c.fuel_per_air


@equation
def enrichment_dp(p_i, c):
    """d/dp_i of :func:`enrichment`: its slope between ambient pressure and full boost, 0 elsewhere."""
    d = p_i - c.ambient_pressure
    if d <= 0.0 or c.enrichment_slope * d >= c.boost_enrichment:
        return 0.0
    return c.enrichment_slope


@equation
def fuel_flow_dp(p_i, w_e, c):
    """d/dp_i of :func:`fuel_flow` at fixed w_e: the burned flow's slope and the enrichment's (none without
    enrichment, as in :func:`fuel_flow`)."""
    if c.boost_enrichment == 0.0:
        return burned_fuel_flow_dp(w_e, c)
    return burned_fuel_flow_dp(w_e, c) * (1.0 + enrichment(p_i, c)) + burned_fuel_flow(
        p_i, w_e, c
    ) * enrichment_dp(p_i, c)


@equation
def fuel_flow_dw(p_i, c):
    """d/dw_e of :func:`fuel_flow` at fixed p_i (linear in w_e; the enrichment depends on p_i only)."""
    if c.boost_enrichment == 0.0:
        return burned_fuel_flow_dw(p_i, c)
    return burned_fuel_flow_dw(p_i, c) * (1.0 + enrichment(p_i, c))


@equation
def crank_torque_dw(w_e, c, cm18=None):
    """dT_cr/dw_e at fixed p_i, fired or not (:func:`partly_fired_torque`): FMEP's speed part (5) through
    the BMEP divisor."""
    return -speed_friction_dw(w_e, c, cm18) * c.bmep_per_net_mep * c.mep_to_torque


@equation
def partly_fired_torque_dp(fired, c):
    """d/dp_i of :func:`partly_fired_torque` at fixed w_e and ``fired``: the fired engine's slope less the
    unfired share of IMEP's (4), through the BMEP divisor of (5)."""
    return c.torque_slope - (1.0 - fired) * imep_per_pressure(c) * c.bmep_per_net_mep * c.mep_to_torque


@equation
def partly_fired_torque_dfired(p_i, c):
    """d/d(fired) of :func:`partly_fired_torque`: what the fuel adds, IMEP (4) through the divisor of (5)."""
    return imep(p_i, c) * c.bmep_per_net_mep * c.mep_to_torque


@equation
def accessory_torque(w_e, c):
    """Torque the accessories (alternator, pumps) take from the crankshaft: their power over the engine
    speed, the speed taken no lower than idle (a running engine)."""
    if c.accessory_power == 0.0:  # none (every preset's hybrid): no division where choices are tried by the
        return 0.0  # dozen per step (the P2's ECMS ran 25 % slower with it)
    return c.accessory_power / (w_e if w_e > c.idle_speed else c.idle_speed)


def torque_slope(c):
    """dT_cr/dp_i from two evaluations of :func:`crank_torque` (evaluated once per parameter set, the
    record's ``torque_slope``). T_cr is affine in p_i by (2)-(8), with a slope that does not depend on w_e
    (IMEP (4) and PMEP (6) are linear in p_i, FMEP's speed part (5) does not depend on p_i): every inversion
    below follows the torque definition above. tests/test_model.py checks the slope at other speeds."""
    return (crank_torque(c.ambient_pressure, 0.0, c) - crank_torque(0.0, 0.0, c)) / c.ambient_pressure


@equation
def torque_per_pressure(w_e, c):
    """dT_cr/dp_i at fixed w_e (:func:`torque_slope`: the same at every speed)."""
    return c.torque_slope


def pressure_per_torque(c):
    """1 / (dT_cr/dp_i) (the record's ``pressure_per_torque``; scalars or arrays of variants, evaluated once
    per parameter set by vpsim.model.record; inf for an engine whose torque does not rise with p_i, which
    :func:`check` refuses)."""
    slope = np.asarray(c.torque_slope, dtype=float)
    out = np.divide(1.0, slope, out=np.full(slope.shape, np.inf), where=slope != 0.0)
    return out if out.ndim else float(out)


@equation
def intake_pressure_for_torque(t_cr, w_e, c, cm18=None):
    """p_i with delta(p_i) = 0 for imposed (T_cr, w_e): the BQM's inversion of (2)-(8).

    delta(p_i) = T_cr(p_i, w_e) - T_cr is linear in p_i, so the root is closed-form (the paper iterates; both
    agree): p_i = (T_cr - T_cr(0, w_e)) / (dT_cr/dp_i). ``cm18``: :func:`speed_power` at w_e, if at hand.
    """
    return (t_cr - crank_torque(0.0, w_e, c, cm18)) * c.pressure_per_torque


@equation
def bqm_fuel_flow(t_cr, w_e, c):
    """BQM: fuel mass flow (kg/s) for imposed crank torque and engine speed."""
    return fuel_flow(intake_pressure_for_torque(t_cr, w_e, c), w_e, c)


# --- throttle and intake manifold (9)-(13) -----------------------------------------------------------------


@equation
def psi(p_r, c):
    """Flow function Psi(p_r): choked (12) for p_r <= p_r*, subcritical (13) above; 0 for p_r >= 1.

    Reverse flow (p_r > 1) cannot occur in a naturally aspirated engine with these equations; the flow is
    taken as zero there, which is also what the manifold equation needs at w_e = 0 (p_i settles at p_a).
    """
    if p_r <= c.critical_ratio:
        return c.psi_choked
    if p_r >= 1.0:
        return 0.0
    _, f = _psi_squared(p_r, c)
    return math.sqrt(f) if f > 0.0 else 0.0


@equation
def _psi_squared(p_r, c):
    """(x, Psi^2) of the subcritical flow (13), x = p_r^(1/gamma): one power, p_r^(2/g) = x^2 and
    p_r^((g+1)/g) = p_r x."""
    g = c.specific_heat_ratio
    x = p_r ** (1.0 / g)
    return x, 2.0 * g / (g - 1.0) * (x * x - p_r * x)


@equation
def _dpsi_from(p_r, x, f, c):
    """dPsi/dp_r of the subcritical flow from :func:`_psi_squared`'s (x, Psi^2)."""
    g = c.specific_heat_ratio
    df = 2.0 * g / (g - 1.0) * ((2.0 / g) * x * x / p_r - ((g + 1.0) / g) * x)
    return df / (2.0 * math.sqrt(f if f > 1e-300 else 1e-300))


@equation
def dpsi_dpr(p_r, c):
    """dPsi/dp_r (0 in the choked region; -> -inf as p_r -> 1; 0 above 1, where Psi = 0)."""
    if p_r <= c.critical_ratio or p_r >= 1.0:
        return 0.0
    x, f = _psi_squared(p_r, c)
    return _dpsi_from(p_r, x, f, c)


@equation
def throttle_flow_per_area_from(p_up, p_i, c):
    """mdot_at / A_eff = p_up Psi(p_i/p_up) / sqrt(R T_a)   (10) with the pressure p_up upstream of the
    throttle (ambient, or a boosted engine's compressor outlet, intercooled to the ambient temperature)."""
    return p_up * psi(p_i / p_up, c) / c.sqrt_rt_ambient


@equation
def throttle_flow_per_area(p_i, c):
    """mdot_at / A_eff = p_a Psi(p_i/p_a) / sqrt(R T_a)   (10)."""
    return throttle_flow_per_area_from(c.ambient_pressure, p_i, c)


@equation
def throttle_mass_flow(a_eff, p_i, c):
    """mdot_at = p_a A_eff Psi(p_i/p_a) / sqrt(R T_a)   (10)."""
    return a_eff * throttle_flow_per_area(p_i, c)


# --- boost: the throttle command beyond A_max ---------------------------------------------------------------
# A boosted engine's air path is driven by one command u (m², what the driver or the inverse asks): up to
# A_max it is the throttle area with ambient pressure upstream, as in an aspirated engine; beyond, the
# throttle stays wide open and the boost control (wastegate) raises the pressure upstream of it, linearly in
# u, to the boost the turbocharger can give at that speed at u = 2 A_max. Ideal boost control: no turbo lag,
# no compressor work in the balance (the exhaust drives it). Aspirated engines (boost_pressure <= p_a) are
# unchanged.

BOOST_SPOOL_SPEED = 200.0  # rad/s (1,900 rpm): a modern turbocharger's full boost from about here up


@equation
def is_boosted(c):
    return c.boost_pressure > c.ambient_pressure


@equation
def boost_available(w_e, c):
    """Pressure upstream of the throttle at full boost: ``c.boost_pressure`` from :data:`BOOST_SPOOL_SPEED`
    up, linearly from ambient below (where the exhaust cannot yet drive the turbine); ambient if aspirated."""
    if not is_boosted(c):
        return c.ambient_pressure
    spool = w_e / BOOST_SPOOL_SPEED if w_e < BOOST_SPOOL_SPEED else 1.0
    if spool < 0.0:
        spool = 0.0
    return c.ambient_pressure + (c.boost_pressure - c.ambient_pressure) * spool


@equation
def boost_available_dw(w_e, c):
    """d/dw_e of :func:`boost_available`: the spool's slope below :data:`BOOST_SPOOL_SPEED`, 0 elsewhere."""
    if not is_boosted(c) or not 0.0 < w_e < BOOST_SPOOL_SPEED:
        return 0.0
    return (c.boost_pressure - c.ambient_pressure) / BOOST_SPOOL_SPEED


@equation
def max_command(c):
    """Upper end of the throttle command: A_max aspirated, 2 A_max boosted (full boost). Branch-free, so it
    also takes a record array of variants."""
    return c.max_throttle_area * (1.0 + is_boosted(c))


@equation
def throttle_upstream(u, w_e, c):
    """(throttle area, pressure upstream of it) for the command u at engine speed w_e."""
    a_max = c.max_throttle_area
    if u <= a_max or not is_boosted(c):
        return u, c.ambient_pressure
    frac = (u - a_max) / a_max
    if frac > 1.0:
        frac = 1.0
    return a_max, c.ambient_pressure + frac * (boost_available(w_e, c) - c.ambient_pressure)


@equation
def manifold_pressure_rate(p_i, a_eff, w_e, c):
    """dp_i/dt = (R T_i / V_i) [mdot_at - w_e m_ac / (2 pi n_r)]   (9); ``a_eff`` is the throttle command
    (the throttle area, and beyond A_max the boost of a boosted engine: :func:`throttle_upstream`)."""
    a, p_up = throttle_upstream(a_eff, w_e, c)
    return (c.rt_intake / c.intake_manifold_volume) * (
        a * throttle_flow_per_area_from(p_up, p_i, c) - cylinder_air_flow(p_i, w_e, c)
    )


@equation
def throttle_for_flow(p_i, air_flow, c):
    """A_eff that passes ``air_flow`` at manifold pressure p_i: (10) solved for A_eff (inf where Psi = 0)."""
    per_area = throttle_flow_per_area(p_i, c)
    if per_area > 0.0:
        return air_flow / per_area
    return math.inf if air_flow > 0.0 else 0.0


@equation
def upstream_for_flow(p_i, air_flow, a_eff, c):
    """Pressure upstream of a throttle of area ``a_eff`` that passes ``air_flow`` into p_i: (10) solved for
    p_up (its flow p_up Psi(p_i/p_up) grows with p_up): closed form where choked, bisection otherwise."""
    k = air_flow * c.sqrt_rt_ambient / a_eff  # p_up Psi(p_i / p_up) asked
    if not k > 0.0:
        return p_i
    p_choked = k / c.psi_choked
    if p_i / p_choked <= c.critical_ratio:
        return p_choked
    lo, hi = p_i, p_i / c.critical_ratio  # subcritical: between no flow and the onset of choking
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if mid * psi(p_i / mid, c) < k:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-13 * hi:
            break
    return 0.5 * (lo + hi)


@equation
def command_for_flow(p_i, air_flow, w_e, c):
    """Throttle command that passes ``air_flow`` at manifold pressure p_i and engine speed w_e: the throttle
    area (:func:`throttle_for_flow`) or, for a boosted engine beyond A_max, the boost command
    (:func:`throttle_upstream` inverted); beyond full boost the command extrapolates past 2 A_max."""
    u = throttle_for_flow(p_i, air_flow, c)
    if u <= c.max_throttle_area or not is_boosted(c):
        return u
    a_max = c.max_throttle_area
    span = boost_available(w_e, c) - c.ambient_pressure
    p_up = upstream_for_flow(p_i, air_flow, a_max, c)
    if not span > 0.0:
        return math.inf if p_up > c.ambient_pressure else a_max
    return a_max * (1.0 + (p_up - c.ambient_pressure) / span)


# --- the forward quasi-static model (FQM): steady state of (9) -------------------------------------------

NEWTON_MAX_ITERATIONS = (
    30  # defaults tighter than the paper's 10, so maps agree with the dynamics to rounding
)
NEWTON_RELATIVE_TOLERANCE = 1e-12


@equation
def steady_pressure(a_eff, w_e, c):
    """FQM: p_i with dp_i/dt = 0 in (9) for imposed throttle area and engine speed; (p_i, Newton iterations).

    Choked flow is tried first ((10),(12) with (8),(9) solved for p_i); where the resulting pressure ratio is
    above the critical one (11) the flow is subcritical and theta(p_i) = 0 (19) is solved by Newton's method.
    theta is concave and decreasing in p_i, so Newton started to the right of the root (the choked estimate,
    or just below p_a) converges monotonically. At w_e = 0 nothing leaves the manifold and p_i = p_a.
    Iterations: -1 where the solve did not converge.
    """
    a_eff, p_a = throttle_upstream(a_eff, w_e, c)  # (ambient upstream, or a boosted engine's boost)
    if not w_e > 0.0:
        return p_a, 0
    k_thr = a_eff * p_a * c.psi_choked / c.sqrt_rt_ambient  # choked throttle flow
    k_cyl = cycles_per_second(w_e, c) * c.air_per_charge  # cylinder flow per unit (s_i p_i - y_i)
    p_choked = (k_thr / k_cyl + c.air_charge_intercept) / c.air_charge_slope
    if p_choked / p_a <= c.critical_ratio:
        return p_choked, 0
    x = min(p_choked, p_a * (1.0 - 1e-9))
    lo = c.critical_ratio * p_a
    hi = p_a * (1.0 - 1e-15)
    for k in range(NEWTON_MAX_ITERATIONS):
        pr = x / p_a
        theta = a_eff * throttle_flow_per_area_from(p_a, x, c) - k_cyl * charge_pressure(x, c)  # (19)
        dtheta = a_eff * p_a * dpsi_dpr(pr, c) / c.sqrt_rt_ambient / p_a - k_cyl * c.air_charge_slope
        x_new = min(max(x - theta / dtheta, lo), hi)
        done = abs(x_new - x) <= NEWTON_RELATIVE_TOLERANCE * abs(x_new)
        x = x_new
        if done:
            return x, k + 1
    return x, -1


@equation
def closed_throttle_pressure_bound(c):
    """An upper bound of the closed-throttle intake pressure (the FQM at A_min) at every speed an engaged
    engine turns at: that pressure at the idle speed, the lowest the clutch engages at (above it the
    pressure falls: the throttle passes the same flow while the cylinders draw more), made less tight by
    1e-9 for the Newton solve's tolerance; +inf where the crank torque does not rise with p_i (the bound
    then proves nothing). A demand at or above :func:`crank_torque` at the bound is above the closed-throttle
    torque, whose solve it then does not need."""
    if not c.torque_slope > 0.0:
        return math.inf
    p, _ = steady_pressure(c.min_throttle_area, c.idle_speed, c)
    return p * (1.0 + 1e-9)


@equation
def steady_torque(a_eff, w_e, c, cm18=None):
    """FQM crank torque at (A_eff, w_e): T_cr(p_i steady, w_e). ``cm18``: :func:`speed_power` at w_e, if
    at hand."""
    p, _ = steady_pressure(a_eff, w_e, c)
    return crank_torque(p, w_e, c, cm18)


@equation
def full_load_pressure(w_e, c):
    """Intake pressure at full load: the FQM at the command's upper end (:func:`max_command`): A_max for an
    aspirated engine; for a boosted one the throttle wide open at full boost (:func:`boost_available`)."""
    p, _ = steady_pressure(max_command(c), w_e, c)
    return p


@equation
def full_load_torque(w_e, c):
    """The maximum-torque line: crank torque at the full-load pressure, capped at the rated power
    (``c.rated_power`` / w_e) where one is given."""
    t = crank_torque(full_load_pressure(w_e, c), w_e, c)
    if c.rated_power > 0.0 and w_e > 0.0 and t * w_e > c.rated_power:
        return c.rated_power / w_e
    return t


@equation
def full_load_screen(w_s, step, c):
    """An intake pressure below which no operating point at an engine speed up to ``w_s`` reaches the
    max-torque line tabulated from the model at nodes ``step`` apart from 0
    (:func:`vpsim.model.maps.generate_engine_map`), so a method need not read the line there; -inf where no
    such bound holds.

    The line's nodes are T_cr(p_max(w_j), w_j). The wide-open-throttle pressure p_max(w_e) falls as w_e rises,
    so at every node up to ``w_s`` it is at least p_max(w_s); between two nodes the interpolated line stays
    above T_cr(p_max(w_s), w_e) less the friction's rise over two node intervals (5), largest at the top (the
    friction is convex in the speed). A demand whose intake pressure (2)-(8) inverted, the torque's
    monotone image, is below p_max(w_s) less that rise (and 1e-7 of ambient for the solve's tolerance) is
    below the line. A boosted engine's full-load pressure is not monotone (spool), a power cap bends the
    line: no bound then."""
    if c.boost_pressure > c.ambient_pressure or c.rated_power > 0.0:
        return -math.inf
    p_floor, _ = steady_pressure(c.max_throttle_area, w_s, c)
    w_below = max(w_s - 2.0 * step, 0.0)
    d_p = intake_pressure_for_torque(0.0, w_s, c) - intake_pressure_for_torque(0.0, w_below, c)
    return p_floor - d_p - 1e-7 * c.ambient_pressure


@equation
def boost_for_power(power, w_e, c):
    """The boost (pressure upstream of the wide-open throttle) that gives ``power`` at engine speed w_e
    (from :data:`BOOST_SPOOL_SPEED` up): the intake pressure of that torque, (2)-(8) inverted, and the
    pressure that pushes its cylinder flow through A_max, (10) inverted."""
    p_i = intake_pressure_for_torque(power / w_e, w_e, c)
    return upstream_for_flow(p_i, cylinder_air_flow(p_i, w_e, c), c.max_throttle_area, c)


@equation
def steady_point(t_cr, w_e, c):
    """(p_i, throttle command) that hold crank torque ``t_cr`` at engine speed ``w_e`` steady (the FQM
    inverted: :func:`intake_pressure_for_torque`, then :func:`command_for_flow`), the manifold pressure
    taken at most 99 % of full load's (ambient for an aspirated engine), where the command stays finite."""
    p = intake_pressure_for_torque(t_cr, w_e, c)
    p_top = full_load_pressure(w_e, c) if is_boosted(c) else c.ambient_pressure
    if p > 0.99 * p_top:
        p = 0.99 * p_top
    return p, command_for_flow(p, cylinder_air_flow(p, w_e, c), w_e, c)


@equation
def idle_throttle(c):
    """Steady throttle area holding the engine at idle speed with zero crank torque (FQM inverted), m²."""
    p = intake_pressure_for_torque(0.0, c.idle_speed, c)
    return throttle_for_flow(p, cylinder_air_flow(p, c.idle_speed, c), c)


# --- array views of the equations with branches -------------------------------------------------------------


@kernel
def _psi_loop(p_r, recs, out):
    one = recs.size == 1
    for k in range(p_r.size):
        out[k] = psi(p_r[k], recs[0 if one else k])


@kernel
def _dpsi_loop(p_r, recs, out):
    one = recs.size == 1
    for k in range(p_r.size):
        out[k] = dpsi_dpr(p_r[k], recs[0 if one else k])


@kernel
def _full_load_loop(w_e, recs, out):
    one = recs.size == 1
    for k in range(w_e.size):
        out[k] = full_load_torque(w_e[k], recs[0 if one else k])


def full_load_torque_array(w_e, c):
    """:func:`full_load_torque` over an array of engine speeds."""
    shape, (w,), recs = _flat(w_e, recs=c)
    out = np.empty(w.size)
    _full_load_loop(w, recs, out)
    return out.reshape(shape)


@kernel
def _steady_loop(a_eff, w_e, recs, p_out, it_out):
    one = recs.size == 1
    for k in range(a_eff.size):
        p, it = steady_pressure(a_eff[k], w_e[k], recs[0 if one else k])
        p_out[k] = p
        it_out[k] = it


@kernel
def _throttle_for_flow_loop(p_i, air_flow, recs, out):
    one = recs.size == 1
    for k in range(p_i.size):
        out[k] = throttle_for_flow(p_i[k], air_flow[k], recs[0 if one else k])


def throttle_for_flow_array(p_i, air_flow, c):
    """:func:`throttle_for_flow` over arrays (``c``: a record, or an array of records broadcast)."""
    shape, (p, f), recs = _flat(p_i, air_flow, recs=c)
    out = np.empty(p.size)
    _throttle_for_flow_loop(p, f, recs, out)
    return out.reshape(shape)


def _flat(*arrays, recs):
    """Broadcast the arguments (and a record array of variants) to one shape; flattened contiguous copies."""
    recs = np.asarray(recs)
    if recs.ndim == 0:
        recs = recs.reshape(1)
    shape = np.broadcast_shapes(*(np.shape(a) for a in arrays), recs.shape if recs.size > 1 else ())
    # writable copies always: a read-only input would be another signature, compiled again
    flat = [np.array(np.broadcast_to(np.asarray(a, dtype=float), shape)).ravel() for a in arrays]
    if recs.size > 1:
        recs = (recs if recs.shape == shape else np.broadcast_to(recs, shape)).ravel()
    if not (recs.flags.writeable and recs.flags.c_contiguous):
        # (a record array of many variants as it is: copying its dozens of fields per variant costs more
        # than the loop itself)
        recs = np.array(recs)
    return shape, flat, recs.view(np.ndarray)


def psi_array(p_r, c):
    """:func:`psi` over arrays (``c``: a record, or an array of records broadcast with ``p_r``)."""
    shape, (x,), recs = _flat(p_r, recs=c)
    out = np.empty(x.size)
    _psi_loop(x, recs, out)
    return out.reshape(shape)


def dpsi_dpr_array(p_r, c):
    """:func:`dpsi_dpr` over arrays."""
    shape, (x,), recs = _flat(p_r, recs=c)
    out = np.empty(x.size)
    _dpsi_loop(x, recs, out)
    return out.reshape(shape)


def steady_pressure_array(a_eff, w_e, c):
    """:func:`steady_pressure` over arrays: (p_i, Newton iterations, -1 where not converged)."""
    shape, (a, w), recs = _flat(a_eff, w_e, recs=c)
    p = np.empty(a.size)
    it = np.empty(a.size, dtype=np.int64)
    _steady_loop(a, w, recs, p, it)
    return p.reshape(shape), it.reshape(shape)


@equation
def throttle_for_pressure_rate(p_i, dp_dt, w_e, c):
    """A_eff that gives the manifold pressure rate ``dp_dt`` at (p_i, w_e): (9) solved for A_eff.

    The cylinders' outflow comes from :func:`manifold_pressure_rate` itself; the throttle flow asked is then
    passed by the throttle command (:func:`command_for_flow`: the area, or beyond A_max a boosted engine's
    boost). Where no flow can raise the pressure (an aspirated engine at p_i >= p_a, Psi = 0) the demand is
    +-inf (0 if none is asked); a negative flow asked gives a negative area (infeasible, flagged).
    """
    rate_0 = manifold_pressure_rate(p_i, 0.0, w_e, c)  # the cylinders' outflow alone
    need = (dp_dt - rate_0) / (c.rt_intake / c.intake_manifold_volume)  # the throttle flow asked
    if need > 0.0 and is_boosted(c):
        return command_for_flow(p_i, need, w_e, c)
    per_area = throttle_flow_per_area(p_i, c)
    if per_area > 0.0:
        return need / per_area
    if need == 0.0:
        return 0.0
    return math.inf if need > 0.0 else -math.inf


@equation
def manifold_rate_dp(p_i, a_eff, w_e, c):
    """d(dp_i/dt)/dp_i of (9) at fixed A_eff and w_e: the manifold's own (stiff) eigenvalue."""
    k = c.rt_intake / c.intake_manifold_volume
    a, p_up = throttle_upstream(a_eff, w_e, c)
    throttle = a * p_up * dpsi_dpr(p_i / p_up, c) / c.sqrt_rt_ambient
    return k * (throttle / p_up - cycles_per_second(w_e, c) * c.air_per_charge * c.air_charge_slope)


@equation
def psi_and_dpsi(p_r, c):
    """(:func:`psi`, :func:`dpsi_dpr`) at p_r with one power (the forward method's Jacobian needs both)."""
    if p_r <= c.critical_ratio:
        return c.psi_choked, 0.0
    if p_r >= 1.0:
        return 0.0, 0.0
    x, f = _psi_squared(p_r, c)
    return (math.sqrt(f) if f > 0.0 else 0.0), _dpsi_from(p_r, x, f, c)


@equation
def manifold_rate_partials(p_i, a_eff, w_e, c):
    """The partial derivatives of (9),(10), :func:`manifold_pressure_rate`, in p_i, in the throttle command
    ``a_eff`` and in w_e: (:func:`manifold_rate_dp`; the throttle's flow per unit area up to A_max (or an
    aspirated engine), beyond it a boosted engine's flow rise with the pressure upstream,
    d(p_up Psi(p_i/p_up))/dp_up = Psi - p_r dPsi/dp_r, times dp_up/du of :func:`throttle_upstream`, 0 at
    full boost; the cylinders' outflow (linear in w_e) and, boosted beyond A_max below full spool, the
    boost's rise with speed). One evaluation of Psi and its derivative."""
    k = c.rt_intake / c.intake_manifold_volume
    a, p_up = throttle_upstream(a_eff, w_e, c)
    p_r = p_i / p_up
    ps, dps = psi_and_dpsi(p_r, c)
    d_p = k * (
        a * dps / c.sqrt_rt_ambient - cycles_per_second(w_e, c) * c.air_per_charge * c.air_charge_slope
    )
    d_w = -k * cylinder_air_flow(p_i, 1.0, c)
    a_max = c.max_throttle_area
    if a_eff <= a_max or not is_boosted(c):
        return d_p, k * p_up * ps / c.sqrt_rt_ambient, d_w
    frac = (a_eff - a_max) / a_max
    per_pressure = a * (ps - p_r * dps) / c.sqrt_rt_ambient
    d_w += k * per_pressure * (frac if frac < 1.0 else 1.0) * boost_available_dw(w_e, c)
    if frac >= 1.0:
        return d_p, 0.0, d_w
    return d_p, k * per_pressure * (boost_available(w_e, c) - c.ambient_pressure) / a_max, d_w


@kernel
def _rate_loop(p_i, a_eff, w_e, recs, out, jac):
    one = recs.size == 1
    for k in range(p_i.size):
        c = recs[0 if one else k]
        out[k] = manifold_pressure_rate(p_i[k], a_eff[k], w_e[k], c)
        jac[k] = manifold_rate_dp(p_i[k], a_eff[k], w_e[k], c)


def manifold_pressure_rate_array(p_i, a_eff, w_e, c):
    """:func:`manifold_pressure_rate` and :func:`manifold_rate_dp` over arrays (records broadcast)."""
    shape, (p, a, w), recs = _flat(p_i, a_eff, w_e, recs=c)
    out = np.empty(p.size)
    jac = np.empty(p.size)
    _rate_loop(p, a, w, recs, out, jac)
    return out.reshape(shape), jac.reshape(shape)


@equation
def accessory_torque_rate(w_e, dw_e, c):
    """d/dt of :func:`accessory_torque` along dw_e/dt (constant power: -P / w_e^2 dw_e/dt above idle)."""
    if w_e > c.idle_speed:
        return -c.accessory_power / (w_e * w_e) * dw_e
    return 0.0
