"""Compiled hot loops (Numba, cached on disk) of the backward method, one run and many design variants.

The NumPy code in :mod:`vpsim.physics`, :mod:`vpsim.maps` and :mod:`vpsim.methods.backward` is the reference;
these kernels are the same equations written as scalar loops.

* ``backward_single`` (one run) repeats the reference's floating-point operations per interval in the
  reference's order (no ``fastmath``: no reassociation, no fused multiply-add), so its time series equal the
  NumPy path's to an ulp (``pow`` is the C library's here, NumPy's may be a SIMD routine an ulp away). The
  integrals (fuel, distance, every energy term) are summed as the intervals are produced, with Kahan's
  compensation, instead of storing each integrand and summing it afterwards (which halves the memory of a
  run; fresh memory is costly on a virtual machine's first touch): they agree with the reference's pairwise
  ``np.sum`` to a few ulps of the summed magnitudes. Tests: tests/test_kernels.py, to 1e-12.
* ``backward_batch`` (many variants, parallel over them) regroups constants per variant and per gear, and
  evaluates the max-torque line lazily (see :mod:`vpsim.batch`); it agrees with single runs to ~1e-13.

Compilation happens on the first call in a process and is written to Numba's on-disk cache (``cache=True``:
``__pycache__`` beside this file, or ``$NUMBA_CACHE_DIR`` when set); later processes load it. Outputs are
allocated by the caller with NumPy (so they are visible to ``tracemalloc``).

Per-variant constants travel as one row of a float64 array (columns named below, built by
:func:`pack_constants` from the same :mod:`vpsim.physics` expressions the reference uses).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from . import physics as ph

_JIT = {"cache": True, "nogil": True, "error_model": "numpy"}

# --- per-variant constants ------------------------------------------------------------------------------

CONSTANTS = (
    "mass",
    "c_aero",
    "f_roll",
    "radius",
    "radius_sq",
    "eta",
    "j_e",
    "vd",
    "two_pi_nr",
    "stroke",
    "k_f",
    "pi_bl",
    "s_i",
    "y_i",
    "p_e",
    "rt_i",
    "afr_l",
    "q_hv",
    "eta_th",
    "idle_fuel",
    "one_kf",
    "kf0215",
    "q",
    "sq1",
    "yq",
    "p_a",
    "sqrt_rta",
    "crit",
    "psi_choked",
    "g2",
    "e1",
    "e2",
    "e3",
    "e4",
    "a_max",
    "a_min",
    "w_line_end",
    "n_line",
    "fuel_density",
)
(
    MASS,
    C_AERO,
    F_ROLL,
    RADIUS,
    RADIUS_SQ,
    ETA,
    J_E,
    VD,
    TWO_PI_NR,
    STROKE,
    K_F,
    PI_BL,
    S_I,
    Y_I,
    P_E,
    RT_I,
    AFR_L,
    Q_HV,
    ETA_TH,
    IDLE_FUEL,
    ONE_KF,
    KF0215,
    Q,
    SQ1,
    YQ,
    P_A,
    SQRT_RTA,
    CRIT,
    PSI_CHOKED,
    G2,
    E1,
    E2,
    E3,
    E4,
    A_MAX,
    A_MIN,
    W_LINE_END,
    N_LINE,
    FUEL_DENSITY,
) = range(len(CONSTANTS))
N_CONSTANTS = len(CONSTANTS)

IDLE_SPEED = 80.0  # rad/s; the same value as vpsim.methods.backward.IDLE_SPEED (checked by a test)
LINE_SPEED_STEP = 1.0  # rad/s, node spacing of the generated max-torque line (maps.generate_engine_map)
NEWTON_MAX_ITER = 30  # maps.steady_state defaults
NEWTON_RTOL = 1e-12


def pack_constants(vehicle, transmission, engine, simulation) -> np.ndarray:
    """The kernels' constants, shape (n, N_CONSTANTS); attributes may be scalars or arrays of length n.

    Every entry is the Python/NumPy expression the reference evaluates, so scalar parameters give bitwise the
    reference's constants.
    """
    veh, eng, sim = vehicle, engine, simulation
    gamma = eng.specific_heat_ratio
    lo, hi = eng.map_speed_range
    w_max = 1.25 * hi  # maps.generate_engine_map
    cols = {
        "mass": veh.mass,
        "c_aero": 0.5 * veh.drag_coefficient * veh.air_density * veh.frontal_area,
        "f_roll": ph.rolling_force(veh),
        "radius": veh.wheel_radius,
        "radius_sq": veh.wheel_radius**2,
        "eta": transmission.efficiency,
        "j_e": eng.inertia,
        "vd": ph.displacement(eng),
        "two_pi_nr": ph.TWO_PI * eng.revolutions_per_cycle,
        "stroke": eng.stroke,
        "k_f": ph.friction_factor(eng),
        "pi_bl": eng.boost_layout,
        "s_i": eng.air_charge_slope,
        "y_i": eng.air_charge_intercept,
        "p_e": eng.exhaust_pressure,
        "rt_i": eng.gas_constant * eng.intake_temperature,
        "afr_l": eng.stoich_air_fuel_ratio * eng.lambda_,
        "q_hv": eng.fuel_heating_value,
        "eta_th": eng.thermal_efficiency,
        "idle_fuel": sim.idle_fuel_flow,
        "one_kf": 1.0 + 0.0215 * ph.friction_factor(eng),
        "kf0215": ph.friction_factor(eng) * 0.0215,
        "q": ph._q(eng),
        "sq1": eng.air_charge_slope * ph._q(eng) + 1.0,
        "yq": eng.air_charge_intercept * ph._q(eng),
        "p_a": eng.ambient_pressure,
        "sqrt_rta": np.sqrt(eng.gas_constant * eng.ambient_temperature),
        "crit": ph.critical_pressure_ratio(gamma),
        "psi_choked": np.sqrt(gamma * (2.0 / (gamma + 1.0)) ** ((gamma + 1.0) / (gamma - 1.0))),
        "g2": 2.0 * gamma / (gamma - 1.0),
        "e1": 2.0 / gamma,
        "e2": (gamma + 1.0) / gamma,
        "e3": 2.0 / gamma - 1.0,
        "e4": 1.0 / gamma,
        "a_max": eng.max_throttle_area,
        "a_min": eng.min_throttle_area,
        "w_line_end": w_max,
        "n_line": np.round(np.asarray(w_max, dtype=float) / LINE_SPEED_STEP) + 1.0,
        "fuel_density": sim.fuel_density,
    }
    arrays = np.broadcast_arrays(*(np.asarray(cols[k], dtype=float) for k in CONSTANTS))
    return np.ascontiguousarray(np.stack([np.atleast_1d(a) for a in arrays], axis=1))


# --- scalar physics (the reference's expressions, same operation order) ---------------------------------


@njit(**_JIT)
def _speed_friction(w, c):
    """physics._speed_friction: k_f (0.464 + 0.0072 c_m^1.8) pi_bl 1e5."""
    c_m = abs(c[STROKE] * w / math.pi)
    return c[K_F] * (0.464 + 0.0072 * c_m**1.8) * c[PI_BL] * 1e5


@njit(**_JIT)
def _intake_pressure(t_cr, sf, c):
    """physics.intake_pressure_for_torque (the BQM's closed-form root); sf = _speed_friction(w_e)."""
    bmep = t_cr * c[TWO_PI_NR] / c[VD]
    rhs = bmep * c[ONE_KF] + sf + c[P_E] + c[YQ]
    return rhs / c[SQ1]


@njit(**_JIT)
def _fuel_flow(p, w, c):
    """physics.fuel_flow: (w / 2 pi n_r) (s_i p - y_i) V_d / (R T_i) / ((A/F)_s lambda)."""
    return (w / c[TWO_PI_NR]) * ((c[S_I] * p - c[Y_I]) * c[VD] / c[RT_I] / c[AFR_L])


@njit(**_JIT)
def _fmep(p, sf, c):
    """physics.fmep; sf = _speed_friction(w_e)."""
    imep = (c[S_I] * p - c[Y_I]) * c[VD] / c[RT_I] / c[AFR_L] * c[Q_HV] * c[ETA_TH] / c[VD]
    bmep = (imep - sf - (c[P_E] - p)) / c[ONE_KF]
    return sf + c[KF0215] * bmep


@njit(**_JIT)
def _crank_torque(p, w, c):
    """physics.crank_torque: BMEP V_d / (2 pi n_r)."""
    sf = _speed_friction(w, c)
    imep = (c[S_I] * p - c[Y_I]) * c[VD] / c[RT_I] / c[AFR_L] * c[Q_HV] * c[ETA_TH] / c[VD]
    bmep = (imep - sf - (c[P_E] - p)) / c[ONE_KF]
    return bmep * c[VD] / c[TWO_PI_NR]


@njit(**_JIT)
def _psi(p_r, c):
    """physics.psi (flow function (12),(13))."""
    if p_r <= c[CRIT]:
        return c[PSI_CHOKED]
    pr = min(max(p_r, c[CRIT]), 1.0)
    return math.sqrt(max(c[G2] * (pr ** c[E1] - pr ** c[E2]), 0.0))


@njit(**_JIT)
def _dpsi(p_r, c):
    """physics.dpsi_dpr."""
    if p_r <= c[CRIT]:
        return 0.0
    pr = min(max(p_r, c[CRIT]), 1.0 - 1e-15)
    f = c[G2] * (pr ** c[E1] - pr ** c[E2])
    df = c[G2] * (c[E1] * pr ** c[E3] - c[E2] * pr ** c[E4])
    return df / (2.0 * math.sqrt(max(f, 1e-300)))


@njit(**_JIT)
def steady_pressure(a_eff, w, c):
    """maps.steady_state for one (A_eff, w_e): choked-flow check, else Newton on theta(p_i) = 0 (19)."""
    p_a = c[P_A]
    if not w > 0.0:
        return p_a
    mdot_choked = p_a * a_eff * c[PSI_CHOKED] / c[SQRT_RTA]
    p_choked = (mdot_choked * c[TWO_PI_NR] * c[RT_I] / (w * c[VD]) + c[Y_I]) / c[S_I]
    if p_choked / p_a <= c[CRIT]:
        return p_choked
    x = min(p_choked, p_a * (1.0 - 1e-9))
    k_cyl = w * c[VD] / (c[TWO_PI_NR] * c[RT_I])
    k_thr = p_a * a_eff / c[SQRT_RTA]
    lo = c[CRIT] * p_a
    hi = p_a * (1.0 - 1e-15)
    for _ in range(NEWTON_MAX_ITER):
        pr = x / p_a
        theta = k_thr * _psi(pr, c) - k_cyl * (c[S_I] * x - c[Y_I])
        dtheta = k_thr * _dpsi(pr, c) / p_a - k_cyl * c[S_I]
        x_new = min(max(x - theta / dtheta, lo), hi)
        done = abs(x_new - x) <= NEWTON_RTOL * abs(x_new)
        x = x_new
        if done:
            break
    return x


# --- table look-ups (numpy.interp and maps.bilinear semantics) ------------------------------------------


@njit(**_JIT)
def _inv_spacing(xg):
    """(len(xg) - 1) / (xg[-1] - xg[0]): index per unit of a uniform grid, used to guess where x falls."""
    return (xg.size - 1) / (xg[xg.size - 1] - xg[0])


@njit(**_JIT)
def _guess(xg, x, inv_dx):
    """Interval index a uniform grid would give for x, clipped to 0..len(xg) - 2 (a start for the walks)."""
    g = (x - xg[0]) * inv_dx
    if not g > 0.0:  # also NaN
        return 0
    return min(int(g), xg.size - 2)


@njit(**_JIT)
def _interp(x, xp, fp, inv_dx):
    """numpy.interp(x, xp, fp) for one x: end values held outside, exact at nodes, same slope arithmetic.

    The interval is found by walking from the uniform-grid guess, exact for any increasing grid.
    """
    n = xp.size
    if x < xp[0]:
        return fp[0]
    if x >= xp[n - 1]:
        return fp[n - 1]
    j = _guess(xp, x, inv_dx)
    while j > 0 and xp[j] > x:
        j -= 1
    while xp[j + 1] <= x:
        j += 1
    if xp[j] == x:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    return slope * (x - xp[j]) + fp[j]


@njit(**_JIT)
def _cell(xg, x, inv_dx):
    """clip(numpy.searchsorted(xg, x) - 1, 0, len(xg) - 2), as maps.bilinear computes it."""
    last = xg.size - 2
    j = _guess(xg, x, inv_dx)
    while j > 0 and xg[j] >= x:
        j -= 1
    while j < last and xg[j + 1] < x:
        j += 1
    return j


@njit(**_JIT)
def _bilinear(xg, yg, table, x, y, inv_dx, inv_dy):
    """maps.bilinear for one point (linear extrapolation outside the grid)."""
    i = _cell(xg, x, inv_dx)
    j = _cell(yg, y, inv_dy)
    tx = (x - xg[i]) / (xg[i + 1] - xg[i])
    ty = (y - yg[j]) / (yg[j + 1] - yg[j])
    f00 = table[i, j]
    f01 = table[i, j + 1]
    f10 = table[i + 1, j]
    f11 = table[i + 1, j + 1]
    return (1 - tx) * ((1 - ty) * f00 + ty * f01) + tx * ((1 - ty) * f10 + ty * f11)


# --- one backward run ----------------------------------------------------------------------------------

# rows of the per-interval series filled by backward_single
(S_TIME, S_V, S_A, S_W, S_DW, S_TCR, S_TE, S_SHORT, S_MDOT, S_MDOT_USED, S_P, S_BRAKE, S_COUPLED) = range(13)
N_SERIES = 13
# entries of the results filled by backward_single: the integrals (compensated sums over the intervals; in
# extended mode the six from I_INDICATED on run over the coupled intervals only, as in the reference), the
# seconds of trace miss, the largest torque shortfall and the largest speed deficit over a contiguous miss
(
    I_FUEL,
    I_DIST,
    I_VEHICLE_KIN,
    I_AERO,
    I_ROLLING,
    I_BRAKE,
    I_SLIP,
    I_INDICATED,
    I_FRICTION,
    I_PUMPING,
    I_ENGINE_KIN,
    I_DRIVELINE,
    I_TRACE,
    R_MISS_S,
    R_MAX_SHORT,
    R_DEFICIT,
) = range(16)
N_SUMS = 14  # I_FUEL .. R_MISS_S
N_RESULTS = 16


@njit(**_JIT)
def _kahan(acc, k, x):
    """acc[k] += x with Kahan's compensation carried in acc[N_RESULTS + k] (error ~1 ulp of the sum)."""
    y = x - acc[N_RESULTS + k]
    t = acc[k] + y
    acc[N_RESULTS + k] = (t - acc[k]) - y
    acc[k] = t


@njit(**_JIT)
def _gears_on_cycle(time_s, sched_t, sched_gear, out):
    """gears.GearSchedule.on_cycle(cycle)[:-1] into ``out``: the schedule's gears held piecewise constant."""
    n = out.size
    same = sched_t.size == time_s.size
    if same:
        for k in range(time_s.size):
            if sched_t[k] != time_s[k]:
                same = False
                break
    if same:
        for k in range(n):
            out[k] = sched_gear[k]
        return
    last = sched_gear.size - 1
    for k in range(n):
        j = np.searchsorted(sched_t, time_s[k], side="right") - 1
        out[k] = sched_gear[min(max(j, 0), last)]


@njit(**_JIT)
def _interval(time_s, speed, k, i, c):
    """dt, mean speed, acceleration, aero force, rolling force, wheel force of interval k (backward.run)."""
    dt = time_s[k + 1] - time_s[k]
    v = 0.5 * (speed[k + 1] + speed[k])
    a = (speed[k + 1] - speed[k]) / dt
    aero = c[C_AERO] * v * abs(v)
    roll = c[F_ROLL] if v > 0 else 0.0
    f_req = c[MASS] * a + aero + roll  # (18)
    return dt, v, a, aero, roll, f_req


@njit(**_JIT)
def backward_single(
    time_s,
    speed,
    sched_t,
    sched_gear,
    ratios,
    c,
    extended,
    exact,
    map_speed,
    map_torque,
    table,
    line_speed,
    line_max,
    line_min,
    gear,
    series,
    results,
):
    """The backward method on one cycle (methods.backward.run, NumPy reference), per interval.

    ``sched_t``, ``sched_gear``: the gear schedule (GearSchedule.time_s, .gear; gears.GearSchedule.on_cycle
    semantics); ``ratios``: total ratio per gear. Fills ``gear`` (engaged gear per interval), ``series``
    (N_SERIES x n) and ``results`` (N_RESULTS; the sums compensated, so they agree with the reference's
    pairwise np.sum to a few ulps of the summed magnitudes).
    """
    n = gear.size
    r = c[RADIUS]
    eta = c[ETA]
    j_e = c[J_E]
    idle = c[IDLE_FUEL]
    inv_line = _inv_spacing(line_speed)
    inv_ms = _inv_spacing(map_speed)
    inv_mt = _inv_spacing(map_torque)
    _gears_on_cycle(time_s, sched_t, sched_gear, gear)
    acc = np.zeros(2 * N_RESULTS)  # sums and their compensations
    max_short = 0.0
    best = 0.0
    cur = 0.0
    for k in range(n):
        i = ratios[gear[k] - 1]
        dt, v, a, aero, roll, f_req = _interval(time_s, speed, k, i, c)
        w_e = i * v / r  # (14),(17)
        dw_e = i * a / r
        t_req = f_req * r / (i * eta) + j_e * dw_e  # (15),(16),(1)
        brake = 0.0
        coupled = True
        slip = False
        if extended:
            t_min = _interp(w_e, line_speed, line_min, inv_line)
            excess = min(t_req - t_min, 0.0)
            brake = -excess * i * eta / r
            t_req = max(t_req, t_min)
            low = w_e < IDLE_SPEED
            slip = low and f_req > 0
            openc = low and not slip
            if slip:
                t_req = f_req * r / (i * eta)
            if low:
                w_e = IDLE_SPEED
                dw_e = 0.0
            if openc:
                brake = max(-f_req, 0.0)
                t_req = 0.0
            elif slip:
                brake = 0.0
            coupled = not openc
        t_max = _interp(w_e, line_speed, line_max, inv_line)
        short = max(t_req - t_max, 0.0)
        t_cr = t_req - short
        sf = _speed_friction(w_e, c)
        p = _intake_pressure(t_cr, sf, c)
        if exact:
            mdot = _fuel_flow(p, w_e, c)
        else:
            mdot = _bilinear(map_speed, map_torque, table, w_e, t_cr, inv_ms, inv_mt)
        if not coupled:
            mdot = idle
        mdot_used = max(mdot, idle)
        if short > max_short:
            max_short = short
        if short > 1e-9:  # a trace miss: the speed the engine could not give accumulates over the run
            _kahan(acc, R_MISS_S, dt)
            m_eq = c[MASS] + j_e * (i * i) * eta / c[RADIUS_SQ]
            cur = cur + short * i * eta / (r * m_eq) * dt
            best = max(best, cur)
        else:
            cur = 0.0
        cps = (w_e / c[TWO_PI_NR]) * c[VD]
        series[S_TIME, k] = 0.5 * (time_s[k + 1] + time_s[k])
        series[S_V, k] = v
        series[S_A, k] = a
        series[S_W, k] = w_e
        series[S_DW, k] = dw_e
        series[S_TCR, k] = t_cr
        series[S_TE, k] = t_cr - j_e * dw_e
        series[S_SHORT, k] = short
        series[S_MDOT, k] = mdot
        series[S_MDOT_USED, k] = mdot_used
        series[S_P, k] = p
        series[S_BRAKE, k] = brake
        series[S_COUPLED, k] = 1.0 if coupled else 0.0
        _kahan(acc, I_FUEL, mdot_used * dt)
        _kahan(acc, I_DIST, v * dt)
        _kahan(acc, I_VEHICLE_KIN, c[MASS] * v * a * dt)
        _kahan(acc, I_AERO, aero * v * dt)
        _kahan(acc, I_ROLLING, roll * v * dt)
        _kahan(acc, I_BRAKE, brake * v * dt)
        if slip:
            _kahan(acc, I_SLIP, (f_req * r / (i * eta)) * (IDLE_SPEED - i * v / r) * dt)
        if coupled:
            _kahan(acc, I_INDICATED, mdot * c[Q_HV] * c[ETA_TH] * dt)
            _kahan(acc, I_FRICTION, _fmep(p, sf, c) * cps * dt)
            _kahan(acc, I_PUMPING, (c[P_E] - p) * cps * dt)
            _kahan(acc, I_ENGINE_KIN, j_e * w_e * dw_e * dt)
            _kahan(acc, I_DRIVELINE, (1 - eta) * (t_cr + short - j_e * dw_e) * w_e * dt)
            _kahan(acc, I_TRACE, short * w_e * dt)
    for q in range(N_SUMS):
        results[q] = acc[q]
    results[R_MAX_SHORT] = max_short
    results[R_DEFICIT] = best


# --- many variants --------------------------------------------------------------------------------------

# columns of the per-variant output of backward_batch
B_FUEL, B_MISS_S, B_MAX_SHORT, B_DEFICIT = range(4)
N_BATCH_OUT = 4


@njit(**_JIT)
def _line_node_speed(j, n_line, w_end):
    """Node j of numpy.linspace(0, w_end, n_line) (the last node is w_end exactly)."""
    if j >= n_line - 1:
        return w_end
    return j * (w_end / (n_line - 1))


@njit(**_JIT)
def _line_value(j, a_eff, cache, n_line, w_end, c):
    """FQM crank torque at line node j for throttle area a_eff, computed on first use and cached."""
    val = cache[j]
    if val != val:  # NaN: not yet computed
        w = _line_node_speed(j, n_line, w_end)
        val = _crank_torque(steady_pressure(a_eff, w, c), w, c)
        cache[j] = val
    return val


@njit(**_JIT)
def _line_interp(w, a_eff, cache, n_line, w_end, c):
    """numpy.interp(w, line speeds, line torques) with the line's nodes computed lazily."""
    if w < 0.0:
        return _line_value(0, a_eff, cache, n_line, w_end, c)
    if w >= w_end:
        return _line_value(n_line - 1, a_eff, cache, n_line, w_end, c)
    step = w_end / (n_line - 1)
    j = min(int(w / step), n_line - 2)
    # move j so that node j <= w < node j+1 with the nodes exactly as linspace computes them
    while j > 0 and _line_node_speed(j, n_line, w_end) > w:
        j -= 1
    while _line_node_speed(j + 1, n_line, w_end) <= w:
        j += 1
    x0 = _line_node_speed(j, n_line, w_end)
    f0 = _line_value(j, a_eff, cache, n_line, w_end, c)
    if x0 == w:
        return f0
    x1 = _line_node_speed(j + 1, n_line, w_end)
    f1 = _line_value(j + 1, a_eff, cache, n_line, w_end, c)
    slope = (f1 - f0) / (x1 - x0)
    return slope * (w - x0) + f0


@njit(**_JIT)
def _batch_one(c, rat, gear, dt, v, a, v18, vmax_gear, extended, out):
    """One variant of backward_batch: the BQM in closed form, lines of its own engine evaluated lazily."""
    n = gear.size
    n_g = rat.size
    r = c[RADIUS]
    eta = c[ETA]
    j_e = c[J_E]
    idle = c[IDLE_FUEL]
    n_line = int(c[N_LINE])
    w_end = c[W_LINE_END]
    step = w_end / (n_line - 1)
    # per gear: engine speed per m/s, wheel-to-crank torque factor, speed-friction slope in v^1.8
    w_per_v = np.empty(n_g)
    t_fac = np.empty(n_g)
    sf_v = np.empty(n_g)
    m_eq = np.empty(n_g)
    w_top = IDLE_SPEED if extended else 0.0
    sf0 = c[K_F] * 0.464 * c[PI_BL] * 1e5
    for g in range(n_g):
        w_per_v[g] = rat[g] / r
        t_fac[g] = r / (rat[g] * eta)
        sf_v[g] = c[K_F] * 0.0072 * (c[STROKE] * rat[g] / (math.pi * r)) ** 1.8 * c[PI_BL] * 1e5
        m_eq[g] = c[MASS] + j_e * (rat[g] * rat[g]) * eta / c[RADIUS_SQ]
        w_top = max(w_top, w_per_v[g] * vmax_gear[g])
    # Screening for the max-torque line (see the module notes in vpsim.batch): the line only matters where the
    # demanded intake pressure comes near the wide-open-throttle pressure p_max(w_e), which decreases with
    # w_e; below p_floor = p_max at a node above every speed of the run, less the largest friction rise over
    # a node interval, no point can reach the (interpolated) line and the line is not evaluated.
    j_s = min(int(math.ceil(w_top / step)) + 2, n_line - 1)
    w_s = _line_node_speed(j_s, n_line, w_end)
    p_floor = steady_pressure(c[A_MAX], w_s, c)
    d_f = _speed_friction(w_s, c) - _speed_friction(max(w_s - 2.0 * step, 0.0), c)
    p_screen = p_floor - d_f / c[SQ1] - 1e-7 * c[P_A]
    cache_max = np.full(n_line, np.nan)
    cache_min = np.full(n_line if extended else 1, np.nan)
    to_p = c[TWO_PI_NR] / c[VD] * c[ONE_KF] / c[SQ1]
    p0 = (c[P_E] + c[YQ]) / c[SQ1]
    fuel_k = c[VD] / c[RT_I] / c[AFR_L] / c[TWO_PI_NR]
    sf_idle = _speed_friction(IDLE_SPEED, c)
    fuel = 0.0
    miss_s = 0.0
    max_short = 0.0
    best = 0.0
    cur = 0.0
    for k in range(n):
        g = gear[k]
        vk = v[k]
        ak = a[k]
        f_req = c[MASS] * ak + c[C_AERO] * vk * vk + (c[F_ROLL] if vk > 0 else 0.0)
        w_e = w_per_v[g] * vk
        sf = sf0 + sf_v[g] * v18[k]
        t_req = f_req * t_fac[g] + j_e * (w_per_v[g] * ak)
        coupled = True
        if extended:
            t_min = _line_interp(w_e, c[A_MIN], cache_min, n_line, w_end, c)
            t_req = max(t_req, t_min)
            if w_e < IDLE_SPEED:
                w_e = IDLE_SPEED
                sf = sf_idle
                if f_req > 0:
                    t_req = f_req * t_fac[g]  # slipping clutch: no inertia torque
                else:
                    coupled = False
                    t_req = 0.0
        p = t_req * to_p + sf / c[SQ1] + p0
        if not (w_e <= w_end and p <= p_screen):
            t_max = _line_interp(w_e, c[A_MAX], cache_max, n_line, w_end, c)
            short = max(t_req - t_max, 0.0)
            if short > 0.0:
                p = (t_req - short) * to_p + sf / c[SQ1] + p0
                if short > 1e-9:
                    miss_s += dt[k]
                    max_short = max(max_short, short)
                    cur += short * rat[g] * eta / (r * m_eq[g]) * dt[k]
                    best = max(best, cur)
                else:
                    cur = 0.0
            else:
                cur = 0.0
        else:
            cur = 0.0
        mdot = w_e * fuel_k * (c[S_I] * p - c[Y_I]) if coupled else idle
        fuel += max(mdot, idle) * dt[k]
    out[B_FUEL] = fuel
    out[B_MISS_S] = miss_s
    out[B_MAX_SHORT] = max_short
    out[B_DEFICIT] = best


@njit(parallel=True, **_JIT)
def backward_batch(consts, ratios, schedule_of_variant, gears, vmax_gear, dt, v, a, v18, extended, out):
    """The backward method for many variants at once (parallel over variants).

    consts: (n_var, N_CONSTANTS); ratios: (n_var, n_gears) total ratios; gears: (n_schedules, n) 0-based gear
    per interval; schedule_of_variant: (n_var,) row of ``gears`` each variant follows; vmax_gear:
    (n_schedules, n_gears) largest interval speed driven in each gear; dt, v, a, v18: per interval (step,
    mean speed, acceleration, mean speed^1.8). Fills out (n_var, N_BATCH_OUT).
    """
    for m in prange(consts.shape[0]):
        s = schedule_of_variant[m]
        _batch_one(consts[m], ratios[m], gears[s], dt, v, a, v18, vmax_gear[s], extended, out[m])
