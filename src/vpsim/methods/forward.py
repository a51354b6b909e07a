"""Forward dynamic method (FDM), paper section 2: the model integrated in time with a PI driver.

States: vehicle speed v (18) and intake-manifold pressure p_i (9); the driver's integral state z
(:mod:`vpsim.drivers.pi`); the engine speed w_e behind an unlocked torque converter
(:func:`vpsim.model.rules.converter_engine`; elsewhere the engine speed is the wheels' or idle); and
quadrature states that integrate the fuel, the distance and every term of the
energy balance along the solution, so the bookkeeping closes to the integrator's accuracy:

    fuel = int max(mdot_f, mdot_idle) dt                                    (section 5)
    q_hv eta_th int mdot_f dt = friction + pumping + engine KE + driveline + vehicle KE + aero + rolling
                                + brakes (+ idle control, extended mode)

Right side, per gear (total ratio i; w_e = i v / r):
    dp_i/dt = (R T_i / V_i) [p_a A_eff Psi(p_i/p_a) / sqrt(R T_a) - w_e (s_i p_i - y_i) V_d / (2pi n_r R T_i)]
    m_eq dv/dt = (i eta_tm / r) T_cr(p_i, w_e) - 1/2 c_d rho A v^2 - m g c_r - F_brake,
with T_cr from (2)-(8) solved for BMEP (:func:`vpsim.model.engine.crank_torque`),
m_eq = m + J_e i² eta_tm / r².

Integrators (``solver=``; docs/methods.md explains both):

* ``rosenbrock`` (default): RODAS3 (Sandu et al. 1997; Hairer & Wanner 1996, IV.7), a linearly implicit,
  L-stable, stiffly accurate Rosenbrock method of order 3 with an embedded order-2 method, so that the step
  follows the accuracy asked and not the stability of the fast manifold. Its Jacobian (v, p_i, z, and the
  rows of the quadratures in these three) is the model's equations differentiated in closed form (the
  derivative helpers beside them in :mod:`vpsim.model`), df/dt follows from it by the PI law's structure
  (open loop: a forward difference in t), once per step; three evaluations of the right side per step.
  The error (filtered by (I - h gamma J)^-1) is measured in the RMS norm over v, p_i, z (ode45's
  scales) and the fuel and distance (relative to their increment over the step plus a rate scale times h).
  Steps end at every node of the cycle's table (where the cycle speed has a kink), at every output time, at
  the gear changes (restarts) and at every event: a switching function of the right side (clutch
  engage/slip, PI saturation, throttle floor, brakes on/off, moving/at rest, slipping clutch's torque sign,
  idle fuel floor) that changed sign inside a step is located on the step's cubic Hermite dense output
  (Illinois method) and the step is taken again to end there.
* ``dopri5``: the paper's solver, Dormand-Prince 5(4) as ode45, with ode45's error norm (max over v, p_i, z
  of |error| / max(|y|, |y_new|, threshold)), step-size control, initial step, FSAL and continuous extension
  (``ntrp45``) for outputs; gear changes restart it; events are stepped over. Its step is bound by stability
  (the manifold's time constant), about 5 steps per cycle second.

Both are plain scalar loops compiled with Numba (cached on disk); the right side calls the model's equations
(:mod:`vpsim.model`) and nothing else. The default maximum step is Simulink's "auto", a fiftieth of the
cycle's duration. Tests check both against independent references (SciPy's LSODA/Radau on the model's
equations, the FQM at steady state, Dormand-Prince at rtol 1e-8).

Modes (one switch for every method):

* ``paper``: no clutch, no brakes. At standstill w_e = i v / r = 0, so nothing leaves the manifold and even
  the closed throttle's leak A_min fills it: the engine pushes the car forward, pumps the manifold down and
  brakes it again; speed and pressure oscillate and settle into a slow creep with the PI's throttle at its
  limit, and at each launch from rest the throttle oscillates (the plant gain grows like 1/v) — the paper's
  meaningless standstill behaviour. The car does not roll backwards: at v = 0 rolling resistance is static
  friction (it holds up to m g c_r) and v >= 0 is kept (a step that ends below zero is set to zero and the
  FSAL derivative is re-evaluated).
* ``extended``: below the idle speed (``c.idle_speed``, :mod:`vpsim.model.rules`) the clutch slips: the engine
  is held at idle speed with the throttle max(A_driver, A_idle) (A_idle: the steady throttle of zero crank
  torque at idle), and the clutch passes max(T_cr, 0) to the gearbox; the engine inertia is then not coupled.
  Above it the driveline is stiff as in ``paper``. The PI's command continues below zero into the friction
  brakes (:mod:`vpsim.drivers.pi`), which therefore act only once the throttle is closed. The idealised idle
  governor's work when the decoupled engine's torque is negative is the ``idle_control`` energy term. With
  a torque converter (docs/model.md) its unlocked coupling takes the clutch's place while the brakes are
  off: the engine speed w_e is then a state, J_e dw_e/dt = T_cr - T_acc - phi(nu) w_e^2, at least idle.
"""

from __future__ import annotations

import math
import time
import types

import numpy as np
from numba import prange
from numba.extending import register_jitable

from ..drivers.pi import PIDriver, pedal_split, pi_law
from ..errors import VpsimError
from ..gears import GearSchedule, default_schedule, gearbox_ratio_series
from ..model import engine as en
from ..model import rules
from ..model import tables as tb
from ..model import vehicle as vh
from ..model._compile import kernel
from ..model.record import kernel_records, memo, record
from ..result import EnergyBalance, Result, TraceMiss, limits_of

BAND_KMH = 2.0  # the regulation's speed tolerance (UN ECE R83 / EPA: +-2 km/h resp. +-2 mph)

# --- the driver's and the mode's settings D (the model's constants are the record c, vpsim.model.record) ---
_KP, _KI, _ULO, _UHI, _AWG, _AMIN, _KB = range(7)  # PIDriver.as_array()
_EXT, _AIDLE, _OPEN, _BAND, _TAB_INV = range(7, 12)
N_SETTINGS = 12
# per-gear constants G: i, 1 / m_eq, i / r, the gear's number (1-based; the converter's lock-up reads it)
_G_I, _G_INV_MEQ, _G_KIN, _G_GEAR = range(4)
N_G = 4

# --- states ---------------------------------------------------------------------------------------------
# w_e: the engine speed while a torque converter's lock-up clutch is open (rules.converter_engine); elsewhere
# the engine speed is algebraic (the wheels', or idle) and, for a car with a converter, this state is set to
# it after every step and follows it in between with the time constant W_TRACK_S, so that it starts from the
# engine's speed when the converter takes over (without a converter it stays constant and nothing reads it:
# the step is that of v, p_i, z alone)
_V, _P, _Z, _W = 0, 1, 2, 3
_FUEL, _DIST, _E_IND, _E_FRIC, _E_PUMP, _E_ENG, _E_DRV, _E_VEH, _E_AERO, _E_ROLL, _E_BRAKE, _E_IDLE = range(
    4, 16
)
_ERR2, _OUTSIDE = 16, 17  # int (v_cycle - v)^2 dt and the time with |v_cycle - v| above the band
_E_ACC = 18  # the accessories' work
NY = 19
N_ERR = 3  # states always in the error norm: v, p_i, z (w_e too while a converter is unlocked)
# states the right side reads (v, p_i, z, w_e): the quadrature states' stage values are never used, so the
# stages are formed for these only (the quadratures enter the step through their derivatives k_j alone)
N_DYN = 4
W_TRACK_S = 0.05  # s: the time constant of w_e following the engine's speed where it is not a state

# --- auxiliary outputs ----------------------------------------------------------------------------------
(
    _X_THR,
    _X_W,
    _X_TCR,
    _X_TE,
    _X_MF,
    _X_MFU,
    _X_BRK,
    _X_ACC,
    _X_VREF,
    _X_CMD,
    _X_COUPLED,
    _X_CONV,  # the converter's lock-up clutch open (w_e a state)
) = range(12)
# switching functions: where one changes sign the right side changes form (a jump or a kink); the Rosenbrock
# integrator locates these instants and restarts there (the Dormand-Prince path ignores them)
_X_SW = 12
(
    _SW_CLUTCH,  # w_wheel - idle speed: clutch engaged / slipping (extended mode)
    _SW_SAT_LO,  # u_raw - u_lo: PI command saturated at its lower limit
    _SW_SAT_HI,  # u_hi - u_raw: ... at its upper limit
    _SW_THROTTLE,  # u - A_min: throttle at its floor, pedal below it (extended mode)
    _SW_BRAKE,  # u: brakes on below zero (extended mode)
    _SW_MOVING,  # v: moving / at rest (static friction, v >= 0)
    _SW_SLIP_TORQUE,  # T_cr while the clutch slips: it passes max(T_cr, 0)
    _SW_LOCKUP,  # v - lock-up speed, in the gears the converter's lock-up clutch may close in
    _SW_CONVERTER,  # the engine driving the unlocked converter: above idle, or held there (converter_engine)
) = range(9)
N_SW = 9
# (the idle fuel floor max(mdot_f, mdot_idle) is no event: only the fuel quadrature sees its kink, and the
# fuel is in the error norm; locating it cost a quarter of the right-side evaluations with driver 2)
# a sign change is an event only where the switching function ends clearly on the other side (|g| above this):
# a function that settles at zero (the slipping clutch's torque at idle, where A_idle gives T_cr = 0) would
# otherwise give an event at every step
SWITCH_SIGNIFICANCE = (1e-6, 1e-12, 1e-12, 1e-12, 1e-12, 1e-9, 1e-4, 1e-9, 1e-4)
SWITCHES = (
    "clutch",
    "saturation_low",
    "saturation_high",
    "throttle_floor",
    "brake",
    "moving",
    "slip_torque",
    "lockup",
    "converter",
)
# the engine's inputs at the point and its friction's power of the speed, c_m^1.8 (the Rosenbrock step's
# analytic Jacobian reads them)
_X_AENG, _X_FIRED, _X_TACC, _X_CM18 = range(_X_SW + N_SW, _X_SW + N_SW + 4)
N_AUX = _X_SW + N_SW + 4

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
def _gear(ratio, gear, c, G):
    """Fill the per-gear constants G for total ratio i of gear number ``gear``."""
    G[_G_I] = ratio
    G[_G_INV_MEQ] = 1.0 / vh.equivalent_mass(ratio, c)
    G[_G_KIN] = vh.engine_speed(1.0, ratio, c)  # w_e per unit v
    G[_G_GEAR] = gear


@register_jitable
def _switch_value(k, v, w_wheel, t_slip, raw, cmd, conv, g_conv, G, c, D):
    """Switching function k (where the right side changes form) from the right side's own values: the speed
    v, the wheel-side engine speed, the slipping engine's crank torque, the PI's unclipped and clipped
    command, whether the torque converter is unlocked and its engine's switching value
    (:func:`.rules.converter_engine`).
    Written once for :func:`_rhs` (every evaluation) and :func:`_switch` (the events' location).

    Not inlined at Numba-IR level: inlined into the right side's loop over k, its chain of branches cost 90
    of the right side's 205 ns; compiled as a function, LLVM reduces it to some 10 ns."""
    ext = D[_EXT] != 0.0
    if k == _SW_MOVING:
        return v
    if k == _SW_CLUTCH:
        return w_wheel - c.idle_speed if ext else 1.0
    if k == _SW_SLIP_TORQUE:  # the clutch passes max(T_cr, 0) while it slips
        return 1.0 if not ext or conv or rules.clutch_engaged(w_wheel, c) else t_slip
    if k == _SW_LOCKUP:  # in a gear with lock-up: closed at and above its speed
        lockable = c.converter_capacity_factor > 0.0 and G[_G_GEAR] >= c.lockup_min_gear
        return v - c.lockup_min_speed if ext and lockable else 1.0
    if k == _SW_CONVERTER:  # the engine on the unlocked converter: above idle, or held there
        return g_conv if conv else 1.0
    if D[_OPEN] != 0.0:  # no driver
        return 1.0
    if k == _SW_SAT_LO:
        return raw - D[_ULO]
    if k == _SW_SAT_HI:
        return D[_UHI] - raw
    if k == _SW_THROTTLE:
        return cmd - D[_AMIN] if ext else 1.0
    return cmd if D[_KB] != 0.0 else 1.0  # _SW_BRAKE


@register_jitable
def _speed_power(w, c):
    """(5)'s power of the speed c_m^1.8 (:func:`.engine.speed_power`) at engine speed w: the record's at the
    idle speed, where the slipping clutch's engine spends its time."""
    return c.idle_speed_power if w == c.idle_speed else en.speed_power(w, c)


@register_jitable
def _rhs(t, y, G, c, D, tab_t, tab_v, dy, aux, full=True):
    """Right side of model + driver + quadratures at (t, y) with gear constants G; fills ``dy`` and ``aux``.

    The table (tab_t, tab_v) is the cycle speed for the PI driver or, with D[_OPEN] = 1, the throttle area
    fed open loop (not clipped). ``full=False`` (the Rosenbrock step's inner stages, whose auxiliary values
    nothing reads): ``dy`` alone, ``aux`` left as it was.
    """
    v = y[_V]
    p = y[_P]
    vv = v if v > 0.0 else 0.0
    # driver
    if D[_OPEN] != 0.0:
        cmd = tb.interp_at(t, tab_t, tab_v, D[_TAB_INV])
        v_ref = vv
        raw = cmd
        throttle = cmd
        brake = 0.0
        dz = 0.0
    else:
        v_ref = tb.interp_at(t, tab_t, tab_v, D[_TAB_INV])
        cmd, dz = pi_law(v_ref - vv, y[_Z], D[_KP], D[_KI], D[_ULO], D[_UHI], D[_AWG])
        throttle, brake = pedal_split(cmd, D[_AMIN], D[_KB])
        raw = 0.0
        if full:
            raw, _ = pi_law(v_ref - vv, y[_Z], D[_KP], D[_KI], -math.inf, math.inf, D[_AWG])  # unclipped
    # driveline kinematics: stiff, or slipping clutch with the engine held at idle (realistic mode), or an
    # unlocked torque converter (rules.converter_engine: the engine speed w_e a state, at least idle), its
    # drive engaged progressively over the pedal's floor band, as a neutral-idle clutch does when the brake
    # is released (a step there would make the PI chatter), and released with the brakes on
    ratio = G[_G_I]
    w_wheel = vh.engine_speed(vv, ratio, c)  # (14),(17)
    ext = D[_EXT] != 0.0
    conv = ext and not vh.converter_locked(G[_G_GEAR], vv, c)
    passed = 1.0
    g_conv = 1.0
    if conv:
        passed = rules.neutral_idle_share(cmd, D[_AMIN])
        w = y[_W] if y[_W] > c.idle_speed else c.idle_speed
        coupled = passed > 0.0
        # the idle governor: at least the throttle that holds the engine at idle speed against its load
        a_gov = rules.converter_idle_command(w_wheel, passed, c)
        a_eng = throttle if throttle > a_gov else a_gov
    else:
        coupled = not ext or rules.clutch_engaged(w_wheel, c)
        if coupled:
            w = w_wheel
            a_eng = throttle
        else:
            w = c.idle_speed
            a_eng = throttle if throttle > D[_AIDLE] else D[_AIDLE]
    # engine: manifold (9),(10), torque (2)-(8), fuel (7); fuel cut-off in overrun (realistic mode, engaged
    # or on the converter): the pedal's floor band cuts cylinders (rules.fired_fraction_of_command:
    # engine_braking's line at a steady state)
    fired = 1.0
    if (coupled or conv) and ext and D[_OPEN] == 0.0:
        fired = rules.fired_fraction_of_command(cmd, D[_AMIN], w, c)
    cm18 = _speed_power(w, c)  # once: the torque and the friction power take it
    t_cr = en.fired_crank_torque(p, w, fired, c, cm18)
    dp = en.manifold_pressure_rate(p, a_eng, w, c)
    mdot_f = fired * en.fuel_flow(p, w, c)
    # vehicle (18) with the engine inertia (1),(14)-(17)
    t_acc = rules.accessories_torque(w, ext, c)
    if conv:  # the converter passes the turbine's torque; the engine's inertia is on the pump's side
        w, t_e, t_turbine, dw, held, g_conv = rules.converter_engine(p, y[_W], w_wheel, passed, fired, c)
        cm18 = _speed_power(w, c)  # (the converter's engine speed)
        acc = vh.acceleration(vh.engine_to_wheel_force(t_turbine, ratio, c), v, brake, c.mass, c)
        clutch = rules.CLUTCH_CONVERTER
    elif coupled:
        t_clutch = t_cr - t_acc
        acc = vh.acceleration(vh.engine_to_wheel_force(t_clutch, ratio, c), v, brake, 1.0 / G[_G_INV_MEQ], c)
        dw = G[_G_KIN] * acc
        clutch = rules.CLUTCH_ENGAGED
        t_e = vh.engine_torque(t_cr - t_acc, dw, c)  # (1): T_e = T_cr - J_e dw_e/dt (less the accessories)
    else:
        t_clutch = rules.slipping_clutch_torque(t_cr - t_acc)
        acc = vh.acceleration(vh.engine_to_wheel_force(t_clutch, ratio, c), v, brake, c.mass, c)
        dw = 0.0
        clutch = rules.CLUTCH_SLIPPING
        t_e = t_clutch
    dy[_V] = acc
    dy[_P] = dp
    dy[_Z] = dz
    if conv:
        dy[_W] = dw
    elif ext and c.converter_capacity_factor > 0.0:  # w_e follows the engine's speed
        dy[_W] = (w - y[_W]) / W_TRACK_S
    else:
        dy[_W] = 0.0
    # quadratures: fuel, distance, energy terms (powers, W)
    used = rules.fuel_used(mdot_f, fired, c)
    dy[_FUEL] = used
    dy[_DIST] = vv
    pw = rules.powers(p, w, dw, t_cr, 0.0, w_wheel, vv, acc, brake, clutch, fired, t_acc, passed, c, cm18)
    dy[_E_IND] = pw[0]
    dy[_E_FRIC] = pw[1]
    dy[_E_PUMP] = pw[2]
    dy[_E_ENG] = pw[3]
    dy[_E_DRV] = pw[4]
    dy[_E_VEH] = pw[5]
    dy[_E_AERO] = pw[6]
    dy[_E_ROLL] = pw[7]
    dy[_E_BRAKE] = pw[8]
    dy[_E_IDLE] = pw[10]
    dy[_E_ACC] = pw[11]
    err = v_ref - vv
    dy[_ERR2] = err * err
    dy[_OUTSIDE] = 1.0 if abs(err) > D[_BAND] else 0.0
    if not full:
        return
    aux[_X_THR] = en.throttle_upstream(a_eng, w, c)[0]  # the throttle's area (a boosted engine: <= A_max)
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
    aux[_X_CONV] = 1.0 if conv else 0.0
    for k in range(N_SW):
        aux[_X_SW + k] = _switch_value(k, v, w_wheel, t_cr, raw, cmd, conv, g_conv, G, c, D)
    aux[_X_AENG] = a_eng
    aux[_X_FIRED] = fired
    aux[_X_TACC] = t_acc
    aux[_X_CM18] = cm18


@register_jitable(inline="always")  # one call site, the Rosenbrock step: no call of ten arrays
def _jacobian(y, aux, G, c, D, jac, col_v, col_p, col_z, col_w):
    """The right side's derivatives in v, p_i and z at (t, y) (``aux`` from :func:`_rhs` there): the 3 x 3
    Jacobian ``jac`` (row-major) and the full columns col_v, col_p, col_z (the quadratures' rows): the
    model's equations differentiated branch by branch.

    Three directions, at fixed t: the speed v at a fixed driver's command (at rest, v = 0, the derivative
    from below: zero, as max(v, 0) does not move; from above the road load steps), p_i, and
    the command. The command moves the pedal's throttle and brake (pedal_split), the slipping engine's
    throttle above the idle one, and in overrun the fired fraction (rules.fired_fraction_of_command), as
    does the engine speed; dp_i/dt (9),(10): :func:`.engine.manifold_rate_partials`; T_cr and
    mdot_f (2)-(8) are affine in p_i and in the fired fraction; dv/dt (1),(14)-(18) is linear in the
    clutch's torque (the slipping clutch's part zero where it passes nothing) and the brake force, all zero
    where static friction holds the car; the powers follow (:func:`.rules.powers_tangent`). z moves the raw
    command u_raw = K_p e + z one for one, the command where it is not saturated (pi_law), and dz/dt's own
    derivative is the anti-windup's (du/du_raw - 1)/T_t; v moves the PI error e = v_cycle - v as well,
    hence the command as -K_p times z does (the right side's change is linear in the three). Open loop
    nothing depends on z."""
    closed = D[_OPEN] == 0.0
    track = D[_EXT] != 0.0 and c.converter_capacity_factor > 0.0  # w_e follows the engine's speed
    for i in range(col_w.size):  # nothing else depends on w_e here
        col_w[i] = 0.0
    col_w[_W] = -1.0 / W_TRACK_S if track else 0.0
    # u_lo <= u_raw <= u_hi (the switching functions' values): the command follows u_raw
    du = 1.0 if closed and aux[_X_SW + _SW_SAT_LO] >= 0.0 and aux[_X_SW + _SW_SAT_HI] >= 0.0 else 0.0
    # the point
    v = y[_V]
    vv = v if v > 0.0 else 0.0
    p = y[_P]
    ratio = G[_G_I]
    w = aux[_X_W]
    t_cr = aux[_X_TCR]
    fired = aux[_X_FIRED]
    t_acc = aux[_X_TACC]
    brake = aux[_X_BRK]
    acc = aux[_X_ACC]
    a_eng = aux[_X_AENG]
    mdot_f = aux[_X_MF]
    cmd = aux[_X_CMD]
    a_min = D[_AMIN]
    coupled = aux[_X_COUPLED] != 0.0
    realistic = D[_EXT] != 0.0
    cut = coupled and realistic and closed  # fuel cut-off in overrun
    if coupled:
        t_clutch = t_cr - t_acc
        mass = 1.0 / G[_G_INV_MEQ]
        clutch = rules.CLUTCH_ENGAGED
        dw = G[_G_KIN] * acc
    else:
        t_clutch = rules.slipping_clutch_torque(t_cr - t_acc)
        mass = c.mass
        clutch = rules.CLUTCH_SLIPPING
        dw = 0.0
    passes = coupled or t_cr - t_acc > 0.0  # the slipping clutch passes the torque's change
    per_force = vh.acceleration_dforce(vh.engine_to_wheel_force(t_clutch, ratio, c), v, brake, mass, c)
    w_wheel = vh.engine_speed(vv, ratio, c)
    rate_dp, rate_da, rate_dw = en.manifold_rate_partials(p, a_eng, w, c)
    moving = v > 0.0  # at rest nothing moves with v (max(v, 0) = 0 below; above, the road load's step)
    for k in range(3):
        if k == 0:
            col = col_v
            d_v, d_p, d_cmd = 1.0, 0.0, 0.0
            if not moving:
                for i in range(col.size):
                    col[i] = 0.0
                continue
        elif k == 1:
            col = col_p
            d_v, d_p, d_cmd = 0.0, 1.0, 0.0
        else:
            col = col_z
            d_v, d_p, d_cmd = 0.0, 0.0, 1.0
            if du == 0.0:
                for i in range(col.size):
                    col[i] = 0.0
                break
        d_wheel = G[_G_KIN] * d_v
        d_w = d_wheel if coupled else 0.0  # the slipping clutch holds the engine at idle
        d_tacc = en.accessory_torque_rate(w, d_w, c) if realistic else 0.0
        # the driver's command through the pedal (pedal_split) and the slipping engine's idle throttle
        d_a = 0.0
        d_brake = 0.0
        if d_cmd != 0.0:
            d_brake = -D[_KB] * d_cmd if cmd < 0.0 else 0.0
            if cmd > a_min and (coupled or cmd > D[_AIDLE]):
                d_a = d_cmd
        d_fired = 0.0
        if cut:
            d_fired = rules.fired_fraction_dcommand(cmd, a_min, w, c) * d_cmd
            d_fired += rules.fired_fraction_dspeed(cmd, a_min, w, c) * d_w
        # engine: manifold (9),(10), torque (2)-(8), fuel (7)
        d_tcr = 0.0
        d_mf = 0.0
        if d_fired != 0.0:
            d_tcr += en.partly_fired_torque_dfired(p, c) * d_fired
            d_mf += en.fuel_flow(p, w, c) * d_fired
        d_dp = rate_dp * d_p + rate_da * d_a + rate_dw * d_w
        if d_p != 0.0:
            d_tcr += en.partly_fired_torque_dp(fired, c) * d_p
            d_mf += fired * en.fuel_flow_dp(p, w, c) * d_p
        if d_w != 0.0:
            d_tcr += en.crank_torque_dw(w, c, aux[_X_CM18]) * d_w
            d_mf += fired * en.fuel_flow_dw(p, c) * d_w
        # vehicle (18) with the engine inertia (1),(14)-(17)
        d_clutch = d_tcr - d_tacc if passes else 0.0
        d_acc = (vh.engine_to_wheel_force(d_clutch, ratio, c) - d_brake) * per_force
        if d_v != 0.0:
            d_acc -= vh.road_load_dv(v, c) / mass * d_v
        d_dw = G[_G_KIN] * d_acc if coupled else 0.0
        col[_V] = d_acc
        col[_P] = d_dp
        col[_FUEL] = rules.fuel_used_tangent(mdot_f, fired, d_mf, d_fired, c)
        col[_DIST] = d_v
        pw = rules.powers_tangent(
            p,
            w,
            dw,
            t_cr,
            w_wheel,
            vv,
            acc,
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
            d_acc,
            d_brake,
            d_fired,
            d_tacc,
            c,
            aux[_X_CM18],
        )
        col[_E_IND] = pw[0]
        col[_E_FRIC] = pw[1]
        col[_E_PUMP] = pw[2]
        col[_E_ENG] = pw[3]
        col[_E_DRV] = pw[4]
        col[_E_VEH] = pw[5]
        col[_E_AERO] = pw[6]
        col[_E_ROLL] = pw[7]
        col[_E_BRAKE] = pw[8]
        col[_E_IDLE] = pw[10]
        col[_E_ACC] = pw[11]
        col[_OUTSIDE] = 0.0
        col[_W] = d_w / W_TRACK_S if track else 0.0  # w_e follows the engine's speed (converter cars)
    # the command's part of the speed's column; the z and e^2 rows
    if du != 0.0 and moving:
        kp = D[_KP]
        for i in range(col_v.size):
            col_v[i] -= kp * col_z[i]
    col_p[_Z] = 0.0
    col_p[_ERR2] = 0.0
    col_z[_ERR2] = 0.0
    if closed:
        col_z[_Z] = (du - 1.0) * D[_AWG]
        col_v[_Z] = -D[_KI] - D[_KP] * col_z[_Z] if moving else 0.0
        col_v[_ERR2] = -2.0 * (aux[_X_VREF] - vv) if moving else 0.0
    else:  # e = 0
        col_z[_Z] = 0.0
        col_v[_Z] = 0.0
        col_v[_ERR2] = 0.0
    for i in range(N_DYN):
        jac[N_DYN * i + _V] = col_v[i]
        jac[N_DYN * i + _P] = col_p[i]
        jac[N_DYN * i + _Z] = col_z[i]
        jac[N_DYN * i + _W] = col_w[i]


@register_jitable
def _jacobian_fd(t, y, f0, G, c, D, tab_t, tab_v, thr, jac, col_v, col_p, col_z, col_w, ytmp, f, aux):
    """As :func:`_jacobian`, by forward differences of the right side (``f0`` at (t, y)), for the unlocked
    torque converter, whose engine speed is the root of the converter's torque balance
    (:func:`.rules.converter_engine`) couples w_e, v and p_i: increments sqrt(eps) times max(|y_k|,
    thr_k); as there, the speed's column is zero at rest and z's open loop. Returns the evaluations of the
    right side it made."""
    ny = y.size
    n = 0
    for k in range(N_DYN):
        col = col_v if k == _V else (col_p if k == _P else (col_z if k == _Z else col_w))
        if (k == _V and not y[_V] > 0.0) or (k == _Z and D[_OPEN] != 0.0):
            for i in range(ny):
                col[i] = 0.0
            continue
        for i in range(N_DYN):
            ytmp[i] = y[i]
        sc = abs(y[k])
        if thr[k] > sc:
            sc = thr[k]
        ytmp[k] = y[k] + _FD_STEP * sc
        d = ytmp[k] - y[k]
        _rhs(t, ytmp, G, c, D, tab_t, tab_v, f, aux)
        n += 1
        for i in range(ny):
            col[i] = (f[i] - f0[i]) / d
        col[_OUTSIDE] = 0.0
    for i in range(N_DYN):
        jac[N_DYN * i + _V] = col_v[i]
        jac[N_DYN * i + _P] = col_p[i]
        jac[N_DYN * i + _Z] = col_z[i]
        jac[N_DYN * i + _W] = col_w[i]
    return n


@register_jitable
def _initial_step(y, f, thr, n, rtol, pw, hmax):
    """ode45's initial step for an error estimate of order 1/pw: the largest |f_i| / max(|y_i|, thr_i) over
    the first n states sets h = (0.8 rtol^pw) / that, at most hmax."""
    rh = 0.0
    for i in range(n):
        sc = abs(y[i])
        if thr[i] > sc:
            sc = thr[i]
        q = abs(f[i]) / sc
        if q > rh:
            rh = q
    rh = rh / (0.8 * rtol**pw)
    h = hmax
    if h * rh > 1.0:
        h = 1.0 / rh
    return h


# the same right side, inlined (at Numba-IR level) into its one call site, the integrator's stage loop: a call
# would pass its seven arrays as some fifty scalars, 53,000 times per UDDS run
_rhs_stage = register_jitable(inline="always")(
    types.FunctionType(_rhs.__code__, _rhs.__globals__, "_rhs_stage", _rhs.__defaults__, _rhs.__closure__)
)


@register_jitable
def _output(t_out, y, h, k1, k3, k4, k5, k6, k7, s, row_y, G, c, D, tab_t, tab_v, scratch, row_aux):
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
    _rhs(t_out, row_y, G, c, D, tab_t, tab_v, scratch, row_aux)


# _nrt=False: no reference counting of arrays (every call of the right side would otherwise pay for atomic
# increments and decrements of its array arguments, which cost more than the arithmetic); the kernel
# therefore allocates nothing, its scratch space comes in ``work``.
@kernel(_nrt=False)  # nogil: vpsim.batch runs variants on threads
def _integrate(
    seg_t,
    seg_ratio,
    seg_gear,
    y0,
    tab_t,
    tab_v,
    c,
    D,
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
    """Dormand-Prince 5(4) from seg_t[0] to seg_t[-1], restarting at every seg_t[k] in gear seg_gear[k] of
    total ratio seg_ratio[k].

    Fills out_y/out_aux at out_t (sorted, within [seg_t[0], seg_t[-1]]); a time equal to a restart instant
    gets the state there with the new gear. stats: [accepted, rejected, rhs evaluations, status];
    fstats: [largest |v_cycle - v| at the step ends].
    ``work`` (11 x len(y0)), ``aux`` (N_AUX) and ``G`` (N_G) are scratch space; the state reached is left in
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
    n_w = 1 if D[_EXT] != 0.0 and c.converter_capacity_factor > 0.0 else 0
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
        _gear(seg_ratio[sgi], seg_gear[sgi], c, G)
        last = sgi == n_seg - 1
        _rhs(t, y, G, c, D, tab_t, tab_v, k1, aux)
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
        absh = _initial_step(y, k1, thr, N_ERR, rtol, pw, hmax)  # (ode45's)
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
                    _rhs_stage(ts, tgt, G, c, D, tab_t, tab_v, work[4 + st], aux)
                nfev += 6
                err = 0.0
                for i in range(N_ERR + n_w):  # (w_e too, for a car with a converter)
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
                    _rhs(tnew, out_y[j_out], G, c, D, tab_t, tab_v, scratch, out_aux[j_out])
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
                        c,
                        D,
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
                _rhs(t, y, G, c, D, tab_t, tab_v, k1, aux)
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


# --- RODAS3: the default integrator ---------------------------------------------------------------------
# Sandu, Verwer, Blom, Spee, Carmichael & Potra (1997), Atmos. Environ. 31:3459-3472 (Rodas3), in the form of
# Hairer & Wanner (1996), Solving ODEs II, IV.7, (7.25), that needs no products with the Jacobian:
#     (I / (h gamma) - J) u_i = f(t + alpha_i h, y + sum_j a_ij u_j) + sum_j (c_ij / h) u_j + gamma_i h df/dt,
#     y_new = y + sum_i m_i u_i,     error = sum_i e_i u_i.
# Four stages, three evaluations of f (stage 2 reuses stage 1's), order 3 with an embedded method of order 2;
# both stiffly accurate and L-stable (R(inf) = 0), so the error estimate stays meaningful in the stiff
# (manifold) component when the step is far beyond its time constant.
_ROS_GAMMA = 0.5
_WA31, _WA41, _WA43 = 2.0, 2.0, 1.0  # a_ij (the others are zero)
_WC21, _WC31, _WC32, _WC41, _WC42, _WC43 = 4.0, 1.0, -1.0, 1.0, -1.0, -8.0 / 3.0
_WM1, _WM3, _WM4 = 2.0, 1.0, 1.0  # m_2 = 0; y_new = stage 4 state + u_4 (stiffly accurate)
_WG1, _WG2 = 0.5, 1.5  # gamma_i = sum_j gamma_ij (0 for stages 3, 4); alpha = (0, 0, 1, 1)
ROS_ORDER = 3  # the step-size controller uses the embedded order 2: h ~ err^(-1/3) (cbrt); the error: u_4
_FD_STEP = 1.4901161193847656e-08  # sqrt(eps): forward-difference increment relative to the state's scale
EVENT_TOLERANCE_S = 1e-6  # events are located to this width (plus rounding of t)
# the step-size factor 0.9 err^(-1/3) is bounded to [0.2, 5]: beyond these errors (a hair inside the bound)
# the bound applies, and the cube root is not taken
_ERR_AT_FAC_MAX = (0.9 / 5.0) ** 3 * (1.0 - 1e-9)
_ERR_AT_FAC_MIN = (0.9 / 0.2) ** 3 * (1.0 + 1e-9)


@register_jitable
def _inverse3(jac, q, winv, nd):
    """The factors of (q I - J)^-1 for the 4 x 4 Jacobian ``jac`` (row-major; v, p_i, z, w_e) by the Schur
    complement of its v, p_i, z block A = (q I - J)[:3, :3], inverted by cofactors: winv[0:9] = A^-1,
    winv[9:12] = A^-1 b, winv[12:15] = c A^-1 (b, c: the block's column and row in w_e), winv[15] = 1 / (d -
    c A^-1 b). ``nd`` = 3 (no converter: nothing depends on w_e, b = 0): A^-1 alone, a 3 x 3 system."""
    n = N_DYN
    a, b, cc = q - jac[0], -jac[1], -jac[2]
    d, e, f = -jac[n], q - jac[n + 1], -jac[n + 2]
    g, hh, i = -jac[2 * n], -jac[2 * n + 1], q - jac[2 * n + 2]
    co0 = e * i - f * hh
    co1 = f * g - d * i
    co2 = d * hh - e * g
    inv_det = 1.0 / (a * co0 + b * co1 + cc * co2)
    winv[0] = co0 * inv_det
    winv[1] = (cc * hh - b * i) * inv_det
    winv[2] = (b * f - cc * e) * inv_det
    winv[3] = co1 * inv_det
    winv[4] = (a * i - cc * g) * inv_det
    winv[5] = (cc * d - a * f) * inv_det
    winv[6] = co2 * inv_det
    winv[7] = (b * g - a * hh) * inv_det
    winv[8] = (a * e - b * d) * inv_det
    if nd < N_DYN:
        return
    b0, b1, b2 = -jac[3], -jac[n + 3], -jac[2 * n + 3]
    c0, c1, c2 = -jac[3 * n], -jac[3 * n + 1], -jac[3 * n + 2]
    for k in range(3):
        winv[9 + k] = winv[3 * k] * b0 + winv[3 * k + 1] * b1 + winv[3 * k + 2] * b2
        winv[12 + k] = c0 * winv[k] + c1 * winv[3 + k] + c2 * winv[6 + k]
    winv[15] = 1.0 / (q - jac[3 * n + 3] - (c0 * winv[9] + c1 * winv[10] + c2 * winv[11]))


@register_jitable
def _solve3(r, winv, u, nd):
    """u = (I/(h gamma) - J)^-1 r for v, p_i, z and (``nd`` = 4) w_e (the factors of :func:`_inverse3`)."""
    r0, r1, r2 = r[0], r[1], r[2]
    x0 = winv[0] * r0 + winv[1] * r1 + winv[2] * r2
    x1 = winv[3] * r0 + winv[4] * r1 + winv[5] * r2
    x2 = winv[6] * r0 + winv[7] * r1 + winv[8] * r2
    if nd < N_DYN:
        u[0] = x0
        u[1] = x1
        u[2] = x2
        return
    xw = (r[3] - (winv[12] * r0 + winv[13] * r1 + winv[14] * r2)) * winv[15]
    u[0] = x0 - winv[9] * xw
    u[1] = x1 - winv[10] * xw
    u[2] = x2 - winv[11] * xw
    u[3] = xw


@register_jitable(inline="always")
def _quadrature_weights(h, ih, hg, u1, u2, u3, u4, e, nd):
    """The weights of a step for the quadrature states (their columns of J are zero; row G_i in v, p_i, z,
    w_e): RODAS3's stages u_j = hg (f_j + sum_k c_jk u_k / h + gamma_j h df/dt + G_i U_j), U_j the stages
    of v, p_i, z (w_e), are linear in (f0, df/dt, k3, k4, G_i U_j), so q_j = sum_k L_jk (inputs of stage k)
    with L lower triangular in hg and h, and the step sum_j m_j q_j and the error estimate q_4 + hg G_i e
    (e: the filtered estimate of v, p_i, z, w_e over hg) are fixed combinations. Returns the step's weights
    of f0, df/dt, k3, k4 and of G_i's four entries (sum_j W_j U_j), then the error's: once per step, so
    that each quadrature costs 8 multiply-adds for its step and 8 for its error (instead of its four
    stages)."""
    l21 = hg * hg * _WC21 * ih
    l31 = hg * ih * (_WC31 * hg + _WC32 * l21)
    l32 = hg * ih * _WC32 * hg
    l41 = hg * ih * (_WC41 * hg + _WC42 * l21 + _WC43 * l31)
    l42 = hg * ih * (_WC42 * hg + _WC43 * l32)
    l43 = hg * ih * _WC43 * hg
    w1 = _WM1 * hg + _WM3 * l31 + _WM4 * l41  # y_new = y + m1 q1 + m3 q3 + m4 q4 (m2 = 0)
    w2 = _WM3 * l32 + _WM4 * l42
    w3 = _WM3 * hg + _WM4 * l43
    w4 = _WM4 * hg
    s0 = w1 * u1[0] + w2 * u2[0] + w3 * u3[0] + w4 * u4[0]
    s1 = w1 * u1[1] + w2 * u2[1] + w3 * u3[1] + w4 * u4[1]
    s2 = w1 * u1[2] + w2 * u2[2] + w3 * u3[2] + w4 * u4[2]
    e0 = l41 * u1[0] + l42 * u2[0] + l43 * u3[0] + hg * (u4[0] + e[0])
    e1 = l41 * u1[1] + l42 * u2[1] + l43 * u3[1] + hg * (u4[1] + e[1])
    e2 = l41 * u1[2] + l42 * u2[2] + l43 * u3[2] + hg * (u4[2] + e[2])
    s3 = e3 = 0.0  # (no converter: w_e is no state of the step)
    if nd == N_DYN:
        s3 = w1 * u1[3] + w2 * u2[3] + w3 * u3[3] + w4 * u4[3]
        e3 = l41 * u1[3] + l42 * u2[3] + l43 * u3[3] + hg * (u4[3] + e[3])
    step = (w1 + w2, h * (_WG1 * w1 + _WG2 * w2), w3, w4, s0, s1, s2, s3)  # (stages 1 and 2 take f0)
    error = (l41 + l42, h * (_WG1 * l41 + _WG2 * l42), l43, hg, e0, e1, e2, e3)
    return step, error


@register_jitable(inline="always")
def _quadrature_sum(i, f0, ft, k3, k4, g0, g1, g2, g3, w):
    """Quadrature i's step or error estimate from weights ``w`` of :func:`_quadrature_weights`."""
    return (
        w[0] * f0[i]
        + w[1] * ft[i]
        + w[2] * k3[i]
        + w[3] * k4[i]
        + w[4] * g0[i]
        + w[5] * g1[i]
        + w[6] * g2[i]
        + w[7] * g3[i]
    )


@register_jitable
def _hermite(s, h, y, ynew, f0, f1, n, out):
    """Cubic Hermite interpolant of the step (values, derivatives at both ends) at t + s h, first n states."""
    s2 = s * s
    s3 = s2 * s
    w_y0 = 2.0 * s3 - 3.0 * s2 + 1.0
    w_f0 = (s3 - 2.0 * s2 + s) * h
    w_y1 = 3.0 * s2 - 2.0 * s3
    w_f1 = (s3 - s2) * h
    for i in range(n):
        out[i] = w_y0 * y[i] + w_f0 * f0[i] + w_y1 * ynew[i] + w_f1 * f1[i]
    if out[_V] < 0.0:
        out[_V] = 0.0


@register_jitable
def _switch(k, t, y, G, c, D, tab_t, tab_v):
    """Switching function k at (t, y), as :func:`_rhs` sets aux[_X_SW + k], without the rest of the right
    side: the events' location (:func:`_locate`) needs this one value, some eight times per event."""
    v = y[_V]
    vv = v if v > 0.0 else 0.0
    w_wheel = vh.engine_speed(vv, G[_G_I], c)  # (14),(17)
    t_slip = raw = cmd = g_conv = 0.0
    conv = D[_EXT] != 0.0 and not vh.converter_locked(G[_G_GEAR], vv, c)
    if k == _SW_SLIP_TORQUE:
        # the slipping engine at idle, all cylinders fired
        t_slip = en.crank_torque(y[_P], c.idle_speed, c, c.idle_speed_power)
    elif k == _SW_CONVERTER:
        if conv:
            if D[_OPEN] != 0.0:
                cmd = tb.interp_at(t, tab_t, tab_v, D[_TAB_INV])
            else:
                v_ref = tb.interp_at(t, tab_t, tab_v, D[_TAB_INV])
                cmd, _ = pi_law(v_ref - vv, y[_Z], D[_KP], D[_KI], D[_ULO], D[_UHI], D[_AWG])
            g_conv = y[_W] - c.idle_speed
            if not g_conv > 0.0:
                share = rules.neutral_idle_share(cmd, D[_AMIN])
                fired = 1.0
                if D[_OPEN] == 0.0:
                    fired = rules.fired_fraction_of_command(cmd, D[_AMIN], c.idle_speed, c)
                g_conv = rules.converter_margin_at_idle(y[_P], w_wheel, share, fired, c)
    elif k != _SW_MOVING and k != _SW_CLUTCH and k != _SW_LOCKUP and D[_OPEN] == 0.0:
        v_ref = tb.interp_at(t, tab_t, tab_v, D[_TAB_INV])
        raw, _ = pi_law(v_ref - vv, y[_Z], D[_KP], D[_KI], -math.inf, math.inf, D[_AWG])
        cmd, _ = pi_law(v_ref - vv, y[_Z], D[_KP], D[_KI], D[_ULO], D[_UHI], D[_AWG])
    return _switch_value(k, v, w_wheel, t_slip, raw, cmd, conv, g_conv, G, c, D)


@register_jitable
def _cross(k, t, t_lim, y, f, aux_y, g_old, ytmp, r, aux, G, c, D, tab_t, tab_v):
    """Step across the zero of switching function k from (t, y) (right side ``f``, ``aux_y`` there; the
    function's sign before the crossing that of ``g_old``), by explicit Euler steps of 1, 2, 4 ...
    microseconds (error ~ their square) ending before ``t_lim`` and 1 ms: the first that reaches the new side
    replaces (y, f, aux_y). Returns the time reached (t if none crossed) and the evaluations made."""
    dt = EVENT_TOLERANCE_S
    n = 0
    while t + dt < t_lim and dt < 1e-3:
        for i in range(y.size):
            ytmp[i] = y[i] + dt * f[i]
        if ytmp[_V] < 0.0:
            ytmp[_V] = 0.0
        _rhs(t + dt, ytmp, G, c, D, tab_t, tab_v, r, aux)
        n += 1
        if (aux[_X_SW + k] > 0.0) != (g_old > 0.0):
            for i in range(y.size):
                y[i] = ytmp[i]
                f[i] = r[i]
            for i in range(aux_y.size):
                aux_y[i] = aux[i]
            return t + dt, n
        dt *= 2.0
    return t, n


@register_jitable
def _locate(k, t, h, ga, gb, y, ynew, f0, f1, ytmp, G, c, D, tab_t, tab_v):
    """First instant in (t, t + h] where switching function k has changed sign, on the step's dense output.

    Illinois (regula falsi with halving of the stale end), bisection where the secant gives nothing; returns
    (the right end of the final bracket, where the function has the new sign; evaluations of the function,
    :func:`_switch`)."""
    a, b = 0.0, 1.0
    fa, fb = ga, gb
    pa = fa > 0.0
    side = 0
    n = 0
    tol = (EVENT_TOLERANCE_S + 8.0 * _EPS * abs(t)) / h
    while b - a > tol and n < 60:
        s = 0.5 * (a + b)
        if fa != fb and fa != 0.0 and fb != 0.0:
            sec = b - fb * (b - a) / (fb - fa)
            if a < sec < b:
                s = sec
        _hermite(s, h, y, ynew, f0, f1, N_DYN, ytmp)
        fs = _switch(k, t + s * h, ytmp, G, c, D, tab_t, tab_v)
        n += 1
        if (fs > 0.0) == pa:
            a, fa = s, fs
            if side == -1:
                fb *= 0.5
            side = -1
        else:
            b, fb = s, fs
            if side == 1:
                fa *= 0.5
            side = 1
    return t + b * h, n


# nogil: vpsim.batch runs variants on threads. fastmath "contract" alone lets LLVM fuse a multiply and an
# add (one rounding instead of two; no reassociation, NaN, infinity or signed-zero assumptions): 6 % less time
@kernel(_nrt=False, fastmath={"contract"})
def _integrate_ros(
    seg_t,
    seg_ratio,
    seg_gear,
    y0,
    tab_t,
    tab_v,
    c,
    D,
    rtol,
    h_max,
    thr,
    qthr,
    max_steps,
    out_t,
    out_y,
    out_aux,
    stats,
    fstats,
    work,
    aux,
    aux1,
    G,
):
    """RODAS3 from seg_t[0] to seg_t[-1], restarting at every seg_t[k] in gear seg_gear[k] of total ratio
    seg_ratio[k].

    Steps end at every node of the table (tab_t, tab_v) (where the cycle speed, or the open-loop throttle,
    has a kink) and at every event (a switching function changing sign, located on the dense output; the
    step is then taken again to end there). Arguments as :func:`_integrate`; ``qthr`` holds the rate scales
    of the fuel and distance in the error norm; stats: [accepted, rejected, rhs evaluations, status, events,
    Jacobians]. ``work`` (21 x len(y0)), ``aux`` and ``aux1`` (N_AUX), ``G`` (N_G) are scratch space; the
    state reached is left in ``work[0]``.
    """
    ny = y0.size
    y = work[0]
    ynew = work[1]
    ytmp = work[2]
    f0 = work[3]
    f1 = work[4]
    u1 = work[5]
    u2 = work[6]
    u3 = work[7]
    u4 = work[8]
    r = work[9]
    jac = work[10]
    winv = work[11]
    sw0 = work[12]
    scratch = work[13]
    ft = work[17]
    k3 = work[18]  # f at stages 3 and 4
    k4 = work[19]
    gq0 = work[14]  # the quadratures' Jacobian columns in v, p_i, z, w_e
    gq1 = work[15]
    gq2 = work[16]
    gq3 = work[20]
    for i in range(ny):
        y[i] = y0[i]
    pw = 1.0 / ROS_ORDER
    n_out = out_t.size
    n_tab = tab_t.size
    j_out = 0
    j_tab = 0
    accepted = 0
    rejected = 0
    nfev = 0
    events = 0
    n_jac = 0
    n_seg = seg_t.size - 1
    h_carry = 0.0
    k_event = 0
    # the right side jumps where an unlocked torque converter's state changes (lock-up, the drive engaged
    # or not): steps across such an instant need the crossing below (without one the kernel steps as before)
    jumps = D[_EXT] != 0.0 and c.converter_capacity_factor > 0.0
    nd = N_DYN if jumps else N_ERR  # the states the step solves for: w_e only with a converter
    for sgi in range(n_seg):
        t = seg_t[sgi]
        t_end = seg_t[sgi + 1]
        _gear(seg_ratio[sgi], seg_gear[sgi], c, G)
        last = sgi == n_seg - 1
        _rhs(t, y, G, c, D, tab_t, tab_v, f0, aux1)
        nfev += 1
        if jumps and aux1[_X_CONV] == 0.0:  # (the new gear's engine speed)
            y[_W] = aux1[_X_W]
            f0[_W] = 0.0
        for k in range(N_SW):
            sw0[k] = aux1[_X_SW + k]
        while j_out < n_out and out_t[j_out] <= t:
            for i in range(ny):
                out_y[j_out, i] = y[i]
            for i in range(aux1.size):
                out_aux[j_out, i] = aux1[i]
            j_out += 1
        span = t_end - t
        if span <= 0.0:
            continue
        hmax = h_max if h_max < span else span
        h = _initial_step(y, f0, thr, N_ERR, rtol, pw, hmax)  # (ode45's, with the order of this method)
        if h_carry > h:  # a gear change: the step the previous gear ended with, if larger
            h = h_carry if h_carry < hmax else hmax
        have_jac = False
        nofailed = True
        t_event = -1.0  # > t: the step is being taken again to end at a located event
        t_target = -1.0  # > t: ... at a jump's crossing estimated after a rejected step (jumps)
        h_want = h
        while True:
            hmin = 16.0 * _EPS * abs(t)
            while j_tab < n_tab and tab_t[j_tab] <= t + hmin:
                j_tab += 1
            t_stop = t_end
            if j_tab < n_tab and tab_t[j_tab] < t_stop:
                t_stop = tab_t[j_tab]
            # output times are stops too: the values there are the integrator's own, not interpolated
            j_stop = j_out
            while j_stop < n_out and out_t[j_stop] <= t + hmin:
                j_stop += 1
            if j_stop < n_out and out_t[j_stop] < t_stop:
                t_stop = out_t[j_stop]
            if t_event > t:
                tnew = t_event
                to_stop = False
            elif t_target > t and t_target < t_stop:
                tnew = t_target
                to_stop = False
            else:
                if h > hmax:
                    h = hmax
                if h < hmin:
                    h = hmin
                h_want = h
                to_stop = t + 1.1 * h >= t_stop
                tnew = t_stop if to_stop else t + h
            h = tnew - t
            # the Jacobian in v, p_i, z in closed form (task 0, once per step) and df/dt (task 3: from the PI
            # structure, or open loop a forward difference in t inside the table's current interval, where f
            # is smooth); then the evaluations of the right side, through one (inlined) call site: stages 3
            # and 4 (both at t + h; stage 2 reuses stage 1's f) and the step's end (the next step's stage 1)
            hg = h * _ROS_GAMMA
            ih = 1.0 / h
            task = 0 if not have_jac else N_DYN + 1
            d = 0.0
            errn = 0.0
            while task < N_DYN + 4:
                if task == N_DYN and D[_OPEN] == 0.0:
                    # closed loop, f depends on t only through the PI error e = v_ref(t) - v, and on (e, z)
                    # only through u_raw = K_p e + z, except dz/dt = K_i e + (u - u_raw)/T_t and e^2 (pi_law):
                    # df/dt = v_ref' df/de = v_ref' (K_p df/dz + K_i on the z row + 2e on the e^2 row)
                    slope = 0.0
                    if 0 < j_tab < n_tab:
                        slope = (tab_v[j_tab] - tab_v[j_tab - 1]) / (tab_t[j_tab] - tab_t[j_tab - 1])
                    kp = D[_KP]
                    for i in range(N_DYN):
                        ft[i] = slope * kp * jac[N_DYN * i + _Z]
                    for i in range(N_DYN, ny):
                        ft[i] = slope * kp * gq2[i]
                    ft[_Z] += slope * D[_KI]
                    vv0 = y[_V] if y[_V] > 0.0 else 0.0
                    ft[_ERR2] += slope * 2.0 * (aux1[_X_VREF] - vv0)
                    n_jac += 1
                    have_jac = True
                    task += 1
                    continue
                if task < N_DYN:
                    # the Jacobian in v, p_i and z in closed form (the model's equations differentiated), or
                    # by differences while the torque converter is unlocked
                    if aux1[_X_CONV] != 0.0:
                        nfev += _jacobian_fd(
                            t, y, f0, G, c, D, tab_t, tab_v, thr, jac, gq0, gq1, gq2, gq3, ytmp, r, aux
                        )
                    else:
                        _jacobian(y, aux1, G, c, D, jac, gq0, gq1, gq2, gq3)
                    task = N_DYN
                    continue
                tgt_f = r
                tgt_a = aux
                if task == N_DYN:
                    d = _FD_STEP * (abs(t) if abs(t) > 1.0 else 1.0)
                    if d > 0.5 * (t_stop - t):
                        d = 0.5 * (t_stop - t)
                    ts = t + d
                    d = ts - t
                    for i in range(nd):
                        ytmp[i] = y[i]
                else:
                    if task == N_DYN + 1:
                        # stages 1 and 2 of v, p_i, z (the quadratures' stages follow after the error test)
                        _inverse3(jac, 1.0 / hg, winv, nd)
                        for i in range(nd):
                            r[i] = f0[i] + (_WG1 * h) * ft[i]
                        _solve3(r, winv, u1, nd)
                        for i in range(nd):  # stage 2 at (t, y): f is stage 1's
                            r[i] = f0[i] + (_WC21 * ih) * u1[i] + (_WG2 * h) * ft[i]
                        _solve3(r, winv, u2, nd)
                        for i in range(nd):
                            ytmp[i] = y[i] + _WA31 * u1[i]
                        tgt_f = k3
                    elif task == N_DYN + 2:
                        for i in range(nd):
                            ytmp[i] = y[i] + _WA41 * u1[i] + _WA43 * u3[i]
                        tgt_f = k4
                    else:  # the right side at the step's end (the next step's first stage)
                        for i in range(nd):
                            ytmp[i] = ynew[i]
                        tgt_f = f1
                        tgt_a = aux1
                    ts = tnew
                _rhs_stage(ts, ytmp, G, c, D, tab_t, tab_v, tgt_f, tgt_a, task == N_DYN + 3)
                nfev += 1
                if task == N_DYN:
                    for i in range(ny):
                        ft[i] = (r[i] - f0[i]) / d
                    n_jac += 1
                    have_jac = True
                elif task == N_DYN + 1:
                    for i in range(nd):
                        r[i] = k3[i] + (_WC31 * u1[i] + _WC32 * u2[i]) * ih
                    _solve3(r, winv, u3, nd)
                elif task == N_DYN + 2:
                    for i in range(nd):
                        r[i] = k4[i] + (_WC41 * u1[i] + _WC42 * u2[i] + _WC43 * u3[i]) * ih
                    _solve3(r, winv, u4, nd)
                    for i in range(nd):
                        ynew[i] = y[i] + _WM1 * u1[i] + _WM3 * u3[i] + _WM4 * u4[i]
                    # error estimate u_4 (y_new minus the embedded solution), filtered by (I - h gamma J)^-1
                    # as Hairer & Wanner (IV.8, (8.19)-(8.20)) do for stiff codes, so that its part in the
                    # damped stiff (manifold) direction is not taken for error: e = (I/hg - J)^-1 u_4 / hg
                    _solve3(u4, winv, ytmp, nd)
                    for i in range(nd):
                        ytmp[i] = ytmp[i] / hg
                    # the quadratures (their columns of J are zero): each stage is linear in f0, df/dt, k3,
                    # k4 and the quadrature's row of J times the stages of v, p_i, z (w_e), so the step and
                    # the error estimate are one combination of these with weights of the step
                    # (_quadrature_weights): for the fuel and the distance now (their errors are in the
                    # norm), for the others once the step is accepted
                    qs, qe = _quadrature_weights(h, ih, hg, u1, u2, u3, u4, ytmp, nd)
                    for i in (_FUEL, _DIST):
                        ynew[i] = y[i] + _quadrature_sum(i, f0, ft, k3, k4, gq0, gq1, gq2, gq3, qs)
                        r[i] = _quadrature_sum(i, f0, ft, k3, k4, gq0, gq1, gq2, gq3, qe)
                    # the RMS norm over v, p_i, z (ode45's scales) and the fuel and distance (relative to
                    # their increment over the step plus a rate scale times h)
                    # (w_e too while a converter is unlocked)
                    err = 0.0
                    n_norm = N_ERR + 2
                    for m in range(N_ERR + 3):
                        if m < N_ERR:
                            i = m
                        elif m == N_ERR:
                            if aux1[_X_CONV] == 0.0:
                                continue
                            i = _W
                            n_norm += 1
                        else:
                            i = _FUEL if m == N_ERR + 1 else _DIST
                        sc = abs(y[i])
                        if abs(ynew[i]) > sc:
                            sc = abs(ynew[i])
                        if i < N_DYN:
                            if thr[i] > sc:
                                sc = thr[i]
                            q = ytmp[i] / sc
                        else:
                            sc = abs(ynew[i] - y[i]) + h * qthr[m - N_ERR - 1]
                            q = r[i] / sc
                        err += q * q
                    err = math.sqrt(err / n_norm)
                    errn = err / rtol
                    if not errn <= 1.0:  # also NaN: rejected, no evaluation at the end
                        break
                    for i in range(N_DYN, ny):
                        ynew[i] = y[i] + _quadrature_sum(i, f0, ft, k3, k4, gq0, gq1, gq2, gq3, qs)
                    if ynew[_V] < 0.0:  # keep v >= 0 (the car does not roll backwards)
                        ynew[_V] = 0.0
                task += 1
            if not errn <= 1.0:  # also NaN
                rejected += 1
                if accepted + rejected >= max_steps:
                    stats[0], stats[1], stats[2], stats[3] = accepted, rejected, nfev, STATUS_TOO_MANY_STEPS
                    stats[4], stats[5] = events, n_jac
                    return
                if h <= hmin:
                    stats[0], stats[1], stats[2], stats[3] = accepted, rejected, nfev, STATUS_STEP_TOO_SMALL
                    stats[4], stats[5] = events, n_jac
                    return
                fac = 0.2
                if errn == errn and nofailed:
                    if errn < _ERR_AT_FAC_MIN:  # (the cube root only where the bound does not apply)
                        fac = 0.9 / np.cbrt(errn)  # errn^(-1/ROS_ORDER): a cube root costs less than a power
                        if fac < 0.2:
                            fac = 0.2
                elif errn == errn:
                    fac = 0.5
                h_tried = h
                h = h * fac
                nofailed = False
                t_event = -1.0
                t_target = -1.0
                # a switching function that changes sign inside the rejected step: where the right side
                # jumps there (the unlocking converter's engine speed and fuel) no step across passes the
                # fuel's error test, however short. The next try ends where the function crosses zero along
                # the step's explicit Euler line (bisection), from where Euler steps take it across (as after
                # an event); a crossing the line does not show is left to the step size
                th = 1.0
                for i in range(N_DYN):
                    ytmp[i] = y[i] + h_tried * f0[i]
                for k in range(N_SW if jumps else 0):
                    g_a = sw0[k]
                    g_b = _switch(k, t + h_tried, ytmp, G, c, D, tab_t, tab_v)
                    if (g_a > 0.0) != (g_b > 0.0) and abs(g_b) > SWITCH_SIGNIFICANCE[k]:
                        sa, sb = 0.0, 1.0
                        while (sb - sa) * h_tried > EVENT_TOLERANCE_S:
                            sm = 0.5 * (sa + sb)
                            for i in range(N_DYN):
                                ytmp[i] = y[i] + sm * h_tried * f0[i]
                            if (_switch(k, t + sm * h_tried, ytmp, G, c, D, tab_t, tab_v) > 0.0) == (
                                g_a > 0.0
                            ):
                                sa = sm
                            else:
                                sb = sm
                        if sa < th:
                            th = sa
                            k_event = k
                        for i in range(N_DYN):
                            ytmp[i] = y[i] + h_tried * f0[i]
                if th < 1.0 and th * h_tried > EVENT_TOLERANCE_S:
                    t_target = t + th * h_tried
                elif th < 1.0:  # at the crossing already: across it, and the step from there
                    t_x, n_x = _cross(
                        k_event,
                        t,
                        t_stop - hmin,
                        y,
                        f0,
                        aux1,
                        sw0[k_event],
                        ytmp,
                        r,
                        aux,
                        G,
                        c,
                        D,
                        tab_t,
                        tab_v,
                    )
                    nfev += n_x
                    if t_x > t:
                        t = t_x
                        for k in range(N_SW):
                            sw0[k] = aux1[_X_SW + k]
                        have_jac = False
                continue
            if t_event < 0.0:
                # did the right side change form inside the step? locate the first such instant
                tb_min = tnew
                for k in range(N_SW):
                    g_a, g_b = sw0[k], aux1[_X_SW + k]
                    if (g_a > 0.0) != (g_b > 0.0) and abs(g_b) > SWITCH_SIGNIFICANCE[k]:
                        tb, _ = _locate(k, t, h, g_a, g_b, y, ynew, f0, f1, ytmp, G, c, D, tab_t, tab_v)
                        if tb < tb_min:
                            tb_min = tb
                            k_event = k
                if tb_min < tnew and tb_min - t > EVENT_TOLERANCE_S + 1e-3 * h:
                    for k in range(N_SW):
                        g_a, g_b = sw0[k], aux1[_X_SW + k]
                        if (g_a > 0.0) != (g_b > 0.0) and abs(g_b) > SWITCH_SIGNIFICANCE[k]:
                            fstats[1 + k] += 1.0
                    events += 1
                    t_event = tb_min  # take the step again, to end there
                    continue
            accepted += 1
            if accepted + rejected >= max_steps:
                stats[0], stats[1], stats[2], stats[3] = accepted, rejected, nfev, STATUS_TOO_MANY_STEPS
                stats[4], stats[5] = events, n_jac
                return
            e_abs = abs(aux1[_X_VREF] - ynew[_V])
            if e_abs > fstats[0]:
                fstats[0] = e_abs
            done = tnew >= t_end
            while j_out < n_out and (out_t[j_out] < tnew or ((last or not done) and out_t[j_out] <= tnew)):
                if out_t[j_out] == tnew:
                    for i in range(ny):
                        out_y[j_out, i] = ynew[i]
                    for i in range(aux1.size):
                        out_aux[j_out, i] = aux1[i]
                else:
                    _hermite((out_t[j_out] - t) / h, h, y, ynew, f0, f1, ny, out_y[j_out])
                    _rhs(out_t[j_out], out_y[j_out], G, c, D, tab_t, tab_v, scratch, out_aux[j_out])
                j_out += 1
            if (
                jumps
                and (t_event > t or t_target > t)
                and (aux1[_X_SW + k_event] > 0.0) == (sw0[k_event] > 0.0)
                and not done
            ):
                # the step taken again to end at the event ended short of it (the event's bracket is on the
                # first step's dense output, or on the Euler line of a rejected step; the step's own solution
                # differs from either by its local error): cross it, so that the next step starts on the new
                # side of a right side that jumps there, where, started on the old side, its error would not
                # shrink with h
                tnew, n_x = _cross(
                    k_event,
                    tnew,
                    t_stop - hmin,
                    ynew,
                    f1,
                    aux1,
                    sw0[k_event],
                    ytmp,
                    r,
                    aux,
                    G,
                    c,
                    D,
                    tab_t,
                    tab_v,
                )
                nfev += n_x
            # next step: the controller's proposal (no growth right after a rejection), or the step wanted
            # before it was cut to a stop or an event
            fac = 5.0
            if errn > _ERR_AT_FAC_MAX:  # (below it the bound applies: no cube root)
                fac = 0.9 / np.cbrt(errn)  # errn^(-1/ROS_ORDER)
                if fac > 5.0:
                    fac = 5.0
                if fac < 0.2:
                    fac = 0.2
            if not nofailed and fac > 1.0:
                fac = 1.0
            h_next = h * fac
            if (to_stop or t_event > t) and h_want > h_next:
                h_next = h_want
            t = tnew
            for i in range(ny):
                y[i] = ynew[i]
                f0[i] = f1[i]
            if jumps and aux1[_X_CONV] == 0.0:  # w_e is the engine's speed wherever it is no state
                y[_W] = aux1[_X_W]
                f0[_W] = 0.0
            for k in range(N_SW):
                sw0[k] = aux1[_X_SW + k]
            have_jac = False
            nofailed = True
            t_event = -1.0
            t_target = -1.0
            h = h_next
            if done:
                h_carry = h_next
                break
    stats[0], stats[1], stats[2], stats[3] = accepted, rejected, nfev, STATUS_OK
    stats[4], stats[5] = events, n_jac
    return


# --- the method -------------------------------------------------------------------------------------------


def settings(params, pi: PIDriver | None = None, mode: str = "paper") -> np.ndarray:
    """The driver's and the mode's settings D of the compiled integrator (the model's constants are the
    parameter record, :func:`vpsim.model.record.record`). Without a driver ``pi`` its entries stay zero."""
    D = np.zeros(N_SETTINGS)
    if pi is not None:
        D[_KP : _KB + 1] = pi.as_array()
    realistic = rules.canonical_mode(mode) == "realistic"
    D[_EXT] = 1.0 if realistic else 0.0
    D[_AIDLE] = memo(params, "idle_throttle", lambda q: en.idle_throttle(record(q))) if realistic else 0.0
    D[_BAND] = BAND_KMH / 3.6
    return D


def initial_state(cycle, params, ratio: float, pi: PIDriver, mode: str) -> np.ndarray:
    """State at the cycle's start: steady manifold for the cycle's initial speed and acceleration.

    At standstill: ``paper`` starts with the manifold at the pressure of zero crank torque at w_e = 0 and the
    throttle closed; ``extended`` at the idle steady state with a zero pedal command.
    """
    y = np.zeros(NY)
    v0, a0 = _cycle_start(cycle.time_s, cycle.speed_mps)
    paper = rules.canonical_mode(mode) == "paper"
    recs = kernel_records(params)
    _start_state_kernel(float(v0), float(a0), float(ratio), paper, pi.u_lo, pi.u_hi, recs, y)
    return y


@register_jitable
def _cycle_start(t, v):
    """(speed, acceleration) at the cycle's start."""
    return v[0], (v[1] - v[0]) / (t[1] - t[0])


@register_jitable
def _start_state(v0, a0, ratio, paper, u_lo, u_hi, c, y):
    """Fill ``y`` (zeros) with :func:`initial_state`'s state (``paper``: the paper mode); compiled for one
    run (:func:`_start_state_kernel`) and into :func:`_variants` for the batch."""
    y[_V] = v0
    y[_W] = c.idle_speed
    if v0 > 0.0:
        w = vh.engine_speed(v0, ratio, c)
        t_cr = vh.crank_torque_demand(vh.wheel_force(v0, a0, c), ratio, vh.engine_speed(a0, ratio, c), c)
        p, u = en.steady_point(t_cr, w, c)
        y[_W] = w
        y[_P] = p
        y[_Z] = u_hi if u > u_hi else (u_lo if u < u_lo else u)
    elif paper:
        y[_P] = en.intake_pressure_for_torque(0.0, 0.0, c)
        y[_Z] = u_lo
    else:
        y[_P] = en.intake_pressure_for_torque(0.0, c.idle_speed, c)
        y[_Z] = 0.0


@kernel
def _start_state_kernel(v0, a0, ratio, paper, u_lo, u_hi, recs, y):
    """One run's :func:`_start_state`, compiled (the model's steady-state solves in plain Python took 20 us
    of a run; ``recs``: the record as an array, whose dispatch costs less than a record's)."""
    _start_state(v0, a0, ratio, paper, u_lo, u_hi, recs[0], y)


# v (m/s), p_i (Pa), z (m²): ode45's atol/rtol per state; w_e (rad/s, a car with a converter): the idle speed
ERROR_THRESHOLDS = np.array([1.0, 1.0e4, 1.0e-4, 80.0])
# the fuel's and the distance's error over a step is measured against their increment plus these rates times
# the step: an error per unit of fuel burnt and distance driven, so the totals' relative error stays ~rtol
# kg/s: the flow of a 2 L engine under a firm load. The fuel sets the step in most steps (UDDS, driver 1,
# realistic mode: 1,796 of 3,004 accepted and 457 of 816 rejected steps at 1 g/s, the flow of steady driving),
# and the cycle total needs no more than its 5e-4 target. At 4 g/s: 14-17 % fewer evaluations on UDDS, cycle
# fuel within 2.4e-4 of the rtol 1e-8 reference on NEDC, FTP-75 and US06 (1.4e-4 at 1 g/s, 1.8e-4 at 2 g/s)
FUEL_RATE_SCALE = 4.0e-3
DISTANCE_RATE_SCALE = 10.0  # m/s
SOLVERS = ("rosenbrock", "dopri5")
DEFAULT_SOLVER = "rosenbrock"
MAX_STEPS = 2_000_000  # accepted and rejected steps of one run, beyond which it stops with an error


@register_jitable
def quadrature_scales(c) -> np.ndarray:
    """Rate scales of the fuel (kg/s) and distance (m/s) in the Rosenbrock error norm."""
    return np.array([FUEL_RATE_SCALE, DISTANCE_RATE_SCALE], dtype=np.float64)


@register_jitable
def error_scales(c) -> np.ndarray:
    """The Rosenbrock error norm's scales of v, p_i and z: each state's error is measured against
    max(|y|, scale) (ode45's threshold), the scale being the state's natural size in this car: 1 m/s, the
    ambient pressure (the manifold's range), the pedal's range (the command's upper end,
    ``engine.max_command``). ode45's fixed thresholds (:data:`ERROR_THRESHOLDS`, 10 kPa and 1e-4 m², which
    the dopri5 solver keeps for the paper's Table 3) measured a manifold at 30 kPa and a PI state near 0
    against their own size: on UDDS (driver 1, paper mode) 2.43 accepted steps per cycle second against
    1.99, for a cycle fuel that stays within 1.4e-4 of the rtol 1e-8 reference (5.6e-5 before). w_e (while it
    is a state, behind an unlocked converter): the idle speed."""
    return np.array([1.0, c.ambient_pressure, en.max_command(c), c.idle_speed])


def integrate(
    seg_t,
    seg_ratio,
    y0,
    c,
    D,
    table_t,
    table_v,
    *,
    open_loop=False,
    rtol=1e-3,
    max_step=np.inf,
    out_t=None,
    max_steps=MAX_STEPS,
    solver=DEFAULT_SOLVER,
    scales=None,
    seg_gear=None,
):
    """Run the kernel from seg_t[0] to seg_t[-1], restarting at each seg_t[k] with ratio seg_ratio[k] in
    gear number seg_gear[k] (default: every segment in a gear of its own above any lock-up gear, which only
    a torque converter reads).

    (table_t, table_v) is the cycle speed the PI driver follows or, with ``open_loop``, the throttle area
    fed to the engine as it is. ``solver``: ``rosenbrock`` (RODAS3, the default) or ``dopri5`` (the
    paper's ode45). ``scales``: the Rosenbrock error scales of ``c`` (:func:`error_scales`) if already at
    hand. Returns (y_end, out_y, out_aux, info); raises VpsimError if the solver fails.
    """
    if solver not in SOLVERS:
        raise VpsimError(f"unknown solver {solver!r}; expected one of {', '.join(SOLVERS)}")
    out_t = np.array(seg_t[-1:] if out_t is None else out_t, dtype=float)
    out_y = np.full((out_t.size, NY), np.nan)
    out_aux = np.full((out_t.size, N_AUX), np.nan)
    stats = np.zeros(6, dtype=np.int64)
    fstats = np.zeros(1 + N_SW)
    D = np.array(D, dtype=float)
    D[_OPEN] = 1.0 if open_loop else 0.0
    table_t = np.asarray(table_t, dtype=float)
    D[_TAB_INV] = (table_t.size - 1) / (table_t[-1] - table_t[0]) if table_t.size > 1 else 0.0
    # np.array copies: one compiled signature for all calls (read-only inputs would compile another)
    args = (
        np.array(seg_t, dtype=float),
        np.array(seg_ratio, dtype=float),
        np.full(len(seg_ratio), np.inf) if seg_gear is None else np.array(seg_gear, dtype=float),
        np.array(y0, dtype=float),
        np.array(table_t, dtype=float),
        np.array(table_v, dtype=float),
        c,
        D,
        float(rtol),
        float(max_step),
        ERROR_THRESHOLDS if solver == "dopri5" else (error_scales(c) if scales is None else scales),
    )
    if solver == "dopri5":
        work = np.zeros((11, NY))
        _integrate(
            *args, int(max_steps), out_t, out_y, out_aux, stats, fstats, work, np.empty(N_AUX), np.empty(N_G)
        )
    else:
        work = np.zeros((21, NY))
        _integrate_ros(
            *args,
            quadrature_scales(c),
            int(max_steps),
            out_t,
            out_y,
            out_aux,
            stats,
            fstats,
            work,
            np.empty(N_AUX),
            np.empty(N_AUX),
            np.empty(N_G),
        )
    y_end = work[0].copy()
    if stats[3] == STATUS_STEP_TOO_SMALL:
        raise VpsimError(f"forward integration failed: step size below the minimum after t = {seg_t[0]:g} s")
    if stats[3] == STATUS_TOO_MANY_STEPS:
        raise VpsimError(f"forward integration stopped after {max_steps} steps (rtol {rtol:g})")
    info = {
        "solver": solver,
        "accepted_steps": int(stats[0]),
        "rejected_steps": int(stats[1]),
        "rhs_evaluations": int(stats[2]),
        "max_speed_error_mps": float(fstats[0]),
    }
    if solver == "rosenbrock":
        info["events"] = int(stats[4])
        info["jacobians"] = int(stats[5])
        info["events_by_switch"] = {name: int(n) for name, n in zip(SWITCHES, fstats[1:], strict=True)}
    return y_end, out_y, out_aux, info


def segments(cycle, schedule: GearSchedule, ratios) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Restart instants (cycle start, every gear change, cycle end), the ratio engaged after each and the
    gear's number (1-based)."""
    t0, t1 = float(cycle.time_s[0]), float(cycle.time_s[-1])
    shifts = schedule.shift_times
    shifts = shifts[(shifts > t0) & (shifts < t1)]
    seg_t = np.concatenate([[t0], shifts, [t1]])
    gears = schedule.gear_at(seg_t[:-1])
    return seg_t, np.asarray(ratios, float)[gears - 1], gears


def warm_up(solver: str | None = None) -> None:
    """Load (or compile) the kernels of ``solver`` (default: both), so that run times measure the
    simulation only. Each solver's integrator is a kernel of its own: a run compiles only the one it uses."""
    solvers = SOLVERS if solver is None else (solver,)
    kernels = {"rosenbrock": _integrate_ros, "dopri5": _integrate}
    if _start_state_kernel.overloads and all(kernels[s].overloads for s in solvers):
        return
    from ..params import load_parameters

    p = load_parameters("hofman2011")
    _start_state_kernel(0.0, 0.0, 10.0, True, 0.0, 1.0, kernel_records(p), np.zeros(NY))
    for s in solvers:
        integrate(
            np.array([0.0, 1.0]),
            np.array([10.0]),
            np.zeros(NY),
            record(p),
            np.zeros(N_SETTINGS),
            np.array([0.0, 1.0]),
            np.zeros(2),
            out_t=np.array([0.0, 1.0]),
            solver=s,
        )


# --- many design variants in one compiled call (vpsim.batch) ----------------------------------------------

V_FUEL, V_DIST, V_OUTSIDE, V_MAX_ERR, V_STEPS, V_STATUS = range(6)
N_VARIANT_OUT = 6


@kernel(parallel=True)
def _variants(
    seg_t, n_seg, seg_gear, ratios, sched_of, tab_t, tab_v, recs, D_all, paper, rtol, h_max, max_steps, out
):
    """:func:`run` without series for every variant m (record ``recs[m]``, settings ``D_all[m]``), in
    parallel: the same start (:func:`_start_state`), error scales and kernel (:func:`_integrate_ros`).
    Schedule s = sched_of[m] restarts at seg_t[s, :n_seg[s] + 1] in the gears seg_gear[s] (1-based).
    ``max_steps`` comes in as an argument, not as the constant MAX_STEPS: a constant would be a literal type,
    a signature of :func:`_integrate_ros` of its own, compiled again (about 17 s) beside the one run's."""
    for m in prange(recs.size):
        c = recs[m]
        s = sched_of[m]
        ns = n_seg[s]
        st = np.empty(ns + 1)
        sr = np.empty(ns)
        sg = np.empty(ns)
        for k in range(ns + 1):
            st[k] = seg_t[s, k]
        for k in range(ns):
            sr[k] = ratios[m, seg_gear[s, k] - 1]
            sg[k] = seg_gear[s, k]
        D = D_all[m].copy()
        if D[_EXT] != 0.0:
            D[_AIDLE] = en.idle_throttle(c)
        y0 = np.zeros(NY)
        v0, a0 = _cycle_start(tab_t, tab_v)
        _start_state(v0, a0, sr[0], paper, D[_ULO], D[_UHI], c, y0)
        stats = np.zeros(6, dtype=np.int64)
        fstats = np.zeros(1 + N_SW)
        work = np.zeros((21, NY))
        _integrate_ros(
            st,
            sr,
            sg,
            y0,
            tab_t,
            tab_v,
            c,
            D,
            rtol[m],
            h_max,
            error_scales(c),
            quadrature_scales(c),
            max_steps,
            np.zeros(0),
            np.zeros((0, NY)),
            np.zeros((0, N_AUX)),
            stats,
            fstats,
            work,
            np.empty(N_AUX),
            np.empty(N_AUX),
            np.empty(N_G),
        )
        out[m, V_FUEL] = work[0, _FUEL]
        out[m, V_DIST] = work[0, _DIST]
        out[m, V_OUTSIDE] = work[0, _OUTSIDE]
        out[m, V_MAX_ERR] = fstats[0]
        out[m, V_STEPS] = stats[0]
        out[m, V_STATUS] = stats[3]


def variant_settings(params, pi: PIDriver, mode: str, vehicle, engine, recs) -> np.ndarray:
    """:func:`settings` for every variant (n_var, N_SETTINGS): the driver's and mode's settings of ``params``
    with the command range, throttle floor and brake gain of each variant (``vehicle``, ``engine``: sections
    whose varied fields are arrays; ``recs``: their records), from the same rule as one run
    (:func:`vpsim.drivers.pi.command_limits`)."""
    from ..drivers.pi import command_limits

    D = np.tile(settings(params, pi, mode), (recs.size, 1))
    u_lo, u_hi, a_min, gain = command_limits(vehicle, engine, en.max_command(recs), mode)
    for k, x in ((_ULO, u_lo), (_UHI, u_hi), (_AMIN, a_min), (_KB, gain)):
        D[:, k] = x
    return D


def run_variants(cycle, recs, ratios, schedules, schedule_of_variant, D_all, mode: str, rtol) -> np.ndarray:
    """The forward method (Rosenbrock, no series) for many variants in one compiled call, parallel over them.

    ``recs``: record array (n_var,); ``ratios``: (n_var, n_gears) total ratios; ``schedules``: GearSchedules;
    ``schedule_of_variant``: index into ``schedules``; ``D_all``: (n_var, N_SETTINGS) driver and mode settings
    (:func:`settings`; the idle throttle of the realistic mode is the kernel's, per variant); ``rtol``: per
    variant. Returns (n_var, N_VARIANT_OUT): fuel (kg), distance (m), seconds outside the band, largest speed
    error at the steps' ends (m/s), accepted steps, solver status. Each row is what :func:`run` gives the
    variant with ``keep_series=False`` (a test checks it).
    """
    n_var = recs.size
    segs = [segments(cycle, sch, np.arange(1.0, sch.gear.max(initial=1) + 1.0))[:2] for sch in schedules]
    n_seg = np.array([st.size - 1 for st, _ in segs], dtype=np.int64)
    seg_t = np.zeros((len(segs), n_seg.max() + 1))
    seg_gear = np.ones((len(segs), n_seg.max()), dtype=np.int64)
    for k, (st, g) in enumerate(segs):
        seg_t[k, : st.size] = st
        seg_gear[k, : g.size] = np.rint(g)
    D = np.array(D_all, dtype=float)
    table_t = np.array(cycle.time_s, dtype=float)
    D[:, _OPEN] = 0.0
    D[:, _TAB_INV] = (table_t.size - 1) / (table_t[-1] - table_t[0])
    out = np.empty((n_var, N_VARIANT_OUT))
    _variants(
        seg_t,
        n_seg,
        seg_gear,
        np.ascontiguousarray(ratios, dtype=float),
        np.asarray(schedule_of_variant, dtype=np.int64),
        table_t,
        np.array(cycle.speed_mps, dtype=float),
        np.asarray(recs).view(np.ndarray),
        np.ascontiguousarray(D),
        rules.canonical_mode(mode) == "paper",
        np.ascontiguousarray(np.broadcast_to(np.asarray(rtol, dtype=float), (n_var,))),
        float(cycle.time_s[-1] - cycle.time_s[0]) / 50.0,
        int(MAX_STEPS),
        out,
    )
    return out


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
    kp: float | None = None,
    ki: float | None = None,
    tracking_time_s: float | None = None,
    solver: str = DEFAULT_SOLVER,
) -> Result:
    """Run the FDM on ``cycle`` with PI driver ``driver`` in ``mode`` and return the :class:`Result`.

    ``solver``: ``rosenbrock`` (RODAS3, the default) or ``dopri5`` (the paper's ode45; module docstring);
    ``rtol`` (default the parameter set's ``simulation.ode_relative_tolerance``, 1e-3 like Simulink),
    ``max_step`` (default: a fiftieth of the cycle duration, Simulink's "auto"); ``kp``/``ki`` (and the
    anti-windup ``tracking_time_s``) override the driver's gains, as the driver tuning does;
    ``keep_series=False`` skips the time series (dense output at the cycle's samples, or at the sorted
    ``output_times`` within the cycle);

    The tracking figures (max and RMS speed error, seconds outside the +-2 km/h band) are integrated along
    the solution: the RMS and the seconds as quadrature states, the maximum over the step ends and the
    output samples.
    """
    from dataclasses import replace

    mode = rules.canonical_mode(mode)
    if solver not in SOLVERS:
        raise VpsimError(f"unknown solver {solver!r}; expected one of {', '.join(SOLVERS)}")
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
    pi = memo(  # (frozen, like the parameter set it is derived from)
        params,
        f"forward_pi_driver:{driver}:{mode}:{tracking_time_s!r}",
        lambda p: PIDriver.from_params(p, driver, mode, tracking_time_s),
    )
    if schedule is None:
        from ..model.maps import cached_engine_map

        schedule = default_schedule(cycle, params, cached_engine_map(params.engine))
    duration = float(cycle.time_s[-1] - cycle.time_s[0])
    h_max = duration / 50.0 if max_step is None else float(max_step)
    if not h_max > 0:
        raise VpsimError(f"max_step = {max_step!r} must be positive")
    warm_up(solver)

    t_cpu = time.process_time()
    ratios = np.asarray(params.transmission.ratios)
    seg_t, seg_ratio, seg_gear = segments(cycle, schedule, ratios)
    c = record(params)
    D = settings(params, pi, mode)
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
        c,
        D,
        cycle.time_s,
        cycle.speed_mps,
        rtol=rtol,
        max_step=h_max,
        out_t=out_t,
        solver=solver,
        seg_gear=seg_gear,
        scales=memo(params, "forward_error_scales", lambda p: error_scales(record(p))),
    )
    fuel_kg = float(y_end[_FUEL])
    distance = float(y_end[_DIST])
    cpu = time.process_time() - t_cpu

    info.update(restarts=int(seg_t.size - 2), rtol=rtol, max_step_s=h_max)
    v = out_y[:, _V]
    on_samples = out_t is cycle.time_s  # the default output: the cycle's own samples
    v_ref = cycle.speed_mps.copy() if on_samples else np.interp(out_t, cycle.time_s, cycle.speed_mps)
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
        accessories=float(y_end[_E_ACC]),
    )
    series = {}
    if keep_series:
        x = out_aux
        gear = schedule.on_cycle(cycle).copy() if on_samples else schedule.gear_at(out_t)
        series = {
            "time_s": out_t.copy(),
            "reference_speed_mps": v_ref,
            "speed_mps": v,
            "accel_mps2": x[:, _X_ACC],
            "gear": gear,
            "gearbox_ratio": gearbox_ratio_series(params, gear),
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
    if solver == "dopri5":
        notes = [
            f"Dormand-Prince 5(4), rtol {rtol:g}: {info['accepted_steps']} steps ({info['rejected_steps']} "
            "rejected), "
            f"{info['restarts']} restarts at gear changes",
        ]
    else:
        notes = [
            f"Rosenbrock RODAS3, rtol {rtol:g}: {info['accepted_steps']} steps ({info['rejected_steps']} "
            f"rejected), {info['restarts']} restarts at gear changes, {info['events']} located events",
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
        limits=limits_of(params),
        solver=info,
    )
