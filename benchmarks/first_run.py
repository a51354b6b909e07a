"""A newcomer's first minutes, timed: `pip install .` in a fresh virtual environment, then the first run of
each method, `vpsim paper`, and a later process; then the same first runs with an empty kernel cache (what
an install without the precompiled kernels, or an edited source, costs).

    python benchmarks/first_run.py [--json FILE] [--keep DIR]

Prints one line per figure (wall seconds, and the child processes' CPU seconds) and, with --json, keeps them.
Takes 6-9 minutes on a 2-core machine (the install compiles every kernel, about a minute and a half of it).
Targets (issue "kernels ready in seconds"): first run of each method <= 10 s, `vpsim paper` <= 60 s, a later
process <= 1 s; the same 10 s for each method on the battery-electric car and, with each energy management
the forward method takes, on the three hybrids (the electric-drive and hybrid issues): these run after the
engine car's, each in a process of its own, and again into an empty cache (after the one before), which
``--no-electrified`` leaves out.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
METHODS = ("backward", "inverse", "forward")
# the electrified presets and the energy managements each method takes (None: not a hybrid)
ELECTRIFIED = (
    ("bev", (None,)),
    ("hev_p2", ("rule", "ecms")),
    ("hev_split", ("rule", "ecms")),
    ("mhev", ("rule", "ecms")),
)


def _electrified_runs():
    """(label, extra arguments) of each electrified first run: every preset on every method."""
    for vehicle, managements in ELECTRIFIED:
        for m in METHODS:
            for ems in managements:
                label = f"{vehicle} {m}" + (f" {ems}" if ems else "")
                yield label, ["--vehicle", vehicle, "--method", m, *(["--ems", ems] if ems else [])]


def _timed(cmd, cwd, env) -> tuple[float, float, str]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(map(str, cmd))} exited {proc.returncode}: {proc.stderr.strip()[-500:]}")
    return wall, cpu, proc.stderr


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, help="write the figures here")
    ap.add_argument("--keep", type=Path, help="build the venv here and keep it (default: a temporary folder)")
    ap.add_argument(
        "--no-electrified",
        action="store_true",
        help="time the engine car only (the battery-electric car and hybrids not)",
    )
    args = ap.parse_args(argv)
    root = Path(tempfile.mkdtemp(prefix="vpsim-first-run-")) if args.keep is None else args.keep
    root.mkdir(parents=True, exist_ok=True)
    src, venv, work = root / "src", root / "venv", root / "work"
    shutil.rmtree(src, ignore_errors=True)
    shutil.copytree(
        REPO,
        src,
        ignore=shutil.ignore_patterns(".git", "__pycache__", "build", "dist", "*.egg-info", "*.nbi", "*.nbc"),
    )
    work.mkdir(exist_ok=True)
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "NUMBA_CACHE_DIR")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["VIRTUAL_ENV"] = str(venv)
    env["MPLBACKEND"] = "Agg"
    out: dict = {"date": time.strftime("%Y-%m-%d"), "cpus": os.cpu_count(), "load_before": os.getloadavg()}

    def report(key, wall, cpu, note=""):
        out[key] = {"wall_s": round(wall, 2), "cpu_s": round(cpu, 2)}
        print(f"{key:<44} {wall:7.1f} s wall {cpu:7.1f} s CPU {note}", flush=True)

    wall, cpu, _ = _timed([str(venv / "bin" / "pip"), "install", "-q", str(src)], work, env)
    report("pip install . (with the kernels)", wall, cpu)
    vpsim = str(venv / "bin" / "vpsim")
    for m in METHODS:
        wall, cpu, err = _timed([vpsim, "simulate", "--cycle", "udds", "--method", m, "--json"], work, env)
        report(f"first run: {m}, udds", wall, cpu, "(compiled)" if "vpsim: compiling" in err else "")
    if not args.no_electrified:
        for label, extra in _electrified_runs():
            wall, cpu, err = _timed([vpsim, "simulate", "--cycle", "udds", *extra, "--json"], work, env)
            report(f"first run: {label}, udds", wall, cpu, "(compiled)" if "vpsim: compiling" in err else "")
    wall, cpu, err = _timed([vpsim, "paper", "--out", str(work / "paper")], work, env)
    report("first run: vpsim paper", wall, cpu, "(compiled)" if "vpsim: compiling" in err else "")
    walls = []
    for _ in range(3):
        w, c, _ = _timed([vpsim, "simulate", "--cycle", "udds", "--method", "forward", "--json"], work, env)
        walls.append((w, c))
    wall, cpu = min(walls)
    report("later process: forward, udds (best of 3)", wall, cpu)
    # the same first runs with an empty cache of their own: what compiling costs
    with tempfile.TemporaryDirectory(prefix="vpsim-empty-cache-") as cache:
        cold = {**env, "NUMBA_CACHE_DIR": cache}
        for m in METHODS:
            wall, cpu, _ = _timed([vpsim, "simulate", "--cycle", "udds", "--method", m, "--json"], work, cold)
            report(f"empty cache: {m}, udds (after the one before)", wall, cpu)
        if not args.no_electrified:
            for label, extra in _electrified_runs():
                wall, cpu, _ = _timed([vpsim, "simulate", "--cycle", "udds", *extra, "--json"], work, cold)
                report(f"empty cache: {label}, udds (after the one before)", wall, cpu)
    out["load_after"] = os.getloadavg()
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    if args.keep is None:
        shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
