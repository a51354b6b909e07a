"""The forward method's default integrator, RODAS3 (``solver="rosenbrock"``; :mod:`vpsim.methods.forward`
describes it, docs/methods.md measures it), with its event location and dense output.
"""

from __future__ import annotations

import math

import numpy as np
from numba.extending import register_jitable

from ..drivers.pi import pi_law
from ..model import engine as en
from ..model import rules
from ..model import tables as tb
from ..model import vehicle as vh
from ..model._compile import kernel
from ._fdm_system import (
    _AMIN,
    _AWG,
    _DIST,
    _EPS,
    _ERR2,
    _EXT,
    _FD_STEP,
    _FUEL,
    _G_GEAR,
    _G_I,
    _KI,
    _KP,
    _OPEN,
    _P,
    _SW_CLUTCH,
    _SW_CONVERTER,
    _SW_LOCKUP,
    _SW_MOVING,
    _SW_SLIP_TORQUE,
    _TAB_INV,
    _UHI,
    _ULO,
    _V,
    _W,
    _X_CONV,
    _X_SW,
    _X_VREF,
    _X_W,
    _Z,
    N_DYN,
    N_ERR,
    N_SW,
    STATUS_OK,
    STATUS_STEP_TOO_SMALL,
    STATUS_TOO_MANY_STEPS,
    SWITCH_SIGNIFICANCE,
    _gear,
    _initial_step,
    _jacobian,
    _jacobian_fd,
    _rhs,
    _rhs_stage,
    _switch_value,
)

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
