"""Benchmarks: vpsim's methods side by side with FASTSim 3.1, batch throughput, linearity, cold start.

:func:`run_benchmarks` measures, on one machine:

* every method (and driver) on UDDS, NEDC and FTP-75 (and HWFET): the median wall time of repeated runs
  with the inputs prepared (engine map, gear schedule; timed separately as setup), solver steps, and peak
  memory of one run (``tracemalloc``: Python and NumPy allocations; and the rise of the process's peak
  resident set, which also sees native allocations such as FASTSim's Rust heap or Numba's);
* the peer, FASTSim 3.1 (``pip install fastsim==3.1.0``, the ``bench`` extra): its conventional 2012 Ford
  Fusion on UDDS and HWFET, ``SimDrive.walk()`` timed alone after a warm-up (the ``SimDrive`` construction
  separately), in this process before any vpsim code has run and in fresh processes of its own; its fastest
  settled figure is the one compared with. If FASTSim is not installed the peer is reported missing and no
  ratio against it is given;
* the ratios twice: from adjacent blocks of runs of both sides (robust to the load of other processes on a
  shared machine) and from each side's best settled median (the figure held against the targets: its row,
  its paired blocks or its fresh processes of its own, the same rule for both tools); the battery-electric
  and hybrid cars against FASTSim's BEV and hybrid the same way, from their rows and their paired blocks
  (:func:`vpsim.bench_powertrains.paired_rows`);
* batch throughput (:func:`vpsim.batch.run_batch`), backward and forward, runs per second, on the threads
  and on one; linearity: FTP-75 repeated 1, 4 and 16 times (:meth:`vpsim.cycles.Cycle.repeat`), time per
  repetition against the single cycle, sizes timed in rounds side by side; cold start: a fresh Python process
  importing vpsim and running UDDS once with the compiled code loaded from Numba's cache, and (not in quick
  mode) the very first compilation into an empty cache (these three in :mod:`vpsim.bench_scale`).

Nothing here prints: :func:`format_report` renders the figures, the CLI (``vpsim bench``) prints them. Times
are wall-clock ``time.perf_counter`` with the garbage collector paused, as :mod:`timeit` does. Memory is
measured after all timings (tracemalloc leaves the process slower for a while).
"""

from __future__ import annotations

import gc
import json
import math
import os
import platform
import re
import statistics
import subprocess
import sys
import time
import tracemalloc
import warnings
from dataclasses import asdict, dataclass, replace

import numpy as np

from .units import LITRES_PER_GALLON as LITRES_PER_GAL

PEER = "fastsim"
PEER_VERSION = "3.1.0"
PEER_VEHICLE = "2012_Ford_Fusion.yaml"
PEER_CYCLES = {"udds": "udds.csv", "hwfet": "hwfet.csv"}
GASOLINE_KWH_PER_GAL = 33.7  # EPA's energy content of gasoline, to turn FASTSim's fuel energy into litres

# target figures of the performance issues (ratios > 1: vpsim faster; inverse_vs_backward: a time ratio);
# "kernels ready in seconds": backward 100x FASTSim, batch backward 100,000 runs/s, forward 5x and batch
# forward 1,700 runs/s kept, a process with the kernels cached (as after `pip install .`) within 1 s
TARGETS = {
    "backward_vs_fastsim_udds": (">=", 100.0),
    "forward_vs_fastsim_udds": (">=", 5.0),
    "inverse_vs_backward": ("<=", 2.0),
    "batch_backward_runs_per_s": (">=", 100000.0),
    "batch_forward_runs_per_s": (">=", 1700.0),
    "linearity_max_dev": ("<=", 0.10),
    "cold_start_s": ("<=", 1.0),
    # the forward method's accepted steps per second of UDDS (driver 1; issue target <= 2), in both modes:
    # the paper's stiff driveline, and the realistic mode's clutch, brakes and idle (what simulate runs)
    "forward_udds_steps_per_cycle_s_paper": ("<=", 2.0),
    "forward_udds_steps_per_cycle_s_realistic": ("<=", 2.0),
    # the battery-electric car (the bev preset) against FASTSim 3.1's BEV on the same car, UDDS
    "bev_backward_vs_fastsim_udds": (">=", 100.0),
    "bev_forward_vs_fastsim_udds": (">=", 5.0),
    # the P2 hybrid (hev_p2, ECMS, backward) against FASTSim 3.1's hybrid resource on UDDS
    "hev_ecms_backward_vs_fastsim_udds": (">=", 50.0),
    "hev_ecms_forward_vs_fastsim_udds": (">=", 5.0),
}
# FASTSim 3.1's hybrid: its Sonata Hybrid resource. Not the car of the hev_p2 preset (after the Ioniq Hybrid):
# the same class and layout (a parallel P2 hybrid with a stepped gearbox), so the ratio compares what each
# tool spends on one UDDS run of such a car, not the same car's figures.
PEER_HEV_VEHICLE = "2021_Hyundai_Sonata_Hybrid_Blue_thrml.yaml"


@dataclass(frozen=True)
class Settings:
    """How much to measure; :data:`PROFILES` holds the full, quick and tiny (test) profiles."""

    cycles: tuple[str, ...]
    methods: tuple[tuple[str, str | None], ...]  # (method, driver)
    min_time_s: float  # time spent repeating one row at least ...
    min_repeats: int  # ... and at least this many runs
    max_repeats: int
    batch_backward_variants: int
    batch_forward_variants: int
    batch_repeats: int
    linearity_methods: tuple[tuple[str, str | None], ...]
    linearity_repeats: tuple[int, ...]
    cold_start_runs: int
    first_compile: bool
    peer_cycles: tuple[str, ...] = ("udds", "hwfet")
    pairs: int = 21  # adjacent block pairs behind each ratio (see _paired)
    peer_warm_up_s: float = 1.5  # untimed FASTSim walks before its timing
    peer_processes: int = 3  # fresh processes timing FASTSim alone


_ALL_METHODS = (("backward", None), ("forward", "1"), ("forward", "2"), ("inverse", "1"), ("inverse", "2"))
_LIN_METHODS = (("backward", None), ("forward", "1"), ("inverse", "1"))
PROFILES = {
    "full": Settings(
        cycles=("udds", "nedc", "ftp75", "hwfet"),
        methods=_ALL_METHODS,
        min_time_s=1.0,
        min_repeats=5,
        max_repeats=5000,
        batch_backward_variants=20000,
        batch_forward_variants=400,
        batch_repeats=5,
        linearity_methods=_LIN_METHODS,
        linearity_repeats=(1, 4, 16),
        cold_start_runs=5,
        first_compile=True,
        pairs=31,
    ),
    "quick": Settings(
        cycles=("udds", "nedc", "ftp75"),
        methods=_ALL_METHODS,
        min_time_s=0.15,
        min_repeats=3,
        max_repeats=1000,
        batch_backward_variants=20000,
        batch_forward_variants=200,
        batch_repeats=3,
        linearity_methods=_LIN_METHODS,
        linearity_repeats=(1, 4, 16),
        cold_start_runs=2,
        first_compile=False,
        pairs=9,
        peer_warm_up_s=1.0,
        peer_processes=1,
    ),
    "tiny": Settings(
        cycles=("udds",),
        methods=(("backward", None),),
        min_time_s=0.01,
        min_repeats=2,
        max_repeats=50,
        batch_backward_variants=200,
        batch_forward_variants=0,
        batch_repeats=1,
        linearity_methods=(("backward", None),),
        linearity_repeats=(1, 4),
        cold_start_runs=0,
        first_compile=False,
        peer_cycles=("udds",),
        pairs=2,
        peer_warm_up_s=0.02,
        peer_processes=0,
    ),
}


# --- measuring ----------------------------------------------------------------------------------------------


def _timed(fn, settings: Settings, setup=None) -> tuple[float, int]:
    """(median seconds, runs) of ``fn()`` after one warm-up call, the garbage collector paused.

    With ``setup``, each run times ``fn(setup())`` and ``setup()`` itself stays outside the timed region.
    """
    call = (lambda: fn(setup())) if setup is not None else fn
    call()
    times: list[float] = []
    enabled = gc.isenabled()
    gc.disable()
    try:
        start = time.perf_counter()
        while len(times) < settings.max_repeats and (
            len(times) < settings.min_repeats or time.perf_counter() - start < settings.min_time_s
        ):
            arg = setup() if setup is not None else None
            t0 = time.perf_counter()
            if setup is not None:
                fn(arg)
            else:
                fn()
            times.append(time.perf_counter() - t0)
            del arg
    finally:
        if enabled:
            gc.enable()
    return statistics.median(times), len(times)


def _proc_status(key: str) -> int | None:
    try:
        with open("/proc/self/status") as fh:
            m = re.search(rf"^{key}:\s+(\d+) kB", fh.read(), re.M)
    except OSError:
        return None
    return int(m.group(1)) if m else None


def _malloc_trim() -> None:
    """Give the C heap's free memory back to the system (glibc): a later peak-RSS rise is new memory."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _memory(fn) -> tuple[float, float | None]:
    """(tracemalloc peak KiB, rise of the peak resident set KiB or None) of one call of ``fn``.

    tracemalloc sees Python's and NumPy's allocations; the resident-set rise (Linux: VmHWM after resetting
    it through /proc/self/clear_refs, with the C heap trimmed first) also sees native ones (FASTSim's Rust
    heap, Numba's), to page granularity.
    """
    gc.collect()
    _malloc_trim()
    rss_kib = None
    try:  # Linux: writing 5 to clear_refs resets the peak RSS (VmHWM) to the current RSS
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        before = _proc_status("VmRSS")
        fn()
        after = _proc_status("VmHWM")
        if before is not None and after is not None:
            rss_kib = float(max(after - before, 0))
    except OSError:
        pass
    gc.collect()
    tracemalloc.start()
    try:
        fn()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak / 1024.0, rss_kib


def _row(tool, method, driver, cycle, median_s, runs, steps, py_kib, rss_kib, fuel, **extra) -> dict:
    return {
        "tool": tool,
        "method": method,
        "driver": driver,
        "cycle": cycle,
        "median_ms": median_s * 1e3,
        "runs": runs,
        "steps": steps,
        "py_peak_kib": py_kib,
        "rss_peak_kib": rss_kib,
        "fuel_l_per_100km": fuel,
        **extra,
    }


def _loadavg() -> float | None:
    """The 1-minute load average (other processes competing for the cores show up here), or None."""
    try:
        return os.getloadavg()[0]
    except (OSError, AttributeError):
        return None


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}"[:200]


# --- vpsim --------------------------------------------------------------------------------------------------


def _forward_steps(settings: Settings) -> dict:
    """Accepted steps of the forward method (driver 1) per second of UDDS, paper and realistic mode: counts,
    not timings (one untimed run each); {} when the profile runs no forward method on UDDS."""
    if ("forward", "1") not in settings.methods or "udds" not in settings.cycles:
        return {}
    from .cycles import load_cycle
    from .simulation import simulate

    cyc = load_cycle("udds")
    duration = float(cyc.time_s[-1] - cyc.time_s[0])
    out = {}
    for mode in ("paper", "realistic"):
        r = simulate(cyc, "forward", "hofman2011", driver="1", mode=mode, keep_series=False)
        out[mode] = {"accepted_steps": int(r.steps), "per_cycle_s": r.steps / duration}
    return out


def _vpsim_rows(settings: Settings, progress) -> tuple[list[dict], dict, list[dict], dict]:
    from .cycles import load_cycle
    from .gears import default_schedule
    from .model.maps import cached_engine_map, generate_engine_map
    from .params import load_parameters
    from .simulation import simulate

    params = load_parameters("hofman2011")
    t0 = time.perf_counter()
    em = generate_engine_map(params.engine)
    setup = {"engine_map_ms": (time.perf_counter() - t0) * 1e3, "gear_schedule_ms": {}}
    cached_engine_map(params.engine)
    rows, failures, calls = [], [], {}
    for name in settings.cycles:
        cyc = load_cycle(name)
        t0 = time.perf_counter()
        schedule = default_schedule(cyc, params, em)
        setup["gear_schedule_ms"][name] = (time.perf_counter() - t0) * 1e3
        for method, driver in settings.methods:
            progress(f"vpsim {method}{'' if driver is None else ' driver ' + driver} on {name}")

            def fn(method=method, driver=driver, cyc=cyc, schedule=schedule):
                return simulate(cyc, method, params, driver=driver, gears=schedule)

            try:
                res = fn()
                med, runs = _timed(fn, settings)
                py_kib, rss_kib = None, None  # measured at the end (see _measure_memory)
            except Exception as exc:  # a method that fails is reported, not fatal to the benchmark
                failures.append({"method": method, "driver": driver, "cycle": name, "error": _one_line(exc)})
                continue
            calls[(method, driver, name)] = fn
            rows.append(
                _row(
                    "vpsim",
                    method,
                    driver,
                    name,
                    med,
                    runs,
                    int(res.steps),
                    py_kib,
                    rss_kib,
                    float(res.fuel_l_per_100km),
                )
            )
    return rows, setup, failures, calls


# --- the peer: FASTSim 3.1 ------------------------------------------------------------------------------


def peer_status() -> dict:
    """Whether FASTSim 3.1.0 can be imported here: {"name", "version", "available", "reason"}."""
    status = {"name": PEER, "version": None, "available": False, "reason": ""}
    try:
        import fastsim  # noqa: F401
    except Exception as exc:  # ImportError, or a broken install
        status["reason"] = (
            f"not installed ({_one_line(exc)}); pip install 'vpsim[bench]' (fastsim=={PEER_VERSION})"
        )
        return status
    version = getattr(fastsim, "__version__", None)
    status["version"] = version
    if version != PEER_VERSION:
        status["reason"] = f"fastsim {version} installed; the benchmark compares against {PEER_VERSION}"
        return status
    status["available"] = True
    return status


def _peer_rows(settings: Settings, progress) -> tuple[list[dict], dict, dict]:
    import fastsim as fsim

    setup: dict = {}
    t0 = time.perf_counter()
    veh = fsim.Vehicle.from_resource(PEER_VEHICLE)
    setup["vehicle_from_resource_ms"] = (time.perf_counter() - t0) * 1e3
    setup["simdrive_new_ms"] = {}
    rows, makers = [], {}
    for name in settings.peer_cycles:
        progress(f"{PEER} {PEER_VERSION} conventional {PEER_VEHICLE} on {name}")
        cyc = fsim.Cycle.from_resource(PEER_CYCLES[name])

        def make(veh=veh, cyc=cyc):
            return fsim.SimDrive(veh, cyc)

        makers[name] = make
        new_s, _ = _timed(make, settings)
        setup["simdrive_new_ms"][name] = new_s * 1e3
        # walk() only: each run walks a fresh SimDrive built outside the timed region. In a fresh process
        # FASTSim's walks take ~1.7x longer for the first second or so (measured here: 12 ms, then 7 ms on
        # UDDS); it gets that second untimed, so its settled speed is what is compared.
        t_warm = time.perf_counter()
        while time.perf_counter() - t_warm < settings.peer_warm_up_s:
            _walk(make())
        med, runs = _timed(_walk, settings, setup=make)
        py_kib, rss_kib = None, None
        sd = make()
        _walk(sd)
        d = sd.to_dict()
        fuel_j = d["veh"]["pt_type"]["Conv"]["fc"]["state"]["energy_fuel_joules"]
        dist_m = d["veh"]["state"]["dist_meters"]
        litres = fuel_j / (GASOLINE_KWH_PER_GAL * 3.6e6) * LITRES_PER_GAL
        rows.append(
            _row(
                f"{PEER} {PEER_VERSION}",
                "conventional walk()",
                None,
                name,
                med,
                runs,
                cyc.len() - 1,
                py_kib,
                rss_kib,
                litres / (dist_m / 1e5),
                vehicle=PEER_VEHICLE,
            )
        )
    return rows, setup, makers


_PEER_CODE = """
import json, statistics, time, warnings
warnings.simplefilter("ignore", DeprecationWarning)
import fastsim as fsim
veh = fsim.Vehicle.from_resource({vehicle!r})
cyc = fsim.Cycle.from_resource({cycle!r})
t0 = time.perf_counter()
while time.perf_counter() - t0 < {warm!r}:
    fsim.SimDrive(veh, cyc).walk()
ts = []
t0 = time.perf_counter()
while len(ts) < 5 or time.perf_counter() - t0 < {measure!r}:
    sd = fsim.SimDrive(veh, cyc)
    t = time.perf_counter()
    sd.walk()
    ts.append(time.perf_counter() - t)
print(json.dumps({{"median_ms": statistics.median(ts) * 1e3, "runs": len(ts)}}))
"""


def _peer_fresh(settings: Settings, progress) -> dict:
    """FASTSim's walk() in fresh processes of its own (nothing of vpsim loaded), after its warm-up.

    Its settled speed varies between processes on this kind of machine (7 ms or 10-12 ms on UDDS); the
    fastest process is the one compared with, which can only understate vpsim's advantage.
    """
    out: dict = {}
    for name in settings.peer_cycles:
        code = _PEER_CODE.format(
            vehicle=PEER_VEHICLE,
            cycle=PEER_CYCLES[name],
            warm=settings.peer_warm_up_s,
            measure=settings.min_time_s,
        )
        entry = _in_fresh_processes(code, settings.peer_processes, f"{PEER} on {name}", progress)
        if entry:
            out[name] = entry
    return out


def _in_fresh_processes(code: str, n: int, label: str, progress) -> dict:
    """Run ``code`` (it prints one JSON object with ``median_ms``) in ``n`` fresh processes: its medians,
    the best of them and the last process's other figures; {"error": ...} if one fails; {} for n = 0."""
    meds: list[float] = []
    last: dict = {}
    for _ in range(n):
        progress(f"{label} in a fresh process")
        try:
            _, last = _subprocess(code)
        except Exception as exc:
            return {"error": _one_line(exc)}
        meds.append(last.pop("median_ms"))
        last.pop("runs", None)
    return {"median_ms_per_process": meds, "best_ms": min(meds), **last} if meds else {}


# the vpsim runs held against the targets, timed in fresh processes too (the rule FASTSim gets)
_FRESH_SIDES = (("forward", "1"), ("backward", None), ("inverse", "1"))


def _vpsim_fresh_child(method: str, driver: str | None, cycle: str, warm_s: float, timing: dict) -> None:
    """In a fresh process: one vpsim row as :func:`_vpsim_rows` times it (``timing``: the profile's
    min_time_s, min_repeats, max_repeats), after ``warm_s`` of untimed runs (FASTSim's warm-up in its own
    processes); prints {"median_ms", "runs", "steps", "fuel_kg"}."""
    from .cycles import load_cycle
    from .gears import default_schedule
    from .model.maps import cached_engine_map
    from .params import load_parameters
    from .simulation import simulate

    settings = replace(PROFILES["tiny"], **timing)
    params = load_parameters("hofman2011")
    cyc = load_cycle(cycle)
    schedule = default_schedule(cyc, params, cached_engine_map(params.engine))

    def fn():
        return simulate(cyc, method, params, driver=driver, gears=schedule)

    t0 = time.perf_counter()
    res = fn()
    while time.perf_counter() - t0 < warm_s:
        fn()
    med, runs = _timed(fn, settings)
    out = {"median_ms": med * 1e3, "runs": runs, "steps": int(res.steps), "fuel_kg": float(res.fuel_kg)}
    print(json.dumps(out))


def _vpsim_fresh(settings: Settings, progress) -> dict:
    """The runs of :data:`_FRESH_SIDES` in fresh processes of their own (nothing of FASTSim loaded), as many
    as FASTSim gets (``peer_processes``): {"method/driver/cycle": {"median_ms_per_process", "best_ms"}}."""
    out: dict = {}
    timing = {k: getattr(settings, k) for k in ("min_time_s", "min_repeats", "max_repeats")}
    for cycle in settings.peer_cycles:
        if cycle not in settings.cycles:
            continue
        for method, driver in _FRESH_SIDES:
            if (method, driver) not in settings.methods:
                continue
            code = (
                "from vpsim.bench import _vpsim_fresh_child; "
                f"_vpsim_fresh_child({method!r}, {driver!r}, {cycle!r}, {settings.peer_warm_up_s!r}, "
                f"{timing!r})"
            )
            label = method if driver is None else f"{method} driver {driver}"
            entry = _in_fresh_processes(code, settings.peer_processes, f"vpsim {label} on {cycle}", progress)
            if entry:
                out[f"{method}/{driver or '-'}/{cycle}"] = entry
    return out


def _measure_memory(rows: list[dict], calls: dict, makers: dict) -> None:
    """Fill the rows' peak-memory figures, after every timing: tracemalloc and trimming the C heap leave the
    process in a state that slows later runs (FASTSim's walk by up to 1.5x), so they come last."""
    for r in rows:
        if r["tool"] == "vpsim":
            fn = calls.get((r["method"], r["driver"], r["cycle"]))
        else:
            make = makers.get(r["cycle"])
            fn = None if make is None else (lambda make=make: _walk(make()))
        if fn is not None:
            r["py_peak_kib"], r["rss_peak_kib"] = _memory(fn)


def _walk(sd) -> None:
    """FASTSim 3.1's ``SimDrive.walk()`` (a deprecated alias of ``run()`` that warns on every call)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        sd.walk()


def _block(call, setup, n: int) -> float:
    """Median seconds of ``n`` timed runs after one untimed warm run (warm caches), ``setup`` untimed."""
    call(setup()) if setup is not None else call()
    ts = []
    for _ in range(n):
        arg = setup() if setup is not None else None
        t0 = time.perf_counter()
        call(arg) if setup is not None else call()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def _paired(a, b, pairs: int, setup_a=None, block_s: float = 0.03) -> dict:
    """Ratio t_a / t_b from ``pairs`` adjacent blocks of runs of ``a`` and of ``b`` (order swapped each pair).

    On a shared machine the load changes over seconds; blocks a few tens of ms long, side by side, see the
    same load, so the median of the per-pair ratios is steadier than a ratio of medians taken minutes apart.
    Within a block the caches are warm (one untimed run first), as for a user running one tool many times;
    alternating single runs instead would time each run of the faster tool with caches emptied by the other.
    """
    t_a = _block(a, setup_a, 1)
    t_b = _block(b, None, 1)
    n_a = max(3, min(1000, math.ceil(block_s / max(t_a, 1e-7))))
    n_b = max(3, min(1000, math.ceil(block_s / max(t_b, 1e-7))))
    ta, tb = [], []
    enabled = gc.isenabled()
    gc.disable()
    try:
        for k in range(pairs):
            for which in (0, 1) if k % 2 == 0 else (1, 0):
                if which == 0:
                    ta.append(_block(a, setup_a, n_a))
                else:
                    tb.append(_block(b, None, n_b))
    finally:
        if enabled:
            gc.enable()
    ratios = [x / y for x, y in zip(ta, tb, strict=True)]
    return {
        "ratio": statistics.median(ratios),
        "a_median_ms": statistics.median(ta) * 1e3,
        "b_median_ms": statistics.median(tb) * 1e3,
        "pairs": pairs,
        "runs_per_block": [n_a, n_b],
    }


def _subprocess(code: str, env: dict | None = None) -> tuple[float, dict]:
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=900)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        lines = (proc.stderr.strip() or proc.stdout.strip() or "no output").splitlines()
        raise RuntimeError(lines[-1])
    return wall, json.loads(proc.stdout.strip().splitlines()[-1])


# --- the report ---------------------------------------------------------------------------------------------


def _find(rows, tool_prefix, method, driver, cycle):
    for r in rows:
        if (
            r["tool"].startswith(tool_prefix)
            and r["method"] == method
            and r["driver"] == driver
            and r["cycle"] == cycle
        ):
            return r
    return None


def _ratios(settings: Settings, calls: dict, makers: dict, progress) -> tuple[dict, dict]:
    """The issue's ratios, each from interleaved runs of its two sides (:func:`_paired`)."""
    plan = {
        "backward_vs_fastsim_udds": (("peer", "udds"), ("backward", None, "udds")),
        "forward_vs_fastsim_udds": (("peer", "udds"), ("forward", "1", "udds")),
        "inverse_vs_backward": (("inverse", "1", "udds"), ("backward", None, "udds")),
        "backward_vs_fastsim_hwfet": (("peer", "hwfet"), ("backward", None, "hwfet")),
        "forward_vs_fastsim_hwfet": (("peer", "hwfet"), ("forward", "1", "hwfet")),
    }
    ratios: dict = {}
    paired: dict = {}
    for key, (num, den) in plan.items():
        if num[0] == "peer":
            a, setup_a = _walk, makers.get(num[1])
            ok = setup_a is not None
        else:
            a, setup_a = calls.get(num), None
            ok = a is not None
        b = calls.get(den)
        if not ok or b is None:
            if not key.endswith("hwfet"):
                ratios[key] = None
            continue
        progress(f"ratio {key}: {settings.pairs} interleaved pairs")
        res = _paired(a, b, settings.pairs, setup_a=setup_a)
        paired[key] = res
        ratios[key] = res["ratio"]
    return ratios, paired


def _ratio(num, den) -> float | None:
    if num is None or den is None or not den["median_ms"]:
        return None
    return num["median_ms"] / den["median_ms"]


def run_benchmarks(profile: str = "full", *, peer: bool = True, progress=None) -> dict:
    """Measure everything (see the module docstring) and return one JSON-ready dict.

    ``profile``: ``"full"``, ``"quick"`` (under a minute) or ``"tiny"`` (seconds; for tests). ``peer=False``
    skips FASTSim (reported as not measured). ``progress``: a callable taking one line of text, or None.
    """
    if profile not in PROFILES:
        raise ValueError(f"profile must be one of {', '.join(PROFILES)}, got {profile!r}")
    settings = PROFILES[profile]
    progress = progress or (lambda line: None)
    from . import bench_powertrains
    from .bench_scale import _batch, _cold_start, _linearity

    started = time.perf_counter()
    load_start = _loadavg()
    import numba

    # The peer first: once vpsim's compiled code has run in this process, FASTSim's walks take ~20 % longer
    # (measured on this kind of machine); timed first, FASTSim is at its fastest, which only makes the
    # comparison harder for vpsim.
    status = (
        peer_status()
        if peer
        else {"name": PEER, "version": None, "available": False, "reason": "skipped (--no-peer)"}
    )
    peer_rows: list[dict] = []
    peer_setup: dict = {}
    makers: dict = {}
    if status["available"]:
        try:
            peer_rows, peer_setup, makers = _peer_rows(settings, progress)
        except Exception as exc:
            status = {**status, "available": False, "reason": f"failed: {_one_line(exc)}"}
    peer_fresh = _peer_fresh(settings, progress) if status["available"] else {}
    bev_peer: dict = {}
    if status["available"]:
        try:
            bev_peer = bench_powertrains.bev_peer_ms(settings, progress)
        except Exception as exc:
            bev_peer = {"failed": _one_line(exc)}
    hev_peer: dict = {}
    if status["available"]:
        try:
            hev_peer = bench_powertrains.hev_peer_ms(settings, progress)
        except Exception as exc:
            hev_peer = {"failed": _one_line(exc)}
    for r in peer_rows:  # the peer's figure: its fastest settled speed, in this process or a fresh one
        best = peer_fresh.get(r["cycle"], {}).get("best_ms")
        r["in_process_median_ms"] = r["median_ms"]
        if best is not None and best < r["median_ms"]:
            r["median_ms"] = best
            r["runs"] = -1  # marks the figure as coming from the fresh processes
    rows, setup, failures, calls = _vpsim_rows(settings, progress)
    bev = bench_powertrains.bev_rows(settings, progress)
    hev = bench_powertrains.hev_rows(settings, progress)
    electric_paired: dict = {}
    if status["available"] and "failed" not in bev_peer and "failed" not in hev_peer:
        try:
            electric_paired = bench_powertrains.paired_rows(settings, progress)
        except Exception as exc:  # reported, not fatal: the rows' own figures stand
            electric_paired = {"failed": _one_line(exc)}
    vpsim_fresh = _vpsim_fresh(settings, progress) if status["available"] else {}
    rows += peer_rows
    paired_ratios, paired = _ratios(settings, calls, makers, progress)
    batch = _batch(settings, progress)
    linearity = _linearity(settings, progress)
    available = {r["method"] for r in rows if r["tool"] == "vpsim"}
    if batch.get("batch_forward", {}).get("runs_per_s"):
        available.add("forward_batch")
    progress("peak memory of one run of each row")
    _measure_memory(rows, calls, makers)
    cold = _cold_start(settings, available, progress)

    # the same ratios from the table's medians (taken one after the other, so more exposed to load changes)
    back = {c: _find(rows, "vpsim", "backward", None, c) for c in settings.cycles}
    extra_ratios = {}
    for c in settings.peer_cycles:
        fs = _find(rows, PEER, "conventional walk()", None, c)
        extra_ratios[f"backward_vs_fastsim_{c}"] = _ratio(fs, back.get(c))
        for d in ("1", "2"):
            extra_ratios[f"forward_driver{d}_vs_fastsim_{c}"] = _ratio(
                fs, _find(rows, "vpsim", "forward", d, c)
            )
    for c in settings.cycles:
        for d in ("1", "2"):
            extra_ratios[f"inverse_driver{d}_vs_backward_{c}"] = _ratio(
                _find(rows, "vpsim", "inverse", d, c), back.get(c)
            )
    # Against the targets: each side at its best settled speed, the same rule for both tools: the fastest of
    # its row in this process, its fresh processes of its own (each tool runs slower once the other's code
    # has run in the process) and its blocks in the paired measurement. (A neighbour's load only ever slows
    # a measurement down.)
    sides = {
        "backward_vs_fastsim_udds": ("udds", ("backward", None, "udds")),
        "forward_vs_fastsim_udds": ("udds", ("forward", "1", "udds")),
        "backward_vs_fastsim_hwfet": ("hwfet", ("backward", None, "hwfet")),
        "forward_vs_fastsim_hwfet": ("hwfet", ("forward", "1", "hwfet")),
        "inverse_vs_backward": (("inverse", "1", "udds"), ("backward", None, "udds")),
    }

    def best_ms(side, paired_ms):
        fresh = None
        if isinstance(side, str):
            row = _find(rows, PEER, "conventional walk()", None, side)  # its fresh processes are in the row
        else:
            row = _find(rows, "vpsim", *side)
            method, driver, cycle = side
            fresh = vpsim_fresh.get(f"{method}/{driver or '-'}/{cycle}", {}).get("best_ms")
        values = [v for v in (None if row is None else row["median_ms"], paired_ms, fresh) if v is not None]
        return min(values) if values else None

    ratios = {}
    for key, (num, den) in sides.items():
        res = paired.get(key, {})
        a_ms = best_ms(num, res.get("a_median_ms"))
        b_ms = best_ms(den, res.get("b_median_ms"))
        if a_ms is None or b_ms is None:
            if not key.endswith("hwfet"):
                ratios[key] = None
            continue
        ratios[key] = a_ms / b_ms
        if res:
            res["best_ms"] = [a_ms, b_ms]
    # the electric cars: the same rule, each side at the fastest of its row and its paired blocks
    ratios.update(bench_powertrains.electric_ratios(bev_peer, hev_peer, bev, hev, electric_paired))
    steps = _forward_steps(settings)
    lin_devs = [v["max_dev"] for v in linearity.values() if "max_dev" in v]
    cold_walls = [
        v["wall_s"] for k, v in cold.items() if isinstance(v, dict) and "wall_s" in v and k != "first_compile"
    ]
    report = {
        "profile": profile,
        "machine": {
            "cores": os.cpu_count(),
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "numba": numba.__version__,
            "numba_threads": numba.config.NUMBA_NUM_THREADS,
            "load_average_start_end": [load_start, _loadavg()],
        },
        "settings": asdict(settings),
        "peer": status,
        "rows": rows,
        "failures": failures,
        "setup": {"vpsim": setup, PEER: peer_setup},
        "peer_fresh_processes": peer_fresh,
        "vpsim_fresh_processes": vpsim_fresh,
        "ratios": ratios,
        "ratios_paired": {
            **paired,
            **{f"{k}_vs_fastsim_udds": v for k, v in electric_paired.items() if isinstance(v, dict)},
        },
        "electric_paired_failed": electric_paired.get("failed"),
        "ratios_from_table": extra_ratios,
        "batch": batch,
        "batch_backward_runs_per_s": batch.get("batch_backward", {}).get("runs_per_s"),
        "batch_backward_realistic_runs_per_s": batch.get("batch_backward_realistic", {}).get("runs_per_s"),
        "batch_forward_runs_per_s": batch.get("batch_forward", {}).get("runs_per_s"),
        "linearity": linearity,
        "linearity_max_dev": max(lin_devs) if lin_devs else None,
        "cold_start": cold,
        "cold_start_s": max(cold_walls) if cold_walls else None,
        "first_compile_s": cold.get("first_compile", {}).get("wall_s"),
        "forward_udds_steps": steps,
        "bev": {"vpsim": bev, PEER: bev_peer},
        "hev": {"vpsim": hev, PEER: hev_peer},
    }
    for mode, v in steps.items():
        report[f"forward_udds_steps_per_cycle_s_{mode}"] = v["per_cycle_s"]
    report["targets"] = _targets(report)
    report["elapsed_s"] = time.perf_counter() - started
    return report


def _targets(report: dict) -> list[dict]:
    values = {**report["ratios"], **{k: report.get(k) for k in TARGETS if k not in report["ratios"]}}
    out = []
    for key, (op, target) in TARGETS.items():
        v = values.get(key)
        met = None
        if v is not None and not (isinstance(v, float) and math.isnan(v)):
            met = {">=": v >= target, "<=": v <= target, "<": v < target}[op]
        out.append({"figure": key, "target": f"{op} {target:g}", "measured": v, "met": met})
    return out


# --- text ---------------------------------------------------------------------------------------------------


def format_report(report: dict) -> str:
    """The benchmark as text (:func:`vpsim.bench_text.format_report`)."""
    from .bench_text import format_report as render

    return render(report)
