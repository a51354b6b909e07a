"""The 2022 EVs' UDDS residuals: the fleet's EV part re-run with one physical change at a time (not shipped).

    python benchmarks/ev_udds_variants.py ../shared/data/epa/22-tstcar.csv base no_spin_pm regen_low
    python benchmarks/ev_udds_variants.py LIST base --csv DIR   # also the per-vehicle rows, DIR/<variant>.csv

Reproduces docs/fleet.md's "UDDS residuals" paragraph. Each variant runs exactly the fleet run's EV part
(``vpsim.fleet.run._run_evs``: the same family folds, classes, technology grid and fit, one backward run per
vehicle and test, no peer) with one change made in this process only:

* ``base``: the shipped model;
* ``no_spin_pm``: a coast-down in neutral keeps an EV's machine coupled to the wheels, so the target road
  load already holds a permanent-magnet machine's no-load loss (the magnets' iron loss, bearings,
  windage): the loss model's speed-only terms (k_fe_h, k_fe_e, k_mech) dropped for every machine run as
  kind ``pm`` (the EESMs included, as the fleet runs them);
* ``no_spin_pm_magnets``: the same for the magnet machines only: the EESMs (no field current in neutral,
  so no iron loss in the coast-down) keep the whole loss model;
* ``no_spin_magnets_windage``: as ``no_spin_pm_magnets``, and machines without magnets (induction, EESM)
  drop their windage term k_mech only;
* ``regen_low``: regeneration down to 0.5 m/s (full share above it; the preset: 1-3 m/s);
* ``wheel_inertia``: the driven wheels' inertia on the dynamometer (1.2 kg m^2 per wheel and tyre; two
  wheels on a two-wheel-drive roll, four on an all-wheel-drive one) added to the rotor's;
* ``no_spin_pm+regen_low``: both;
* ``no_spin_all``: the speed-only terms dropped for every machine, the induction machines too (the argument
  for a machine without magnets: no flux at zero torque, so no no-load iron loss, and its bearings and
  windage in the coast-down);
* ``regen_share_0.8``: the machine takes 80 % of a braking demand (blending that leaves a fifth to the
  friction brakes; the preset: all of it);
* ``drive_eff_0.93``, ``drive_eff_0.90``: the drive's efficiency (``transmission.efficiency``: the
  reduction's, and the loss proportional to the power passed that the loss model does not carry) at that
  value for every car (the preset: 0.97), with the two-parameter fit;
* ``two_parameter``: the fit before the drive efficiency became its third parameter (2026-12-07): the loss
  scale and the accessories, the drive at the preset's 0.97.

``base`` is the shipped three-parameter fit; every other variant changes one thing on it, except the
``drive_eff_*`` and ``two_parameter`` variants, which run the two-parameter fit (as every variant did
before 2026-12-07, when docs/fleet.md's table of them was measured).

Prints per variant the UDDS and highway n / median / median |error| / p90 |error| (MPGe, out of fold) and the
per-class UDDS median |error|; CPU seconds per variant.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from vpsim.fleet import calibrate as cal
from vpsim.fleet import ev
from vpsim.fleet import run as fleet_run
from vpsim.fleet.epa import read_test_car_list
from vpsim.model import machine as mc

J_WHEEL_KGM2 = 1.2
SPIN = ("k_fe_h", "k_fe_e", "k_mech")
VARIANTS = (
    "base",
    "no_spin_pm",
    "no_spin_pm_magnets",
    "no_spin_magnets_windage",
    "regen_low",
    "wheel_inertia",
    "no_spin_pm+regen_low",
    "no_spin_all",
    "regen_share_0.8",
    "drive_eff_0.93",
    "drive_eff_0.90",
    "two_parameter",
)


def _coefficients(variant: str) -> dict:
    base = dict(mc.DEFAULT_COEFFICIENTS)
    if "no_spin" in variant:
        base["pm"] = replace(base["pm"], **{k: 0.0 for k in SPIN})
    if variant == "no_spin_all":
        base["induction"] = replace(base["induction"], **{k: 0.0 for k in SPIN})
    if variant == "no_spin_magnets_windage":
        base["induction"] = replace(base["induction"], k_mech=0.0)
    return base


def _parameters(variant: str, shipped):
    def build(rec, technology=None):
        p = shipped(rec, technology)
        if variant in ("no_spin_pm_magnets", "no_spin_magnets_windage") and ev.ev_class(rec) == "bev_eesm":
            # the kinds share one coefficient set: "induction" keeps the EESM's whole loss model
            p = p.with_changes(machine={"kind": "induction"})
        if variant == "regen_share_0.8":
            p = p.with_changes(electric={"regen_share": 0.8})
        if variant.startswith("drive_eff_"):
            p = p.with_changes(transmission={"efficiency": float(variant.rsplit("_", 1)[1])})
        if variant.endswith("regen_low"):
            p = p.with_changes(electric={"regen_speed_low": 0.0, "regen_speed_high": 0.5})
        if variant == "wheel_inertia":
            n = 4 if rec.drive.strip().upper() in ev.AWD_CODES else 2
            j = p.machine.inertia + n * J_WHEEL_KGM2 / p.transmission.final_drive**2
            p = p.with_changes(machine={"inertia": j})
        return p

    return build


def run_variant(cars, variant: str) -> list[dict]:
    shipped_params, shipped_coeff = ev.ev_parameters, dict(mc.DEFAULT_COEFFICIENTS)
    shipped_fit = (ev.TECH_PARAMS, ev.grid_chunk, ev.fit, ev.on_bounds)
    try:
        mc.DEFAULT_COEFFICIENTS.update(_coefficients(variant))
        ev.ev_parameters = _parameters(variant, shipped_params)
        if variant.startswith("drive_eff_") or variant.startswith("two_parameter"):
            # the fit as it was before the drive efficiency became its third parameter: the loss scale and
            # the accessories only (the drive efficiency the variant's, or the preset's)
            ev.TECH_PARAMS = ev.TECH_PARAMS[:2]
            ev.grid_chunk = _two_parameter_grid_chunk
            ev.fit, ev.on_bounds = ev.GRID.fit, ev.GRID.on_bounds
        out = fleet_run._run_evs(cars.ev_vehicles, cal.FoldSpec(5), fleet_run._Serial(), {}, False, {})
    finally:
        ev.ev_parameters = shipped_params
        mc.DEFAULT_COEFFICIENTS.update(shipped_coeff)
        ev.TECH_PARAMS, ev.grid_chunk, ev.fit, ev.on_bounds = shipped_fit
    by_key = {(v.vehicle_id, v.configuration): ev.ev_class(v) for v in cars.ev_vehicles}
    return [{**r, "class": by_key[(r["vehicle_id"], r["configuration"])]} for r in out["rows"]]


def _two_parameter_grid_chunk(items):
    return ev.GRID.grid_chunk(items, lambda rec, _: ev.ev_parameters(rec), ev._wall_of, "log_wall", "energy")


def _stats(errors) -> str:
    e = np.asarray([x for x in errors if np.isfinite(x)])
    a = np.abs(e)
    return f"{e.size:3d}  {np.median(e):+5.1f} / {np.median(a):4.2f} / {np.quantile(a, 0.9):5.2f} %"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("list", help="the EPA test car list (22-tstcar.csv)")
    ap.add_argument("variants", nargs="*", default=list(VARIANTS), choices=VARIANTS)
    ap.add_argument("--csv", help="write each variant's rows to this folder")
    a = ap.parse_args()
    if a.csv:  # made (or refused) now, not after minutes of runs
        try:
            Path(a.csv).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            ap.error(f"--csv {a.csv}: cannot make that folder ({exc.strerror})")
    cars = read_test_car_list(a.list)
    for variant in a.variants:
        t0 = time.process_time()
        rows = run_variant(cars, variant)
        cpu = time.process_time() - t0
        print(f"{variant}: n  median / median|error| / p90|error| (MPGe, out of fold; CPU {cpu:.0f} s)")
        for cyc in ev.EV_CYCLES:
            print(f"  {cyc:5s} {_stats([r['error_pct'] for r in rows if r['cycle'] == cyc])}")
        for cls in ev.CLASSES:
            e = [r["error_pct"] for r in rows if r["cycle"] == "udds" and r["class"] == cls]
            if e:
                print(f"  udds {cls:14s} {_stats(e)}")
        if a.csv:
            import pandas as pd

            pd.DataFrame(rows).to_csv(f"{a.csv}/{variant.replace('+', '_')}.csv", index=False)


if __name__ == "__main__":
    main()
