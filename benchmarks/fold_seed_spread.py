"""How much the fleet's headline figures move with the deal of families into folds (not shipped).

    python benchmarks/fold_seed_spread.py ../shared/data/epa/22-tstcar.csv            # seeds 0-9
    python benchmarks/fold_seed_spread.py LIST --seeds 20 --workers 2
    python benchmarks/fold_seed_spread.py LIST --part mhev     # the mild hybrids (also: hev, bev)
    python benchmarks/fold_seed_spread.py LIST --deal hash     # the hash deal (calibrate.assign_folds)
    python benchmarks/fold_seed_spread.py LIST --deal blocks   # the hash order cut into equal blocks
    python benchmarks/fold_seed_spread.py LIST --drop-families 3 --draws 5   # a list with fewer families

``vpsim fleet`` deals the vehicle families into 5 folds in an order shuffled with one fixed seed
(:data:`vpsim.fleet.calibrate.SEED`), fits each class's technology without the fold and predicts the fold.
A different seed is an equally valid deal; the spread of the figures over seeds is the part of a headline
figure that comes from the deal, not from the model. This runs exactly the fleet's conventional part
(:mod:`vpsim.fleet.run`: the technology grid once, then per seed the folds, the cross-validated fit and the
backward predictions), without the peer, for the fleet's own seed and ``--seeds`` others (0, 1, ...), and
prints per test the median error, median |error| and 90th percentile |error| (mpg, out of fold) at the
fleet's seed, and their range and standard deviation over all seeds.

``--part mhev``, ``hev`` or ``bev`` does the same for the fleet's mild-hybrid, full-hybrid or
battery-electric part (:mod:`vpsim.fleet.run_electrified`: its grid once, then per seed its folds over its
own families, the fit per class out of fold and one real run per vehicle and test; MPGe for the EVs). The
small parts have 39-61 families in 5 folds, so a deal moves them more than the engine cars' 488.

``--drop-families N`` (engine cars): how far the headline moves when the list holds N families fewer (as
when the reader learns, or stops, to read a family), the rest unchanged. For each of ``--draws`` random
choices of N families (a fixed generator), the fleet's seed deals the smaller list and the fit and
predictions are made again; printed is the change of each test's median |error| *on the vehicles both lists
hold*, for every deal side by side (shuffle, hash, blocks). Under the shuffle most families change fold;
under the hash none does, so what moves there is the fit's loss of the dropped families alone; under the
blocks a few at the blocks' edges do.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from vpsim.fleet import calibrate as cal
from vpsim.fleet import run as fleet_run
from vpsim.fleet.cycles import FLEET_CYCLES
from vpsim.fleet.epa import mpg_from_l_per_100km, read_test_car_list
from vpsim.fleet.report import error_stats


def figures(errors: np.ndarray) -> tuple[float, float, float]:
    a = np.abs(errors)
    return float(np.median(errors)), float(np.median(a)), float(np.quantile(a, 0.9))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("list", help="the EPA test car list (22-tstcar.csv)")
    ap.add_argument("--seeds", type=int, default=10, help="other seeds to deal with: 0 .. N-1 (default 10)")
    ap.add_argument("--workers", type=int, default=2, help="local processes for the runs (default 2)")
    ap.add_argument(
        "--part", choices=("conventional", "mhev", "hev", "bev"), default="conventional", help="fleet part"
    )
    ap.add_argument("--deal", choices=cal.DEALS, default=cal.DEFAULT_DEAL, help="how families are dealt")
    ap.add_argument("--drop-families", type=int, default=0, help="engine cars: N families fewer (see above)")
    ap.add_argument("--draws", type=int, default=5, help="random choices of the dropped families (default 5)")
    a = ap.parse_args()
    if a.seeds < 1 or a.workers < 1:
        ap.error("--seeds and --workers must be at least 1")
    if a.drop_families < 0 or a.draws < 1:
        ap.error("--drop-families must be 0 or more and --draws at least 1")
    t0 = time.perf_counter()
    cars = read_test_car_list(a.list)
    if a.part != "conventional":
        if a.drop_families:
            ap.error("--drop-families is measured on the engine cars (the default --part)")
        electrified(cars, a.part, [cal.SEED, *range(a.seeds)], a.workers, t0, a.deal)
        return
    vehicles = [v for v in cars.vehicles if any(c in v.measured_mpg for c in FLEET_CYCLES)]
    groups = cal.vehicle_groups(vehicles, "family")
    work = [(v, tuple(c for c in FLEET_CYCLES if c in v.measured_mpg)) for v in vehicles]
    chunks = [work[i : i + fleet_run.CHUNK] for i in range(0, len(work), fleet_run.CHUNK)]
    by_key = {v.key: v for v in vehicles}
    seeds = [cal.SEED, *range(a.seeds)]
    table: dict[str, list[tuple[float, float, float]]] = {c: [] for c in FLEET_CYCLES}
    executor = fleet_run._Pool(a.workers) if a.workers > 1 else fleet_run._Serial()
    with executor:
        grid_rows = [r for part in executor.map(fleet_run.grid_chunk, chunks) for r in part]
        ok = [r for r in grid_rows if r["log_fuel"] is not None]
        lg, meas, vclass, per_watt = fleet_run.fit_inputs(ok, by_key, FLEET_CYCLES)
        gears = {(r["key"], r["cycle"]): r["gear"] for r in ok}
        header("conventional", vehicles, groups, ok, t0)
        if a.drop_families:
            dropped(vehicles, groups, ok, lg, meas, vclass, per_watt, gears, executor, a, t0)
            return
        for seed in seeds:
            errs = conventional_errors(
                vehicles, seed, groups, ok, lg, meas, vclass, per_watt, gears, executor, a.deal
            )
            line = []
            for c in FLEET_CYCLES:
                f = figures(np.array(list(errs[c].values())))
                table[c].append(f)
                line.append(f"{c} {f[0]:+.2f} / {f[1]:.2f} / {f[2]:.2f}")
            print(f"  seed {seed:>5}: " + "; ".join(line))
    summary(table, {c: sum(1 for r in ok if r["cycle"] == c) for c in FLEET_CYCLES}, len(seeds), t0)


def conventional_errors(vehicles, seed, groups, ok, lg, meas, vclass, per_watt, gears, executor, scheme):
    """The engine cars' out-of-fold errors (% of mpg) dealt with ``seed``: {test: {key: error}}. ``vehicles``
    may be a part of the list: the grid rows of the others are left out of the fit."""
    keys = {v.key for v in vehicles}
    take = np.array([r["key"] in keys for r in ok])
    rows = [r for r, t in zip(ok, take, strict=True) if t]
    by_key = {v.key: v for v in vehicles}
    fold_of, vfold = deal(vehicles, seed, groups, rows, scheme)
    sub_class = vclass[take]
    tech = cal.cross_validate(lg[take], meas[take], vfold, sub_class, 5, per_watt[take])
    items = [
        (by_key[r["key"]], r["cycle"], tech[(fold_of[r["key"]], sub_class[i])], gears[(r["key"], r["cycle"])])
        for i, r in enumerate(rows)
    ]
    step = fleet_run.CHUNK * 2
    pch = [items[i : i + step] for i in range(0, len(items), step)]
    preds = [p for part in executor.map(fleet_run.predict_chunk, pch, "backward") for p in part]
    errs: dict[str, dict[str, float]] = {c: {} for c in FLEET_CYCLES}
    for (v, c, _, _), p in zip(items, preds, strict=True):
        if not p["error"]:
            mpg = mpg_from_l_per_100km(p["predicted_l_per_100km"])
            errs[c][v.key] = 100.0 * (mpg / v.measured_mpg[c] - 1.0)
    return errs


def dropped(vehicles, groups, ok, lg, meas, vclass, per_watt, gears, executor, a, t0) -> None:
    """``--drop-families``: the change of each test's median |error| on the common vehicles, per deal."""
    families = sorted(set(groups.values()))
    rng = np.random.default_rng(0)
    args = (ok, lg, meas, vclass, per_watt, gears, executor)
    full = {d: conventional_errors(vehicles, cal.SEED, groups, *args, d) for d in cal.DEALS}
    print(f"  {a.drop_families} of {len(families)} families dropped, {a.draws} draws; the fleet's seed")
    print(
        "  change of median |error| on the vehicles both lists hold (points), per test: "
        + ", ".join(FLEET_CYCLES)
    )
    moved = {d: [] for d in cal.DEALS}
    for draw in range(a.draws):
        gone = set(rng.choice(families, size=a.drop_families, replace=False))
        rest = [v for v in vehicles if groups[v.key] not in gone]
        line = []
        for d in cal.DEALS:
            errs = conventional_errors(rest, cal.SEED, groups, *args, d)
            deltas = []
            for c in FLEET_CYCLES:
                common = sorted(errs[c])
                before = np.median(np.abs([full[d][c][k] for k in common]))
                after = np.median(np.abs([errs[c][k] for k in common]))
                deltas.append(after - before)
            moved[d].append(deltas)
            before_f = cal.assign_folds([v.key for v in vehicles], 5, cal.SEED, groups, d)
            after_f = cal.assign_folds([v.key for v in rest], 5, cal.SEED, groups, d)
            fams = {groups[v.key] for v in rest}
            moved_fams = {groups[v.key] for v in rest if before_f[v.key] != after_f[v.key]}
            line.append(
                f"{d} " + " ".join(f"{x:+.3f}" for x in deltas) + f" ({len(moved_fams)}/{len(fams)} moved)"
            )
        print(f"  draw {draw}: " + "   ".join(line), flush=True)
    for d in cal.DEALS:
        x = np.abs(np.array(moved[d]))
        print(
            f"  {d:8s} largest |change| per test: "
            + " ".join(f"{m:.3f}" for m in x.max(axis=0))
            + f"; mean over tests and draws {x.mean():.3f} points"
        )
    print(f"{time.perf_counter() - t0:.0f} s wall")


def header(part: str, recs, groups: dict, ok: list, t0: float) -> None:
    print(
        f"{part}: {len(recs)} vehicles, {len(set(groups.values()))} families, {len(ok)} rows; "
        f"grid {time.perf_counter() - t0:.0f} s"
    )


def deal(recs, seed: int, groups: dict, ok: list, scheme: str = cal.DEFAULT_DEAL) -> tuple[dict, np.ndarray]:
    """The fleet's 5 folds dealt with ``seed``: (fold of each record's key, fold of each grid row)."""
    fold_of = cal.assign_folds([v.key for v in recs], 5, seed=seed, groups=groups, deal=scheme)
    return fold_of, np.array([fold_of[r["key"]] for r in ok])


def summary(table: dict, n: dict, n_seeds: int, t0: float) -> None:
    print("median / median |error| / p90 |error| (%): the fleet's seed; over all seeds min-max (std)")
    for c, rows in table.items():
        x = np.array(rows)
        parts = [
            f"{x[0, j]:+.2f} [{x[:, j].min():+.2f} .. {x[:, j].max():+.2f}] ({x[:, j].std(ddof=1):.2f})"
            for j in range(3)
        ]
        print(f"  {c:9s} n {n[c]:4d}  " + "  ".join(parts))
    print(f"{n_seeds} deals, {time.perf_counter() - t0:.0f} s wall")


def electrified(
    cars, part: str, seeds: list[int], workers: int, t0: float, scheme: str = cal.DEFAULT_DEAL
) -> dict:
    """The fleet's ``part`` (``mhev``, ``hev`` or ``bev``) as :func:`vpsim.fleet.run_electrified` runs it,
    dealt with each seed: the figures its ``by_powertrain`` block reports (vpsim's, without the peer).
    Returns {test: [(median, median |error|, p90 |error|) per seed]}."""
    from vpsim.fleet import ev as evm
    from vpsim.fleet import hev as hvm
    from vpsim.fleet import mhev as mhm
    from vpsim.fleet.run import _log_l100
    from vpsim.fleet.run_electrified import EV_CHUNK, HEV_CHUNK, _fit_classes, _predict

    if part == "bev":
        hm, recs, cycles, class_fn, chunk = evm, cars.ev_vehicles, evm.EV_CYCLES, evm.ev_class, EV_CHUNK
        measured = {v.key: v.measured_mpge for v in recs}
        grid_key = "log_wall"

        def log_measured(v, c):
            return math.log(evm.wall_wh_per_km(v.measured_mpge[c]))

        def economy(pred):
            return pred["mpge"]
    else:
        hm = mhm if part == "mhev" else hvm
        recs = cars.mhev_vehicles if part == "mhev" else cars.hev_vehicles
        cycles = mhm.MHEV_CYCLES if part == "mhev" else hvm.HEV_CYCLES
        class_fn = mhm.mhev_class if part == "mhev" else hvm.hev_class
        chunk, grid_key = HEV_CHUNK, "log_fuel"
        measured = {v.key: v.measured_mpg for v in recs}

        def log_measured(v, c):
            return _log_l100(v.measured_mpg[c])

        def economy(pred):
            return mpg_from_l_per_100km(pred["l_per_100km_cs"])

    recs = [v for v in recs if any(c in measured[v.key] for c in cycles)]
    groups = cal.vehicle_groups(recs, "family", labels=hm.family_labels)
    work = [(v, tuple(c for c in cycles if c in measured[v.key])) for v in recs]
    by_key = {v.key: v for v in recs}
    class_of = {v.key: class_fn(v) for v in recs}
    table: dict[str, list[tuple[float, float, float]]] = {c: [] for c in cycles}
    executor = fleet_run._Pool(workers) if workers > 1 else fleet_run._Serial()
    with executor:
        chunks = [work[i : i + chunk] for i in range(0, len(work), chunk)]
        grid_rows = [r for p in executor.map(hm.grid_chunk, chunks) for r in p]
        ok = [r for r in grid_rows if r[grid_key] is not None]
        failed = {(r["key"], r["cycle"]): r["error"] for r in grid_rows if r[grid_key] is None}
        grid = np.stack([r[grid_key] for r in ok])
        meas = np.array([log_measured(by_key[r["key"]], r["cycle"]) for r in ok])
        header(part, recs, groups, ok, t0)
        for seed in seeds:
            fold_of, _ = deal(recs, seed, groups, ok, scheme)
            tech = _fit_classes(hm, grid, meas, ok, class_of, fold_of, 5, {})  # the fleet part's own fit
            preds = _predict(executor, hm.predict_chunk, work, failed, tech, fold_of, class_of, 4 * chunk)
            line = []
            for c in cycles:
                errs = [
                    100.0 * (economy(p) / measured[v.key][c] - 1.0)
                    for v, cs in work
                    if c in cs and (p := preds.get((v.key, c))) is not None and not p.get("error")
                ]
                st = error_stats(errs)
                f = (st["median_error_pct"], st["median_abs_error_pct"], st["p90_abs_error_pct"])
                table[c].append(f)
                line.append(f"{c} {f[0]:+.2f} / {f[1]:.2f} / {f[2]:.2f}")
            print(f"  seed {seed:>5}: " + "; ".join(line), flush=True)
    summary(table, {c: sum(1 for r in ok if r["cycle"] == c) for c in cycles}, len(seeds), t0)
    return table


if __name__ == "__main__":
    main()
