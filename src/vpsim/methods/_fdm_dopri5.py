"""The paper's integrator for the forward method: Dormand-Prince 5(4) as ode45 (``solver="dopri5"``;
:mod:`vpsim.methods.forward` describes it), compiled on its own so that a run with the default solver never
compiles it.
"""

from __future__ import annotations

from numba.extending import register_jitable

from ..model._compile import kernel
from ._fdm_system import (
    _EPS,
    _ERR2,
    _EXT,
    _OUTSIDE,
    _V,
    _X_VREF,
    N_DYN,
    N_ERR,
    STATUS_OK,
    STATUS_STEP_TOO_SMALL,
    STATUS_TOO_MANY_STEPS,
    _gear,
    _initial_step,
    _rhs,
    _rhs_stage,
)

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
            # a duration and a square integrate to no less than nothing, and the time outside the band to
            # no more than the step: the order-5 weights (one of them negative) gave the indicator's
            # quadrature a negative increment over steps where it switched (trace miss -0.12 s on UDDS)
            if ynew[_OUTSIDE] < y[_OUTSIDE]:
                ynew[_OUTSIDE] = y[_OUTSIDE]
            elif ynew[_OUTSIDE] > y[_OUTSIDE] + h:
                ynew[_OUTSIDE] = y[_OUTSIDE] + h
            if ynew[_ERR2] < y[_ERR2]:
                ynew[_ERR2] = y[_ERR2]
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
