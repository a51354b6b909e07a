"""Batch evaluation: many design variants through one method in one call, one row per variant.

    >>> import numpy as np
    >>> from vpsim.batch import run_batch
    >>> df = run_batch("udds", {"engine.bore": np.linspace(0.08, 0.095, 4), "vehicle.mass": 1500.0})
    >>> list(df.columns[:3])
    ['engine.bore', 'vehicle.mass', 'fuel_l_per_100km']
    >>> len(df)
    4

Variants name parameters as ``section.field`` (``engine.bore``, ``vehicle.mass``,
``transmission.final_drive``, ``engine.lambda``, ``simulation.idle_fuel_flow``; one gear as
``transmission.gearbox_ratios[2]``, 1-based). They may be given as a pandas DataFrame (one column per
parameter), a list of dicts (a parameter missing from a dict keeps the base value) or a dict of arrays
(scalars broadcast). Every value is validated by :meth:`vpsim.params.Parameters.with_changes`, so a bad
name or an implausible value raises :class:`~vpsim.errors.ParameterError` naming the variant row.

Methods:

* ``backward``: compiled over variants (:func:`vpsim.methods.backward_variants.run_variants`, parallel over
  the cores). Each variant has its own engine, hence its own fuel map and max-torque line. The fuel flow is
  the BQM in closed form (:func:`vpsim.model.engine.bqm_fuel_flow`, linear in p_i: nothing to tabulate); this
  is what :func:`vpsim.methods.backward.run` computes with ``engine_map=generate_engine_map(eng, exact=True)``
  (the default table lookup differs from it by < 1e-5 relative). The max-torque line (the FQM at A_max, a
  Newton solve per speed, tabulated at 1 rad/s like :func:`vpsim.model.maps.generate_engine_map` and
  interpolated) is evaluated lazily: the wide-open-throttle intake pressure p_max(w_e) decreases with w_e, so
  one Newton solve per variant, at a node above the run's top speed, gives a pressure below which no point of
  the run can reach the line (allowing for the friction rise over two node intervals). Only points above it
  evaluate the line, at the two nodes around them, each node solved once per variant. Every point goes through
  the same model functions as a single run (:func:`vpsim.model.rules.operating_point`,
  :func:`vpsim.model.engine.intake_pressure_for_torque`, :func:`vpsim.model.engine.fuel_flow`).
* ``forward``: the forward dynamic method's compiled integrator (:mod:`vpsim.methods.forward`) run for each
  variant inside one compiled call, parallel over variants (:func:`vpsim.methods.forward.run_variants`):
  the records and driver settings of all variants are built at once, and each row is what
  :func:`vpsim.methods.forward.run` gives the variant.

Gear schedule (``gears``): by default every variant follows the base design's schedule (derived once from
the cycle by the documented rule, or the :class:`~vpsim.gears.GearSchedule` / CSV given). The paper
prescribes gears in time, and a fair sweep compares designs on the same shifts: a design change then shows
its own effect, not that of a different shift pattern. ``gears="per_variant"`` derives each variant's own
schedule by the rule instead (what :func:`vpsim.simulate` does for one design; slower, a few ms per variant).
"""

from __future__ import annotations

import difflib
import re
from dataclasses import fields, replace
from pathlib import Path

import numpy as np

from .cycles import Cycle, load_cycle
from .errors import ParameterError, VpsimError
from .gears import GearSchedule, default_schedule, load_schedule, schedule_for
from .params import Parameters, load_parameters

METHODS = ("backward", "forward")
RESULT_COLUMNS = (
    "fuel_l_per_100km",
    "fuel_kg",
    "distance_km",
    "trace_miss_s",
    "trace_miss_max_torque_shortfall_nm",
    "max_speed_error_mps",
    "steps",
)

_SECTIONS = ("vehicle", "transmission", "engine", "simulation")
_ALIASES = {"lambda": "lambda_"}
_GEAR_RE = re.compile(r"^transmission\.gearbox_ratios\[(\d+)\]$")


# --- the public entry -----------------------------------------------------------------------------------


def run_batch(
    cycle: str | Path | Cycle = "udds",
    variants=None,
    method: str = "backward",
    params: str | Path | Parameters = "hofman2011",
    *,
    mode: str = "paper",
    gears="baseline",
    driver: int | str | None = None,
    rtol: float | None = None,
):
    """Simulate every variant of ``params`` on ``cycle`` with ``method``; a DataFrame, one row per variant.

    ``variants``: DataFrame, list of dicts or dict of arrays of parameter values (see the module docstring);
    ``None`` runs the base design alone. ``gears``: ``"baseline"`` (default: every variant on the base
    design's schedule), ``"per_variant"``, a :class:`~vpsim.gears.GearSchedule` or a schedule CSV.
    ``driver`` (forward only, default 1) and ``rtol`` (forward only) as in :func:`vpsim.simulate`.

    Columns: the variant parameters as given, then ``fuel_l_per_100km``, ``fuel_kg``, ``distance_km``,
    ``trace_miss_s``, ``trace_miss_max_torque_shortfall_nm`` (backward), ``max_speed_error_mps`` and
    ``steps`` (forward); ``engine_starts`` where ``simulation.stop_start`` is set (backward only).
    """
    import pandas as pd

    if method not in METHODS:
        raise VpsimError(f"batch method {method!r} is not available; expected one of {', '.join(METHODS)}")
    from .model.rules import canonical_mode

    mode = canonical_mode(mode)
    if method == "backward" and (driver is not None or rtol is not None):
        raise VpsimError("the backward method tracks the cycle exactly and takes no driver or rtol")
    if not isinstance(cycle, Cycle):
        cycle = load_cycle(cycle)
    if not isinstance(params, Parameters):
        params = load_parameters(params)
    if params.simulation.stop_start and method != "backward":
        raise VpsimError(
            "simulation.stop_start is modelled by the backward batch only; run the forward variants with "
            "vpsim.simulate"
        )
    names, values = normalise_variants(variants, params)
    recs = _validate_variants(params, names, values)
    schedules, schedule_of_variant = _schedules(cycle, params, names, values, gears)
    if method == "backward":
        out = _backward(cycle, params, names, values, schedules, schedule_of_variant, mode, recs)
    else:
        out = _forward(cycle, params, names, values, schedules, schedule_of_variant, mode, driver, rtol, recs)
    # one construction (a column inserted at a time costs a copy of the frame's block each)
    df = pd.DataFrame({**{name: values[:, j] for j, name in enumerate(names)}, **out})
    df.index.name = "variant"
    return df


# --- variants: normalise and validate -------------------------------------------------------------------


def normalise_variants(variants, params: Parameters) -> tuple[list[str], np.ndarray]:
    """(names, values[n_variants, n_names]) from a DataFrame, a list of dicts or a dict of arrays."""
    import pandas as pd

    if variants is None:
        return [], np.zeros((1, 0))
    if isinstance(variants, pd.DataFrame):
        cols = {str(c): variants[c].to_numpy() for c in variants.columns}
        n = len(variants)
    elif isinstance(variants, dict):
        cols = {str(k): v for k, v in variants.items()}
        lengths = {k: np.size(v) for k, v in cols.items() if np.ndim(v) > 0}
        if len(set(lengths.values())) > 1:
            detail = ", ".join(f"{k}: {n}" for k, n in lengths.items())
            raise ParameterError(f"variants: the arrays have different lengths ({detail})")
        n = next(iter(lengths.values()), 1)
        cols = {
            k: (np.full(n, v, dtype=object) if np.ndim(v) == 0 else np.asarray(v)) for k, v in cols.items()
        }
    elif isinstance(variants, list | tuple):
        if not all(isinstance(row, dict) for row in variants):
            raise ParameterError("variants: a list of variants must hold dicts of parameter values")
        keys: list[str] = []
        for row in variants:
            keys += [str(k) for k in row if str(k) not in keys]
        n = len(variants)
        flat = params.flat()
        cols = {}
        for k in keys:
            base = _base_value(flat, k, params)
            cols[k] = np.array([row.get(k, base) for row in variants], dtype=object)
    else:
        raise ParameterError(
            "variants must be a pandas DataFrame, a list of dicts or a dict of arrays, "
            f"got {type(variants).__name__}"
        )
    if n == 0:
        raise ParameterError("variants: no variant given (an empty table)")
    names = list(cols)
    canon = [_canonical(name) for name in names]
    for k, c in enumerate(canon):
        if c in canon[:k]:
            raise ParameterError(
                f"variants: {names[k]!r} names the same parameter as {names[canon.index(c)]!r}"
            )
    values = np.empty((n, len(names)))
    for j, name in enumerate(names):
        col = cols[name]
        if isinstance(col, np.ndarray) and col.dtype.kind in "fiu":  # numeric already: no per-value check
            values[:, j] = col
            continue
        for i in range(n):
            v = col[i]
            v = v.item() if isinstance(v, np.generic) else v
            if isinstance(v, bool | np.bool_) or not isinstance(v, int | float | np.integer | np.floating):
                raise ParameterError(f"variant {i}: {name} = {v!r} is not a number")
            values[i, j] = float(v)
    return names, values


def _canonical(name: str) -> str:
    sec, _, fld = name.partition(".")
    return f"{sec}.{_ALIASES.get(fld, fld)}"


def _base_value(flat: dict, name: str, params: Parameters):
    m = _GEAR_RE.match(name)
    if m:
        g = int(m.group(1))
        ratios = params.transmission.gearbox_ratios
        return ratios[g - 1] if 1 <= g <= len(ratios) else float("nan")
    return flat.get(name, float("nan"))


def _split(name: str, params: Parameters) -> tuple[str, str, int | None]:
    """(section, field, gear) of a variant column; raises ParameterError for unknown or non-scalar names."""
    m = _GEAR_RE.match(name)
    if m:
        g = int(m.group(1))
        n_g = params.transmission.n_gears
        if not 1 <= g <= n_g:
            raise ParameterError(f"variants: {name}: gear {g} does not exist (gears 1..{n_g})")
        return "transmission", "gearbox_ratios", g
    sec, dot, fld = name.partition(".")
    scalar = {
        s: {
            _ALIASES.get(f.name, f.name) if f.name != "lambda_" else "lambda": f.type
            for f in fields(getattr(params, s))
        }
        for s in _SECTIONS
    }
    known = [f"{s}.{f}" for s, fs in scalar.items() for f, t in fs.items() if t in ("float", "int")]
    if not dot or sec not in scalar or fld not in scalar[sec]:
        close = difflib.get_close_matches(name, known, n=3)
        hint = f"; did you mean {' or '.join(close)}?" if close else f"; parameters are named like {known[0]}"
        raise ParameterError(f"variants: unknown parameter {name!r}{hint}")
    if scalar[sec][fld] not in ("float", "int"):
        raise ParameterError(
            f"variants: {name} is a list; vary one entry (e.g. transmission.gearbox_ratios[2]) "
            "or use a separate parameter set"
        )
    return sec, fld, None


def validate_variants(params: Parameters, names: list[str], values: np.ndarray) -> None:
    """Check every variant through :meth:`Parameters.with_changes`; errors name the variant row (the checks:
    :func:`_validate_variants`)."""
    _validate_variants(params, names, values)


def _validate_variants(params: Parameters, names: list[str], values: np.ndarray):
    """:func:`validate_variants`; returns the variants' records where the engine check built them, else None.

    The per-field checks are intervals, so each column is validated at its smallest and largest value (and
    every value for whole-number fields); the checks that couple fields (A_min < A_max, a stepped gearbox's
    descending ratios, a road load that stays >= 0 up to the US06's top speed, and the engine as a whole:
    :func:`vpsim.params.engine_check_figures`) are then applied to every row, vectorised.
    """
    n = values.shape[0]
    gear_cols = [j for j, nm in enumerate(names) if _GEAR_RE.match(nm)]
    road_cols = [j for j, nm in enumerate(names) if _canonical(nm).startswith("vehicle.road_load_")]
    for j, name in enumerate(names):
        sec, fld, gear = _split(name, params)
        if _canonical(name) == "transmission.cvt_ratio_step" or (
            gear is not None and params.transmission.is_cvt
        ):
            raise ParameterError(
                f"variants: {name} changes the ratio grid of a CVT (another number of ratios per variant); "
                "run one batch per CVT range and step"
            )
        col = values[:, j]
        bad = np.flatnonzero(~np.isfinite(col))
        rows = [int(bad[0])] if bad.size else []
        typ = {f.name: f.type for f in fields(getattr(params, sec))}.get(_ALIASES.get(fld, fld))
        if typ == "int":
            frac = np.flatnonzero(col != np.round(col))
            rows += [int(frac[0])] if frac.size else []
        rows += [int(np.argmin(col)), int(np.argmax(col))]
        # fields checked together (the gears' order, the road load's A, B, C) go with their partners
        group = gear_cols if j in gear_cols else road_cols if j in road_cols else [j]
        for i in rows:
            _check_row(params, names, values, i, only=group)
    if any(_canonical(n) in ("engine.min_throttle_area", "engine.max_throttle_area") for n in names):
        lo = _column(params, names, values, "engine.min_throttle_area")
        hi = _column(params, names, values, "engine.max_throttle_area")
        bad = np.flatnonzero(~(lo < hi))
        if bad.size:
            _check_row(params, names, values, int(bad[0]))
    if gear_cols and not params.transmission.is_cvt:  # a stepped gearbox's ratios descend (params.validate)
        ratios = np.tile(np.asarray(params.transmission.gearbox_ratios, float), (n, 1))
        for j in gear_cols:
            ratios[:, _split(names[j], params)[2] - 1] = values[:, j]
        bad = np.flatnonzero(~np.all(np.diff(ratios, axis=1) < 0.0, axis=1))
        if bad.size:
            _check_row(params, names, values, int(bad[0]))
    if road_cols:
        # the coast-down road load may not push the car up to the US06's top speed (params.validate)
        from .params import ROAD_LOAD_CHECK_SPEED

        a, b, c = (_column(params, names, values, f"vehicle.road_load_{k}") for k in "abc")
        top = ROAD_LOAD_CHECK_SPEED
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):  # c may be subnormal: -b/2c inf
            vertex = np.where(c > 0.0, np.clip(-b / (2.0 * c), 0.0, top), 0.0)
        lowest = np.minimum.reduce([a, a + b * top + c * top * top, a + b * vertex + c * vertex * vertex])
        used = (a != 0.0) | (b != 0.0) | (c != 0.0)
        bad = np.flatnonzero(used & (lowest < 0.0))
        if bad.size:
            _check_row(params, names, values, int(bad[0]))
    return _validated_records(params, names, values)


def _validated_records(params: Parameters, names: list[str], values: np.ndarray):
    """The engine check of :func:`validate_variants` (after its per-field checks); returns the variants'
    records (:func:`vpsim.model.record.records`) where it built them, for the run to use, else None."""
    if any(n.startswith("engine.") for n in names):
        # the engine as a whole (displacement, full-load and motoring BMEP, idle) couples its fields: checked
        # for every variant at once, the first implausible one then through with_changes for its message
        from .model.record import records
        from .params import engine_check_figures

        n = values.shape[0]
        (veh, tr, eng, sim), _ = _sections(params, names, values)
        recs = records(veh, tr, eng, sim)
        for i in np.flatnonzero(~np.broadcast_to(engine_check_figures(recs)["ok"], n)):
            _check_row(params, names, values, int(i))
        return recs
    return None


def _column(params, names, values, key):
    canon = [_canonical(n) for n in names]
    if key in canon:
        return values[:, canon.index(key)]
    sec, fld = key.split(".")
    return np.full(values.shape[0], float(getattr(getattr(params, sec), fld)))


def variant_parameters(params: Parameters, names: list[str], row) -> Parameters:
    """The validated :class:`Parameters` of one variant (``row``: its values in the order of ``names``)."""
    sections: dict[str, dict] = {}
    gears: dict[int, float] = {}
    for name, value in zip(names, row, strict=True):
        sec, fld, gear = _split(name, params)
        if gear is not None:
            gears[gear] = float(value)
            continue
        typ = {f.name: f.type for f in fields(getattr(params, sec))}[_ALIASES.get(fld, fld)]
        v = float(value)
        sections.setdefault(sec, {})[fld] = int(v) if typ == "int" and v.is_integer() else v
    if gears:
        ratios = list(params.transmission.gearbox_ratios)
        for g, v in gears.items():
            ratios[g - 1] = v
        sections.setdefault("transmission", {})["gearbox_ratios"] = ratios
    return params.with_changes(**sections) if sections else params


def _check_row(params, names, values, i, only=None):
    sel = range(len(names)) if only is None else [only] if isinstance(only, int) else only
    try:
        variant_parameters(params, [names[j] for j in sel], [values[i, j] for j in sel])
    except ParameterError as exc:
        msg = str(exc)
        for prefix in ("parameters: ", "with_changes: "):
            msg = msg.removeprefix(prefix)
        raise ParameterError(f"variant {i}: {msg}") from None


# --- array-valued parameter sections ------------------------------------------------------------------


def _sections(params: Parameters, names: list[str], values: np.ndarray):
    """Vehicle, transmission, engine, simulation whose varied fields are arrays over the variants, and the
    total ratios per variant and gear (n_variants, n_gears)."""
    n = values.shape[0]
    changes: dict[str, dict] = {s: {} for s in _SECTIONS}
    gearbox = np.tile(np.asarray(params.transmission.gearbox_steps, float), (n, 1))
    for j, name in enumerate(names):
        sec, fld, gear = _split(name, params)
        if gear is not None:
            gearbox[:, gear - 1] = values[:, j]
        else:
            changes[sec][_ALIASES.get(fld, fld)] = values[:, j]
    secs = [
        replace(getattr(params, s), **changes[s]) if changes[s] else getattr(params, s) for s in _SECTIONS
    ]
    final = np.broadcast_to(np.asarray(secs[1].final_drive, float), (n,))
    ratios = np.ascontiguousarray(gearbox * final[:, None])
    return secs, ratios


def _schedules(cycle, params, names, values, gears):
    """(gear arrays per schedule (n_schedules, n_samples), schedule index per variant)."""
    n = values.shape[0]
    if isinstance(gears, str) and gears == "per_variant":
        from .model.maps import generate_engine_map

        rows = []
        for i in range(n):
            p = variant_parameters(params, names, values[i])
            em = generate_engine_map(p.engine, exact=True)
            rows.append(default_schedule(cycle, p, em).on_cycle(cycle))
        return np.array(rows), np.arange(n)
    if isinstance(gears, str) and gears == "baseline":
        schedule = schedule_for(cycle, params)  # the rule on the base map, kept per parameter set and cycle
    elif isinstance(gears, GearSchedule):
        schedule = gears
    elif isinstance(gears, str | Path):
        schedule = load_schedule(Path(gears), params.transmission.n_gears, cycle=cycle)
    else:
        raise VpsimError(
            f"gears must be 'baseline', 'per_variant', a GearSchedule or a CSV path, got {gears!r}"
        )
    return schedule.on_cycle(cycle)[None, :], np.zeros(n, dtype=np.int64)


# --- backward -----------------------------------------------------------------------------------------------


def _backward(cycle, params, names, values, schedules, schedule_of_variant, mode, recs=None):
    from .methods import backward_variants
    from .model.record import records

    (veh, tr, eng, sim), ratios = _sections(params, names, values)
    if recs is None:  # (built by the engine check where an engine field varies)
        recs = records(veh, tr, eng, sim)
    n_var = values.shape[0]
    if recs.size != n_var:
        recs = np.ascontiguousarray(np.broadcast_to(recs, (n_var,))).view(np.recarray)
    out = backward_variants.run_variants(cycle, recs, ratios, schedules, schedule_of_variant, mode)
    distance = cycle.distance_m
    fuel = out[:, backward_variants.B_FUEL]
    extra = {}
    if params.simulation.stop_start:  # as backward.run: the stopped intervals' idle fuel, less the restarts'
        fuel, starts = _stop_start(cycle, params, recs, fuel)
        extra = {"engine_starts": np.full(n_var, starts)}
    return {
        "fuel_l_per_100km": fuel / recs.fuel_density / (distance / 1e5)
        if distance > 0
        else np.full(n_var, np.nan),
        "fuel_kg": fuel,
        "distance_km": np.full(n_var, distance / 1e3),
        "trace_miss_s": out[:, backward_variants.B_MISS_S],
        "trace_miss_max_torque_shortfall_nm": out[:, backward_variants.B_MAX_SHORT],
        **extra,
    }


def _stop_start(cycle, params, recs, fuel):
    """Stop-start (``simulation.stop_start``) on the backward batch: (fuel, restarts). The stops are the
    cycle's (:func:`vpsim.model.rules.stopped_at_rest`), the same for every variant; in them the backward
    method's engine idles declutched at its idle flow, which the stopped engine does not burn, and each
    restart costs ``hybrid.engine_start_fuel``: :func:`vpsim.methods.backward.run`'s figure (a test holds the
    two equal variant by variant)."""
    from .model import rules

    t, v = cycle.time_s, cycle.speed_mps
    dt = np.diff(t)
    stopped, starts = rules.stopped_at_rest(0.5 * (v[1:] + v[:-1]), np.diff(v) / dt)
    seconds = float(dt[stopped].sum())
    return fuel - recs.idle_fuel_flow * seconds + starts * params.hybrid.engine_start_fuel, starts


# --- forward ------------------------------------------------------------------------------------------------


def _forward(cycle, params, names, values, schedules, schedule_of_variant, mode, driver, rtol, recs=None):
    """The forward dynamic method for every variant in one compiled call, parallel over the variants.

    Each row is what :func:`vpsim.methods.forward.run` gives that variant without series (same start, same
    driver settings, same kernel; a test checks it row by row). The variants' records and driver settings are
    built for all of them at once from the arrays of values, not as one parameter set each.
    """
    from .drivers.pi import PIDriver
    from .methods import forward
    from .model.record import records

    driver = "1" if driver is None else str(driver)
    pi = PIDriver.from_params(params, driver, mode)  # also validates the driver's name
    (veh, tr, eng, sim), ratios = _sections(params, names, values)
    n = values.shape[0]
    if recs is None:  # (built by the engine check where an engine field varies)
        recs = records(veh, tr, eng, sim)
    if recs.size != n:
        recs = np.ascontiguousarray(np.broadcast_to(recs, (n,))).view(np.recarray)
    if rtol is None:
        rtol = np.broadcast_to(np.asarray(sim.ode_relative_tolerance, dtype=float), (n,))
    else:
        rtol = np.full(n, float(rtol))
    bad = np.flatnonzero(~((rtol > 0.0) & (rtol < 1.0)))
    if bad.size:
        raise VpsimError(f"variant {bad[0]}: rtol = {rtol[bad[0]]!r} must be in (0, 1)")
    D = forward.variant_settings(params, pi, mode, veh, eng, recs)
    gear_schedules = [GearSchedule(cycle.time_s.copy(), g, source="batch") for g in schedules]
    out = forward.run_variants(cycle, recs, ratios, gear_schedules, schedule_of_variant, D, mode, rtol)
    status = out[:, forward.V_STATUS]
    failed = np.flatnonzero(status != forward.STATUS_OK)
    if failed.size:
        i = int(failed[0])
        why = (
            "step size below the minimum"
            if status[i] == forward.STATUS_STEP_TOO_SMALL
            else f"more than {forward.MAX_STEPS} steps"
        )
        raise VpsimError(
            f"variant {i}: forward integration failed ({why}); {failed.size} of {n} variants failed"
        )
    fuel = out[:, forward.V_FUEL]
    distance = out[:, forward.V_DIST]
    with np.errstate(divide="ignore", invalid="ignore"):
        per_100km = np.where(distance > 0.0, fuel / recs.fuel_density / (distance / 1e5), np.nan)
    return {
        "fuel_l_per_100km": per_100km,
        "fuel_kg": fuel,
        "distance_km": distance / 1e3,
        "trace_miss_s": out[:, forward.V_OUTSIDE],
        "max_speed_error_mps": out[:, forward.V_MAX_ERR],
        "steps": out[:, forward.V_STEPS].astype(np.int64),
    }


__all__ = ["METHODS", "normalise_variants", "run_batch", "validate_variants", "variant_parameters"]
