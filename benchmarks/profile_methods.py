"""Where the time of one UDDS run goes, per method: the figures behind benchmarks/README.md.

    python benchmarks/profile_methods.py            # all methods
    python benchmarks/profile_methods.py backward   # one

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


def profile_forward(p, cyc, schedule):
    from vpsim.methods import forward

    r = simulate(cyc, "forward", p, gears=schedule)
    run = median_us(lambda: simulate(cyc, "forward", p, gears=schedule), 40)
    info = r.solver if hasattr(r, "solver") else {}
    nfev = info.get("rhs_evaluations")
    pr = cProfile.Profile()
    pr.enable()
    for _ in range(20):
        simulate(cyc, "forward", p, gears=schedule)
    pr.disable()
    st = pstats.Stats(pr)
    kernel = sum(v[2] for k, v in st.stats.items() if k[2] == "_integrate") / 20 * 1e6
    per = f", {kernel * 1e3 / nfev:.0f} ns per right-side evaluation" if nfev else ""
    print(
        f"forward udds driver 1: run {run:.0f} us, kernel {kernel:.0f} us; {r.steps} steps, "
        f"{nfev} right-side evaluations{per}"
    )
    print(f"  forward kernel cache: {forward._integrate._cache._cache_path}")
    print(top(lambda: simulate(cyc, "forward", p, gears=schedule), 20))


def profile_inverse(p, cyc, schedule):
    run = median_us(lambda: simulate(cyc, "inverse", p, gears=schedule), 200)
    print(f"inverse udds driver 1: run {run:.1f} us")
    print(top(lambda: simulate(cyc, "inverse", p, gears=schedule), 500))


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


if __name__ == "__main__":
    main(sys.argv[1:])
