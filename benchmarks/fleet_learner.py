"""How much of the fleet's error could any function of the record's fields remove? A learner's bound.

    vpsim fleet 22-tstcar.csv --out fleet/             # the model's out-of-fold predictions
    pip install scikit-learn                           # for this script only; not a vpsim dependency
    python benchmarks/fleet_learner.py fleet/ 22-tstcar.csv

A gradient-boosted tree ensemble (scikit-learn's ``HistGradientBoostingRegressor``) is given the fields the
model is built from (test mass, road load A/B/C, displacement, cylinders, rated power, transmission type,
gears, N/V and axle ratio, boosted) and learns, out of fold, either the model's error (log of predicted over
measured mpg: "the model corrected") or the measured mpg itself ("the learner alone", no physics). Three
ways to hold rows out, five folds each:

* ``vehicle``: the fleet's own folds (by test vehicle, as the issue asks of the model). A learner then sees
  the same car model in other configurations and test vehicles, so it can look up a sibling's measurement.
* ``family``: by make and the model name's first word (every 911, every Civic held out together).
* ``manufacturer``: by the record's manufacturer.

The model's technology (three parameters per class) cannot learn a sibling's measurement, so its errors
hardly depend on the folds; a learner's do. Prints a Markdown table of median / 90th percentile |error|.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

CYCLES = ("ftp_bag2", "ftp_bag3", "hwy", "us06")
FEATURES = (
    "test_mass_kg",
    "road_load_a",
    "road_load_b",
    "road_load_c",
    "displacement_l",
    "cylinders",
    "rated_power_kw",
    "transmission_code",
    "n_gears",
    "nv_ratio",
    "axle_ratio",
    "boosted",
)
SCHEMES = ("vehicle", "family", "manufacturer")
SEED = 0


def group_folds(keys: pd.Series, k: int = 5, seed: int = SEED) -> np.ndarray:
    """Fold (0..k-1) of each row such that rows with equal ``keys`` share a fold: the fleet's own rule
    (:func:`vpsim.fleet.calibrate.assign_folds`) dealing groups instead of vehicles."""
    from vpsim.fleet.calibrate import assign_folds

    return keys.map(assign_folds(list(keys.unique()), k, seed)).to_numpy()


def frame(fleet_dir: Path, record_csv: Path) -> pd.DataFrame:
    """The fleet's rows (status ok) with the record fields the learner reads and the three fold columns."""
    from vpsim.fleet.epa import read_test_car_list

    rows = pd.read_csv(fleet_dir / "vehicles.csv")
    rows = rows[rows.status == "ok"].copy()
    recs = read_test_car_list(record_csv).vehicles
    a, b, c = zip(*(r.road_load_si for r in recs), strict=True)
    fields = pd.DataFrame(
        {
            "vehicle_id": [r.vehicle_id for r in recs],
            "configuration": [r.configuration for r in recs],
            "road_load_a": a,
            "road_load_b": b,
            "road_load_c": c,
            "nv_ratio": [r.nv_ratio for r in recs],
            "axle_ratio": [r.axle_ratio for r in recs],
        }
    )
    rows["vehicle_id"] = rows["vehicle_id"].astype(str)
    df = rows.merge(fields, on=["vehicle_id", "configuration"], how="inner")
    df["transmission_code"] = df["transmission"].astype("category").cat.codes
    df["boosted"] = df["boosted"].astype(float)
    first_word = df["model"].astype(str).str.lower().str.split().str[0]
    df["fold_vehicle"] = df["fold"]
    df["fold_family"] = group_folds(df["make"].astype(str).str.lower() + "|" + first_word)
    df["fold_manufacturer"] = group_folds(df["manufacturer"].astype(str))
    return df


def out_of_fold(df: pd.DataFrame, target: np.ndarray, folds: np.ndarray) -> np.ndarray:
    """The learner's prediction of ``target`` for every row from a fit on the other folds."""
    from sklearn.ensemble import HistGradientBoostingRegressor

    x = df[list(FEATURES)].to_numpy(dtype=float)
    pred = np.full(target.size, np.nan)
    for f in np.unique(folds):
        test = folds == f
        model = HistGradientBoostingRegressor(
            max_depth=3,
            learning_rate=0.05,
            max_iter=300,
            min_samples_leaf=10,
            categorical_features=[FEATURES.index("transmission_code")],
            random_state=SEED,
        )
        model.fit(x[~test], target[~test])
        pred[test] = model.predict(x[test])
    return pred


def _fmt(err_pct: np.ndarray) -> str:
    a = np.abs(err_pct)
    return f"{np.median(a):.1f} / {np.percentile(a, 90):.1f}"


def table(df: pd.DataFrame) -> str:
    head = "| cycle | n | model | " + " | ".join(
        f"model corrected, by {s} | learner alone, by {s}" for s in SCHEMES
    )
    lines = [head + " |", "|" + "---|" * (3 + 2 * len(SCHEMES))]
    for cyc in CYCLES:
        d = df[df.cycle == cyc]
        if d.empty:
            continue
        log_ratio = np.log(d.predicted_mpg.to_numpy() / d.measured_mpg.to_numpy())
        log_meas = np.log(d.measured_mpg.to_numpy())
        cells = [cyc, str(len(d)), _fmt(np.expm1(log_ratio) * 100)]
        for s in SCHEMES:
            folds = d[f"fold_{s}"].to_numpy()
            cells.append(_fmt(np.expm1(log_ratio - out_of_fold(d, log_ratio, folds)) * 100))
            cells.append(_fmt(np.expm1(out_of_fold(d, log_meas, folds) - log_meas) * 100))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("fleet_dir", type=Path, help="the --out folder of `vpsim fleet`")
    ap.add_argument("record", type=Path, help="the Test Car List the fleet ran on")
    args = ap.parse_args(argv)
    try:
        import sklearn  # noqa: F401
    except ImportError:
        sys.stderr.write("fleet_learner: needs scikit-learn (pip install scikit-learn), not a vpsim one\n")
        return 2
    if not (args.fleet_dir / "vehicles.csv").is_file():
        missing = args.fleet_dir / "vehicles.csv"
        sys.stderr.write(f"fleet_learner: {missing} not found (run `vpsim fleet` first)\n")
        return 2
    df = frame(args.fleet_dir, args.record)
    n_veh = len(df.drop_duplicates(["vehicle_id", "configuration"]))
    print("Median / 90th percentile |error| in %, every figure out of fold (learner: scikit-learn's")
    print(f"HistGradientBoostingRegressor, depth 3, 300 iterations; {n_veh} vehicles, rows of status ok):\n")
    print(table(df))
    return 0


if __name__ == "__main__":
    sys.exit(main())
