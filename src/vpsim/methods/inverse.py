"""Inverse dynamic method (IDM), paper section 4: stable inversion of the affine model (21).

The driver is the smoothing (34)-(35) (:class:`vpsim.drivers.smoothing.SmoothingDriver`, half-width a = 5 s
for driver 1, 1 s for driver 2), which gives the desired speed y_d = v_d(t) and its exact first and second
derivatives. With x1 = v, x2 = p_i, u = A_eff the relative degree is 2, equal to the order, so there are no
zero dynamics and the inversion is algebraic, point by point:

    x2   = (dy_d - c1 y_d^2 - c2 y_d^1.8 - c4) / c3                                        (33)
    L_f^2 h = (2 c1 x1 + 1.8 c2 x1^0.8) dy_d + c3 (c5 x1 + c6 x1 x2)                      (31)
    u_d  = (d2y_d - L_f^2 h) / (c3 c7 Psi(x2 / p_a))                                        (30),(32)

(in (31) the bracket c1 x1^2 + c2 x1^1.8 + c3 x2 + c4 equals dy_d by (33)). The coefficients c1..c7 depend
on the engaged ratio (:func:`vpsim.physics.statespace_coefficients`); as in the backward method, rolling
resistance acts only while the vehicle moves (v_d > 0).

Grid and fuel. The paper integrates the fuel with ode45, the step capped at 1 s. Here the inversion is
evaluated at every cycle sample (plus, at each gear change, the instant once more with the old gear, since
x2 jumps there) and the fuel, distance and energy terms are integrated by the trapezoidal rule: against a
0.05 s Simpson reference the fuel differs by under 0.05 % on NEDC and FTP-75 (a test keeps it under 0.1 %).
``steps`` is the number of evaluation points. The cost counts the smoothing, which on a uniformly sampled
cycle is three discrete convolutions (:func:`smoothed_on_samples`). The grid, the smoothing on it, the
inversion and the bookkeeping are compiled (``run(..., compiled=False)``: the NumPy reference).

The compiled core borrows the forward method's scalar engine functions; numba's cache of this module is not
invalidated when forward.py changes (a test compares the core with its Python code, which catches that).

Infeasible throttle. Where u_d leaves [A_min, A_max] the demanded trajectory cannot be produced by a real
throttle. This is reported (``TraceMiss.infeasible_throttle_s``, with the time below A_min and above A_max in
``details``), never hidden:

* ``paper`` mode (no clutch, no brakes): the inversion is kept as it is, the method being the mathematical
  inverse. Below A_min (deceleration beyond engine braking) the required p_i is below what the closed
  throttle gives, the fuel flow computed from it is below the idle flow and the idle floor applies, as it
  would with the closed throttle; so the fuel is unaffected. At standstill w_e = 0, nothing leaves the
  manifold and u_d = 0: those seconds are counted apart (``details["standstill_s"]``), not as infeasible.
  The series' ``throttle_area_m2`` is u_d clipped to [A_min, A_max]; ``throttle_demand_m2`` is u_d itself.
* ``extended`` mode: where the demanded crank torque is below the closed-throttle line (the FQM at A_min),
  the friction brakes take the difference and the engine runs on that line with the throttle closed and
  the manifold at its steady state (quasi-static on those stretches: the manifold time constant, under
  0.1 s, is short against the 1 s grid). Below the idle speed the clutch slips with the engine held at idle
  (it passes the torque the vehicle needs) or opens when no traction is needed (engine idling, brakes).

Demand beyond full load (u_d > A_max, or x2 >= p_a where Psi = 0) is reported the same way; the fuel is then
that of the demanded trajectory.
"""

from __future__ import annotations

import functools
import math
import time

import numpy as np
from numba import njit

from .. import physics as ph
from ..drivers.smoothing import SmoothingDriver, bump_kernel, bump_kernel_cdf, bump_kernel_moment
from ..errors import VpsimError
from ..gears import GearSchedule, default_schedule
from ..result import EnergyBalance, Result, TraceMiss
from .backward import IDLE_SPEED
from .forward import _INV_AFR, _INV_PA, _KF, _KMEP, _PE, _QHV, constants, engine_scalar, psi_scalar

BAND_KMH = 2.0  # the regulation's speed tolerance, as for the forward method
_MOVING = 1e-9  # m/s: v_d above this counts as moving (v_d is exactly 0 only where the cycle rests +-a)


def smoothed_on_samples(time_s, speed_mps, a: float):
    """(v_d, dv_d/dt, d2v_d/dt2) of the smoothing driver at the samples of a uniformly sampled cycle.

    The same convolution as :meth:`SmoothingDriver.evaluate <vpsim.drivers.smoothing.SmoothingDriver>`,
    with the same kernel functions, organised for this grid: with v_c(tau) = v_0 + sum_k dm_k (tau - t_k)_+
    (dm_k the slope change at sample k, the ends held), the smoothed speed at a sample is
    v_c(t_i) + sum_k dm_k C((i - k) dt), C(x) = x G(x) - M(x) - x_+ being zero for |x| >= a, so each of the
    three outputs is one discrete convolution of dm with 2a/dt + 1 kernel samples (G: the kernel's
    cumulative, M: its first moment). Agrees with ``SmoothingDriver.evaluate`` to rounding (tested).
    """
    t = np.asarray(time_s, float)
    v = np.asarray(speed_mps, float)
    dt = float(t[1] - t[0])
    m = np.concatenate([[0.0], np.diff(v) / dt, [0.0]])  # slopes before/after each sample, ends held
    dm = np.diff(m)
    c_v, c_dv, c_ddv = _sample_taps(a, dt)
    k = (c_v.size - 1) // 2  # the taps are centred: sample i takes the full convolution's entry i + k
    n = v.size
    v_d = v + np.convolve(dm, c_v)[k : k + n]
    dv_d = 0.5 * (m[:-1] + m[1:]) + np.convolve(dm, c_dv)[k : k + n]
    ddv_d = np.convolve(dm, c_ddv)[k : k + n]
    return v_d, dv_d, ddv_d


@functools.lru_cache(maxsize=16)
def _sample_taps(a: float, dt: float):
    """Kernel samples at offsets -K dt .. K dt for :func:`smoothed_on_samples` (cached per a, dt)."""
    k = int(np.ceil(a / dt))
    x = np.arange(-k, k + 1) * dt
    inside = np.abs(x) < a
    ramp = np.maximum(x, 0.0)
    cdf = bump_kernel_cdf(x, a)
    c_v = np.where(inside, x * cdf - bump_kernel_moment(x, a) - ramp, 0.0)
    step = np.where(x > 0.0, 1.0, np.where(x < 0.0, 0.0, 0.5))
    c_dv = np.where(inside, cdf - step, 0.0)
    c_ddv = bump_kernel(x, a)
    for arr in (c_v, c_dv, c_ddv):
        arr.flags.writeable = False
    return c_v, c_dv, c_ddv


@njit(cache=True)
def _is_uniform_compiled(t):
    """:func:`_is_uniform` in one pass."""
    if t.size < 2:
        return False
    d0 = t[1] - t[0]
    for i in range(1, t.size - 1):
        if not (abs((t[i + 1] - t[i]) - d0) <= 1e-9 * d0):
            return False
    return True


@njit(cache=True)
def _grid_and_smoothing(t_s, v_s, sched_t, sched_g, c_v, c_dv, c_ddv):
    """:func:`evaluation_grid` and :func:`smoothed_on_samples` (indexed by the grid's samples) in one
    compiled pass, for a uniformly sampled cycle.

    Returns two arrays (few objects to hand back: this is part of a call's fixed cost), ``F`` (6 x points):
    t, v_d, dv_d/dt, d2v_d/dt2, the cycle speed at the points, the interval lengths (first n - 1 entries);
    ``I`` (5 x points): gear, left, right (first n - 1), sample, the gear at each cycle sample
    (``GearSchedule.on_cycle``, first n); t, gear, left, right and sample as :func:`evaluation_grid`
    gives them.
    """
    n_s = t_s.size
    n = n_s - 1
    # gear at each sample: right-continuous lookup in the schedule (searchsorted right - 1, clipped)
    g_s = np.empty(n_s, dtype=sched_g.dtype)
    j = 0
    m_sched = sched_t.size
    for i in range(n_s):
        while j < m_sched and sched_t[j] <= t_s[i]:
            j += 1
        idx = j - 1
        if idx < 0:
            idx = 0
        elif idx > m_sched - 1:
            idx = m_sched - 1
        g_s[i] = sched_g[idx]
    n_ends = 0
    for e in range(1, n):
        if g_s[e] != g_s[e - 1]:
            n_ends += 1
    n_pts = n_s + n_ends
    F = np.zeros((6, n_pts))
    I = np.zeros((5, n_pts), dtype=np.int64)
    t, v, dv, ddv, v_c, dt = F[0], F[1], F[2], F[3], F[4], F[5]
    gear, left, right, sample = I[0], I[1], I[2], I[3]
    I[4, :n_s] = g_s
    for i in range(n):
        left[i] = i
        right[i] = i + 1
        dt[i] = t_s[i + 1] - t_s[i]
    for i in range(n_s):
        t[i] = t_s[i]
        sample[i] = i
        gear[i] = g_s[i] if i < n else g_s[n - 1]
    q = n_s
    for e in range(1, n):
        if g_s[e] != g_s[e - 1]:
            t[q] = t_s[e]
            gear[q] = g_s[e - 1]
            sample[q] = e
            right[e - 1] = q
            q += 1
    # smoothing on the samples: slope changes dm convolved with the centred taps
    step = t_s[1] - t_s[0]
    m = np.empty(n_s + 1)
    m[0] = 0.0
    m[n_s] = 0.0
    for i in range(1, n_s):
        m[i] = (v_s[i] - v_s[i - 1]) / step
    k = (c_v.size - 1) // 2
    for i in range(n_s):  # the points 0..n_s - 1 are the samples
        lo = i - k if i - k > 0 else 0
        hi = i + k if i + k < n_s - 1 else n_s - 1
        sv = 0.0
        sdv = 0.0
        sddv = 0.0
        for r in range(lo, hi + 1):
            d = m[r + 1] - m[r]
            c = k + i - r
            sv += d * c_v[c]
            sdv += d * c_dv[c]
            sddv += d * c_ddv[c]
        v[i] = v_s[i] + sv
        dv[i] = 0.5 * (m[i] + m[i + 1]) + sdv
        ddv[i] = sddv
        v_c[i] = v_s[i]
    for p in range(n_s, n_pts):  # the gear changes' second points
        s = sample[p]
        v[p] = v[s]
        dv[p] = dv[s]
        ddv[p] = ddv[s]
        v_c[p] = v_s[s]
    return F, I


def _is_uniform(t) -> bool:
    d = np.diff(t)
    return bool(d.size >= 1 and np.all(np.abs(d - d[0]) <= 1e-9 * d[0]))


def evaluation_grid(cycle, schedule: GearSchedule):
    """Times and gears of the IDM grid, and the trapezoid bookkeeping.

    Returns (t, gear, left, right, sample): the evaluation times (the cycle samples, then each gear-change
    instant again with the gear engaged before it), the gear (1-based) at each, the indices of each
    interval's left and right end (the right end evaluated with the interval's own gear, since x2 jumps at a
    change), and the cycle sample each point sits on.
    """
    t_s = cycle.time_s
    n = t_s.size - 1
    g_int = schedule.on_cycle(cycle)[:-1]  # gear engaged on interval k
    ends = np.flatnonzero(g_int[1:] != g_int[:-1]) + 1  # samples where the gear changes
    t = np.concatenate([t_s, t_s[ends]])
    g = np.concatenate([g_int, g_int[-1:], g_int[ends - 1]])
    left = np.arange(n)
    right = np.arange(1, n + 1)
    right[ends - 1] = n + 1 + np.arange(ends.size)
    return t, g, left, right, np.concatenate([np.arange(n + 1), ends])


def invert(v, dv, ddv, gear, params, mode: str = "paper") -> dict[str, np.ndarray]:
    """The algebraic inversion (30)-(33) at points (v_d, dv_d/dt, d2v_d/dt2, engaged gear 1..n) (1-D arrays).

    Returns arrays: intake pressure, throttle demand u_d, engine speed and acceleration, crank torque, fuel
    flow, brake force, clutch state and the moving flag. ``mode`` as in the module docstring.
    """
    if mode not in ("paper", "extended"):
        raise VpsimError(f"unknown mode {mode!r}; expected paper or extended")
    eng = params.engine
    v = np.ascontiguousarray(v, dtype=float)
    dv = np.ascontiguousarray(dv, dtype=float)
    ddv = np.ascontiguousarray(ddv, dtype=float)
    gi = np.asarray(gear, dtype=np.int64) - 1
    if gi.size and not (0 <= gi.min() and gi.max() < params.transmission.n_gears):
        raise VpsimError(f"gear numbers must be 1..{params.transmission.n_gears}")
    P, coef = _model_constants(params)
    out = np.empty((6, v.size))
    _invert_core(v, dv, ddv, gi, coef, P, out)
    p, u, w, dw, t_cr, mdot_f = out
    moving = v > _MOVING
    brake = np.zeros(v.size)
    coupled = np.ones(v.size, bool)
    w_eng, dw_eng = w, dw
    if mode == "extended":
        r = np.asarray(params.transmission.ratios)[gi]
        p, u, t_cr, brake, coupled, w_eng, dw_eng = _extended(
            np.maximum(v, 0.0), dv, ddv, r, w, dw, p, u, t_cr, moving, params
        )
        mdot_f = ph.fuel_flow(p, w_eng, eng)
    return {
        "intake_pressure_pa": p,
        "throttle_demand_m2": u,
        "engine_speed_radps": w_eng,
        "engine_accel_radps2": dw_eng,
        "wheel_side_speed_radps": w,
        "crank_torque_nm": t_cr,
        "fuel_flow_kgps": mdot_f,
        "brake_force_n": brake,
        "clutch_engaged": coupled,
        "moving": moving,
    }


def _model_constants(params):
    """(P, coef): the forward kernel's model constants and, per gear, c1..c7 of (21), i / r and the
    rolling-resistance part of c4 (removed at standstill); cached per (immutable) model parameters."""
    return _all_constants(params)[:2]


_last_constants: list = [None, None]  # the parameter set of the last call and its constants


def _all_constants(params):
    """(P, coef, K) of :func:`_model_constants` and :func:`_accounting_constants`; the parameter set of the
    previous call is recognised by identity (parameter sets are immutable), others through the caches."""
    if _last_constants[0] is params:
        return _last_constants[1]
    out = _constants_of(params.vehicle, params.transmission, params.engine, params.simulation) + (
        _accounting_constants_of(params.vehicle, params.transmission, params.engine, params.simulation),
    )
    _last_constants[0], _last_constants[1] = params, out
    return out


@functools.lru_cache(maxsize=32)
def _constants_of(vehicle, transmission, engine, simulation):
    from types import SimpleNamespace

    P = constants(
        SimpleNamespace(vehicle=vehicle, transmission=transmission, engine=engine, simulation=simulation)
    )
    ratios = np.asarray(transmission.ratios, float)
    coef = np.empty((ratios.size, 9))
    eta = transmission.efficiency
    coef[:, :7] = np.column_stack(
        np.broadcast_arrays(*ph.statespace_coefficients(ratios, vehicle, engine, eta))
    )
    coef[:, 7] = ratios / vehicle.wheel_radius
    coef[:, 8] = ph.rolling_force(vehicle) / ph.equivalent_mass(ratios, vehicle, engine, eta)
    for arr in (P, coef):
        arr.flags.writeable = False
    return P, coef


@njit(cache=True)
def _invert_point(v, dv, ddv, c, P):
    """(33), (31), (32), (30) at one point in the gear whose coefficients are ``c`` (a row of coef):
    returns p_i, u_d, w_e, dw_e/dt, mdot_ac, T_cr, BMEP and the speed part of FMEP."""
    c1, c2, c3, c4, c5, c6, c7, kin, roll = c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8]
    x1 = v if v > 0.0 else 0.0
    if x1 <= _MOVING:
        c4 = c4 + roll  # rolling resistance only while moving
    x108 = x1**0.8
    x2 = (dv - c1 * x1 * x1 - c2 * x108 * x1 - c4) / c3  # (33)
    lf2h = (2.0 * c1 * x1 + 1.8 * c2 * x108) * dv + c3 * (c5 * x1 + c6 * x1 * x2)  # (31)
    gain = c3 * c7 * psi_scalar(x2 * P[_INV_PA], P)  # (32)
    num = ddv - lf2h
    if gain > 0.0:
        u = num / gain  # (30)
    elif num == 0.0:
        u = 0.0
    else:
        u = math.inf if num > 0.0 else -math.inf  # x2 >= p_a: no flow can raise the pressure further
    w = kin * x1
    mdot_ac, t_cr, bmep, fric_speed = engine_scalar(x2, w, P)
    return x2, u, w, kin * dv, mdot_ac, t_cr, bmep, fric_speed


@njit(cache=True)
def _invert_core(v, dv, ddv, gi, coef, P, out):
    """(33), (31), (32), (30) point by point; out rows: p_i, u_d, w_e, dw_e/dt, T_cr, mdot_f."""
    for k in range(v.size):
        x2, u, w, dw, mdot_ac, t_cr, _, _ = _invert_point(v[k], dv[k], ddv[k], coef[gi[k]], P)
        out[0, k] = x2
        out[1, k] = u
        out[2, k] = w
        out[3, k] = dw
        out[4, k] = t_cr
        out[5, k] = mdot_ac * P[_INV_AFR]


def powers(v, dv, inv, params) -> dict[str, np.ndarray]:
    """Power of every term of the energy balance (W) at the inversion's points (keys of EnergyBalance)."""
    veh, eng, tr = params.vehicle, params.engine, params.transmission
    eta = tr.efficiency
    v = np.maximum(np.asarray(v, float), 0.0)
    p, w_eng, dw_eng = inv["intake_pressure_pa"], inv["engine_speed_radps"], inv["engine_accel_radps2"]
    coupled, t_cr, w = inv["clutch_engaged"], inv["crank_torque_nm"], inv["wheel_side_speed_radps"]
    cyc = ph.mep_to_torque(1.0, eng) * w_eng  # MEP x this = power
    t_e = engine_torque(inv, eng)
    return {
        "indicated": inv["fuel_flow_kgps"] * eng.fuel_heating_value * eng.thermal_efficiency,
        "friction": ph.fmep(p, w_eng, eng) * cyc,
        "pumping": ph.pmep(p, eng) * cyc,
        "engine_kinetic": eng.inertia * w_eng * dw_eng,
        # stiff: (1 - eta) T_e w_e; slipping clutch: slip loss T_c (w_idle - w_wheel) + (1 - eta) T_c w_wheel
        "driveline_loss": np.where(
            coupled, (1 - eta) * t_e * w_eng, np.where(t_cr > 0, t_e * (w_eng - eta * w), 0.0)
        ),
        "vehicle_kinetic": veh.mass * v * dv,
        "aero": ph.aero_force(v, veh) * v,
        "rolling": ph.rolling_force(veh) * inv["moving"] * v,
        "brake": inv["brake_force_n"] * v,
    }


def engine_torque(inv, eng):
    """Flywheel torque T_e = T_cr - J_e dw_e/dt (1); with the clutch slipping, the clutch torque."""
    t_cr = inv["crank_torque_nm"]
    return np.where(
        inv["clutch_engaged"], t_cr - eng.inertia * inv["engine_accel_radps2"], np.maximum(t_cr, 0.0)
    )


def _extended(v, dv, ddv, ratio, w, dw, p, u, t_cr, moving, params):
    """Clutch, idle and brakes of the ``extended`` mode (module docstring)."""
    from ..maps import steady_state

    veh, eng, tr = params.vehicle, params.engine, params.transmission
    eta, r, m = tr.efficiency, veh.wheel_radius, veh.mass
    p, u, t_cr = p.copy(), u.copy(), t_cr.copy()
    brake = np.zeros_like(v)
    # coupled, demand below the closed-throttle line: engine on the line, brakes take the rest
    low = w < IDLE_SPEED
    hi = ~low
    if np.any(hi):
        closed = steady_state(eng.min_throttle_area, w[hi], eng)
        t_min = closed.crank_torque
        braking = t_cr[hi] < t_min
        idx = np.flatnonzero(hi)[braking]
        brake[idx] = (t_min[braking] - t_cr[idx]) * ratio[idx] * eta / r
        t_cr[idx] = t_min[braking]
        p[idx] = closed.intake_pressure[braking]
        u[idx] = eng.min_throttle_area
    # below idle speed: slipping clutch (engine at idle, no inertia) or open clutch (engine idling, brakes)
    w_eng = np.where(low, IDLE_SPEED, w)
    dw_eng = np.where(low, 0.0, dw)
    coupled = hi.copy()
    if np.any(low):
        vl, dvl, ddvl, il = v[low], dv[low], ddv[low], ratio[low]
        force = m * dvl + ph.aero_force(vl, veh) + ph.rolling_force(veh) * moving[low]
        t_c = force * r / (il * eta)
        traction = t_c > 0.0
        t_l = np.where(traction, t_c, 0.0)
        p_l = ph.intake_pressure_for_torque(t_l, IDLE_SPEED, eng)
        # throttle from the manifold (9) with dp_i/dt = dp/dT dT/dt (p_i is affine in T_cr at fixed speed)
        dp_dt_cr = ph.intake_pressure_for_torque(1.0, IDLE_SPEED, eng) - ph.intake_pressure_for_torque(
            0.0, IDLE_SPEED, eng
        )
        dt_c = (
            (m * ddvl + 2.0 * 0.5 * veh.drag_coefficient * veh.air_density * veh.frontal_area * vl * dvl)
            * r
            / (il * eta)
        )
        dp = np.where(traction, dp_dt_cr * dt_c, 0.0)
        rt = eng.gas_constant * eng.intake_temperature
        outflow = ph.cylinder_air_flow(p_l, IDLE_SPEED, eng)
        per_area = ph.throttle_mass_flow(1.0, p_l, eng)
        with np.errstate(divide="ignore", invalid="ignore"):
            u_l = (dp * eng.intake_manifold_volume / rt + outflow) / per_area
        p[low] = p_l
        u[low] = u_l
        t_cr[low] = t_l
        brake[low] = np.maximum(-force, 0.0)
    return p, u, t_cr, brake, coupled, w_eng, dw_eng


def _trapezoid(f, left, right, dt):
    """Sum over intervals of dt (f_left + f_right) / 2."""
    return float(np.sum(dt * (f[left] + f[right])) * 0.5)


@njit(cache=True)
def _fuel_and_distance(mdot, v, idle, left, right, dt):
    """Trapezoid sums of max(mdot_f, mdot_idle) (section 5) and of v over the intervals."""
    fuel = 0.0
    dist = 0.0
    for k in range(dt.size):
        a = mdot[left[k]] if mdot[left[k]] > idle else idle
        b = mdot[right[k]] if mdot[right[k]] > idle else idle
        fuel += 0.5 * dt[k] * (a + b)
        dist += 0.5 * dt[k] * (max(v[left[k]], 0.0) + max(v[right[k]], 0.0))
    return fuel, dist


# rows of the per-point array of the compiled path (the inversion's outputs, as :func:`invert` returns them)
_R_P, _R_U, _R_WENG, _R_DWENG, _R_W, _R_TCR, _R_MDOT, _R_BRAKE, _R_COUPLED, _R_MOVING, _R_FMEP = range(11)
N_ROWS = 11
# constants of the accounting kernel
_K_IDLE, _K_ETA, _K_J, _K_M, _K_AERO, _K_ROLL, _K_AMIN, _K_AMAX, _K_BAND = range(9)
# its results: fuel, distance, the energy terms (in EnergyBalance's order), then the trace figures
_ENERGY_KEYS = (
    "indicated",
    "friction",
    "pumping",
    "engine_kinetic",
    "driveline_loss",
    "vehicle_kinetic",
    "aero",
    "rolling",
    "brake",
)
_A_FUEL, _A_DIST = 0, 1
_A_E0 = 2  # 9 energy terms
_A_BELOW, _A_ABOVE, _A_STAND, _A_BRAKED, _A_UMIN, _A_UMAX, _A_ERR2, _A_WSUM, _A_OUT, _A_ERRMAX = range(11, 21)
N_ACC = 21


@njit(cache=True)
def _invert_rows(v, dv, ddv, gear, coef, P, rows):
    """The paper-mode inversion into ``rows`` (N_ROWS x n): (33), (31), (32), (30) point by point, in gears
    ``gear`` (1-based); False (nothing computed) if a gear is not one of coef's rows."""
    for k in range(v.size):
        if not (1 <= gear[k] <= coef.shape[0]):
            return False
    for k in range(v.size):
        c = coef[gear[k] - 1]
        x2, u, w, dw, mdot_ac, t_cr, bmep, fric_speed = _invert_point(v[k], dv[k], ddv[k], c, P)
        rows[_R_FMEP, k] = fric_speed + P[_KF] * 0.0215 * bmep  # FMEP (5)
        rows[_R_P, k] = x2
        rows[_R_U, k] = u
        rows[_R_WENG, k] = w
        rows[_R_DWENG, k] = dw
        rows[_R_W, k] = w
        rows[_R_TCR, k] = t_cr
        rows[_R_MDOT, k] = mdot_ac * P[_INV_AFR]
        rows[_R_BRAKE, k] = 0.0
        rows[_R_COUPLED, k] = 1.0
        rows[_R_MOVING, k] = 1.0 if v[k] > _MOVING else 0.0
    return True


@njit(cache=True)
def _account(v, dv, vc, rows, left, right, dt, P, K, weight, acc):
    """Fuel, distance, energy terms (trapezoid), infeasible and standstill seconds and the tracking figures
    of the grid's points in one pass (the bookkeeping of :func:`run`'s NumPy reference path).

    The trapezoid sums are sums over the points of weight x integrand, ``weight`` (scratch, one per point)
    being the time each point stands for.
    """
    n = v.size
    for i in range(N_ACC):
        acc[i] = 0.0
    for k in range(n):
        weight[k] = 0.0
    for j in range(dt.size):
        hw = 0.5 * dt[j]
        weight[left[j]] += hw
        weight[right[j]] += hw
    acc[_A_UMIN] = math.inf
    acc[_A_UMAX] = -math.inf
    n_moving = 0
    n_moving_u = 0
    eta = K[_K_ETA]
    idle = K[_K_IDLE]
    for k in range(n):
        wk = weight[k]
        x = v[k] if v[k] > 0.0 else 0.0
        p = rows[_R_P, k]
        w_eng = rows[_R_WENG, k]
        t_cr = rows[_R_TCR, k]
        mdot = rows[_R_MDOT, k]
        coupled = rows[_R_COUPLED, k] != 0.0
        moving = rows[_R_MOVING, k] != 0.0
        brake = rows[_R_BRAKE, k]
        cyc = P[_KMEP] * w_eng
        if coupled:
            t_e = t_cr - K[_K_J] * rows[_R_DWENG, k]
            drv = (1.0 - eta) * t_e * w_eng
        else:
            drv = t_cr * (w_eng - eta * rows[_R_W, k]) if t_cr > 0.0 else 0.0
        acc[_A_FUEL] += wk * (mdot if mdot > idle else idle)
        acc[_A_DIST] += wk * x
        acc[_A_E0 + 0] += wk * (mdot * P[_QHV])
        acc[_A_E0 + 1] += wk * (rows[_R_FMEP, k] * cyc)
        acc[_A_E0 + 2] += wk * ((P[_PE] - p) * cyc)
        acc[_A_E0 + 3] += wk * (K[_K_J] * w_eng * rows[_R_DWENG, k])
        acc[_A_E0 + 4] += wk * drv
        acc[_A_E0 + 5] += wk * (K[_K_M] * x * dv[k])
        acc[_A_E0 + 6] += wk * (K[_K_AERO] * x * x * x)
        if moving:
            acc[_A_E0 + 7] += wk * (K[_K_ROLL] * x)
        acc[_A_E0 + 8] += wk * (brake * x)
        u = rows[_R_U, k]
        err = abs(v[k] - vc[k])
        if err > acc[_A_ERRMAX]:
            acc[_A_ERRMAX] = err
        if moving:
            n_moving += 1
            if brake <= 0.0 and not (u >= K[_K_AMIN]):  # (NaN counts as infeasible)
                acc[_A_BELOW] += wk
            if u > K[_K_AMAX]:
                acc[_A_ABOVE] += wk
            if not math.isnan(u):
                n_moving_u += 1
                if u < acc[_A_UMIN]:
                    acc[_A_UMIN] = u
                if u > acc[_A_UMAX]:
                    acc[_A_UMAX] = u
        else:
            acc[_A_STAND] += wk
        if brake > 0.0:
            acc[_A_BRAKED] += wk
        acc[_A_ERR2] += wk * err * err
        acc[_A_WSUM] += wk
        if err > K[_K_BAND]:
            acc[_A_OUT] += wk
    if n_moving_u == 0:  # as np.nanmin / np.nanmax of the moving points' demands
        acc[_A_UMIN] = 0.0 if n_moving == 0 else math.nan
        acc[_A_UMAX] = acc[_A_UMIN]


@njit(cache=True)
def _series_extras(rows, K, out):
    """Engine torque (1), throttle area (u_d clipped to [A_min, A_max]) and fuel flow with the idle floor at
    the first ``out.shape[1]`` points, into the rows of ``out``."""
    for k in range(out.shape[1]):
        t_cr = rows[_R_TCR, k]
        if rows[_R_COUPLED, k] != 0.0:
            out[0, k] = t_cr - K[_K_J] * rows[_R_DWENG, k]
        else:
            out[0, k] = t_cr if t_cr > 0.0 else 0.0
        u = rows[_R_U, k]
        if u < K[_K_AMIN]:
            u = K[_K_AMIN]
        elif u > K[_K_AMAX]:
            u = K[_K_AMAX]
        out[1, k] = u  # (NaN stays NaN, as with np.clip)
        mdot = rows[_R_MDOT, k]
        out[2, k] = mdot if mdot > K[_K_IDLE] else K[_K_IDLE]


@njit(cache=True)
def _paper_pass(v, dv, ddv, gear, coef, P, vc, left, right, dt, K, rows, weight, acc, extra):
    """:func:`_invert_rows`, :func:`_account` and :func:`_series_extras` in one call (paper mode)."""
    if not _invert_rows(v, dv, ddv, gear, coef, P, rows):
        return False
    _account(v, dv, vc, rows, left, right, dt, P, K, weight, acc)
    _series_extras(rows, K, extra)
    return True


_warm = False


def warm_up() -> None:
    """Load (or compile) the compiled parts once per process, so run times measure the method only."""
    global _warm
    if not _warm:
        z = np.zeros(2)
        idx = np.zeros(2, dtype=np.int64)
        coef, P = np.ones((1, 9)), np.ones(64)
        coef.flags.writeable = P.flags.writeable = False  # as the cached constants are
        _invert_core(z, z, z, idx, coef, P, np.empty((6, 2)))
        _fuel_and_distance(z, z, 0.0, idx[:1], idx[:1] + 1, np.ones(1))
        rows = np.zeros((N_ROWS, 2))
        _invert_rows(z, z, z, idx + 1, coef, P, rows)
        _account(z, z, z, rows, idx[:1], idx[:1] + 1, np.ones(1), P, np.ones(9), np.empty(2), np.empty(N_ACC))
        ts = np.arange(3.0)
        ts.flags.writeable = False  # as a loaded cycle's arrays are
        taps = _sample_taps(1.0, 1.0)
        _is_uniform_compiled(ts)
        K = np.ones(9)
        K.flags.writeable = False
        _series_extras(rows, K, np.empty((3, 2)))
        one = idx[:1]
        _paper_pass(
            z, z, z, idx + 1, coef, P, z, one, one + 1, z[:1], K, rows, z.copy(), np.empty(N_ACC), rows[:3]
        )
        _grid_and_smoothing(ts, ts, ts.copy(), np.ones(3, dtype=np.int64), *taps)
        _warm = True


def _bookkeeping_reference(
    cycle, params, schedule, mode, a, t, gear, left, right, v, dv, ddv, keep_series, t_cpu
):
    """The NumPy reference of the inversion and its bookkeeping (``run(..., compiled=False)``)."""
    eng, sim = params.engine, params.simulation
    n_s = cycle.time_s.size
    inv = invert(v, dv, ddv, gear, params, mode)
    dt = np.diff(cycle.time_s)
    fuel_kg, distance = _fuel_and_distance(inv["fuel_flow_kgps"], v, sim.idle_fuel_flow, left, right, dt)
    cpu = time.process_time() - t_cpu
    mdot = inv["fuel_flow_kgps"]
    used = ph.fuel_with_idle_floor(mdot, sim.idle_fuel_flow)

    energy = EnergyBalance(
        **{k: _trapezoid(pw, left, right, dt) for k, pw in powers(v, dv, inv, params).items()}
    )
    # time each grid point stands for (trapezoid weights), to turn flags into seconds
    weight = np.zeros(t.size)
    np.add.at(weight, left, 0.5 * dt)
    np.add.at(weight, right, 0.5 * dt)
    u = inv["throttle_demand_m2"]
    moving = inv["moving"]
    braked = inv["brake_force_n"] > 0.0
    below = moving & ~braked & ~(u >= eng.min_throttle_area)  # (NaN counts as infeasible)
    above = moving & (u > eng.max_throttle_area)
    below_s = float(np.sum(weight[below]))
    above_s = float(np.sum(weight[above]))
    v_c = np.interp(t, cycle.time_s, cycle.speed_mps)
    err = np.abs(v - v_c)
    band = BAND_KMH / 3.6
    um = u[moving]
    trace = TraceMiss(
        seconds=below_s + above_s,
        max_speed_error_mps=float(np.max(err)),
        infeasible_throttle_s=below_s + above_s,
        details={
            "below_min_throttle_s": below_s,
            "above_max_throttle_s": above_s,
            "standstill_s": float(np.sum(weight[~moving])),
            "braked_s": float(np.sum(weight[braked])),
            "min_throttle_demand_m2": float(np.nanmin(um)) if um.size else 0.0,
            "max_throttle_demand_m2": float(np.nanmax(um)) if um.size else 0.0,
            "rms_speed_error_mps": float(np.sqrt(np.sum(weight * err**2) / np.sum(weight))),
            "seconds_outside_band": float(np.sum(weight[err > band])),
            "band_kmh": BAND_KMH,
            "smoothing_a_s": a,
        },
    )
    series = {}
    if keep_series:
        k = slice(0, n_s)  # the cycle samples (right-continuous gear)
        series = {
            "time_s": t[k],
            "reference_speed_mps": v_c[k],
            "speed_mps": v[k],
            "accel_mps2": dv[k],
            "jerk_mps3": ddv[k],
            "gear": schedule.gear_at(t[k]),
            "engine_speed_radps": inv["engine_speed_radps"][k],
            "crank_torque_nm": inv["crank_torque_nm"][k],
            "engine_torque_nm": engine_torque(inv, eng)[k],
            "intake_pressure_pa": inv["intake_pressure_pa"][k],
            "throttle_area_m2": np.clip(u[k], eng.min_throttle_area, eng.max_throttle_area),
            "throttle_demand_m2": u[k],
            "fuel_flow_kgps": mdot[k],
            "fuel_flow_used_kgps": used[k],
            "brake_force_n": inv["brake_force_n"][k],
            "torque_shortfall_nm": np.zeros(n_s),
            "clutch_engaged": inv["clutch_engaged"][k],
        }
    return energy, trace, series, fuel_kg, distance, below_s, above_s, cpu


def _bookkeeping_compiled(cycle, params, mode, a, grid, v, dv, ddv, keep_series, t_cpu):
    """The inversion and its bookkeeping in compiled passes (paper mode: two kernels, no NumPy temporaries;
    extended mode: the NumPy clutch/idle/brake logic, then the compiled accounting).

    ``grid``: (t, gear, left, right, gear at the cycle samples, interval lengths, cycle speed at the points).
    """
    eng = params.engine
    t, gear, left, right, gear_s, dt, v_c = grid
    n_s = cycle.time_s.size
    rows = np.empty((N_ROWS, t.size))
    P, coef, K = _all_constants(params)
    acc = np.empty(N_ACC)
    extra = np.empty((3, n_s if keep_series else 0))
    if mode == "paper":
        gear = gear.astype(np.int64, copy=False)
        if not _paper_pass(
            v, dv, ddv, gear, coef, P, v_c, left, right, dt, K, rows, np.empty(t.size), acc, extra
        ):
            raise VpsimError(f"gear numbers must be 1..{params.transmission.n_gears}")
    else:
        inv = invert(v, dv, ddv, gear, params, mode)
        for r, key in enumerate(_ROW_KEYS):
            rows[r] = inv[key]
        rows[_R_FMEP] = ph.fmep(inv["intake_pressure_pa"], inv["engine_speed_radps"], eng)
        _account(v, dv, v_c, rows, left, right, dt, P, K, np.empty(t.size), acc)
        _series_extras(rows, K, extra)
    fuel_kg, distance = float(acc[_A_FUEL]), float(acc[_A_DIST])
    cpu = time.process_time() - t_cpu
    energy = EnergyBalance(**{key: float(acc[_A_E0 + i]) for i, key in enumerate(_ENERGY_KEYS)})
    below_s, above_s = float(acc[_A_BELOW]), float(acc[_A_ABOVE])
    trace = TraceMiss(
        seconds=below_s + above_s,
        max_speed_error_mps=float(acc[_A_ERRMAX]),
        infeasible_throttle_s=below_s + above_s,
        details={
            "below_min_throttle_s": below_s,
            "above_max_throttle_s": above_s,
            "standstill_s": float(acc[_A_STAND]),
            "braked_s": float(acc[_A_BRAKED]),
            "min_throttle_demand_m2": float(acc[_A_UMIN]),
            "max_throttle_demand_m2": float(acc[_A_UMAX]),
            "rms_speed_error_mps": math.sqrt(acc[_A_ERR2] / acc[_A_WSUM]),
            "seconds_outside_band": float(acc[_A_OUT]),
            "band_kmh": BAND_KMH,
            "smoothing_a_s": a,
        },
    )
    series = {}
    if keep_series:
        k = slice(0, n_s)
        u = rows[_R_U, k]
        coupled = rows[_R_COUPLED, k] != 0.0
        series = {
            "time_s": t[k],
            "reference_speed_mps": v_c[k],
            "speed_mps": v[k],
            "accel_mps2": dv[k],
            "jerk_mps3": ddv[k],
            "gear": gear_s,
            "engine_speed_radps": rows[_R_WENG, k],
            "crank_torque_nm": rows[_R_TCR, k],
            "engine_torque_nm": extra[0],
            "intake_pressure_pa": rows[_R_P, k],
            "throttle_area_m2": extra[1],
            "throttle_demand_m2": u,
            "fuel_flow_kgps": rows[_R_MDOT, k],
            "fuel_flow_used_kgps": extra[2],
            "brake_force_n": rows[_R_BRAKE, k],
            "torque_shortfall_nm": np.zeros(n_s),
            "clutch_engaged": coupled,
        }
    return energy, trace, series, fuel_kg, distance, below_s, above_s, cpu


_ROW_KEYS = (
    "intake_pressure_pa",
    "throttle_demand_m2",
    "engine_speed_radps",
    "engine_accel_radps2",
    "wheel_side_speed_radps",
    "crank_torque_nm",
    "fuel_flow_kgps",
    "brake_force_n",
    "clutch_engaged",
    "moving",
)


def _accounting_constants(params):
    return _all_constants(params)[2]


@functools.lru_cache(maxsize=32)
def _accounting_constants_of(veh, tr, eng, sim):
    K = np.empty(9)
    K[_K_IDLE] = sim.idle_fuel_flow
    K[_K_ETA] = tr.efficiency
    K[_K_J] = eng.inertia
    K[_K_M] = veh.mass
    K[_K_AERO] = 0.5 * veh.drag_coefficient * veh.air_density * veh.frontal_area
    K[_K_ROLL] = ph.rolling_force(veh)
    K[_K_AMIN] = eng.min_throttle_area
    K[_K_AMAX] = eng.max_throttle_area
    K[_K_BAND] = BAND_KMH / 3.6
    K.flags.writeable = False
    return K


def run(
    cycle,
    params,
    *,
    driver="1",
    schedule: GearSchedule | None = None,
    mode: str = "paper",
    a: float | None = None,
    keep_series: bool = True,
    compiled: bool = True,
) -> Result:
    """Run the IDM on ``cycle`` with the smoothing driver ``driver`` (half-width ``a`` overrides it).

    ``compiled=False`` runs the NumPy reference of the inversion's bookkeeping (fuel, energy terms,
    infeasible seconds, tracking figures); the compiled path (default) does it in one pass over the grid.
    """
    if mode not in ("paper", "extended"):
        raise VpsimError(f"unknown mode {mode!r}; expected paper or extended")
    driver = str(driver)
    a = params.driver(driver).inverse_a if a is None else float(a)
    if not (math.isfinite(a) and a > 0.0):
        raise VpsimError(f"smoothing half-width a = {a:g} s must be positive")
    if schedule is None:
        from ..maps import cached_engine_map

        schedule = default_schedule(cycle, params, cached_engine_map(params.engine))
    sim = params.simulation
    warm_up()

    t_cpu = time.process_time()
    if compiled and _is_uniform_compiled(cycle.time_s):  # grid and smoothing in one compiled pass
        taps = _sample_taps(a, float(cycle.time_s[1] - cycle.time_s[0]))
        F, I = _grid_and_smoothing(cycle.time_s, cycle.speed_mps, schedule.time_s, schedule.gear, *taps)
        n = cycle.time_s.size - 1
        t, v, dv, ddv, gear = F[0], F[1], F[2], F[3], I[0]
        grid = (t, gear, I[1, :n], I[2, :n], I[4, : n + 1], F[5, :n], F[4])
    else:
        t, gear, left, right, sample = evaluation_grid(cycle, schedule)
        if _is_uniform(cycle.time_s):  # the grid's points all sit on samples: index them
            v, dv, ddv = (x[sample] for x in smoothed_on_samples(cycle.time_s, cycle.speed_mps, a))
        else:
            v, dv, ddv = SmoothingDriver(cycle.time_s, cycle.speed_mps, a).evaluate(t)
        # the grid's points sit on samples (np.interp there is the sample)
        gear_s = schedule.gear_at(t[: cycle.time_s.size])
        grid = (t, gear, left, right, gear_s, np.diff(cycle.time_s), cycle.speed_mps[sample])
    if compiled:
        energy, trace, series, fuel_kg, distance, below_s, above_s, cpu = _bookkeeping_compiled(
            cycle, params, mode, a, grid, v, dv, ddv, keep_series, t_cpu
        )
    else:
        energy, trace, series, fuel_kg, distance, below_s, above_s, cpu = _bookkeeping_reference(
            cycle, params, schedule, mode, a, t, gear, left, right, v, dv, ddv, keep_series, t_cpu
        )
    notes = [f"smoothing a = {a:g} s; {t.size} evaluation points (cycle samples and gear changes), trapezoid"]
    if below_s:
        what = "deceleration beyond engine braking (no brakes)" if mode == "paper" else "manifold too slow"
        notes.append(f"throttle demand below A_min for {below_s:.1f} s while moving: {what}")
    if above_s:
        notes.append(f"throttle demand above A_max for {above_s:.1f} s: beyond full load; fuel of the demand")
    return Result(
        method="inverse",
        cycle=cycle.name,
        driver=driver,
        mode=mode,
        series=series,
        fuel_kg=fuel_kg,
        distance_m=distance,
        fuel_density_kg_per_l=sim.fuel_density,
        cpu_time_s=cpu,
        steps=int(t.size),
        trace_miss=trace,
        energy=energy,
        vehicle=params.name,
        notes=tuple(notes),
    )
