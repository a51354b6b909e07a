"""FASTSim 3.1's battery-electric peer on the EPA 2022 list's electric records (vpsim.fleet.peer_bev).

    python benchmarks/peer_bev.py ../shared/data/epa/22-tstcar.csv [--no-calibrated] [--repeat 30]

Prints how the records pair up, FASTSim's BEV with its defaults against the measured unadjusted MPGe
(median error, median |error|, 90th percentile of |error|, per cycle), the calibrated peer's errors out of
fold (5 folds, the configurations of one test vehicle held out together), and the time of one FASTSim BEV
UDDS run (``SimDrive.run()`` only; median of repeated runs, with the spread).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from vpsim.fleet import peer_bev as pb

CYCLES = {"udds": "udds_mpge", "hwfet": "hwy_mpge"}


def errors_line(label: str, pred, meas) -> str:
    e = 100.0 * (np.asarray(pred) / np.asarray(meas) - 1.0)
    e = e[np.isfinite(e)]
    a = np.abs(e)
    return (
        f"{label:<28} n={e.size:3d}  median {np.median(e):+6.1f} %  median |err| {np.median(a):5.1f} %  "
        f"p90 |err| {np.percentile(a, 90):5.1f} %"
    )


def run_fleet(df, tech_of=None) -> dict:
    items = [(row, c, None if tech_of is None else tech_of(i)) for i, row in df.iterrows() for c in CYCLES]
    return {(r["key"], r["cycle"]): r for r in pb.bev_peer_chunk(items)}


def report(df, rows, label: str) -> None:
    for c, col in CYCLES.items():
        pred = [rows[(pb._key(r), c)]["mpge"] for _, r in df.iterrows()]
        print(errors_line(f"{label} {c}", pred, df[col]))
    misses = [k for k, r in rows.items() if r.get("trace_miss")]
    errs = [k for k, r in rows.items() if r["peer_error"]]
    print(f"  trace misses: {len(misses)} runs {sorted({k for k, _ in misses})}; errors: {len(errs)}")


def time_udds(row, repeat: int) -> list[float]:
    import fastsim as fsim

    veh = fsim.Vehicle.from_dict(pb.bev_peer_vehicle(*(row[k] for k in pb.EV_COLUMNS[4:9])))
    cyc = pb._fastsim_cycle("udds")
    params = pb._sim_params()
    out = []
    for _ in range(repeat + 1):
        sd = fsim.SimDrive(veh, cyc, params)
        t0 = time.perf_counter()
        sd.run()
        out.append((time.perf_counter() - t0) * 1e3)
    return out[1:]  # the first is a warm-up


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("csv")
    ap.add_argument("--no-calibrated", action="store_true")
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--folds", type=int, default=5)
    args = ap.parse_args(argv)

    rep: dict = {}
    df = pb.ev_records(args.csv, rep)
    print(
        f"{rep['n_rows']} charge-depleting UDDS/HWY rows on electricity, {rep['n_vehicles']} vehicles, "
        f"{rep['n_paired']} paired ({int(df['fe_in_kwh_per_100mi'].sum())} of them listed in kWh/100 mi, "
        f"converted; {int((df['n_udds'] > 1).sum())} with repeated tests, averaged)"
    )
    for name, why in rep["unpaired"]:
        print(f"  not paired: {name}: {why}")

    t0 = time.perf_counter()
    rows = run_fleet(df)
    print(f"FASTSim BEV, defaults ({pb.PEER_BEV_VEHICLE}), {time.perf_counter() - t0:.1f} s:")
    report(df, rows, "fastsim")

    if not args.no_calibrated:
        from vpsim.fleet.calibrate import assign_folds

        t0 = time.perf_counter()
        keys = [pb._key(r) for _, r in df.iterrows()]
        groups = {pb._key(r): r["test_vehicle_id"] for _, r in df.iterrows()}
        fold_of = assign_folds(keys, args.folds, groups=groups)
        cal = {
            (r["key"], r["cycle"]): r
            for r in pb.bev_calibration_chunk([(r, c) for _, r in df.iterrows() for c in CYCLES])
        }
        ok = [i for i, k in enumerate(keys) if all(cal[(k, c)]["log_wh_per_km"] is not None for c in CYCLES)]
        grid = np.array([cal[(keys[i], c)]["log_wh_per_km"] for i in ok for c in CYCLES])
        meas = np.log([pb.wh_per_km_from_mpge(df.iloc[i][col]) for i in ok for col in CYCLES.values()])
        folds = np.array([fold_of[keys[i]] for i in ok for _ in CYCLES])
        tech = pb.calibrate_bev_peer(grid, meas, folds, args.folds)
        for (f, cls), t in sorted(tech.items()):
            print(
                f"  fold {f} {cls}: scale {t['drivetrain_efficiency_scale']:.3f}  "
                f"accessories {t['accessory_power_w']:.0f} W  train loss {t['train_loss']:.4f}"
            )

        def tech_of(i):
            t = tech[(fold_of[keys[i]], "bev")]
            return {p: t[p] for p in pb.BEV_PEER_PARAMS}

        rows_cal = run_fleet(df, tech_of)
        print(f"FASTSim BEV, calibrated out of fold ({time.perf_counter() - t0:.1f} s):")
        report(df, rows_cal, "fastsim_calibrated")

    ms = time_udds(df.iloc[0], args.repeat)
    q = np.percentile(ms, [10, 90])
    print(
        f"one FASTSim BEV UDDS run (SimDrive.run): median {statistics.median(ms):.1f} ms over {len(ms)} runs "
        f"(min {min(ms):.1f}, p10 {q[0]:.1f}, p90 {q[1]:.1f}, max {max(ms):.1f} ms)"
    )


if __name__ == "__main__":
    main()
