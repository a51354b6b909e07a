"""Run a fleet of certification records on the cycles their tests measured, with out-of-fold technology.

    >>> from vpsim.fleet.run import run_fleet                                     # doctest: +SKIP
    >>> res = run_fleet("22-tstcar.csv", cycles=("ftp_bag2", "hwy"), folds=5)    # doctest: +SKIP

Steps (:mod:`vpsim.fleet.calibrate` explains the calibration):

1. read the list (:func:`vpsim.fleet.epa.read_test_car_list`); folds by vehicle family (or manufacturer,
   or record: :func:`vpsim.fleet.calibrate.vehicle_groups`);
2. per vehicle and cycle: its parameters (road load folded over *that* cycle's speeds), its gear schedule
   (the documented rule of :func:`vpsim.gears.default_schedule` with an earlier upshift,
   :data:`~vpsim.fleet.vehicle.GEAR_RULE`, and for a manual a driver's shift point,
   :data:`~vpsim.fleet.vehicle.MANUAL_GEAR_RULE`, which the vehicle's parameters carry; derived once with
   the preset technology and then kept for every technology value, as a sweep keeps the shifts), and the
   backward method over the technology grid in one :func:`vpsim.batch.run_batch` call (extended mode:
   clutch, idle, brakes);
3. technology per fold and class fitted on the other folds;
4. per vehicle and cycle: one run at its fold's technology with ``method`` (backward, or forward with the
   preset PI driver 2, which keeps within the +-2 km/h band of the test): the prediction reported. The
   technology is fitted on the backward grid for both methods (the same physical model; the forward
   method differs by the driver's tracking).

Steps 2 and 4 run in chunks of vehicles, in this process or on Dask (``local_cluster`` workers, or a
``scheduler`` address); chunks are deterministic, so every execution gives the same rows. The
battery-electric records and the hybrids follow the same steps in :mod:`vpsim.fleet.run_electrified`.
"""

from __future__ import annotations

import contextlib
import math
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import VpsimError
from . import calibrate as cal
from .cycles import FLEET_CYCLES, fleet_cycle
from .epa import TestCarList, VehicleRecord, mpg_from_l_per_100km, read_test_car_list
from .run_electrified import HYBRID_EXTRA_COLUMNS, _run_evs, _run_hevs, _run_mhevs
from .vehicle import GEAR_RULE, MANUAL_GEAR_RULE, gear_rule  # noqa: F401 (the fleet's rules)

METHODS = ("backward", "forward")
EV_COLUMNS = (
    "vehicle_id",
    "configuration",
    "make",
    "model",
    "manufacturer",
    "cycle",
    "measured_mpge",
    "predicted_mpge",
    "error_pct",
    "fold",
    "status",
    "family",
    "rated_power_kw",
    "test_mass_kg",
    "power_to_mass_w_per_kg",
    "final_drive",
    "wheel_radius_m",
    "ratio_rule",
    "battery_strings",
    "machine_loss_scale",
    "accessory_power_w",
    "drive_efficiency",
    "trace_miss_s",
    "fastsim_mpge",
    "fastsim_error_pct",
    "fastsim_status",
    "fastsim_calibrated_mpge",
    "fastsim_calibrated_error_pct",
    "detail",
)
HEV_COLUMNS = (
    "vehicle_id",
    "configuration",
    "make",
    "model",
    "manufacturer",
    "layout",
    "cycle",
    "measured_mpg",
    "predicted_mpg",
    "error_pct",
    "fold",
    "status",
    "family",
    "rated_power_kw",
    "test_mass_kg",
    "displacement_l",
    "boosted",
    "machine_kw",
    "thermal_efficiency",
    "accessory_power_w",
    "trace_miss_s",
    "fastsim_mpg",
    "fastsim_error_pct",
    "fastsim_status",
    "fastsim_calibrated_mpg",
    "fastsim_calibrated_error_pct",
    "fastsim_calibrated_status",
    "detail",
)
MODE = "extended"
CHUNK = 64  # vehicles per unit of work
FORWARD_DRIVER = "2"  # the stiffer preset PI driver (a = 1 s): the test driver follows the trace closely


@dataclass
class FleetRun:
    """Outcome of :func:`run_fleet`: one row per vehicle x cycle, and how it was obtained."""

    rows: list[dict]
    cars: TestCarList
    cycles: tuple[str, ...]
    folds: int
    method: str
    technology: dict  # "fold<k>.<class>" -> fitted parameters (out of fold)
    technology_all: dict  # class -> parameters fitted on every vehicle (for new cars)
    timings: dict = field(default_factory=dict)
    execution: str = "serial"
    peer: dict = field(default_factory=dict)  # FASTSim status: available, version, reason
    grouping: str = cal.DEFAULT_GROUPING  # what cross-validation holds out together (calibrate.GROUPINGS)
    n_groups: int = 0
    seed: int = cal.SEED  # the deal of groups into folds (calibrate.assign_folds)
    deal: str = cal.DEFAULT_DEAL  # how the groups are dealt (calibrate.DEALS)
    peer_technology: dict = field(default_factory=dict)  # the calibrated FASTSim's, "fold<k>.<class>"
    # the battery-electric records (vpsim.fleet.ev): rows, their technology and folds (_run_evs)
    ev: dict = field(default_factory=dict)
    # the full hybrids (vpsim.fleet.hev): rows, their technology and folds (_run_hevs)
    hev: dict = field(default_factory=dict)
    # the mild hybrids (vpsim.fleet.mhev): rows, their technology and folds (_run_mhevs)
    mhev: dict = field(default_factory=dict)

    def frame(self):
        import pandas as pd

        return pd.DataFrame(self.rows)

    def to_dataframe(self):
        """The engine cars' rows (:meth:`frame`): one per vehicle x cycle, measured and predicted mpg, the
        error, fold, class and technology, FASTSim's figures; the other parts: :meth:`ev_frame`,
        :meth:`hev_frame`, :meth:`mhev_frame`."""
        return self.frame()

    def __str__(self) -> str:
        """What ``vpsim fleet`` prints of the run (:func:`vpsim.fleet.report.summary_lines`): medians and
        90th percentiles of the errors per part and cycle beside FASTSim's, the differences with their
        intervals (a family bootstrap, a few seconds), the runtime."""
        from .report import run_info, summary, summary_lines

        return "\n".join(summary_lines(summary(self), run_info(self), self.cycles))

    def plot(self):
        """Predicted against measured fuel economy, one panel per cycle and part (the report's
        ``predicted_vs_measured.png``); FASTSim's beside vpsim's where it ran. Returns the Figure."""
        from .report_figures import figure_predicted_vs_measured

        peer = bool(self.peer.get("available"))
        return figure_predicted_vs_measured(
            self.frame(), self.cycles, peer, self.ev_frame(), self.hev_frame(), self.mhev_frame()
        )

    def ev_frame(self):
        """One row per battery-electric vehicle x test (``udds``, ``hwy``): MPGe measured and predicted."""
        import pandas as pd

        return pd.DataFrame(self.ev.get("rows", []), columns=EV_COLUMNS)

    def hev_frame(self):
        """One row per full hybrid x test (``udds_hot``, ``hwy``, ``us06``): mpg measured and predicted
        (charge-sustaining, ECMS)."""
        import pandas as pd

        from . import hev

        return pd.DataFrame(self.hev.get("rows", []), columns=hybrid_columns(hev))

    def mhev_frame(self):
        """One row per mild hybrid x test (``ftp_bag2``, ``ftp_bag3``, ``hwy``, ``us06``): mpg measured and
        predicted (charge-sustaining, ECMS); ``layout`` is its class (``mhev_p0``, ``mhev_p1``)."""
        import pandas as pd

        from . import mhev

        return pd.DataFrame(self.mhev.get("rows", []), columns=hybrid_columns(mhev))


def hybrid_columns(module) -> list[str]:
    """A hybrid part's columns: :data:`HEV_COLUMNS`, its technology's third parameter after the accessories
    (``module``: :mod:`vpsim.fleet.hev` or :mod:`.mhev`)."""
    cols = list(HEV_COLUMNS)
    at = cols.index("accessory_power_w") + 1
    return cols[:at] + [HYBRID_EXTRA_COLUMNS[p] for p in module.TECH_PARAMS[2:]] + cols[at:]


def _vehicle_class(rec: VehicleRecord) -> str:
    from .calibrate import vehicle_class

    return vehicle_class(rec)


# --- units of work (module level: they travel to Dask workers) ----------------------------------------------


@contextlib.contextmanager
def _kernels_on_one_thread():
    """Compiled kernels on one thread while a chunk runs: a fleet is thousands of small batch calls, and a
    parallel kernel's thread start-up and join then cost more than they save (4x per call measured on a
    busy 2-core machine); the fleet's parallelism is over vehicles, in processes. numba's thread count is
    per calling thread, so it is set here, in the thread that runs the chunk (a Dask worker's executor
    thread is not the one ``Client.run`` reaches)."""
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(before)


def grid_chunk(items: list[tuple[VehicleRecord, tuple[str, ...]]]) -> list[dict]:
    """Backward runs over the technology grid; one dict per vehicle x cycle (``log_fuel`` on the grid)."""
    with _kernels_on_one_thread():
        return _grid_chunk(items)


def _grid_chunk(items: list[tuple[VehicleRecord, tuple[str, ...]]]) -> list[dict]:
    from ..batch import run_batch
    from ..gears import default_schedule
    from .vehicle import record_parameters

    variants = cal.grid_variants()
    shape = (len(cal.GRID[0]), len(cal.GRID[1]))
    out = []
    for rec, cycles in items:
        for name in cycles:
            row = {"key": rec.key, "cycle": name, "log_fuel": None, "gear": None, "error": ""}
            try:
                cyc = fleet_cycle(name)
                p = record_parameters(rec, [cyc])
                sched = default_schedule(cyc, p, None)  # the vehicle's own rule (vehicle.gear_rule)
                df = run_batch(cyc, variants, method="backward", params=p, mode=MODE, gears=sched)
                fuel = df["fuel_l_per_100km"].to_numpy()
                if not np.all(np.isfinite(fuel) & (fuel > 0)):
                    raise VpsimError("non-positive or non-finite fuel on the technology grid")
                row["log_fuel"] = np.log(fuel).reshape(shape)
                row["gear"] = sched.gear.astype(np.int16)  # a CVT's grid has up to MAX_CVT_STEPS points
            except Exception as exc:  # one vehicle's failure never stops the fleet
                row["error"] = _one_line(exc)
            out.append(row)
    return out


def fit_inputs(ok: list[dict], by_key: dict, cycles) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What the technology fit takes from the grid rows ``ok`` (those that ran) of the engine cars
    ``by_key``: ln fuel at the grid's nodes, the measured ln L/100 km, each row's class, and its fuel per
    watt of accessory load (:func:`vpsim.fleet.calibrate.fuel_per_watt`). The fleet run's and any rerun of
    its fit with other folds (``benchmarks/fold_seed_spread.py``)."""
    lg = np.stack([r["log_fuel"] for r in ok])
    meas = np.array([_log_l100(by_key[r["key"]].measured_mpg[r["cycle"]]) for r in ok])
    vclass = np.array([_vehicle_class(by_key[r["key"]]) for r in ok])
    fpw = {c: cal.fuel_per_watt(fleet_cycle(c).duration_s, fleet_cycle(c).distance_m) for c in cycles}
    per_watt = np.array([fpw[r["cycle"]] for r in ok])
    return lg, meas, vclass, per_watt


def predict_chunk(items: list[tuple[VehicleRecord, str, dict, np.ndarray]], method: str) -> list[dict]:
    """One run per (record, cycle, technology, gear per sample) with ``method``; dicts with the prediction."""
    with _kernels_on_one_thread():
        return _predict_chunk(items, method)


def _predict_chunk(items, method: str) -> list[dict]:
    from ..batch import run_batch
    from ..gears import GearSchedule
    from .vehicle import record_parameters

    out = []
    for rec, name, tech, gear in items:
        row = {"key": rec.key, "cycle": name}
        try:
            cyc = fleet_cycle(name)
            sched = GearSchedule(cyc.time_s.copy(), gear.astype(np.int64), source="fleet: default rule")
            p = record_parameters(rec, [cyc], technology={k: tech[k] for k in cal.TECH_PARAMS})
            drv = {"driver": FORWARD_DRIVER} if method == "forward" else {}
            df = run_batch(cyc, None, method=method, params=p, mode=MODE, gears=sched, **drv)
            l100 = float(df["fuel_l_per_100km"].iloc[0])
            row["predicted_l_per_100km"] = l100
            row["trace_miss_s"] = float(df["trace_miss_s"].iloc[0])
            if "max_speed_error_mps" in df:
                row["max_speed_error_mps"] = float(df["max_speed_error_mps"].iloc[0])
            row["n_gears_model"] = p.transmission.n_gears
            row["rolling_resistance"] = p.vehicle.rolling_resistance
            row["drag_coefficient"] = p.vehicle.drag_coefficient
            row["error"] = ""
        except Exception as exc:
            row["error"] = _one_line(exc)
        out.append(row)
    return out


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}"[:200]


# --- execution ---------------------------------------------------------------------------------------------


class _Serial:
    name = "serial (this process)"

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def map(self, fn, chunks, *args):
        for c in chunks:
            yield fn(c, *args)


class _Pool:
    """Local worker processes (spawned), one kernel thread each; results in submission order."""

    def __init__(self, n: int):
        self.n = n
        self.name = f"{n} local processes"

    def __enter__(self):
        import concurrent.futures as cf
        import multiprocessing

        self.pool = cf.ProcessPoolExecutor(
            max_workers=self.n, mp_context=multiprocessing.get_context("spawn")
        )
        return self

    def __exit__(self, *exc):
        self.pool.shutdown(wait=True, cancel_futures=True)
        return False

    def map(self, fn, chunks, *args):
        futures = [self.pool.submit(fn, c, *args) for c in chunks]
        for f in futures:
            yield f.result()


class _Remembering:
    """An executor that keeps each chunk's result under what produced it (the function, the chunk and the
    arguments, pickled and hashed) and submits only the chunks it has not seen. Every result of the fleet's
    chunk functions follows from those alone, so several deals of one list (``run_fleet(..., seed=s,
    memory=m)`` with one ``m``) compute the deal-independent work once: the technology grids and FASTSim's
    default and calibration-grid runs; what depends on the deal (the fits' predictions) differs in its
    arguments and is run. Results come out in submission order, as from the executor it wraps."""

    def __init__(self, inner, memory: dict):
        self.inner, self.memory, self.name = inner, memory, inner.name

    def __enter__(self):
        self.inner.__enter__()
        return self

    def __exit__(self, *exc):
        return self.inner.__exit__(*exc)

    def map(self, fn, chunks, *args):
        import hashlib
        import pickle

        chunks = list(chunks)
        name = (fn.__module__, fn.__qualname__)
        keys = [hashlib.blake2b(pickle.dumps((name, c, args), protocol=5)).digest() for c in chunks]
        todo: dict[bytes, object] = {}
        for k, c in zip(keys, chunks, strict=True):
            if k not in self.memory and k not in todo:
                todo[k] = c
        fresh = self.inner.map(fn, list(todo.values()), *args)
        for k in keys:
            if k not in self.memory:
                self.memory[k] = next(fresh)
            yield self.memory[k]


def _dask(scheduler: str | None, local: int | None):
    """The sweeps' Dask executor (connection, local cluster, clean-up), mapping in submission order."""
    from ..sweep.runner import _DaskExecutor

    class _FleetDask(_DaskExecutor):
        name = f"dask local cluster of {local}" if local else f"dask scheduler {scheduler}"

        def map(self, fn, chunks, *args):
            futures = [self.client.submit(fn, c, *args, pure=False) for c in chunks]
            for f in futures:  # in submission order: the rows come out in the same order as serial
                yield f.result()

    return _FleetDask(scheduler, local)


def _progress(label: str, done: int, total: int, t0: float, enabled: bool) -> None:
    if enabled:
        sys.stderr.write(f"\rvpsim fleet: {label} {done}/{total} ({time.perf_counter() - t0:.0f} s)")
        if done == total:
            sys.stderr.write("\n")
        sys.stderr.flush()


# --- the fleet ---------------------------------------------------------------------------------------------


def run_fleet(
    source,
    *,
    cycles=FLEET_CYCLES,
    folds: int = 5,
    method: str = "backward",
    local_cluster: int | None = None,
    scheduler: str | None = None,
    progress: bool = False,
    limit: int | None = None,
    peer: bool = True,
    workers: int | None = None,
    group_by: str = cal.DEFAULT_GROUPING,
    seed: int = cal.SEED,
    memory: dict | None = None,
    deal: str = cal.DEFAULT_DEAL,
) -> FleetRun:
    """Run every usable vehicle of ``source`` (a path or a :class:`TestCarList`) on the cycles it measured.

    ``limit``: only the first ``limit`` usable vehicles (in file order), for a quick look. ``peer``: also
    run FASTSim (:mod:`vpsim.fleet.peer`) on the same records when it is installed. ``workers``: local
    processes when no Dask cluster is given (default: the number of cores; 1 runs in this process).
    ``group_by``: what a fold holds out together (:func:`vpsim.fleet.calibrate.vehicle_groups`): ``family``
    (default), ``record``, or ``manufacturer`` (one fold per manufacturer; ``folds`` is then not used).
    ``seed``: the order the groups are dealt into folds in (:func:`vpsim.fleet.calibrate.assign_folds`; every
    part of the fleet, and its peer's calibration, on the same deal); another seed is an equally valid deal.
    ``deal``: ``shuffle`` (the default and the headline's); ``hash``, where a family's fold depends on the
    seed and its own label alone, so families the list gains or loses move no other family; or ``blocks``,
    the families in that hash's order cut into folds of equal records, so the folds are balanced and a
    family gained or lost moves only a few at the folds' edges (:func:`vpsim.fleet.calibrate.assign_folds`).
    ``memory``: a dict kept between calls (empty at first) in which the runs' chunk results are remembered
    (:class:`_Remembering`), so that runs of one list on several seeds compute the deal-independent grids
    and peer runs once; the figures are those of separate runs.
    """
    t_start = time.perf_counter()
    cycles = tuple(cycles)
    for c in cycles:
        if c not in FLEET_CYCLES:
            raise VpsimError(f"unknown fleet cycle {c!r}; expected some of {', '.join(FLEET_CYCLES)}")
    if not cycles:
        raise VpsimError("no cycle given")
    if len(set(cycles)) != len(cycles):
        raise VpsimError(f"cycles {', '.join(cycles)}: a cycle named twice would count its rows twice")
    if limit is not None and limit < 1:
        raise VpsimError(f"limit = {limit}: expected a positive number of vehicles")
    if method not in METHODS:
        raise VpsimError(f"method {method!r} is not available for the fleet; expected backward or forward")
    if scheduler is not None and local_cluster is not None:
        raise VpsimError("give a scheduler address or a local cluster size, not both")
    if local_cluster is not None and local_cluster < 1:
        raise VpsimError(f"local cluster size must be at least 1, got {local_cluster}")
    if workers is not None and workers < 1:
        raise VpsimError(f"workers must be at least 1, got {workers}")
    if group_by not in cal.GROUPINGS:
        raise VpsimError(f"--group-by {group_by!r}: expected one of {', '.join(cal.GROUPINGS)}")
    if folds < 2:
        raise VpsimError(f"--folds must be at least 2 (cross-validation), got {folds}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise VpsimError(f"--seed {seed!r}: expected a whole number, 0 or more")
    if deal not in cal.DEALS:
        raise VpsimError(f"--deal {deal!r}: expected one of {', '.join(cal.DEALS)}")
    if deal != cal.DEFAULT_DEAL and group_by == "manufacturer":
        raise VpsimError(
            f"--deal {deal} with --group-by manufacturer: each manufacturer is its own fold, no deal"
        )
    cars = source if isinstance(source, TestCarList) else read_test_car_list(source)
    vehicles = [v for v in cars.vehicles if any(c in v.measured_mpg for c in cycles)]
    if limit is not None:
        vehicles = vehicles[:limit]
    groups = cal.vehicle_groups(vehicles, group_by)
    n_groups = len(set(groups.values()))
    if group_by == "manufacturer":
        folds = n_groups  # leave one manufacturer out at a time
    if n_groups < max(folds, 2):
        raise VpsimError(
            f"{len(vehicles)} usable vehicle(s) in {n_groups} {group_by} group(s) with a test on "
            f"{', '.join(cycles)}: too few for {max(folds, 2)} folds"
        )
    spec = cal.FoldSpec(folds, group_by, seed, deal)  # (every part deals its records by it)
    try:
        fold_of = spec.assign([v.key for v in vehicles], groups)
    except ValueError as exc:
        raise VpsimError(f"{len(vehicles)} usable vehicle(s): {exc}") from None
    timings = {"read_s": time.perf_counter() - t_start}
    work = [(v, tuple(c for c in cycles if c in v.measured_mpg)) for v in vehicles]
    chunks = [work[i : i + CHUNK] for i in range(0, len(work), CHUNK)]
    if scheduler is not None or local_cluster is not None:
        executor = _dask(scheduler, local_cluster)
    else:
        import os

        n = workers or os.cpu_count() or 1
        if workers is None and len(work) < 4 * CHUNK:  # a small fleet is not worth starting processes for
            n = 1
        executor = _Serial() if n == 1 or len(chunks) == 1 else _Pool(min(n, len(chunks)))
    if memory is not None:
        executor = _Remembering(executor, memory)
    with executor:
        # 2. the technology grid
        t0 = time.perf_counter()
        grid_rows: list[dict] = []
        for i, part in enumerate(executor.map(grid_chunk, chunks)):
            grid_rows += part
            _progress("technology grid, vehicles", min((i + 1) * CHUNK, len(work)), len(work), t0, progress)
        timings["grid_s"] = time.perf_counter() - t0
        # 3. cross-validated technology
        by_key = {v.key: v for v in vehicles}
        ok = [r for r in grid_rows if r["log_fuel"] is not None]
        if not ok:
            raise VpsimError("no vehicle could be simulated on the technology grid: " + grid_rows[0]["error"])
        lg, meas, vclass, per_watt = fit_inputs(ok, by_key, cycles)
        vfold = np.array([fold_of[r["key"]] for r in ok])
        tech = cal.cross_validate(lg, meas, vfold, vclass, folds, per_watt)
        tech_all = cal.fit_all(lg, meas, vclass, per_watt)
        # 4. predictions at each vehicle's out-of-fold technology
        t0 = time.perf_counter()
        failed_grid = {(r["key"], r["cycle"]): r["error"] for r in grid_rows if r["log_fuel"] is None}
        gears = {(r["key"], r["cycle"]): r["gear"] for r in ok}
        items = [
            (v, c, tech[(fold_of[v.key], _vehicle_class(v))], gears[(v.key, c)])
            for v, cs in work
            for c in cs
            if (v.key, c) not in failed_grid
        ]
        pchunks = [items[i : i + CHUNK * 2] for i in range(0, len(items), CHUNK * 2)]
        preds: dict[tuple[str, str], dict] = {}
        done = 0
        for part in executor.map(predict_chunk, pchunks, method):
            for r in part:
                preds[(r["key"], r["cycle"])] = r
            done += len(part)
            _progress(f"{method} runs", done, len(items), t0, progress)
        timings["predict_s"] = time.perf_counter() - t0
        # 5. the peer on the same records and cycles
        from . import peer as peer_mod
        from . import peer_cache

        peer_state = (
            peer_mod.status()
            if peer
            else {"available": False, "version": None, "reason": "not run (--no-peer)"}
        )
        peer_rows: dict[tuple[str, str], dict] = {}
        peer_cal_rows: dict[tuple[str, str], dict] = {}
        peer_technology: dict = {}
        cache_before = peer_cache.entries() if peer_state["available"] else None
        if peer_state["available"]:
            t0 = time.perf_counter()
            pitems = [(v, c) for v, cs in work for c in cs]
            pch = [pitems[i : i + CHUNK * 2] for i in range(0, len(pitems), CHUNK * 2)]
            done = 0
            for part in executor.map(peer_mod.peer_chunk, pch):
                for r in part:
                    peer_rows[(r["key"], r["cycle"])] = r
                done += len(part)
                _progress("FASTSim runs", done, len(pitems), t0, progress)
            timings["peer_s"] = time.perf_counter() - t0
            # the calibrated peer: its technology per class on the same folds, then one run per row
            t0 = time.perf_counter()
            grid_peer: list[dict] = []
            done = 0
            for part in executor.map(peer_mod.calibration_chunk, pch):
                grid_peer += part
                done += len(part)
                _progress("FASTSim calibration runs", done, len(pitems), t0, progress)
            okp = [r for r in grid_peer if r["log_l100"] is not None]
            if okp:
                peer_tech = peer_mod.calibrate_peer(
                    np.stack([r["log_l100"] for r in okp]),
                    np.array([_log_l100(by_key[r["key"]].measured_mpg[r["cycle"]]) for r in okp]),
                    np.array([fold_of[r["key"]] for r in okp]),
                    np.array([_vehicle_class(by_key[r["key"]]) for r in okp]),
                    folds,
                    cal.CLASSES,
                )
                citems = [
                    (v, c, peer_tech[(fold_of[v.key], _vehicle_class(v))]) for v, cs in work for c in cs
                ]
                cch = [citems[i : i + CHUNK * 2] for i in range(0, len(citems), CHUNK * 2)]
                for part in executor.map(peer_mod.peer_chunk, cch):
                    for r in part:
                        peer_cal_rows[(r["key"], r["cycle"])] = r
                peer_technology = {
                    f"fold{f}.{cls}": {k: (round(x, 6) if isinstance(x, float) else x) for k, x in t.items()}
                    for (f, cls), t in sorted(peer_tech.items())
                }
            timings["peer_calibrated_s"] = time.perf_counter() - t0
        # 6. the battery-electric records: the same procedure with the class "bev" (vpsim.fleet.ev)
        t0 = time.perf_counter()
        evs = cars.ev_vehicles if limit is None else cars.ev_vehicles[:limit]
        ev_out = _run_evs(evs, spec, executor, peer_state, progress, timings)
        timings["ev_s"] = time.perf_counter() - t0
        # 7. the full hybrids: the same procedure with the classes hev_split, hev_p2 (vpsim.fleet.hev)
        t0 = time.perf_counter()
        hevs = cars.hev_vehicles if limit is None else cars.hev_vehicles[:limit]
        hev_out = _run_hevs(hevs, spec, executor, peer_state, progress, timings)
        timings["hev_s"] = time.perf_counter() - t0
        # 8. the mild hybrids: the same procedure with the classes mhev_p0, mhev_p1 (vpsim.fleet.mhev)
        t0 = time.perf_counter()
        mhevs = cars.mhev_vehicles if limit is None else cars.mhev_vehicles[:limit]
        mhev_out = _run_mhevs(mhevs, spec, executor, peer_state, progress, timings)
        timings["mhev_s"] = time.perf_counter() - t0
    rows = []
    for v, cs in work:
        for c in cs:
            row = _row(
                v, c, fold_of[v.key], groups[v.key], tech, preds.get((v.key, c)), failed_grid.get((v.key, c))
            )
            if peer_state["available"]:
                pr = peer_rows.get((v.key, c), {})
                mpg = pr.get("peer_mpg", math.nan)
                meas = v.measured_mpg[c]
                row["fastsim_mpg"] = round(mpg, 4) if math.isfinite(mpg) else math.nan
                row["fastsim_error_pct"] = (
                    round(100 * (mpg - meas) / meas, 4) if math.isfinite(mpg) else math.nan
                )
                row["fastsim_status"] = pr.get("peer_error") or (
                    "ok" if pr.get("peer_trace_met") else "trace_miss" if pr else "not run"
                )
                pc = peer_cal_rows.get((v.key, c), {})
                mpg = pc.get("peer_mpg", math.nan)
                row["fastsim_calibrated_mpg"] = round(mpg, 4) if math.isfinite(mpg) else math.nan
                row["fastsim_calibrated_error_pct"] = (
                    round(100 * (mpg - meas) / meas, 4) if math.isfinite(mpg) else math.nan
                )
            rows.append(row)
    timings["total_s"] = time.perf_counter() - t_start
    technology = {
        f"fold{f}.{cls}": {k: (round(x, 6) if isinstance(x, float) else x) for k, x in t.items()}
        for (f, cls), t in sorted(tech.items())
    }
    if peer_state["available"]:  # FASTSim's runs remembered on disk (vpsim.fleet.peer_cache): run.json
        peer_state = dict(peer_state, run_cache=peer_cache.describe(cache_before))
    return FleetRun(
        rows,
        cars,
        cycles,
        folds,
        method,
        technology,
        tech_all,
        timings,
        executor.name,
        peer_state,
        grouping=group_by,
        n_groups=n_groups,
        seed=seed,
        deal=deal,
        peer_technology=peer_technology,
        ev=ev_out,
        hev=hev_out,
        mhev=mhev_out,
    )


def _log_l100(mpg: float) -> float:
    return math.log(mpg_from_l_per_100km(mpg))  # the same conversion both ways: L/100 km = 235.2 / mpg


def _row(
    v: VehicleRecord,
    cycle: str,
    fold: int,
    family: str,
    tech: dict,
    pred: dict | None,
    grid_error: str | None,
) -> dict:
    t = tech[(fold, _vehicle_class(v))]
    row = {
        "vehicle_id": v.vehicle_id,
        "configuration": v.configuration,
        "make": v.make,
        "model": v.model,
        "manufacturer": v.manufacturer,
        "cycle": cycle,
        "measured_mpg": round(v.measured_mpg[cycle], 4),
        "predicted_mpg": math.nan,
        "error_pct": math.nan,
        "fold": fold,
        "status": "ok",
        "family": family,
        "transmission": v.transmission_kind,
        "n_gears": v.n_gears,
        "boosted": v.boosted,
        "cylinders": v.cylinders,
        "displacement_l": v.displacement_l,
        "rated_power_kw": round(v.rated_power_kw, 2),
        "test_mass_kg": round(v.mass_kg, 1),
        "power_to_mass_w_per_kg": round(1e3 * v.rated_power_kw / v.mass_kg, 2),
        "specific_power_kw_per_l": round(v.specific_power_kw_per_l, 2),
        "technology_class": _vehicle_class(v),
        "thermal_efficiency": t[cal.TECH_PARAMS[0]],
        "friction_coefficient": t[cal.TECH_PARAMS[1]],
        "accessory_power_w": t[cal.TECH_PARAMS[2]],
        "trace_miss_s": math.nan,
        "detail": "",
    }
    err = grid_error or (pred or {}).get("error") or ("" if pred else "not run")
    if err:
        row["status"] = "failed"
        row["detail"] = err
        return row
    mpg = mpg_from_l_per_100km(pred["predicted_l_per_100km"])
    row["predicted_mpg"] = round(mpg, 4)
    row["error_pct"] = round(100.0 * (mpg - v.measured_mpg[cycle]) / v.measured_mpg[cycle], 4)
    row["trace_miss_s"] = pred["trace_miss_s"]
    if "max_speed_error_mps" in pred:
        row["max_speed_error_mps"] = round(pred["max_speed_error_mps"], 4)
    if pred["trace_miss_s"] > 0:
        row["status"] = "trace_miss"
        if "max_speed_error_mps" in pred:  # the forward method: the PI driver's tracking
            row["detail"] = (
                f"the speed is outside the trace's band for {pred['trace_miss_s']:.3g} s "
                f"(max error {pred['max_speed_error_mps']:.2f} m/s)"
            )
        else:
            row["detail"] = f"the engine's full-load torque misses the trace for {pred['trace_miss_s']:g} s"
    return row


__all__ = ["FleetRun", "METHODS", "grid_chunk", "predict_chunk", "run_fleet"]
