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

The figures are drawn in :mod:`vpsim.fleet.report_figures` and ``report.md`` is written in
:mod:`vpsim.fleet.report_md`; this module holds the numbers of ``summary.json`` and ``run.json``, the
analyses behind the report and the writing of the output folder.
"""

from __future__ import annotations

import json
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


BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 0


def weighted_medians(sorted_values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The median of ``sorted_values`` (ascending) repeated ``weights[b, i]`` times, for each row b of the
    integer ``weights``: what ``np.median(np.repeat(sorted_values, weights[b]))`` gives, without the
    repetition (the middle one or two of the repeated values, their mean)."""
    cum = np.cumsum(weights, axis=1)
    total = cum[:, -1:]
    lo = np.argmax(cum > (total - 1) // 2, axis=1)  # the value at position (T - 1) // 2 of the repetition
    hi = np.argmax(cum > total // 2, axis=1)  # and at T // 2
    return 0.5 * (sorted_values[lo] + sorted_values[hi])


def family_bootstrap(
    errors, peer_errors, families, resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED
):
    """The draws behind :func:`paired_difference`: ``(e, q, n_families, diffs)`` with ``e`` and ``q`` the
    |errors| of the rows where both are finite, and ``diffs`` vpsim's median |error| minus the peer's in each
    of ``resamples`` draws of as many whole families as there are, with replacement (the draws depend only
    on the number of families and ``seed``: two deals of the same rows are drawn alike). ``None`` when no
    row has both errors."""
    e = np.abs(np.asarray(errors, float))
    q = np.abs(np.asarray(peer_errors, float))
    fam = np.asarray(families, dtype=object)
    ok = np.isfinite(e) & np.isfinite(q)
    e, q, fam = e[ok], q[ok], fam[ok]
    if e.size == 0:
        return None
    _, code = np.unique(fam.astype(str), return_inverse=True)
    n_fam = int(code.max()) + 1
    counts = np.random.default_rng(seed).multinomial(n_fam, np.full(n_fam, 1.0 / n_fam), size=resamples)
    diffs = np.zeros(resamples)
    for x, sign in ((e, 1.0), (q, -1.0)):
        order = np.argsort(x, kind="stable")
        diffs += sign * weighted_medians(x[order], counts[:, code[order]])
    return e, q, n_fam, diffs


def paired_difference(
    errors, peer_errors, families, resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> dict:
    """vpsim's median |error| minus the peer's on the same rows (points), and how sure that difference is:
    a paired bootstrap over whole families (the groups cross-validation holds out together, so that a
    family's records, alike in both tools' errors, are drawn together), ``resamples`` draws of as many
    families as there are, with replacement. Rows where either error is missing are left out. Keys: ``n``,
    ``families``, ``median_abs_error_pct`` (vpsim), ``peer_median_abs_error_pct``, ``difference_pts``,
    ``ci95_pts`` (the 2.5th and 97.5th percentiles of the resampled differences), ``share_vpsim_lower``
    (of the resamples), ``resamples``."""
    drawn = family_bootstrap(errors, peer_errors, families, resamples, seed)
    if drawn is None:
        return {"n": 0, "measured": False, "reason": "no row with both predictions"}
    e, q, n_fam, diffs = drawn
    point = float(np.median(e) - np.median(q))
    lo, hi = np.percentile(diffs, [2.5, 97.5])
    return {
        "n": int(e.size),
        "families": n_fam,
        "median_abs_error_pct": round(float(np.median(e)), 3),
        "peer_median_abs_error_pct": round(float(np.median(q)), 3),
        "difference_pts": round(point, 3),
        "ci95_pts": [round(float(lo), 3), round(float(hi), 3)],
        "share_vpsim_lower": round(float(np.mean(diffs < 0.0)), 3),
        "resamples": int(resamples),
    }


def peer_differences(run) -> dict:
    """``peer.vpsim_minus_fastsim_calibrated_by_powertrain``: per powertrain and test,
    :func:`paired_difference` of vpsim's out-of-fold errors against the calibrated FASTSim's on the same
    rows, resampled by family (by vehicle where a frame has no ``family`` column: rows written before it);
    ``{"measured": false, "reason": ...}`` where FASTSim was not calibrated on a powertrain's records."""
    col = "fastsim_calibrated_error_pct"
    out = {}
    for name, df, cycles in (
        ("conventional", run.frame(), run.cycles),
        ("bev", run.ev_frame(), EV_CYCLES),
        ("hev", run.hev_frame(), HEV_CYCLES),
        ("mhev", run.mhev_frame(), MHEV_CYCLES),
    ):
        if not len(df) or col not in df or not np.isfinite(df[col].to_numpy(float)).any():
            out[name] = {"measured": False, "reason": "FASTSim not calibrated on these records"}
            continue
        group = "family" if "family" in df else "vehicle_id"
        out[name] = {}
        for c in cycles:
            rows = df[df["cycle"] == c]
            out[name][c] = paired_difference(rows["error_pct"], rows[col], rows[group])
    return out


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
    out["peer"]["vpsim_minus_fastsim_calibrated_by_powertrain"] = (
        peer_differences(run)
        if run.peer.get("available")
        else {"measured": False, "reason": run.peer.get("reason", "not run")}
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
        "seed": run.seed,
        "deal": run.deal,
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


_NOT_RUN = f"{'not run':>26s}"  # a peer column without figures, as wide as the figures' three


def _f(x) -> str:
    return "       –" if x is None else f"{x:+7.1f}%"


def summary_lines(s: dict, info: dict, names) -> list[str]:
    """What ``vpsim fleet`` prints of a run: counts and exclusions, how it was held out, each cycle's median
    / median |error| / p90 beside FASTSim's (calibrated, defaults), the electric and hybrid parts, the
    differences from the calibrated FASTSim with their intervals, the record's repeatability, what a
    correction per manufacturer leaves, and the runtime. ``s``: :func:`summary`; ``info``:
    :func:`run_info`; ``names``: the engine cars' cycles, in order."""
    from .calibrate import DEFAULT_DEAL, SEED

    out: list[str] = []
    excl = sum(s["excluded"].values())
    out.append(
        f"{s['n_vehicles']} vehicles, {info['n_rows']} vehicle x cycle rows; {excl} vehicles excluded:"
    )
    out.append("  " + ", ".join(f"{k} {v}" for k, v in s["excluded"].items()))
    fs = s["peer"]["fastsim"]
    fc = s["peer"]["fastsim_calibrated"]
    measured = fs.get("measured", True)
    v = s["validation"]
    scheme = v.get("deal", DEFAULT_DEAL)
    deal = "" if v["seed"] == SEED else f", dealt with seed {v['seed']} (the fleet's: {SEED})"
    if scheme != DEFAULT_DEAL:  # (not the headline's deal: say so on the line)
        deal += f", {scheme} deal (the headline's: {DEFAULT_DEAL})"
    out.append(f"held out by {v['grouping']}: {v['folds']} folds of {v['groups']} groups{deal}")
    out.append(
        f"{'cycle':10s} {'n':>5s} {'median':>8s} {'med|e|':>8s} {'p90|e|':>8s}"
        + (
            "   FASTSim calibrated: median, med|e|, p90   FASTSim defaults: median, med|e|, p90"
            if measured
            else ""
        )
    )

    def trio(x):
        return f"{_f(x['median_error_pct'])} {_f(x['median_abs_error_pct'])} {_f(x['p90_abs_error_pct'])}"

    for c in names:
        line = f"{c:10s} {s['cycles'][c]['n']:5d} {trio(s['cycles'][c])}"
        if measured:
            line += f"   {trio(fc[c])}   {trio(fs[c])}"
        out.append(line)
    if not measured:
        out.append(f"FASTSim not measured: {fs.get('reason')}")
    # the electric and hybrid parts, each beside its peer (calibrated, then defaults) as the engine cars
    parts = (
        ("bev", "battery-electric: {n} vehicles ({status}), MPGe"),
        ("hev", "full hybrids: {n} vehicles ({status}), mpg charge-sustaining (ECMS)"),
        ("mhev", "mild hybrids: {n} vehicles ({status}), mpg charge-sustaining (ECMS)"),
    )
    for pt, title in parts:
        part = s["by_powertrain"][pt]
        peer = s["peer"]["fastsim_by_powertrain"].get(pt, {})
        peer_cal = s["peer"]["fastsim_calibrated_by_powertrain"].get(pt, {})
        out.append(title.format(n=part["n_vehicles"], status=part["status"]))
        if "vehicle" in peer and part["cycles"]:
            out.append(f"  (peer: {peer['vehicle']})")
        for c, v in part["cycles"].items():
            line = f"{c:10s} {v['n']:5d} {trio(v)}"
            if "measured" not in peer and c in peer:
                line += f"   {trio(peer_cal[c]) if c in peer_cal else _NOT_RUN}   {trio(peer[c])}"
            out.append(line)
    diffs = s["peer"].get("vpsim_minus_fastsim_calibrated_by_powertrain", {})
    if diffs.get("measured") is not False and diffs:
        out.append(
            "vpsim minus the calibrated FASTSim, median |error| in points [95 % interval, families drawn]:"
        )
        for pt, tests in diffs.items():
            shown = [
                f"{c} {d['difference_pts']:+.1f} [{d['ci95_pts'][0]:+.1f}, {d['ci95_pts'][1]:+.1f}]"
                for c, d in tests.items()
                if isinstance(d, dict) and d.get("n")
            ]
            if shown:
                out.append(f"  {pt}: " + "; ".join(shown))
    rep = {c: r for c, r in info.get("record_repeatability", {}).items() if r.get("rows")}
    if rep:
        beyond = "rows_beyond_12_pct_whatever_the_model"
        out.append(
            "rows the record cannot tell apart (identical inputs), and of them beyond 12 % whatever the "
            "model: " + ", ".join(f"{c} {r['rows']}, {r[beyond]}" for c, r in rep.items()) + " (report.md)"
        )
    left = {c: b["out_of_fold"] for c, b in info.get("between_manufacturers", {}).items()}
    if left:
        figures = [
            f"{c} {o['median_abs_error_pct']:.1f} / {o['p90_abs_error_pct']:.1f} %" for c, o in left.items()
        ]
        out.append(
            "left by a correction per manufacturer (out of fold; median / p90 |error|): "
            + "; ".join(figures)
            + " (report.md)"
        )
    rt = info["runtime_s"]
    out.append(
        f"runtime {rt['total_s']:.1f} s ({info['execution']}): "
        + ", ".join(f"{k} {v:.1f} s" for k, v in rt.items() if k != "total_s")
    )
    return out


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

REPEATABILITY_TOLERANCES_PCT = (5.0, 12.0)  # the median and 90th-percentile targets


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
    # here, not at the top: these modules import this one's constants and analyses
    from .report_figures import figure_by_group, figure_histograms, figure_worst
    from .report_md import markdown

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
        "predicted_vs_measured.png": run.plot(),
        "error_histograms.png": figure_histograms(df, run.cycles, peer),
        "error_by_group.png": figure_by_group(df, run.cycles),
        "worst_vehicles.png": figure_worst(w),
    }
    for name, fig in figs.items():
        fig.savefig(out / name, dpi=110)
    (out / "report.md").write_text(markdown(run, s, info, df, w, command))
    marker.unlink()
    return s, info


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
