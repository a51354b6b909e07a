"""The battery-electric car on the three methods: one operating point
(:func:`vpsim.model.electric.electric_point`), three ways to get speed and acceleration.

* ``backward``: the cycle tracked exactly; each interval of the piecewise-linear cycle at its mean speed and
  constant acceleration (as the engine's backward method), the state of charge carried from interval to
  interval (:func:`interval_kernel`).
* ``inverse``: the smoothing driver's v_d, dv_d/dt (eqs (34)-(35)) at the midpoints of a grid no coarser
  than ``simulation.inverse_max_step``; the machine torque from the inverted dynamics, which for the stiff
  electric driveline is the same operating point (the same kernel).
* ``forward``: the vehicle's speed, the driver's integral and the state of charge are states of an ODE
  integrated by the classical Runge-Kutta method on a grid that steps on every cycle sample (the
  reference's kinks) and at most ``max_step`` apart. A PI driver on the speed error commands the wheel
  force per unit mass, u = k_p e + k_i int e (``electric.forward_kp``, ``forward_ki``): positive, the
  machine drives; negative, it brakes (regenerating its share, the friction brakes the rest).

The energy terms (``ELECTRIC_TERMS``) are booked from the same point at each evaluation, so the balance
chemical = battery loss + accessories + machine loss + rotor kinetic + driveline loss + vehicle kinetic
+ aero + rolling + brake - trace miss (- unserved) closes to rounding.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..errors import VpsimError
from ..model import battery as bt
from ..model import electric as el
from ..model import vehicle as vh
from ..model._compile import kernel
from ..model.engine import equation, inline
from ..result import ElectricBalance, Result, TraceMiss
from ..units import METRES_PER_MILE
from ._hybrid import rows_at_samples

ELECTRIC_TERMS = el.ELECTRIC_TERMS
(
    T_CHEM,
    T_BLOSS,
    T_ACC,
    T_MLOSS,
    T_ROTOR,
    T_DRIVE,
    T_KIN,
    T_AERO,
    T_ROLL,
    T_BRAKE,
    T_MISS,
    T_UNSERVED,
) = range(12)
N_TERMS = 12
# further sums after the terms
S_DIST, S_REGEN, S_MISS_S, S_MACHINE_S, S_BATTERY_S, S_TERMINAL, S_MAX_MISS = range(N_TERMS, N_TERMS + 7)
N_SUMS = N_TERMS + 7
# rows of the per-point series
(P_T, P_V, P_A, P_W, P_TM, P_BRAKE, P_MISS, P_I, P_UOC, P_U, P_SOC, P_PT, P_LIM_M, P_LIM_B) = range(14)
N_ROWS = 14
MISS_TOLERANCE_N = 1e-9


@equation
def _book(v, a, dw, w, t, brake, missing, i, u_oc, r, p_machine, ratio, c, e, dt, sums):
    """Add one point's energy terms (its powers times dt) to ``sums``; returns the terminal power."""
    vv = v if v > 0.0 else 0.0
    p_terminal = el.pack_power(i, u_oc, r, r)
    p_asked = p_machine + e.accessory_power
    rotor = el.rotor_torque(dw, e) * w
    f_wheel = vh.wheel_force(vv, a, c) + brake - missing  # what the machine's side gives at the wheels
    sums[T_CHEM] += bt.chemical_power(u_oc, i, e.coulombic_efficiency) * dt
    sums[T_BLOSS] += bt.battery_loss(u_oc, r, i, e.coulombic_efficiency) * dt
    sums[T_ACC] += e.accessory_power * dt
    sums[T_MLOSS] += (p_machine - t * w) * dt
    sums[T_ROTOR] += rotor * dt
    sums[T_DRIVE] += (t * w - rotor - f_wheel * vv) * dt
    sums[T_KIN] += el.kinetic_power(vv, a, c) * dt
    sums[T_AERO] += vh.aero_force(vv, c) * vv * dt
    sums[T_ROLL] += vh.rolling_force(vv, c) * vv * dt
    sums[T_BRAKE] += brake * vv * dt
    sums[T_MISS] += missing * vv * dt
    sums[T_UNSERVED] += (p_asked - p_terminal) * dt
    sums[S_DIST] += vv * dt
    if p_machine < 0.0:
        sums[S_REGEN] += -p_machine * dt
    sums[S_TERMINAL] += p_terminal * dt
    return p_terminal


@kernel(_nrt=False)
def interval_kernel(t_mid, v, a, dt, ratio, soc0, c, e, m, tabs, rows, sums):
    """Backward and inverse: each point stands for an interval dt at speed v and acceleration a; the state
    of charge moves on by (B3) at the point's current. Returns the final state of charge."""
    soc = soc0
    for k in range(v.size):
        vk = v[k] if v[k] > 0.0 else 0.0
        dw = vh.engine_speed(a[k], ratio, c)  # i a / r
        f = vh.wheel_force(vk, a[k], c)
        w, t, brake, missing, i, u_oc, r, p_m, at_m, at_b = el.electric_point(
            f, vk, dw, ratio, soc, c, e, m, tabs
        )
        if missing < MISS_TOLERANCE_N:
            missing = 0.0
        p_t = _book(vk, a[k], dw, w, t, brake, missing, i, u_oc, r, p_m, ratio, c, e, dt[k], sums)
        short = el.shaft_torque(missing, ratio, c)  # the machine torque the missing force needed
        if missing > 0.0:
            sums[S_MISS_S] += dt[k]
            sums[S_MAX_MISS] = max(sums[S_MAX_MISS], short)
        sums[S_MACHINE_S] += at_m * dt[k]
        sums[S_BATTERY_S] += at_b * dt[k]
        _store(rows, k, t_mid[k], vk, a[k], w, t, brake, short, i, u_oc, r, soc, p_t, at_m, at_b)
        soc += bt.soc_rate(i, e.capacity_as, e.coulombic_efficiency) * dt[k]
    return soc


@inline
def _forward_point(v, xi, soc, v_ref, kp, ki, ratio, c, e, m, tabs):
    """The forward model at one instant: (dv/dt, the point's values). The driver's wheel force m u (net of
    the road load it feels), the machine and brakes as the point gives them; the rotor's inertia joins the
    mass the net force moves (:func:`vpsim.model.electric.rotor_mass`)."""
    vv = v if v > 0.0 else 0.0
    u = kp * (v_ref - v) + ki * xi
    f_cmd = el.driver_force(u, vv, c)
    w, t, brake, missing, i, u_oc, r, p_m, at_m, at_b = el.electric_point(
        f_cmd, vv, 0.0, ratio, soc, c, e, m, tabs
    )
    acc = el.forward_acceleration(t, brake, vv, ratio, c, e)
    if vv <= 0.0 and acc < 0.0:
        acc = 0.0  # at rest the brakes hold; the car does not roll back
    return acc, w, t, brake, i, u_oc, r, p_m, at_m, at_b


@equation
def _stage(v, xi, soc, v_ref, weight, kp, ki, ratio, c, e, m, tabs, sums):
    """One Runge-Kutta stage: the derivatives (dv, d int e, dSOC); its energy terms booked at ``weight``."""
    acc, w, t, brake, i, u_oc, r, p_m, at_m, at_b = _forward_point(
        v, xi, soc, v_ref, kp, ki, ratio, c, e, m, tabs
    )
    vv = v if v > 0.0 else 0.0
    dw = vh.engine_speed(acc, ratio, c)
    _book(vv, acc, dw, w, t, brake, 0.0, i, u_oc, r, p_m, ratio, c, e, weight, sums)
    sums[S_MACHINE_S] += at_m * weight
    sums[S_BATTERY_S] += at_b * weight
    return acc, v_ref - v, bt.soc_rate(i, e.capacity_as, e.coulombic_efficiency)


@kernel(_nrt=False)
def forward_kernel(time_s, speed, max_step, kp, ki, ratio, soc0, c, e, m, tabs, rows, sums):
    """Forward: classical RK4 on (v, int e, SOC) between the cycle's samples (each interval split into equal
    steps at most ``max_step``); the energy terms at the four stages with the RK weights, so the balance
    holds for the integrated run. ``rows`` at the cycle's samples. Returns the number of steps."""
    v, xi, soc = speed[0], 0.0, soc0
    steps = 0
    _sample(rows, 0, time_s[0], v, speed[0], xi, soc, kp, ki, ratio, c, e, m, tabs)
    for k in range(time_s.size - 1):
        t0, t1 = time_s[k], time_s[k + 1]
        nsub = max(1, int(math.ceil((t1 - t0) / max_step - 1e-12)))
        h = (t1 - t0) / nsub
        slope = (speed[k + 1] - speed[k]) / (t1 - t0)
        for s in range(nsub):
            ts = s * h
            r0 = speed[k] + slope * ts
            r1 = speed[k] + slope * (ts + 0.5 * h)
            r2 = speed[k] + slope * (ts + h)
            a1, x1, s1 = _stage(v, xi, soc, r0, h / 6.0, kp, ki, ratio, c, e, m, tabs, sums)
            a2, x2, s2 = _stage(
                v + 0.5 * h * a1,
                xi + 0.5 * h * x1,
                soc + 0.5 * h * s1,
                r1,
                h / 3.0,
                kp,
                ki,
                ratio,
                c,
                e,
                m,
                tabs,
                sums,
            )
            a3, x3, s3 = _stage(
                v + 0.5 * h * a2,
                xi + 0.5 * h * x2,
                soc + 0.5 * h * s2,
                r1,
                h / 3.0,
                kp,
                ki,
                ratio,
                c,
                e,
                m,
                tabs,
                sums,
            )
            a4, x4, s4 = _stage(
                v + h * a3, xi + h * x3, soc + h * s3, r2, h / 6.0, kp, ki, ratio, c, e, m, tabs, sums
            )
            v += h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
            xi += h / 6.0 * (x1 + 2.0 * x2 + 2.0 * x3 + x4)
            soc += h / 6.0 * (s1 + 2.0 * s2 + 2.0 * s3 + s4)
            steps += 1
        _sample(rows, k + 1, t1, v, speed[k + 1], xi, soc, kp, ki, ratio, c, e, m, tabs)
    return steps


@equation
def _sample(rows, j, t, v, v_ref, xi, soc, kp, ki, ratio, c, e, m, tabs):
    acc, w, tm, brake, i, u_oc, r, p_m, at_m, at_b = _forward_point(
        v, xi, soc, v_ref, kp, ki, ratio, c, e, m, tabs
    )
    _store(rows, j, t, v, acc, w, tm, brake, 0.0, i, u_oc, r, soc, el.pack_power(i, u_oc, r, r), at_m, at_b)


@equation
def _store(rows, k, t, v, a, w, tm, brake, short, i, u_oc, r, soc, p_t, at_m, at_b):
    """One row of the series: time, speed, acceleration, machine speed and torque, brake force, torque
    short, battery current, voltages, state of charge, terminal power, the limit flags."""
    rows[P_T, k] = t
    rows[P_V, k] = v
    rows[P_A, k] = a
    rows[P_W, k] = w
    rows[P_TM, k] = tm
    rows[P_BRAKE, k] = brake
    rows[P_MISS, k] = short
    rows[P_I, k] = i
    rows[P_UOC, k] = u_oc
    rows[P_U, k] = u_oc - r * i
    rows[P_SOC, k] = soc
    rows[P_PT, k] = p_t
    rows[P_LIM_M, k] = at_m
    rows[P_LIM_B, k] = at_b


# --- Python side ------------------------------------------------------------------------------------------


def _ratio(params) -> float:
    return vh.total_ratio(params.transmission.gearbox_ratios[0], params.transmission.final_drive)


def _c(params):
    from ..model.record import kernel_records

    return kernel_records(params)[0]


def warm_up() -> None:
    """Compile (or load from the cache) the kernels on a two-sample cycle."""
    from ..params import load_parameters

    p = load_parameters("bev")
    t = np.array([0.0, 1.0])
    v = np.array([0.0, 1.0])
    _intervals(t, v, v * 0.0 + 1.0, t, p)
    _forward(t, v, p)


def _intervals(t_mid, v, a, dt, params):
    e, m, tabs = el.electric_records(params)
    rows = np.empty((N_ROWS, v.size))
    sums = np.zeros(N_SUMS)
    soc_end = interval_kernel(
        t_mid,
        v,
        a,
        dt,
        _ratio(params),
        params.battery.soc_initial,
        _c(params),
        e,
        m,
        tabs.astuple(),
        rows,
        sums,
    )
    return rows, sums, soc_end


def _forward(time_s, speed, params):
    e, m, tabs = el.electric_records(params)
    rows = np.empty((N_ROWS, time_s.size))
    sums = np.zeros(N_SUMS)
    ep = params.electric
    steps = forward_kernel(
        time_s,
        speed,
        ep.forward_max_step,
        ep.forward_kp,
        ep.forward_ki,
        _ratio(params),
        params.battery.soc_initial,
        _c(params),
        e,
        m,
        tabs.astuple(),
        rows,
        sums,
    )
    return rows, sums, steps


def run(cycle, params, method: str = "backward", *, driver: str | None = None, mode: str = "realistic"):
    """The battery-electric car of ``params`` on ``cycle`` with ``method``; a :class:`vpsim.result.Result`."""
    t_start = time.process_time()
    ts, vs = np.asarray(cycle.time_s, float), np.asarray(cycle.speed_mps, float)
    if method == "backward":
        dt = np.diff(ts)
        rows, sums, soc_end = _intervals(
            0.5 * (ts[1:] + ts[:-1]), 0.5 * (vs[1:] + vs[:-1]), np.diff(vs) / dt, dt, params
        )
        steps = dt.size
        at_samples = _per_sample(rows, ts, vs, soc_end)
    elif method == "inverse":
        from ..drivers.smoothing import SmoothingDriver, inverse_grid

        a_half = params.driver(driver or "2").inverse_a
        grid = inverse_grid(ts, params.simulation.inverse_max_step)  # (drivers.smoothing)
        mid = 0.5 * (grid[1:] + grid[:-1])
        sm = SmoothingDriver(ts, vs, a_half)
        v_mid, a_mid, _ = sm.evaluate(mid)
        rows, sums, soc_end = _intervals(mid, v_mid, a_mid, np.diff(grid), params)
        steps = mid.size
        v_samples = sm.evaluate(ts)[0]
        # the grid's intervals that start at a cycle sample
        starts = np.searchsorted(grid, ts[:-1])
        at_samples = _per_sample(rows[:, starts], ts, v_samples, soc_end, socs=rows[P_SOC, starts])
    elif method == "forward":
        rows, sums, steps = _forward(ts, vs, params)
        soc_end = float(rows[P_SOC, -1])
        at_samples = {k: rows[j] for k, j in _COLUMNS.items()}
    else:
        raise VpsimError(f"unknown method {method!r}")
    cpu = time.process_time() - t_start
    return _result(cycle, params, method, driver, mode, at_samples, sums, soc_end, steps, cpu)


_COLUMNS = {
    "time_s": P_T,
    "speed_mps": P_V,
    "accel_mps2": P_A,
    "machine_speed_radps": P_W,
    "machine_torque_nm": P_TM,
    "brake_force_n": P_BRAKE,
    "torque_shortfall_nm": P_MISS,
    "battery_current_a": P_I,
    "open_circuit_voltage_v": P_UOC,
    "battery_voltage_v": P_U,
    "soc": P_SOC,
    "battery_power_w": P_PT,
    "machine_at_limit": P_LIM_M,
    "battery_at_limit": P_LIM_B,
}


def _per_sample(rows, ts, vs, soc_end, socs=None):
    """Interval values at the cycle's samples: each interval's at the sample that starts it (the last
    sample repeats the last interval's); speed and state of charge at the samples themselves."""
    picked = rows_at_samples(rows, ts.size, rows.shape[1])
    out = {k: picked[j] for k, j in _COLUMNS.items()}
    out["time_s"] = ts.copy()
    out["speed_mps"] = vs.copy()
    soc = rows[P_SOC] if socs is None else socs
    out["soc"] = np.append(soc[: ts.size - 1], soc_end)
    return out


def _result(cycle, params, method, driver, mode, series, sums, soc_end, steps, cpu):
    e, _, _ = el.electric_records(params)
    series = dict(series)
    series["reference_speed_mps"] = np.asarray(cycle.speed_mps, float).copy()
    series["gear"] = np.ones(series["time_s"].size)
    series["gearbox_ratio"] = np.full(series["time_s"].size, params.transmission.gearbox_ratios[0])
    for k in ("machine_at_limit", "battery_at_limit"):
        series[k] = series[k] > 0.5
    distance = float(sums[S_DIST])
    chemical = float(sums[T_CHEM])
    terminal = float(sums[S_TERMINAL])
    wall = el.wall_energy(chemical, e) if chemical > 0.0 else math.nan
    km = distance / 1e3
    electric = {
        "electric_wh_per_km": terminal / 3600.0 / km if km > 1e-3 else math.nan,
        "wall_wh_per_km": wall / 3600.0 / km if km > 1e-3 else math.nan,
        "mpge": (distance / METRES_PER_MILE) / (wall / 3.6e6 / el.KWH_PER_GALLON_EQUIVALENT)
        if km > 1e-3 and wall > 0.0
        else math.nan,
        "soc_start": float(params.battery.soc_initial),
        "soc_end": float(soc_end),
        "regen_wh": float(sums[S_REGEN]) / 3600.0,
        "battery_chemical_wh": chemical / 3600.0,
        "wall_wh": wall / 3600.0,
    }
    balance = ElectricBalance({name: float(sums[j]) for j, name in enumerate(ELECTRIC_TERMS)})
    max_short = float(sums[S_MAX_MISS])
    trace = TraceMiss(
        seconds=round(float(sums[S_MISS_S]), 9),
        max_torque_shortfall_nm=float(max_short),
        details={
            "machine_at_limit_s": round(float(sums[S_MACHINE_S]), 6),
            "battery_at_limit_s": round(float(sums[S_BATTERY_S]), 6),
            **({"torque_beyond_full_load_s": round(float(sums[S_MISS_S]), 6)} if method != "forward" else {}),
        },
    )
    return Result(
        method=method,
        cycle=cycle.name,
        driver=None if method == "backward" else (driver or "2"),
        mode=mode,
        series=series,
        fuel_kg=0.0,
        distance_m=distance,
        fuel_density_kg_per_l=params.simulation.fuel_density,
        cpu_time_s=cpu,
        steps=int(steps),
        trace_miss=trace,
        energy=balance,
        vehicle=params.name,
        solver={"steps": int(steps)},
        limits={},
        electric=electric,
    )
