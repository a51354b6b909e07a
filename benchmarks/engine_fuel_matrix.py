"""Fuel, trace miss and every series of the engine cars on six cycles by every method and mode, and batch
variants, to a JSON file, and the differences against another run's file: the check for a change to the
conventional kernels meant to be only faster (the electric and hybrid cars' counterpart:
``electric_fuel_matrix.py``).

    python benchmarks/engine_fuel_matrix.py before.json                  # on the old checkout
    python benchmarks/engine_fuel_matrix.py after.json --against before.json

Cases: the presets hofman2011, geo_metro_1l and saturn_1_9l on NEDC, FTP-75, UDDS, HWFET, US06 and WLTC 3b,
by the backward, inverse (drivers 1 and 2) and forward (driver 1) methods, paper and realistic mode; and
``vpsim.batch.run_batch`` (backward) over 300 seeded variants of hofman2011 (bore, mass, final drive) on
UDDS, US06 and NEDC in both modes. Per run it keeps the fuel (kg), the trace-miss seconds, a SHA-1 of every
series (bit for bit) and each series' sum of |x| (a magnitude for a series that moved). Against another
file it prints the largest relative difference of the fuel and of any figure, and how many runs' series
are not identical to the bit. To run an old checkout: ``PYTHONPATH=OLD/src python ...`` with a
``NUMBA_CACHE_DIR`` of its own.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import time
from pathlib import Path

import numpy as np

from vpsim.batch import run_batch
from vpsim.cycles import load_cycle
from vpsim.simulation import simulate

PRESETS = ("hofman2011", "geo_metro_1l", "saturn_1_9l")
CYCLES = ("nedc", "ftp75", "udds", "hwfet", "us06", "wltc3b")
METHODS = (("backward", None), ("inverse", "1"), ("inverse", "2"), ("forward", "1"))
MODES = ("paper", "realistic")
BATCH_CYCLES = ("udds", "us06", "nedc")
BATCH_VARIANTS = 300


def _series_figures(series: dict) -> tuple[str, dict]:
    digest = hashlib.sha1()
    sums = {}
    for key in sorted(series):
        x = np.ascontiguousarray(np.asarray(series[key]))
        digest.update(key.encode())
        digest.update(x.tobytes())
        if x.dtype.kind == "f":
            sums["sum_abs." + key] = float(np.nansum(np.abs(x)))
    return digest.hexdigest(), sums


def figures() -> dict:
    out = {}
    for preset in PRESETS:
        for cycle in CYCLES:
            cyc = load_cycle(cycle)
            for method, driver in METHODS:
                for mode in MODES:
                    key = f"{preset}/{cycle}/{method}{'' if driver is None else driver}/{mode}"
                    r = simulate(cyc, method, preset, driver=driver, mode=mode)
                    digest, sums = _series_figures(r.series)
                    out[key] = {
                        "fuel_kg": r.fuel_kg,
                        "trace_miss_s": float(r.trace_miss.seconds),
                        "series_sha1": digest,
                        **sums,
                    }
                    print(key, f"fuel {r.fuel_kg:.12g} kg", flush=True)
    rng = np.random.default_rng(1)
    variants = {
        "engine.bore": rng.uniform(0.07, 0.09, BATCH_VARIANTS),
        "vehicle.mass": rng.uniform(900.0, 1600.0, BATCH_VARIANTS),
        "transmission.final_drive": rng.uniform(3.0, 4.5, BATCH_VARIANTS),
    }
    for cycle in BATCH_CYCLES:
        for mode in MODES:
            df = run_batch(cycle, variants, mode=mode)
            for i, (fuel, miss) in enumerate(zip(df["fuel_kg"], df["trace_miss_s"], strict=True)):
                out[f"batch/{cycle}/{mode}/{i}"] = {"fuel_kg": float(fuel), "trace_miss_s": float(miss)}
            print(f"batch/{cycle}/{mode}: {len(df)} variants", flush=True)
    return out


def compare(a: dict, b: dict) -> tuple[tuple, tuple, list]:
    """((rel, case) of the fuel, (rel, case field) of any figure, [runs whose series are not identical])."""
    fuel, any_, moved = (0.0, None), (0.0, None), []
    for key, row in a.items():
        other = b.get(key, {})
        for f, x in row.items():
            y = other.get(f)
            if f == "series_sha1":
                if y is not None and x != y:
                    moved.append(key)
                continue
            if y is None or math.isnan(x) or math.isnan(y) or x == y:
                continue
            rel = abs(x - y) / max(abs(x), abs(y))
            if rel > any_[0]:
                any_ = (rel, f"{key} {f}")
            if f == "fuel_kg" and rel > fuel[0]:
                fuel = (rel, key)
    return fuel, any_, moved


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="JSON file to write")
    ap.add_argument("--against", help="a JSON file of another run to compare with")
    args = ap.parse_args()
    t0 = time.process_time()
    out = figures()
    Path(args.out).write_text(json.dumps(out, indent=1))
    print(f"{len(out)} cases, {time.process_time() - t0:.1f} s CPU")
    if args.against:
        other = json.loads(Path(args.against).read_text())
        missing = sorted(set(other) ^ set(out))
        if missing:
            print(f"cases in one file only: {', '.join(missing[:10])}{' ...' if len(missing) > 10 else ''}")
        (rf, kf), (ra, ka), moved = compare(other, out)
        print(f"largest relative difference: fuel {rf:.3g} ({kf}), any figure {ra:.3g} ({ka})")
        runs = sum(1 for k in out if "series_sha1" in out[k])
        print(
            f"series not identical to the bit: {len(moved)} of {runs} runs"
            + (f" ({', '.join(moved[:6])}{' ...' if len(moved) > 6 else ''})" if moved else "")
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
