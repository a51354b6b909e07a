"""The one high-level entry point: ``simulate(cycle, method=...)`` returns a :class:`~vpsim.result.Result`.

    >>> import vpsim
    >>> r = vpsim.simulate("nedc", method="backward")
    >>> print(f"{r.fuel_l_per_100km:.2f} L/100 km")  # doctest: +SKIP

Methods: ``backward`` (quasi-static, exact tracking), ``forward`` (dynamic, PI driver), ``inverse`` (stable
inversion, smoothing driver). Modes: ``realistic`` (the default: clutch and idle at standstill, friction
brakes) and ``paper`` (the paper's model: no clutch, no brakes, idle fuel floor; ``vpsim paper`` uses it).
"""

from __future__ import annotations

from pathlib import Path

from .cycles import Cycle, load_cycle
from .errors import VpsimError
from .gears import GearSchedule, load_schedule, schedule_for
from .model.rules import canonical_mode
from .params import HYBRIDS, Parameters, load_parameters

METHODS = ("backward", "forward", "inverse")
MODES = ("realistic", "paper", "extended")  # "extended": the realistic mode's earlier name


def resolve_inputs(cycle, params, gears=None):
    """Turn names/paths into (Cycle, Parameters, GearSchedule)."""
    if not isinstance(cycle, Cycle):
        cycle = load_cycle(cycle)
    if not isinstance(params, Parameters):
        params = load_parameters(params)
    if gears is None or isinstance(gears, GearSchedule):
        schedule = gears
    else:
        schedule = load_schedule(Path(gears), params.transmission.n_gears, cycle=cycle)
    if schedule is None:
        schedule = schedule_for(cycle, params)
    return cycle, params, schedule


def simulate(
    cycle: str | Path | Cycle = "nedc",
    method: str = "backward",
    params: str | Path | Parameters = "hofman2011",
    *,
    driver: int | str | None = None,
    mode: str = "realistic",
    gears=None,
    **options,
):
    """Simulate ``params`` (preset name, TOML file or Parameters) on ``cycle`` with ``method``.

    ``mode``: ``"realistic"`` (default: clutch and idle at standstill, friction brakes) or ``"paper"`` (the
    paper's model: stiff driveline, no brakes; ``"extended"`` is the realistic mode's earlier name).
    ``driver`` (1 or 2; forward and inverse only) picks the tuning: default 2 (tight tracking) in the
    realistic mode, 1 in the paper mode (the paper's tables use both); ``gears`` is a schedule file or
    :class:`~vpsim.gears.GearSchedule` (default: derived from the cycle by the documented rule); further
    ``options`` go to the method (e.g. ``engine_map=`` for the backward method, ``rtol=`` for the forward).
    """
    if method not in METHODS:
        raise VpsimError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    mode = canonical_mode(mode)
    if not isinstance(params, Parameters):
        params = load_parameters(params)
    if params.powertrain.type == "bev":
        return _simulate_bev(cycle, method, params, driver, mode, gears, options)
    if params.powertrain.type in HYBRIDS:
        return _simulate_hev(cycle, method, params, driver, mode, gears, options)
    cycle, params, schedule = resolve_inputs(cycle, params, gears)
    if options:
        _check_options(method, options)
    if method == "backward":
        if driver is not None:
            raise VpsimError("the backward method tracks the cycle exactly and takes no driver")
        return _method_run("backward")(cycle, params, schedule=schedule, mode=mode, **options)
    driver = ("2" if mode == "realistic" else "1") if driver is None else str(driver)
    params.driver(driver)  # validates
    return _method_run(method)(cycle, params, driver=driver, schedule=schedule, mode=mode, **options)


_MODULES: dict = {}


def _method_run(method: str):
    """The engine car's ``vpsim.methods.<method>.run``, imported on first use (a process that runs one method
    does not import the others) and then one dictionary look-up: an import statement in the call cost 1-2 us
    of a 90 us backward run."""
    module = _MODULES.get(method)
    if module is None:
        import importlib

        # (relative: the package imports itself by its own name, as a renamed copy does)
        module = _MODULES[method] = importlib.import_module(f".methods.{method}", __package__)
    return module.run


def _check_options(method: str, options: dict) -> None:
    """The engine car's method takes ``options`` (its ``run``'s keywords beyond those simulate sets), or one
    line saying which it takes: not a TypeError from inside the method."""
    import inspect

    run = _method_run(method)
    own = ("cycle", "params", "driver", "schedule", "mode")
    takes = [k for k in inspect.signature(run).parameters if k not in own and not k.startswith("_")]
    for name in options:
        if name not in takes:
            what = " (a hybrid's energy management)" if name == "ems" else ""
            raise VpsimError(
                f"option {name!r}{what} does not apply to the engine car's {method} method; it takes "
                f"{', '.join(takes)}"
            )


# (powertrain, method, management) already run in this process: their compiled kernels are loaded
_LOADED: set[tuple] = set()


def _load_before_timing(key: tuple, run, cycle: Cycle) -> None:
    """Run ``run`` on the cycle's first seconds before the real run, once per process and ``key``, so that
    the real run's ``cpu_time_s`` is the method's own time, not the compilation of its kernels or their
    loading from the cache (the engine car's methods arrange this on their own). In a fresh process the
    electric and hybrid cars' kernels took 17-130 ms of CPU to load, which ``vpsim simulate`` reported as
    the run's CPU time; the UDDS runs themselves take 0.6-9 ms."""
    if key in _LOADED:
        return
    _LOADED.add(key)
    t = cycle.time_s
    try:
        run(cycle.window(float(t[0]), float(t[min(3, t.size - 1)])))
    except Exception:  # noqa: BLE001 (only a warm-up: the real run that follows reports its own errors)
        pass


def _simulate_bev(cycle, method, params, driver, mode, gears, options):
    """The battery-electric car (:mod:`vpsim.methods.bev`): a single reduction, so no gear schedule."""
    if gears is not None:
        raise VpsimError("a battery-electric car has a single reduction and takes no gear schedule")
    if options:
        raise VpsimError(
            f"option {sorted(options)[0]!r} does not apply to a battery-electric car (its methods take none)"
        )
    if method == "backward" and driver is not None:
        raise VpsimError("the backward method tracks the cycle exactly and takes no driver")
    if method == "inverse":
        driver = "2" if driver is None else str(driver)
        params.driver(driver)  # validates
    elif method == "forward":
        if driver is not None:  # as the hybrid's forward method
            raise VpsimError(
                "the battery-electric car's forward driver takes its gains from electric.forward_kp and "
                "forward_ki; it takes no --driver"
            )
    if not isinstance(cycle, Cycle):
        cycle = load_cycle(cycle)
    from .methods import bev

    _load_before_timing(
        ("bev", method), lambda c: bev.run(c, params, method, driver=driver, mode=mode), cycle
    )
    return bev.run(cycle, params, method, driver=driver, mode=mode)


def _simulate_hev(cycle, method, params, driver, mode, gears, options):
    """The hybrids, P2 (:mod:`vpsim.methods.hev`) and power-split (:mod:`vpsim.methods.hev_split`): the
    backward and inverse methods with their energy management, and the forward method of both
    (:mod:`vpsim.methods.hev_forward`)."""
    if method == "forward" and driver is not None:
        raise VpsimError(
            "the hybrid's forward driver takes its gains from electric.forward_kp and forward_ki; "
            "it takes no --driver"
        )
    if method == "backward" and driver is not None:
        raise VpsimError("the backward method tracks the cycle exactly and takes no driver")
    if gears is not None:
        raise VpsimError(
            "the hybrid takes its gears from the gear rule; a schedule file is not supported yet"
        )
    ems = options.pop("ems", None)
    if options:
        raise VpsimError(f"option {sorted(options)[0]!r} does not apply to the hybrid")
    if not isinstance(cycle, Cycle):
        cycle = load_cycle(cycle)
    if params.powertrain.type == "hev_split":
        from .methods import hev_split as hev
    else:
        from .methods import hev

    if method == "inverse":
        driver = "2" if driver is None else str(driver)
        params.driver(driver)  # validates

        def run(c):
            return hev.run_inverse(c, params, driver=driver, ems=ems, mode=mode)
    elif method == "forward":
        from .methods import hev_forward

        def run(c):
            return hev_forward.run(c, params, ems=ems, mode=mode)
    else:

        def run(c):
            return hev.run(c, params, ems=ems, mode=mode)

    _load_before_timing((params.powertrain.type, method, ems or params.hybrid.ems), run, cycle)
    return run(cycle)
