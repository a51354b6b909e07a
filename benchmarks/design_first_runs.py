"""What one run costs when its parameter set is new: a sweep's, a fleet grid's or a user's edited vehicle.

    python benchmarks/design_first_runs.py                 # every preset, UDDS, backward
    python benchmarks/design_first_runs.py --json out.json
    PYTHONPATH=OLD/src python benchmarks/design_first_runs.py   # another version, to compare

``vpsim bench`` times repeated runs of one parameter set, as design work on one car does: what a method
derives from the parameters (the engine's generated map, the gear schedule, a power split's operating lines,
the records) is built once and kept on the set. A sweep, the fleet's technology grids and a user who edits a
vehicle file run each parameter set once, so that set-up is paid on every run. Per preset (the engine car,
the battery-electric car, the P2, the power split and the mild hybrid; hybrids with ECMS), the median CPU
time (``time.process_time``; 15 runs after one warm-up) of ``vpsim.simulate(udds, "backward", q)`` where
``q`` is:

* ``same``: the preset itself every time (what ``vpsim bench`` measures);
* ``new_vehicle``: a new parameter set each run that differs in the vehicle's mass (what a fleet grid's
  accessory or battery nodes, or a sweep over mass or cells, are like);
* ``new_engine``: a new parameter set each run whose engine differs (thermal efficiency; the engine's map and
  everything derived from it are built anew; not for the battery-electric car).

Run it under two versions (``PYTHONPATH``) in turns, on a quiet machine: CPU time of a few milliseconds moves
by 10-30 % with the load of the other core.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

PRESETS = (("hofman2011", None), ("bev", None), ("hev_p2", "ecms"), ("hev_split", "ecms"), ("mhev", "ecms"))
RUNS = 15


def median_ms(params_of, kw, runs: int = RUNS) -> float:
    import vpsim

    times = []
    for k in range(runs):
        q = params_of(k)
        start = time.process_time()
        vpsim.simulate("udds", "backward", q, **kw)
        times.append(time.process_time() - start)
    return 1e3 * statistics.median(times)


def measure(runs: int = RUNS) -> dict:
    import vpsim
    from vpsim.params import load_parameters

    out = {}
    for name, ems in PRESETS:
        p = load_parameters(name)
        kw = {"ems": ems} if ems else {}
        vpsim.simulate("udds", "backward", p, **kw)  # kernels loaded, the preset's own set-up built
        row = {
            "same": median_ms(lambda k, p=p: p, kw, runs),
            "new_vehicle": median_ms(
                lambda k, p=p: p.with_changes(vehicle={"mass": p.vehicle.mass + 1.0 + k}), kw, runs
            ),
        }
        if name != "bev":
            eta = p.engine.thermal_efficiency
            row["new_engine"] = median_ms(
                lambda k, p=p, eta=eta: p.with_changes(engine={"thermal_efficiency": eta - 0.001 * (k + 1)}),
                kw,
                runs,
            )
        out[name] = row
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    ap.add_argument("--runs", type=int, default=RUNS, help=f"runs per median (default {RUNS})")
    args = ap.parse_args(argv)
    import vpsim

    res = measure(args.runs)
    print(f"vpsim {vpsim.__file__}")
    print("UDDS, backward, median CPU ms per run: the same parameter set / a new vehicle mass / a new engine")
    for name, row in res.items():
        eng = f"{row['new_engine']:8.2f}" if "new_engine" in row else "       -"
        print(f"  {name:11s} {row['same']:8.2f} {row['new_vehicle']:8.2f} {eng}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"udds_backward_cpu_ms": res, "runs": args.runs}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
