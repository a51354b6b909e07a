"""What the hybrid layouts' backward and inverse methods share around their kernels: the running sums'
places, the :class:`vpsim.result.Result` they make of a run, and the inverse method's trajectory and result
(the P2 of :mod:`vpsim.methods.hev`, the power split of :mod:`vpsim.methods.hev_split`)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..errors import VpsimError
from ..model import electric as el
from ..model import hybrid as hy
from ..model.engine import equation
from ..result import ElectricBalance, Result, TraceMiss

N_TERMS = len(hy.HYBRID_TERMS)
# the running sums after the energy terms, in every layout's kernel (a layout may add its own after them)
S_FUEL, S_DIST, S_STARTS, S_MISS_S, S_MAX_MISS, S_MACHINE_S, S_BATTERY_S, S_REGEN, S_ON_S = range(
    N_TERMS, N_TERMS + 9
)
N_COMMON_SUMS = N_TERMS + 9


def inverse_trajectory(cycle, params, driver: str, ems: str) -> tuple:
    """The inverse method's input for a hybrid: (ts, vs, grid, smooth), the cycle's samples, the grid of
    :func:`vpsim.drivers.smoothing.inverse_grid` and the smoothing driver's speed (34)-(35) on it (not below
    zero). The DP management is refused: it needs the backward method's known cycle."""
    from ..drivers.smoothing import SmoothingDriver, inverse_grid

    if ems == "dp":
        raise VpsimError(
            "the dynamic programming management runs on the backward method only (a known cycle)"
        )
    a = params.driver(driver).inverse_a
    ts, vs = np.asarray(cycle.time_s, float), np.asarray(cycle.speed_mps, float)
    grid = inverse_grid(ts, params.simulation.inverse_max_step)
    smooth = np.maximum(SmoothingDriver(ts, vs, a).evaluate(grid)[0], 0.0)
    return ts, vs, grid, smooth


def inverse_result(result_of, cycle, trajectory: tuple, rows, driver: str) -> Result:
    """The inverse run's Result from its grid rows: ``result_of(cycle, rows)`` (the layout's result builder)
    on the cycle's samples with the rows of the grid intervals that start at them; the speed series is the
    smoothed trajectory's at the samples (grid points), the method, driver and steps the inverse method's."""
    from ..cycles import Cycle

    ts, vs, grid, smooth = trajectory
    starts = np.searchsorted(grid, ts[:-1])  # the grid intervals that start at the cycle's samples
    r = result_of(Cycle(cycle.name, ts, vs), rows[:, starts])
    series = dict(r.series)
    series["speed_mps"] = smooth[np.searchsorted(grid, ts)]  # the samples are grid points
    return dataclasses.replace(r, method="inverse", driver=driver, series=series, steps=int(grid.size - 1))


def rows_at_samples(rows, n_samples: int, n: int) -> np.ndarray:
    """The first ``n`` interval columns of ``rows`` at a cycle's ``n_samples`` samples: each interval's at the
    sample that starts it, the last interval's repeated at the samples past it (one copy, so each series
    cut from it owns its memory). The electric and hybrid cars' series (:func:`series`,
    :func:`vpsim.methods.bev.run`)."""
    m = min(n_samples, n)
    block = np.empty((rows.shape[0], n_samples))
    block[:, :m] = rows[:, :m]
    block[:, m:] = rows[:, m - 1 : m]
    return block


def series(cycle, rows, columns: dict[str, int], soc_row: int, soc_end: float, n: int) -> dict:
    """The run's series at the cycle's samples: each interval's row (the last repeated at the end), the
    cycle's time and speed, the state of charge at each sample, the flags as booleans."""
    ts = np.asarray(cycle.time_s, float)
    block = rows_at_samples(rows, ts.size, n)  # every row at once (each series a row of it, not of rows)
    out = {k: block[j] for k, j in columns.items()}
    out["time_s"] = ts.copy()
    out["speed_mps"] = np.asarray(cycle.speed_mps, float).copy()
    out["reference_speed_mps"] = out["speed_mps"].copy()
    out["soc"] = np.append(rows[soc_row, : ts.size - 1], soc_end)
    for k in ("engine_on", "machine_at_limit", "battery_at_limit"):
        out[k] = out[k] > 0.5
    return out


def result(cycle, params, ems, mode, series, sums, soc_start, soc_end, n, cpu, details=None):
    """The backward run's :class:`vpsim.result.Result`: the energy balance of :data:`HYBRID_TERMS`
    (indicated + chemical = the rest), the charge-sustaining figures, the trace miss with the time at the
    machine's and the battery's limits (and a layout's own ``details``)."""
    terms = {name: float(sums[q]) for q, name in enumerate(hy.HYBRID_TERMS)}
    fuel = float(sums[S_FUEL])
    distance = float(sums[S_DIST])
    electric = hy.electric_figures(
        params, terms, fuel, distance, soc_start, soc_end, sums[S_REGEN], sums[S_STARTS], sums[S_ON_S], ems
    )
    trace = TraceMiss(
        seconds=round(float(sums[S_MISS_S]), 9),
        max_torque_shortfall_nm=float(sums[S_MAX_MISS]),
        details={
            "machine_at_limit_s": round(float(sums[S_MACHINE_S]), 6),
            "battery_at_limit_s": round(float(sums[S_BATTERY_S]), 6),
            "torque_beyond_full_load_s": round(float(sums[S_MISS_S]), 6),
            **(details or {}),
        },
    )
    return Result(
        method="backward",
        cycle=cycle.name,
        driver=None,
        mode=mode,
        series=series,
        fuel_kg=fuel,
        distance_m=distance,
        fuel_density_kg_per_l=params.simulation.fuel_density,
        cpu_time_s=cpu,
        steps=int(n),
        trace_miss=trace,
        energy=ElectricBalance(terms),
        vehicle=params.name,
        solver={"steps": int(n), "ems": ems},
        limits={},
        electric=electric,
    )


@equation
def book_step(sums, pt, terms, vv, dt, ratio, on, c, h):
    """Add one step's figures to the running sums: a start (counted, its fuel), the energy terms ``terms`` of
    the point ``pt`` (a layout's powers) over dt, the fuel, the distance at speed ``vv``, the trace miss, the
    time at the machine's and battery's limits and with the engine on, the regenerated energy. ``on``: the
    engine's state before the step. Returns (engine running, force missing)."""
    running = pt[16]
    if running > 0.0 and on == 0.0:
        sums[S_STARTS] += 1.0
        sums[S_FUEL] += h.engine_start_fuel
    missing = pt[13] if pt[13] > hy.MISS_TOLERANCE_N else 0.0
    for q in range(N_TERMS):
        sums[q] += terms[q] * dt
    sums[S_FUEL] += pt[6] * dt
    sums[S_DIST] += vv * dt
    if missing > 0.0:
        sums[S_MISS_S] += dt
        sums[S_MAX_MISS] = max(sums[S_MAX_MISS], el.shaft_torque(missing, ratio, c))
    sums[S_MACHINE_S] += pt[14] * dt
    sums[S_BATTERY_S] += pt[15] * dt
    sums[S_ON_S] += running * dt
    if pt[11] < 0.0:
        sums[S_REGEN] += -pt[11] * dt
    return running, missing


@equation
def store_point(rows, k, at, pt, running, missing, ratio, soc, c):
    """Column k of the series rows ``at`` to ``at + 10``, which every layout's series holds in this order: the
    point ``pt``'s intake pressure (NaN with the engine off), fuel flow, battery current, open-circuit and
    terminal voltage, the charge at the step's start, the brakes, the torque short (at the shaft), the engine
    running, the machine and the battery at their limits."""
    rows[at, k] = pt[5] if running > 0.0 else math.nan
    rows[at + 1, k] = pt[6]
    rows[at + 2, k] = pt[8]
    rows[at + 3, k] = pt[9]
    rows[at + 4, k] = pt[9] - pt[10] * pt[8]
    rows[at + 5, k] = soc
    rows[at + 6, k] = pt[12]
    rows[at + 7, k] = el.shaft_torque(missing, ratio, c)
    rows[at + 8, k] = running
    rows[at + 9, k] = pt[14]
    rows[at + 10, k] = pt[15]
