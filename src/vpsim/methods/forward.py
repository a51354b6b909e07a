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

import numpy as np
from numba import prange
from numba.extending import register_jitable

from ..drivers.pi import PIDriver
from ..errors import VpsimError
from ..gears import GearSchedule, gearbox_ratio_series, schedule_for
from ..model import engine as en
from ..model import rules
from ..model import vehicle as vh
from ..model._compile import compiled, kernel
from ..model.record import kernel_records, memo, record
from ..result import EnergyBalance, Result, TraceMiss, limits_of

# the forward method's parts, in one namespace (tests and benchmarks reach them through this module)
from ._fdm_dopri5 import _integrate
from ._fdm_rosenbrock import (  # noqa: F401
    _integrate_ros,
    _quadrature_sum,
    _quadrature_weights,
    _switch,
)
from ._fdm_system import (  # noqa: F401
    _AIDLE,
    _AMIN,
    _BAND,
    _DIST,
    _E_ACC,
    _E_AERO,
    _E_BRAKE,
    _E_DRV,
    _E_ENG,
    _E_FRIC,
    _E_IDLE,
    _E_IND,
    _E_PUMP,
    _E_ROLL,
    _E_VEH,
    _ERR2,
    _EXT,
    _FUEL,
    _KB,
    _KI,
    _KP,
    _OPEN,
    _OUTSIDE,
    _P,
    _SW_SAT_HI,
    _SW_SAT_LO,
    _TAB_INV,
    _UHI,
    _ULO,
    _V,
    _W,
    _X_ACC,
    _X_AENG,
    _X_BRK,
    _X_CMD,
    _X_COUPLED,
    _X_FIRED,
    _X_MF,
    _X_MFU,
    _X_SW,
    _X_TCR,
    _X_TE,
    _X_THR,
    _X_VREF,
    _X_W,
    _Z,
    BAND_KMH,
    N_AUX,
    N_G,
    N_SETTINGS,
    N_SW,
    NY,
    STATUS_OK,
    STATUS_STEP_TOO_SMALL,
    STATUS_TOO_MANY_STEPS,
    SWITCHES,
    _gear,
    _jacobian,
    _rhs,
)

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
    if compiled(_start_state_kernel, *(kernels[s] for s in solvers)):
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
        schedule = schedule_for(cycle, params)
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
    stop_start = params.simulation.stop_start
    if stop_start and mode == "paper":
        raise VpsimError(
            "simulation.stop_start needs the realistic mode's clutch: in paper mode the forward car's engine "
            "stays coupled at rest (use --mode realistic, or set stop_start = false)"
        )
    if stop_start and output_times is not None:
        raise VpsimError("simulation.stop_start reads the cycle's samples: output_times cannot be set")
    if not keep_series and not stop_start:
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
    starts, stopped = 0, None
    if stop_start:
        y_end, starts, stopped = _stop_engine_at_rest(cycle, params, y_end, out_y, out_aux)
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
        if stop_start:  # the samples inside a stop: the standing engine's (as the backward method's)
            inside = np.zeros(out_t.size, dtype=bool)
            inside[1:-1] = stopped[:-1] & stopped[1:]
            for key in ("engine_speed_radps", "crank_torque_nm", "engine_torque_nm"):
                series[key][inside] = 0.0
            for key in ("fuel_flow_kgps", "fuel_flow_used_kgps"):
                series[key][inside] = 0.0
            for key in ("intake_pressure_pa", "throttle_area_m2"):
                series[key][inside] = np.nan
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
    if stop_start:
        stood = float(np.diff(cycle.time_s)[stopped].sum())
        notes.append(f"stop-start: {starts} engine restarts, {stood:.0f} s stopped")
    r = Result(
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
    if stop_start:
        r.solver.update(engine_starts=starts)
    return r


# the engine's side of the balance: its terms stand with it while the clutch is open (indicated = friction +
# pumping + its kinetic energy + the idle governor + the accessories, the clutch passing nothing)
_ENGINE_SIDE = (_FUEL, _E_IND, _E_FRIC, _E_PUMP, _E_ENG, _E_IDLE, _E_ACC)  # (fuel, indicated, then the rest)


def _stop_engine_at_rest(cycle, params, y_end, out_y, out_aux):
    """Stop-start (``simulation.stop_start``) on the forward car: (the totals, the restarts, the stopped
    intervals). The engine stops in the cycle's intervals at rest after the first move
    (:func:`vpsim.model.rules.stopped_at_rest`) where the car's clutch is open at both of the interval's
    samples (the driver may still be braking the car to a stop as the cycle rests; a coupled engine keeps
    running). The integration carries the idling engine through the stop, so its state at the restart is
    the idling one the start's fuel buys; its fuel and every engine-side term over the stopped intervals come
    off the totals (the increments of the quadrature states between the samples), and each restart costs
    ``hybrid.engine_start_fuel``, as on the backward method."""
    t, v = cycle.time_s, cycle.speed_mps
    free = out_aux[:, _X_COUPLED] <= 0.5
    stopped, starts = rules.stopped_at_rest(
        0.5 * (v[1:] + v[:-1]), np.diff(v) / np.diff(t), free[:-1] & free[1:]
    )
    side = list(_ENGINE_SIDE)
    removed = np.diff(out_y[:, side], axis=0)[stopped].sum(axis=0)
    # The free engine's terms balance: its indicated work is what the others take. The samples are dense
    # output inside steps (at rest up to a fiftieth of the cycle long) that may begin while the clutch still
    # closes, where the Hermite interpolation misplaces that balance by about 1e-9 of the run's work; the
    # indicated work removed is therefore the other terms' sum.
    removed[side.index(_E_IND)] = removed[2:].sum()
    y_end = y_end.copy()
    y_end[side] -= removed
    y_end[_FUEL] += starts * params.hybrid.engine_start_fuel
    return y_end, starts, stopped
