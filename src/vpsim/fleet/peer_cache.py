"""FASTSim's runs for the fleet's peers, remembered on disk by a digest of everything FASTSim is given.

A fleet run spends most of its time in FASTSim (about three quarters of a `vpsim fleet` on the 2022 list):
its runs with its defaults and on its calibration grids, which do not depend on vpsim's model, the deal or
the fit. :func:`run` runs one ``SimDrive`` and keeps what the peers read of it (the vehicle's final state and
each powertrain component's) under a SHA-256 of the vehicle dict, the cycle's samples, the simulation
parameters and FASTSim's version; the next run with the same inputs reads it back instead of simulating.
The outputs are FASTSim's own numbers, stored as JSON (floats round-trip exactly; zlib-compressed, about
1 kB a run), so a remembered run gives the figures of a fresh one to the bit; anything that changes an
input changes the digest.

Where: ``$VPSIM_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/vpsim``, else ``~/.cache/vpsim``; one SQLite
file per FASTSim version and storage format (``fastsim-<version>-v1.sqlite``; 28 MB after a whole fleet
run of the 2022 list, 29,574 runs). ``VPSIM_PEER_CACHE=0`` (``vpsim fleet
--no-peer-cache``) runs FASTSim every time. A cache that cannot be opened or written is left alone with one
warning on stderr: the run goes on without it. Errors FASTSim raises are not remembered.
"""

from __future__ import annotations

import hashlib
import json
import os
import sqlite3
import sys
import zlib
from pathlib import Path

ENV_SWITCH = "VPSIM_PEER_CACHE"
ENV_DIR = "VPSIM_CACHE_DIR"
FORMAT = 1  # how a run is stored (zlib-compressed JSON): part of the file's name

_STATE: dict = {}  # per process: the open connection (or False once it failed), FASTSim cycles, params


def enabled() -> bool:
    """Whether FASTSim's runs are remembered (``VPSIM_PEER_CACHE`` is not ``0``)."""
    return os.environ.get(ENV_SWITCH, "1").strip() not in ("0", "false", "no", "off")


def cache_dir() -> Path:
    """The folder of the cache files (module docstring)."""
    if os.environ.get(ENV_DIR):
        return Path(os.environ[ENV_DIR]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base).expanduser() / "vpsim"


def _version() -> str:
    try:
        import fastsim
    except ImportError:
        return "none"
    return str(getattr(fastsim, "__version__", "unknown"))


def cache_path() -> Path:
    """The cache file of the installed FASTSim."""
    return cache_dir() / f"fastsim-{_version()}-v{FORMAT}.sqlite"


def entries() -> int | None:
    """How many runs the cache file holds (None: off, or no file yet)."""
    if not enabled():
        return None
    path = cache_path()
    if not path.is_file():
        return None
    try:
        with sqlite3.connect(path, timeout=30.0) as con:
            return int(con.execute("SELECT COUNT(*) FROM runs").fetchone()[0])
    except sqlite3.Error:
        return None


def describe(entries_before: int | None) -> dict:
    """The cache as a run report gives it: ``enabled``, ``path``, ``entries_before`` (as given) and
    ``entries_after`` the run; their difference is the FASTSim runs the cache did not hold."""
    if not enabled():
        return {"enabled": False, "path": None, "entries_before": None, "entries_after": None}
    return {
        "enabled": True,
        "path": str(cache_path()),
        "entries_before": entries_before,
        "entries_after": entries(),
    }


def _warn(what: str, exc: Exception) -> None:
    print(f"vpsim: FASTSim run cache {what} ({exc}); running FASTSim without it", file=sys.stderr)


def _connection():
    """This process's connection to the cache file (a forked worker opens its own; the file named by the
    environment now), or False."""
    path = cache_path()
    if _STATE.get("pid") != os.getpid() or _STATE.get("path") != path:
        _STATE.update(pid=os.getpid(), path=path, con=None)
    con = _STATE.get("con")
    if con is None:
        con = False
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            con = sqlite3.connect(path, timeout=60.0, isolation_level=None)
            con.execute("PRAGMA journal_mode=WAL")  # readers and one writer at a time, across processes
            con.execute("PRAGMA synchronous=NORMAL")  # no flush to disk per run: a cache, not a record
            con.execute("CREATE TABLE IF NOT EXISTS runs (key TEXT PRIMARY KEY, outputs BLOB NOT NULL)")
        except (OSError, sqlite3.Error) as exc:
            _warn(f"at {path} cannot be opened", exc)
            con = False
        _STATE["con"] = con
    return con


def _fastsim_cycle(cycle):
    import fastsim as fsim

    cycles = _STATE.setdefault("cycles", {})
    key = (cycle.name, cycle.time_s.tobytes(), cycle.speed_mps.tobytes())
    if key not in cycles:
        cycles[key] = fsim.Cycle.from_dict(
            {"time_seconds": cycle.time_s.tolist(), "speed_meters_per_second": cycle.speed_mps.tolist()}
        )
    return cycles[key]


def _sim_params():
    """The peers' simulation parameters (:func:`vpsim.fleet.peer._sim_params`): (object, its dict)."""
    if "params" not in _STATE:
        from .peer import _sim_params

        params = _sim_params()
        _STATE["params"] = (params, params.to_dict())
    return _STATE["params"]


def _cycle_token(cycle) -> str:
    """A digest of the cycle's samples (kept per process: every run of a chunk shares its cycles)."""
    tokens = _STATE.setdefault("cycle_tokens", {})
    raw = cycle.time_s.tobytes() + b"|" + cycle.speed_mps.tobytes()
    token = tokens.get(raw)
    if token is None:
        token = tokens[raw] = hashlib.sha256(raw).hexdigest()
    return token


def digest(vehicle: dict, cycle, sim_params: dict) -> str:
    """The cache key of a run: SHA-256 of its inputs (the vehicle dict and simulation parameters as JSON
    with sorted keys, the cycle's samples as float64 bytes) and FASTSim's version."""
    text = json.dumps([_version(), vehicle, _cycle_token(cycle), sim_params], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def _outputs(o: dict) -> dict:
    """What the peers read of ``SimDrive.to_dict()``: the vehicle's state and each powertrain component's,
    nested as in the dict (``["veh"]["state"]``, ``["veh"]["pt_type"][kind][component]["state"]``)."""
    veh = o["veh"]
    pt = {}
    for kind, parts in veh["pt_type"].items():
        pt[kind] = {
            name: {"state": part["state"]}
            for name, part in parts.items()
            if isinstance(part, dict) and "state" in part
        }
    return {"veh": {"state": veh["state"], "pt_type": pt}}


def _simulate(vehicle: dict, cycle, params) -> dict:
    """FASTSim itself: :func:`_outputs` of a ``SimDrive`` run."""
    import warnings

    import fastsim as fsim

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        sd = fsim.SimDrive(fsim.Vehicle.from_dict(vehicle), _fastsim_cycle(cycle), params)
        sd.run()
        return _outputs(sd.to_dict())


def run(vehicle: dict, cycle) -> dict:
    """FASTSim's ``SimDrive`` of the vehicle dict over ``cycle`` (a :class:`vpsim.cycles.Cycle`), with the
    peers' simulation parameters: :func:`_outputs` of it, from the cache where it holds the run."""
    params, params_dict = _sim_params()
    con = _connection() if enabled() else False
    key = None
    if con:
        key = digest(vehicle, cycle, params_dict)
        try:
            hit = con.execute("SELECT outputs FROM runs WHERE key = ?", (key,)).fetchone()
        except sqlite3.Error as exc:
            _warn("cannot be read", exc)
            _STATE["con"] = con = False
            hit = None
        if hit is not None:
            try:
                return json.loads(zlib.decompress(hit[0]))
            except (zlib.error, ValueError, TypeError):  # a damaged entry: run again, and replace it
                pass
    out = _simulate(vehicle, cycle, params)
    if con:
        try:
            con.execute(
                "INSERT OR REPLACE INTO runs VALUES (?, ?)", (key, zlib.compress(json.dumps(out).encode(), 6))
            )
        except sqlite3.Error as exc:
            _warn("cannot be written", exc)
            _STATE["con"] = False
    return out
