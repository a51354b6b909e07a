"""The full hybrids' part of the fleet run alone: out-of-fold errors per class in a few minutes (not shipped).

    python benchmarks/hev_out_of_fold.py ../shared/data/epa/22-tstcar.csv
    python benchmarks/hev_out_of_fold.py LIST --csv rows.csv   # also the per-vehicle rows
    python benchmarks/hev_out_of_fold.py LIST --set electric.regen_share=0.7 --layout hev_p2   # one change

Runs exactly the fleet run's full-hybrid part (``vpsim.fleet.run._run_hevs``: the same family folds, classes,
technology grid and fit, one backward ECMS run per vehicle and test at its fold's technology) in this
process, without the peer, on the list's full hybrids only (the conventional cars, EVs and mild hybrids are
not read into it). Prints per class and test n / median / median |error| / p90 |error| of mpg, the P2s
together, all of them (the fleet report's ``by_powertrain.hev``), each class's fitted technology per fold,
and the CPU time (about 4 min on one core: 232 s on 2026-12-05, a quiet machine).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from vpsim.fleet import calibrate as cal
from vpsim.fleet import hev
from vpsim.fleet import run as fleet_run
from vpsim.fleet.epa import read_test_car_list


def _stats(errors) -> str:
    e = np.asarray([x for x in errors if np.isfinite(x)])
    if e.size == 0:
        return "  0"
    a = np.abs(e)
    return f"{e.size:3d}  {np.median(e):+6.1f} / {np.median(a):5.2f} / {np.quantile(a, 0.9):5.2f} %"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("list", help="the EPA test car list (22-tstcar.csv)")
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--csv", help="write the per-vehicle rows (with their class) to this file")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.FIELD=VALUE",
        help="a change to the full hybrids' parameters (repeatable), e.g. electric.regen_share=0.7",
    )
    ap.add_argument(
        "--layout", choices=("hev_split", "hev_p2"), help="make the --set changes to this layout only"
    )
    a = ap.parse_args()
    changes = {k: float(v) for k, _, v in (x.partition("=") for x in a.set)}
    cars = read_test_car_list(a.list)
    recs = cars.hev_vehicles
    shipped = hev.hev_parameters

    def build(rec, technology=None):  # the changes first: the fitted technology overrides them
        mine = changes if a.layout in (None, rec.layout) else {}
        return shipped(rec, {**mine, **(technology or {})})

    hev.hev_parameters = build
    t0 = time.process_time()
    try:
        out = fleet_run._run_hevs(recs, cal.FoldSpec(a.folds), fleet_run._Serial(), {}, False, {})
    finally:
        hev.hev_parameters = shipped
    cpu = time.process_time() - t0
    if changes:
        print(f"changes {changes} to {a.layout or 'every layout'}")
    cls = {(v.vehicle_id, v.configuration): hev.hev_class(v) for v in recs}
    rows = [{**r, "class": cls[(r["vehicle_id"], r["configuration"])]} for r in out["rows"]]
    print(f"full hybrids: n  median / median|error| / p90|error| (mpg, out of fold; CPU {cpu:.0f} s)")
    groups = [(c, (c,)) for c in hev.CLASSES] + [
        ("hev_p2 + converter", ("hev_p2", "hev_p2_converter")),
        ("all full hybrids", tuple(hev.CLASSES)),  # the fleet report's by_powertrain.hev figures
    ]
    for name, members in groups:
        for cyc in hev.HEV_CYCLES:
            e = [r["error_pct"] for r in rows if r["cycle"] == cyc and r["class"] in members]
            if e:
                print(f"  {name:19s} {cyc:8s} {_stats(e)}")
    failed = [r for r in rows if r["status"] == "failed"]
    if failed:  # a change the model refuses fails its rows: say so, not an empty class
        print(
            f"  {len(failed)} rows failed, e.g. {failed[0]['vehicle_id']} {failed[0]['cycle']}: "
            f"{failed[0]['detail']}"
        )
    for key, t in out["technology"].items():
        eta, acc = t[hev.TECH_PARAMS[0]], t[hev.TECH_PARAMS[1]]
        extra = "".join(f"  {p.split('.')[1]} {t[p]:.3g}" for p in hev.TECH_PARAMS[2:])
        print(f"  {key:24s} eta {eta:.4f}  accessories {acc:6.0f} W{extra}")
    if a.csv:
        import pandas as pd

        pd.DataFrame(rows).to_csv(a.csv, index=False)


if __name__ == "__main__":
    main()
