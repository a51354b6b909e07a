"""Inverse dynamic method (IDM), paper section 4: stable inversion of the affine model (21).

The driver is the smoothing (34)-(35) (:class:`vpsim.drivers.smoothing.SmoothingDriver`, half-width a = 5 s
for driver 1, 1 s for driver 2), which gives the desired speed y_d = v_d(t) and its exact first and second
derivatives. With x1 = v, x2 = p_i, u = A_eff the relative degree is 2, equal to the order, so there are no
zero dynamics and the inversion is algebraic, point by point:

    x2   = (dy_d - c1 y_d^2 - c2 y_d^1.8 - c4) / c3                                        (33)
    L_f^2 h = (2 c1 x1 + 1.8 c2 x1^0.8) dy_d + c3 (c5 x1 + c6 x1 x2)                      (31)
    u_d  = (d2y_d - L_f^2 h) / (c3 c7 Psi(x2 / p_a))                                        (30),(32)

(in (31) the bracket c1 x1^2 + c2 x1^1.8 + c3 x2 + c4 equals dy_d by (33)). The coefficients c1..c7 depend
on the engaged ratio (:func:`vpsim.model.vehicle.statespace_coefficients`); as in the backward method, rolling
resistance acts only while the vehicle moves (v_d > 0).

Grid and fuel. The paper integrates the fuel with ode45, the step capped at 1 s. Here the inversion is
evaluated at every cycle sample (plus, at each gear change, the instant once more with the old gear, since
x2 jumps there) and the fuel, distance and energy terms are integrated by the trapezoidal rule: against a
0.05 s Simpson reference the fuel differs by under 0.05 % on NEDC and FTP-75 (a test keeps it under 0.1 %).
``steps`` is the number of evaluation points. The cost counts the smoothing, which on a uniformly sampled
cycle is three discrete convolutions (:func:`_sample_taps`). The grid, the smoothing on it, the
inversion (:func:`invert_point`) and the bookkeeping (:func:`account`) are compiled; they call the model's
equations (:mod:`vpsim.model`) and its rules for the realistic car, and restate none of them.

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
that of the demanded trajectory. A boosted engine's demand u_d is the throttle command
(:func:`vpsim.model.engine.throttle_upstream`): beyond A_max the throttle is wide open and the boost rises, to
full boost at 2 A_max; beyond full load means u_d > 2 A_max there.
"""

from __future__ import annotations

import functools
import math
import time

import numpy as np

from ..cycles import Cycle
from ..cycles.resample import subdivide
from ..drivers.smoothing import SmoothingDriver, bump_kernel, bump_kernel_cdf, bump_kernel_moment
from ..errors import VpsimError
from ..gears import GearSchedule, gearbox_ratio_series, schedule_for
from ..model import engine as en
from ..model import rules
from ..model import vehicle as vh
from ..model._compile import compiled, kernel
from ..model.engine import inline
from ..model.record import kernel_records, memo, readonly, record
from ..model.record import ratios as total_ratios
from ..result import EnergyBalance, Result, TraceMiss, limits_of

BAND_KMH = 2.0  # the regulation's speed tolerance, as for the forward method
MAX_TAPS = 200_001  # largest discrete smoothing kernel (2a/dt + 1 samples) the uniform-grid path builds
_MOVING = 1e-9  # m/s: v_d above this counts as moving (v_d is exactly 0 only where the cycle rests +-a)


@functools.lru_cache(maxsize=16)
def _sample_taps(a: float, dt: float):
    """Kernel samples at offsets -K dt .. K dt for the convolution of :func:`_grid_and_smoothing` (cached per
    a, dt): with v_c(tau) = v_0 + sum_k dm_k (tau - t_k)_+ (dm_k the slope change at sample k, the ends held),
    the smoothed speed at a sample is v_c(t_i) + sum_k dm_k C((i - k) dt), C(x) = x G(x) - M(x) - x_+ being
    zero for |x| >= a (G: the kernel's cumulative, M: its first moment); so each of v_d and its two
    derivatives is one discrete convolution of dm with 2a/dt + 1 taps."""
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


@kernel
def _is_uniform_compiled(t):
    """:func:`_is_uniform` in one pass."""
    if t.size < 2:
        return False
    d0 = t[1] - t[0]
    for i in range(1, t.size - 1):
        if not (abs((t[i + 1] - t[i]) - d0) <= 1e-9 * d0):
            return False
    return True


@inline
def _four_windows(dm, i, k, c_v, c_dv, c_ddv, v_s, m, v, dv, ddv):
    """The smoothing at samples i .. i + 3, whose windows i - k .. i + 3 + k lie inside the cycle: the four
    sums run side by side (each still in its own order, over r ascending, so the figures are those of one
    sum at a time), which keeps four chains of additions in flight instead of one."""
    v0 = v1 = v2 = v3 = 0.0
    d0 = d1 = d2 = d3 = 0.0
    a0 = a1 = a2 = a3 = 0.0
    base = i - k
    for j in range(2 * k + 1):
        c = 2 * k - j  # the tap of sample i + q at r = i + q - k + j
        cv = c_v[c]
        cdv = c_dv[c]
        cddv = c_ddv[c]
        x0 = dm[base + j]
        x1 = dm[base + j + 1]
        x2 = dm[base + j + 2]
        x3 = dm[base + j + 3]
        v0 += x0 * cv
        v1 += x1 * cv
        v2 += x2 * cv
        v3 += x3 * cv
        d0 += x0 * cdv
        d1 += x1 * cdv
        d2 += x2 * cdv
        d3 += x3 * cdv
        a0 += x0 * cddv
        a1 += x1 * cddv
        a2 += x2 * cddv
        a3 += x3 * cddv
    v[i] = v_s[i] + v0
    v[i + 1] = v_s[i + 1] + v1
    v[i + 2] = v_s[i + 2] + v2
    v[i + 3] = v_s[i + 3] + v3
    dv[i] = 0.5 * (m[i] + m[i + 1]) + d0
    dv[i + 1] = 0.5 * (m[i + 1] + m[i + 2]) + d1
    dv[i + 2] = 0.5 * (m[i + 2] + m[i + 3]) + d2
    dv[i + 3] = 0.5 * (m[i + 3] + m[i + 4]) + d3
    ddv[i] = a0
    ddv[i + 1] = a1
    ddv[i + 2] = a2
    ddv[i + 3] = a3


@kernel
def _grid_and_smoothing(t_s, v_s, sched_t, sched_g, c_v, c_dv, c_ddv):
    """:func:`evaluation_grid` and the smoothing at the samples (the convolutions of :func:`_sample_taps`)
    in one compiled pass, for a uniformly sampled cycle.

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
    dm = np.empty(n_s)
    for r in range(n_s):
        dm[r] = m[r + 1] - m[r]
    k = (c_v.size - 1) // 2
    i = 0
    while i < n_s:  # the points 0..n_s - 1 are the samples
        if i - k >= 0 and i + 3 + k <= n_s - 1:  # four whole windows: four sums at a time
            _four_windows(dm, i, k, c_v, c_dv, c_ddv, v_s, m, v, dv, ddv)
            i += 4
            continue
        lo = i - k if i - k > 0 else 0
        hi = i + k if i + k < n_s - 1 else n_s - 1
        sv = 0.0
        sdv = 0.0
        sddv = 0.0
        for r in range(lo, hi + 1):
            c = k + i - r
            sv += dm[r] * c_v[c]
            sdv += dm[r] * c_dv[c]
            sddv += dm[r] * c_ddv[c]
        v[i] = v_s[i] + sv
        dv[i] = 0.5 * (m[i] + m[i + 1]) + sdv
        ddv[i] = sddv
        i += 1
    for i in range(n_s):
        v_c[i] = v_s[i]
    for p in range(n_s, n_pts):  # the gear changes' second points
        s = sample[p]
        v[p] = v[s]
        dv[p] = dv[s]
        ddv[p] = ddv[s]
        v_c[p] = v_s[s]
    return F, I


def _trajectory(time_s, speed, schedule: GearSchedule, a: float):
    """(F, I) of :func:`_grid_and_smoothing` and :func:`speed_powers` of the smoothed speed: the smoothing
    driver's trajectory on the cycle's samples ``time_s``, ``speed`` in ``schedule``'s gears, which no
    parameter of the car changes. Kept on the (frozen) schedule per half-width a for the samples last
    given (as the backward method keeps a cycle's intervals): every run of any design on that cycle and
    schedule shares it (read-only arrays; :func:`_kept_trajectory` reads it back)."""
    kept = memo(schedule, "inverse_trajectories", _no_trajectories)
    taps = _sample_taps(a, float(time_s[1] - time_s[0]))
    F, I = _grid_and_smoothing(time_s, speed, schedule.time_s, schedule.gear, *taps)
    x108 = np.empty(F.shape[1])
    speed_powers(F[1], x108)
    out = readonly((F, I, x108))
    if len(kept) < 8:  # (a few drivers' half-widths; beyond, computed each run)
        kept[a] = (time_s, speed, out)
    return out


def _read_only(*arrays) -> tuple:
    """Read-only views of ``arrays`` (theirs left writable): what the kernels are compiled for, the kept
    trajectory's arrays being read-only (:func:`_trajectory`); Numba compiles a kernel anew for each
    writability of an argument."""
    out = []
    for x in arrays:
        view = x.view()
        view.flags.writeable = False
        out.append(view)
    return tuple(out)


def _no_trajectories(schedule) -> dict:
    return {}


def _zeros(cycle) -> np.ndarray:
    """Zeros at the cycle's samples, read-only (kept on the cycle: a series every run reports as zero)."""
    (z,) = readonly((np.zeros(cycle.time_s.size),))
    return z


def _kept_trajectory(time_s, speed, schedule: GearSchedule, a: float):
    """What :func:`_trajectory` keeps for these samples, schedule and half-width, or None."""
    hit = memo(schedule, "inverse_trajectories", _no_trajectories).get(a)
    if hit is not None and hit[0] is time_s and hit[1] is speed:
        return hit[2]
    return None


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


# --- the inversion, point by point ---------------------------------------------------------------------

# rows of the per-point array
(R_P, R_U, R_WENG, R_DWENG, R_W, R_TCR, R_MDOT, R_BRAKE, R_CLUTCH, R_MOVING, R_FIRED, R_CM18) = range(12)
N_ROWS = 12  # (R_CM18, c_m^1.8 at the engine speed, is the energy terms' and not in invert()'s output)
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
    "fired",
)


@inline
def invert_point(v, dv, ddv, x108, ratio, gear, coef, extended, p_closed_max, c):
    """(33), (31), (32), (30) at one point in gear ``gear`` (1-based) of total ratio ``ratio`` (``coef``:
    :func:`gear_coefficients`' row of the gear), with the realistic car's rules in ``extended``
    mode; ``x108``: max(v, 0)^0.8 (:func:`speed_powers`: the power in (33) and in c_m^1.8). Through an
    unlocked torque converter the point is the quasi-static one of
    :func:`vpsim.model.rules.converter_point` (the throttle the steady one; no traction: as below idle).
    ``p_closed_max``: :func:`vpsim.model.engine.closed_throttle_pressure_bound`.

    Returns p_i, u_d, w_e, dw_e/dt, w_wheel, T_cr, brake force, clutch state, moving, the fired fraction and
    c_m^1.8 of (5) at w_e (:func:`vpsim.model.engine.speed_power`, for the energy terms). The throttle u_d is
    the one that gives the required dp_i/dt in the manifold equation (9)
    (:func:`vpsim.model.engine.throttle_for_pressure_rate`), which is (30)-(32) without restating (9).
    """
    c1, c2, c3, c4, roll, cb = coef[0], coef[1], coef[2], coef[3], coef[4], coef[5]
    x1 = v if v > 0.0 else 0.0
    moving = x1 > _MOVING
    if not moving:
        c4 = c4 + roll  # rolling resistance only while moving
        cb = 0.0
    x2 = (dv - c1 * x1 * x1 - c2 * x108 * x1 - cb * x1 - c4) / c3  # (33)
    dx2 = (ddv - (2.0 * c1 * x1 + 1.8 * c2 * x108 + cb) * dv) / c3  # (31): dp_i/dt the trajectory needs
    w = vh.engine_speed(x1, ratio, c)
    dw = vh.engine_speed(dv, ratio, c)
    unlocked = extended and not vh.converter_locked(gear, x1, c)
    if unlocked:
        force = vh.wheel_force(x1, dv, c)
        if force > 0.0:
            w_p, dw_p, t_p, brake = rules.converter_point(force, w, dw, ratio, c)
            cm18_p = en.speed_power(w_p, c)
            p = en.intake_pressure_for_torque(t_p, w_p, c, cm18_p)
            u = en.throttle_for_pressure_rate(p, 0.0, w_p, c)
            return p, u, w_p, dw_p, w, t_p, brake, rules.CLUTCH_CONVERTER, moving, 1.0, cm18_p
    if extended and rules.clutch_engaged(w, c) and not unlocked:  # the accessories' torque on top
        tpp = en.torque_per_pressure(w, c)
        x2 += en.accessory_torque(w, c) / tpp
        dx2 += en.accessory_torque_rate(w, dw, c) / tpp
    u = en.throttle_for_pressure_rate(x2, dx2, w, c)  # (30),(32)
    # c_m^1.8 of (5) at w = i x1 / r: the gear's factor (coef[6]) times x1^1.8 = x1 x1^0.8, no further power
    cm18 = coef[6] * x1 * x108
    t_cr = en.crank_torque(x2, w, c, cm18)
    if not extended:
        return x2, u, w, dw, w, t_cr, 0.0, rules.CLUTCH_ENGAGED, moving, 1.0, cm18
    if rules.clutch_engaged(w, c) and not unlocked:
        # the closed-throttle torque bounded first (no Newton solve where the demand is above the bound)
        if t_cr >= en.crank_torque(p_closed_max, w, c, cm18):
            return x2, u, w, dw, w, t_cr, 0.0, rules.CLUTCH_ENGAGED, moving, 1.0, cm18
        p_closed, _ = en.steady_pressure(c.min_throttle_area, w, c)
        t_closed = en.crank_torque(p_closed, w, c, cm18)
        if t_cr < t_closed:  # beyond engine braking: the engine on the closed-throttle line, brakes the rest
            t_eng, brake, fired = rules.engine_braking(t_cr, t_closed, p_closed, w, ratio, c, cm18)
            u_closed = c.min_throttle_area
            return p_closed, u_closed, w, dw, w, t_eng, brake, rules.CLUTCH_ENGAGED, moving, fired, cm18
        return x2, u, w, dw, w, t_cr, 0.0, rules.CLUTCH_ENGAGED, moving, 1.0, cm18
    # below idle speed: the clutch slips (engine at idle passes the wheel torque) or the engine idles (so
    # too behind an unlocked converter without traction)
    force = vh.wheel_force(x1, dv, c)
    traction = force > 0.0
    t_c = (
        vh.wheel_to_engine_torque(force, ratio, c) + en.accessory_torque(c.idle_speed, c) if traction else 0.0
    )
    w_idle = c.idle_speed
    p = en.intake_pressure_for_torque(t_c, w_idle, c, c.idle_speed_power)
    dp = 0.0
    if traction:  # p_i is affine in T_cr at fixed speed: dp_i/dt = dp_i/dT_cr dT_clutch/dt
        dt_c = vh.wheel_to_engine_torque(vh.wheel_force_rate(x1, dv, ddv, c), ratio, c)
        dp = dt_c / en.torque_per_pressure(w_idle, c)
    u_idle = en.throttle_for_pressure_rate(p, dp, w_idle, c)
    brake = -force if force < 0.0 else 0.0
    return p, u_idle, w_idle, 0.0, w, t_c, brake, rules.CLUTCH_SLIPPING, moving, 1.0, c.idle_speed_power


@inline
def _speed_power08(v):
    """max(v, 0)^0.8, as (33) takes it."""
    x1 = v if v > 0.0 else 0.0
    return x1**0.8


@kernel
def speed_powers(v, out):
    """:func:`_speed_power08` of every point's v into ``out``: a power per point the trajectory fixes, so
    runs of any design on one trajectory share it (:func:`_trajectory`)."""
    for k in range(v.size):
        out[k] = _speed_power08(v[k])


@kernel
def invert_points(v, dv, ddv, x108, gear, ratios, coef, extended, recs, rows):
    """:func:`invert_point` at every point (gear 1-based) into ``rows``; False if a gear does not exist.
    ``x108``: :func:`speed_powers` of v."""
    c = recs[0]
    for k in range(v.size):
        if not (1 <= gear[k] <= ratios.size):
            return False
    p_closed_max = en.closed_throttle_pressure_bound(c)
    for k in range(v.size):
        g = gear[k] - 1
        p, u, w_e, dw_e, w, t_cr, brake, clutch, moving, fired, cm18 = invert_point(
            v[k], dv[k], ddv[k], x108[k], ratios[g], g + 1, coef[g], extended, p_closed_max, c
        )
        rows[R_P, k] = p
        rows[R_U, k] = u
        rows[R_WENG, k] = w_e
        rows[R_DWENG, k] = dw_e
        rows[R_W, k] = w
        rows[R_TCR, k] = t_cr
        rows[R_MDOT, k] = fired * en.fuel_flow(p, w_e, c)  # fuel cut-off: the fired cylinders' part
        rows[R_BRAKE, k] = brake
        rows[R_CLUTCH, k] = clutch
        rows[R_MOVING, k] = 1.0 if moving else 0.0
        rows[R_FIRED, k] = fired
        rows[R_CM18, k] = cm18
    return True


def gear_coefficients(params) -> np.ndarray:
    """Per gear: c1..c4 of (21) (:func:`vpsim.model.vehicle.statespace_coefficients`), the rolling part of
    c4, m g c_r / m_eq (removed at standstill), the coast-down B's term and c_m^1.8 of (5) per unit of
    vehicle speed (:func:`vpsim.model.engine.speed_power` at i / r); computed once per parameter set."""
    return memo(params, "inverse_gear_coefficients", _gear_coefficients)


def _gear_coefficients(params) -> np.ndarray:
    c = record(params)
    r = total_ratios(params.transmission)
    coef = np.empty((r.size, 7))
    coef[:, :4] = np.column_stack(np.broadcast_arrays(*vh.statespace_coefficients(r, c)[:4]))
    coef[:, 4], coef[:, 5] = vh.rolling_coefficients(r, c)
    coef[:, 6] = en.speed_power(vh.engine_speed(1.0, r, c), c)  # c_m^1.8 per unit of vehicle speed
    coef.flags.writeable = False
    return coef


def invert(v, dv, ddv, gear, params, mode: str = "paper") -> dict[str, np.ndarray]:
    """The algebraic inversion at points (v_d, dv_d/dt, d2v_d/dt2, engaged gear 1..n) (1-D arrays).

    Returns arrays: intake pressure, throttle demand u_d, engine speed and acceleration, wheel-side speed,
    crank torque, fuel flow, brake force, clutch state and the moving flag. ``mode`` as in the module
    docstring.
    """
    mode = rules.canonical_mode(mode)
    v, dv, ddv = (np.ascontiguousarray(x, dtype=float) for x in (v, dv, ddv))
    gear = np.ascontiguousarray(gear, dtype=np.int64)
    rows = np.empty((N_ROWS, v.size))
    x108 = np.empty(v.size)
    speed_powers(v, x108)
    v, dv, ddv, x108, gear = _read_only(v, dv, ddv, x108, gear)  # (the kernels' one signature)
    ok = invert_points(
        v,
        dv,
        ddv,
        x108,
        gear,
        total_ratios(params.transmission),
        gear_coefficients(params),
        mode == "realistic",
        kernel_records(params),
        rows,
    )
    if not ok:
        raise VpsimError(f"gear numbers must be 1..{params.transmission.n_gears}")
    out = dict(zip(_ROW_KEYS, rows[: len(_ROW_KEYS)], strict=True))
    out["clutch_engaged"] = rows[R_CLUTCH] == rules.CLUTCH_ENGAGED
    out["moving"] = rows[R_MOVING] != 0.0
    return out


# --- bookkeeping: fuel, energy, feasibility, tracking (trapezoid over the grid) --------------------------

# results of account(): the energy terms (rules.ENERGY_TERMS order), then these
_A_FUEL = rules.N_TERMS
(_A_DIST, _A_BELOW, _A_ABOVE, _A_STAND, _A_BRAKED, _A_UMIN, _A_UMAX, _A_ERR2, _A_WSUM, _A_OUT, _A_ERRMAX) = (
    range(_A_FUEL + 1, _A_FUEL + 12)
)
N_ACC = _A_FUEL + 12


@kernel
def account(v, dv, vc, rows, left, right, dt, recs, realistic, band, weight, acc, extra):
    """Fuel, distance, energy terms (trapezoid), infeasible and standstill seconds and the tracking figures
    of the grid's points in one pass; ``extra`` (3 x n samples): engine torque (1), throttle area (u_d
    clipped to [A_min, A_max]) and the fuel flow booked (idle floor) at the first points.

    The trapezoid sums are sums over the points of weight x integrand, ``weight`` (scratch, one per point)
    being the time each point stands for.
    """
    c = recs[0]
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
    for k in range(n):
        wk = weight[k]
        x = v[k] if v[k] > 0.0 else 0.0
        clutch = int(rows[R_CLUTCH, k])
        t_cr = rows[R_TCR, k]
        mdot = rows[R_MDOT, k]
        brake = rows[R_BRAKE, k]
        moving = rows[R_MOVING, k] != 0.0
        fired = rows[R_FIRED, k]
        used = rules.fuel_used(mdot, fired, c)
        pw = rules.powers(
            rows[R_P, k],
            rows[R_WENG, k],
            rows[R_DWENG, k],
            t_cr,
            0.0,
            rows[R_W, k],
            x,
            dv[k],
            brake,
            clutch,
            fired,
            rules.accessories_torque(rows[R_WENG, k], realistic, c),
            1.0,
            c,
            rows[R_CM18, k],
        )
        acc[0] += wk * pw[0]
        acc[1] += wk * pw[1]
        acc[2] += wk * pw[2]
        acc[3] += wk * pw[3]
        acc[4] += wk * pw[4]
        acc[5] += wk * pw[5]
        acc[6] += wk * pw[6]
        acc[7] += wk * pw[7]
        acc[8] += wk * pw[8]
        acc[9] += wk * pw[9]
        acc[10] += wk * pw[10]
        acc[11] += wk * pw[11]
        acc[_A_FUEL] += wk * used
        acc[_A_DIST] += wk * x
        u = rows[R_U, k]
        err = abs(v[k] - vc[k])
        if err > acc[_A_ERRMAX]:
            acc[_A_ERRMAX] = err
        if moving:
            n_moving += 1
            if brake <= 0.0 and not (u >= c.min_throttle_area):  # (NaN counts as infeasible)
                acc[_A_BELOW] += wk
            if u > en.max_command(c):  # (a boosted engine's command goes on to full boost)
                acc[_A_ABOVE] += wk
            if not math.isnan(u):
                n_moving_u += 1
                acc[_A_UMIN] = min(acc[_A_UMIN], u)
                acc[_A_UMAX] = max(acc[_A_UMAX], u)
        else:
            acc[_A_STAND] += wk
        if brake > 0.0:
            acc[_A_BRAKED] += wk
        acc[_A_ERR2] += wk * err * err
        acc[_A_WSUM] += wk
        if err > band:
            acc[_A_OUT] += wk
        if k < extra.shape[1]:
            if clutch == rules.CLUTCH_ENGAGED or clutch == rules.CLUTCH_CONVERTER:
                extra[0, k] = vh.engine_torque(t_cr, rows[R_DWENG, k], c)
            else:
                extra[0, k] = rules.slipping_clutch_torque(t_cr)
            extra[1, k] = min(max(u, c.min_throttle_area), c.max_throttle_area) if u == u else u  # the area
            extra[2, k] = used
    if n_moving_u == 0:  # as np.nanmin / np.nanmax of the moving points' demands
        acc[_A_UMIN] = 0.0 if n_moving == 0 else math.nan
        acc[_A_UMAX] = acc[_A_UMIN]


def _subdivided(cycle, max_step: float):
    """:func:`vpsim.cycles.resample.subdivide` of the cycle to the step cap, kept on the (immutable) cycle
    per step: every run on it shares the result (read-only arrays)."""
    return memo(
        cycle,
        f"inverse_subdivided_{max_step!r}",
        lambda cyc: readonly(subdivide(cyc.time_s, cyc.speed_mps, max_step)),
    )


def run(
    cycle,
    params,
    *,
    driver="1",
    schedule: GearSchedule | None = None,
    mode: str = "paper",
    a: float | None = None,
    keep_series: bool = True,
) -> Result:
    """Run the IDM on ``cycle`` with the smoothing driver ``driver`` (half-width ``a`` overrides it)."""
    mode = rules.canonical_mode(mode)
    driver = str(driver)
    a = params.driver(driver).inverse_a if a is None else float(a)
    if not (math.isfinite(a) and a > 0.0):
        raise VpsimError(f"smoothing half-width a = {a:g} s must be positive")
    if schedule is None:
        schedule = schedule_for(cycle, params)
    c = kernel_records(params)
    ratios = total_ratios(params.transmission)
    coef = gear_coefficients(params)
    extended = mode == "realistic"
    n_s = cycle.time_s.size
    stop_start = params.simulation.stop_start

    def passes(time_s, speed, keep):
        # on a uniform grid the smoothing is a discrete convolution with 2a/dt + 1 taps; past MAX_TAPS (a very
        # fine grid or a very wide kernel) the window-by-window evaluation keeps the memory bounded
        kept = _kept_trajectory(time_s, speed, schedule, a)  # (a uniform grid's, as below)
        if kept is not None or (_is_uniform_compiled(time_s) and a / (time_s[1] - time_s[0]) <= MAX_TAPS / 2):
            F, I, x108 = kept or _trajectory(time_s, speed, schedule, a)
            n = time_s.size - 1
            t, v, dv, ddv, gear = F[0], F[1], F[2], F[3], I[0]
            left, right, gear_s, dt, v_c = I[1, :n], I[2, :n], I[4, : n + 1], F[5, :n], F[4]
        else:
            t, gear, left, right, sample = evaluation_grid(Cycle("grid", time_s, speed), schedule)
            v, dv, ddv = SmoothingDriver(time_s, speed, a).evaluate(t)
            gear_s = schedule.gear_at(t[: time_s.size])
            dt, v_c = np.diff(time_s), speed[sample]
            x108 = np.empty(v.size)
            speed_powers(v, x108)
            # read-only views, as the kept trajectory's: the kernels compiled for one signature
            t, v, dv, ddv, x108, gear, left, right, dt, v_c = _read_only(
                t, v, dv, ddv, x108, np.ascontiguousarray(gear, dtype=np.int64), left, right, dt, v_c
            )
        rows = np.empty((N_ROWS, t.size))
        if not invert_points(v, dv, ddv, x108, gear, ratios, coef, extended, c, rows):
            raise VpsimError(f"gear numbers must be 1..{params.transmission.n_gears}")
        stopped, starts = _stop_engine_at_rest(t, v, dv, rows) if stop_start else (None, 0)
        acc = np.empty(N_ACC)
        extra = np.empty((3, time_s.size if keep else 0))
        account(v, dv, v_c, rows, left, right, dt, c, extended, BAND_KMH / 3.6, np.empty(t.size), acc, extra)
        if stop_start:
            acc[_A_FUEL] += starts * params.hybrid.engine_start_fuel
        return t, v, dv, ddv, gear_s, v_c, rows, acc, extra, stopped, starts

    if not compiled(invert_points, account, speed_powers):  # compile (or load) outside the timing
        passes(cycle.time_s[:3], cycle.speed_mps[:3], keep_series)
    t_cpu = time.process_time()
    # the paper caps the step at 1 s (simulation.inverse_max_step): longer intervals of a coarse or gappy
    # trace
    # are subdivided, so the trapezoid follows the smoothed speed and the method drives the trace's distance
    time_s, speed, samples = _subdivided(cycle, params.simulation.inverse_max_step)
    t, v, dv, ddv, gear_s, v_c, rows, acc, extra, stopped, starts = passes(time_s, speed, keep_series)
    cpu = time.process_time() - t_cpu
    if samples is not None:  # series at the cycle's own samples
        gear_s, extra = gear_s[samples], extra[:, samples] if keep_series else extra
        stopped = stopped[samples] if stop_start else None
        t, v, dv, ddv, v_c, rows = (
            t[samples],
            v[samples],
            dv[samples],
            ddv[samples],
            v_c[samples],
            rows[:, samples],
        )

    sums = acc.tolist()  # (Python floats, in one call)
    fuel_kg, distance = sums[_A_FUEL], sums[_A_DIST]
    energy = EnergyBalance(*sums[: rules.N_TERMS])  # (rules.ENERGY_TERMS is its field order)
    below_s, above_s = sums[_A_BELOW], sums[_A_ABOVE]
    trace = TraceMiss(
        seconds=below_s + above_s,
        max_speed_error_mps=sums[_A_ERRMAX],
        infeasible_throttle_s=below_s + above_s,
        details={
            "below_min_throttle_s": below_s,
            "above_max_throttle_s": above_s,
            "standstill_s": sums[_A_STAND],
            "braked_s": sums[_A_BRAKED],
            "min_throttle_demand_m2": sums[_A_UMIN],
            "max_throttle_demand_m2": sums[_A_UMAX],
            "rms_speed_error_mps": math.sqrt(sums[_A_ERR2] / sums[_A_WSUM]) if sums[_A_WSUM] > 0 else 0.0,
            "seconds_outside_band": sums[_A_OUT],
            "band_kmh": BAND_KMH,
            "smoothing_a_s": a,
        },
    )
    series = {}
    if keep_series:
        k = slice(0, n_s)
        series = {
            "time_s": t[k],
            "reference_speed_mps": v_c[k],
            "speed_mps": v[k],
            "accel_mps2": dv[k],
            "jerk_mps3": ddv[k],
            "gear": gear_s,
            "gearbox_ratio": gearbox_ratio_series(params, gear_s),
            "engine_speed_radps": rows[R_WENG, k],
            "crank_torque_nm": rows[R_TCR, k],
            "engine_torque_nm": extra[0],
            "intake_pressure_pa": rows[R_P, k],
            "throttle_area_m2": extra[1],
            "throttle_demand_m2": rows[R_U, k],
            "fuel_flow_kgps": rows[R_MDOT, k],
            "fuel_flow_used_kgps": extra[2],
            "brake_force_n": rows[R_BRAKE, k],
            # (read-only zeros: the method meets the max-torque line as a throttle demand beyond A_max)
            "torque_shortfall_nm": memo(cycle, "inverse_zero_series", _zeros),
            "clutch_engaged": rows[R_CLUTCH, k] == rules.CLUTCH_ENGAGED,
        }
        if stop_start:  # the standing engine's samples (as the backward method's)
            for key in ("intake_pressure_pa", "throttle_area_m2", "throttle_demand_m2"):
                series[key] = np.where(stopped[k], np.nan, series[key])
    notes = [f"smoothing a = {a:g} s; {t.size} evaluation points (cycle samples and gear changes), trapezoid"]
    if below_s:
        what = "deceleration beyond engine braking (no brakes)" if mode == "paper" else "manifold too slow"
        notes.append(f"throttle demand below A_min for {below_s:.1f} s while moving: {what}")
    if above_s:
        top = "full boost" if en.is_boosted(record(params)) else "A_max"
        notes.append(f"throttle demand above {top} for {above_s:.1f} s: beyond full load; fuel of the demand")
    if stop_start:
        notes.append(f"stop-start: {starts} engine restarts (where the smoothed car stands)")
    r = Result(
        method="inverse",
        cycle=cycle.name,
        driver=driver,
        mode=mode,
        series=series,
        fuel_kg=fuel_kg,
        distance_m=distance,
        fuel_density_kg_per_l=params.simulation.fuel_density,
        cpu_time_s=cpu,
        steps=int(t.size),
        trace_miss=trace,
        energy=energy,
        vehicle=params.name,
        notes=tuple(notes),
        limits=limits_of(params),
    )
    if stop_start:
        r.solver.update(engine_starts=starts)
    return r


def _stop_engine_at_rest(t, v, dv, rows):
    """Stop-start (``simulation.stop_start``) on the smoothing driver's trajectory: (the points whose engine
    stands, the restarts). The engine stops at the points where the smoothed car is at rest (v and dv/dt
    zero) after it first moved (:func:`vpsim.model.rules.stopped_at_rest`, the points taken as the
    backward method takes intervals); their rows become the standing engine's (no speed, torque, pressure or
    fuel, the clutch open), as the backward method's stopped intervals; ``t`` the points' times (in time
    order, the points make the intervals). The smoothing starts the car moving up to the half-width a
    before the cycle does, and it comes to rest up to a after, so its stops are up to 2a shorter than the
    cycle's, and a stop shorter than 2a has none."""
    order = np.argsort(t, kind="stable")  # (the grid's gear-change points follow the cycle's samples)
    stopped = np.empty(t.size, dtype=bool)
    stopped[order], starts = rules.stopped_at_rest(v[order], dv[order])
    for row in (R_P, R_U, R_WENG, R_DWENG, R_TCR, R_MDOT, R_FIRED, R_BRAKE, R_CM18):
        rows[row, stopped] = 0.0
    rows[R_CLUTCH, stopped] = rules.CLUTCH_OPEN
    return stopped, starts
