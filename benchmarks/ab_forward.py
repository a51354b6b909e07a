"""Two versions of the forward kernel against each other, in one process: the figure for a kernel change.

    python benchmarks/ab_forward.py OLD_SRC NEW_SRC                 # e.g. a worktree of main, and src/
    python benchmarks/ab_forward.py OLD_SRC NEW_SRC --cycles udds,nedc,us06,ftp75 --runs 300

OLD_SRC and NEW_SRC are ``src`` folders of two checkouts (or their ``vpsim`` package folders). Each package
is copied under a name of its own (``vpsim_a``, ``vpsim_b``: the package imports itself relatively) into a
scratch folder kept between calls, so Numba's on-disk cache serves a version already compiled. For every
cycle each version runs once through ``simulate`` (driver 1, realistic mode, its own gear schedule) with
the Rosenbrock kernel's arguments captured; then the two compiled kernels run on their arguments
alternately, ``--runs`` times each (garbage collector paused), and the script prints both medians, the
median of the per-pair ratios B/A (< 1: B faster), and each version's steps, right-side evaluations and
fuel (with their relative difference), which a change meant to be only faster leaves alone or moves by
rounding only.

Why: this 2-core virtual machine's speed drifts by up to 1.5x over minutes, so versions timed in
alternating processes differ by more than a change of a few per cent; run by run in one process, the pair
ratio resolves 1-2 %. Parameter presets come from the installed ``vpsim`` (``importlib.resources``).
"""

from __future__ import annotations

import argparse
import gc
import importlib
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SCRATCH = Path(tempfile.gettempdir()) / "vpsim_ab_forward"  # (default; --scratch)


def _package_dir(src: str) -> Path:
    p = Path(src).resolve()
    pkg = p / "vpsim" if (p / "vpsim" / "__init__.py").is_file() else p
    if not (pkg / "methods" / "forward.py").is_file():
        raise SystemExit(f"ab_forward: {src}: no vpsim package here (expected vpsim/methods/forward.py)")
    return pkg


def _install(src: str, name: str, scratch: Path) -> None:
    """Copy package ``src`` to scratch/name; files whose text is unchanged keep their time stamps, so a
    kernel compiled from them before is loaded from Numba's cache."""
    dst = scratch / name
    pkg = _package_dir(src)
    dst.mkdir(parents=True, exist_ok=True)
    wanted = {f.relative_to(pkg) for f in pkg.rglob("*") if f.is_file() and "__pycache__" not in f.parts}
    for rel in wanted:
        target = dst / rel
        if not target.is_file() or target.read_bytes() != (pkg / rel).read_bytes():
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(pkg / rel, target)
    for f in list(dst.rglob("*")):
        if f.is_file() and "__pycache__" not in f.parts and f.relative_to(dst) not in wanted:
            f.unlink()


def _prepared(pkg: str, cycle: str):
    """(the kernel with its captured arguments, the run's Result) for package ``pkg`` on ``cycle``."""
    sim = importlib.import_module(f"{pkg}.simulation")
    fw = importlib.import_module(f"{pkg}.methods.forward")
    kernel = fw._integrate_ros
    captured = {}

    class Capture:
        overloads = True  # forward.warm_up looks at it

        def __call__(self, *args):
            captured["args"] = args
            return kernel(*args)

    fw._integrate_ros = Capture()
    try:
        result = sim.simulate(cycle, "forward", "hofman2011", driver="1")
    finally:
        fw._integrate_ros = kernel
    args = captured["args"]
    return (lambda: kernel(*args)), result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("old_src")
    ap.add_argument("new_src")
    ap.add_argument("--cycles", default="udds,nedc,us06", help="comma-separated cycle names")
    ap.add_argument("--runs", type=int, default=300, help="timed runs of each version per cycle")
    ap.add_argument("--warmup", type=int, default=20, help="untimed runs of each version first (default 20)")
    ap.add_argument(
        "--scratch", type=Path, default=SCRATCH, help=f"where the copies live (default {SCRATCH})"
    )
    a = ap.parse_args(argv)
    if a.runs < 1:
        ap.error(f"--runs {a.runs}: expected at least 1")
    if a.warmup < 0:
        ap.error(f"--warmup {a.warmup}: expected 0 or more")
    _install(a.old_src, "vpsim_a", a.scratch)
    _install(a.new_src, "vpsim_b", a.scratch)
    for name in [m for m in sys.modules if m.split(".")[0] in ("vpsim_a", "vpsim_b")]:
        del sys.modules[name]  # (a second call in one process imports the copies it made, not the first's)
    sys.path.insert(0, str(a.scratch))
    print(f"A = {_package_dir(a.old_src)}\nB = {_package_dir(a.new_src)}", flush=True)
    for cycle in a.cycles.split(","):
        try:
            run_a, res_a = _prepared("vpsim_a", cycle)
            run_b, res_b = _prepared("vpsim_b", cycle)
        except Exception as exc:  # a version's own error (an unknown cycle, ...): its one line, no traceback
            raise SystemExit(f"ab_forward: {cycle}: {exc}") from None
        for _ in range(a.warmup):
            run_a()
            run_b()
        ta, tb = np.empty(a.runs), np.empty(a.runs)
        gc.disable()
        try:
            for i in range(a.runs):
                t0 = time.perf_counter()
                run_a()
                t1 = time.perf_counter()
                run_b()
                ta[i], tb[i] = t1 - t0, time.perf_counter() - t1
        finally:
            gc.enable()
        same_steps = (
            res_a.steps == res_b.steps and res_a.solver["rhs_evaluations"] == res_b.solver["rhs_evaluations"]
        )
        print(
            f"{cycle}: A {np.median(ta) * 1e3:.3f} ms, B {np.median(tb) * 1e3:.3f} ms (medians of {a.runs}); "
            f"B/A {np.median(tb / ta):.3f} (median of the pairs); steps {res_a.steps} / {res_b.steps}, "
            f"evaluations {res_a.solver['rhs_evaluations']} / {res_b.solver['rhs_evaluations']}"
            f"{' (the same)' if same_steps else ''}, fuel {res_a.fuel_kg:.9g} / {res_b.fuel_kg:.9g} kg "
            f"(relative difference {abs(res_b.fuel_kg / res_a.fuel_kg - 1.0):.1e})",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
