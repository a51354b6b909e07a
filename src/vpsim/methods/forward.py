"""Forward dynamic method (FDM), paper section 2: the model integrated in time with a PI driver.

States: vehicle speed v (18) and intake-manifold pressure p_i (9); the driver's integral state z
(:mod:`vpsim.drivers.pi`); and quadrature states that integrate the fuel, the distance and every term of the
energy balance along the solution, so the bookkeeping closes to the integrator's accuracy:

    fuel = int max(mdot_f, mdot_idle) dt                                    (section 5)
    q_hv eta_th int mdot_f dt = friction + pumping + engine KE + driveline + vehicle KE + aero + rolling
                                + brakes (+ idle control, extended mode)

Right side, per gear (total ratio i; w_e = i v / r):
    dp_i/dt = (R T_i / V_i) [p_a A_eff Psi(p_i/p_a) / sqrt(R T_a) - w_e (s_i p_i - y_i) V_d / (2pi n_r R T_i)]
    m_eq dv/dt = (i eta_tm / r) T_cr(p_i, w_e) - 1/2 c_d rho A v^2 - m g c_r - F_brake,
with T_cr from (2)-(8) solved for BMEP (as :func:`vpsim.physics.crank_torque`), m_eq = m + J_e i² eta_tm / r².

Integrator: Dormand-Prince 5(4), which is what ode45 is, with ode45's error norm (max over the dynamic states
of |error| / max(|y|, |y_new|, threshold)), step-size control (factor 0.8 (rtol/err)^(1/5) after a first
rejection, halving after further ones, growth at most 5x), initial step selection, FSAL and its 4th-order
continuous extension (ode45's ``ntrp45``) for output at the requested times. Gear changes happen at the
prescribed instants: the integration stops exactly there and restarts in the new gear (new initial step).
The default maximum step is Simulink's "auto", a fiftieth of the cycle's duration. The quadrature states do
not enter the error norm (as in CVODES' default), their integrands are smooth where the dynamic states are.
The kernel is plain scalar loops compiled with ``numba.njit(cache=True)``; ``_integrate.py_func`` runs the
very same code in Python (the reference the tests compare against).

Modes (one switch for every method):

* ``paper``: no clutch, no brakes. At standstill w_e = i v / r = 0, so nothing leaves the manifold and even
  the closed throttle's leak A_min fills it: the engine pushes the car forward, pumps the manifold down and
  brakes it again; speed and pressure oscillate and settle into a slow creep with the PI's throttle at its
  limit, and at each launch from rest the throttle oscillates (the plant gain grows like 1/v) — the paper's
  meaningless standstill behaviour. The car does not roll backwards: at v = 0 rolling resistance is static
  friction (it holds up to m g c_r) and v >= 0 is kept (a step that ends below zero is set to zero and the
  FSAL derivative is re-evaluated).
* ``extended``: below the idle speed (:data:`vpsim.methods.backward.IDLE_SPEED`) the clutch slips: the engine
  is held at idle speed with the throttle max(A_driver, A_idle) (A_idle: the steady throttle of zero crank
  torque at idle), and the clutch passes max(T_cr, 0) to the gearbox; the engine inertia is then not coupled.
  Above it the driveline is stiff as in ``paper``. The PI's command continues below zero into the friction
  brakes (:mod:`vpsim.drivers.pi`), which therefore act only once the throttle is closed. The idealised idle
  governor's work when the decoupled engine's torque is negative is the ``idle_control`` energy term.
"""

from __future__ import annotations

import math
import time
import types

import numpy as np
from numba import njit
from numba.extending import register_jitable

from .. import physics as ph
from ..drivers.pi import PIDriver, pedal_split, pi_law
from ..errors import VpsimError
from ..gears import GearSchedule, default_schedule
from ..result import EnergyBalance, Result, TraceMiss
from .backward import IDLE_SPEED

BAND_KMH = 2.0  # the regulation's speed tolerance (UN ECE R83 / EPA: +-2 km/h resp. +-2 mph)

# --- layout of the constants vector P (reciprocals and products precomputed: the right side is latency bound)
(
    _M,
    _INV_M,
    _R,
    _ETA,
    _J,
    _AERO,
    _ROLL,
    _INV_PA,
    _KTHR,
    _GAMMA,
    _PRCRIT,
    _PSICH,
    _KMAN,
    _KCYL,
    _SI,
    _YI,
    _INV_AFR,
    _Q,
    _KF,
    _FS0,
    _FS1,
    _CM,
    _BM,
    _PE,
    _KMEP,
    _QHV,
) = range(26)
_KP, _KI, _ULO, _UHI, _AWG, _AMIN, _KB = range(26, 33)
_EXT, _WIDLE, _AIDLE, _MIDLE, _TAB_INVDT, _OPEN, _BAND = range(33, 40)
N_CONST = 40
# per-gear constants G: i, i / r, i eta_tm / r, 1 / m_eq, J_e i / r
_G_I, _G_KIN, _G_FORCE, _G_INV_MEQ, _G_JW = range(5)

# --- states ---------------------------------------------------------------------------------------------
_V, _P, _Z = 0, 1, 2
_FUEL, _DIST, _E_IND, _E_FRIC, _E_PUMP, _E_ENG, _E_DRV, _E_VEH, _E_AERO, _E_ROLL, _E_BRAKE, _E_IDLE = range(
    3, 15
)
_ERR2, _OUTSIDE = 15, 16  # int (v_cycle - v)^2 dt and the time with |v_cycle - v| above the band
NY = 17
N_ERR = 3  # states in the error norm: v, p_i, z
# states the right side reads (v, p_i, z): the quadrature states' stage values are never used, so the stages
# are formed for these only (the quadratures enter the step through their derivatives k_j alone)
N_DYN = 3

# --- auxiliary outputs ----------------------------------------------------------------------------------
_X_THR, _X_W, _X_TCR, _X_TE, _X_MF, _X_MFU, _X_BRK, _X_ACC, _X_VREF, _X_CMD, _X_COUPLED = range(11)
N_AUX = 11

# --- Dormand-Prince 5(4) tableau -------------------------------------------------------------------------
_C2, _C3, _C4, _C5 = 1.0 / 5.0, 3.0 / 10.0, 4.0 / 5.0, 8.0 / 9.0
_A21 = 1.0 / 5.0
_A31, _A32 = 3.0 / 40.0, 9.0 / 40.0
_A41, _A42, _A43 = 44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0
_A51, _A52, _A53, _A54 = 19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0
_A61, _A62, _A63, _A64, _A65 = (
    9017.0 / 3168.0,
    -355.0 / 33.0,
    46732.0 / 5247.0,
    49.0 / 176.0,
    -5103.0 / 18656.0,
)
_B1, _B3, _B4, _B5, _B6 = 35.0 / 384.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0
_E1, _E3, _E4, _E5, _E6, _E7 = (
    71.0 / 57600.0,
    -71.0 / 16695.0,
    71.0 / 1920.0,
    -17253.0 / 339200.0,
    22.0 / 525.0,
    -1.0 / 40.0,
)
# continuous extension (ode45's ntrp45): y(t + s h) = y + h sum_j k_j (b_j1 s + b_j2 s² + b_j3 s³ + b_j4 s⁴)
_BI = (
    (1.0, -183.0 / 64.0, 37.0 / 12.0, -145.0 / 128.0),
    (0.0, 0.0, 0.0, 0.0),
    (0.0, 1500.0 / 371.0, -1000.0 / 159.0, 1000.0 / 371.0),
    (0.0, -125.0 / 32.0, 125.0 / 12.0, -375.0 / 64.0),
    (0.0, 9477.0 / 3392.0, -729.0 / 106.0, 25515.0 / 6784.0),
    (0.0, -11.0 / 7.0, 11.0 / 3.0, -55.0 / 28.0),
    (0.0, 1.5, -4.0, 2.5),
)
_EPS = 2.220446049250313e-16
STATUS_OK, STATUS_STEP_TOO_SMALL, STATUS_TOO_MANY_STEPS = 0, 1, 2


@register_jitable
def _interp(xs, ys, x, inv_dt):
    """Piecewise-linear interpolation, held constant outside [xs[0], xs[-1]].

    ``inv_dt`` > 0 declares the grid uniform with that inverse spacing (the interval is then found by one
    multiplication instead of a binary search).
    """
    n = xs.size
    if x <= xs[0]:
        return ys[0]
    if x >= xs[n - 1]:
        return ys[n - 1]
    if inv_dt > 0.0:
        k = int((x - xs[0]) * inv_dt)
        if k > n - 2:
            k = n - 2
        return ys[k] + (ys[k + 1] - ys[k]) * ((x - xs[k]) * inv_dt)
    k = np.searchsorted(xs, x, "right") - 1
    return ys[k] + (ys[k + 1] - ys[k]) * (x - xs[k]) / (xs[k + 1] - xs[k])


@register_jitable
def psi_scalar(pr, P):
    """Flow function Psi (12),(13) of one pressure ratio; zero at and above p_r = 1 (no reverse flow)."""
    if pr <= P[_PRCRIT]:
        return P[_PSICH]
    if pr >= 1.0:
        return 0.0
    g = P[_GAMMA]
    lp = math.log(pr)
    f = 2.0 * g / (g - 1.0) * (math.exp(2.0 / g * lp) - math.exp((g + 1.0) / g * lp))
    return math.sqrt(f) if f > 0.0 else 0.0


@register_jitable
def engine_scalar(p, w, P):
    """Engine at (p_i, w_e): cylinder air flow (8), crank torque (2)-(6) solved for BMEP, fuel flow (7).

    Returns (mdot_ac, T_cr, BMEP, speed part of FMEP); scalar form of :mod:`vpsim.physics` for the kernels.
    """
    charge = P[_SI] * p - P[_YI]  # s_i p_i - y_i, proportional to the air charge
    mdot_ac = P[_KCYL] * w * charge
    fric_speed = P[_FS0] + P[_FS1] * (P[_CM] * w) ** 1.8
    bmep = (P[_Q] * charge - fric_speed - (P[_PE] - p)) * P[_BM]
    return mdot_ac, bmep * P[_KMEP], bmep, fric_speed


@register_jitable
def _gear(ratio, P, G):
    """Fill the per-gear constants G for total ratio i."""
    G[_G_I] = ratio
    G[_G_KIN] = ratio / P[_R]
    G[_G_FORCE] = ratio * P[_ETA] / P[_R]
    G[_G_INV_MEQ] = 1.0 / (P[_M] + P[_J] * G[_G_KIN] * G[_G_FORCE])
    G[_G_JW] = P[_J] * G[_G_KIN]


@register_jitable
def _rhs(t, y, G, P, tab_t, tab_v, dy, aux):
    """Right side of model + driver + quadratures at (t, y) with gear constants G; fills ``dy`` and ``aux``.

    The table (tab_t, tab_v) is the cycle speed for the PI driver or, with P[_OPEN] = 1, the throttle area
    fed open loop (not clipped).
    """
    v = y[_V]
    p = y[_P]
    vv = v if v > 0.0 else 0.0
    # driver
    if P[_OPEN] != 0.0:
        cmd = _interp(tab_t, tab_v, t, P[_TAB_INVDT])
        v_ref = vv
        throttle = cmd
        brake = 0.0
        dz = 0.0
    else:
        v_ref = _interp(tab_t, tab_v, t, P[_TAB_INVDT])
        cmd, dz = pi_law(v_ref - vv, y[_Z], P[_KP], P[_KI], P[_ULO], P[_UHI], P[_AWG])
        throttle, brake = pedal_split(cmd, P[_AMIN], P[_KB])
    # driveline kinematics: stiff, or slipping clutch with the engine held at idle (extended mode)
    w_wheel = G[_G_KIN] * vv
    coupled = P[_EXT] == 0.0 or w_wheel >= P[_WIDLE]
    if coupled:
        w = w_wheel
        a_eng = throttle
    else:
        w = P[_WIDLE]
        a_eng = throttle if throttle > P[_AIDLE] else P[_AIDLE]
    # engine: manifold (9),(10), air and fuel charge (7),(8), torque (2)-(6) solved for BMEP
    mdot_ac, t_cr, bmep, fric_speed = engine_scalar(p, w, P)
    dp = P[_KMAN] * (P[_KTHR] * a_eng * psi_scalar(p * P[_INV_PA], P) - mdot_ac)
    mdot_f = mdot_ac * P[_INV_AFR]
    # vehicle (18) with the engine inertia (1),(14)-(17)
    if coupled:
        inv_m = G[_G_INV_MEQ]
        t_clutch = t_cr
    else:
        inv_m = P[_INV_M]
        t_clutch = t_cr if t_cr > 0.0 else 0.0
    f_drive = t_clutch * G[_G_FORCE]
    aero = P[_AERO] * vv * vv
    roll = P[_ROLL]
    if v > 0.0:
        acc = (f_drive - aero - roll - brake) * inv_m
    else:  # standstill: rolling resistance and brakes hold as static friction; no rolling backwards
        hold = roll + brake
        acc = (f_drive - hold) * inv_m if f_drive > hold else 0.0
        roll = 0.0
    dy[_V] = acc
    dy[_P] = dp
    dy[_Z] = dz
    # quadratures: fuel, distance, energy terms (powers, W)
    used = mdot_f if mdot_f > P[_MIDLE] else P[_MIDLE]
    cyc = P[_KMEP] * w  # MEP x this = power
    eta = P[_ETA]
    dy[_FUEL] = used
    dy[_DIST] = vv
    dy[_E_IND] = mdot_f * P[_QHV]
    dy[_E_FRIC] = (fric_speed + P[_KF] * 0.0215 * bmep) * cyc  # FMEP (5)
    dy[_E_PUMP] = (P[_PE] - p) * cyc  # PMEP (6)
    if coupled:
        t_e = t_cr - G[_G_JW] * acc  # (1): T_e = T_cr - J_e dw_e/dt
        dy[_E_ENG] = G[_G_JW] * acc * w
        dy[_E_DRV] = (1.0 - eta) * t_e * w
        dy[_E_IDLE] = 0.0
    else:  # slipping clutch: slip loss T_c (w_idle - w_wheel) counted with the driveline
        t_e = t_clutch
        dy[_E_ENG] = 0.0
        dy[_E_DRV] = (1.0 - eta) * t_clutch * w_wheel + t_clutch * (w - w_wheel)
        dy[_E_IDLE] = (t_cr - t_clutch) * w
    dy[_E_VEH] = P[_M] * vv * acc
    dy[_E_AERO] = aero * vv
    dy[_E_ROLL] = roll * vv
    dy[_E_BRAKE] = brake * vv
    err = v_ref - vv
    dy[_ERR2] = err * err
    dy[_OUTSIDE] = 1.0 if abs(err) > P[_BAND] else 0.0
    aux[_X_THR] = a_eng
    aux[_X_W] = w
    aux[_X_TCR] = t_cr
    aux[_X_TE] = t_e
    aux[_X_MF] = mdot_f
    aux[_X_MFU] = used
    aux[_X_BRK] = brake
    aux[_X_ACC] = acc
    aux[_X_VREF] = v_ref
    aux[_X_CMD] = cmd
    aux[_X_COUPLED] = 1.0 if coupled else 0.0


# the same right side, inlined (at Numba-IR level) into its one call site, the integrator's stage loop: a call
# would pass its seven arrays as some fifty scalars, 53,000 times per UDDS run
_rhs_stage = register_jitable(inline="always")(
    types.FunctionType(_rhs.__code__, _rhs.__globals__, "_rhs_stage", _rhs.__defaults__, _rhs.__closure__)
)


@register_jitable
def _output(t_out, y, h, k1, k3, k4, k5, k6, k7, s, row_y, G, P, tab_t, tab_v, scratch, row_aux):
    """Dense output at t + s h (ntrp45) into ``row_y`` and its auxiliary quantities into ``row_aux``."""
    s2 = s * s
    s3 = s2 * s
    s4 = s3 * s
    w1 = _BI[0][0] * s + _BI[0][1] * s2 + _BI[0][2] * s3 + _BI[0][3] * s4
    w3 = _BI[2][1] * s2 + _BI[2][2] * s3 + _BI[2][3] * s4
    w4 = _BI[3][1] * s2 + _BI[3][2] * s3 + _BI[3][3] * s4
    w5 = _BI[4][1] * s2 + _BI[4][2] * s3 + _BI[4][3] * s4
    w6 = _BI[5][1] * s2 + _BI[5][2] * s3 + _BI[5][3] * s4
    w7 = _BI[6][1] * s2 + _BI[6][2] * s3 + _BI[6][3] * s4
    for i in range(y.size):
        row_y[i] = y[i] + h * (w1 * k1[i] + w3 * k3[i] + w4 * k4[i] + w5 * k5[i] + w6 * k6[i] + w7 * k7[i])
    if row_y[_V] < 0.0:  # v >= 0, as at the step ends
        row_y[_V] = 0.0
    _rhs(t_out, row_y, G, P, tab_t, tab_v, scratch, row_aux)


# _nrt=False: no reference counting of arrays (every call of the right side would otherwise pay for atomic
# increments and decrements of its array arguments, which cost more than the arithmetic); the kernel
# therefore allocates nothing, its scratch space comes in ``work``.
@njit(cache=True, nogil=True, _nrt=False)  # nogil: vpsim.batch runs variants on threads
def _integrate(
    seg_t,
    seg_ratio,
    y0,
    tab_t,
    tab_v,
    P,
    rtol,
    h_max,
    thr,
    max_steps,
    out_t,
    out_y,
    out_aux,
    stats,
    fstats,
    work,
    aux,
    G,
):
    """Dormand-Prince 5(4) from seg_t[0] to seg_t[-1], restarting at every seg_t[k] in gear seg_ratio[k].

    Fills out_y/out_aux at out_t (sorted, within [seg_t[0], seg_t[-1]]); a time equal to a restart instant
    gets the state there with the new gear. stats: [accepted, rejected, rhs evaluations, status];
    fstats: [largest |v_cycle - v| at the step ends].
    ``work`` (11 x len(y0)), ``aux`` (N_AUX) and ``G`` (5) are scratch space; the state reached is left in
    ``work[0]``.
    """
    ny = y0.size
    y = work[0]
    ynew = work[1]
    ytmp = work[2]
    k1 = work[3]
    k2 = work[4]
    k3 = work[5]
    k4 = work[6]
    k5 = work[7]
    k6 = work[8]
    k7 = work[9]
    scratch = work[10]
    for i in range(ny):
        y[i] = y0[i]
    pw = 1.0 / 5.0
    n_out = out_t.size
    j_out = 0
    accepted = 0
    rejected = 0
    nfev = 0
    n_seg = seg_t.size - 1
    for sgi in range(n_seg):
        t = seg_t[sgi]
        t_end = seg_t[sgi + 1]
        _gear(seg_ratio[sgi], P, G)
        last = sgi == n_seg - 1
        _rhs(t, y, G, P, tab_t, tab_v, k1, aux)
        nfev += 1
        while j_out < n_out and out_t[j_out] <= t:
            for i in range(ny):
                out_y[j_out, i] = y[i]
            for i in range(aux.size):
                out_aux[j_out, i] = aux[i]
            j_out += 1
        span = t_end - t
        if span <= 0.0:
            continue
        hmax = h_max if h_max < span else span
        # initial step (ode45)
        rh = 0.0
        for i in range(N_ERR):
            sc = abs(y[i])
            if thr[i] > sc:
                sc = thr[i]
            q = abs(k1[i]) / sc
            if q > rh:
                rh = q
        rh = rh / (0.8 * rtol**pw)
        absh = hmax
        if absh * rh > 1.0:
            absh = 1.0 / rh
        while True:
            hmin = 16.0 * _EPS * abs(t)
            if absh > hmax:
                absh = hmax
            if absh < hmin:
                absh = hmin
            h = absh
            done = False
            if 1.1 * absh >= t_end - t:
                h = t_end - t
                absh = h
                done = True
            nofailed = True
            while True:
                tnew = t_end if done else t + h
                # stages 2..7: the stage state (as the tableau's row), then the right side at it; one call
                # site for the six, so that the right side is compiled inline once
                for st in range(6):
                    tgt = ytmp
                    ts = tnew
                    if st == 0:
                        ts = t + _C2 * h
                        for i in range(N_DYN):
                            ytmp[i] = y[i] + h * (_A21 * k1[i])
                    elif st == 1:
                        ts = t + _C3 * h
                        for i in range(N_DYN):
                            ytmp[i] = y[i] + h * (_A31 * k1[i] + _A32 * k2[i])
                    elif st == 2:
                        ts = t + _C4 * h
                        for i in range(N_DYN):
                            ytmp[i] = y[i] + h * (_A41 * k1[i] + _A42 * k2[i] + _A43 * k3[i])
                    elif st == 3:
                        ts = t + _C5 * h
                        for i in range(N_DYN):
                            ytmp[i] = y[i] + h * (_A51 * k1[i] + _A52 * k2[i] + _A53 * k3[i] + _A54 * k4[i])
                    elif st == 4:
                        for i in range(N_DYN):
                            ytmp[i] = y[i] + h * (
                                _A61 * k1[i] + _A62 * k2[i] + _A63 * k3[i] + _A64 * k4[i] + _A65 * k5[i]
                            )
                    else:
                        tgt = ynew
                        for i in range(ny):
                            ynew[i] = y[i] + h * (
                                _B1 * k1[i] + _B3 * k3[i] + _B4 * k4[i] + _B5 * k5[i] + _B6 * k6[i]
                            )
                    _rhs_stage(ts, tgt, G, P, tab_t, tab_v, work[4 + st], aux)
                nfev += 6
                err = 0.0
                for i in range(N_ERR):
                    e = _E1 * k1[i] + _E3 * k3[i] + _E4 * k4[i] + _E5 * k5[i] + _E6 * k6[i] + _E7 * k7[i]
                    sc = abs(y[i])
                    if abs(ynew[i]) > sc:
                        sc = abs(ynew[i])
                    if thr[i] > sc:
                        sc = thr[i]
                    q = abs(e) / sc
                    if q > err:
                        err = q
                err = absh * err
                if err <= rtol:
                    break
                rejected += 1
                if accepted + rejected >= max_steps:
                    stats[0], stats[1], stats[2], stats[3] = accepted, rejected, nfev, STATUS_TOO_MANY_STEPS
                    return
                if absh <= hmin:
                    stats[0], stats[1], stats[2], stats[3] = accepted, rejected, nfev, STATUS_STEP_TOO_SMALL
                    return
                if nofailed:
                    nofailed = False
                    f = 0.8 * (rtol / err) ** pw
                    absh = absh * (f if f > 0.1 else 0.1)
                else:
                    absh = 0.5 * absh
                if absh < hmin:
                    absh = hmin
                h = absh
                done = False
            accepted += 1
            e_abs = abs(aux[_X_VREF] - (ynew[_V] if ynew[_V] > 0.0 else 0.0))  # aux is from (tnew, ynew)
            if e_abs > fstats[0]:
                fstats[0] = e_abs
            clamped = ynew[_V] < 0.0
            if clamped:  # keep v >= 0 (the car does not roll backwards); the derivative is re-evaluated below
                ynew[_V] = 0.0
            if accepted + rejected >= max_steps:
                stats[0], stats[1], stats[2], stats[3] = accepted, rejected, nfev, STATUS_TOO_MANY_STEPS
                return
            # dense output strictly inside the step (and at its end on the last segment)
            while j_out < n_out and (out_t[j_out] < tnew or (last and out_t[j_out] <= tnew)):
                if out_t[j_out] == tnew:
                    for i in range(ny):
                        out_y[j_out, i] = ynew[i]
                    _rhs(tnew, out_y[j_out], G, P, tab_t, tab_v, scratch, out_aux[j_out])
                else:
                    _output(
                        out_t[j_out],
                        y,
                        h,
                        k1,
                        k3,
                        k4,
                        k5,
                        k6,
                        k7,
                        (out_t[j_out] - t) / h,
                        out_y[j_out],
                        G,
                        P,
                        tab_t,
                        tab_v,
                        scratch,
                        out_aux[j_out],
                    )
                j_out += 1
            t = tnew
            for i in range(ny):
                y[i] = ynew[i]
            for i in range(ny):  # FSAL
                k1[i] = k7[i]
            if clamped:
                _rhs(t, y, G, P, tab_t, tab_v, k1, aux)
                nfev += 1
            if done:
                break
            if nofailed:
                temp = 1.25 * (err / rtol) ** pw
                if temp > 0.2:
                    absh = absh / temp
                else:
                    absh = 5.0 * absh
    stats[0], stats[1], stats[2], stats[3] = accepted, rejected, nfev, STATUS_OK
    return


# --- the method -------------------------------------------------------------------------------------------


def constants(params, pi: PIDriver | None = None, mode: str = "paper") -> np.ndarray:
    """The constants vector P of the compiled kernels (model, driver and mode) from a parameter set.

    Without a driver ``pi`` its entries stay zero (the inverse method uses the model's constants only).
    """
    veh, eng, tr, sim = params.vehicle, params.engine, params.transmission, params.simulation
    g = eng.specific_heat_ratio
    vd = ph.displacement(eng)
    rt_i = eng.gas_constant * eng.intake_temperature
    n_r = eng.revolutions_per_cycle
    k_f = float(ph.friction_factor(eng))
    P = np.zeros(N_CONST)
    P[_M] = veh.mass
    P[_INV_M] = 1.0 / veh.mass
    P[_R] = veh.wheel_radius
    P[_ETA] = tr.efficiency
    P[_J] = eng.inertia
    P[_AERO] = 0.5 * veh.drag_coefficient * veh.air_density * veh.frontal_area
    P[_ROLL] = ph.rolling_force(veh)
    P[_INV_PA] = 1.0 / eng.ambient_pressure
    P[_KTHR] = eng.ambient_pressure / math.sqrt(eng.gas_constant * eng.ambient_temperature)  # (10)
    P[_GAMMA] = g
    P[_PRCRIT] = ph.critical_pressure_ratio(g)  # (11)
    P[_PSICH] = math.sqrt(g * (2.0 / (g + 1.0)) ** ((g + 1.0) / (g - 1.0)))  # (12)
    P[_KMAN] = rt_i / eng.intake_manifold_volume  # (9)
    P[_KCYL] = vd / (ph.TWO_PI * n_r * rt_i)  # (8)/(2 pi n_r)
    P[_SI] = eng.air_charge_slope
    P[_YI] = eng.air_charge_intercept
    P[_INV_AFR] = 1.0 / (eng.stoich_air_fuel_ratio * eng.lambda_)  # (7)
    P[_Q] = ph._q(eng)
    P[_KF] = k_f
    P[_FS0] = k_f * 0.464 * eng.boost_layout * 1e5  # (5)
    P[_FS1] = k_f * 0.0072 * eng.boost_layout * 1e5
    P[_CM] = eng.stroke / math.pi
    P[_BM] = 1.0 / (1.0 + 0.0215 * k_f)
    P[_PE] = eng.exhaust_pressure
    P[_KMEP] = vd / (ph.TWO_PI * n_r)  # (3)
    P[_QHV] = eng.fuel_heating_value * eng.thermal_efficiency
    if pi is not None:
        P[_KP : _KB + 1] = pi.as_array()
    P[_EXT] = 1.0 if mode == "extended" else 0.0
    P[_WIDLE] = IDLE_SPEED
    P[_AIDLE] = idle_throttle(eng)
    P[_MIDLE] = sim.idle_fuel_flow
    P[_BAND] = BAND_KMH / 3.6
    return P


def idle_throttle(eng, w_idle: float = IDLE_SPEED) -> float:
    """Steady throttle area holding the engine at ``w_idle`` with zero crank torque (FQM inverted), m²."""
    p = float(ph.intake_pressure_for_torque(0.0, w_idle, eng))
    flow = float(ph.cylinder_air_flow(p, w_idle, eng))
    unit = float(ph.throttle_mass_flow(1.0, p, eng))  # flow per m² at this pressure
    return flow / unit


def initial_state(cycle, params, ratio: float, pi: PIDriver, mode: str) -> np.ndarray:
    """State at the cycle's start: steady manifold for the cycle's initial speed and acceleration.

    At standstill: ``paper`` starts with the manifold at the pressure of zero crank torque at w_e = 0 and the
    throttle closed; ``extended`` at the idle steady state with a zero pedal command.
    """
    veh, eng, tr = params.vehicle, params.engine, params.transmission
    y = np.zeros(NY)
    v0 = float(cycle.speed_mps[0])
    y[_V] = v0
    if v0 > 0.0:
        a0 = float((cycle.speed_mps[1] - cycle.speed_mps[0]) / (cycle.time_s[1] - cycle.time_s[0]))
        m_eq = ph.equivalent_mass(ratio, veh, eng, tr.efficiency)
        t_cr = (m_eq * a0 + ph.road_load(v0, veh)) * veh.wheel_radius / (ratio * tr.efficiency)
        w = ratio * v0 / veh.wheel_radius
        p = float(ph.intake_pressure_for_torque(t_cr, w, eng))
        p = min(p, 0.99 * eng.ambient_pressure)
        u = float(ph.cylinder_air_flow(p, w, eng) / ph.throttle_mass_flow(1.0, p, eng))
        y[_P] = p
        y[_Z] = float(np.clip(u, pi.u_lo, pi.u_hi))
    elif mode == "paper":
        y[_P] = float(ph.intake_pressure_for_torque(0.0, 0.0, eng))
        y[_Z] = pi.u_lo
    else:
        y[_P] = float(ph.intake_pressure_for_torque(0.0, IDLE_SPEED, eng))
        y[_Z] = 0.0
    return y


ERROR_THRESHOLDS = np.array([1.0, 1.0e4, 1.0e-4])  # v (m/s), p_i (Pa), z (m²): ode45's atol/rtol per state


def integrate(
    seg_t,
    seg_ratio,
    y0,
    P,
    table_t,
    table_v,
    *,
    open_loop=False,
    rtol=1e-3,
    max_step=np.inf,
    out_t=None,
    max_steps=2_000_000,
    compiled=True,
):
    """Run the kernel from seg_t[0] to seg_t[-1], restarting at each seg_t[k] with ratio seg_ratio[k].

    (table_t, table_v) is the cycle speed the PI driver follows or, with ``open_loop``, the throttle area
    fed to the engine as it is. Returns (y_end, out_y, out_aux, info); raises VpsimError if the solver fails.
    """
    out_t = np.array(seg_t[-1:] if out_t is None else out_t, dtype=float)
    out_y = np.full((out_t.size, NY), np.nan)
    out_aux = np.full((out_t.size, N_AUX), np.nan)
    stats = np.zeros(4, dtype=np.int64)
    fstats = np.zeros(1)
    P = np.array(P, dtype=float)
    P[_TAB_INVDT] = _uniform_inverse_spacing(table_t)
    P[_OPEN] = 1.0 if open_loop else 0.0
    fn = _integrate if compiled else _integrate.py_func
    # np.array copies: one compiled signature for all calls (read-only inputs would compile another)
    work = np.zeros((11, NY))
    fn(
        np.array(seg_t, dtype=float),
        np.array(seg_ratio, dtype=float),
        np.array(y0, dtype=float),
        np.array(table_t, dtype=float),
        np.array(table_v, dtype=float),
        P,
        float(rtol),
        float(max_step),
        ERROR_THRESHOLDS,
        int(max_steps),
        out_t,
        out_y,
        out_aux,
        stats,
        fstats,
        work,
        np.empty(N_AUX),
        np.empty(5),
    )
    y_end = work[0].copy()
    if stats[3] == STATUS_STEP_TOO_SMALL:
        raise VpsimError(f"forward integration failed: step size below the minimum after t = {seg_t[0]:g} s")
    if stats[3] == STATUS_TOO_MANY_STEPS:
        raise VpsimError(f"forward integration stopped after {max_steps} steps (rtol {rtol:g})")
    info = {
        "accepted_steps": int(stats[0]),
        "rejected_steps": int(stats[1]),
        "rhs_evaluations": int(stats[2]),
        "max_speed_error_mps": float(fstats[0]),
    }
    return y_end, out_y, out_aux, info


def _uniform_inverse_spacing(t) -> float:
    """1/dt if the grid ``t`` is uniform (to 1e-9 relative), else 0 (binary search in the kernel)."""
    d = np.diff(np.asarray(t, float))
    if d.size and np.all(np.abs(d - d[0]) <= 1e-9 * d[0]):
        return 1.0 / float(d[0])
    return 0.0


def segments(cycle, schedule: GearSchedule, ratios) -> tuple[np.ndarray, np.ndarray]:
    """Restart instants (cycle start, every gear change, cycle end) and the ratio engaged after each."""
    t0, t1 = float(cycle.time_s[0]), float(cycle.time_s[-1])
    shifts = schedule.shift_times
    shifts = shifts[(shifts > t0) & (shifts < t1)]
    seg_t = np.concatenate([[t0], shifts, [t1]])
    gears = schedule.gear_at(seg_t[:-1])
    return seg_t, np.asarray(ratios, float)[gears - 1]


_warm = False


def warm_up() -> None:
    """Load (or compile) the kernel once per process, so run times measure the simulation only."""
    global _warm
    if not _warm:
        P = np.zeros(N_CONST)
        P[[_M, _INV_M, _R, _ETA, _INV_PA, _GAMMA, _PRCRIT, _PSICH, _BM, _KP, _KI, _UHI, _AWG]] = 1.0
        integrate(np.array([0.0, 1.0]), np.array([1.0]), np.zeros(NY), P, np.array([0.0, 1.0]), np.zeros(2))
        _warm = True


def run(
    cycle,
    params,
    *,
    driver="1",
    schedule: GearSchedule | None = None,
    mode: str = "paper",
    rtol: float | None = None,
    max_step: float | None = None,
    keep_series: bool = True,
    output_times=None,
    compiled: bool = True,
    kp: float | None = None,
    ki: float | None = None,
    tracking_time_s: float | None = None,
) -> Result:
    """Run the FDM on ``cycle`` with PI driver ``driver`` in ``mode`` and return the :class:`Result`.

    ``rtol`` (default the parameter set's ``simulation.ode_relative_tolerance``, 1e-3 like Simulink),
    ``max_step`` (default: a fiftieth of the cycle duration, Simulink's "auto"); ``kp``/``ki`` (and the
    anti-windup ``tracking_time_s``) override the driver's gains, as the driver tuning does;
    ``keep_series=False`` skips the time series (dense output at the cycle's samples, or at the sorted
    ``output_times`` within the cycle);
    ``compiled=False`` runs the pure-Python reference of the same kernel (slow).

    The tracking figures (max and RMS speed error, seconds outside the +-2 km/h band) are integrated along
    the solution: the RMS and the seconds as quadrature states, the maximum over the step ends and the
    output samples.
    """
    from dataclasses import replace

    if mode not in ("paper", "extended"):
        raise VpsimError(f"unknown mode {mode!r}; expected paper or extended")
    rtol = params.simulation.ode_relative_tolerance if rtol is None else float(rtol)
    if not (0.0 < rtol < 1.0):
        raise VpsimError(f"rtol = {rtol!r} must be in (0, 1)")
    driver = str(driver)
    if kp is not None or ki is not None:
        d = params.driver(driver)
        d = replace(
            d,
            forward_kp=d.forward_kp if kp is None else float(kp),
            forward_ki=d.forward_ki if ki is None else float(ki),
        )
        params = replace(params, drivers={**params.drivers, driver: d})
    pi = PIDriver.from_params(params, driver, mode, tracking_time_s)
    if schedule is None:
        from ..maps import cached_engine_map

        schedule = default_schedule(cycle, params, cached_engine_map(params.engine))
    duration = float(cycle.time_s[-1] - cycle.time_s[0])
    h_max = duration / 50.0 if max_step is None else float(max_step)
    if not h_max > 0:
        raise VpsimError(f"max_step = {max_step!r} must be positive")
    if compiled:
        warm_up()

    t_cpu = time.process_time()
    ratios = np.asarray(params.transmission.ratios)
    seg_t, seg_ratio = segments(cycle, schedule, ratios)
    P = constants(params, pi, mode)
    y0 = initial_state(cycle, params, seg_ratio[0], pi, mode)
    if not keep_series:
        out_t = np.zeros(0)
    elif output_times is None:
        out_t = cycle.time_s
    else:
        out_t = np.asarray(output_times, dtype=float)
        if (
            out_t.ndim != 1
            or np.any(np.diff(out_t) < 0)
            or (out_t.size and not (cycle.time_s[0] <= out_t[0] and out_t[-1] <= cycle.time_s[-1]))
        ):
            raise VpsimError("output_times must be sorted and within the cycle's time span")
    y_end, out_y, out_aux, info = integrate(
        seg_t,
        seg_ratio,
        y0,
        P,
        cycle.time_s,
        cycle.speed_mps,
        rtol=rtol,
        max_step=h_max,
        out_t=out_t,
        compiled=compiled,
    )
    fuel_kg = float(y_end[_FUEL])
    distance = float(y_end[_DIST])
    cpu = time.process_time() - t_cpu

    info.update(restarts=int(seg_t.size - 2), rtol=rtol, max_step_s=h_max)
    v = out_y[:, _V]
    v_ref = np.interp(out_t, cycle.time_s, cycle.speed_mps)
    max_err = max(info.pop("max_speed_error_mps"), float(np.max(np.abs(v - v_ref), initial=0.0)))
    rms = math.sqrt(max(float(y_end[_ERR2]), 0.0) / duration) if duration > 0 else 0.0
    outside = float(y_end[_OUTSIDE])
    trace = TraceMiss(
        seconds=outside,
        max_speed_error_mps=max_err,
        details={"rms_speed_error_mps": rms, "seconds_outside_band": outside, "band_kmh": BAND_KMH},
    )
    energy = EnergyBalance(
        indicated=float(y_end[_E_IND]),
        friction=float(y_end[_E_FRIC]),
        pumping=float(y_end[_E_PUMP]),
        engine_kinetic=float(y_end[_E_ENG]),
        driveline_loss=float(y_end[_E_DRV]),
        vehicle_kinetic=float(y_end[_E_VEH]),
        aero=float(y_end[_E_AERO]),
        rolling=float(y_end[_E_ROLL]),
        brake=float(y_end[_E_BRAKE]),
        idle_control=float(y_end[_E_IDLE]),
    )
    series = {}
    if keep_series:
        x = out_aux
        series = {
            "time_s": out_t.copy(),
            "reference_speed_mps": v_ref,
            "speed_mps": v,
            "accel_mps2": x[:, _X_ACC],
            "gear": schedule.gear_at(out_t),
            "engine_speed_radps": x[:, _X_W],
            "crank_torque_nm": x[:, _X_TCR],
            "engine_torque_nm": x[:, _X_TE],
            "intake_pressure_pa": out_y[:, _P],
            "throttle_area_m2": x[:, _X_THR],
            "fuel_flow_kgps": x[:, _X_MF],
            "fuel_flow_used_kgps": x[:, _X_MFU],
            "brake_force_n": x[:, _X_BRK],
            "torque_shortfall_nm": np.zeros(v.size),
            "driver_command_m2": x[:, _X_CMD],
            "clutch_engaged": x[:, _X_COUPLED] > 0.5,
        }
    notes = [
        f"Dormand-Prince 5(4), rtol {rtol:g}: {info['accepted_steps']} steps ({info['rejected_steps']} "
        "rejected), "
        f"{info['restarts']} restarts at gear changes",
    ]
    if outside:
        notes.append(
            f"speed outside the +-{BAND_KMH:g} km/h band for {outside:.1f} s "
            f"(max error {max_err:.2f} m/s, RMS {rms:.3f} m/s)"
        )
    if mode == "paper":
        notes.append(
            "paper mode: no clutch and no brakes; at standstill the engine stands with the car, which creeps "
            "and oscillates (as the paper reports; see docs/methods.md)"
        )
    return Result(
        method="forward",
        cycle=cycle.name,
        driver=driver,
        mode=mode,
        series=series,
        fuel_kg=fuel_kg,
        distance_m=distance,
        fuel_density_kg_per_l=params.simulation.fuel_density,
        cpu_time_s=cpu,
        steps=info["accepted_steps"],
        trace_miss=trace,
        energy=energy,
        vehicle=params.name,
        notes=tuple(notes),
        solver=info,
    )
