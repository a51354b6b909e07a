"""Fit the electric machine's normalised loss coefficients on ADVISOR's measured maps; print the LOO check.

    python benchmarks/machine_fit.py            # coefficients per kind and the leave-one-out table
    python benchmarks/machine_fit.py --json     # the same as JSON
    python benchmarks/machine_fit.py --no-cycles  # without the cycle-energy columns (no simulation)

Reads the six motor maps MC_*.m from ``../shared/data/raw/advisor`` (``$VPSIM_SHARED`` to override; they are
never copied into the repository) with :func:`vpsim.engines.machine_map.load_machine`.

Fit: for each file the rating comes from its envelope (peak power, corner speed P_max / T_max, highest
speed); every map point in the torque envelope of both quadrants with T != 0 and w != 0
(``MeasuredMachine.map_points``) gives one equation P_loss / P_r = sum_k c_k phi_k(tau, omega), where the
basis phi_k is :func:`vpsim.model.machine.loss_w` itself evaluated with one coefficient set to 1 and a
rating of 1 W (so the fit uses the model's one definition). The coefficients are the non-negative least
squares solution (scipy.optimize.nnls) over the pooled points of the files fitted; non-negative because
each term is a loss.

Pooling: the coefficients are fitted on the files of both kinds together. With two induction and four PM
maps, a fit per kind predicted the left-out file worse than the pooled fit (mean median error 3.8 against
2.9 points with the model's present normalisation), so both kinds ship the same coefficients; ``kind``
stays in the API for a future fit with more maps.

Leave-one-out: each file is predicted by coefficients fitted on the five *other* files, scaled to the file's
own rating. The figures per file: the median of |efficiency error| in percentage points over its map
points, and the cycle-energy error (UDDS, HWFET) of the battery-electric car of
``vpsim.powertrains.car_with_machine``: 100 (E_model - E_map) / E_map of the battery's energy with the
model at the file's rating and the LOO coefficients, against the same car with the measured map. The
``shipped`` columns repeat the cycle error with the shipped defaults, which have seen the file (what
``vpsim machine compare`` prints). The shipped defaults (vpsim.model.machine.DEFAULT_COEFFICIENTS) are the
fit on all six files.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import nnls

from vpsim.engines.machine_map import MeasuredMachine, load_machine
from vpsim.model import machine as machine_model
from vpsim.model.machine import (
    COEFFICIENT_NAMES,
    LossCoefficients,
    MachineSpec,
    efficiency_errors_pts,
    loss_w,
    machine_record,
)

FILES = {
    "MC_AC59": "induction",
    "MC_AC75": "induction",
    "MC_PM32": "pm",
    "MC_PM49": "pm",
    "MC_PM58": "pm",
    "MC_PRIUS_JPN": "pm",
}
REPO = Path(__file__).resolve().parents[1]
CYCLES = ("udds", "hwfet")


def advisor_dir() -> Path:
    return Path(os.environ.get("VPSIM_SHARED", REPO.parent / "shared")) / "data" / "raw" / "advisor"


def load_all(folder: Path | None = None) -> dict[str, MeasuredMachine]:
    folder = folder or advisor_dir()
    return {name: load_machine(folder / f"{name}.m") for name in FILES}


def design(machine: MeasuredMachine) -> tuple[np.ndarray, np.ndarray]:
    """(basis, target): one row per map point, columns the normalised loss terms, target P_loss / P_r."""
    t, w, eff = machine.map_points()
    p_mech = t * w
    loss = np.where(p_mech > 0, p_mech / eff - p_mech, -p_mech * (1.0 - eff))
    columns = []
    for name in COEFFICIENT_NAMES:
        unit = LossCoefficients(**{k: float(k == name) for k in COEFFICIENT_NAMES})
        spec = MachineSpec.from_measured(machine, coefficients=unit)
        columns.append(loss_w(t, w, machine_record(spec)) / spec.rated_power_w)
    return np.column_stack(columns), loss / machine.rated_power_w


def fit(machines: list[MeasuredMachine]) -> LossCoefficients:
    rows = [design(m) for m in machines]
    basis = np.vstack([r[0] for r in rows])
    target = np.concatenate([r[1] for r in rows])
    c, _ = nnls(basis, target)
    return LossCoefficients(**dict(zip(COEFFICIENT_NAMES, (float(x) for x in c), strict=True)))


def training_set(name: str) -> list[str]:
    """The files a left-out file is predicted from: all the others, both kinds (see the module docstring)."""
    return [o for o in FILES if o != name]


def fitted_defaults(machines: dict[str, MeasuredMachine]) -> dict[str, LossCoefficients]:
    pooled = fit([machines[n] for n in FILES])
    return {k: pooled for k in sorted(set(FILES.values()))}


@contextlib.contextmanager
def _defaults_of(kind: str, coeffs: LossCoefficients):
    """The car of ``car_with_machine`` takes a machine's rating and kind, not its coefficients (the
    parameter file has none): swap the kind's defaults while it is built and simulated."""
    table = machine_model.DEFAULT_COEFFICIENTS
    old = table[kind]
    table[kind] = coeffs
    try:
        yield
    finally:
        table[kind] = old


def cycle_energy_errors_pct(m: MeasuredMachine, kind: str, coeffs: LossCoefficients) -> dict[str, float]:
    """100 (E_model - E_map) / E_map of the battery energy per cycle, the model with ``coeffs``."""
    from vpsim.powertrains import cycle_battery_energy_j

    spec = MachineSpec.from_measured(m, kind=kind, coefficients=coeffs)
    out = {}
    for cycle in CYCLES:
        e_map = cycle_battery_energy_j(cycle, m)
        with _defaults_of(kind, coeffs):
            e_model = cycle_battery_energy_j(cycle, spec)
        out[cycle] = 100.0 * (e_model - e_map) / e_map
    return out


def own_fit_error_pts(m: MeasuredMachine, kind: str) -> float:
    """The median |efficiency error| (points) of the model fitted on the file itself: what the model's form
    can reach on that map at best (by this fit's objective), the floor under its leave-one-out figure."""
    err, _, _ = efficiency_errors_pts(m, MachineSpec.from_measured(m, kind=kind, coefficients=fit([m])))
    return float(np.median(np.abs(err)))


def leave_one_out(machines: dict[str, MeasuredMachine], cycles: bool = False) -> list[dict]:
    """One row per file: its LOO efficiency figures and, with ``cycles``, its LOO and shipped cycle-energy
    errors (``cycle_energy_error_pct`` and ``shipped_cycle_energy_error_pct``)."""
    rows = []
    shipped = fitted_defaults(machines) if cycles else {}
    for name, kind in FILES.items():
        train = training_set(name)
        coeffs = fit([machines[o] for o in train])
        m = machines[name]
        err, _, _ = efficiency_errors_pts(m, MachineSpec.from_measured(m, kind=kind, coefficients=coeffs))
        row = {
            "file": name,
            "kind": kind,
            "rated_power_kw": m.rated_power_w / 1e3,
            "base_speed_rpm": m.base_speed_radps * 30 / math.pi,
            "max_speed_rpm": m.max_speed_radps * 30 / math.pi,
            "fitted_on": train,
            "n_points": int(err.size),
            "median_abs_efficiency_error_pts": float(np.median(np.abs(err))),
            "max_abs_efficiency_error_pts": float(np.max(np.abs(err))),
            "own_fit_median_abs_efficiency_error_pts": own_fit_error_pts(m, kind),
        }
        if cycles:
            row["cycle_energy_error_pct"] = cycle_energy_errors_pct(m, kind, coeffs)
            row["shipped_cycle_energy_error_pct"] = cycle_energy_errors_pct(m, kind, shipped[kind])
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print JSON instead of tables")
    ap.add_argument("--no-cycles", action="store_true", help="skip the cycle-energy errors (no simulation)")
    args = ap.parse_args(argv)
    folder = advisor_dir()
    if not folder.is_dir():
        print(f"machine_fit: reference data not found at {folder} (set VPSIM_SHARED)", file=sys.stderr)
        return 2
    machines = load_all(folder)
    defaults = fitted_defaults(machines)
    cycles = not args.no_cycles
    loo = leave_one_out(machines, cycles=cycles)
    if args.json:
        out = {"defaults": {k: c.as_dict() for k, c in defaults.items()}, "leave_one_out": loo}
        print(json.dumps(out, indent=2))
        return 0
    print("Default coefficients (fitted on all six files, both kinds pooled):")
    for kind, c in defaults.items():
        print(f"  {kind:9s} " + ", ".join(f"{k}={v:.6g}" for k, v in c.as_dict().items()))
    print()
    head = (
        "| file | kind | rating kW | base rpm | max rpm | points | median abs error (pts) | max | own fit |"
    )
    rule = "|---|---|---:|---:|---:|---:|---:|---:|---:|"
    if cycles:
        head += " LOO udds % | LOO hwfet % | shipped udds % | shipped hwfet % |"
        rule += "---:|---:|---:|---:|"
    print(head)
    print(rule)
    for r in loo:
        line = (
            f"| {r['file']} | {r['kind']} | {r['rated_power_kw']:.1f} | {r['base_speed_rpm']:.0f} | "
            f"{r['max_speed_rpm']:.0f} | {r['n_points']} | "
            f"{r['median_abs_efficiency_error_pts']:.2f} | {r['max_abs_efficiency_error_pts']:.1f} | "
            f"{r['own_fit_median_abs_efficiency_error_pts']:.2f} |"
        )
        if cycles:
            loo_c, ship_c = r["cycle_energy_error_pct"], r["shipped_cycle_energy_error_pct"]
            line += "".join(f" {d[c]:+.1f} |" for d in (loo_c, ship_c) for c in CYCLES)
        print(line)
    print()
    print("Each file's efficiency and LOO cycle figures come from the fit on the five other files;")
    print("the shipped columns use the defaults, fitted on all six (they have seen the file); own fit: the")
    print("model fitted on the file alone, the floor the model's form reaches on that map.")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
