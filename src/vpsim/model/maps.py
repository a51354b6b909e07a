"""Quasi-static maps generated from the model (paper section 3), and the engine-map protocol.

* FQM, the forward quasi-static model: impose (A_eff, w_e), set dp_i/dt = 0 in (9), solve for p_i
  (:func:`vpsim.model.engine.steady_pressure`), then T_cr and mdot_f. Over a grid this gives the torque lines
  of Figure 2; the line at A_eff = A_max is the maximum-torque line that limits the backward method.
* BQM, the backward quasi-static model: impose (T_cr, w_e), solve delta(p_i) = 0 (closed form,
  :func:`vpsim.model.engine.intake_pressure_for_torque`), then mdot_f. Over a grid this gives the fuel map of
  Figure 3, used by the backward method as a 2-D table.

:class:`GeneratedEngineMap` bundles both for one engine. Every engine map — generated here, measured
(:class:`vpsim.engines.measured.MeasuredEngineMap`) or derived from these — implements :class:`EngineMap`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace
from typing import Protocol, runtime_checkable

import numpy as np

from . import engine as en
from . import tables
from .record import engine_fields, engine_record, memo


@runtime_checkable
class EngineMap(Protocol):
    """What the backward method and the gear rule need of an engine: quasi-static fuel and torque limits."""

    @property
    def name(self) -> str: ...

    @property
    def inertia(self) -> float: ...

    def fuel_flow(self, t_cr, w_e) -> np.ndarray:
        """Fuel mass flow (kg/s) at crank torque ``t_cr`` (N m) and engine speed ``w_e`` (rad/s)."""

    def max_torque(self, w_e) -> np.ndarray:
        """Full-load crank torque (N m)."""

    def min_torque(self, w_e) -> np.ndarray:
        """Closed-throttle (engine-braking) crank torque (N m)."""


@dataclass(frozen=True)
class SteadyState:
    """Solution of the FQM at given (A_eff, w_e) (arrays broadcast)."""

    intake_pressure: np.ndarray  # Pa
    crank_torque: np.ndarray  # N m
    fuel_flow: np.ndarray  # kg/s
    choked: np.ndarray  # bool
    iterations: np.ndarray  # Newton iterations used (0 where choked)
    converged: np.ndarray  # bool


def steady_state(a_eff, w_e, eng) -> SteadyState:
    """FQM: steady state of the manifold (9) for imposed throttle area and engine speed (arrays broadcast).

    See :func:`vpsim.model.engine.steady_pressure` (choked-flow check, else Newton on (19)).
    """
    c = engine_fields(eng)  # the equations' fields; the compiled loop takes the record
    a_eff, w_e = np.broadcast_arrays(np.asarray(a_eff, float), np.asarray(w_e, float))
    p, it = en.steady_pressure_array(a_eff, w_e, engine_record(eng))
    return SteadyState(
        intake_pressure=p,
        crank_torque=en.crank_torque(p, w_e, c),
        fuel_flow=en.fuel_flow(p, w_e, c),
        choked=(w_e > 0) & (p / c.ambient_pressure <= c.critical_ratio),
        iterations=np.maximum(it, 0),
        converged=it >= 0,
    )


@dataclass(frozen=True)
class TorqueMap:
    """FQM over a grid: ``torque[i, j]`` at (``a_eff[i]``, ``speed[j]``) (paper Figure 2)."""

    a_eff: np.ndarray  # m^2
    speed: np.ndarray  # rad/s
    torque: np.ndarray  # N m
    intake_pressure: np.ndarray  # Pa
    fuel_flow: np.ndarray  # kg/s


def torque_map(eng, a_eff=None, speed=None) -> TorqueMap:
    """Torque lines T_cr(w_e) for a set of throttle areas (default: 12 areas up to A_max)."""
    if a_eff is None:
        a_eff = np.geomspace(2e-5, eng.max_throttle_area, 12)
    if speed is None:
        speed = np.linspace(*eng.map_speed_range, 121)
    a_eff, speed = np.asarray(a_eff, float), np.asarray(speed, float)
    ss = steady_state(a_eff[:, None], speed[None, :], eng)
    return TorqueMap(a_eff, speed, ss.crank_torque, ss.intake_pressure, ss.fuel_flow)


def max_torque(w_e, eng):
    """The maximum-torque line (:func:`vpsim.model.engine.full_load_torque`): the FQM at A_eff = A_max for an
    aspirated engine, at the boost pressure for a boosted one, capped at the rated power if given."""
    return en.full_load_torque_array(np.asarray(w_e, float), engine_record(eng))


def min_torque(w_e, eng):
    """The engine-braking line: FQM crank torque at A_eff = A_min (closed throttle)."""
    return steady_state(eng.min_throttle_area, w_e, eng).crank_torque


def bqm_fuel_flow(t_cr, w_e, eng):
    """BQM: fuel mass flow (kg/s) for imposed crank torque and engine speed, from delta(p_i) = 0."""
    return en.bqm_fuel_flow(np.asarray(t_cr, float), np.asarray(w_e, float), engine_fields(eng))


LINE_SPEED_STEP = 1.0  # rad/s between the nodes of the generated max- and min-torque lines
MAX_SPEED_FACTOR = 1.25  # the lines and the table reach 1.25 x the upper map speed


@dataclass(frozen=True)
class GeneratedEngineMap:
    """The engine as the backward method sees it: fuel map (Figure 3) and max-torque line, from the physics.

    ``fuel_flow(t_cr, w_e)`` interpolates the table bilinearly (the paper's lookup); ``exact=True`` evaluates
    the closed-form BQM instead. The table is exact in torque (mdot_f is affine in T_cr at fixed w_e) and
    interpolates the smooth w_e dependence; its spacing is chosen so the difference is below 1e-5.
    """

    engine: object = field(repr=False)
    speed: np.ndarray  # rad/s, table rows
    torque: np.ndarray  # N m, table columns
    table: np.ndarray  # kg/s, shape (len(speed), len(torque))
    max_torque_speed: np.ndarray
    max_torque_values: np.ndarray
    min_torque_values: np.ndarray
    exact: bool = False

    @property
    def inertia(self) -> float:
        return self.engine.inertia

    @property
    def name(self) -> str:
        return "generated"

    def max_torque(self, w_e):
        """Maximum-torque line (FQM at A_max), N m."""
        return tables.interp(w_e, self.max_torque_speed, self.max_torque_values)

    def min_torque(self, w_e):
        """Engine-braking line (FQM at A_min, closed throttle), N m."""
        return tables.interp(w_e, self.max_torque_speed, self.min_torque_values)

    def fuel_flow(self, t_cr, w_e):
        if self.exact:
            return bqm_fuel_flow(t_cr, w_e, self.engine)
        return tables.bilinear(self.speed, self.torque, self.table, w_e, t_cr)

    def intake_pressure(self, t_cr, w_e):
        return en.intake_pressure_for_torque(
            np.asarray(t_cr, float), np.asarray(w_e, float), engine_fields(self.engine)
        )

    def with_exact(self, exact: bool = True) -> GeneratedEngineMap:
        return replace(self, exact=exact)


def generate_engine_map(
    eng,
    *,
    max_speed: float | None = None,
    speed_step: float = 2.0,
    torque_step: float = 2.0,
    exact: bool = False,
) -> GeneratedEngineMap:
    """Build the BQM fuel map and the max-torque line of an engine.

    The table spans w_e from 0 to ``max_speed`` (default 1.25 x the upper map speed) and T_cr from the
    closed-throttle line's minimum to the max-torque line's maximum; outside it, the bilinear look-up
    extrapolates linearly, which is exact in torque.
    """
    lo, hi = eng.map_speed_range
    w_max = MAX_SPEED_FACTOR * hi if max_speed is None else max_speed
    w_line = np.linspace(0.0, w_max, int(round(w_max / LINE_SPEED_STEP)) + 1)
    t_line = max_torque(w_line, eng)
    t_closed = min_torque(w_line, eng)
    t_min = float(np.min(t_closed))
    t_hi = float(np.max(t_line))
    speed = np.linspace(0.0, w_max, int(np.ceil(w_max / speed_step)) + 1)
    n_t = int(np.ceil((t_hi - t_min) / torque_step)) + 1
    torque = np.linspace(t_min, t_hi, max(n_t, 2))
    table = bqm_fuel_flow(torque[None, :], speed[:, None], eng)
    for arr in (speed, torque, table, w_line, t_line, t_closed):
        arr.flags.writeable = False
    return GeneratedEngineMap(eng, speed, torque, table, w_line, t_line, t_closed, exact)


def cached_engine_map(eng) -> GeneratedEngineMap:
    """:func:`generate_engine_map` with default resolution, cached per (immutable) engine parameter set: kept
    on the engine object (an attribute look-up for every run of it), and shared by equal engines."""
    return memo(eng, "engine_map", _engine_map_of_equal)


@functools.lru_cache(maxsize=64)
def _engine_map_of_equal(eng) -> GeneratedEngineMap:
    return generate_engine_map(eng)
