"""The mild hybrids' out-of-fold errors alone, and the same records run as conventional cars (not shipped).

    python benchmarks/mhev_oof.py ../shared/data/epa/22-tstcar.csv
    python benchmarks/mhev_oof.py LIST --csv DIR     # also the per-vehicle rows: DIR/mhev.csv, DIR/conv.csv
    python benchmarks/mhev_oof.py LIST --no-conventional
    python benchmarks/mhev_oof.py LIST --converter   # the automatics' torque converter in the mild hybrids
    python benchmarks/mhev_oof.py LIST --crank-accessories   # the fitted load on the crank (not kept)
    python benchmarks/mhev_oof.py LIST --aspiration-classes  # the belt class split by aspiration (not kept)
    python benchmarks/mhev_oof.py LIST --accessory-max 1000  # the fitted load capped (not kept)

Runs exactly the fleet run's mild-hybrid part (``vpsim.fleet.run._run_mhevs``: the mild hybrids' family
folds, the classes ``mhev_p0`` / ``mhev_p1``, the technology grid and fit, one backward ECMS run per
vehicle and test at its fold's technology, the charge-sustaining figure), in this process, without the peer;
a few minutes of CPU instead of the whole fleet's twenty.

Then, unless ``--no-conventional``, the same records as *conventional cars*: the conventional fleet's
vehicle (:func:`vpsim.fleet.vehicle.record_parameters`, torque converter included), gear rule and
technology grid (:mod:`vpsim.fleet.calibrate`: thermal efficiency, friction, accessories), its technology
fitted out of fold on the *same* folds and classes (the layouts), as FASTSim's calibrated conventional car
is in the fleet run: what the hybrid layer adds over a calibrated conventional car of the same record.

Prints per test and class n / median / median |error| / p90 |error| (mpg, out of fold), the same per
maker's system for bag 2, and the fitted technology per fold; CPU seconds.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from vpsim.fleet import calibrate as cal
from vpsim.fleet import mhev as mm
from vpsim.fleet import run as fleet_run
from vpsim.fleet.cycles import fleet_cycle
from vpsim.fleet.epa import mpg_from_l_per_100km, read_test_car_list

ASPIRATED = "mhev_p0_aspirated"  # --aspiration-classes


def run_mhev(cars, folds: int = 5, group_by: str = "family", changes: dict | None = None) -> dict:
    """The fleet's mild-hybrid part, serial, no peer: its ``out`` (rows, technology, folds). ``changes``
    ({"section.field": value}) are put into every mild hybrid's parameters in this process only (before
    the fitted technology, which overrides them)."""
    shipped = mm.mhev_parameters

    def build(rec, cycle_name=None, technology=None):
        return shipped(rec, cycle_name, {**(changes or {}), **(technology or {})})

    try:
        mm.mhev_parameters = build
        return fleet_run._run_mhevs(
            cars.mhev_vehicles, cal.FoldSpec(folds, group_by), fleet_run._Serial(), {}, False, {}
        )
    finally:
        mm.mhev_parameters = shipped


def run_conventional(cars, fold_of: dict, folds: int, class_of=mm.mhev_class) -> tuple[list[dict], dict]:
    """The mild hybrids' records as conventional cars, technology fitted out of fold per ``class_of`` on the
    given folds: (rows, technology per (fold, class))."""
    recs = [v for v in cars.mhev_vehicles if v.key in fold_of]
    work = [(v, tuple(c for c in mm.MHEV_CYCLES if c in v.measured_mpg)) for v in recs]
    grid_rows = fleet_run.grid_chunk(work)
    by_key = {v.key: v for v in recs}
    ok = [r for r in grid_rows if r["log_fuel"] is not None]
    lg = np.stack([r["log_fuel"] for r in ok])
    meas = np.array([fleet_run._log_l100(by_key[r["key"]].measured_mpg[r["cycle"]]) for r in ok])
    vfold = np.array([fold_of[r["key"]] for r in ok])
    classes = sorted({class_of(v) for v in recs})
    vclass = np.array([class_of(by_key[r["key"]]) for r in ok], dtype=object)
    fpw = {c: cal.fuel_per_watt(fleet_cycle(c).duration_s, fleet_cycle(c).distance_m) for c in mm.MHEV_CYCLES}
    per_watt = np.array([fpw[r["cycle"]] for r in ok])

    def fit_rows(rows):
        return cal.fit(lg[rows], meas[rows], per_watt[rows])

    tech = cal.per_fold_and_class(fit_rows, vfold, vclass, folds, tuple(classes))
    items = [
        (by_key[r["key"]], r["cycle"], tech[(fold_of[r["key"]], class_of(by_key[r["key"]]))], r["gear"])
        for r in ok
    ]
    preds = fleet_run.predict_chunk(items, "backward")
    rows = []
    for (v, c, t, _), p in zip(items, preds, strict=True):
        meas_c = v.measured_mpg[c]
        mpg = mpg_from_l_per_100km(p["predicted_l_per_100km"]) if not p["error"] else math.nan
        rows.append(
            {
                "vehicle_id": v.vehicle_id,
                "configuration": v.configuration,
                "make": v.make,
                "model": v.model,
                "layout": v.layout,
                "system": v.system,
                "cycle": c,
                "fold": fold_of[v.key],
                "measured_mpg": meas_c,
                "predicted_mpg": mpg,
                "error_pct": 100.0 * (mpg / meas_c - 1.0),
                **{k.split(".")[1]: t[k] for k in cal.TECH_PARAMS},
            }
        )
    return rows, tech


def stats(errors) -> str:
    e = np.asarray([x for x in errors if np.isfinite(x)])
    if not e.size:
        return "  0"
    a = np.abs(e)
    return f"{e.size:3d}  {np.median(e):+5.1f} / {np.median(a):4.1f} / {np.quantile(a, 0.9):5.1f} %"


def report(label: str, rows: list[dict]) -> None:
    print(f"{label}: n  median / median|error| / p90|error| (mpg, out of fold)")
    for c in mm.MHEV_CYCLES:
        line = f"  {c:9s} all {stats([r['error_pct'] for r in rows if r['cycle'] == c])}"
        for cls in mm.CLASSES:
            line += (
                f" | {cls} {stats([r['error_pct'] for r in rows if r['cycle'] == c and r['layout'] == cls])}"
            )
        print(line)
    print("  median error per system (n): " + ", ".join(mm.MHEV_CYCLES))
    for s in mm.SYSTEMS:
        parts = []
        for c in mm.MHEV_CYCLES:
            e = [r["error_pct"] for r in rows if r["cycle"] == c and r["system"] == s]
            e = [x for x in e if np.isfinite(x)]
            parts.append(f"{np.median(e):+6.1f} ({len(e):2d})" if e else "     -     ")
        print(f"    {s:9s} " + "  ".join(parts))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("list", help="the EPA test car list (22-tstcar.csv)")
    ap.add_argument("--csv", help="write the rows to this folder (mhev.csv, conv.csv)")
    ap.add_argument("--no-conventional", action="store_true", help="the mild-hybrid model only")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.FIELD=VALUE",
        help="a change to every mild hybrid's parameters (repeatable), e.g. engine.friction_coefficient=0.7",
    )
    ap.add_argument(
        "--converter",
        action="store_true",
        help="the torque-converter automatics with their converter (mhev.CONVERTER; the fleet: off)",
    )
    ap.add_argument(
        "--aspiration-classes",
        action="store_true",
        help="a class of its own for the aspirated belt-machine cars (mhev_p0_aspirated: the eTorque trucks)",
    )
    ap.add_argument(
        "--crank-accessories",
        action="store_true",
        help="fit the accessory load on the crank (engine.accessory_power) instead of the electric network",
    )
    ap.add_argument(
        "--accessory-max",
        type=float,
        default=None,
        metavar="W",
        help="the fitted accessory load's upper bound (W; the fleet: 3,000, the conventional classes' bound)",
    )
    a = ap.parse_args()
    if a.aspiration_classes:  # in this process only: the fleet's classes are the layouts
        layout_class = mm.mhev_class
        mm.CLASSES = (*mm.CLASSES, ASPIRATED)
        mm.mhev_class = lambda r: (
            ASPIRATED if layout_class(r) == "mhev_p0" and not r.boosted else layout_class(r)
        )
    if a.accessory_max is not None:  # in this process only
        mm.ACCESSORY_AXIS = mm.ACCESSORY_AXIS[mm.ACCESSORY_AXIS <= a.accessory_max]
        mm.fit_accessories_on("electric")
    if a.crank_accessories:
        mm.fit_accessories_on("engine")
    if a.csv:  # made (or refused) now, not after minutes of runs
        try:
            Path(a.csv).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            ap.error(f"--csv {a.csv}: cannot make that folder ({exc.strerror})")
    mm.CONVERTER = a.converter or mm.CONVERTER
    changes = {k: float(v) for k, _, v in (x.partition("=") for x in a.set)}
    cars = read_test_car_list(a.list)
    system = {v.key: v.system for v in cars.mhev_vehicles}
    key = {(v.vehicle_id, v.configuration): v.key for v in cars.mhev_vehicles}
    t0 = time.process_time()
    out = run_mhev(cars, changes=changes)
    rows = [{**r, "system": system[key[(r["vehicle_id"], r["configuration"])]]} for r in out["rows"]]
    conv_note = " with converters" if mm.CONVERTER else ""
    print(f"mild-hybrid model {changes or ''}{conv_note} (CPU {time.process_time() - t0:.0f} s)")
    report("  vpsim mild hybrid", rows)
    for name, t in out["technology"].items():
        print(f"    {name}: " + ", ".join(f"{k} {v:.4g}" for k, v in t.items() if isinstance(v, float)))
    if a.csv:
        import pandas as pd

        pd.DataFrame(rows).to_csv(f"{a.csv}/mhev.csv", index=False)
    if a.no_conventional:
        return
    t0 = time.process_time()
    conv, tech = run_conventional(cars, out["fold_of"], out["folds"])
    print(
        "the same records as conventional cars, fitted on the same folds and classes "
        f"(CPU {time.process_time() - t0:.0f} s)"
    )
    report("  vpsim conventional", conv)
    for (f, cls), t in sorted(tech.items()):
        print(f"    fold{f}.{cls}: " + ", ".join(f"{k} {t[k]:.4g}" for k in cal.TECH_PARAMS))
    if a.csv:
        import pandas as pd

        pd.DataFrame(conv).to_csv(f"{a.csv}/conv.csv", index=False)


if __name__ == "__main__":
    main()
