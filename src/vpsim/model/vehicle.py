"""Driveline and vehicle, equations (1) and (14)-(18) of Hofman et al. (2011), and the affine form (21);
the realistic car's torque converter.

Written once, as :mod:`vpsim.model.engine` is: plain functions of scalars (or arrays) and the parameter
record ``c``, inlined by every compiled kernel. SI units; ``ratio`` is the total ratio i (gearbox x final
drive) of the engaged gear.
"""

from __future__ import annotations

import math

import numpy as np

from . import engine as en
from .engine import equation


def coastdown(c):
    """Whether the road load is given as coast-down coefficients F = A + B v + C v^2 (any of them set)."""
    return (c.road_load_a != 0.0) | (c.road_load_b != 0.0) | (c.road_load_c != 0.0)


def aero_coefficient(c):
    """1/2 c_d rho A_f of the aerodynamic drag in (18); with a coast-down road load its C.
    (Evaluated once per parameter set, by vpsim.model.record.)"""
    return np.where(coastdown(c), c.road_load_c, 0.5 * c.drag_coefficient * c.air_density * c.frontal_area)


def rolling_force_moving(c):
    """m g c_r of (18), while the vehicle moves; with a coast-down road load its A."""
    return np.where(coastdown(c), c.road_load_a, c.mass * c.gravity * c.rolling_resistance)


@equation
def aero_force(v, c):
    """1/2 c_d rho A v |v| (acts against the motion)."""
    return c.aero_coefficient * v * abs(v)


@equation
def rolling_force_in_motion(v, c):
    """m g c_r (with a coast-down road load A + B v): the rolling resistance of a car that moves or sets off
    (a launch meets it from the first instant)."""
    return c.rolling_force + c.road_load_b * v


@equation
def rolling_force(v, c):
    """:func:`rolling_force_in_motion` while moving (v > 0); at rest rolling resistance is static friction
    and pushes nothing."""
    return rolling_force_in_motion(v, c) * (v > 0.0)


@equation
def road_load(v, c):
    """Resistance force of (18): aerodynamic drag plus rolling resistance."""
    return aero_force(v, c) + rolling_force(v, c)


@equation
def wheel_force(v, a, c):
    """Force at the wheels that speed v and acceleration a ask for: m a + road load   (18)."""
    return c.mass * a + road_load(v, c)


@equation
def total_ratio(gearbox_ratio, final_drive):
    """i = i_g i_f: the ratio from the engine to the wheels, gearbox times final drive   (14)."""
    return gearbox_ratio * final_drive


@equation
def engine_speed(v, ratio, c):
    """w_e = i w_w = i v / r   (14),(17)."""
    return ratio * v / c.wheel_radius


@equation
def equivalent_mass(ratio, c):
    """m_eq = m + J_e i^2 eta_tm / r^2: the engine inertia seen at the wheels through (1),(14)-(17)."""
    return c.mass + c.inertia * ratio**2 * c.efficiency / c.wheel_radius**2


@equation
def wheel_to_engine_torque(f_wheel, ratio, c):
    """T_e = F_w r / (i eta_tm)   (15),(16). The paper's constant efficiency applies in both directions."""
    return f_wheel * c.wheel_radius / (ratio * c.efficiency)


@equation
def engine_to_wheel_force(t_e, ratio, c):
    """F_w = T_e i eta_tm / r   (15),(16)."""
    return t_e * ratio * c.efficiency / c.wheel_radius


@equation
def inertia_torque(dw_e, c):
    """J_e dw_e/dt: the crank torque that accelerates the engine's own inertia   (1)."""
    return c.inertia * dw_e


@equation
def engine_torque(t_cr, dw_e, c):
    """T_e = T_cr - J_e dw_e/dt: the torque the engine passes on   (1)."""
    return t_cr - inertia_torque(dw_e, c)


@equation
def crank_torque_demand(f_wheel, ratio, dw_e, c):
    """T_cr = T_e + J_e dw_e/dt with T_e from the wheel force   (1),(15),(16)."""
    return wheel_to_engine_torque(f_wheel, ratio, c) + inertia_torque(dw_e, c)


@equation
def acceleration_shortfall(t_short, ratio, c):
    """The acceleration a crank-torque shortfall ``t_short`` costs the stiff driveline: F_w / m_eq of the
    missing torque   (1),(14)-(18)."""
    return engine_to_wheel_force(t_short, ratio, c) / equivalent_mass(ratio, c)


@equation
def vehicle_acceleration(t_cr, ratio, v, brake, c):
    """dv/dt of the stiff driveline: (i eta_tm / r) T_cr - road load - brake, over m_eq   (1),(14)-(18)."""
    return (engine_to_wheel_force(t_cr, ratio, c) - road_load(v, c) - brake) / equivalent_mass(ratio, c)


@equation
def statespace_coefficients(ratio, c):
    """Coefficients c1..c7 of the affine state-space form (21) for total ratio i.

    dx1/dt = c1 x1^2 + c2 x1^1.8 + c3 x2 + c4;  dx2/dt = c5 x1 + c6 x1 x2 + c7 Psi(x2/p_a) u,
    with x1 = v, x2 = p_i, u = A_eff; valid for v > 0 (rolling resistance in c4). Obtained by inserting
    (2)-(10) into (1),(14)-(18).
    """
    r = c.wheel_radius
    m_eq = equivalent_mass(ratio, c)
    g = (ratio * c.efficiency / r) / m_eq  # wheel acceleration per unit crank torque
    t_0 = en.crank_torque(0.0, 0.0, c)  # T_cr = t_p p_i + t_0 - (friction rise with speed)
    c1 = -c.aero_coefficient / m_eq
    c2 = g * (en.crank_torque(0.0, ratio / r, c) - t_0)  # v = 1 m/s: the c_m^1.8 friction term of (5)
    c3 = g * en.torque_per_pressure(0.0, c)
    c4 = g * t_0 - c.rolling_force / m_eq
    kv = ratio * c.displacement / (en.TWO_PI * c.revolutions_per_cycle * r * c.intake_manifold_volume)
    c5 = kv * c.air_charge_intercept
    c6 = -kv * c.air_charge_slope
    c7 = c.rt_intake * c.ambient_pressure / (c.intake_manifold_volume * c.sqrt_rt_ambient)
    return c1, c2, c3, c4, c5, c6, c7


@equation
def rolling_coefficients(ratio, c):
    """The rolling resistance's parts of (21) per equivalent mass: its constant part (in c4 while moving; at
    rest static friction), and minus the coast-down road load's linear term B, which the paper's affine form
    does not have: (m g c_r / m_eq, -B / m_eq)."""
    m_eq = equivalent_mass(ratio, c)
    return c.rolling_force / m_eq, -c.road_load_b / m_eq


@equation
def acceleration(f_drive, v, brake, mass, c):
    """dv/dt from the driving force at the wheels, road load (18) and brakes, for the mass ``mass`` moved.

    At rest (v <= 0) rolling resistance and brakes are static friction: they hold the car up to their size
    and never push it backwards.
    """
    if v > 0.0:
        return (f_drive - road_load(v, c) - brake) / mass
    hold = c.rolling_force + brake
    return (f_drive - hold) / mass if f_drive > hold else 0.0


@equation
def aero_force_dv(v, c):
    """d/dv of :func:`aero_force`: 2 (1/2 c_d rho A_f) |v|."""
    return 2.0 * c.aero_coefficient * abs(v)


@equation
def rolling_force_dv(v, c):
    """d/dv of :func:`rolling_force` while moving: B of a coast-down road load (0 otherwise); its step at
    rest is left out (static friction)."""
    return c.road_load_b if v > 0.0 else 0.0


@equation
def road_load_dv(v, c):
    """d/dv of :func:`road_load` while moving: :func:`aero_force_dv` + :func:`rolling_force_dv`."""
    return aero_force_dv(v, c) + rolling_force_dv(v, c)


@equation
def acceleration_dforce(f_drive, v, brake, mass, c):
    """d/dF_drive of :func:`acceleration` (and minus its derivative in the brake force): 1 / mass while
    moving or pushed off, 0 while static friction (rolling resistance and brakes) holds the car at rest."""
    if v > 0.0 or f_drive > c.rolling_force + brake:
        return 1.0 / mass
    return 0.0


@equation
def wheel_force_rate(v, a, jerk, c):
    """d/dt of the wheel force (18) along a trajectory (v, dv/dt, d2v/dt2): m jerk + d(road load)/dv a."""
    return c.mass * jerk + road_load_dv(v, c) * a


# --- torque converter (realistic mode) ------------------------------------------------------------------
# The quasi-static converter of Kotwicki (1982, SAE 820393) and Guzzella & Sciarretta (Vehicle Propulsion
# Systems, section on torque converters): over the speed ratio nu = w_turbine / w_pump, the pump torque is
# T_p = phi(nu) w_p^2 (phi = 1 / K^2, K the capacity factor) and the turbine torque T_t = mu(nu) T_p. The
# curves here are the typical shape of a passenger-car converter: mu falls linearly from the stall torque
# ratio at nu = 0 to 1 at the coupling point nu_c and is 1 above (fluid coupling); phi is its stall value up
# to nu_c and falls linearly to 0 at nu = 1 (no torque without slip).


@equation
def converter_torque_ratio(nu, c):
    """mu(nu) = T_turbine / T_pump: the stall ratio at nu = 0, linearly to 1 at the coupling point, then 1."""
    nc = c.converter_coupling_speed_ratio
    if nu >= nc:
        return 1.0
    return c.converter_stall_torque_ratio + (1.0 - c.converter_stall_torque_ratio) * nu / nc


@equation
def converter_capacity(nu, c):
    """phi(nu) = T_pump / w_pump^2 = 1 / K(nu)^2: 1 / K_stall^2 up to the coupling point, then linearly to 0
    at nu = 1 and on below zero beyond it (the turbine overrunning the pump: the coupling passes torque back
    to the engine, which only the forward method, with the engine speed a state, reaches)."""
    k = 1.0 / (c.converter_capacity_factor * c.converter_capacity_factor)
    nc = c.converter_coupling_speed_ratio
    if nu <= nc:
        return k
    return k * (1.0 - nu) / (1.0 - nc)


@equation
def converter_pump_torque(w_p, w_t, c):
    """T_p = phi(nu) w_p^2 at pump speed ``w_p`` > 0 and turbine speed ``w_t`` (nu = w_t / w_p)."""
    return converter_capacity(w_t / w_p, c) * w_p * w_p


@equation
def converter_pump_torque_dw(w_p, w_t, c):
    """d/dw_p of :func:`converter_pump_torque` at fixed turbine speed: 2 w_p / K^2 up to the coupling
    point; above it T_p = (w_p^2 - w_t w_p) / (K^2 (1 - nu_c)), so (2 w_p - w_t) / (K^2 (1 - nu_c))."""
    k = 1.0 / (c.converter_capacity_factor * c.converter_capacity_factor)
    nc = c.converter_coupling_speed_ratio
    nu = w_t / w_p
    if nu <= nc:
        return 2.0 * k * w_p
    return k * (2.0 * w_p - w_t) / (1.0 - nc)


@equation
def converter_speed_ratio(t_t, w_t, c):
    """The speed ratio nu at which the converter passes turbine torque ``t_t`` > 0 at turbine speed ``w_t``
    > 0: the root of t_t = mu(nu) phi(nu) (w_t / nu)^2, unique since mu phi / nu^2 falls with nu; each
    branch is a quadratic in nu, solved in closed form. The slip 1 - nu is positive."""
    nc = c.converter_coupling_speed_ratio
    s = w_t * w_t / (c.converter_capacity_factor * c.converter_capacity_factor)
    # coupling branch: t_t nu^2 = s (1 - nu) / (1 - nc), i.e. q nu^2 + nu - 1 = 0
    q = t_t * (1.0 - nc) / s
    nu = 2.0 / (1.0 + math.sqrt(1.0 + 4.0 * q))
    if nu >= nc:
        return nu
    # multiplication branch: t_t nu^2 = s (mu_s + (1 - mu_s) nu / nc)
    mu_s = c.converter_stall_torque_ratio
    b = s * (1.0 - mu_s) / nc
    return (b + math.sqrt(b * b + 4.0 * t_t * s * mu_s)) / (2.0 * t_t)


@equation
def converter_pump_point(w_t, dw_t, t_t, c):
    """The unlocked converter seen from its pump side, for a pump that can turn at any speed (a P2 hybrid's
    machine drives it; the engine joins it at or above idle): with the turbine (gearbox input) at speed
    ``w_t``, acceleration ``dw_t``, asked for torque ``t_t``, returns (pump speed w_t / nu, its acceleration
    dw_t / nu, pump torque t_t / mu(nu), torque ratio mu(nu), traction passed 1 or 0). With traction
    (``t_t`` > 0, ``w_t`` > 0) nu is :func:`converter_speed_ratio`'s root; without (braking, coasting, at
    rest) the unlocked converter passes no torque: the pump turns with the turbine, unloaded, and the
    friction brakes take a braking demand (the quasi-static converter has no overrun branch to regenerate
    through)."""
    if t_t <= 0.0 or w_t <= 0.0:
        return w_t, dw_t, 0.0, 1.0, 0.0
    nu = converter_speed_ratio(t_t, w_t, c)
    mu = converter_torque_ratio(nu, c)
    return w_t / nu, dw_t / nu, t_t / mu, mu, 1.0


@equation
def converter_engine_point(w_t, dw_t, t_t, c):
    """The unlocked converter with traction (``t_t`` > 0) driven by an engine that turns at idle speed or
    faster (the engine car, a mild hybrid's crank with its machine): the pump at w_t / nu (nu the root of
    :func:`converter_speed_ratio`; at a standing turbine the stall, T_t = mu_s phi_s w_p^2) with torque
    T_t / mu(nu). Where that speed is below idle the engine idles and the converter, at nu = w_t / idle,
    passes mu(nu) phi(nu) idle^2, more than asked (creep: the brakes hold the rest). Returns (w_p, dw_p, T_p,
    mu(nu), held at idle 1 or 0); the pump's acceleration is the turbine's over nu (quasi-static)."""
    if w_t > 0.0:
        nu = converter_speed_ratio(t_t, w_t, c)
        w_p = w_t / nu
    else:  # stall
        nu = 0.0
        w_p = math.sqrt(t_t / (converter_torque_ratio(0.0, c) * converter_capacity(0.0, c)))
    if w_p >= c.idle_speed:
        mu = converter_torque_ratio(nu, c)
        return w_p, (dw_t / nu if nu > 0.0 else 0.0), t_t / mu, mu, 0.0
    nu = w_t / c.idle_speed
    t_p = converter_capacity(nu, c) * c.idle_speed * c.idle_speed
    return c.idle_speed, 0.0, t_p, converter_torque_ratio(nu, c), 1.0


@equation
def converter_locked(gear, v, c):
    """No converter, or its lock-up clutch closed: in gear ``gear`` (1-based) >= ``lockup_min_gear`` at or
    above ``lockup_min_speed``."""
    return c.converter_capacity_factor <= 0.0 or (gear >= c.lockup_min_gear and v >= c.lockup_min_speed)
