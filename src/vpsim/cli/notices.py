"""What the command line says while it waits: one-time compilation of the kernels, and long work ahead.

The library never prints. The compiled kernels are Numba functions cached on disk (beside the modules, or in
``$NUMBA_CACHE_DIR``); the first run after installing (or after their source changed) compiles them, which
takes seconds to a minute on a small machine. Numba announces a real compilation (not a load from its disk
cache) with a ``numba:compile`` event; :func:`announce_compilation` listens for it in this process and says
on stderr, as the compilation starts, what is compiled and that it happens once. Work done in other
processes (a sweep's workers) cannot be heard that way: :func:`cold_kernels` looks at the disk cache's index
instead.
"""

from __future__ import annotations

import importlib
import sys

import click

# which kernels a module's compiled functions are, and what their compilation costs on a 2-core machine,
# quiet to loaded (measured with an empty cache, 2026-12-03: benchmarks/first_run.py; the electric and hybrid
# ones 2026-12-06, a process whose model's kernels were cached: bev 7.6-8.7 s, the P2 and mild hybrid 19-21 s
# backward and inverse, 21-25 s forward, the power split 15-16 s, each on a quiet machine; the upper ends
# since 2026-12-08, a quiet 2-core machine 2.5-3.5 times slower (FASTSim's UDDS run 25 ms against 7), each
# process's wall time less its 1.5 s of start: the engine car's backward 37 s with the views and look-ups,
# inverse 27 s, forward 76 s; bev 13-17 s; the P2 39-40 s per method; the power split 35-38 s).
# ``pip install .`` compiles them all into the package (setup.py): these are heard only where that cache does
# not serve (an editable install, another processor, a $NUMBA_CACHE_DIR of one's own, an edited source).
KERNELS = {
    "vpsim.model.engine": ("model's array views", "1-3 s"),
    "vpsim.model.tables": ("model's table look-ups", "1-2 s"),
    "vpsim.methods.backward": ("backward kernels", "15-35 s"),
    "vpsim.methods.forward": ("forward method's start state and batch", "2-40 s"),
    "vpsim.methods._fdm_rosenbrock": ("forward integrator", "35-110 s"),
    "vpsim.methods._fdm_dopri5": ("forward method's Dormand-Prince integrator", "20-50 s"),
    "vpsim.methods.inverse": ("inverse kernels", "10-30 s"),
    "vpsim.methods.bev": ("battery-electric kernels", "5-20 s"),
    "vpsim.methods.hev": ("hybrid kernels", "15-45 s"),
    "vpsim.methods.hev_forward": ("hybrids' forward kernels", "15-45 s"),
    "vpsim.methods.hev_split": ("power-split hybrid kernels", "15-40 s"),
}
_MODEL = ("vpsim.model.engine", "vpsim.model.tables", "vpsim.methods.backward")  # maps and gear rule too
METHOD_MODULES = {
    "backward": _MODEL,
    "forward": (*_MODEL, "vpsim.methods._fdm_rosenbrock", "vpsim.methods.forward"),
    "inverse": (*_MODEL, "vpsim.methods.inverse"),
}

_listener = None


def echo(message: str) -> None:
    """One line on stderr, on a line of its own even while a progress bar is drawn on a terminal."""
    prefix = "\r\x1b[K" if sys.stderr.isatty() else ""
    click.echo(prefix + message, err=True)


def _kernel_group(dispatcher) -> tuple[str, str] | None:
    module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
    if module.split(".")[0] != "vpsim":
        return None
    return KERNELS.get(module, (f"compiled functions of {module}", "some seconds"))


def announce_compilation(say=echo) -> bool:
    """Say on stderr when vpsim's kernels start compiling (once per kind) and when done; idempotent.

    Returns False when this Numba has no event API (then nothing is said).
    """
    global _listener
    if _listener is not None:
        return True
    try:
        from numba.core import event
    except ImportError:  # pragma: no cover - numba is a dependency
        return False

    class CompileNotice(event.Listener):
        """Announces the outermost compilation of each kind of kernel (nested ones are part of it)."""

        def __init__(self):
            self.said: set[str] = set()
            self.depth = 0

        def on_start(self, ev):
            self.depth += 1
            if self.depth > 1:
                return
            group = _kernel_group(ev.data.get("dispatcher") if isinstance(ev.data, dict) else None)
            if group is None or group[0] in self.said:
                return
            what, how_long = group
            self.said.add(what)
            say(
                f"vpsim: compiling the {what} (one-time: cached on disk for later runs; {how_long} on "
                "2 cores; `python -m vpsim.precompile` compiles all ahead)"
            )

        def on_end(self, ev):
            self.depth = max(self.depth - 1, 0)

    _listener = CompileNotice()
    event.register("numba:compile", _listener)
    return True


def cold_kernels(methods) -> list[str]:
    """The kinds of kernels the given methods need that have nothing usable in the disk cache.

    A compiled function whose cache index is absent or stale (its source changed) is cold. This reads
    Numba's cache through its dispatchers' cache objects; if that is not possible, nothing is reported.
    """
    modules = []
    for m in methods:
        modules += [x for x in METHOD_MODULES.get(m, ()) if x not in modules]
    cold = []
    try:
        from numba.core.caching import NullCache
        from numba.core.dispatcher import Dispatcher
    except ImportError:  # pragma: no cover
        return []
    for name in modules:
        try:
            mod = importlib.import_module(name)
        except ImportError:
            continue
        for obj in vars(mod).values():
            if not isinstance(obj, Dispatcher) or getattr(obj.py_func, "__module__", None) != name:
                continue
            cache = getattr(obj, "_cache", None)
            if cache is None or isinstance(cache, NullCache):
                continue
            try:
                empty = not cache._cache_file._load_index()
            except Exception:  # noqa: BLE001 - Numba's internals moved: better silent than wrong
                return []
            if empty:
                cold.append(KERNELS.get(name, (name, ""))[0])
                break
    return cold
