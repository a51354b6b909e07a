"""The battery-electric and hybrid cars' rows of ``vpsim bench`` (:mod:`vpsim.bench`): each car against
FASTSim 3.1's vehicle of its class, the peer timed before any vpsim kernel runs in the process."""

from __future__ import annotations

import time

from .bench import PEER, PEER_CYCLES, PEER_HEV_VEHICLE, Settings, _timed, _walk


def bev_peer_inputs(params) -> tuple:
    """The bev preset as FASTSim's BEV peer takes a car (:func:`vpsim.fleet.peer_bev.bev_peer_vehicle`):
    mass, road load A (N), B (N per m/s), C (N per (m/s)^2) and rated power (W), from the model's record."""
    from .model.record import record

    c = record(params)
    return (float(c.mass), float(c.rolling_force), float(c.road_load_b), float(c.aero_coefficient))


def _bev_peer_maker():
    """(a fresh SimDrive of FASTSim's BEV on the bev preset's car over UDDS, its run), the vehicle and cycle
    built once here (:func:`vpsim.fleet.peer_bev.bev_peer_vehicle`)."""
    import fastsim as fsim

    from .fleet import peer_bev as pb
    from .params import load_parameters

    p = load_parameters("bev")
    mass, a, b, cc = bev_peer_inputs(p)
    veh = fsim.Vehicle.from_dict(pb.bev_peer_vehicle(mass, a, b, cc, p.machine.rated_power))
    cyc = pb._fastsim_cycle("udds")
    params = pb._sim_params()
    return (lambda: fsim.SimDrive(veh, cyc, params)), (lambda sd: sd.run())


def bev_peer_ms(settings: Settings, progress) -> dict:
    """FASTSim 3.1's BEV on the bev preset's car over UDDS: median ms of ``SimDrive.run()`` (the vehicle and
    cycle built outside the timing), before any vpsim kernel runs in this process."""
    import warnings

    progress("FASTSim BEV on the bev preset, UDDS")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        make, call = _bev_peer_maker()
        median, runs = _timed(call, settings, setup=make)
    return {"median_ms": median * 1e3, "runs": runs}


def bev_rows(settings: Settings, progress) -> dict:
    """vpsim's battery-electric car (the bev preset) on UDDS, each method: median ms of one run."""
    from .cycles import load_cycle
    from .params import load_parameters
    from .simulation import simulate

    progress("vpsim battery-electric car, UDDS")
    p = load_parameters("bev")
    cyc = load_cycle("udds")
    out = {}
    for method in ("backward", "forward", "inverse"):
        median, runs = _timed(lambda m=method: simulate(cyc, m, p), settings)
        out[method] = {"median_ms": median * 1e3, "runs": runs}
    return out


def _hev_peer_maker():
    """(a fresh SimDrive of FASTSim's hybrid :data:`PEER_HEV_VEHICLE` over UDDS, its walk)."""
    import fastsim as fsim

    veh = fsim.Vehicle.from_resource(PEER_HEV_VEHICLE)
    cyc = fsim.Cycle.from_resource(PEER_CYCLES["udds"])
    return (lambda: fsim.SimDrive(veh, cyc)), _walk


def hev_peer_ms(settings: Settings, progress) -> dict:
    """FASTSim 3.1's hybrid (:data:`PEER_HEV_VEHICLE`, a different car than hev_p2's: see there) on UDDS:
    median ms of ``walk()`` on a SimDrive built outside the timing, after its warm-up, before any vpsim
    kernel runs in this process (as the other peer rows)."""
    import warnings

    progress(f"{PEER} hybrid {PEER_HEV_VEHICLE}, UDDS")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        make, call = _hev_peer_maker()
        t_warm = time.perf_counter()
        while time.perf_counter() - t_warm < settings.peer_warm_up_s:
            call(make())
        median, runs = _timed(call, settings, setup=make)
    return {"median_ms": median * 1e3, "runs": runs, "vehicle": PEER_HEV_VEHICLE}


def hev_rows(settings: Settings, progress) -> dict:
    """vpsim's P2 hybrid (hev_p2) on UDDS, backward and forward methods, rule and ECMS: median ms of
    one run with its inputs prepared (the gear schedule, as for the engine car's rows), and of a whole
    ``simulate`` call (the schedule derived inside)."""
    from .cycles import load_cycle
    from .gears import default_schedule
    from .methods import hev, hev_forward
    from .model.maps import cached_engine_map
    from .params import load_parameters
    from .simulation import simulate

    progress("vpsim P2 hybrid, UDDS")
    p = load_parameters("hev_p2")
    cyc = load_cycle("udds")
    schedule = default_schedule(cyc, p, cached_engine_map(p.engine))
    out = {}
    for ems in ("rule", "ecms"):
        median, runs = _timed(lambda e=ems: hev.run(cyc, p, ems=e, schedule=schedule), settings)
        whole, _ = _timed(lambda e=ems: simulate(cyc, "backward", p, ems=e), settings)
        out[ems] = {"median_ms": median * 1e3, "runs": runs, "simulate_median_ms": whole * 1e3}
    # the forward method (vpsim.methods.hev_forward): the same car and schedule, the PI driver and the
    # causal management at the 0.25 s step
    for ems in ("rule", "ecms"):
        median, runs = _timed(lambda e=ems: hev_forward.run(cyc, p, ems=e, schedule=schedule), settings)
        whole, _ = _timed(lambda e=ems: simulate(cyc, "forward", p, ems=e), settings)
        out[f"forward_{ems}"] = {"median_ms": median * 1e3, "runs": runs, "simulate_median_ms": whole * 1e3}
    return out


def best_ratio(peer_row: dict | None, own_row: dict | None, paired: dict | None) -> tuple:
    """(FASTSim's ms over vpsim's, [FASTSim's ms, vpsim's ms]) with each side at the faster of its own row's
    median (``median_ms``) and its median in the paired blocks (``a_median_ms`` FASTSim's, ``b_median_ms``
    vpsim's); the ratio None where a side has no figure (FASTSim not installed, a row that failed)."""
    paired = paired or {}

    def fastest(*values):
        return min((v for v in values if v is not None), default=None)

    peer_ms = fastest((peer_row or {}).get("median_ms"), paired.get("a_median_ms"))
    own_ms = fastest((own_row or {}).get("median_ms"), paired.get("b_median_ms"))
    ratio = None if peer_ms is None or not own_ms else peer_ms / own_ms
    return ratio, [peer_ms, own_ms]


def electric_ratios(bev_peer: dict, hev_peer: dict, bev: dict, hev: dict, paired: dict) -> dict:
    """The electric cars' ratios against FASTSim held against the targets ({"<key>_vs_fastsim_udds": ratio}),
    each by :func:`best_ratio` from the peers' rows, vpsim's rows (:func:`bev_rows`, :func:`hev_rows`) and
    :func:`paired_rows`; each paired entry gets its ``best_ms``."""
    sides = {
        "bev_backward": (bev_peer, bev.get("backward")),
        "bev_forward": (bev_peer, bev.get("forward")),
        "hev_ecms_backward": (hev_peer, hev.get("ecms")),
        "hev_ecms_forward": (hev_peer, hev.get("forward_ecms")),
    }
    out = {}
    for key, (peer_row, own_row) in sides.items():
        res = paired.get(key) if isinstance(paired.get(key), dict) else None
        out[f"{key}_vs_fastsim_udds"], best = best_ratio(peer_row, own_row, res)
        if res:
            res["best_ms"] = best
    return out


def paired_rows(settings: Settings, progress) -> dict:
    """The electric cars' ratios against FASTSim from interleaved blocks (:func:`vpsim.bench._paired`, as
    the engine car's): ``bev_backward``, ``bev_forward`` (the bev preset against FASTSim's BEV) and
    ``hev_ecms_backward``, ``hev_ecms_forward`` (hev_p2 with ECMS, its schedule prepared as in
    :func:`hev_rows`, against FASTSim's hybrid); each {"ratio", "a_median_ms" (FASTSim), "b_median_ms"
    (vpsim), ...}. Run after both tools' own rows, so each side's blocks are one more measurement of it."""
    import warnings

    from .bench import _paired
    from .cycles import load_cycle
    from .gears import default_schedule
    from .methods import hev
    from .methods.hev_forward import run as fwd
    from .model.maps import cached_engine_map
    from .params import load_parameters
    from .simulation import simulate

    cyc = load_cycle("udds")
    bev = load_parameters("bev")
    p2 = load_parameters("hev_p2")
    sched = default_schedule(cyc, p2, cached_engine_map(p2.engine))
    ems = "ecms"
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        bev_make, bev_call = _bev_peer_maker()
        hev_make, hev_call = _hev_peer_maker()
        plan = {
            "bev_backward": (bev_make, bev_call, lambda: simulate(cyc, "backward", bev)),
            "bev_forward": (bev_make, bev_call, lambda: simulate(cyc, "forward", bev)),
            "hev_ecms_backward": (hev_make, hev_call, lambda: hev.run(cyc, p2, ems=ems, schedule=sched)),
            "hev_ecms_forward": (hev_make, hev_call, lambda: fwd(cyc, p2, ems=ems, schedule=sched)),
        }
        for key, (make, call, ours) in plan.items():
            progress(f"ratio {key}: {settings.pairs} interleaved pairs")
            out[key] = _paired(call, ours, settings.pairs, setup_a=make)
    return out
