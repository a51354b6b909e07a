"""``vpsim bench``'s batch throughput, linearity and cold-start figures (:mod:`vpsim.bench`): many design
variants in one compiled call (on the threads and on one), FTP-75 repeated, and fresh processes with the
kernels cached and (in the full profile) into an empty cache."""

from __future__ import annotations

import gc
import math
import os
import statistics
import tempfile
import time
from functools import partial

import numpy as np

from .bench import Settings, _block, _one_line, _subprocess


def batch_variants(n: int, seed: int = 0):
    """A reproducible sweep of ``n`` designs around the base vehicle (bore, stroke, final drive, mass)."""
    import pandas as pd

    rng = np.random.default_rng(seed)
    return pd.DataFrame(
        {
            "engine.bore": rng.uniform(0.085, 0.095, n),
            "engine.stroke": rng.uniform(0.085, 0.095, n),
            "transmission.final_drive": rng.uniform(4.0, 4.9, n),
            "vehicle.mass": rng.uniform(1500.0, 1800.0, n),
        }
    )


def _threads() -> int:
    import numba

    return int(numba.get_num_threads())


def _one_thread_runs_per_s(fn, n: int, settings: Settings) -> float | None:
    """Runs per second of the batch ``fn`` (``n`` variants) with Numba's parallel loops on one thread (the
    median of ``settings.batch_repeats`` runs); None where the process has one thread anyway."""
    import numba

    threads = numba.get_num_threads()
    if threads <= 1:
        return None
    times = []
    numba.set_num_threads(1)
    try:
        for _ in range(settings.batch_repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
    finally:
        numba.set_num_threads(threads)
    return n / statistics.median(times)


def _batch(settings: Settings, progress) -> dict:
    from .batch import run_batch
    from .cycles import load_cycle

    cyc = load_cycle("udds")
    out: dict = {}
    for method, n, mode in (
        ("backward", settings.batch_backward_variants, "paper"),
        ("backward", settings.batch_backward_variants, "realistic"),
        ("forward", settings.batch_forward_variants, "paper"),
    ):
        key = f"batch_{method}" if mode == "paper" else f"batch_{method}_{mode}"
        if n <= 0:
            out[key] = {"variants": 0, "runs_per_s": None, "error": "not measured in this profile"}
            continue
        progress(f"batch {method} ({mode} mode): {n} variants on udds")
        variants = batch_variants(n)
        try:
            run_batch(cyc, variants.iloc[: min(n, 8)], method=method, mode=mode)  # load / compile
            times = []
            for _ in range(settings.batch_repeats):
                t0 = time.perf_counter()
                df = run_batch(cyc, variants, method=method, mode=mode)
                times.append(time.perf_counter() - t0)
        except Exception as exc:
            out[key] = {"variants": n, "runs_per_s": None, "error": _one_line(exc)}
            continue
        med = statistics.median(times)
        one = _one_thread_runs_per_s(partial(run_batch, cyc, variants, method=method, mode=mode), n, settings)
        out[key] = {
            "variants": n,
            "cycle": "udds",
            "mode": mode,
            "median_s": med,
            "runs_per_s": n / med,
            # the same batch on one thread: the kernel's own speed, apart from how much of the second core
            # the machine gives (on a shared virtual machine the 2-thread figure moved 1.55-1.98x this one)
            "one_thread_runs_per_s": one,
            "threads": _threads(),
            "trace_miss_share": float(np.mean(df["trace_miss_s"] > 0)),
            "fuel_l_per_100km_range": [
                float(df["fuel_l_per_100km"].min()),
                float(df["fuel_l_per_100km"].max()),
            ],
        }
    return out


def _linearity(settings: Settings, progress) -> dict:
    from .cycles import load_cycle
    from .gears import default_schedule
    from .model.maps import cached_engine_map
    from .params import load_parameters
    from .simulation import simulate

    params = load_parameters("hofman2011")
    em = cached_engine_map(params.engine)
    base = load_cycle("ftp75")
    out: dict = {}
    for method, driver in settings.linearity_methods:
        label = method if driver is None else f"{method} driver {driver}"
        progress(f"linearity {label}: ftp75 x {', '.join(map(str, settings.linearity_repeats))}")
        reps = settings.linearity_repeats
        fns = {}
        try:
            for n in reps:
                cyc = base.repeat(n)
                schedule = default_schedule(cyc, params, em)

                def fn(cyc=cyc, schedule=schedule, method=method, driver=driver):
                    return simulate(cyc, method, params, driver=driver, gears=schedule)

                fns[n] = (fn, max(3, min(1000, math.ceil(0.03 / max(_block(fn, None, 1), 1e-7)))))
            # rounds of one block per size, side by side (as for the ratios): the load of the other
            # processes on a shared machine then weighs on every size alike
            blocks: dict[int, list[float]] = {n: [] for n in reps}
            enabled = gc.isenabled()
            gc.disable()
            try:
                for _ in range(settings.pairs):
                    for n in reps:
                        blocks[n].append(_block(fns[n][0], None, fns[n][1]))
            finally:
                if enabled:
                    gc.enable()
        except Exception as exc:
            out[label] = {"error": _one_line(exc)}
            continue
        n0 = reps[0]
        per_rep = {
            str(n): statistics.median(t / n / (t0 / n0) for t, t0 in zip(blocks[n], blocks[n0], strict=True))
            for n in reps
        }
        times = {n: statistics.median(blocks[n]) for n in reps}
        marginal = None
        if len(reps) >= 3:  # cost of one more repetition, large against small: 1 for affine growth
            (a, b, c) = reps[-3:]
            marginal = ((times[c] - times[b]) / (c - b)) / ((times[b] - times[a]) / (b - a))
        out[label] = {
            "ms": {str(n): times[n] * 1e3 for n in reps},
            "per_repetition_vs_1x": per_rep,
            "max_dev": max(abs(r - 1.0) for r in per_rep.values()),
            "marginal_ratio": marginal,
            "rounds": settings.pairs,
        }
    return out


_COLD_CODE = """
import json, time
t0 = time.perf_counter()
import vpsim
from vpsim.simulation import simulate
t1 = time.perf_counter()
for method in {methods!r}:
    r = simulate("udds", method=method)
t2 = time.perf_counter()
extra = {{}}
if {batch!r}:
    from vpsim.batch import run_batch
    run_batch("udds", {{"vehicle.mass": [1500.0, 1600.0]}})
    if {forward_batch!r}:
        run_batch("udds", {{"vehicle.mass": [1500.0, 1600.0]}}, method="forward")
    extra["batch_s"] = time.perf_counter() - t2
print(json.dumps({{"import_s": t1 - t0, "first_run_s": t2 - t1, **extra}}))
"""


def cache_locations() -> dict:
    """Where Numba keeps the compiled kernels of vpsim (from the dispatchers' cache objects)."""
    from .methods import backward

    out = {"NUMBA_CACHE_DIR": os.environ.get("NUMBA_CACHE_DIR")}
    try:
        out["vpsim.methods.backward"] = backward.run_kernel._cache._cache_path
    except AttributeError:
        out["vpsim.methods.backward"] = None
    try:
        from .methods import forward

        out["vpsim.methods.forward"] = forward._integrate._cache._cache_path
    except Exception:
        out["vpsim.methods.forward"] = None
    return out


def _cold_start(settings: Settings, available: set[str], progress) -> dict:
    out: dict = {"cache": cache_locations()}
    if settings.cold_start_runs <= 0:
        return out
    methods = [m for m in ("backward", "forward", "inverse") if m in available]
    for method in methods:
        progress(
            f"cold start: fresh process, import vpsim, {method} on udds ({settings.cold_start_runs} runs)"
        )
        try:
            walls, inner = [], []
            for _ in range(settings.cold_start_runs):
                w, d = _subprocess(_COLD_CODE.format(methods=[method], batch=False, forward_batch=False))
                walls.append(w)
                inner.append(d)
        except Exception as exc:
            out[method] = {"error": _one_line(exc)}
            continue
        k = int(np.argsort(walls)[len(walls) // 2])
        out[method] = {
            "wall_s": statistics.median(walls),
            "import_s": inner[k]["import_s"],
            "first_run_s": inner[k]["first_run_s"],
        }
    if settings.first_compile:
        progress("first compilation: fresh process with an empty NUMBA_CACHE_DIR (compiles every kernel)")
        code = _COLD_CODE.format(methods=methods, batch=True, forward_batch="forward_batch" in available)
        with tempfile.TemporaryDirectory(prefix="vpsim-numba-cache-") as tmp:
            env = {**os.environ, "NUMBA_CACHE_DIR": tmp}
            try:
                wall, inner = _subprocess(code, env)
                wall2, inner2 = _subprocess(code, env)
                out["first_compile"] = {
                    "wall_s": wall,
                    "same_run_cached_wall_s": wall2,
                    "compile_s": wall - wall2,
                    "covers": f"import, {', '.join(methods)} on udds, backward"
                    + (" and forward" if "forward_batch" in available else "")
                    + " batch",
                }
            except Exception as exc:
                out["first_compile"] = {"error": _one_line(exc)}
    return out
