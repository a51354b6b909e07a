"""The three methods side by side on the hybrid presets (issue: "ECMS within 3 % across the three methods"):
for each preset, cycle and management, the charge-sustaining fuel (SAE J1711, with its 1 % band) and the
fuel corrected for the battery's energy change at any size of it, by the backward, inverse and forward
method, and the spread of each (largest over smallest, minus 1); with ``--regression`` also the fuel at zero
net energy change by J1711's own procedure (:func:`vpsim.charge_balance.regression`, five runs from
starting charges 0.06 apart); the forward car's largest speed error and its time outside the +-2 km/h band.

    python benchmarks/method_spread.py                 # the table (seconds, once the kernels are compiled)
    python benchmarks/method_spread.py --json out.json # and every figure to a file
    python benchmarks/method_spread.py --regression    # and J1711's regression (five times the runs)
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from vpsim.charge_balance import regression
from vpsim.cycles import load_cycle
from vpsim.params import load_parameters
from vpsim.simulation import simulate

PRESETS = ("hev_p2", "hev_split", "mhev")
CYCLES = ("udds", "hwfet", "us06")
METHODS = ("backward", "inverse", "forward")


def spread(values) -> float:
    return max(values) / min(values) - 1.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", help="write every figure to this file")
    ap.add_argument("--regression", action="store_true", help="and J1711's regression by every method")
    args = ap.parse_args()
    t0 = time.process_time()
    rows = {}
    print(
        f"{'case':24s} {'J1711 L/100km (b / i / f)':>27s} {'spread':>7s}   "
        f"{'corrected (b / i / f)':>23s} {'spread':>7s}   {'fwd max err':>11s} {'outside':>8s}"
    )
    for preset in PRESETS:
        p = load_parameters(preset)
        for cycle in CYCLES:
            cyc = load_cycle(cycle)
            for ems in ("rule", "ecms"):
                runs = {m: simulate(cyc, m, p, ems=ems) for m in METHODS}
                cs = [runs[m].electric["fuel_l_per_100km_cs"] for m in METHODS]
                corr = [runs[m].electric["fuel_l_per_100km_corrected"] for m in METHODS]
                fwd = runs["forward"].summary()
                key = f"{preset}/{cycle}/{ems}"
                rows[key] = {
                    "fuel_l_per_100km_cs": dict(zip(METHODS, cs, strict=True)),
                    "fuel_l_per_100km_corrected": dict(zip(METHODS, corr, strict=True)),
                    "net_energy_change_ratio": {
                        m: runs[m].electric["net_energy_change_ratio"] for m in METHODS
                    },
                    "spread_cs": spread(cs),
                    "spread_corrected": spread(corr),
                    "forward_max_speed_error_mps": fwd["max_speed_error_mps"],
                    "forward_speed_not_followed_s": fwd["speed_not_followed_s"],
                    "trace_miss_s": {m: runs[m].summary()["demand_not_deliverable_s"] for m in METHODS},
                }
                extra = ""
                if args.regression:
                    reg = [regression(cyc, p, method=m, ems=ems).fuel_l_per_100km for m in METHODS]
                    rows[key]["fuel_l_per_100km_regression"] = dict(zip(METHODS, reg, strict=True))
                    rows[key]["spread_regression"] = spread(reg)
                    extra = f"   regression {' / '.join(f'{x:.3f}' for x in reg)} {spread(reg):6.1%}"
                print(
                    f"{key:24s} {' / '.join(f'{x:.3f}' for x in cs):>27s} {spread(cs):7.1%}   "
                    f"{' / '.join(f'{x:.3f}' for x in corr):>23s} {spread(corr):7.1%}   "
                    f"{fwd['max_speed_error_mps']:9.2f} m/s {fwd['speed_not_followed_s']:6.1f} s" + extra,
                    flush=True,
                )
    worst = max(rows.items(), key=lambda kv: kv[1]["spread_corrected"])
    print(
        f"{len(rows)} cases, {time.process_time() - t0:.0f} s CPU; largest spread of the corrected fuel "
        f"{worst[1]['spread_corrected']:.1%} ({worst[0]}); beyond 3 %: "
        + (", ".join(k for k, r in rows.items() if r["spread_corrected"] > 0.03) or "none")
        + "; J1711 figures beyond 3 %: "
        + (", ".join(k for k, r in rows.items() if r["spread_cs"] > 0.03) or "none")
    )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
