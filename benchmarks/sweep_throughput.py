"""Throughput of a backward design-space sweep: in process, serial, and on a Dask LocalCluster.

    python benchmarks/sweep_throughput.py                 # 10,000 points (about three minutes on 2 cores)
    python benchmarks/sweep_throughput.py --points 2000 --accel

The sweep is a Latin hypercube over bore, stroke, cylinders, final drive, mass and frontal area: every point
has its own engine, so every point builds its fuel map. Measured (wall clock, results written to a
temporary folder as in real use):

* in-process batch path: :func:`vpsim.sweep.compute_chunk` called on every chunk in this process, nothing
  stored: the work itself (backward rows through the compiled :func:`vpsim.batch.run_batch`);
* serial: ``run_sweep(workers=1)``, the same work plus planning and storing every chunk;
  both on one core (the compiled kernels limited to one thread);
* Dask, 1 and 2 workers: ``run_sweep(scheduler=...)`` on a LocalCluster started (and warmed up) beforehand;
  cluster start-up is reported on its own.

Printed: points per second of each, the speed-up of 2 workers over serial, and the overhead per point of the
cluster path against the in-process batch path, (T_dask,1 worker - T_batch) / N, split into a fixed part per
sweep and a marginal part per point (from a second sweep of N/5 points).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path


def spec_for(points: int, accel: bool, seed: int = 1):
    from vpsim.sweep import make_spec

    return make_spec(
        name="throughput",
        sampling="lhs",
        samples=points,
        seed=seed,
        baseline=False,
        cycles=["nedc"],
        methods=["backward"],
        acceleration=accel,
        parameters={
            "engine.bore": {"range": [0.075, 0.095]},
            "engine.stroke": {"range": [0.075, 0.095]},
            "engine.cylinders": [3, 4, 5, 6],
            "transmission.final_drive": {"range": [3.5, 5.0]},
            "vehicle.mass": {"range": [1200.0, 1800.0]},
            "vehicle.frontal_area": {"range": [2.0, 2.6]},
        },
    )


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=10_000)
    ap.add_argument("--accel", action="store_true", help="include the 0-100 km/h run of every design")
    args = ap.parse_args(argv)

    import warnings

    import numba
    from dask.distributed import Client, LocalCluster

    from vpsim.sweep import compute_chunk, plan, run_sweep
    from vpsim.sweep.runner import batch_available, make_chunks, result_schema

    n = args.points
    spec = spec_for(n, args.accel)
    warm = spec_for(40, args.accel, seed=99)
    print(
        f"{n} design points, backward on NEDC, acceleration {'on' if args.accel else 'off'}; "
        f"{os.cpu_count()} cores; compiled batch path {'available' if batch_available() else 'not available'}"
    )
    run_sweep(warm, workers=1)  # imports, compiled kernels, caches

    def batch_time(sp):
        """The work alone: compute_chunk on every chunk in this process, nothing stored."""
        pl = plan(sp)
        chunks = make_chunks(
            pl.tasks, pl, run_id="bench", workers=1, chunk_size=None, schema=result_schema(sp)
        )
        t0 = time.perf_counter()
        rows = sum(len(compute_chunk(c)) for c in chunks)
        assert rows == sp.n_designs
        return time.perf_counter() - t0, len(chunks)

    small = spec_for(n // 5, args.accel, seed=2)  # a second size separates fixed and per-point overhead
    threads = numba.get_num_threads()
    numba.set_num_threads(1)  # serial means one core: the compiled kernels too
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t_batch, n_chunks_serial = batch_time(spec)
        t_batch_small, _ = batch_time(small)
        t0 = time.perf_counter()
        serial = run_sweep(spec, tmp / "serial", workers=1)
        t_serial = time.perf_counter() - t0
        assert serial.n_computed == n and serial.n_failed == 0
        numba.set_num_threads(threads)

        timings, startup = {}, {}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for workers in (1, 2):
                t0 = time.perf_counter()
                with (
                    LocalCluster(
                        n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0"
                    ) as cluster,
                    Client(cluster),
                ):
                    startup[workers] = time.perf_counter() - t0
                    run_sweep(warm, scheduler=cluster.scheduler_address)  # warm every worker
                    t0 = time.perf_counter()
                    r = run_sweep(spec, tmp / f"dask{workers}", scheduler=cluster.scheduler_address)
                    timings[workers] = time.perf_counter() - t0
                    assert r.n_computed == n and r.n_failed == 0
                    if workers == 1:
                        t0 = time.perf_counter()
                        run_sweep(small, tmp / "dask1_small", scheduler=cluster.scheduler_address)
                        t_small = time.perf_counter() - t0
                    n_chunks = r.n_chunks

    def line(name, t):
        print(f"  {name:<34} {t:8.2f} s   {n / t:8.0f} points/s   {t / n * 1e3:7.3f} ms/point")

    print(f"chunks: {n_chunks_serial} in process, {n_chunks} on 2 workers")
    line("in-process batch path", t_batch)
    line("serial run_sweep (stored)", t_serial)
    line("Dask LocalCluster, 1 worker", timings[1])
    line("Dask LocalCluster, 2 workers", timings[2])
    print(f"  cluster start-up: {startup[1]:.2f} s (1 worker), {startup[2]:.2f} s (2 workers), not included")
    print(f"speed-up, 2 workers over serial: {t_serial / timings[2]:.2f}x")
    over = timings[1] - t_batch
    print(
        f"overhead per point, cluster path (1 worker) vs in-process batch path: {over / n * 1e3:+.3f} ms "
        f"({(timings[1] / t_batch - 1) * 100:+.1f} %)"
    )
    # overhead(N) = fixed + marginal * N, from this sweep and one of N/5 points
    marginal = (over - (t_small - t_batch_small)) / (n - small.n_designs)
    print(
        f"  = {over - marginal * n:.2f} s fixed per sweep (connect, start, read back) "
        f"+ {marginal * 1e3:.3f} ms marginal per point"
    )
    print(
        "overhead per point, serial run_sweep (planning + storing) vs in-process batch path: "
        f"{(t_serial - t_batch) / n * 1e3:+.3f} ms"
    )


if __name__ == "__main__":
    main()
