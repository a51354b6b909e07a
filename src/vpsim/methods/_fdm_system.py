"""The forward method's system: its state, settings and switching functions, the right side (the model's
equations, :mod:`vpsim.model`, and nothing else), its closed-form and finite-difference Jacobians and the
integrators' shared helpers. :mod:`vpsim.methods.forward` runs it; its docstring describes the states.
"""

from __future__ import annotations

import math
import types

from numba.extending import register_jitable

from ..drivers.pi import pedal_split, pi_law
from ..model import engine as en
from ..model import rules
from ..model import tables as tb
from ..model import vehicle as vh

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

_EPS = 2.220446049250313e-16
_FD_STEP = 1.4901161193847656e-08  # sqrt(eps): forward-difference increment relative to the state's scale
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
