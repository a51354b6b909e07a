"""The fleet run's battery-electric and hybrid parts (steps 6 to 8 of :func:`vpsim.fleet.run.run_fleet`).

Each part folds its records by family, fits its technology per class out of fold, runs every vehicle once
per test at its fold's technology, and runs FASTSim on the same records with its defaults and calibrated on
the same folds (:class:`PeerCalibration`, :func:`_calibrated_peer`). :mod:`vpsim.fleet.run` imports the
parts from here; the helpers they share with it (``_progress``, ``_log_l100``) are imported from there
inside the functions, so that neither module imports the other as it loads.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from . import calibrate as cal
from .epa import mpg_from_l_per_100km

EV_CHUNK = 8  # battery-electric vehicles per unit of work (each runs 44 grid points per test)
HEV_CHUNK = 8  # hybrids per unit of work (each runs 12 ECMS grid points per test)


def _rounded(t: dict) -> dict:
    return {k: (round(x, 6) if isinstance(x, float) else x) for k, x in t.items()}


def _fit_classes(module, grid, meas, ok, class_of, fold_of, k, out) -> dict:
    """The electric or hybrid fleet's technology (``module``: :mod:`vpsim.fleet.ev` or :mod:`.hev`, its
    ``fit`` and ``CLASSES``): per fold and class out of fold, into ``out["technology"]``, and per class on
    every vehicle into ``out["technology_all"]``; the out-of-fold fits {(fold, class): parameters}."""
    vfold = np.array([fold_of[r["key"]] for r in ok])
    vclass = np.array([class_of[r["key"]] for r in ok], dtype=object)
    tech = cal.per_fold_and_class(
        lambda rows: module.fit(grid[rows], meas[rows]), vfold, vclass, k, module.CLASSES
    )
    out["technology"] = {f"fold{f}.{c}": _rounded(t) for (f, c), t in sorted(tech.items())}
    out["technology_all"] = {}
    for c in module.CLASSES:
        rows = vclass == c
        if rows.any():
            params_all, loss_all = module.fit(grid[rows], meas[rows])
            out["technology_all"][c] = _rounded(
                {**params_all, "train_loss": loss_all, "n_train": int(rows.sum())}
            )
    return tech


def _predict(executor, predict_chunk, work, failed, tech, fold_of, class_of, chunk: int) -> dict:
    """One real run per (vehicle, test) at its fold's class technology, in chunks on ``executor``:
    {(key, cycle): row}."""
    items = [
        (v, c, tech[(fold_of[v.key], class_of[v.key])])
        for v, cs in work
        for c in cs
        if (v.key, c) not in failed
    ]
    preds: dict = {}
    for part in executor.map(predict_chunk, [items[i : i + chunk] for i in range(0, len(items), chunk)]):
        for r in part:
            preds[(r["key"], r["cycle"])] = r
    return preds


def _run_evs(evs, spec: cal.FoldSpec, executor, peer_state, progress, timings) -> dict:
    """The battery-electric records on their two tests: technology of the class ``bev`` fitted out of fold
    exactly as the conventional classes' (folds of :func:`vpsim.fleet.calibrate.assign_folds` over the EV
    families, :func:`~vpsim.fleet.calibrate.per_fold_and_class`), then one backward run per vehicle and
    test at its fold's technology; FASTSim's BEV (:mod:`vpsim.fleet.peer_bev`) on the same records, with
    its defaults and calibrated on the same folds. Returns ``rows``, ``technology`` ("fold<k>.bev"),
    ``technology_all``, ``folds``, ``groups``, ``peer_technology`` and ``status`` ("ok" or why not run)."""
    from . import ev as evm
    from . import peer_bev as pb
    from .run import _progress

    out = {"rows": [], "technology": {}, "technology_all": {}, "folds": 0, "groups": 0}
    out.update(peer_technology={}, status="ok", n_records=len(evs))
    evs = [v for v in evs if any(c in v.measured_mpge for c in evm.EV_CYCLES)]
    if not evs:
        out["status"] = "no battery-electric record with a charge-depleting UDDS or highway test"
        return out
    groups = cal.vehicle_groups(evs, spec.group_by, labels=evm.family_labels)
    n_groups = len(set(groups.values()))
    k = spec.n_folds(n_groups)
    if n_groups < max(k, 2):
        out["status"] = (
            f"{len(evs)} battery-electric vehicle(s) in {n_groups} group(s): too few for {k} folds"
        )
        return out
    try:
        fold_of = spec.assign([v.key for v in evs], groups)
    except ValueError as exc:  # (a hash or blocks deal left a fold of a small part empty)
        out["status"] = f"{len(evs)} battery-electric vehicle(s): {exc}"
        return out
    out.update(folds=k, groups=n_groups, fold_of=fold_of, group_of=groups)
    work = [(v, tuple(c for c in evm.EV_CYCLES if c in v.measured_mpge)) for v in evs]
    chunks = [work[i : i + EV_CHUNK] for i in range(0, len(work), EV_CHUNK)]
    t0 = time.perf_counter()
    grid_rows: list[dict] = []
    for i, part in enumerate(executor.map(evm.grid_chunk, chunks)):
        grid_rows += part
        _progress(
            "electric: technology grid, vehicles", min((i + 1) * EV_CHUNK, len(work)), len(work), t0, progress
        )
    by_key = {v.key: v for v in evs}
    ok = [r for r in grid_rows if r["log_wall"] is not None]
    failed = {(r["key"], r["cycle"]): r["error"] for r in grid_rows if r["log_wall"] is None}
    if not ok:
        out["status"] = "no battery-electric vehicle could be simulated: " + grid_rows[0]["error"]
        return out
    grid = np.stack([r["log_wall"] for r in ok])
    meas = np.array([math.log(evm.wall_wh_per_km(by_key[r["key"]].measured_mpge[r["cycle"]])) for r in ok])
    class_of = {v.key: evm.ev_class(v) for v in evs}
    tech = _fit_classes(evm, grid, meas, ok, class_of, fold_of, k, out)
    preds = _predict(executor, evm.predict_chunk, work, failed, tech, fold_of, class_of, 4 * EV_CHUNK)
    timings["ev_vpsim_s"] = time.perf_counter() - t0
    peer_rows: dict = {}
    peer_cal_rows: dict = {}
    if peer_state.get("available"):
        t0 = time.perf_counter()
        pitems = [(evm.peer_row(v), evm.PEER_CYCLE[c]) for v, cs in work for c in cs]
        pch = [pitems[i : i + 2 * EV_CHUNK] for i in range(0, len(pitems), 2 * EV_CHUNK)]
        for part in executor.map(pb.bev_peer_chunk, pch):
            for r in part:
                peer_rows[(r["key"], r["cycle"])] = r
        cal_rows: list[dict] = []
        done = 0
        for part in executor.map(pb.bev_calibration_chunk, pch):
            cal_rows += part
            done += len(part)
            _progress("electric: FASTSim calibration runs", done, len(pitems), t0, progress)
        okp = [r for r in cal_rows if r["log_wh_per_km"] is not None]
        if okp:
            key_of = {pb._key(evm.peer_row(v)): v for v in evs}
            cycle_of = {p: c for c, p in evm.PEER_CYCLE.items()}
            ptech = pb.calibrate_bev_peer(
                np.stack([r["log_wh_per_km"] for r in okp]),
                np.array(
                    [
                        math.log(evm.wall_wh_per_km(key_of[r["key"]].measured_mpge[cycle_of[r["cycle"]]]))
                        for r in okp
                    ]
                ),
                np.array([fold_of[key_of[r["key"]].key] for r in okp]),
                k,
                np.array([class_of[key_of[r["key"]].key] for r in okp], dtype=object),
                evm.CLASSES,
            )
            citems = [
                (evm.peer_row(v), evm.PEER_CYCLE[c], _peer_tech(ptech[(fold_of[v.key], class_of[v.key])]))
                for v, cs in work
                for c in cs
            ]
            cch = [citems[i : i + 2 * EV_CHUNK] for i in range(0, len(citems), 2 * EV_CHUNK)]
            for part in executor.map(pb.bev_peer_chunk, cch):
                for r in part:
                    peer_cal_rows[(r["key"], r["cycle"])] = r
            out["peer_technology"] = {f"fold{f}.{c}": _rounded(t) for (f, c), t in sorted(ptech.items())}
        timings["ev_peer_s"] = time.perf_counter() - t0
    rows = []
    for v, cs in work:
        t = tech[(fold_of[v.key], class_of[v.key])]
        for c in cs:
            meas_c = v.measured_mpge[c]
            row = {
                "vehicle_id": v.vehicle_id,
                "configuration": v.configuration,
                "make": v.make,
                "model": v.model,
                "manufacturer": v.manufacturer,
                "cycle": c,
                "measured_mpge": round(meas_c, 4),
                "predicted_mpge": math.nan,
                "error_pct": math.nan,
                "fold": fold_of[v.key],
                "status": "ok",
                "family": groups[v.key],
                "rated_power_kw": round(v.rated_power_kw, 2),
                "test_mass_kg": round(v.mass_kg, 1),
                "power_to_mass_w_per_kg": round(1e3 * v.rated_power_kw / v.mass_kg, 2),
                "final_drive": round(v.final_drive, 4),
                "wheel_radius_m": round(v.wheel_radius_m, 4),
                "ratio_rule": v.ratio_rule,
                "battery_strings": evm.pack_strings(v.rated_power_kw * 1e3),
                "machine_loss_scale": t[evm.TECH_PARAMS[0]],
                "accessory_power_w": t[evm.TECH_PARAMS[1]],
                "drive_efficiency": math.nan,
                "trace_miss_s": math.nan,
                "fastsim_mpge": math.nan,
                "fastsim_error_pct": math.nan,
                "fastsim_status": "not run",
                "fastsim_calibrated_mpge": math.nan,
                "fastsim_calibrated_error_pct": math.nan,
                "detail": "",
            }
            pred = preds.get((v.key, c))
            err = failed.get((v.key, c)) or (pred or {}).get("error") or ("" if pred else "not run")
            if err:
                row["status"], row["detail"] = "failed", err
            else:
                row["predicted_mpge"] = round(pred["mpge"], 4)
                row["error_pct"] = round(100.0 * (pred["mpge"] / meas_c - 1.0), 4)
                row["trace_miss_s"] = pred["trace_miss_s"]
                row["drive_efficiency"] = pred["drive_efficiency"]  # the run's (the fit's third parameter)
                if pred["trace_miss_s"] > 0:
                    row["status"] = "trace_miss"
                    row["detail"] = (
                        f"the machine or battery cannot give the trace's power for {pred['trace_miss_s']:g} s"
                    )
            pkey = (pb._key(evm.peer_row(v)), evm.PEER_CYCLE[c])
            for col, src in (("fastsim", peer_rows), ("fastsim_calibrated", peer_cal_rows)):
                pr = src.get(pkey)
                if pr is None:
                    continue
                mpge = pr.get("mpge", math.nan)
                if math.isfinite(mpge):
                    row[f"{col}_mpge"] = round(mpge, 4)
                    row[f"{col}_error_pct"] = round(100.0 * (mpge / meas_c - 1.0), 4)
                if col == "fastsim":
                    row["fastsim_status"] = pr.get("peer_error") or (
                        "trace_miss" if pr.get("trace_miss") else "ok"
                    )
            rows.append(row)
    out["rows"] = rows
    return out


def _run_hevs(hevs, spec: cal.FoldSpec, executor, peer_state, progress, timings) -> dict:
    """The full hybrids on their tests: technology per layout class (:data:`vpsim.fleet.hev.CLASSES`) fitted
    out of fold as the other classes' (folds over the hybrid families), then one backward ECMS run per
    vehicle and test at its fold's technology, the charge-sustaining figure compared; FASTSim's hybrid
    (:mod:`vpsim.fleet.peer_hev`, its defaults) on the same records. Returns ``rows``,
    ``technology`` ("fold<k>.<class>"), ``technology_all``, ``folds``, ``groups`` and ``status``."""
    from . import hev as hm
    from . import peer_hev as ph

    what = {
        "name": "full hybrid",
        "label": "hybrids",
        "cycles": hm.HEV_CYCLES,
        "tests": "hot UDDS, HWY or US06",
    }
    calibrated = PeerCalibration(
        ph.hev_calibration_chunk, ph.calibrate_hev_peer, ph.hev_peer_chunk, ph.HEV_PEER_PARAMS, "hybrid"
    )
    part = HybridFleet(hm, hm.hev_class, ph.hev_peer_chunk, calibrated, what)
    return _run_hybrids(hevs, part, spec, executor, peer_state, progress, timings)


def _run_mhevs(mhevs, spec: cal.FoldSpec, executor, peer_state, progress, timings) -> dict:
    """The mild hybrids (:mod:`vpsim.fleet.mhev`) as the full hybrids (:func:`_run_hevs`), classes
    :data:`vpsim.fleet.mhev.CLASSES`; the peer is FASTSim's conventional car of the same record
    (:mod:`vpsim.fleet.peer`: FASTSim 3.1 has no mild-hybrid resource), with its defaults and calibrated
    on the mild hybrids' own folds and classes as the conventional cars' peer is on theirs."""
    from . import mhev as mm
    from . import peer as peer_mod

    what = {
        "name": "mild hybrid",
        "label": "mild hybrids",
        "cycles": mm.MHEV_CYCLES,
        "tests": "FTP, HWY or US06",
    }
    calibrated = PeerCalibration(
        peer_mod.calibration_chunk,
        peer_mod.calibrate_peer,
        peer_mod.peer_chunk,
        peer_mod.PEER_PARAMS,
        "conventional car",
    )
    part = HybridFleet(mm, mm.mhev_class, peer_mod.peer_chunk, calibrated, what)
    return _run_hybrids(mhevs, part, spec, executor, peer_state, progress, timings)


# a hybrid part's third technology parameter in its rows, under the column name the other parts give it
HYBRID_EXTRA_COLUMNS = {
    "engine.friction_coefficient": "friction_coefficient",
    "machine.loss_scale": "machine_loss_scale",
}


class HybridFleet(NamedTuple):
    """A hybrid part of the fleet for :func:`_run_hybrids`: its module ``hm`` (:mod:`vpsim.fleet.hev` or
    :mod:`.mhev`: ``fit``, ``CLASSES``, ``TECH_PARAMS``, ``grid_chunk``, ``predict_chunk``,
    ``family_labels``), ``class_fn`` its technology class of a record, ``peer_chunk`` runs FASTSim on
    (record, test) items, ``calibrated`` (:class:`PeerCalibration`) fits and runs it calibrated, ``what``
    names the vehicles and their tests (``name``, ``label``, ``cycles``, ``tests``)."""

    hm: object
    class_fn: Callable
    peer_chunk: Callable
    calibrated: PeerCalibration
    what: dict


def _run_hybrids(recs, part: HybridFleet, spec: cal.FoldSpec, executor, peer_state, progress, timings):
    """The hybrids ``recs`` of the fleet part ``part`` (:class:`HybridFleet`) on their tests
    ``part.what["cycles"]``."""
    from .run import _log_l100, _progress

    hm, class_fn, peer_chunk, calibrated, what = part
    name = what["name"]
    out = {"rows": [], "technology": {}, "technology_all": {}, "folds": 0, "groups": 0}
    out.update(status="ok", n_records=len(recs))
    recs = [v for v in recs if any(c in v.measured_mpg for c in what["cycles"])]
    if not recs:
        out["status"] = f"no {name} with a {what['tests']} test"
        return out
    groups = cal.vehicle_groups(recs, spec.group_by, labels=hm.family_labels)
    n_groups = len(set(groups.values()))
    k = spec.n_folds(n_groups)
    if n_groups < max(k, 2):
        out["status"] = f"{len(recs)} {name}(s) in {n_groups} group(s): too few for {k} folds"
        return out
    try:
        fold_of = spec.assign([v.key for v in recs], groups)
    except ValueError as exc:  # (a hash or blocks deal left a fold of a small part empty)
        out["status"] = f"{len(recs)} {name}(s): {exc}"
        return out
    out.update(folds=k, groups=n_groups, fold_of=fold_of, group_of=groups)
    work = [(v, tuple(c for c in what["cycles"] if c in v.measured_mpg)) for v in recs]
    chunks = [work[i : i + HEV_CHUNK] for i in range(0, len(work), HEV_CHUNK)]
    t0 = time.perf_counter()
    grid_rows: list[dict] = []
    for i, part in enumerate(executor.map(hm.grid_chunk, chunks)):
        grid_rows += part
        done = min((i + 1) * HEV_CHUNK, len(work))
        _progress(f"{what['label']}: technology grid, vehicles", done, len(work), t0, progress)
    by_key = {v.key: v for v in recs}
    ok = [r for r in grid_rows if r["log_fuel"] is not None]
    failed = {(r["key"], r["cycle"]): r["error"] for r in grid_rows if r["log_fuel"] is None}
    if not ok:
        out["status"] = f"no {name} could be simulated: " + grid_rows[0]["error"]
        return out
    grid = np.stack([r["log_fuel"] for r in ok])
    meas = np.array([_log_l100(by_key[r["key"]].measured_mpg[r["cycle"]]) for r in ok])
    class_of = {v.key: class_fn(v) for v in recs}
    tech = _fit_classes(hm, grid, meas, ok, class_of, fold_of, k, out)
    preds = _predict(executor, hm.predict_chunk, work, failed, tech, fold_of, class_of, 4 * HEV_CHUNK)
    prefix = "hev" if hm.__name__.endswith(".hev") else "mhev"
    timings[f"{prefix}_vpsim_s"] = time.perf_counter() - t0
    peer_rows: dict = {}
    if peer_state.get("available"):
        t0 = time.perf_counter()
        pitems = [(v, c) for v, cs in work for c in cs]
        pch = [pitems[i : i + 2 * HEV_CHUNK] for i in range(0, len(pitems), 2 * HEV_CHUNK)]
        for part in executor.map(peer_chunk, pch):
            for r in part:
                peer_rows[(r["key"], r["cycle"])] = r
        timings[f"{prefix}_peer_s"] = time.perf_counter() - t0
    if peer_state.get("available"):
        # FASTSim with its technology fitted on the same folds and classes (the fair peer)
        t0 = time.perf_counter()
        peer_cal_rows = _calibrated_peer(
            calibrated, executor, work, class_of, fold_of, k, hm.CLASSES, what["label"], out, progress
        )
        timings[f"{prefix}_peer_calibrated_s"] = time.perf_counter() - t0
    else:
        peer_cal_rows = {}
    out["peer_run"] = bool(peer_rows)
    rows = []
    for v, cs in work:
        t = tech[(fold_of[v.key], class_of[v.key])]
        for c in cs:
            meas_c = v.measured_mpg[c]
            row = {
                "vehicle_id": v.vehicle_id,
                "configuration": v.configuration,
                "make": v.make,
                "model": v.model,
                "manufacturer": v.manufacturer,
                "layout": v.layout,
                "cycle": c,
                "measured_mpg": round(meas_c, 4),
                "predicted_mpg": math.nan,
                "error_pct": math.nan,
                "fold": fold_of[v.key],
                "status": "ok",
                "family": groups[v.key],
                "rated_power_kw": round(v.rated_power_kw, 2),
                "test_mass_kg": round(v.mass_kg, 1),
                "displacement_l": v.displacement_l,
                "boosted": v.boosted,
                "machine_kw": math.nan,
                "thermal_efficiency": t[hm.TECH_PARAMS[0]],
                "accessory_power_w": t[hm.TECH_PARAMS[1]],
                **{HYBRID_EXTRA_COLUMNS[p]: t[p] for p in hm.TECH_PARAMS[2:]},
                "trace_miss_s": math.nan,
                "fastsim_mpg": math.nan,
                "fastsim_error_pct": math.nan,
                "fastsim_status": "not run",
                "fastsim_calibrated_mpg": math.nan,
                "fastsim_calibrated_error_pct": math.nan,
                "fastsim_calibrated_status": "not run",
                "detail": "",
            }
            for col, prows in (("fastsim", peer_rows), ("fastsim_calibrated", peer_cal_rows)):
                pr = prows.get((v.key, c))
                if pr is None:
                    continue
                mpg = pr.get("peer_mpg", math.nan)
                if math.isfinite(mpg):
                    row[f"{col}_mpg"] = round(mpg, 4)
                    row[f"{col}_error_pct"] = round(100.0 * (mpg / meas_c - 1.0), 4)
                miss = pr.get("trace_miss") if "trace_miss" in pr else pr.get("peer_trace_met") is False
                row[f"{col}_status"] = pr.get("peer_error") or ("trace_miss" if miss else "ok")
            pred = preds.get((v.key, c))
            err = failed.get((v.key, c)) or (pred or {}).get("error") or ("" if pred else "not run")
            if err:
                row["status"], row["detail"] = "failed", err
            else:
                mpg = mpg_from_l_per_100km(pred["l_per_100km_cs"])
                row["predicted_mpg"] = round(mpg, 4)
                row["error_pct"] = round(100.0 * (mpg / meas_c - 1.0), 4)
                row["machine_kw"] = round(pred["machine_kw"], 2)
                row["trace_miss_s"] = pred["trace_miss_s"]
                if pred["trace_miss_s"] > 0:
                    row["status"] = "trace_miss"
                    row["detail"] = (
                        f"the powertrain cannot give the trace's power for {pred['trace_miss_s']:g} s"
                    )
            rows.append(row)
    out["rows"] = rows
    return out


class PeerCalibration(NamedTuple):
    """How a fleet part's FASTSim peer is calibrated: ``grid_chunk`` runs (record, test) items on its
    technology grid (rows with ``log_l100``), ``calibrate`` fits its ``params`` per (fold, class) from them,
    ``run_chunk`` runs (record, test, technology) items; ``vehicle`` names FASTSim's vehicle."""

    grid_chunk: Callable
    calibrate: Callable
    run_chunk: Callable
    params: tuple
    vehicle: str


def _calibrated_peer(spec, executor, work, class_of, fold_of, k, classes, label, out, progress) -> dict:
    """FASTSim calibrated as vpsim is on these records (``spec``: :class:`PeerCalibration`): its grid on
    every (record, test), its parameters fitted per fold and vpsim's class out of fold, then every record
    run at its fold's values. Returns {(key, test): row}; the fits go into ``out["peer_technology"]``
    ("fold<k>.<class>"), or why not into ``out["peer_technology_status"]``."""
    from .run import _log_l100, _progress

    items = [(v, c) for v, cs in work for c in cs]
    size = max(1, HEV_CHUNK // 2)
    t0 = time.perf_counter()
    grid_rows: list[dict] = []
    for i, part in enumerate(
        executor.map(spec.grid_chunk, [items[j : j + size] for j in range(0, len(items), size)])
    ):
        grid_rows += part
        _progress(
            f"{label}: FASTSim's calibration grid, tests",
            min((i + 1) * size, len(items)),
            len(items),
            t0,
            progress,
        )
    by_key = {v.key: v for v, _ in work}
    ok = [r for r in grid_rows if r["log_l100"] is not None]
    if not ok:
        out["peer_technology_status"] = "no record ran on FASTSim's calibration grid: " + (
            grid_rows[0]["peer_error"] if grid_rows else "no test"
        )
        return {}
    ptech = spec.calibrate(
        np.stack([r["log_l100"] for r in ok]),
        np.array([_log_l100(by_key[r["key"]].measured_mpg[r["cycle"]]) for r in ok]),
        np.array([fold_of[r["key"]] for r in ok]),
        np.array([class_of[r["key"]] for r in ok], dtype=object),
        k,
        classes,
    )
    out["peer_technology"] = {f"fold{f}.{c}": _rounded(t) for (f, c), t in sorted(ptech.items())}
    out["peer_vehicle"] = spec.vehicle
    citems = [
        (v, c, {p: ptech[(fold_of[v.key], class_of[v.key])][p] for p in spec.params})
        for v, cs in work
        for c in cs
    ]
    rows: dict = {}
    for part in executor.map(
        spec.run_chunk, [citems[j : j + 2 * HEV_CHUNK] for j in range(0, len(citems), 2 * HEV_CHUNK)]
    ):
        for r in part:
            rows[(r["key"], r["cycle"])] = r
    return rows


def _peer_tech(t: dict) -> dict:
    from .peer_bev import BEV_PEER_PARAMS

    return {k: t[k] for k in BEV_PEER_PARAMS}
