"""``report.md``, the fleet report's text: :func:`markdown` and the sections it is made of, written from
the summary, the run info and the rows (:func:`vpsim.fleet.report.write_outputs` calls it)."""

from __future__ import annotations

import math
from pathlib import Path

from . import calibrate as cal
from .report import (
    BOOTSTRAP_RESAMPLES,
    GROUPS,
    MHEV_PEER_NOTE,
    POWERTRAINS,
    REPEATABILITY_TOLERANCES_PCT,
    _ev,
    _hev,
    _in_order,
    breakdown,
    technology_bounds,
)


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
        "each with its own technology (`machine.loss_scale`, `electric.accessory_power`, "
        "`transmission.efficiency`) fitted on the same "
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
    L += _differences_md(s["peer"]["vpsim_minus_fastsim_calibrated_by_powertrain"])
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
            "| fold.class | machine loss scale | accessories, W | drive efficiency | training rows "
            "| on a bound |",
            "|---|---|---|---|---|---|",
        ]
        for k, t in {
            **run.ev["technology"],
            **{f"all.{c}": t for c, t in run.ev["technology_all"].items()},
        }.items():
            hits = ev.on_bounds(t)
            L.append(
                f"| {k} | {t[ev.TECH_PARAMS[0]]:.2f} | {t[ev.TECH_PARAMS[1]]:.0f} | "
                f"{t[ev.TECH_PARAMS[2]]:.3f} | {t['n_train']} | "
                + (", ".join(f"{p.split('.')[1]} {side}" for p, side in hits.items()) or "–")
                + " |"
            )
        reasons = {(p, side) for t in run.ev["technology"].values() for p, side in ev.on_bounds(t).items()}
        for p, side in sorted(reasons):
            L.append(f"\n`{p}` on its {side} bound: the bound stays: {ev.BOUND_REASONS.get((p, side), '')}.")
    return L + _hev_md(run, s)


def _differences_md(d: dict) -> list[str]:
    """vpsim's median |error| against the calibrated FASTSim's, with a family bootstrap's interval
    (``peer.vpsim_minus_fastsim_calibrated_by_powertrain``)."""
    if d.get("measured") is False:
        return ["", f"vpsim against the calibrated FASTSim: not measured ({d.get('reason')})."]
    L = [
        "",
        "### vpsim against the calibrated FASTSim, with its uncertainty",
        "",
        "Median |error| of vpsim minus that of the calibrated FASTSim on the same rows (points; negative: "
        "vpsim closer to the measurement), and a 95 % interval from a paired bootstrap that draws whole "
        f"families (the groups the folds hold out together), {BOOTSTRAP_RESAMPLES:,} draws. "
        "An interval that straddles 0 does not tell the two apart on this list. These figures are of one "
        "deal of families into folds (`validation.seed`, `validation.deal`); `vpsim fleet FILE --out DIR "
        "--seed N` runs another, and `vpsim fleet-deals DIR DIR ...` sets several side by side.",
        "",
        "| powertrain | test | n | families | vpsim | FASTSim calibrated | difference | 95 % interval "
        "| share of draws with vpsim lower |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for pt, tests in d.items():
        if tests.get("measured") is False:
            L.append(f"| {pt} | – | – | – | – | not measured ({tests.get('reason')}) | – | – | – |")
            continue
        for c, v in tests.items():
            if v.get("measured") is False:
                L.append(f"| {pt} | {c} | 0 | – | – | – | – | – | – |")
                continue
            lo, hi = v["ci95_pts"]
            L.append(
                f"| {pt} | {c} | {v['n']} | {v['families']} | {v['median_abs_error_pct']:.2f} % | "
                f"{v['peer_median_abs_error_pct']:.2f} % | {v['difference_pts']:+.2f} | "
                f"{lo:+.2f} to {hi:+.2f} | {v['share_vpsim_lower']:.2f} |"
            )
    return L


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


def _deal_words(run) -> str:
    """How the groups were dealt into folds, in words (``validation.seed``, ``validation.deal``)."""
    if run.grouping == "manufacturer":
        return "a fold per manufacturer"
    how = {
        "shuffle": "shuffled with seed {} and dealt to the emptiest fold",
        "hash": "each to the fold a hash of seed {} and its name picks (folds balanced on average only)",
        "blocks": "in the order a hash of seed {} and their names gives, cut into blocks of equal records",
    }[run.deal]
    return how.format(run.seed) + ("" if run.seed == cal.SEED else f"; the fleet's seed is {cal.SEED}")


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
        + f" ({run.n_groups} groups, {_deal_words(run)}): **every error below is out of fold**. Constants "
        "chosen while looking at this list's errors are listed at the end of this report.",
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
