"""Compile every kernel once and leave it in the on-disk cache, so that no run has to.

``pip install .`` runs this on the package it is about to install (``setup.py``), so that a user's first
``vpsim simulate`` loads its kernels (about a second) instead of compiling them (tens of seconds). Anyone
can run it again, for example after installing a wheel built on another machine (a cache built for another
processor is not used), or to warm a ``$NUMBA_CACHE_DIR``::

    python -m vpsim.precompile            # all kernels, two processes
    python -m vpsim.precompile --jobs 1   # one process

Each group below compiles what one kind of run needs, by running it on a short cycle: Numba compiles per
argument type, not value, so one run of each signature is enough. The groups run in parallel processes;
kernels both need (the model's maps) are compiled by each, and the cache takes either copy.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

# what each group runs: every signature the methods, their drivers, solvers and modes, the batch (sweeps)
# and the maps compile
GROUPS = {  # the first two of about equal length (60 s on a 2-core machine), the third shorter (about 30 s)
    "rosenbrock": "forward method (Rosenbrock, the default solver) and its batch",
    "others": "backward and inverse methods, their batch, the maps, the forward method's Dormand-Prince and "
    "the battery-electric and hybrid cars",
    "split": "power-split hybrid",
}


def _short_cycle():
    import numpy as np

    from .cycles import Cycle

    t = np.arange(0.0, 41.0)
    v = np.interp(t, [0, 2, 12, 22, 34, 38, 40], [0, 0, 12, 14, 3, 0, 0])  # m/s: stop, go, cruise, stop
    return Cycle(name="precompile", time_s=t, speed_mps=v)


class _GivenMap:
    """An engine map that is not generated (a measured one, say): the backward method asks it for fuel."""

    def __init__(self):
        from .model.maps import cached_engine_map
        from .params import load_parameters

        self._map = cached_engine_map(load_parameters("hofman2011").engine)

    def __getattr__(self, name):
        return getattr(self._map, name)


def _array_views():
    """The model's array views (maps, figures, parameter checks) and table look-ups."""
    import numpy as np

    from .model import engine as en
    from .model import tables
    from .model.record import engine_record
    from .params import load_parameters

    rec = engine_record(load_parameters("hofman2011").engine)
    x = np.array([0.3, 0.6])
    en.psi_array(x, rec)
    en.dpsi_dpr_array(x, rec)
    en.throttle_for_flow_array(x * 1e5, x * 1e-3, rec)
    en.manifold_pressure_rate_array(x * 1e5, x * 1e-4, x * 300.0, rec)
    en.full_load_torque_array(x * 300.0, rec)
    en.steady_pressure_array(x * 1e-4, x * 300.0, rec)
    tables.interp(x, np.array([0.0, 1.0]), np.array([1.0, 2.0]))
    tables.bilinear(np.array([0.0, 1.0]), np.array([0.0, 1.0]), np.eye(2), x, x)


KERNEL_MODULES = (
    "vpsim.model.engine",
    "vpsim.model.tables",
    "vpsim.methods.backward",
    "vpsim.methods.backward_variants",
    "vpsim.methods._fdm_system",
    "vpsim.methods._fdm_rosenbrock",
    "vpsim.methods._fdm_dopri5",
    "vpsim.methods.forward",
    "vpsim.methods.inverse",
    "vpsim.methods.bev",
    "vpsim.methods.hev",
    "vpsim.methods.hev_split",
    "vpsim.performance",
    "vpsim.methods.hev_forward",
)


def uncompiled() -> list[str]:
    """vpsim's kernels that have nothing in the disk cache (after :func:`precompile`: none)."""
    import importlib

    from numba.core.dispatcher import Dispatcher

    out = []
    for name in KERNEL_MODULES:
        mod = importlib.import_module(name)
        for attr, obj in sorted(vars(mod).items()):
            if isinstance(obj, Dispatcher) and obj.py_func.__module__ == name:
                try:
                    empty = not obj._cache._cache_file._load_index()
                except AttributeError:  # a Numba whose cache internals moved: nothing to say
                    return []
                if empty:
                    out.append(f"{name}.{attr}")
    return out


def run_group(group: str) -> None:
    """Compile the kernels of ``group`` (a key of :data:`GROUPS`) in this process."""
    import vpsim
    from vpsim.batch import run_batch

    cycle = _short_cycle()
    variants = {"vehicle.mass": [1200.0, 1300.0]}
    if group == "others":
        _array_views()
        for mode in ("paper", "realistic"):
            vpsim.simulate(cycle, method="backward", mode=mode, engine_map=_GivenMap())
            vpsim.simulate(cycle, method="backward", mode=mode)
            for driver in ("1", "2"):
                vpsim.simulate(cycle, method="inverse", mode=mode, driver=driver)
            run_batch(cycle, variants, method="backward", mode=mode)
            vpsim.simulate(cycle, method="forward", mode=mode, solver="dopri5")
        for method in ("backward", "forward", "inverse"):  # the battery-electric car
            vpsim.simulate(cycle, method=method, params="bev")
        for ems in ("ecms", "dp"):  # the hybrid (rule and ecms share one kernel)
            vpsim.simulate(cycle, method="backward", params="hev_p2", ems=ems)
        vpsim.simulate(cycle, method="inverse", params="hev_p2")
        from vpsim.performance import acceleration_time

        acceleration_time(vpsim.load_parameters("hev_p2"))  # the P2's boost-torque table
        vpsim.simulate(cycle, method="forward", params="hev_p2")
    elif group == "split":  # the power-split hybrid (rule and ecms share one kernel)
        for ems in ("ecms", "dp"):
            vpsim.simulate(cycle, method="backward", params="hev_split", ems=ems)
        vpsim.simulate(cycle, method="inverse", params="hev_split")
        vpsim.simulate(cycle, method="forward", params="hev_split")
    elif group == "rosenbrock":
        for mode in ("paper", "realistic"):
            vpsim.simulate(cycle, method="forward", mode=mode)
            run_batch(cycle, variants, method="forward", mode=mode)
    else:
        raise ValueError(f"unknown group {group!r}; expected one of {', '.join(GROUPS)}")


def precompile(jobs: int = 2, say=print, env: dict | None = None) -> bool:
    """Compile every group, ``jobs`` processes at a time; True if all of them finished."""
    env = {**os.environ, **(env or {})}
    pending = list(GROUPS)
    running: list[tuple[str, subprocess.Popen, float]] = []
    ok = True
    while pending or running:
        while pending and len(running) < max(1, jobs):
            g = pending.pop(0)
            say(f"vpsim: compiling the {GROUPS[g]} ...")
            cmd = [sys.executable, "-c", f"from vpsim.precompile import run_group; run_group({g!r})"]
            running.append((g, subprocess.Popen(cmd, env=env), time.perf_counter()))
        g, proc, t0 = running.pop(0)
        rc = proc.wait()
        ok &= rc == 0
        say(
            f"vpsim: {GROUPS[g]}: {'compiled' if rc == 0 else f'failed (exit {rc})'} in "
            f"{time.perf_counter() - t0:.0f} s"
        )
    missing = uncompiled() if ok else []
    if missing:
        say(f"vpsim: not compiled ahead (they compile on first use): {', '.join(missing)}")
    return ok


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m vpsim.precompile", description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=2, help="processes at a time (default 2)")
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error(f"--jobs {args.jobs}: expected 1 or more")
    return 0 if precompile(args.jobs) else 1


if __name__ == "__main__":
    raise SystemExit(main())
