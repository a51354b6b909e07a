"""Running a sweep: plan the rows, skip those already stored, compute the rest in chunks, store each chunk.

Execution (one code path for the work, :func:`compute_chunk`, three ways to run it):

* ``workers=1``: in this process, chunk after chunk;
* ``workers=N`` (default: all local cores): a pool of N local processes (spawned; they ignore Ctrl-C, which
  only the parent handles). A pool broken by a killed process is restarted and its chunks resubmitted. By
  default a sweep estimated at under about 1.5 s of work runs in this process instead, as starting the
  processes would cost more than it saves;
* ``scheduler="tcp://host:port"``: a running Dask cluster; ``local_cluster=N``: an embedded
  :class:`dask.distributed.LocalCluster` of N single-threaded worker processes, closed at the end. A chunk on
  a worker that dies is rerun elsewhere by Dask.

A chunk is a group of whole design points (all of one design's cycle x method x driver rows, so the
acceleration run is shared) sized so that it takes some tenths of a second: scheduling and storing then cost
little against the work (see ``benchmarks/sweep_throughput.py``), and there are still several chunks per
worker to balance the load. Rows are written by the calling process only, as chunks finish, through the
store (:mod:`vpsim.sweep.store`); a design point that fails (an invalid combination, a solver failure) is a
row with ``error`` filled and NaN objectives, and the sweep goes on. Nothing here prints: progress is
reported through the ``progress(done_rows, total_rows)`` callback.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import importlib.util
import math
import multiprocessing
import os
import signal
import socket
import time
import uuid
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .. import __version__
from ..errors import VpsimError
from .spec import AccelerationSettings, SweepSpec, apply_changes, load_spec, make_spec
from .store import (
    DesignValues,
    MemoryStore,
    ResultStore,
    cycle_key,
    design_identity,
    design_values,
    point_identity,
)

# costs in rough units of 1 ms, used to size chunks: per design (parameters, bookkeeping), per row by
# method (one simulate call; a row of the compiled backward batch), per design for the 0-100 km/h run
_DESIGN_COST = 0.03
_ROW_COST = {"backward": 2.5, "inverse": 10.0, "forward": 10.0}
_BATCH_ROW_COST = 0.04
_ACCEL_COST = 1.5
_TARGET_CHUNK_COST = 400.0
_SMALL_SWEEP_COST = 1500.0  # below this, the default runs in process (starting worker processes costs ~2 s)
_CHUNKS_PER_WORKER = 4

OBJECTIVES = {
    "fuel_l_per_100km": "float",
    "fuel_kg": "float",
    "distance_km": "float",
    "trace_miss_s": "float",
    "trace_miss_max_torque_shortfall_nm": "float",
    "max_speed_error_mps": "float",
    "accel_0_100_s": "float",
    "accel_note": "str",
}
_ID_COLUMNS = {
    "point_id": "str",
    "design_id": "str",
    "design": "int",
    "is_baseline": "bool",
    "cycle": "str",
    "method": "str",
    "driver": "str",
    "mode": "str",
}
_META_COLUMNS = {
    "error": "str",
    "warning": "str",
    "compute_time_s": "float",
    "run_id": "str",
    "computed_at": "float",
    "worker": "str",
    "vpsim_version": "str",
}


def result_schema(spec: SweepSpec) -> dict[str, str]:
    """Column name -> type of the result table for ``spec`` (a hybrid base's columns too: sweep/hybrid.py)."""
    from .hybrid import HYBRID_COLUMNS

    params = {a.name: ("str" if a.kind == "ratios" else a.kind) for a in spec.axes}
    extra = HYBRID_COLUMNS if spec.hybrid else {}
    return _ID_COLUMNS | params | {"displacement_l": "float"} | OBJECTIVES | extra | _META_COLUMNS


# --- work units -------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Task:
    """One design point and the rows of it still to compute: (point_id, cycle index, method, driver)."""

    design: int
    design_id: str
    changes: dict
    is_baseline: bool
    rows: tuple[tuple[str, int, str, str], ...]
    values: dict = field(default_factory=dict)  # every swept parameter's value (the base's where unchanged)


@dataclass(frozen=True)
class Chunk:
    """What a worker needs: base parameters, cycles (and gear schedules), settings, a group of tasks."""

    base: object  # Parameters
    cycles: tuple  # Cycle objects, indexed by Task.rows
    schedules: tuple  # GearSchedule per cycle ("baseline" gears) or None per cycle ("per_design")
    mode: str
    acceleration: AccelerationSettings
    tasks: tuple[Task, ...]
    run_id: str
    schema: dict
    single_thread: bool = False  # limit compiled kernels to one thread (one worker process per core)
    hybrid: bool = False  # a hybrid base: rows through vpsim.sweep.hybrid, with the management ``ems``
    ems: str | None = None

    @property
    def n_rows(self) -> int:
        return sum(len(t.rows) for t in self.tasks)


@dataclass
class Plan:
    """Every row of a sweep, with its identity."""

    spec: SweepSpec
    base: object
    cycles: tuple
    schedules: tuple
    tasks: list[Task]  # all rows, grouped by design

    @property
    def n_rows(self) -> int:
        return sum(len(t.rows) for t in self.tasks)

    def pending(self, done: set[str]) -> list[Task]:
        if not done:
            return list(self.tasks)
        out = []
        for t in self.tasks:
            rows = tuple(r for r in t.rows if r[0] not in done)
            if rows:
                out.append(Task(t.design, t.design_id, t.changes, t.is_baseline, rows, t.values))
        return out


def plan(spec: SweepSpec) -> Plan:
    """All rows of ``spec`` with their point ids (cheap: no simulation but the base's gear schedules)."""
    from ..cycles import load_cycle
    from ..gears import default_schedule
    from ..model.maps import cached_engine_map

    base = spec.parameters()
    cycles = tuple(load_cycle(c) for c in spec.cycles)
    if spec.gears == "baseline" and not spec.hybrid:  # a hybrid runs on its own gear rule
        schedules = tuple(default_schedule(c, base, cached_engine_map(base.engine)) for c in cycles)
    else:
        schedules = (None,) * len(cycles)
    ckeys = [cycle_key(c) for c in cycles]
    flat = base.flat()
    base_design = DesignValues.of(flat)
    accel = spec.acceleration.as_dict() if spec.acceleration.enabled else None
    combos = []
    for ci in range(len(cycles)):
        for m in spec.methods:
            for d in [""] if m == "backward" else spec.drivers:
                dvals = {k: v for k, v in flat.items() if k.startswith(f"drivers.{d}.")} if d else None
                combos.append((ci, m, d, dvals))
    base_values = design_values(flat, {})
    base_values["engine.scale"] = 1.0  # a sizing rule's value at the base (spec.apply_changes)
    for a in spec.axes:
        if a.name.startswith("transmission.gearbox_ratios["):
            base_values[a.name] = base_values["transmission.gearbox_ratios"][
                int(a.name[a.name.index("[") + 1 : -1]) - 1
            ]
    tasks = []
    seen: set[str] = set()
    for des in spec.designs():
        did = design_identity(base_design, des.changes)
        if did in seen:  # e.g. a grid point equal to the baseline
            continue
        seen.add(did)
        rows = tuple(
            (point_identity(did, ckeys[ci], m, d, dv, spec.mode, spec.gears, accel), ci, m, d)
            for ci, m, d, dv in combos
        )
        values = {a.name: des.changes.get(a.name, base_values[a.name]) for a in spec.axes}
        tasks.append(Task(des.index, did, des.changes, des.is_baseline, rows, values))
    return Plan(spec, base, cycles, schedules, tasks)


def _cost_model(spec: SweepSpec) -> Callable[[Task], float]:
    """Estimated cost of a task in units of about 1 ms (used to size chunks, not to promise times)."""
    batch = batch_available() and spec.gears == "baseline"
    accel = _ACCEL_COST if spec.acceleration.enabled else 0.0

    if spec.hybrid:
        from .hybrid import ROW_COST

        hybrid_row = ROW_COST[spec.ems or spec.parameters().hybrid.ems]

    def cost(t: Task) -> float:
        if spec.hybrid:
            return _DESIGN_COST + hybrid_row * len(t.rows) + accel
        rows = sum(_BATCH_ROW_COST if (r[2] == "backward" and batch) else _ROW_COST[r[2]] for r in t.rows)
        return _DESIGN_COST + rows + accel

    return cost


def make_chunks(
    tasks: list[Task],
    plan_: Plan,
    *,
    run_id: str,
    workers: int,
    chunk_size: int | None,
    schema: dict,
    single_thread: bool = False,
) -> list[Chunk]:
    """Group whole designs into chunks: ``chunk_size`` rows each, or sized by the estimated cost."""
    spec = plan_.spec
    cost = _cost_model(spec)

    if chunk_size is None:
        total = sum(cost(t) for t in tasks)
        limit = max(min(_TARGET_CHUNK_COST, total / (_CHUNKS_PER_WORKER * max(workers, 1))), 1e-9)
        size_of = cost
    else:
        if chunk_size < 1:
            raise VpsimError(f"chunk size must be at least 1, got {chunk_size}")
        limit = float(chunk_size)

        def size_of(t):
            return len(t.rows)

    chunks, group, acc = [], [], 0.0
    for t in tasks:
        c = size_of(t)
        if group and acc + c > limit + 1e-9:
            chunks.append(group)
            group, acc = [], 0.0
        group.append(t)
        acc += c
    if group:
        chunks.append(group)
    return [
        Chunk(
            plan_.base,
            plan_.cycles,
            plan_.schedules,
            spec.mode,
            spec.acceleration,
            tuple(g),
            run_id,
            schema,
            single_thread,
            spec.hybrid,
            spec.ems,
        )
        for g in chunks
    ]


# --- the work ---------------------------------------------------------------------------------------------


def compute_chunk(chunk: Chunk) -> pd.DataFrame:
    """Compute every row of a chunk; failures become rows with ``error`` set. Runs on any worker.

    Backward rows go through the compiled many-variant path (:func:`vpsim.batch.run_batch`) where it is
    installed and the gears are the baseline schedule; otherwise (and for a design the batch cannot take, such
    as a whole new ratio set) each row is one :func:`vpsim.simulate` call with the same exact BQM fuel flow
    and the same schedule, so both paths give the same numbers (to about 1e-14).
    """
    with _kernel_threads(1 if chunk.single_thread else None):
        return _compute_chunk(chunk)


def _compute_chunk(chunk: Chunk) -> pd.DataFrame:
    from .store import conform

    t_start = time.time()
    params_of: dict[int, object] = {}
    setup_error: dict[int, str] = {}

    def params(t: Task):
        """The design's validated parameters (None, with the reason in setup_error, if invalid)."""
        if t.design not in params_of and t.design not in setup_error:
            try:
                params_of[t.design] = apply_changes(chunk.base, t.changes)
            except Exception as exc:  # an invalid combination is a result, not a crash
                setup_error[t.design] = _one_line(exc)
        return params_of.get(t.design)

    # a chunk of backward and forward rows for the compiled batch is validated as a whole, much cheaper than
    # building every design's Parameters; anything else (or a failed check) validates design by design
    whole = _batch_only(chunk) and _valid_together(chunk)
    if not whole:
        for t in chunk.tasks:
            params(t)
    if chunk.acceleration.enabled:
        accel = _accelerations(chunk, params_of)
    else:
        accel = {}
    out: dict[str, dict] = {}  # point_id -> objectives, error, warning, compute time
    groups: dict[tuple[int, str, str], list[tuple[Task, str]]] = {}
    for t in chunk.tasks:
        for pid, ci, method, driver in t.rows:
            if whole or t.design in params_of:
                groups.setdefault((ci, method, driver), []).append((t, pid))
            else:
                out[pid] = {"error": setup_error[t.design]}
    for (ci, method, driver), items in groups.items():
        cycle, schedule = chunk.cycles[ci], chunk.schedules[ci]
        if method in ("backward", "forward") and schedule is not None and batch_available():
            batchable = [(t, pid) for t, pid in items if not _changes_grid(t.changes, chunk.base)]
            done = _batch_rows(cycle, schedule, chunk, batchable, method, driver)
            out.update(done)
            items = [(t, pid) for t, pid in items if pid not in done]
        for t, pid in items:
            p = params(t)
            out[pid] = (
                _one_row(cycle, schedule, method, driver, p, chunk.mode, chunk)
                if p is not None
                else {"error": setup_error[t.design]}
            )
    base_flat = DesignValues.of(chunk.base.flat())
    rows = []
    for t in chunk.tasks:
        p = params_of.get(t.design)
        if p is not None:
            disp = p.engine.displacement * 1e3
        elif t.design in setup_error:
            disp = math.nan
        else:
            v = design_values(base_flat, t.changes)
            disp = v["engine.cylinders"] * math.pi / 4.0 * v["engine.bore"] ** 2 * v["engine.stroke"] * 1e3
        for pid, ci, method, driver in t.rows:
            row = {
                "point_id": pid,
                "design_id": t.design_id,
                "design": t.design,
                "is_baseline": t.is_baseline,
                "cycle": chunk.cycles[ci].name,
                "method": method,
                "driver": driver,
                "mode": chunk.mode,
            }
            row.update(_param_columns(t.values))
            row["displacement_l"] = disp
            if t.design in accel:
                row["accel_0_100_s"], row["accel_note"] = accel[t.design]
            row.update(out[pid])
            rows.append(row)
    now = time.time()
    df = pd.DataFrame(rows)
    df["run_id"] = chunk.run_id
    df["computed_at"] = now
    df["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    df["vpsim_version"] = __version__
    if "error" in df:  # a failed row has NaN objectives, whatever was filled before the failure
        failed = df["error"].notna()
        for col, typ in OBJECTIVES.items():
            if col in df and typ == "float":
                df.loc[failed, col] = np.nan
    if chunk.hybrid:
        from .hybrid import flag_feasibility

        df = flag_feasibility(df)
    df = conform(df, chunk.schema)
    df.attrs["wall_s"] = now - t_start
    return df


def _batch_only(chunk: Chunk) -> bool:
    """Every row of the chunk goes to the compiled batch (backward or forward) and nothing needs a Parameters
    object."""
    return (
        batch_available()
        and not chunk.acceleration.enabled
        and all(s is not None for s in chunk.schedules)
        and all(r[2] in ("backward", "forward") for t in chunk.tasks for r in t.rows)
        and not any(_changes_grid(t.changes, chunk.base) for t in chunk.tasks)
    )


def _changes_grid(changes, base) -> bool:
    """A design that changes the whole gearbox, a CVT's step or its range (another ratio grid): not one
    ratio matrix with the rest of its batch."""
    if "transmission.gearbox_ratios" in changes or "transmission.cvt_ratio_step" in changes:
        return True
    if "engine.scale" in changes:  # a sizing rule (spec.apply_changes), not a column of the batch
        return True
    return base.transmission.is_cvt and any(k.startswith("transmission.gearbox_ratios[") for k in changes)


def _valid_together(chunk: Chunk) -> bool:
    """Validate all designs of the chunk at once (the batch's own vectorised check); False if any fails."""
    from ..batch import normalise_variants, validate_variants

    try:
        names, values = normalise_variants(_variant_columns(chunk.tasks, chunk.base), chunk.base)
        validate_variants(chunk.base, names, values)
    except Exception:
        return False
    return True


def _variant_columns(tasks, base) -> dict[str, np.ndarray]:
    """The designs' changes as one numeric column per parameter (base values where a design keeps them)."""
    values = DesignValues.of(base.flat())
    names = list(dict.fromkeys(k for t in tasks for k in t.changes))
    cols = {}
    for name in names:
        if name.startswith("transmission.gearbox_ratios["):
            default = values["transmission.gearbox_ratios"][int(name[name.index("[") + 1 : -1]) - 1]
        else:
            default = values[name]
        cols[name] = np.array([t.changes.get(name, default) for t in tasks], dtype=float)
    return cols or {"vehicle.mass": np.full(len(tasks), values["vehicle.mass"])}


def _accelerations(chunk: Chunk, params_of: dict) -> dict[int, tuple[float, str]]:
    """0-100 km/h of every valid design of the chunk, integrated together; a failure is isolated."""
    from ..performance import acceleration_times

    acc = chunk.acceleration
    kw = {"launch_speed": acc.launch_speed}
    if acc.shift_speed is not None:
        kw["shift_speed"] = acc.shift_speed
    else:
        kw["shift_fraction"] = acc.shift_fraction
    ok = [t.design for t in chunk.tasks if t.design in params_of]
    try:
        with _captured_warnings():
            res = acceleration_times([params_of[d] for d in ok], **kw)
        return {d: (r.time_s, r.reason) for d, r in zip(ok, res, strict=True)}
    except Exception:
        out = {}
        for d in ok:
            try:
                with _captured_warnings():
                    r = acceleration_times([params_of[d]], **kw)[0]
                out[d] = (r.time_s, r.reason)
            except Exception as exc:
                out[d] = (math.nan, f"failed: {_one_line(exc)}")
        return out


def _batch_rows(cycle, schedule, chunk: Chunk, items, method: str, driver: str) -> dict[str, dict]:
    """Rows of many designs in one batch call (one compiled pass, parallel over the designs); {} if the batch
    cannot take them, and the rows then run one by one."""
    from ..batch import run_batch

    if not items:
        return {}
    t0 = time.perf_counter()
    try:
        with _captured_warnings() as caught:
            df = run_batch(
                cycle,
                _variant_columns([t for t, _ in items], chunk.base),
                method,
                chunk.base,
                mode=chunk.mode,
                gears=schedule,
                **({"driver": driver} if method == "forward" else {}),
            )
    except Exception:
        return {}
    extra = {
        "warning": _one_line(caught[0].message) if caught else "",
        "compute_time_s": (time.perf_counter() - t0) / len(items),
    }
    # what Result.summary() says where the batch has no column: the backward method tracks the cycle
    # exactly; the forward method has no max-torque line to miss (its shortfall shows as speed error)
    for col in ("max_speed_error_mps", "trace_miss_max_torque_shortfall_nm"):
        if col not in df.columns:
            df[col] = 0.0
    cols = [c for c in OBJECTIVES if c in df.columns]
    arrays = [df[c].to_numpy().tolist() for c in cols]
    return {
        pid: dict(zip(cols, vals, strict=True)) | extra
        for (_, pid), vals in zip(items, zip(*arrays, strict=True), strict=True)
    }


def _one_row(cycle, schedule, method: str, driver: str, params, mode: str, chunk=None) -> dict:
    t0 = time.perf_counter()
    row: dict = {}
    try:
        with _captured_warnings() as caught:
            if chunk is not None and chunk.hybrid:
                from .hybrid import simulate_row

                row.update(simulate_row(cycle, method, driver, params, mode, chunk.ems, OBJECTIVES))
            else:
                row.update(_simulate_row(cycle, method, driver, params, mode, schedule))
        if caught:
            row["warning"] = _one_line(caught[0].message)
    except Exception as exc:  # a solver failure or an infeasible input is a result
        row["error"] = _one_line(exc)
    row["compute_time_s"] = time.perf_counter() - t0
    return row


def _simulate_row(cycle, method: str, driver: str, params, mode: str, schedule=None) -> dict:
    from ..model.maps import generate_engine_map
    from ..simulation import simulate

    if method == "backward":
        # the exact BQM fuel flow, as the compiled batch path computes it
        emap = generate_engine_map(params.engine, exact=True)
        r = simulate(cycle, "backward", params, mode=mode, gears=schedule, engine_map=emap, keep_series=False)
    else:
        r = simulate(cycle, method, params, driver=driver, mode=mode, gears=schedule)
    s = r.summary()
    return {k: s[k] for k in OBJECTIVES if k in s}


def _param_columns(values: dict) -> dict:
    return {k: (",".join(f"{x:g}" for x in v) if isinstance(v, tuple) else v) for k, v in values.items()}


def _one_line(exc) -> str:
    text = f"{type(exc).__name__}: {exc}" if isinstance(exc, BaseException) else str(exc)
    text = " ".join(text.split())
    return text[:500]


@contextlib.contextmanager
def _captured_warnings():
    """Numerical warnings of odd designs become part of the row, identically on every execution path."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield caught


@contextlib.contextmanager
def _kernel_threads(n: int | None):
    """Limit the compiled kernels' threads for the duration (a worker process per core needs one each)."""
    if n is None:
        yield
        return
    try:
        import numba
    except ImportError:  # pragma: no cover - numba is a dependency
        yield
        return
    before = numba.get_num_threads()
    numba.set_num_threads(min(n, before))
    try:
        yield
    finally:
        numba.set_num_threads(before)


# --- running ------------------------------------------------------------------------------------------------


def max_local_workers() -> int:
    """The most local worker processes a sweep starts: 4 per core (more only costs memory)."""
    return 4 * (os.cpu_count() or 1)


@dataclass
class SweepRun:
    """Outcome of :func:`run_sweep`: all results (stored before plus computed now) and counts for this run."""

    results: pd.DataFrame
    run_id: str
    n_rows: int  # rows the spec asks for
    n_skipped: int  # already stored before this run
    n_computed: int  # computed and stored by this run
    n_failed: int  # rows of this run with an error
    elapsed_s: float
    path: Path | None = None
    # chunks lost to the infrastructure (a worker that kept dying): not stored, --resume retries them
    chunk_errors: list[str] = field(default_factory=list)
    n_chunks: int = 0  # chunks this run sent out
    # damaged result parts/blocks found when resuming (one line each); their rows were computed again
    damaged: list[str] = field(default_factory=list)

    def rows_line(self) -> str:
        """Rows asked, computed now, present before, failed, and the time: one line."""
        return (
            f"{self.n_rows} rows: {self.n_computed} computed now, {self.n_skipped} already present, "
            f"{self.n_failed} failed (see the error column); {self.elapsed_s:.1f} s"
        )

    def __str__(self) -> str:
        """What the command line prints of a run: damaged parts found, :meth:`rows_line`, chunks lost, where
        the results are."""
        lines = [self.rows_line()]
        if self.damaged:
            more = f" (and {len(self.damaged) - 1} more)" if len(self.damaged) > 1 else ""
            lines.insert(
                0,
                f"found {len(self.damaged)} damaged result part(s) and computed their rows again: "
                f"{self.damaged[0]}{more}",
            )
        if self.chunk_errors:
            lines.append(
                f"{len(self.chunk_errors)} chunk(s) could not be computed ({self.chunk_errors[0]}); "
                "resume to retry them"
            )
        lines.append(f"results in {self.path}" if self.path is not None else "results in memory")
        return "\n".join(lines)

    def to_dataframe(self) -> pd.DataFrame:
        """The results, one row per design x cycle x method (x driver): :attr:`results`."""
        return self.results

    def plot(self, *, cycle: str | None = None, method: str | None = None):
        """The figure of the sweep: fuel on ``cycle`` (default the first) against 0-100 km/h with the Pareto
        front where the sweep computed acceleration (:func:`vpsim.sweep.plots.plot_pareto`), otherwise fuel
        against displacement (:func:`vpsim.sweep.plots.plot_fuel_vs_displacement`). Returns the Figure."""
        from .plots import ACCEL, plot_fuel_vs_displacement, plot_pareto

        df = self.results
        if df.empty:
            raise VpsimError("the sweep has no results to plot")
        for name, value in (("cycle", cycle), ("method", method)):
            have = sorted(set(df[name].astype(str)))
            if value is not None and value not in have:
                raise VpsimError(f"{name} {value!r} is not in the sweep's results; it has {', '.join(have)}")
        if ACCEL in df and np.isfinite(pd.to_numeric(df[ACCEL], errors="coerce")).any():
            ax, _ = plot_pareto(df, cycle=cycle, method=method)
        else:
            ax = plot_fuel_vs_displacement(df, method=method)
        return ax.figure


def run_sweep(
    spec: SweepSpec | str | Path | dict,
    out: str | Path | None = None,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    local_cluster: int | None = None,
    resume: bool = False,
    fmt: str | None = None,
    chunk_size: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> SweepRun:
    """Run (or, with ``resume=True``, complete) a sweep; results go to ``out`` as chunks finish.

    ``spec`` is a :class:`SweepSpec`, a spec TOML path or a dict of its keys. ``out`` is the output folder
    (``None``: keep the results in memory). Execution: ``scheduler`` (a Dask scheduler address) or
    ``local_cluster`` (N workers in an embedded Dask LocalCluster) or ``workers`` local processes (default
    all cores; 1 runs in this process). ``fmt`` is ``"parquet"`` (default) or ``"csv"``.
    """
    t0 = time.perf_counter()
    if isinstance(spec, str | Path):
        spec = load_spec(spec)
    elif isinstance(spec, dict):
        spec = make_spec(**spec)
    if scheduler is not None and local_cluster is not None:
        raise VpsimError("give a scheduler address or a local cluster size, not both")
    if local_cluster is not None and local_cluster < 1:
        raise VpsimError(f"local cluster size must be at least 1, got {local_cluster}")
    if workers is not None and workers < 1:
        raise VpsimError(f"workers must be at least 1, got {workers}")
    limit = max_local_workers()
    for what, n in (("workers", workers), ("local cluster size", local_cluster)):
        if n is not None and n > limit:
            raise VpsimError(
                f"{what} {n} is more than {limit} (4 per core of this machine); each is a process"
            )
    if fmt is not None and fmt not in ("parquet", "csv"):
        raise VpsimError(f"format must be parquet or csv, got {fmt!r}")
    schema = result_schema(spec)
    run_id = time.strftime("%Y%m%dT%H%M%S") + "-" + uuid.uuid4().hex[:8]
    store = MemoryStore() if out is None else ResultStore(out, fmt, schema)
    store.run_id = run_id
    store.open(
        resume=resume,
        meta={"spec": spec.as_dict(), "fingerprint": spec.fingerprint(), "vpsim_version": __version__},
    )
    try:
        p = plan(spec)
        done = store.completed() if resume else set()
        pending = p.pending(done)
        n_pending = sum(len(t.rows) for t in pending)
        if scheduler is not None or local_cluster is not None:
            executor = _DaskExecutor(scheduler, local_cluster)
        else:
            n = workers or os.cpu_count() or 1
            if workers is None:  # by default, work of a second or two is not worth starting processes for
                cost = _cost_model(spec)
                if sum(cost(t) for t in pending) < _SMALL_SWEEP_COST:
                    n = 1
            executor = _SerialExecutor() if n == 1 or n_pending <= 1 else _PoolExecutor(n)
        computed = failed = n_chunks = 0
        chunk_errors: list[str] = []
        if pending:
            with executor:
                if progress is not None:
                    progress(0, n_pending)
                chunks = make_chunks(
                    pending,
                    p,
                    run_id=run_id,
                    workers=executor.n_workers,
                    chunk_size=chunk_size,
                    schema=schema,
                    single_thread=executor.single_thread,
                )
                n_chunks = len(chunks)
                for _chunk, df, err in executor.map(chunks):
                    if err is not None:
                        chunk_errors.append(err)
                        continue
                    store.append(df)
                    computed += len(df)
                    failed += int(df["error"].notna().sum())
                    if progress is not None:
                        progress(computed, n_pending)
        results = store.read()
    finally:
        store.close()
    return SweepRun(
        results,
        run_id,
        p.n_rows,
        p.n_rows - n_pending,
        computed,
        failed,
        time.perf_counter() - t0,
        store.path,
        chunk_errors,
        n_chunks,
        list(getattr(store, "damaged", [])),
    )


class _SerialExecutor:
    n_workers = 1
    single_thread = False  # compiled kernels may use every core of this process

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def map(self, chunks: list[Chunk]) -> Iterator[tuple[Chunk, pd.DataFrame | None, str | None]]:
        for c in chunks:
            yield c, compute_chunk(c), None


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class _PoolExecutor:
    """Local worker processes; keeps ``2 x workers`` chunks in flight and restarts a broken pool."""

    max_restarts = 3
    single_thread = True

    def __init__(self, n: int):
        self.n_workers = n
        self._pool = None

    def _new_pool(self):
        ctx = multiprocessing.get_context("spawn")
        return cf.ProcessPoolExecutor(max_workers=self.n_workers, mp_context=ctx, initializer=_ignore_sigint)

    def __enter__(self):
        self._pool = self._new_pool()
        return self

    def __exit__(self, *exc):
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        return False

    def map(self, chunks):
        queue = list(reversed(chunks))
        restarts = 0
        in_flight: dict[cf.Future, Chunk] = {}
        while queue or in_flight:
            while queue and len(in_flight) < 2 * self.n_workers:
                c = queue.pop()
                in_flight[self._pool.submit(compute_chunk, c)] = c
            finished, _ = cf.wait(in_flight, return_when=cf.FIRST_COMPLETED)
            broken = False
            for f in finished:
                c = in_flight.pop(f)
                try:
                    df = f.result()
                except cf.process.BrokenProcessPool:
                    broken = True
                    queue.append(c)
                    continue
                except Exception as exc:
                    yield c, None, _one_line(exc)
                    continue
                yield c, df, None
            if broken:
                restarts += 1
                queue.extend(in_flight.values())
                in_flight.clear()
                self._pool.shutdown(wait=False, cancel_futures=True)
                if restarts > self.max_restarts:
                    for c in queue:
                        yield c, None, "the local worker processes kept dying; resume to retry"
                    return
                self._pool = self._new_pool()


class _DaskExecutor:
    """A Dask cluster (address) or an embedded LocalCluster; ``2 x workers`` chunks in flight."""

    single_thread = True  # one worker process per core is the norm; kernels then use one thread each

    def __init__(self, scheduler: str | None, local: int | None):
        self.scheduler = scheduler
        self.local = local
        self.client = None
        self.cluster = None
        self.n_workers = local or 1

    def __enter__(self):
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise VpsimError("a Dask cluster needs dask[distributed]: pip install 'vpsim[cluster]'") from None
        if self.local is not None:
            self.cluster = LocalCluster(
                n_workers=self.local, threads_per_worker=1, processes=True, dashboard_address=":0"
            )
            self.client = Client(self.cluster)
        else:
            try:
                self.client = Client(self.scheduler, timeout="20s")
            except (OSError, TimeoutError, ValueError, TypeError) as exc:  # ValueError: a malformed address
                raise VpsimError(f"cannot reach the Dask scheduler at {self.scheduler}: {exc}") from None
            self.n_workers = max(len(self.client.scheduler_info().get("workers", {})), 1)
        return self

    def __exit__(self, *exc):
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        return False

    def map(self, chunks):
        from dask.distributed import as_completed

        queue = list(reversed(chunks))
        owner = {}
        attempts: dict[int, int] = {}

        def submit():
            c = queue.pop()
            attempts[id(c)] = attempts.get(id(c), 0) + 1
            f = self.client.submit(compute_chunk, c, pure=False)
            owner[f.key] = c
            return f

        first = [submit() for _ in range(min(len(queue), 2 * self.n_workers))]
        ac = as_completed(first)
        futures = set(first)
        try:
            for f in ac:
                futures.discard(f)
                c = owner.pop(f.key)
                try:
                    df = f.result()
                except Exception as exc:  # KilledWorker after repeated deaths, or an escaped error
                    if attempts[id(c)] < _DASK_ATTEMPTS:
                        # a chunk is idempotent (rows are keyed by point_id): try it again, e.g. after a
                        # worker died and the client's connection state went astray with it
                        queue.append(c)
                    else:
                        yield c, None, _one_line(exc)
                else:
                    yield c, df, None
                f.release()
                if queue:
                    nf = submit()
                    futures.add(nf)
                    ac.add(nf)
        finally:
            for f in futures:
                f.cancel()


_DASK_ATTEMPTS = 3  # submissions of one chunk before its failure is reported


def batch_available() -> bool:
    """Whether the compiled many-variant backward path (``vpsim.batch``) is installed."""
    return importlib.util.find_spec("vpsim.batch") is not None
