"""Fuel and electric figures of every hybrid and electric preset on UDDS, HWFET and US06 by every method and
management, to a JSON file, and the largest relative difference against another run's file: the check for
a change meant to be only faster (it moves the figures by rounding only).

    python benchmarks/electric_fuel_matrix.py before.json                 # on the old checkout
    python benchmarks/electric_fuel_matrix.py after.json --against before.json
    python benchmarks/electric_fuel_matrix.py after.json --measured       # with ADVISOR machine maps

``--measured`` puts a measured machine map in (bev: MC_PM49, hev_p2: MC_PM32, hev_split: MC_PM49, from
``$VPSIM_SHARED/data/raw/advisor``, default ``../shared`` beside the repository), the cases a scalable
machine does not reach (the map's piecewise-linear losses, the ECMS's exhaustive search).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

from vpsim.cycles import load_cycle
from vpsim.params import load_parameters
from vpsim.simulation import simulate

PRESETS = ("hev_p2", "hev_split", "mhev", "bev")
MAPS = {"bev": "MC_PM49", "hev_p2": "MC_PM32", "hev_split": "MC_PM49"}


def cases(measured: bool):
    shared = Path(os.environ.get("VPSIM_SHARED", Path(__file__).resolve().parents[2] / "shared"))
    for preset in MAPS if measured else PRESETS:
        for cycle in ("udds", "hwfet", "us06"):
            for method in ("backward", "forward", "inverse"):
                for ems in ("rule", "ecms") if preset != "bev" else (None,):
                    p = load_parameters(preset)
                    name = preset
                    if measured:
                        path = shared / "data" / "raw" / "advisor" / f"{MAPS[preset]}.m"
                        if not path.is_file():
                            sys.exit(f"machine map {path} not found (set VPSIM_SHARED)")
                        p = p.with_changes(machine={"map_file": str(path)})
                        name = f"{preset}+{MAPS[preset]}"
                    yield f"{name}/{cycle}/{method}/{ems}", cycle, method, p, ems


def figures(measured: bool) -> dict:
    out = {}
    for key, cycle, method, p, ems in cases(measured):
        r = simulate(load_cycle(cycle), method, p, **({} if ems is None else {"ems": ems}))
        row = {"fuel_kg": r.fuel_kg}
        for k, v in r.electric.items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                row["e." + k] = float(v)
        out[key] = row
        print(key, f"fuel {r.fuel_kg:.12g} kg", flush=True)
    return out


def largest_difference(a: dict, b: dict) -> tuple[tuple, tuple]:
    """((rel, case) of the fuel, (rel, case field) of any figure): the largest relative differences."""
    fuel, any_ = (0.0, None), (0.0, None)
    for key, row in a.items():
        for f, x in row.items():
            y = b.get(key, {}).get(f)
            if y is None or math.isnan(x) or math.isnan(y) or x == y:
                continue
            rel = abs(x - y) / max(abs(x), abs(y))
            if rel > any_[0]:
                any_ = (rel, f"{key} {f}")
            if f == "fuel_kg" and rel > fuel[0]:
                fuel = (rel, key)
    return fuel, any_


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="JSON file to write")
    ap.add_argument("--against", help="a JSON file of another run to compare with")
    ap.add_argument("--measured", action="store_true", help="with measured machine maps")
    args = ap.parse_args()
    t0 = time.process_time()
    out = figures(args.measured)
    Path(args.out).write_text(json.dumps(out, indent=1))
    print(f"{len(out)} cases, {time.process_time() - t0:.1f} s CPU")
    if args.against:
        other = json.loads(Path(args.against).read_text())
        missing = sorted(set(other) ^ set(out))
        if missing:
            print(f"cases in one file only: {', '.join(missing)}")
        (rf, kf), (ra, ka) = largest_difference(other, out)
        print(f"largest relative difference: fuel {rf:.3g} ({kf}), any figure {ra:.3g} ({ka})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
