"""What ``vpsim fleet`` writes: the table, the summary, the report and the figures of a :class:`FleetRun`.

* ``vehicles.csv``: one row per vehicle x cycle; first the columns of :data:`CSV_COLUMNS`, then extras
  (transmission, boost, mass, technology used, trace miss, FASTSim's prediction);
* ``summary.json``: exactly :data:`SUMMARY_KEYS`, and exactly :data:`STAT_KEYS` per cycle (statistics of
  error_pct = 100 (predicted - measured) / measured in mpg over the rows with a prediction; FASTSim's over
  the same rows where it gave one); ``peer.fastsim`` is ``{"measured": false, "reason": ...}`` when
  FASTSim is not installed;
* ``run.json``: the settings, row counts, trace misses and failures per cycle, and the runtime;
* ``excluded.csv``: every excluded vehicle and skipped test row with its one-line reason;
* ``technology.json``: the technology per fold and class (out of fold), and fitted on all vehicles;
* ``report.md`` and the figures ``predicted_vs_measured.png``, ``error_histograms.png``,
  ``error_by_group.png``, ``worst_vehicles.png``.

Figures are drawn on :class:`matplotlib.figure.Figure` objects (no pyplot state, no backend choice).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from . import calibrate as cal

CSV_COLUMNS = (
    "vehicle_id",
    "configuration",
    "make",
    "model",
    "cycle",
    "measured_mpg",
    "predicted_mpg",
    "error_pct",
    "fold",
    "status",
)
# exactly these; ``n_vehicles`` and ``cycles`` are the conventional fleet's, ``by_powertrain`` has both
SUMMARY_KEYS = ("n_vehicles", "excluded", "held_out", "cycles", "peer", "validation", "by_powertrain")
POWERTRAINS = ("conventional", "bev", "hev", "mhev")
EV_CYCLES = ("udds", "hwy")
HEV_CYCLES = ("udds_hot", "hwy", "us06")  # vpsim.fleet.hev.HEV_CYCLES (udds_hot: the 4-bag FTP's bags 3 + 4)
MHEV_CYCLES = ("ftp_bag2", "ftp_bag3", "hwy", "us06")  # vpsim.fleet.mhev.MHEV_CYCLES
# the peer of the mild hybrids: FASTSim 3.1 has no mild-hybrid resource; its conventional car of the record
MHEV_PEER_NOTE = "FASTSim's conventional car of the same record (FASTSim 3.1 has no mild-hybrid resource)"
STAT_KEYS = ("n", "median_error_pct", "median_abs_error_pct", "p90_abs_error_pct")
FIGURES = ("predicted_vs_measured.png", "error_histograms.png", "error_by_group.png", "worst_vehicles.png")
N_WORST = 20


def error_stats(errors) -> dict:
    e = np.asarray(errors, float)
    e = e[np.isfinite(e)]
    if e.size == 0:
        return {"n": 0, "median_error_pct": None, "median_abs_error_pct": None, "p90_abs_error_pct": None}
    return {
        "n": int(e.size),
        "median_error_pct": round(float(np.median(e)), 3),
        "median_abs_error_pct": round(float(np.median(np.abs(e))), 3),
        "p90_abs_error_pct": round(float(np.percentile(np.abs(e), 90)), 3),
    }


def summary(run) -> dict:
    """The summary with exactly the keys of :data:`SUMMARY_KEYS` (the run's settings: :func:`run_info`)."""
    df = run.frame()
    predicted = df[np.isfinite(df["error_pct"])]
    out = {
        "n_vehicles": int(df.drop_duplicates(["vehicle_id", "configuration"]).shape[0]),
        "excluded": dict(sorted(run.cars.excluded.items(), key=lambda kv: (-kv[1], kv[0]))),
        "held_out": True,
        "cycles": {c: error_stats(predicted[predicted["cycle"] == c]["error_pct"]) for c in run.cycles},
        "peer": {},
        "validation": validation(run),
    }
    if run.peer.get("available"):
        both = predicted[np.isfinite(predicted["fastsim_error_pct"])]
        out["peer"]["fastsim"] = {
            c: error_stats(both[both["cycle"] == c]["fastsim_error_pct"]) for c in run.cycles
        }
        cal_rows = predicted[np.isfinite(predicted["fastsim_calibrated_error_pct"])]
        calibrated = {
            c: error_stats(cal_rows[cal_rows["cycle"] == c]["fastsim_calibrated_error_pct"])
            for c in run.cycles
        }
        out["peer"]["fastsim_calibrated"] = calibrated
        out["peer"]["fastsim_calibrated_by_powertrain"] = {"conventional": calibrated}
    else:
        missing = {"measured": False, "reason": run.peer.get("reason", "not run")}
        out["peer"]["fastsim"] = missing
        out["peer"]["fastsim_calibrated"] = dict(missing)
        out["peer"]["fastsim_calibrated_by_powertrain"] = {"conventional": dict(missing)}
    out["peer"]["fastsim_by_powertrain"] = {"conventional": out["peer"]["fastsim"]}
    ev = run.ev_frame()
    ev_ok = ev[np.isfinite(ev["error_pct"].to_numpy(float))]
    out["by_powertrain"] = {
        "conventional": {"n_vehicles": out["n_vehicles"], "cycles": out["cycles"]},
        "bev": {
            "n_vehicles": int(ev_ok.drop_duplicates(["vehicle_id", "configuration"]).shape[0]),
            "status": run.ev.get("status", "not run"),
            "cycles": {c: error_stats(ev_ok[ev_ok["cycle"] == c]["error_pct"]) for c in EV_CYCLES},
        },
    }
    hv = run.hev_frame()
    hv_ok = hv[np.isfinite(hv["error_pct"].to_numpy(float))]
    out["by_powertrain"]["hev"] = {
        "n_vehicles": int(hv_ok.drop_duplicates(["vehicle_id", "configuration"]).shape[0]),
        "status": run.hev.get("status", "not run"),
        "cycles": {c: error_stats(hv_ok[hv_ok["cycle"] == c]["error_pct"]) for c in HEV_CYCLES},
    }
    for key, col in (
        ("fastsim_by_powertrain", "fastsim"),
        ("fastsim_calibrated_by_powertrain", "fastsim_calibrated"),
    ):
        # FASTSim's hybrid (vpsim.fleet.peer_hev): its defaults, and calibrated as vpsim's hybrids are
        hv_col = hv_ok[f"{col}_error_pct"].to_numpy(float)
        if run.hev.get("peer_run") and np.isfinite(hv_col).any():
            both = hv_ok[np.isfinite(hv_col)]
            out["peer"][key]["hev"] = {
                c: error_stats(both[both["cycle"] == c][f"{col}_error_pct"]) for c in HEV_CYCLES
            }
        else:
            why = run.hev.get("status") if run.peer.get("available") else run.peer.get("reason", "not run")
            if run.peer.get("available") and key != "fastsim_by_powertrain":
                why = run.hev.get("peer_technology_status", why)
            out["peer"][key]["hev"] = {"measured": False, "reason": why or "no full hybrid predicted"}
        if run.peer.get("available") and len(ev_ok):
            both = ev_ok[np.isfinite(ev_ok[f"{col}_error_pct"].to_numpy(float))]
            out["peer"][key]["bev"] = {
                c: error_stats(both[both["cycle"] == c][f"{col}_error_pct"]) for c in EV_CYCLES
            }
        else:
            why = run.peer.get("reason", "not run") if not run.peer.get("available") else run.ev.get("status")
            out["peer"][key]["bev"] = {"measured": False, "reason": why or "no electric vehicle predicted"}
    _powertrain_block(
        out, run, "mhev", run.mhev_frame(), run.mhev, MHEV_CYCLES, "mild hybrid", MHEV_PEER_NOTE
    )
    return out


def _powertrain_block(out, run, name, frame, state, cycles, what, peer_note) -> None:
    """``by_powertrain.<name>`` (its records' out-of-fold errors per test and per class) and
    ``peer.fastsim_by_powertrain.<name>`` (FASTSim with its defaults on the same rows, ``peer_note`` says
    which FASTSim vehicle) and ``peer.fastsim_calibrated_by_powertrain.<name>`` (FASTSim calibrated on the
    same folds and classes, or why not)."""
    ok = frame[np.isfinite(frame["error_pct"].to_numpy(float))]

    def stats(rows, col="error_pct"):
        return {c: error_stats(rows[rows["cycle"] == c][col]) for c in cycles}

    out["by_powertrain"][name] = {
        "n_vehicles": int(ok.drop_duplicates(["vehicle_id", "configuration"]).shape[0]),
        "status": state.get("status", "not run"),
        "cycles": stats(ok),
        "classes": {c: stats(ok[ok["layout"] == c]) for c in sorted(set(ok["layout"]))},
    }
    peer = out["peer"]
    if state.get("peer_run"):
        both = ok[np.isfinite(ok["fastsim_error_pct"].to_numpy(float))]
        peer["fastsim_by_powertrain"][name] = {**stats(both, "fastsim_error_pct"), "vehicle": peer_note}
    else:
        why = state.get("status") if run.peer.get("available") else run.peer.get("reason", "not run")
        peer["fastsim_by_powertrain"][name] = {"measured": False, "reason": why or f"no {what} predicted"}
    cal = ok[np.isfinite(ok["fastsim_calibrated_error_pct"].to_numpy(float))] if len(ok) else ok
    if state.get("peer_run") and len(cal):
        peer["fastsim_calibrated_by_powertrain"][name] = {
            **stats(cal, "fastsim_calibrated_error_pct"),
            "vehicle": peer_note,
        }
    else:
        why = state.get("peer_technology_status") or peer["fastsim_by_powertrain"][name].get("reason")
        peer["fastsim_calibrated_by_powertrain"][name] = {"measured": False, "reason": why or "not run"}


def validation(run) -> dict:
    """How the errors were held out, and what was chosen while looking at this list (``summary.json``)."""
    from .tuned import TUNED_ON_THIS_LIST

    return {
        "grouping": run.grouping,
        "folds": run.folds,
        "groups": run.n_groups,
        "tuned_on_this_list": [dict(t) for t in TUNED_ON_THIS_LIST],
    }


def _ev():
    from . import ev

    return ev


def _hev():
    from . import hev

    return hev


def _mhev():
    from . import mhev

    return mhev


def ev_technology_bounds(run) -> dict:
    """As :func:`technology_bounds`, for the battery-electric class's fits."""
    ev = _ev()
    out = {}
    fits = {
        **run.ev.get("technology", {}),
        **{f"all.{c}": t for c, t in run.ev.get("technology_all", {}).items()},
    }
    for name, t in fits.items():
        hits = ev.on_bounds(t)
        if hits:
            out[name] = {
                p: {"bound": side, "value": t[p], "reason": ev.BOUND_REASONS.get((p, side), "")}
                for p, side in hits.items()
            }
    return out


def technology_bounds(run) -> dict:
    """{"fold<k>.<class>" or "all.<class>": {parameter: {"bound": "low"|"high", "value", "reason"}}} for the
    fitted values that sit on their search bounds."""
    out = {}
    fits = {**run.technology, **{f"all.{c}": t for c, t in run.technology_all.items()}}
    for name, t in fits.items():
        hits = cal.on_bounds(t)
        if hits:
            out[name] = {
                p: {"bound": side, "value": t[p], "reason": cal.BOUND_REASONS.get((p, side), "")}
                for p, side in hits.items()
            }
    return out


def _inputs(run) -> dict[str, tuple]:
    from .vehicle import model_inputs

    return {rec.key: model_inputs(rec) for rec in run.cars.vehicles}


def run_info(run) -> dict:
    """How the run was made and what it met: settings, counts, trace misses, runtime (``run.json``)."""
    df = run.frame()
    info = {
        "method": run.method,
        "mode": "extended",
        "folds": run.folds,
        "technology_parameters": list(cal.TECH_PARAMS),
        "technology_classes": list(cal.CLASSES),
        "input": str(run.cars.path),
        "n_test_rows": run.cars.n_rows,
        "n_rows": int(len(df)),
        "status": {k: int(v) for k, v in df["status"].value_counts().items()},
        "trace_miss": {
            c: int(((df["cycle"] == c) & (df["status"] == "trace_miss")).sum()) for c in run.cycles
        },
        "failed": {c: int(((df["cycle"] == c) & (df["status"] == "failed")).sum()) for c in run.cycles},
        "execution": run.execution,
        "runtime_s": {k: round(v, 2) for k, v in run.timings.items()},
        "record_repeatability": repeatability(df, _inputs(run)),
        "between_manufacturers": between_manufacturers(df),
        "peer": {"fastsim": dict(run.peer)},
    }
    if run.peer.get("available"):
        info["peer"]["fastsim"]["trace_miss"] = {
            c: int(((df["cycle"] == c) & (df["fastsim_status"] == "trace_miss")).sum()) for c in run.cycles
        }
        info["peer"]["fastsim"]["failed"] = {
            c: int(((df["cycle"] == c) & ~np.isfinite(df["fastsim_mpg"])).sum()) for c in run.cycles
        }
    return info


# --- how repeatable the record is ---------------------------------------------------------------------------

REPEATABILITY_TOLERANCES_PCT = (5.0, 12.0)  # the issue's median and 90th-percentile targets


def _most_within(m_sorted: np.ndarray, tol: float) -> int:
    """The most of the sorted measurements ``m_sorted`` one prediction p can have within ``tol`` of
    (|p / m - 1| <= tol): those in a window [x, x (1 + tol) / (1 - tol)]."""
    ratio = (1.0 + tol) / (1.0 - tol)
    best, j = 0, 0
    for i in range(m_sorted.size):
        while m_sorted[i] > m_sorted[j] * ratio * (1.0 + 1e-12):
            j += 1
        best = max(best, i - j + 1)
    return best


def repeatability(df, inputs: dict[str, tuple]) -> dict:
    """How far the measurements of vehicles the record cannot tell apart differ: per cycle, over the rows
    whose vehicle shares every model input (:data:`vpsim.fleet.vehicle.MODEL_INPUTS`; ``inputs``: vehicle
    key ``"id#configuration"`` -> those values) with another vehicle of the run.

    A model of these inputs predicts one value for every vehicle of such a group, so on these rows no model of
    the record can do better than the group's spread. Per cycle: ``rows``, ``groups``; the errors of the best
    single prediction per group (its geometric mean of measured mpg, the least-squares prediction of ln mpg):
    ``best_possible_median_abs_error_pct`` and ``..._p90_...``; ``rows_beyond_<tol>_pct_whatever_the_model``:
    rows that miss by more than tol with every prediction (per group, all rows but the most one prediction
    can be within tol of); vpsim's errors on the same rows; and the group with the widest spread.
    """
    out: dict = {}
    if len(df) == 0:
        return out
    key = df["vehicle_id"].astype(str) + "#" + df["configuration"].astype(str)
    group = key.map(lambda k: inputs.get(k))
    for c in sorted(df["cycle"].unique()):
        sel = (df["cycle"] == c).to_numpy() & group.notna().to_numpy()
        sub = df[sel].assign(_g=group[sel].map(repr))
        sizes = sub.groupby("_g")["vehicle_id"].transform("size")
        sub = sub[sizes >= 2]
        if len(sub) == 0:
            out[c] = {"rows": 0, "groups": 0}
            continue
        ln = np.log(sub["measured_mpg"].to_numpy(float))
        gmean = sub.assign(_ln=ln).groupby("_g")["_ln"].transform("mean").to_numpy()
        best = 100.0 * np.abs(np.exp(gmean - ln) - 1.0)
        entry = {
            "rows": int(len(sub)),
            "groups": int(sub["_g"].nunique()),
            "best_possible_median_abs_error_pct": round(float(np.median(best)), 3),
            "best_possible_p90_abs_error_pct": round(float(np.percentile(best, 90)), 3),
        }
        for tol in REPEATABILITY_TOLERANCES_PCT:
            missed = 0
            for _, g in sub.groupby("_g"):
                m = np.sort(g["measured_mpg"].to_numpy(float))
                missed += m.size - _most_within(m, tol / 100.0)
            entry[f"rows_beyond_{tol:g}_pct_whatever_the_model"] = int(missed)
        e = sub["error_pct"].to_numpy(float)
        e = np.abs(e[np.isfinite(e)])
        entry["vpsim_median_abs_error_pct"] = round(float(np.median(e)), 3) if e.size else None
        entry["vpsim_p90_abs_error_pct"] = round(float(np.percentile(e, 90)), 3) if e.size else None
        spread = sub.groupby("_g")["measured_mpg"].agg(lambda s: s.max() / s.min() - 1.0)
        g = sub[sub["_g"] == spread.idxmax()].sort_values("measured_mpg")
        entry["widest_group"] = {
            "spread_pct": round(100.0 * float(spread.max()), 1),
            "vehicles": [f"{r.make} {r.model} ({r.vehicle_id}#{r.configuration})" for r in g.itertuples()],
            "measured_mpg": [float(x) for x in g["measured_mpg"]],
        }
        out[c] = entry
    return out


# --- how much of the error lies between manufacturers ---------------------------------------------------


def between_manufacturers(df) -> dict:
    """What a correction per manufacturer and cycle would leave of the errors: each prediction divided by
    the median predicted / measured mpg of its manufacturer's vehicles on that cycle, taken

    * ``out_of_fold``: from the manufacturer's vehicles in the other folds (none there: no correction),
      as a fitted correction would be used on a new car;
    * ``in_sample``: from all of them, the vehicle's own measurement included, which no prediction may
      use: optimistic, the correction sees the row it corrects.

    A diagnostic, never applied to the predictions. Technology the record does not name (stop-start,
    cylinder deactivation, Atkinson-cycle engines, 48 V systems not listed as hybrids) is shared within a
    manufacturer, so what the correction removes is error between manufacturers, and what it leaves lies
    between one manufacturer's vehicles. Per cycle: ``manufacturers``, and per kind ``median_abs_error_pct``
    and ``p90_abs_error_pct`` (the same rows as the cycle's figures).
    """
    import pandas as pd

    out: dict = {}
    if len(df) == 0 or "manufacturer" not in df:
        return out
    d = df[np.isfinite(df["error_pct"].to_numpy(float))]
    for c in sorted(d["cycle"].unique()):
        sub = d[d["cycle"] == c]
        lr = np.log1p(sub["error_pct"].to_numpy(float) / 100.0)  # ln(predicted / measured mpg)
        maker = sub["manufacturer"].astype(str).str.strip().str.lower().to_numpy()
        fold = sub["fold"].to_numpy()
        f = pd.DataFrame({"lr": lr, "m": maker})
        own = f.groupby("m")["lr"].transform("median").to_numpy()
        oof = np.zeros(lr.size)
        for k in np.unique(fold):
            train = f[fold != k].groupby("m")["lr"].median()
            test = fold == k
            oof[test] = train.reindex(maker[test]).fillna(0.0).to_numpy()

        def stats(left):
            e = 100.0 * np.abs(np.expm1(left))
            return {
                "median_abs_error_pct": round(float(np.median(e)), 3),
                "p90_abs_error_pct": round(float(np.percentile(e, 90)), 3),
            }

        out[c] = {
            "manufacturers": int(len(set(maker))),
            "out_of_fold": stats(lr - oof),
            "in_sample": stats(lr - own),
        }
    return out


def _manufacturers_md(bm: dict, s: dict, cycles) -> list[str]:
    rows = [c for c in cycles if c in bm]
    if not rows:
        return []
    L = [
        "",
        "## How much of the error lies between manufacturers",
        "",
        "A diagnostic, not applied to the predictions: the errors left after dividing every prediction by "
        "its manufacturer's median predicted / measured mpg on the cycle, taken from the manufacturer's "
        "vehicles in the other folds (as a fitted correction would be used), or from all of them, the "
        "vehicle's own measurement included (optimistic: the correction sees the row it corrects). What the "
        "record does not name (stop-start, cylinder deactivation, Atkinson-cycle engines) is shared within a "
        "manufacturer; what the correction leaves lies between one manufacturer's vehicles.",
        "",
        "| cycle | manufacturers | vpsim median / p90 abs | corrected out of fold | corrected in sample |",
        "|---|---|---|---|---|",
    ]
    for c in rows:
        b, v = bm[c], s["cycles"].get(c, {})
        o, i = b["out_of_fold"], b["in_sample"]
        L.append(
            f"| {c} | {b['manufacturers']} | {_fmt(v.get('median_abs_error_pct'), '.1f')} / "
            f"{_fmt(v.get('p90_abs_error_pct'), '.1f')} % | {o['median_abs_error_pct']:.1f} / "
            f"{o['p90_abs_error_pct']:.1f} % | {i['median_abs_error_pct']:.1f} / "
            f"{i['p90_abs_error_pct']:.1f} % |"
        )
    return L


# --- mechanisms -----------------------------------------------------------------------------------------


TWIN_NOTE_PCT = 5.0  # a twin measured this much apart is named as the first mechanism


def twin_differences(df, inputs: dict[str, tuple]) -> dict:
    """Per vehicle with twins (equal in every model input; ``inputs`` as :func:`repeatability`): its
    measured mpg against its twins' geometric mean, in %, the median over the cycles both measured."""
    if len(df) == 0:
        return {}
    key = df["vehicle_id"].astype(str) + "#" + df["configuration"].astype(str)
    d = df.assign(_k=key, _g=key.map(lambda k: repr(inputs.get(k))), _ln=np.log(df["measured_mpg"]))
    d = d[key.map(lambda k: k in inputs)]
    g = d.groupby(["_g", "cycle"])["_ln"]
    n, total = g.transform("size"), g.transform("sum")
    d = d[n >= 2].assign(_diff=lambda x: 100.0 * (np.exp(x["_ln"] - (total - x["_ln"]) / (n - 1)) - 1.0))
    return {
        tuple(k): float(v) for k, v in d.groupby(["vehicle_id", "configuration"])["_diff"].median().items()
    }


def _manual_table() -> str:
    """The fleet's upshift speeds of a manual (mph, gears 1-2 to 5-6), as the report names them."""
    from .epa import MPH_TO_MPS
    from .vehicle import MANUAL_GEAR_RULE

    return "/".join(f"{v / MPH_TO_MPS:.0f}" for v in MANUAL_GEAR_RULE.upshift_speeds(6))


def mechanisms(df, inputs: dict[str, tuple] | None = None):
    """A data-derived mechanism per vehicle (a string): what sets it apart from the fleet, in order of the
    model gaps it points at. ``df``: the rows of :func:`FleetRun.frame`; with ``inputs`` (as
    :func:`repeatability`), first a twin the record cannot tell apart that measured differently."""
    twins = twin_differences(df, inputs) if inputs else {}
    forward = "max_speed_error_mps" in df  # the forward method's rows carry its tracking
    per = df.groupby(["vehicle_id", "configuration"]).agg(
        transmission=("transmission", "first"),
        n_gears=("n_gears", "first"),
        boosted=("boosted", "first"),
        pw=("power_to_mass_w_per_kg", "first"),
        sp=("specific_power_kw_per_l", "first"),
        mass=("test_mass_kg", "first"),
        cyl=("cylinders", "first"),
        miss=("trace_miss_s", "max"),
        err=("error_pct", "median"),
    )
    pw90, m90, pw10, sp90 = (
        np.nanpercentile(per["pw"], 90),
        np.nanpercentile(per["mass"], 90),
        np.nanpercentile(per["pw"], 10),
        np.nanpercentile(per["sp"], 90),
    )
    out = {}
    for key, r in per.iterrows():
        parts = []
        diff = twins.get(tuple(key))
        if diff is not None and abs(diff) >= TWIN_NOTE_PCT:
            side = "below" if diff < 0 else "above"
            parts.append(f"measured {abs(diff):.0f} % {side} a twin with the same record inputs")
        if r["miss"] > 0:
            if forward:  # the PI driver's tracking, outside the band somewhere
                cause = "the PI driver outside the +-2 km/h band"
            else:
                cause = "the engine lacks the full-load torque the trace asks"
            parts.append(f"trace miss {r['miss']:.2g} s ({cause})")
        if r["pw"] >= pw90:
            parts.append(f"high power/mass {r['pw']:.0f} W/kg (engine at very low load)")
        elif r["pw"] <= pw10:
            parts.append(f"low power/mass {r['pw']:.0f} W/kg (engine near full load)")
        if r["sp"] >= sp90:
            parts.append(f"high specific power {r['sp']:.0f} kW/L (high-output engine)")
        if r["transmission"] == "cvt":
            parts.append("CVT (model: default ratio range and strategy, default converter)")
        elif r["transmission"] == "automatic":
            parts.append("automatic (model: default converter and lock-up, one shift rule)")
        elif r["transmission"] == "manual":
            table = _manual_table()
            parts.append(f"manual (model: upshifts at {table} mph while accelerating; its own unknown)")
        if r["boosted"]:
            parts.append("boosted (model: the boost of its rated power)")
        if r["mass"] >= m90:
            parts.append(f"heavy: {r['mass']:.0f} kg")
        if r["cyl"] >= 8:
            parts.append(f"{int(r['cyl'])} cylinders")
        out[key] = "; ".join(parts) if parts else "no distinguishing feature in the record"
    return out


def worst(df, n: int = N_WORST, inputs: dict[str, tuple] | None = None):
    """The ``n`` vehicles with the largest median |error| over their cycles, with their mechanism
    (:func:`mechanisms`)."""
    import pandas as pd

    ok = df[np.isfinite(df["error_pct"])].copy()
    ok["abs_error_pct"] = ok["error_pct"].abs()
    g = ok.groupby(["vehicle_id", "configuration"])
    per = g.agg(
        make=("make", "first"),
        model=("model", "first"),
        median_error_pct=("error_pct", "median"),
        median_abs_error_pct=("abs_error_pct", "median"),
        cycles=("cycle", lambda s: ",".join(s)),
    )
    per = per.sort_values("median_abs_error_pct", ascending=False).head(n)
    mech = mechanisms(df, inputs)
    per["mechanism"] = [mech[k] for k in per.index]
    return per.reset_index() if len(per) else pd.DataFrame()


# --- breakdowns -----------------------------------------------------------------------------------------


MASS_LABELS = ("<1600 kg", "1600-1900", "1900-2200", "2200-2600", ">2600 kg")  # light to heavy


def _mass_bin(m):
    edges = [0, 1600, 1900, 2200, 2600, 10000]
    for lo, hi, lab in zip(edges[:-1], edges[1:], MASS_LABELS, strict=True):
        if lo <= m < hi:
            return lab
    return MASS_LABELS[-1]


def _in_order(groups):
    """Groups in reading order: the mass bins light to heavy, the others sorted ("<1600 kg" sorts last)."""
    return sorted(groups, key=lambda g: (MASS_LABELS.index(g), "") if g in MASS_LABELS else (-1, str(g)))


GROUPS = {
    "transmission": lambda df: df["transmission"],
    "boost": lambda df: np.where(df["boosted"], "boosted", "NA"),
    "cylinders": lambda df: df["cylinders"].map(lambda z: f"{int(z)} cyl" if z < 8 else ">=8 cyl"),
    "test mass": lambda df: df["test_mass_kg"].map(_mass_bin),
}


def breakdown(df):
    """Per group kind, group and cycle: n, median error, median |error| (a long DataFrame)."""
    import pandas as pd

    ok = df[np.isfinite(df["error_pct"])].copy()
    rows = []
    for kind, fn in GROUPS.items():
        ok["group"] = fn(ok)
        for (grp, cyc), sub in ok.groupby(["group", "cycle"]):
            e = sub["error_pct"].to_numpy()
            rows.append(
                {
                    "by": kind,
                    "group": grp,
                    "cycle": cyc,
                    "n": len(e),
                    "median_error_pct": round(float(np.median(e)), 2),
                    "median_abs_error_pct": round(float(np.median(np.abs(e))), 2),
                }
            )
    return pd.DataFrame(rows)


# --- figures --------------------------------------------------------------------------------------------


def _axes_grid(n, ncols=2, size=(5.2, 4.2)):
    from matplotlib.figure import Figure

    nrows = max(1, math.ceil(n / ncols))
    fig = Figure(figsize=(size[0] * ncols, size[1] * nrows), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for ax in axes[n:]:
        ax.set_visible(False)
    return fig, axes


def _diagonal(ax, lo, hi, title, measured_unit, predicted_unit):
    """A predicted-against-measured panel's frame: the diagonal, +-10 % lines, limits, labels, legend."""
    x = np.array([lo, hi])
    ax.plot(x, x, "k-", lw=0.8)
    ax.plot(x, 1.1 * x, "k:", lw=0.7)
    ax.plot(x, 0.9 * x, "k:", lw=0.7, label="±10 %")
    ax.set_xlim(lo, hi)
    ax.set_ylim(lo, hi)
    ax.set_title(title)
    ax.set_xlabel(f"measured {measured_unit}")
    ax.set_ylabel(f"predicted {predicted_unit} (out of fold)")
    ax.legend(fontsize=7, loc="upper left")


def figure_predicted_vs_measured(df, cycles, peer: bool, ev=None, hev=None):
    """One panel per conventional cycle (mpg); with battery-electric rows ``ev``, one per EV test (MPGe:
    green diamonds); with full-hybrid rows ``hev``, one per hybrid test (charge-sustaining mpg: purple
    triangles, trace misses as red crosses; FASTSim's hybrid calibrated on the same classes beside them, or
    its defaults where it was not calibrated)."""
    ev_cycles = [c for c in EV_CYCLES if ev is not None and (ev["cycle"] == c).any()]
    hev_cycles = [c for c in HEV_CYCLES if hev is not None and (hev["cycle"] == c).any()]
    fig, axes = _axes_grid(len(cycles) + len(ev_cycles) + len(hev_cycles))
    first = len(cycles) + len(ev_cycles)
    for ax, c in zip(axes[first:], hev_cycles, strict=False):
        sub = hev[(hev["cycle"] == c) & np.isfinite(hev["predicted_mpg"].to_numpy(float))]
        vals = np.concatenate([sub["measured_mpg"], sub["predicted_mpg"]])
        lo, hi = (0.9 * vals.min(), 1.05 * vals.max()) if vals.size else (0, 1)
        for col, what in (("fastsim_calibrated_mpg", "calibrated"), ("fastsim_mpg", "defaults")):
            # the peer calibrated as vpsim's hybrids are (the fair comparison), else its defaults
            if peer and col in sub and np.isfinite(sub[col].to_numpy(float)).any():
                ax.scatter(
                    sub["measured_mpg"],
                    sub[col],
                    s=14,
                    marker="s",
                    c="tab:orange",
                    alpha=0.45,
                    label=f"FASTSim 3.1 hybrid, {what}",
                )
                break
        miss = (sub["status"] == "trace_miss").to_numpy()
        ax.scatter(
            sub["measured_mpg"][~miss],
            sub["predicted_mpg"][~miss],
            s=24,
            marker="^",
            c="tab:purple",
            alpha=0.75,
            label="vpsim hybrid (ECMS, charge-sustaining)",
        )
        if miss.any():
            ax.scatter(
                sub["measured_mpg"][miss],
                sub["predicted_mpg"][miss],
                s=20,
                marker="x",
                c="tab:red",
                label="vpsim hybrid, trace miss",
            )
        _diagonal(ax, lo, hi, f"full hybrid, {c} (n = {len(sub)})", "mpg", "mpg")
    for ax, c in zip(axes[len(cycles) :], ev_cycles, strict=False):
        sub = ev[(ev["cycle"] == c) & np.isfinite(ev["predicted_mpge"].to_numpy(float))]
        vals = np.concatenate([sub["measured_mpge"], sub["predicted_mpge"]])
        lo, hi = (0.9 * vals.min(), 1.05 * vals.max()) if vals.size else (0, 1)
        if peer and np.isfinite(sub["fastsim_calibrated_mpge"].to_numpy(float)).any():
            ax.scatter(
                sub["measured_mpge"],
                sub["fastsim_calibrated_mpge"],
                s=14,
                marker="s",
                c="tab:orange",
                alpha=0.45,
                label="FASTSim 3.1 BEV, calibrated",
            )
        ax.scatter(
            sub["measured_mpge"],
            sub["predicted_mpge"],
            s=22,
            marker="D",
            c="tab:green",
            alpha=0.75,
            label="vpsim BEV",
        )
        _diagonal(ax, lo, hi, f"battery-electric, {c} (n = {len(sub)})", "MPGe (unadjusted)", "MPGe")
    for ax, c in zip(axes, cycles, strict=False):
        sub = df[(df["cycle"] == c) & np.isfinite(df["predicted_mpg"])]
        lo = 0.9 * min(sub["measured_mpg"].min(), sub["predicted_mpg"].min()) if len(sub) else 0
        hi = 1.05 * max(sub["measured_mpg"].max(), sub["predicted_mpg"].max()) if len(sub) else 1
        if peer and "fastsim_calibrated_mpg" in sub:  # the peer calibrated as vpsim is, the fair comparison
            ax.scatter(
                sub["measured_mpg"],
                sub["fastsim_calibrated_mpg"],
                s=7,
                c="tab:orange",
                alpha=0.45,
                label="FASTSim 3.1, calibrated",
            )
        elif peer and "fastsim_mpg" in sub:
            ax.scatter(
                sub["measured_mpg"], sub["fastsim_mpg"], s=7, c="tab:orange", alpha=0.45, label="FASTSim 3.1"
            )
        miss = sub["status"] == "trace_miss"
        ax.scatter(
            sub["measured_mpg"][~miss],
            sub["predicted_mpg"][~miss],
            s=7,
            c="tab:blue",
            alpha=0.6,
            label="vpsim",
        )
        if miss.any():
            ax.scatter(
                sub["measured_mpg"][miss],
                sub["predicted_mpg"][miss],
                s=12,
                marker="x",
                c="tab:red",
                label="vpsim, trace miss",
            )
        _diagonal(ax, lo, hi, f"{c} (n = {len(sub)})", "mpg", "mpg")
    fig.suptitle(
        "Predicted against measured fuel economy (MPGe for the battery-electric cars), EPA test cars"
        if not hev_cycles
        else "Predicted against measured fuel economy (MPGe for the battery-electric cars; hybrids "
        "charge-sustaining), EPA test cars"
    )
    return fig


def figure_histograms(df, cycles, peer: bool):
    fig, axes = _axes_grid(len(cycles))
    bins = np.arange(-60, 61, 4)
    for ax, c in zip(axes, cycles, strict=False):
        sub = df[(df["cycle"] == c) & np.isfinite(df["error_pct"])]
        ax.hist(np.clip(sub["error_pct"], -59.9, 59.9), bins=bins, alpha=0.7, color="tab:blue", label="vpsim")
        peers = (
            ("fastsim_calibrated_error_pct", "FASTSim 3.1, calibrated", "-"),
            ("fastsim_error_pct", "FASTSim 3.1, defaults", ":"),
        )
        for col, label, style in peers if peer else ():
            if col in sub:
                ax.hist(
                    np.clip(sub[col].dropna(), -59.9, 59.9),
                    bins=bins,
                    histtype="step",
                    lw=1.5,
                    ls=style,
                    color="tab:orange",
                    label=label,
                )
        ax.axvline(0, color="k", lw=0.8)
        ax.set_title(f"{c}: median {np.median(sub['error_pct']):+.1f} %" if len(sub) else c)
        ax.set_xlabel("error of predicted mpg, % (clipped at ±60)")
        ax.set_ylabel("vehicles")
        ax.legend(fontsize=7)
    fig.suptitle("Error histograms (out of fold)")
    return fig


def figure_by_group(df, cycles):
    fig, axes = _axes_grid(len(GROUPS))
    ok = df[np.isfinite(df["error_pct"])].copy()
    colours = ["tab:blue", "tab:green", "tab:purple", "tab:red"]
    for ax, (kind, fn) in zip(axes, GROUPS.items(), strict=False):
        ok["group"] = fn(ok)
        groups = _in_order(ok["group"].unique())
        for j, c in enumerate(cycles):
            xs, med, q1, q3 = [], [], [], []
            for i, g in enumerate(groups):
                e = ok[(ok["group"] == g) & (ok["cycle"] == c)]["error_pct"]
                if len(e):
                    xs.append(i + (j - (len(cycles) - 1) / 2) * 0.18)
                    med.append(np.median(e))
                    q1.append(np.percentile(e, 25))
                    q3.append(np.percentile(e, 75))
            med, q1, q3 = map(np.asarray, (med, q1, q3))
            ax.errorbar(
                xs, med, yerr=[med - q1, q3 - med], fmt="o", ms=4, capsize=2, color=colours[j % 4], label=c
            )
        counts = ok.drop_duplicates(["vehicle_id", "configuration"]).groupby("group").size()
        ax.set_xticks(range(len(groups)), [f"{g}\n({counts.get(g, 0)})" for g in groups], fontsize=8)
        ax.axhline(0, color="k", lw=0.8)
        ax.set_title(f"error by {kind} (median, quartiles; vehicles)")
        ax.set_ylabel("error of predicted mpg, %")
        ax.legend(fontsize=7)
    return fig


def figure_worst(w):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(16, 0.42 * max(len(w), 4) + 1.2), layout="constrained")
    ax = fig.subplots()
    if len(w):
        y = np.arange(len(w))[::-1]
        e = w["median_error_pct"].to_numpy()
        ax.barh(y, e, color=np.where(e > 0, "tab:blue", "tab:red"))
        labels = [f"{r.make} {r.model} ({r.vehicle_id}#{r.configuration})"[:48] for r in w.itertuples()]
        ax.set_yticks(y, labels, fontsize=7)
        lim = 1.05 * float(np.max(np.abs(e)))
        ax.set_xlim(-lim, lim)
        for yi, r in zip(y, w.itertuples(), strict=True):  # the mechanism on the empty side of the bar
            neg = r.median_error_pct < 0
            ax.text(
                0.01 * lim if neg else -0.01 * lim,
                yi,
                r.mechanism[:150],
                va="center",
                fontsize=5.5,
                ha="left" if neg else "right",
            )
        ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("median error over the vehicle's cycles, % (> 0: predicted mpg too high)")
    ax.set_title(f"The {len(w)} worst vehicles and the mechanism the record points at")
    return fig


# --- writing --------------------------------------------------------------------------------------------


INCOMPLETE = ".vpsim-fleet-incomplete"  # present in an output folder while (or if) its writing did not finish


def check_complete(folder, what: str = "output") -> None:
    """One-line error if ``folder`` holds a ``vpsim fleet`` output whose writing did not finish (a run killed
    while writing leaves files of two runs side by side: none of them is to be trusted)."""
    from ..errors import VpsimError

    if (Path(folder) / INCOMPLETE).exists():
        raise VpsimError(
            f"{Path(folder) / what}: from a vpsim fleet run that did not finish writing its folder "
            f"({Path(folder) / INCOMPLETE} is there); run vpsim fleet again"
        )


def prepare_output_folder(out_dir, inputs=()) -> Path:
    """Check, before any work, that ``out_dir`` can be written and is no input; one-line error if not."""
    import tempfile

    from ..errors import VpsimError

    out = Path(out_dir)
    for name in inputs:
        src = Path(name).resolve()
        if src == out.resolve() or out.resolve() in src.parents:
            raise VpsimError(
                f"--out {out_dir}: holds an input of this command ({name}); choose another folder"
            )
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out, prefix=".vpsim-write-test-"):
            pass
    except OSError as exc:
        raise VpsimError(f"--out {out_dir}: cannot write there ({exc.strerror or exc})") from None
    return out


def write_outputs(run, out_dir, command: str = "") -> tuple[dict, dict]:
    """Write everything into ``out_dir``; returns (summary, run info).

    While it writes, the folder holds a marker (:data:`INCOMPLETE`), removed once every file is written:
    a folder killed halfway says so, and readers of its files (``vpsim vehicle from-epa --technology``)
    refuse it (:func:`check_complete`)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    marker = out / INCOMPLETE
    marker.write_text("vpsim fleet is writing this folder; if this file stays, the run did not finish\n")
    df = run.frame()
    cols = list(CSV_COLUMNS) + [c for c in df.columns if c not in CSV_COLUMNS]
    df[cols].to_csv(out / "vehicles.csv", index=False)
    run.ev_frame().to_csv(out / "vehicles_ev.csv", index=False)
    run.hev_frame().to_csv(out / "vehicles_hev.csv", index=False)
    run.mhev_frame().to_csv(out / "vehicles_mhev.csv", index=False)
    import pandas as pd

    pd.DataFrame(
        run.cars.excluded_rows,
        columns=["line", "vehicle_id", "configuration", "make", "model", "test_number", "reason"],
    ).to_csv(out / "excluded.csv", index=False)
    (out / "technology.json").write_text(
        json.dumps(
            {
                "out_of_fold": run.technology,
                "all_vehicles": run.technology_all,
                "search_bounds": {k: list(v) for k, v in cal.search_bounds().items()},
                "on_search_bound": technology_bounds(run),
                "peer_fastsim_calibrated_out_of_fold": run.peer_technology,
                "bev": {
                    "parameters": list(_ev().TECH_PARAMS),
                    "out_of_fold": run.ev.get("technology", {}),
                    "all_vehicles": run.ev.get("technology_all", {}),
                    "search_bounds": {k: list(v) for k, v in _ev().search_bounds().items()},
                    "on_search_bound": ev_technology_bounds(run),
                    "peer_fastsim_calibrated_out_of_fold": run.ev.get("peer_technology", {}),
                },
                "hev": {
                    "parameters": list(_hev().TECH_PARAMS),
                    "out_of_fold": run.hev.get("technology", {}),
                    "all_vehicles": run.hev.get("technology_all", {}),
                    "search_bounds": {k: list(v) for k, v in _hev().search_bounds().items()},
                    "peer_fastsim_calibrated_out_of_fold": run.hev.get("peer_technology", {}),
                },
                "mhev": {
                    "parameters": list(_mhev().TECH_PARAMS),
                    "out_of_fold": run.mhev.get("technology", {}),
                    "all_vehicles": run.mhev.get("technology_all", {}),
                    "search_bounds": {k: list(v) for k, v in _mhev().search_bounds().items()},
                    "peer_fastsim_calibrated_out_of_fold": run.mhev.get("peer_technology", {}),
                },
            },
            indent=2,
        )
        + "\n"
    )
    s = summary(run)
    info = run_info(run)
    (out / "summary.json").write_text(json.dumps(s, indent=2) + "\n")
    (out / "run.json").write_text(json.dumps(info, indent=2) + "\n")
    peer = bool(run.peer.get("available"))
    w = worst(df, inputs=_inputs(run))
    figs = {
        "predicted_vs_measured.png": figure_predicted_vs_measured(
            df, run.cycles, peer, run.ev_frame(), run.hev_frame()
        ),
        "error_histograms.png": figure_histograms(df, run.cycles, peer),
        "error_by_group.png": figure_by_group(df, run.cycles),
        "worst_vehicles.png": figure_worst(w),
    }
    for name, fig in figs.items():
        fig.savefig(out / name, dpi=110)
    (out / "report.md").write_text(markdown(run, s, info, df, w, command))
    marker.unlink()
    return s, info


def _fmt(x, spec="+.1f"):
    return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def _repeatability_md(rep: dict, cycles) -> list[str]:
    rows = [c for c in cycles if rep.get(c, {}).get("rows")]
    if not rows:
        return []
    lo, hi = (f"{t:g}" for t in REPEATABILITY_TOLERANCES_PCT)
    L = [
        "",
        "## How repeatable the record is",
        "",
        "Vehicles equal in every field the model is built from (test mass, road load, engine, transmission, "
        "N/V and axle ratio) get one prediction from any model of the record, so the spread of their "
        "measurements is error no such model can remove. Best possible: each group predicted at the "
        "geometric mean of its measurements.",
        "",
        f"| cycle | rows (groups) | best possible median / p90 abs | rows beyond {lo} / {hi} % whatever the "
        "model | vpsim median / p90 abs on these rows | widest group |",
        "|---|---|---|---|---|---|",
    ]
    for c in rows:
        r = rep[c]
        wg = r["widest_group"]
        beyond = [r[f"rows_beyond_{t}_pct_whatever_the_model"] for t in (lo, hi)]
        L.append(
            f"| {c} | {r['rows']} ({r['groups']}) | {r['best_possible_median_abs_error_pct']:.1f} / "
            f"{r['best_possible_p90_abs_error_pct']:.1f} % | {beyond[0]} / {beyond[1]} | "
            f"{_fmt(r['vpsim_median_abs_error_pct'], '.1f')} / "
            f"{_fmt(r['vpsim_p90_abs_error_pct'], '.1f')} % | {wg['vehicles'][0]}: "
            + ", ".join(f"{m:g}" for m in wg["measured_mpg"])
            + f" mpg (+{wg['spread_pct']:.0f} %) |"
        )
    return L


def _powertrain_md(run, s) -> list[str]:
    """The table per powertrain (conventional cycles in mpg, battery-electric tests in MPGe) and the
    battery-electric class's technology."""
    ev = _ev()
    fs, fc = s["peer"]["fastsim_by_powertrain"], s["peer"]["fastsim_calibrated_by_powertrain"]

    def trio(v):
        if not v or v.get("measured") is False:
            return "not measured"
        return (
            f"{_fmt(v.get('median_error_pct'))} / {_fmt(v.get('median_abs_error_pct'), '.1f')} / "
            f"{_fmt(v.get('p90_abs_error_pct'), '.1f')} %"
        )

    L = [
        "",
        "## Errors per powertrain",
        "",
        "Median / median abs / p90 abs error, out of fold. Conventional cars: mpg on the cycles above; "
        "battery-electric cars (`vpsim.fleet.ev`): unadjusted MPGe of the charge-depleting UDDS and highway "
        "tests, five classes (`bev`, `bev_awd`, `bev_two_speed`, `bev_induction`, `bev_eesm`: "
        "`vpsim.fleet.ev.ev_class`) "
        "each with its own technology (`machine.loss_scale`, `electric.accessory_power`) fitted on the same "
        "kind of folds (EV families held out together). FASTSim: its BEV (`vpsim.fleet.peer_bev`) on the "
        "same records, calibrated per the same classes.",
        "",
        "| powertrain | test | n | vpsim | FASTSim calibrated | FASTSim defaults |",
        "|---|---|---|---|---|---|",
    ]
    for pt in POWERTRAINS:
        b = s["by_powertrain"][pt]
        for c, v in b["cycles"].items():
            L.append(
                f"| {pt} | {c} | {v['n']} | {trio(v)} | {trio(fc.get(pt, {}).get(c, fc.get(pt)))} | "
                f"{trio(fs.get(pt, {}).get(c, fs.get(pt)))} |"
            )
    bev = s["by_powertrain"]["bev"]
    L += ["", f"Battery-electric vehicles predicted: {bev['n_vehicles']} ({bev['status']})."]
    if run.ev.get("technology"):
        L += [
            "",
            f"Battery-electric technology per fold ({run.ev['folds']} folds of {run.ev['groups']} EV groups; "
            "search bounds: "
            + ", ".join(f"`{k}` {lo:g}-{hi:g}" for k, (lo, hi) in ev.search_bounds().items())
            + "):",
            "",
            "| fold.class | machine loss scale | accessories, W | training rows | on a bound |",
            "|---|---|---|---|---|",
        ]
        for k, t in {
            **run.ev["technology"],
            **{f"all.{c}": t for c, t in run.ev["technology_all"].items()},
        }.items():
            hits = ev.on_bounds(t)
            L.append(
                f"| {k} | {t[ev.TECH_PARAMS[0]]:.2f} | {t[ev.TECH_PARAMS[1]]:.0f} | {t['n_train']} | "
                + (", ".join(f"{p.split('.')[1]} {side}" for p, side in hits.items()) or "–")
                + " |"
            )
        reasons = {(p, side) for t in run.ev["technology"].values() for p, side in ev.on_bounds(t).items()}
        for p, side in sorted(reasons):
            L.append(f"\n`{p}` on its {side} bound: the bound stays: {ev.BOUND_REASONS.get((p, side), '')}.")
    return L + _hev_md(run, s)


def _hev_md(run, s) -> list[str]:
    """The full and the mild hybrids' counts and technology per fold and class (:mod:`vpsim.fleet.hev`,
    :mod:`vpsim.fleet.mhev`)."""
    from . import mhev

    b, m = s["by_powertrain"]["hev"], s["by_powertrain"]["mhev"]
    full = (
        f"Full hybrids predicted: {b['n_vehicles']} ({b['status']}); backward, ECMS, the charge-sustaining "
        "figure against the unadjusted test. `udds_hot`: the hot-start UDDS of the 4-bag FTP (bags 3 + 4, "
        "or Ford's bag 2), not bags 2 and 3 alone (their charge swing sets their figure; docs/fleet.md). "
        "Classes `hev_split`, `hev_p2`, `hev_p2_converter` (`vpsim.fleet.hev.hev_class`)."
    )
    mild = (
        f"Mild hybrids predicted: {m['n_vehicles']} ({m['status']}); backward, ECMS, charge-sustaining; "
        "the 4-bag FTP's bags 2 and 3 as a conventional car's. Classes `mhev_p0` (belt) and `mhev_p1` "
        f"(crank) (`vpsim.fleet.mhev`). FASTSim: {MHEV_PEER_NOTE}. Per class (median / median abs / p90 "
        "abs): "
        + "; ".join(
            f"`{c}` "
            + ", ".join(
                f"{t} {_fmt(v['median_error_pct'])} / {_fmt(v['median_abs_error_pct'], '.1f')} / "
                f"{_fmt(v['p90_abs_error_pct'], '.1f')} % (n {v['n']})"
                for t, v in by.items()
                if v["n"]
            )
            for c, by in m.get("classes", {}).items()
        )
        + "."
    )
    return _hybrid_md(run.hev, _hev(), full, "Hybrid") + _hybrid_md(run.mhev, mhev, mild, "Mild-hybrid")


def _hybrid_md(part: dict, hm, text: str, what: str) -> list[str]:
    """``text``, then the technology per fold and class of a hybrid fleet ``part`` (module ``hm``)."""
    L = ["", text]
    extra = hm.TECH_PARAMS[2:]  # beyond the efficiency and the accessories (the mild hybrids' friction)
    if part.get("technology"):
        L += [
            "",
            f"{what} technology per fold ({part['folds']} folds of {part['groups']} groups; "
            "search bounds: "
            + ", ".join(f"`{k}` {lo:g}-{hi:g}" for k, (lo, hi) in hm.search_bounds().items())
            + "):",
            "",
            "| fold.class | thermal efficiency | accessories, W | "
            + "".join(f"{p.split('.')[1].replace('_', ' ')} | " for p in extra)
            + "training rows | on a bound |",
            "|---|---|---|---|---|" + "---|" * len(extra),
        ]
        for k, t in {
            **part["technology"],
            **{f"all.{c}": t for c, t in part["technology_all"].items()},
        }.items():
            hits = hm.on_bounds(t)
            L.append(
                f"| {k} | {t[hm.TECH_PARAMS[0]]:.4f} | {t[hm.TECH_PARAMS[1]]:.0f} | "
                + "".join(f"{t[p]:.3g} | " for p in extra)
                + f"{t['n_train']} | "
                + (", ".join(f"{p.split('.')[1]} {side}" for p, side in hits.items()) or "–")
                + " |"
            )
        reasons = {(p, side) for t in part["technology"].values() for p, side in hm.on_bounds(t).items()}
        for p, side in sorted(reasons):
            L.append(f"\n`{p}` on its {side} bound: the bound stays: {hm.BOUND_REASONS.get((p, side), '')}.")
    if part.get("peer_technology"):
        from . import peer as pc
        from . import peer_hev as ph

        how = (
            "`vpsim.fleet.peer_hev`: its hybrid, the engine's efficiency curve times a scale searched over "
            f"{ph.CAL_SCALE[0]:g}-{ph.CAL_SCALE[-1]:g}, the accessory power over "
            f"{ph.CAL_AUX[0]:g}-{ph.CAL_AUX[-1]:g} W"
            if hm.__name__.endswith(".hev")
            else "`vpsim.fleet.peer`: its conventional car, the efficiency level, the accessory power over "
            f"{pc.CAL_AUX[0]:g}-{pc.CAL_AUX[-1]:g} W and the part-load exponent, as for the conventional cars"
        )
        L += [
            "",
            f"FASTSim calibrated the same way ({how}), per fold and class:",
            "",
            "| fold.class | efficiency scale | accessories, W | part-load exponent | training rows |",
            "|---|---|---|---|---|",
        ]
        for k, t in part["peer_technology"].items():
            q = t.get("part_load_exponent")
            L.append(
                f"| {k} | {t['efficiency_scale']:.3f} | {t['accessory_power_w']:.0f} | "
                f"{'–' if q is None else format(q, '.2f')} | {t['n_train']} |"
            )
    elif part.get("peer_technology_status"):
        L += ["", f"FASTSim was not calibrated on the {what.lower()}s: {part['peer_technology_status']}."]
    return L


def markdown(run, s, info, df, w, command: str) -> str:
    L = [
        "# Fleet: predicted against measured fuel economy",
        "",
        f"Input: `{Path(run.cars.path).name}` ({info['n_test_rows']} test rows). Method: **{run.method}**, "
        "extended mode; technology (`engine.thermal_efficiency`, `engine.friction_coefficient`, "
        "`engine.accessory_power` per class: "
        f"aspirated, boosted, high-output above {cal.HIGH_OUTPUT_KW_PER_L:g} kW/L) "
        f"fitted by {run.folds}-fold cross-validation"
        + {
            "family": " holding out whole vehicle families (the same test vehicle, the same manufacturer, "
            "model and engine, or the same inputs to the model)",
            "manufacturer": ", one manufacturer held out at a time",
            "record": " by single records (a vehicle's twin or sibling configuration may be in another fold)",
        }[run.grouping]
        + f" ({run.n_groups} groups): **every error below is out of fold**. Constants chosen while looking "
        "at this list's errors are listed at the end of this report.",
    ]
    if command:
        L += ["", f"Command: `{command}`"]
    rt = info["runtime_s"]
    L += [
        "",
        f"Runtime: {rt.get('total_s', 0):.1f} s in total ({run.execution}); "
        + ", ".join(f"{k} {v:.1f} s" for k, v in rt.items() if k != "total_s")
        + ".",
    ]
    L += [
        "",
        f"## Vehicles: {s['n_vehicles']} run, {sum(s['excluded'].values())} excluded",
        "",
        "| reason | vehicles |",
        "|---|---|",
    ]
    L += [f"| {k} | {v} |" for k, v in s["excluded"].items()]
    L += ["", "Every excluded vehicle and skipped test row, with its reason: `excluded.csv`.", ""]
    L += [
        "## Errors per cycle (error = predicted / measured mpg − 1)",
        "",
        "Median / median abs / p90 abs error. FASTSim 3.1 twice: calibrated as vpsim is (three technology "
        "parameters per class fitted on the same folds by the same loss: `vpsim.fleet.peer`), and with its "
        "own defaults.",
        "",
        "| cycle | n | vpsim | trace misses | FASTSim calibrated | FASTSim defaults |",
        "|---|---|---|---|---|---|",
    ]
    fs = s["peer"]["fastsim"]
    fc = s["peer"].get("fastsim_calibrated", {})
    measured = fs.get("measured", True)

    def trio(v):
        return (
            f"{_fmt(v.get('median_error_pct'))} / {_fmt(v.get('median_abs_error_pct'), '.1f')} / "
            f"{_fmt(v.get('p90_abs_error_pct'), '.1f')} %"
        )

    for c in run.cycles:
        v = s["cycles"][c]
        L.append(
            f"| {c} | {v['n']} | {trio(v)} | {info['trace_miss'][c]} | "
            + (f"{trio(fc.get(c, {}))} | {trio(fs.get(c, {}))} |" if measured else "not measured | |")
        )
    if not measured:
        L += ["", f"FASTSim: not measured ({fs.get('reason')})."]
    else:
        tm = info["peer"]["fastsim"]["trace_miss"]
        L += [
            "",
            "FASTSim trace misses (its power ramp; run with trace_miss_opts = Allow): "
            + ", ".join(f"{c} {n}" for c, n in tm.items())
            + ".",
        ]
    L += [
        "",
        "![predicted vs measured](predicted_vs_measured.png)",
        "",
        "![error histograms](error_histograms.png)",
    ]
    L += _powertrain_md(run, s)
    L += _repeatability_md(info.get("record_repeatability", {}), run.cycles)
    L += _manufacturers_md(info.get("between_manufacturers", {}), s, run.cycles)
    L += [
        "",
        "## Technology fitted (out of fold)",
        "",
        "| fold.class | thermal efficiency | friction coefficient | accessories, W | training rows | basis |",
        "|---|---|---|---|---|---|",
    ]
    for k, t in run.technology.items():
        L.append(
            f"| {k} | {t['engine.thermal_efficiency']:.3f} | {t['engine.friction_coefficient']:.3f} | "
            f"{t['engine.accessory_power']:.0f} | {t['n_train']} | {t['basis']} |"
        )
    L += [
        "",
        "## Error by transmission, boost, cylinders and test mass",
        "",
        "Median error (median |error|) in %, per cycle:",
        "",
    ]
    b = breakdown(df)
    if len(b):
        for kind in GROUPS:
            sub = b[b["by"] == kind]
            L += [
                f"**{kind}**",
                "",
                "| group | " + " | ".join(run.cycles) + " |",
                "|---|" + "---|" * len(run.cycles),
            ]
            for g in _in_order(sub["group"].unique()):
                cells = []
                for c in run.cycles:
                    r = sub[(sub["group"] == g) & (sub["cycle"] == c)]
                    cells.append(
                        f"{r['median_error_pct'].iloc[0]:+.1f} ({r['median_abs_error_pct'].iloc[0]:.1f}), "
                        f"n={r['n'].iloc[0]}"
                        if len(r)
                        else "–"
                    )
                L.append(f"| {g} | " + " | ".join(cells) + " |")
            L.append("")
    L += [
        "![error by group](error_by_group.png)",
        "",
        f"## The {len(w)} worst vehicles",
        "",
        "| vehicle | make model | cycles | median error | mechanism (from the record) |",
        "|---|---|---|---|---|",
    ]
    for r in w.itertuples():
        L.append(
            f"| {r.vehicle_id}#{r.configuration} | {r.make} {r.model} | {r.cycles} | "
            f"{r.median_error_pct:+.1f} % | {r.mechanism} |"
        )
    L += ["", "![worst vehicles](worst_vehicles.png)", ""]
    bounds = technology_bounds(run)
    L += ["## Fitted values on their search bounds", ""]
    if not bounds:
        L += ["None: every fitted technology value lies inside its search range.", ""]
    else:
        L += [
            "A value on its bound is where the fit would go further if allowed; the bound stays for the "
            "reason given (`technology.json`: `on_search_bound`).",
            "",
            "| fit | parameter | value | bound | why the bound holds |",
            "|---|---|---|---|---|",
        ]
        for fit, hits in bounds.items():
            for par, h in hits.items():
                L.append(f"| {fit} | `{par}` | {h['value']:g} | {h['bound']} | {h['reason']} |")
        L.append("")
    tuned = s["validation"]["tuned_on_this_list"]
    L += [
        f"## Constants chosen while looking at this list ({len(tuned)})",
        "",
        "Beyond the technology fitted out of fold, these constants were chosen, compared or tuned on "
        "this same list's results (from the project's history). An error on a car nobody looked at may be "
        "larger by what they absorbed; the grouped and leave-one-manufacturer-out runs (`--group-by`) show "
        "how much of the accuracy carries across vehicles and makers.",
        "",
        "| constant | value | where | how it was chosen |",
        "|---|---|---|---|",
    ]
    for t in tuned:
        L.append(f"| `{t['name']}` | {t['value']} | `{t['where']}` | {t['how']} |")
    return "\n".join(L) + "\n"


__all__ = [
    "CSV_COLUMNS",
    "FIGURES",
    "SUMMARY_KEYS",
    "breakdown",
    "error_stats",
    "repeatability",
    "summary",
    "worst",
    "write_outputs",
]
