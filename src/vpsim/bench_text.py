"""The benchmark's report (:func:`vpsim.bench.run_benchmarks`) as text: one table of runs, then setup, batch,
linearity, cold start, ratios and targets. ``vpsim bench`` prints it."""

from __future__ import annotations

import math

from .bench import PEER, PEER_VERSION, _find


def _fmt(v, spec: str, none: str = "-") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return none
    return format(v, spec)


def format_report(report: dict) -> str:
    """The benchmark as text: one table of runs, then setup, batch, linearity, cold start, ratios, targets."""
    m = report["machine"]
    lines = [
        f"vpsim bench ({report['profile']}): {m['cores']} cores, Python {m['python']}, numpy {m['numpy']}, "
        f"numba {m['numba']}; load average {_fmt(m['load_average_start_end'][0], '.2f')} at the start, "
        f"{_fmt(m['load_average_start_end'][1], '.2f')} at the end",
        "median wall time of repeated runs, inputs prepared (setup below)",
        "",
        f"{'tool':<14} {'method':<20} {'drv':<3} {'cycle':<6} {'median ms':>10} {'runs':>5} {'steps':>6} "
        f"{'py peak KiB':>11} {'RSS+ KiB':>9} {'L/100km':>8}",
    ]
    for r in report["rows"]:
        lines.append(
            f"{r['tool']:<14} {r['method']:<20} {r['driver'] or '-':<3} {r['cycle']:<6} "
            f"{r['median_ms']:>10.3f} {'fresh' if r['runs'] < 0 else r['runs']:>5} {r['steps']:>6d} "
            f"{_fmt(r['py_peak_kib'], '11.0f'):>11} "
            f"{_fmt(r['rss_peak_kib'], '9.0f'):>9} {_fmt(r['fuel_l_per_100km'], '8.2f'):>8}"
        )
    for f in report["failures"]:
        lines.append(
            f"{'vpsim':<14} {f['method']:<20} {f['driver'] or '-':<3} {f['cycle']:<6} failed: {f['error']}"
        )
    peer = report["peer"]
    if not peer["available"]:
        lines.append(f"{PEER + ' ' + PEER_VERSION:<14} not measured: {peer['reason']}")
    for r in report["rows"]:
        fresh = report.get("peer_fresh_processes", {}).get(r["cycle"], {}) if r["tool"] != "vpsim" else {}
        if fresh.get("median_ms_per_process"):
            per = ", ".join(f"{m:.2f}" for m in fresh["median_ms_per_process"])
            lines.append(
                f"  {PEER} on {r['cycle']}: the faster of {r['in_process_median_ms']:.2f} ms here and "
                f"{per} ms in fresh processes of its own, each after its warm-up"
            )
    for key, fresh in report.get("vpsim_fresh_processes", {}).items():
        method, driver, cycle = key.split("/")
        row = _find(report["rows"], "vpsim", method, None if driver == "-" else driver, cycle)
        if fresh.get("median_ms_per_process") and row is not None:
            per = ", ".join(f"{m:.3f}" for m in fresh["median_ms_per_process"])
            label = method + ("" if driver == "-" else f" driver {driver}")
            lines.append(
                f"  vpsim {label} on {cycle}: {row['median_ms']:.3f} ms here, {per} ms in fresh processes of "
                "its own, each after the same warm-up"
            )
    su = report["setup"]["vpsim"]
    sched = ", ".join(f"{k} {v:.2f}" for k, v in su["gear_schedule_ms"].items())
    lines += [
        "",
        f"setup (outside the timed runs): vpsim engine map {su['engine_map_ms']:.1f} ms; "
        f"gear schedule ms: {sched}",
    ]
    ps = report["setup"].get(PEER) or {}
    if ps:
        new = ", ".join(f"{k} {v:.3f}" for k, v in ps["simdrive_new_ms"].items())
        lines.append(
            f"  {PEER}: Vehicle.from_resource {ps['vehicle_from_resource_ms']:.2f} ms; SimDrive() ms: {new}"
        )
    lines.append("")
    for key in ("batch_backward", "batch_backward_realistic", "batch_forward"):
        b = report["batch"].get(key, {})
        if b.get("runs_per_s"):
            # run_batch's default: the paper mode (and driver 1 forward), where the stiff driveline creeps at
            # standstill and the soft PI leaves the band (the paper's own behaviour, docs/methods.md)
            setting = f"{b.get('mode', 'paper')} mode" + (", driver 1" if key == "batch_forward" else "")
            one = b.get("one_thread_runs_per_s")
            on_one = f"; on one thread {one:,.0f} runs/s ({b['runs_per_s'] / one:.2f}x on {b['threads']})"
            lines.append(
                f"{key.replace('_', ' ')}: {b['variants']} variants on {b['cycle']} ({setting}) "
                f"in {b['median_s']:.3f} s = "
                f"{b['runs_per_s']:,.0f} runs/s (variants with a trace miss: {b['trace_miss_share']:.0%})"
                + (on_one if one else "")
            )
        else:
            lines.append(f"{key.replace('_', ' ')}: not measured ({b.get('error', 'unavailable')})")
    lin = report["linearity"]
    for label, v in lin.items():
        if "error" in v:
            lines.append(f"linearity {label}: failed ({v['error']})")
            continue
        per = ", ".join(f"x{n}: {r:.3f}" for n, r in v["per_repetition_vs_1x"].items())
        ms = ", ".join(f"{t:.2f}" for t in v["ms"].values())
        marg = v.get("marginal_ratio")
        lines.append(
            f"linearity {label} (ftp75 repeated, {v['rounds']} rounds; time per repetition / 1x): {per}; "
            f"ms {ms}"
            + (f"; a repetition added beyond x4 costs {marg:.2f}x one added beyond x1" if marg else "")
        )
    cold = report["cold_start"]
    for method in ("backward", "forward", "inverse"):
        c = cold.get(method)
        if c and "wall_s" in c:
            lines.append(
                f"cold start {method}: {c['wall_s']:.2f} s wall for a fresh process "
                f"(import {c['import_s']:.2f} s, "
                f"first udds run {c['first_run_s']:.3f} s, kernels from the cache, as after pip install .)"
            )
        elif c:
            lines.append(f"cold start {method}: failed ({c['error']})")
    fc = cold.get("first_compile")
    if fc and "wall_s" in fc:
        lines.append(
            f"first compilation (empty cache; {fc['covers']}): {fc['wall_s']:.1f} s, "
            f"then {fc['same_run_cached_wall_s']:.2f} s "
            f"once cached (compiling: {fc['compile_s']:.1f} s)"
        )
    cache = cold["cache"]
    lines.append(
        f"Numba cache: {cache.get('vpsim.methods.backward')}"
        + (f" (NUMBA_CACHE_DIR={cache['NUMBA_CACHE_DIR']})" if cache.get("NUMBA_CACHE_DIR") else "")
    )
    lines += [
        "",
        "ratios (> 1: vpsim faster; inverse_vs_backward is a time ratio, smaller is better), "
        "median over adjacent blocks of runs of both sides:",
    ]
    for k, v in report["ratios_paired"].items():
        lines.append(
            f"  {k:<34} {v['ratio']:8.2f}  ({v['pairs']} block pairs; block medians {v['a_median_ms']:.3f} / "
            f"{v['b_median_ms']:.3f} ms)"
        )
    more = {k: v for k, v in report["ratios_from_table"].items() if v is not None}
    if more:
        lines.append("  from the table's medians (each row timed on its own, minutes apart):")
        items = [f"{k} {v:.2f}" for k, v in more.items()]
        for i in range(0, len(items), 3):
            lines.append("    " + ", ".join(items[i : i + 3]))
    used = {k: v for k, v in report["ratios"].items() if v is not None}
    if used:
        lines.append(
            "  against the targets (each side at its best settled median, its fresh processes included):"
        )
        items = [f"{k} {v:.2f}" for k, v in used.items()]
        for i in range(0, len(items), 3):
            lines.append("    " + ", ".join(items[i : i + 3]))
    bev = report.get("bev", {})
    if bev.get("vpsim"):
        peer_bev = bev.get(PEER, {})
        runs = ", ".join(f"{m} {v['median_ms']:.3f} ms" for m, v in bev["vpsim"].items())
        fs = (
            f"{PEER} BEV {peer_bev['median_ms']:.2f} ms ({peer_bev['runs']} runs, timed before vpsim's "
            "code ran)"
            if "median_ms" in peer_bev
            else f"{PEER} BEV not measured{': ' + peer_bev['failed'] if 'failed' in peer_bev else ''}"
        )
        lines += ["", f"battery-electric car (bev preset), one UDDS run: {runs}; {fs}"]
    hev = report.get("hev", {})
    if hev.get("vpsim"):
        peer_hev = hev.get(PEER, {})
        runs = ", ".join(
            f"{m} {v['median_ms']:.3f} ms (whole simulate call {v['simulate_median_ms']:.3f} ms)"
            for m, v in hev["vpsim"].items()
        )
        fs = (
            f"{PEER} hybrid {peer_hev['vehicle']} {peer_hev['median_ms']:.2f} ms ({peer_hev['runs']} runs, "
            "timed before vpsim's code ran; a different car of the same class and P2 layout)"
            if "median_ms" in peer_hev
            else f"{PEER} hybrid not measured{': ' + peer_hev['failed'] if 'failed' in peer_hev else ''}"
        )
        lines += ["", f"P2 hybrid (hev_p2 preset), one UDDS run (backward; forward_*: forward): {runs}; {fs}"]
    lines += ["", "targets:"]
    for t in report["targets"]:
        state = {True: "met", False: "MISSED", None: "not measured"}[t["met"]]
        lines.append(
            f"  {t['figure']:<41} {t['target']:>9}  measured {_fmt(t['measured'], '.3g'):>8}  {state}"
        )
    lines.append(f"\nbenchmark took {report['elapsed_s']:.1f} s")
    return "\n".join(lines)
