"""Backward quasi-static method (BQM), paper section 3.

The cycle is tracked exactly by construction: from the cycle's speed and acceleration on each interval
(piecewise-linear cycle, so constant acceleration and mean speed per interval) follow the wheel force (18),
wheel torque and speed (16),(17), engine torque and speed through the prescribed gear (14),(15) and the
crank torque with the engine inertia (1). The crank torque is limited by the max-torque line; what is cut
off is reported as a trace miss, never clipped silently. The fuel flow is looked up in the engine's fuel map
(generated from the physics by :mod:`vpsim.maps`, or measured) and floored at the idle flow (section 5).

Modes:
* ``paper``: no clutch, no brakes; the engine stays coupled at standstill (w_e = 0, idle fuel).
* ``extended``: below idle speed the clutch slips (engine held at idle speed, transmitting the torque asked
  for) or opens when no traction is needed; friction brakes take what engine braking (the closed-throttle
  line) cannot.
"""

from __future__ import annotations

import functools
import time
import weakref

import numpy as np

from .. import _kernels as kn
from .. import physics as ph
from ..gears import GearSchedule, default_schedule
from ..maps import GeneratedEngineMap, cached_engine_map
from ..result import EnergyBalance, Result, TraceMiss

IDLE_SPEED = 80.0  # rad/s, the engine speed held in extended mode below which the clutch slips or opens


def run(
    cycle,
    params,
    *,
    engine_map=None,
    schedule: GearSchedule | None = None,
    mode: str = "paper",
    keep_series: bool = True,
    compiled: bool = True,
) -> Result:
    """Run the BQM on ``cycle``. ``engine_map`` defaults to the map generated from ``params.engine``.

    With a generated map (:class:`vpsim.maps.GeneratedEngineMap`) the per-interval loop runs compiled
    (:func:`vpsim._kernels.backward_single`, cached on disk by Numba); ``compiled=False``, or a map of another
    kind, runs the NumPy reference. Both give the same result to rounding (checked by tests/test_kernels.py).
    """
    if mode not in ("paper", "extended"):
        raise ValueError(f"mode must be 'paper' or 'extended', got {mode!r}")
    if engine_map is None:
        engine_map = cached_engine_map(params.engine)
    if schedule is None:
        schedule = default_schedule(cycle, params, engine_map)
    if compiled and isinstance(engine_map, GeneratedEngineMap):
        return _run_compiled(cycle, params, engine_map, schedule, mode, keep_series)
    return _run_numpy(cycle, params, engine_map, schedule, mode, keep_series)


def _run_numpy(cycle, params, engine_map, schedule: GearSchedule, mode: str, keep_series: bool) -> Result:
    """The reference implementation: the BQM as vectorised NumPy over the cycle's intervals."""
    t0 = time.process_time()
    veh, tr, sim = params.vehicle, params.transmission, params.simulation
    ratios = np.asarray(tr.ratios)
    gear = schedule.on_cycle(cycle)[:-1]
    i = ratios[gear - 1]
    t = cycle.time_s
    dt = np.diff(t)
    v = 0.5 * (cycle.speed_mps[1:] + cycle.speed_mps[:-1])
    a = np.diff(cycle.speed_mps) / dt
    moving = v > 0
    r = veh.wheel_radius
    eta = tr.efficiency
    j_e = engine_map.inertia
    aero = ph.aero_force(v, veh)
    roll = ph.rolling_force(veh) * moving
    f_req = veh.mass * a + aero + roll  # (18): the wheel force the cycle asks for
    w_e = i * v / r  # (14),(17)
    dw_e = i * a / r
    t_cr_req = f_req * r / (i * eta) + j_e * dw_e  # (15),(16),(1)
    brake_force = np.zeros_like(v)
    coupled = np.ones(v.shape, bool)
    if mode == "extended":
        # engine braking limit: the closed-throttle line; brakes take the rest
        t_min = engine_map.min_torque(w_e) if hasattr(engine_map, "min_torque") else np.zeros_like(w_e)
        excess = np.minimum(t_cr_req - t_min, 0.0)
        brake_force = -excess * i * eta / r
        t_cr_req = np.maximum(t_cr_req, t_min)
        # below idle speed: clutch slips at idle speed under traction, opens otherwise
        low = w_e < IDLE_SPEED
        slip = low & (f_req > 0)
        openc = low & ~slip
        t_cr_req = np.where(slip, f_req * r / (i * eta), t_cr_req)  # slipping clutch: no inertia change
        w_e = np.where(low, IDLE_SPEED, w_e)
        dw_e = np.where(low, 0.0, dw_e)
        brake_force = np.where(openc, np.maximum(-f_req, 0.0), np.where(slip, 0.0, brake_force))
        t_cr_req = np.where(openc, 0.0, t_cr_req)
        coupled = ~openc
    t_max = engine_map.max_torque(w_e)
    shortfall = np.maximum(t_cr_req - t_max, 0.0)
    t_cr = t_cr_req - shortfall
    mdot = engine_map.fuel_flow(t_cr, w_e)
    if mode == "extended":
        mdot = np.where(coupled, mdot, sim.idle_fuel_flow)
    mdot_used = ph.fuel_with_idle_floor(mdot, sim.idle_fuel_flow)
    fuel_kg = float(np.sum(mdot_used * dt))
    distance = float(np.sum(v * dt))
    cpu = time.process_time() - t0

    missed = shortfall > 1e-9
    m_eq = veh.mass + j_e * i**2 * eta / r**2
    dv_deficit = shortfall * i * eta / (r * m_eq)  # acceleration the engine could not give
    trace = TraceMiss(
        seconds=float(np.sum(dt[missed])),
        max_torque_shortfall_nm=float(shortfall.max(initial=0.0)),
        details={"speed_deficit_mps": float(_max_run_sum(dv_deficit * dt, missed))},
    )
    energy = None
    intake = None
    if hasattr(engine_map, "intake_pressure"):
        eng = engine_map.engine
        p_i = engine_map.intake_pressure(t_cr, w_e)
        intake = np.where(coupled, p_i, np.nan)
        cps = ph.cycles_per_second(w_e, eng) * ph.displacement(eng)  # MEP x this = power
        c = coupled
        energy = EnergyBalance(
            indicated=float(np.sum((mdot * eng.fuel_heating_value * eng.thermal_efficiency * dt)[c])),
            friction=float(np.sum((ph.fmep(p_i, w_e, eng) * cps * dt)[c])),
            pumping=float(np.sum((ph.pmep(p_i, eng) * cps * dt)[c])),
            engine_kinetic=float(np.sum((j_e * w_e * dw_e * dt)[c])),
            driveline_loss=float(np.sum(((1 - eta) * (t_cr + shortfall - j_e * dw_e) * w_e * dt)[c])),
            vehicle_kinetic=float(np.sum(veh.mass * v * a * dt)),
            aero=float(np.sum(aero * v * dt)),
            rolling=float(np.sum(roll * v * dt)),
            brake=float(np.sum(brake_force * v * dt)),
            trace_miss=float(np.sum((shortfall * w_e * dt)[c])),
        )
        if mode == "extended":
            # a slipping clutch dissipates T_e (w_idle - w_wheel-side); count it with the driveline
            slip_loss = np.where(slip, (f_req * r / (i * eta)) * (IDLE_SPEED - i * v / r), 0.0)
            energy = _replace(energy, driveline_loss=energy.driveline_loss + float(np.sum(slip_loss * dt)))
    series = {}
    if keep_series:
        series = {
            "time_s": 0.5 * (t[1:] + t[:-1]),
            "reference_speed_mps": v,
            "speed_mps": v,
            "accel_mps2": a,
            "gear": gear,
            "engine_speed_radps": w_e,
            "crank_torque_nm": t_cr,
            "engine_torque_nm": t_cr - j_e * dw_e,
            "intake_pressure_pa": intake if intake is not None else np.full_like(v, np.nan),
            "fuel_flow_kgps": mdot,
            "fuel_flow_used_kgps": mdot_used,
            "brake_force_n": brake_force,
            "torque_shortfall_nm": shortfall,
        }
    return _result(cycle, params, mode, series, fuel_kg, distance, cpu, int(dt.size), trace, energy)


_warm = False


def _run_compiled(cycle, params, engine_map, schedule: GearSchedule, mode: str, keep_series: bool) -> Result:
    """The same computation as :func:`_run_numpy`, its per-interval loop compiled (vpsim._kernels)."""
    global _warm
    if not _warm:  # load (or compile) the kernel once per process, so cpu_time_s measures the run only
        _warm = True
        tiny = cycle.__class__(cycle.name, cycle.time_s[:2], cycle.speed_mps[:2])
        _run_compiled(tiny, params, engine_map, schedule, mode, keep_series)
    t0 = time.process_time()
    eng = engine_map.engine
    c, ratios = _kernel_inputs(params, eng)
    n = cycle.time_s.size - 1
    gear = np.empty(n, dtype=np.int64)
    s = np.empty((kn.N_SERIES, n))
    res = np.empty(kn.N_RESULTS)
    extended = mode == "extended"
    kn.backward_single(
        cycle.time_s,
        cycle.speed_mps,
        schedule.time_s,
        schedule.gear,
        ratios,
        c,
        extended,
        bool(engine_map.exact),
        engine_map.speed,
        engine_map.torque,
        engine_map.table,
        engine_map.max_torque_speed,
        engine_map.max_torque_values,
        engine_map.min_torque_values,
        gear,
        s,
        res,
    )
    cpu = time.process_time() - t0
    sums = res.tolist()
    trace = TraceMiss(
        seconds=sums[kn.R_MISS_S],
        max_torque_shortfall_nm=sums[kn.R_MAX_SHORT],
        details={"speed_deficit_mps": sums[kn.R_DEFICIT]},
    )
    energy = EnergyBalance(
        indicated=sums[kn.I_INDICATED],
        friction=sums[kn.I_FRICTION],
        pumping=sums[kn.I_PUMPING],
        engine_kinetic=sums[kn.I_ENGINE_KIN],
        driveline_loss=sums[kn.I_DRIVELINE] + sums[kn.I_SLIP] if extended else sums[kn.I_DRIVELINE],
        vehicle_kinetic=sums[kn.I_VEHICLE_KIN],
        aero=sums[kn.I_AERO],
        rolling=sums[kn.I_ROLLING],
        brake=sums[kn.I_BRAKE],
        trace_miss=sums[kn.I_TRACE],
    )
    series = {}
    if keep_series:
        v = s[kn.S_V]
        p_i = np.where(s[kn.S_COUPLED] > 0, s[kn.S_P], np.nan) if extended else s[kn.S_P]
        series = {
            "time_s": s[kn.S_TIME],
            "reference_speed_mps": v,
            "speed_mps": v,
            "accel_mps2": s[kn.S_A],
            "gear": gear,
            "engine_speed_radps": s[kn.S_W],
            "crank_torque_nm": s[kn.S_TCR],
            "engine_torque_nm": s[kn.S_TE],
            "intake_pressure_pa": p_i,
            "fuel_flow_kgps": s[kn.S_MDOT],
            "fuel_flow_used_kgps": s[kn.S_MDOT_USED],
            "brake_force_n": s[kn.S_BRAKE],
            "torque_shortfall_nm": s[kn.S_SHORT],
        }
    return _result(cycle, params, mode, series, sums[kn.I_FUEL], sums[kn.I_DIST], cpu, n, trace, energy)


_INPUTS: dict = {}  # (id(params), id(engine)) -> (weak refs to both, constants, ratios): see _kernel_inputs


def _kernel_inputs(params, engine) -> tuple[np.ndarray, np.ndarray]:
    """(constants, total ratios) of the kernel for this parameter set and engine, memoised by identity.

    Hashing the frozen parameter sections for an lru_cache costs about a microsecond per run, a tenth of the
    Python around a compiled run; an identity look-up (checked through weak references, so a recycled id
    never returns another set's values) is nearly free. Values are rebuilt from scratch after 64 entries.
    """
    key = (id(params), id(engine))
    hit = _INPUTS.get(key)
    if hit is not None and hit[0]() is params and hit[1]() is engine:
        return hit[2], hit[3]
    c = _constants(params.vehicle, params.transmission, engine, params.simulation)
    r = _ratios(params.transmission)
    if len(_INPUTS) >= 64:
        _INPUTS.clear()
    _INPUTS[key] = (weakref.ref(params), weakref.ref(engine), c, r)
    return c, r


@functools.lru_cache(maxsize=128)
def _ratios(transmission) -> np.ndarray:
    """Total ratio per gear as an array (read-only), cached per transmission."""
    r = np.asarray(transmission.ratios, dtype=float)
    r.setflags(write=False)
    return r


@functools.lru_cache(maxsize=128)
def _constants(vehicle, transmission, engine, simulation) -> np.ndarray:
    """The compiled kernel's constants for one parameter set (vpsim._kernels.pack_constants), cached."""
    c = kn.pack_constants(vehicle, transmission, engine, simulation)[0]
    c.setflags(write=False)
    return c


def _result(cycle, params, mode, series, fuel_kg, distance, cpu, steps, trace, energy) -> Result:
    sim = params.simulation
    notes = []
    if trace.seconds:
        notes.append(
            f"trace miss: the cycle asks more torque than the max-torque line for {trace.seconds:g} s "
            f"(largest shortfall {trace.max_torque_shortfall_nm:.1f} N m); fuel is computed at the line"
        )
    return Result(
        method="backward",
        cycle=cycle.name,
        driver=None,
        mode=mode,
        series=series,
        fuel_kg=fuel_kg,
        distance_m=distance,
        fuel_density_kg_per_l=sim.fuel_density,
        cpu_time_s=cpu,
        steps=steps,
        trace_miss=trace,
        energy=energy,
        vehicle=params.name,
        notes=tuple(notes),
    )


def _replace(obj, **kw):
    from dataclasses import replace

    return replace(obj, **kw)


def _max_run_sum(x, mask):
    """Largest sum of ``x`` over a contiguous run where ``mask`` holds."""
    if not np.any(mask):
        return 0.0
    best = cur = 0.0
    for xi, m in zip(x, mask, strict=True):
        cur = cur + xi if m else 0.0
        best = max(best, cur)
    return best
