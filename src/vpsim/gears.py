"""Gear schedules prescribed in time, identical for every method (the paper shifts at fixed instants).

A :class:`GearSchedule` holds the engaged gear (1..n) for each sample interval of a cycle: the gear at
``time_s[k]`` is engaged on [t_k, t_{k+1}). It is derived once from the cycle by :func:`default_schedule`
or read from a CSV file (``time_s,gear``) by :func:`load_schedule`. Gear 0 (neutral) in a file is
accepted and mapped to the gear a stiff driveline must keep engaged (see :func:`load_schedule`).

The default rule (documented in docs/methods.md):

1. For each interval, the engine speed in every gear follows from the interval's mean speed.
2. A gear is *admissible* if its engine speed stays below ``max_engine_speed`` and the crank torque the
   interval asks for (road load + acceleration, engine inertia included) is at most ``torque_reserve``
   times that gear's maximum torque.
3. The chosen gear is the highest admissible gear whose engine speed is at least ``min_engine_speed``;
   if none reaches it, the lowest admissible gear (gear 1 at standstill and crawling).
4. With a driver's shift points (as a manual is driven): while the vehicle accelerates (more than
   ``cruise_acceleration``), gear k + 1 is used only once the engine in gear k has reached
   ``upshift_engine_speed``, and/or only at vehicle speeds of at least ``upshift_speed`` + (k - 1)
   ``upshift_speed_step`` (an owner's manual's table of upshift speeds); in cruise and deceleration rule 3
   alone applies (owner's manuals give shift speeds "for acceleration" and allow earlier upshifts at steady
   speed). The gear is then the highest admissible gear within that limit (the lowest admissible gear if
   none).
5. While decelerating, the engine does not upshift (a driver holds or downshifts when braking).
6. Short engagements (< ``min_hold_s``) are merged into the preceding gear where that gear is admissible.

A CVT (``transmission.cvt_ratio_step`` > 0) has the points of its ratio grid for gears (gear 1 its launch
ratio): rules 1-5 choose its ratio on every interval, and rule 6 does not apply (nothing to hold), so the
engine runs at the lowest speed at or above ``min_engine_speed`` that carries the load with the reserve.
"""

from __future__ import annotations

import csv
import functools
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .cycles import Cycle
from .errors import CycleError
from .model import vehicle as vh
from .model.record import memo, record
from .textio import read_text


@dataclass(frozen=True)
class GearSchedule:
    """Engaged gear per cycle sample (1-based; the last sample repeats the one before)."""

    time_s: np.ndarray
    gear: np.ndarray
    source: str = "default rule"

    def __post_init__(self):
        g = np.asarray(self.gear, dtype=np.int64)
        t = np.asarray(self.time_s, dtype=float)
        if g.shape != t.shape:
            raise CycleError(f"gear schedule ({self.source}): {g.size} gears for {t.size} times")
        object.__setattr__(self, "gear", g)
        object.__setattr__(self, "time_s", t)

    def on_cycle(self, cycle: Cycle) -> np.ndarray:
        """Gear at each sample of ``cycle`` (held piecewise constant from the schedule's times)."""
        if self.time_s.shape == cycle.time_s.shape and np.array_equal(self.time_s, cycle.time_s):
            return self.gear
        return self.gear[_held_index(self.time_s, cycle.time_s)]

    def gear_at(self, t):
        """Gear engaged at times t (right-continuous)."""
        return self.gear[_held_index(self.time_s, t)]

    @functools.cached_property  # (the schedule is frozen; the forward method asks at every run)
    def shift_times(self) -> np.ndarray:
        """Instants where the engaged gear changes."""
        return self.time_s[1:][np.diff(self.gear) != 0]


def _held_index(times, t):
    """Index of the last of the sorted ``times`` at or before t (0 before the first): a value held from each
    time on. (searchsorted's right side is at most len(times): only the lower end needs a bound.)"""
    idx = np.searchsorted(times, t, side="right") - 1
    return np.maximum(idx, 0, out=idx) if isinstance(idx, np.ndarray) else max(int(idx), 0)


def gearbox_ratio_series(params, gear) -> np.ndarray:
    """The gearbox ratio engaged for gear numbers ``gear`` (1-based; a CVT's grid point), for the series; a
    number below 1 gives the first, beyond the last gear the last."""
    steps = gearbox_steps(params.transmission)
    # one call, the array's own method (np.clip's overhead, or a maximum and a minimum, cost a run's 5-10 us;
    # np.take's dispatch to the method another microsecond)
    return steps.take(np.asarray(gear, dtype=np.int64) - 1, mode="clip")


def gearbox_steps(transmission) -> np.ndarray:
    """The gearbox ratio of each gear (a CVT's grid), read-only, cached per transmission."""
    return memo(transmission, "gearbox_steps_array", _steps_array)


def _steps_array(transmission) -> np.ndarray:
    steps = np.asarray(transmission.gearbox_steps, dtype=float)
    steps.setflags(write=False)
    return steps


RULE_STEP_S = 1.0  # longest interval the gear rule looks at (longer ones are subdivided)
FULL_LOAD_NODES = 2048  # speeds at which the rule evaluates the full-load line for a CVT's grid


@dataclass(frozen=True)
class GearRule:
    """Parameters of the default schedule rule (engine speeds in rad/s)."""

    min_engine_speed: float = 200.0  # about 1900 rpm: shift up once the next gear keeps the engine above this
    max_engine_speed: float = 600.0
    # an automatic's load-dependent strategy: the speed kept rises linearly with the load (demanded over
    # full-load torque in that gear) from min_engine_speed at no load to this at full load; None: constant
    full_load_engine_speed: float | None = None
    torque_reserve: float = 0.9
    min_hold_s: float = 3.0
    # a driver's shift point (rule 4): while accelerating, leave gear k only once the engine in it reaches
    # this speed; None: no shift point (an automatic's schedule)
    upshift_engine_speed: float | None = None
    # a driver's shift speeds (rule 4): while accelerating, gear k + 1 only at vehicle speeds of at least
    # upshift_speed + (k - 1) upshift_speed_step (m/s); None: none
    upshift_speed: float | None = None
    upshift_speed_step: float = 0.0
    cruise_acceleration: float = 0.1  # m/s^2: at or below this the vehicle cruises or decelerates (rule 4)

    def __post_init__(self):
        w = self.upshift_engine_speed
        if w is not None and not (math.isfinite(w) and w > 0):
            raise CycleError(f"gear rule: upshift_engine_speed must be a positive speed in rad/s, got {w!r}")
        v = self.upshift_speed
        if v is not None and not (math.isfinite(v) and v > 0):
            raise CycleError(f"gear rule: upshift_speed must be a positive vehicle speed in m/s, got {v!r}")
        dv = self.upshift_speed_step
        if not (math.isfinite(dv) and dv >= 0):
            raise CycleError(f"gear rule: upshift_speed_step must be a speed >= 0 in m/s, got {dv!r}")

    def upshift_speeds(self, n_gears: int) -> np.ndarray:
        """Vehicle speeds (m/s) from which gears 2..n_gears may be used while accelerating (rule 4; empty
        without shift speeds)."""
        if self.upshift_speed is None:
            return np.zeros(0)
        return self.upshift_speed + self.upshift_speed_step * np.arange(max(n_gears - 1, 0))

    @classmethod
    def of(cls, params) -> GearRule:
        """The rule a parameter set asks for: ``transmission.shift_engine_speed`` (rule 3),
        ``transmission.shift_point_engine_speed`` and ``transmission.shift_point_speed`` /
        ``shift_point_speed_step`` (rule 4, 0: none); the other settings the defaults."""
        tr = params.transmission
        point = tr.shift_point_engine_speed
        first = tr.shift_point_speed
        return cls(
            min_engine_speed=tr.shift_engine_speed,
            upshift_engine_speed=point if point > 0 else None,
            upshift_speed=first if first > 0 else None,
            upshift_speed_step=tr.shift_point_speed_step,
        )


def interval_demand(cycle: Cycle, ratio, params):
    """Mean speed, acceleration, engine speed and crank torque on each interval for total ratio(s) ``ratio``.

    This is the backward (quasi-static) kinematics used by the BQM and by the gear rule: the cycle is
    piecewise linear, so on [t_k, t_{k+1}] the acceleration is constant and the mean speed is the average.
    Rolling resistance acts only while the vehicle moves. Returns (v, a, w_e, dw_e, t_cr, t_e).
    """
    c = record(params)
    t, v_s = cycle.time_s, cycle.speed_mps
    dt = np.diff(t)
    v = 0.5 * (v_s[1:] + v_s[:-1])
    a = np.diff(v_s) / dt
    force = vh.wheel_force(v, a, c)  # (18)
    w_e = vh.engine_speed(v, ratio, c)  # (14),(17)
    dw_e = vh.engine_speed(a, ratio, c)
    t_e = vh.wheel_to_engine_torque(force, ratio, c)  # (15),(16)
    t_cr = vh.crank_torque_demand(force, ratio, dw_e, c)  # (1)
    return v, a, w_e, dw_e, t_cr, t_e


SCHEDULES_KEPT = 16  # derived schedules kept per parameter set (the oldest goes first)
SECTION_SETS_KEPT = 64  # sets of the sections the rule reads whose schedules are kept (the oldest goes first)
# (vehicle, transmission, engine, simulation) -> {id(cycle): (cycle, schedule)}: the schedules of parameter
# sets that differ only in what the rule does not read
_BY_SECTIONS: dict = {}


def schedule_for(cycle: Cycle, params) -> GearSchedule:
    """:func:`default_schedule` of ``cycle`` for ``params`` on the engine's generated map (what a method
    derives when given no schedule), derived once per (parameter set, cycle) and kept on the parameter set:
    both are immutable. The rule's Python took 0.9 ms on UDDS, seven times the backward run it served.

    The rule reads the parameter set's record (its vehicle, transmission, engine and simulation sections,
    :func:`vpsim.model.record.record`), the transmission's rule settings and the engine's map, nothing else;
    so a parameter set equal in those four sections takes the schedule derived for another (a hybrid's
    battery, machines, accessories on the electric network or management varied over a grid: 1.7 ms of a
    2.5 ms run each).

    The schedule returned is shared: do not write into its arrays. (They stay writable, as a fresh
    derivation's: compiled kernels specialise on an array's writability, and a read-only schedule would be a
    signature the install's compiled cache does not hold, compiled again on a user's first run.)"""
    from .model.maps import cached_engine_map

    kept = memo(params, "default_schedules", lambda p: {})
    hit = kept.get(id(cycle))
    if hit is not None and hit[0] is cycle:  # (the entry holds the cycle: its id is not reused meanwhile)
        return hit[1]
    sections = (params.vehicle, params.transmission, params.engine, params.simulation)
    shared = _BY_SECTIONS.get(sections)
    if shared is None:
        shared = {}
        _keep(_BY_SECTIONS, sections, shared, SECTION_SETS_KEPT)
    hit = shared.get(id(cycle))
    if hit is not None and hit[0] is cycle:
        schedule = hit[1]
    else:
        schedule = default_schedule(cycle, params, cached_engine_map(params.engine))
        _keep(shared, id(cycle), (cycle, schedule), SCHEDULES_KEPT)
    _keep(kept, id(cycle), (cycle, schedule), SCHEDULES_KEPT)
    return schedule


def _keep(table: dict, key, value, most: int) -> None:
    """``table[key] = value``, the oldest entry dropped first when ``table`` holds ``most``."""
    if len(table) >= most:
        try:
            table.pop(next(iter(table)), None)
        except (RuntimeError, StopIteration):  # another thread changed the table meanwhile: keep it
            pass
    table[key] = value


def default_schedule(cycle: Cycle, params, engine_map=None, rule: GearRule | None = None) -> GearSchedule:
    """Derive the gear schedule of ``cycle`` once, by the documented rule (module docstring): ``rule``, or
    the one ``params`` sets (:meth:`GearRule.of`: the preset's is the documented 200 rad/s).

    The rule looks at every interval's demand; a coarse or gappy trace is first subdivided to 1 s steps
    (its piecewise-linear speed unchanged), so its schedule is the one of the same trace sampled at 1 Hz.
    """
    from .cycles.resample import subdivide
    from .model.maps import max_torque

    t_fine, v_fine, original = subdivide(cycle.time_s, cycle.speed_mps, RULE_STEP_S)
    if original is not None:
        cycle = Cycle(cycle.name, t_fine, v_fine, source=cycle.source)
    rule = rule or GearRule.of(params)
    if rule.upshift_speed is not None and params.transmission.is_cvt:
        raise CycleError(
            "gear rule: upshift_speed is a stepped gearbox's table of shift speeds; a CVT chooses its ratio"
        )
    ratios = np.asarray(params.transmission.ratios)
    n_g = len(ratios)
    v, a, w_e, _, t_cr, _ = interval_demand(cycle, ratios[:, None], params)  # shape (gears, intervals)
    if engine_map is not None:
        t_max = engine_map.max_torque(w_e)
    elif params.transmission.is_cvt and w_e.size > 4 * FULL_LOAD_NODES:
        # a CVT's grid has many points: the full-load line at FULL_LOAD_NODES speeds, interpolated linearly
        # (the line is smooth; its deviation is far below the rule's torque reserve)
        nodes = np.linspace(float(w_e.min()), float(w_e.max()), FULL_LOAD_NODES)
        t_max = np.interp(w_e, nodes, max_torque(nodes, params.engine))
    else:
        t_max = max_torque(w_e, params.engine)
    speed_ok = w_e <= rule.max_engine_speed
    admissible = speed_ok & (t_cr <= rule.torque_reserve * t_max)
    # nothing fits: the gear with the largest traction reserve within the speed limit (the highest gear if
    # even that is over-speed); the trace miss is then reported by the method
    none = ~admissible.any(axis=0)
    if np.any(none):
        reserve = np.where(speed_ok, ratios[:, None] * (t_max - t_cr), -np.inf)
        fallback = np.where(speed_ok.any(axis=0), np.argmax(reserve, axis=0), n_g - 1)
        admissible[fallback[none], np.flatnonzero(none)] = True
    w_keep = rule.min_engine_speed
    if rule.full_load_engine_speed is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            load = np.clip(np.where(t_max > 0, t_cr / t_max, 1.0), 0.0, 1.0)
        w_keep = rule.min_engine_speed + (rule.full_load_engine_speed - rule.min_engine_speed) * load
    high_enough = admissible & (w_e >= w_keep)
    gears = np.arange(1, n_g + 1)[:, None]
    best_high = np.where(high_enough, gears, 0).max(axis=0)
    lowest_adm = np.where(admissible, gears, n_g + 1).min(axis=0)
    gear = np.where(best_high > 0, best_high, lowest_adm)
    if rule.upshift_engine_speed is not None or rule.upshift_speed is not None:
        # gear g is reached once the engine in gear g - 1 has reached the shift point (w_e falls with the
        # gear, so the gears reached are 1..cap), and at the vehicle speed from which the table allows it
        cap = np.full(a.shape, n_g)
        if rule.upshift_engine_speed is not None:
            cap = 1 + np.sum(w_e[:-1] >= rule.upshift_engine_speed, axis=0)
        if rule.upshift_speed is not None:
            v_up = rule.upshift_speeds(n_g)
            cap = np.minimum(cap, 1 + np.sum(v[None, :] >= v_up[:, None], axis=0))
        cap = np.where(a > rule.cruise_acceleration, cap, n_g)
        capped = np.where(admissible & (gears <= cap[None, :]), gears, 0).max(axis=0)
        gear = np.where(capped > 0, np.minimum(gear, capped), lowest_adm)
    n = gear.size
    # no upshift while decelerating
    for k in range(1, n):
        if a[k] < 0 and gear[k] > gear[k - 1] and admissible[gear[k - 1] - 1, k]:
            gear[k] = gear[k - 1]
    # merge short engagements into the preceding gear where admissible (a CVT has no shift to hold)
    dt = np.diff(cycle.time_s)
    hold = 0.0 if params.transmission.is_cvt else rule.min_hold_s
    k = 1
    while hold > 0.0 and k < n:
        if gear[k] != gear[k - 1]:
            j = k
            while j < n and gear[j] == gear[k]:
                j += 1
            dur = float(np.sum(dt[k:j]))
            prev = gear[k - 1]
            if dur < hold and j < n and np.all(admissible[prev - 1, k:j]):
                gear[k:j] = prev
            k = j
        else:
            k += 1
    full = np.append(gear, gear[-1])
    return GearSchedule(cycle.time_s.copy(), full, source="default rule")


MAX_GEAR_FILE_BYTES = 64 * 1024 * 1024  # a gear schedule larger than this is refused


def load_schedule(path: str | Path, n_gears: int, *, cycle: Cycle | None = None) -> GearSchedule:
    """Read a gear schedule CSV with columns ``time_s,gear`` (gear 0 = neutral, 1..n_gears engaged).

    The stiff-driveline model of the paper has no clutch: a neutral sample (0) keeps the gear engaged
    before it (or gear 1 at the start). The file is read like a cycle CSV: UTF-8 with or without BOM, any
    newline convention, ``#`` comment lines, ``,`` ``;`` or tab as delimiter. With ``cycle`` given, every
    time must lie within the cycle. Errors name the line.
    """
    from .cycles import _clip, _cut, _number, _rows, _sniff_delimiter, _uncommented

    path = Path(path)
    text = read_text(path, CycleError, limit=MAX_GEAR_FILE_BYTES, what="gear schedule CSV file")
    delim = _sniff_delimiter(io.StringIO(text))
    reader = csv.reader(_uncommented(io.StringIO(text)), delimiter=delim)
    times: list[float] = []
    gears: list[int] = []
    header = None
    ti = gi = -1
    for lineno, row in _rows(reader, path):
        if not row or not "".join(row).strip():
            continue
        if header is None:
            header = [h.strip().lower() for h in row]
            if "time_s" not in header or "gear" not in header:
                raise CycleError(
                    f"{path}:{lineno}: header must contain time_s and gear, got {_cut(','.join(header), 80)}"
                )
            for col in ("time_s", "gear"):
                if header.count(col) > 1:
                    raise CycleError(f"{path}:{lineno}: column {col!r} appears twice in the header")
            ti, gi = header.index("time_s"), header.index("gear")
            continue
        if len(row) <= max(ti, gi):
            raise CycleError(f"{path}:{lineno}: expected {len(header)} fields, got {len(row)}")
        t_text, g_text = row[ti].strip(), row[gi].strip()
        try:
            t = _number(t_text)
        except ValueError:
            raise CycleError(f"{path}:{lineno}: time_s {_cut(t_text)} is not a number") from None
        if not math.isfinite(t):
            raise CycleError(f"{path}:{lineno}: time_s is {_clip(t_text)}, expected a finite number")
        try:
            gf = _number(g_text)
        except ValueError:
            raise CycleError(f"{path}:{lineno}: gear {_cut(g_text)} is not a number") from None
        if not math.isfinite(gf):
            raise CycleError(
                f"{path}:{lineno}: gear is {_clip(g_text)}, expected a whole number in 0..{n_gears}"
            )
        if not gf.is_integer() or not 0 <= gf <= n_gears:
            raise CycleError(f"{path}:{lineno}: gear {_clip(g_text)} is not a whole number in 0..{n_gears}")
        if times and t <= times[-1]:
            raise CycleError(f"{path}:{lineno}: time {t:g} does not increase (previous {times[-1]:g})")
        if cycle is not None:
            t0, t1 = float(cycle.time_s[0]), float(cycle.time_s[-1])
            if not t0 <= t <= t1:
                raise CycleError(
                    f"{path}:{lineno}: time {t:g} s is outside the cycle {cycle.name} ({t0:g} to {t1:g} s)"
                )
        times.append(t)
        gears.append(int(gf))
    if header is None:
        raise CycleError(f"{path}: empty file, expected a header time_s,gear and gear samples")
    if len(times) < 1:
        raise CycleError(f"{path}: no gear samples after the header")
    g = np.array(gears)
    for k in range(len(g)):
        if g[k] == 0:
            g[k] = g[k - 1] if k > 0 else 1
    return GearSchedule(np.array(times), g, source=str(path))


def agreement(a: np.ndarray, b: np.ndarray, mask=None) -> float:
    """Share of samples where two gear sequences agree (optionally over ``mask``)."""
    a, b = np.asarray(a), np.asarray(b)
    if mask is None:
        mask = np.ones(a.shape, bool)
    return float(np.mean(a[mask] == b[mask])) if np.any(mask) else float("nan")
