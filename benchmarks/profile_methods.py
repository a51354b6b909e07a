"""Where the time of one UDDS run goes, per method: the figures behind benchmarks/README.md.

    python benchmarks/profile_methods.py            # all methods
    python benchmarks/profile_methods.py backward   # one
    python benchmarks/profile_methods.py linearity  # the backward's ns per interval, x1 against x16 FTP-75

Prints, for each method, the median wall time of a run with inputs prepared, its split into the compiled
kernel and the Python around it, and the ten most expensive functions under cProfile. Wall times on a
shared machine are noisy: compare figures from one run of this script.
"""

from __future__ import annotations

import cProfile
import io
import pstats
import statistics
import sys
import time

import numpy as np

from vpsim.cycles import Cycle, load_cycle
from vpsim.gears import default_schedule
from vpsim.methods import backward
from vpsim.model.maps import cached_engine_map
from vpsim.params import load_parameters
from vpsim.simulation import simulate


def median_us(fn, n=300):
    fn()
    ts = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts) * 1e6


def top(fn, n_calls, lines=10) -> str:
    pr = cProfile.Profile()
    pr.enable()
    for _ in range(n_calls):
        fn()
    pr.disable()
    out = io.StringIO()
    pstats.Stats(pr, stream=out).sort_stats("tottime").print_stats(lines)
    text = out.getvalue()
    return text[text.find("   ncalls") :]


def profile_backward(p, cyc, schedule, em):
    run = median_us(lambda: backward.run(cyc, p, engine_map=em, schedule=schedule))
    n = cyc.time_s.size - 1
    two = Cycle("two", np.array([0.0, 1.0, 2.0]), np.array([0.0, 1.0, 0.0]))
    s2 = default_schedule(two, p, em)
    fixed = median_us(lambda: backward.run(two, p, engine_map=em, schedule=s2), 2000)
    print(
        f"backward udds: run {run:.1f} us ({(run - fixed) * 1e3 / n:.0f} ns per interval beyond the fixed "
        "cost); "
        f"fixed cost (2-interval cycle) {fixed:.1f} us"
    )
    print(top(lambda: backward.run(cyc, p, engine_map=em, schedule=schedule), 2000))
    split_backward(p, cyc, schedule, em)


def split_backward(p, cyc, schedule, em):
    """One UDDS run in each mode (``vpsim bench`` times ``simulate``, whose default is the realistic mode),
    split into the compiled pass with and without the rows the series are made from, ``sample_rows`` (the
    series at the samples) and the Python around them."""
    kind, m_speed, m_torque, table, l_speed, l_max, l_min, s_max, s_min = backward._map_arrays(em, p)
    recs = backward.kernel_records(p)
    ratios = backward.total_ratios(p.transmission)
    intervals = backward.cycle_intervals(cyc)
    n = cyc.time_s.size - 1
    gear = np.empty(n, dtype=np.int64)
    rows = np.empty((backward.N_ROWS, n))
    acc = np.empty(backward.N_ACC)
    out = np.empty((backward.N_SAMPLE_ROWS, n + 1))
    gear_out, engaged_out = np.empty(n + 1, dtype=np.int64), np.empty(n + 1, dtype=np.bool_)
    steps = backward.gearbox_steps(p.transmission)
    generated = True
    peer = _peer_udds_us()
    if peer is not None:
        print(f"FASTSim's UDDS walk {peer:.0f} us here (vpsim bench's peer): 100x needs {peer / 100:.1f} us")
    for mode in ("realistic", "paper"):
        extended = mode == "realistic"

        def kernel(r, extended=extended):
            backward.run_kernel(
                cyc.time_s, *intervals, schedule.time_s, schedule.gear, ratios, recs, extended, kind,
                m_speed, m_torque, table, l_speed, l_max, l_min, s_max, s_min, generated, True,
                backward._interval_gears(schedule, cyc), gear, r, acc,
            )  # fmt: skip

        call = median_us(lambda m=mode: simulate(cyc, "backward", p, gears=schedule, mode=m), 2000)
        with_rows = median_us(lambda: kernel(rows), 2000)
        sums_only = median_us(lambda: kernel(np.empty((backward.N_ROWS, 0))), 2000)
        kernel(rows)
        sample = median_us(
            lambda: backward.sample_rows(rows, gear, steps, recs, generated, out, gear_out, engaged_out), 2000
        )
        print(
            f"backward udds, {mode} mode: simulate {call:.1f} us = the pass {with_rows:.1f} us "
            f"({sums_only:.1f} us without the series' rows) + sample_rows {sample:.1f} us + "
            f"{call - with_rows - sample:.1f} us of Python"
        )


def _peer_udds_us():
    """The median of FASTSim's UDDS walk timed with ``vpsim bench``'s own helpers (after a second's warm-up),
    or None when FASTSim is not installed."""
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            import fastsim as fsim
    except ImportError:
        return None
    from vpsim.bench import PEER_CYCLES, PEER_VEHICLE, _block, _walk

    veh = fsim.Vehicle.from_resource(PEER_VEHICLE)
    cyc = fsim.Cycle.from_resource(PEER_CYCLES["udds"])
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < 1.0:
        _walk(fsim.SimDrive(veh, cyc))
    return _block(_walk, lambda: fsim.SimDrive(veh, cyc), 100) * 1e6


def profile_forward(p, cyc, schedule):
    from vpsim.methods import forward

    r = simulate(cyc, "forward", p, driver=1, gears=schedule)
    run = median_us(lambda: simulate(cyc, "forward", p, driver=1, gears=schedule), 40)
    info = r.solver if hasattr(r, "solver") else {}
    nfev = info.get("rhs_evaluations")
    pr = cProfile.Profile()
    pr.enable()
    for _ in range(20):
        simulate(cyc, "forward", p, driver=1, gears=schedule)
    pr.disable()
    st = pstats.Stats(pr)
    # the integrator's kernel, whichever solver ran (_integrate_ros: RODAS3, the default; _integrate: DOPRI5)
    kernel = sum(v[2] for k, v in st.stats.items() if k[2] in ("_integrate_ros", "_integrate")) / 20 * 1e6
    per = f", {kernel * 1e3 / nfev:.0f} ns per right-side evaluation" if nfev else ""
    print(
        f"forward udds driver 1: run {run:.0f} us, kernel {kernel:.0f} us; {r.steps} steps, "
        f"{nfev} right-side evaluations{per}"
    )
    print(f"  forward kernel cache: {forward._integrate_ros._cache._cache_path}")
    print(top(lambda: simulate(cyc, "forward", p, driver=1, gears=schedule), 20))


def profile_inverse(p, cyc, schedule):
    run = median_us(lambda: simulate(cyc, "inverse", p, driver=1, gears=schedule), 200)
    print(f"inverse udds driver 1: run {run:.1f} us")
    print(top(lambda: simulate(cyc, "inverse", p, driver=1, gears=schedule), 500))


def profile_linearity(p, em):
    """Why the backward linearity (FTP-75 x16 against x1) moves between runs: ns per interval of a whole
    simulate call on the cycle repeated exactly and on the same cycle with 3 % noise on every sample's speed
    (a trace that does not repeat), 15 interleaved rounds."""
    import gc

    base = load_cycle("ftp75")
    rng = np.random.default_rng(0)

    def noisy(c):
        v = c.speed_mps * (1.0 + 0.03 * rng.standard_normal(c.speed_mps.size)) * (c.speed_mps > 0)
        return Cycle(f"{c.name} noisy", c.time_s, np.maximum(v, 0.0))

    cases = {}
    for label, cyc in (
        ("x1", base),
        ("x16", base.repeat(16)),
        ("x1 with noise", noisy(base)),
        ("x16 with noise", noisy(base.repeat(16))),
    ):
        schedule = default_schedule(cyc, p, em)
        cases[label] = (
            lambda cyc=cyc, s=schedule: simulate(cyc, "backward", p, gears=s),
            cyc.time_s.size - 1,
        )
    per = {k: [] for k in cases}
    enabled = gc.isenabled()
    gc.disable()
    try:
        for _ in range(15):
            for k, (fn, n) in cases.items():
                reps = max(3, int(0.03 / (80e-9 * n)))
                fn()
                t0 = time.perf_counter()
                for _ in range(reps):
                    fn()
                per[k].append((time.perf_counter() - t0) / reps / n * 1e9)
    finally:
        if enabled:
            gc.enable()
    print("backward simulate, ns per interval (median of 15 rounds):")
    for k, v in per.items():
        print(f"  ftp75 {k:15s} {statistics.median(v):6.1f}")


def main(argv):
    which = argv or ["backward", "forward", "inverse"]
    p = load_parameters("hofman2011")
    cyc = load_cycle("udds")
    em = cached_engine_map(p.engine)
    schedule = default_schedule(cyc, p, em)
    if "backward" in which:
        profile_backward(p, cyc, schedule, em)
    if "forward" in which:
        profile_forward(p, cyc, schedule)
    if "inverse" in which:
        profile_inverse(p, cyc, schedule)
    if "linearity" in which:
        profile_linearity(p, em)


if __name__ == "__main__":
    main(sys.argv[1:])
