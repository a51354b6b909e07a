"""Driveline and vehicle, equations (1) and (14)-(18) of Hofman et al. (2011), and the affine form (21).

Written once, as :mod:`vpsim.model.engine` is: plain functions of scalars (or arrays) and the parameter
record ``c``, inlined by every compiled kernel. SI units; ``ratio`` is the total ratio i (gearbox x final
drive) of the engaged gear.
"""

from __future__ import annotations

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
def rolling_force(v, c):
    """m g c_r while moving (v > 0) (with a coast-down road load A + B v); at rest rolling resistance is
    static friction and pushes nothing."""
    return (c.rolling_force + c.road_load_b * v) * (v > 0.0)


@equation
def road_load(v, c):
    """Resistance force of (18): aerodynamic drag plus rolling resistance."""
    return aero_force(v, c) + rolling_force(v, c)


@equation
def wheel_force(v, a, c):
    """Force at the wheels that speed v and acceleration a ask for: m a + road load   (18)."""
    return c.mass * a + road_load(v, c)


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
def crank_torque_demand(f_wheel, ratio, dw_e, c):
    """T_cr = T_e + J_e dw_e/dt with T_e from the wheel force   (1),(15),(16)."""
    return wheel_to_engine_torque(f_wheel, ratio, c) + c.inertia * dw_e


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
def wheel_force_rate(v, a, jerk, c):
    """d/dt of the wheel force (18) along a trajectory (v, dv/dt, d2v/dt2): m jerk + d(drag)/dv a."""
    return c.mass * jerk + 2.0 * c.aero_coefficient * abs(v) * a
