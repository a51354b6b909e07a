"""The physical powertrain model, equations (1)-(18) of Hofman et al. (2011), as pure vectorised functions.

Every simulation method (forward, backward, inverse) and every map is built from these functions; nothing
here knows about methods, drivers or cycles. Arguments are NumPy arrays or scalars (broadcast together);
``eng``, ``veh`` are :class:`vpsim.params.Engine` / :class:`vpsim.params.Vehicle` (their numeric attributes
may themselves be arrays, which is how batches of design variants are evaluated). SI units throughout.

Symbols follow the paper: p_i intake manifold pressure, w_e engine speed (omega_e), A_eff effective throttle
area, T_cr crank (combustion) torque, T_e flywheel torque, m_ac / m_f air / fuel charge per cycle.
Mean effective pressures convert to torque with V_d / (2 pi n_r) (= V_d / 4pi for n_r = 2, eq. (3)).
"""

from __future__ import annotations

import numpy as np

TWO_PI = 2.0 * np.pi


# --- engine: cylinder air and fuel charge ---------------------------------------------------------------


def displacement(eng) -> float:
    """V_d = z (pi/4) B^2 S."""
    return eng.cylinders * np.pi / 4.0 * eng.bore**2 * eng.stroke


def air_charge(p_i, eng):
    """m_ac = eta_vol p_i V_d / (R T_i) = (s_i p_i - y_i) V_d / (R T_i)   (8)."""
    return (
        (eng.air_charge_slope * p_i - eng.air_charge_intercept)
        * displacement(eng)
        / (eng.gas_constant * eng.intake_temperature)
    )


def fuel_charge(p_i, eng):
    """m_f = m_ac / ((A/F)_s lambda)   (7)."""
    return air_charge(p_i, eng) / (eng.stoich_air_fuel_ratio * eng.lambda_)


def cycles_per_second(w_e, eng):
    """Engine cycles per second, w_e / (2 pi n_r)."""
    return w_e / (TWO_PI * eng.revolutions_per_cycle)


def cylinder_air_flow(p_i, w_e, eng):
    """Air mass flow into the cylinders, w_e m_ac / (2 pi n_r) (the outflow term of (9))."""
    return cycles_per_second(w_e, eng) * air_charge(p_i, eng)


def fuel_flow(p_i, w_e, eng):
    """Fuel mass flow mdot_f = m_f w_e / (2 pi n_r) (kg/s). Negative where p_i < y_i/s_i (no air charge)."""
    return cycles_per_second(w_e, eng) * fuel_charge(p_i, eng)


# --- engine: mean effective pressures and torque ---------------------------------------------------------


def imep(p_i, eng):
    """Gross indicated mean effective pressure IMEP_g = m_f q_hv eta_th / V_d   (4)."""
    return fuel_charge(p_i, eng) * eng.fuel_heating_value * eng.thermal_efficiency / displacement(eng)


def pmep(p_i, eng):
    """Pumping mean effective pressure PMEP = p_e - p_i   (6)."""
    return eng.exhaust_pressure - p_i


def mean_piston_speed(w_e, eng):
    """c_m = S w_e / pi (m/s)."""
    return eng.stroke * w_e / np.pi


def friction_factor(eng):
    """k_f = xi_aux (0.075 / B)^0.5, the bore scaling of Soltic's friction law (5)."""
    return eng.friction_coefficient * np.sqrt(0.075 / eng.bore)


def _speed_friction(w_e, eng):
    """The speed-dependent part of FMEP: k_f (0.464 + 0.0072 c_m^1.8) pi_bl 1e5   (5)."""
    c_m = np.abs(mean_piston_speed(w_e, eng))
    return friction_factor(eng) * (0.464 + 0.0072 * c_m**1.8) * eng.boost_layout * 1e5


def bmep_from_pressure(p_i, w_e, eng):
    """BMEP solved from (2)-(6); FMEP contains BMEP, hence the division by (1 + 0.0215 k_f)."""
    k_f = friction_factor(eng)
    return (imep(p_i, eng) - _speed_friction(w_e, eng) - pmep(p_i, eng)) / (1.0 + 0.0215 * k_f)


def fmep(p_i, w_e, eng):
    """Friction mean effective pressure FMEP (5), Soltic's law with the auxiliary factor xi_aux."""
    return _speed_friction(w_e, eng) + friction_factor(eng) * 0.0215 * bmep_from_pressure(p_i, w_e, eng)


def mep_to_torque(mep, eng):
    """Torque of a mean effective pressure: T = MEP V_d / (2 pi n_r)   (3)."""
    return mep * displacement(eng) / (TWO_PI * eng.revolutions_per_cycle)


def torque_to_mep(torque, eng):
    return torque * (TWO_PI * eng.revolutions_per_cycle) / displacement(eng)


def crank_torque(p_i, w_e, eng):
    """T_cr = BMEP V_d / 4pi   (2),(3)."""
    return mep_to_torque(bmep_from_pressure(p_i, w_e, eng), eng)


def intake_pressure_for_torque(t_cr, w_e, eng):
    """p_i with delta(p_i) = 0 for imposed (T_cr, w_e): the BQM's inversion of (2),(7),(8).

    delta(p_i) = (s_i p_i - y_i) Q - k_f[(0.464 + 0.0072 c_m^1.8) pi_bl 1e5 + 0.0215 BMEP] - p_e + p_i - BMEP
    is linear in p_i, so the root is closed-form (the paper iterates; both agree).
    Q = q_hv eta_th / ((A/F)_s lambda R T_i).
    """
    q = _q(eng)
    k_f = friction_factor(eng)
    bmep = torque_to_mep(t_cr, eng)
    rhs = (
        bmep * (1.0 + 0.0215 * k_f)
        + _speed_friction(w_e, eng)
        + eng.exhaust_pressure
        + eng.air_charge_intercept * q
    )
    return rhs / (eng.air_charge_slope * q + 1.0)


def _q(eng):
    return (
        eng.fuel_heating_value
        * eng.thermal_efficiency
        / (eng.stoich_air_fuel_ratio * eng.lambda_ * eng.gas_constant * eng.intake_temperature)
    )


# --- engine: throttle and intake manifold -----------------------------------------------------------------


def critical_pressure_ratio(gamma):
    """p_r* = (2/(gamma+1))^(gamma/(gamma-1))   (11)."""
    return (2.0 / (gamma + 1.0)) ** (gamma / (gamma - 1.0))


def psi(p_r, gamma):
    """Flow function Psi(p_r): choked (12) for p_r <= p_r*, subcritical (13) above; 0 for p_r >= 1.

    Reverse flow (p_r > 1) cannot occur in a naturally aspirated engine with these equations; the flow is
    taken as zero there, which is also what the manifold equation needs at w_e = 0 (p_i settles at p_a).
    """
    p_r = np.asarray(p_r, dtype=float)
    crit = critical_pressure_ratio(gamma)
    choked = np.sqrt(gamma * (2.0 / (gamma + 1.0)) ** ((gamma + 1.0) / (gamma - 1.0)))
    pr = np.clip(p_r, crit, 1.0)
    sub = np.sqrt(
        np.maximum(2.0 * gamma / (gamma - 1.0) * (pr ** (2.0 / gamma) - pr ** ((gamma + 1.0) / gamma)), 0.0)
    )
    return np.where(p_r <= crit, choked, sub)


def dpsi_dpr(p_r, gamma):
    """dPsi/dp_r (0 in the choked region; -inf as p_r -> 1)."""
    p_r = np.asarray(p_r, dtype=float)
    crit = critical_pressure_ratio(gamma)
    pr = np.clip(p_r, crit, 1.0 - 1e-15)
    f = 2.0 * gamma / (gamma - 1.0) * (pr ** (2.0 / gamma) - pr ** ((gamma + 1.0) / gamma))
    df = (
        2.0
        * gamma
        / (gamma - 1.0)
        * ((2.0 / gamma) * pr ** (2.0 / gamma - 1.0) - ((gamma + 1.0) / gamma) * pr ** (1.0 / gamma))
    )
    return np.where(p_r <= crit, 0.0, df / (2.0 * np.sqrt(np.maximum(f, 1e-300))))


def throttle_mass_flow(a_eff, p_i, eng):
    """mdot_at = p_a A_eff Psi(p_i/p_a) / sqrt(R T_a)   (10)."""
    p_r = p_i / eng.ambient_pressure
    return (
        eng.ambient_pressure
        * a_eff
        * psi(p_r, eng.specific_heat_ratio)
        / np.sqrt(eng.gas_constant * eng.ambient_temperature)
    )


def manifold_pressure_rate(p_i, a_eff, w_e, eng):
    """dp_i/dt = (R T_i / V_i) [mdot_at - w_e m_ac / (2 pi n_r)]   (9)."""
    return (eng.gas_constant * eng.intake_temperature / eng.intake_manifold_volume) * (
        throttle_mass_flow(a_eff, p_i, eng) - cylinder_air_flow(p_i, w_e, eng)
    )


# --- driveline and vehicle ----------------------------------------------------------------------------------


def engine_speed(v, ratio, veh):
    """w_e = i w_w = i v / r   (14),(17)."""
    return ratio * v / veh.wheel_radius


def aero_force(v, veh):
    """1/2 c_d rho A v^2 (acts against the motion)."""
    return 0.5 * veh.drag_coefficient * veh.air_density * veh.frontal_area * v * np.abs(v)


def rolling_force(veh):
    """m g c_r (18)."""
    return veh.mass * veh.gravity * veh.rolling_resistance


def road_load(v, veh):
    """Resistance force 1/2 c_d rho A v^2 + m g c_r of (18), for v >= 0."""
    return aero_force(v, veh) + rolling_force(veh)


def equivalent_mass(ratio, veh, eng, eta):
    """m_eq = m + J_e i^2 eta_tm / r^2: the engine inertia seen at the wheels through (1),(14)-(17)."""
    return veh.mass + eng.inertia * ratio**2 * eta / veh.wheel_radius**2


def wheel_to_engine_torque(t_w, ratio, eta):
    """T_e = T_w / (i eta_tm)   (15). The paper's constant efficiency applies in both directions."""
    return t_w / (ratio * eta)


def statespace_coefficients(ratio, veh, eng, eta):
    """Coefficients c1..c7 of the affine state-space form (21) for total ratio i (arrays broadcast).

    dx1/dt = c1 x1^2 + c2 x1^1.8 + c3 x2 + c4;  dx2/dt = c5 x1 + c6 x1 x2 + c7 Psi(x2/p_a) u,
    with x1 = v, x2 = p_i, u = A_eff. Valid for v >= 0.
    """
    r = veh.wheel_radius
    vd = displacement(eng)
    k_f = friction_factor(eng)
    m_eq = equivalent_mass(ratio, veh, eng, eta)
    n_r = eng.revolutions_per_cycle
    g = (ratio * eta / r) / m_eq * (vd / (TWO_PI * n_r)) / (1.0 + 0.0215 * k_f)
    q = _q(eng)
    c1 = -0.5 * veh.drag_coefficient * veh.air_density * veh.frontal_area / m_eq
    c2 = -g * 0.0072 * (eng.stroke * ratio / (np.pi * r)) ** 1.8 * eng.boost_layout * 1e5 * k_f
    c3 = g * (eng.air_charge_slope * q + 1.0)
    c4 = -g * (eng.air_charge_intercept * q + 0.464 * eng.boost_layout * 1e5 * k_f + eng.exhaust_pressure) - (
        veh.mass * veh.gravity * veh.rolling_resistance / m_eq
    )
    kv = ratio * vd / (TWO_PI * n_r * r * eng.intake_manifold_volume)  # R T_i cancels in (8)x(9)
    c5 = kv * eng.air_charge_intercept
    c6 = -kv * eng.air_charge_slope
    c7 = (
        eng.gas_constant
        * eng.intake_temperature
        * eng.ambient_pressure
        / (eng.intake_manifold_volume * np.sqrt(eng.gas_constant * eng.ambient_temperature))
    )
    return c1, c2, c3, c4, c5, c6, c7


# --- fuel ------------------------------------------------------------------------------------------


def fuel_with_idle_floor(mdot_f, idle_fuel_flow):
    """The paper's fuel bookkeeping: only traction matters; braking and idling burn the idle flow.

    Total fuel = integral of max(mdot_f, mdot_idle) dt (section 5).
    """
    return np.maximum(mdot_f, idle_fuel_flow)


def litres_per_100km(fuel_kg, distance_m, fuel_density_kg_per_l):
    """Fuel consumption in L/100 km."""
    if distance_m <= 0:
        return float("nan")
    return fuel_kg / fuel_density_kg_per_l / (distance_m / 1e5)
