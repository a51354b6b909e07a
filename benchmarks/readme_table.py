"""The README's speed table from `vpsim bench --json` files: each figure as the range over the runs.

    vpsim bench --quick --json q1.json        # two or three times, and `vpsim bench --json full.json` once
    python benchmarks/readme_table.py q1.json q2.json q3.json full.json

Prints a Markdown table (paste it into README.md's "Speed" section and benchmarks/README.md) and a line saying
what the runs were: profile, date, cores, load average. A figure a run does not have (the first compilation
is measured by the full profile only; FASTSim when it is not installed) is left out of its range.
"""

from __future__ import annotations

import argparse
import json
from datetime import UTC, datetime
from pathlib import Path


def _row(report: dict, method: str, driver, cycle: str = "udds", tool: str = "vpsim"):
    for r in report.get("rows", []):
        if r["tool"].startswith(tool) and r["cycle"] == cycle and (tool != "vpsim" or r["method"] == method):
            if tool != "vpsim" or r["driver"] == driver:
                return r["median_ms"]
    return None


FIGURES = (
    # (label, unit, format, getter)
    ("backward, one UDDS run", "ms", "{:.2f}", lambda r: _row(r, "backward", None)),
    ("forward (driver 1), one UDDS run", "ms", "{:.1f}", lambda r: _row(r, "forward", "1")),
    ("inverse (driver 1, with smoothing), one UDDS run", "ms", "{:.2f}", lambda r: _row(r, "inverse", "1")),
    ("FASTSim 3.1 `walk()`, one UDDS run", "ms", "{:.1f}", lambda r: _row(r, None, None, tool="fastsim")),
    (
        "backward vs FASTSim on UDDS (x faster)",
        "",
        "{:.0f}x",
        lambda r: r.get("ratios", {}).get("backward_vs_fastsim_udds"),
    ),
    (
        "forward vs FASTSim on UDDS (x faster)",
        "",
        "{:.1f}x",
        lambda r: r.get("ratios", {}).get("forward_vs_fastsim_udds"),
    ),
    ("batch backward, UDDS", "runs/s", "sig3", lambda r: r.get("batch_backward_runs_per_s")),
    ("batch forward, UDDS", "runs/s", "sig3", lambda r: r.get("batch_forward_runs_per_s")),
    ("new process, kernels cached (slowest method)", "s", "{:.1f}", lambda r: r.get("cold_start_s")),
    ("first compilation of every kernel (empty cache)", "s", "{:.0f}", lambda r: r.get("first_compile_s")),
)


def _format(value: float, fmt: str) -> str:
    if fmt == "sig3":  # three significant digits, thousands separated: 114,014 -> 114,000
        return f"{float(f'{value:.3g}'):,.0f}"
    return fmt.format(value)


def _range(values, fmt: str) -> str:
    values = [v for v in values if v is not None and v == v]
    if not values:
        return "not measured"
    lo, hi = min(values), max(values)
    a, b = _format(lo, fmt), _format(hi, fmt)
    return a if a == b else f"{a} – {b}"


def table(reports: list[dict]) -> str:
    lines = ["| figure | measured (range over the runs) |", "| --- | --- |"]
    for label, unit, fmt, get in FIGURES:
        vals = []
        for r in reports:
            try:
                vals.append(get(r))
            except (KeyError, TypeError):
                vals.append(None)
        cell = _range(vals, fmt)
        if unit and cell != "not measured":
            cell += f" {unit}"
        lines.append(f"| {label} | {cell} |")
    return "\n".join(lines)


def describe(reports: list[dict], paths: list[Path]) -> str:
    profiles = ", ".join(sorted({r.get("profile", "?") for r in reports}))
    m = reports[0].get("machine", {})
    loads = [x for r in reports for x in (r.get("machine", {}).get("load_average_start_end") or [])]
    dates = sorted(datetime.fromtimestamp(p.stat().st_mtime, UTC).strftime("%Y-%m-%d") for p in paths)
    load = f"{min(loads):.1f}–{max(loads):.1f}" if loads else "unknown"
    return (
        f"{len(reports)} runs of `vpsim bench` ({profiles}), {dates[0]}"
        + (f" to {dates[-1]}" if dates[-1] != dates[0] else "")
        + f"; {m.get('cores', '?')} cores ({m.get('processor') or m.get('platform', '?')}), "
        f"Python {m.get('python', '?')}, NumPy {m.get('numpy', '?')}, Numba {m.get('numba', '?')}; "
        f"load average {load} during the runs"
    )


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("json", nargs="+", type=Path, help="files written by vpsim bench --json")
    args = ap.parse_args(argv)
    reports = [json.loads(p.read_text()) for p in args.json]
    print(describe(reports, args.json))
    print()
    print(table(reports))


if __name__ == "__main__":
    main()
