"""Quasi-static maps generated from the physical model (paper section 3).

* FQM, the forward quasi-static model: impose (A_eff, w_e), set dp_i/dt = 0 in (9), solve for p_i (choked-flow
  check, else Newton on theta(p_i) (19)), then T_cr and mdot_f. Over a grid this gives the torque lines of
  Figure 2; the line at A_eff = A_max is the maximum-torque line that limits the backward method.
* BQM, the backward quasi-static model: impose (T_cr, w_e), solve delta(p_i) = 0 (closed form, it is linear),
  then mdot_f. Over a grid this gives the fuel map of Figure 3, used by the backward method as a 2-D table.

:class:`GeneratedEngineMap` bundles both for one engine and is what the backward method consumes; a measured
map (:mod:`vpsim.engines`) offers the same ``fuel_flow`` / ``max_torque`` interface.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from . import physics as ph


@dataclass(frozen=True)
class SteadyState:
    """Solution of the FQM at given (A_eff, w_e) (arrays broadcast)."""

    intake_pressure: np.ndarray  # Pa
    crank_torque: np.ndarray  # N m
    fuel_flow: np.ndarray  # kg/s
    choked: np.ndarray  # bool
    iterations: np.ndarray  # Newton iterations used (0 where choked)
    converged: np.ndarray  # bool


def steady_state(a_eff, w_e, eng, *, max_iter: int = 30, rtol: float = 1e-12) -> SteadyState:
    """FQM: steady state of the manifold (9) for imposed throttle area and engine speed.

    Choked flow is tried first ((10),(12) with (8),(9) solved for p_i); where the resulting pressure ratio is
    above the critical one (11) the flow is subcritical and theta(p_i) = 0 (19) is solved by Newton's method.
    theta is concave and decreasing in p_i, so Newton started to the right of the root (the choked estimate,
    or just below p_a as the paper does) converges monotonically. The paper stops at 10 iterations and a
    relative tolerance; ``max_iter``/``rtol`` default tighter so maps agree with the dynamic model to
    rounding.
    At w_e = 0 nothing leaves the manifold and p_i = p_a.
    """
    a_eff, w_e = np.broadcast_arrays(np.asarray(a_eff, float), np.asarray(w_e, float))
    p_a = eng.ambient_pressure
    gamma = eng.specific_heat_ratio
    crit = ph.critical_pressure_ratio(gamma)
    vd = ph.displacement(eng)
    rt_i = eng.gas_constant * eng.intake_temperature
    with np.errstate(divide="ignore", invalid="ignore"):
        # choked: mdot_at fixed; w_e (s_i p_i - y_i) V_d / (2 pi n_r R T_i) = mdot_at
        mdot_choked = ph.throttle_mass_flow(a_eff, 0.0, eng)
        p_choked = (
            mdot_choked * ph.TWO_PI * eng.revolutions_per_cycle * rt_i / (w_e * vd) + eng.air_charge_intercept
        ) / (eng.air_charge_slope)
    moving = w_e > 0
    choked = moving & (p_choked / p_a <= crit)
    p = np.where(choked, p_choked, p_a)
    iters = np.zeros(p.shape, dtype=int)
    converged = np.ones(p.shape, dtype=bool)
    sub = moving & ~choked
    if np.any(sub):
        a_s, w_s = a_eff[sub], w_e[sub]
        x = np.minimum(p_choked[sub], p_a * (1.0 - 1e-9))
        k_cyl = w_s * vd / (ph.TWO_PI * eng.revolutions_per_cycle * rt_i)
        k_thr = p_a * a_s / np.sqrt(eng.gas_constant * eng.ambient_temperature)
        done = np.zeros(x.shape, dtype=bool)
        n = np.zeros(x.shape, dtype=int)
        for _ in range(max_iter):
            pr = x / p_a
            theta = k_thr * ph.psi(pr, gamma) - k_cyl * (eng.air_charge_slope * x - eng.air_charge_intercept)
            dtheta = k_thr * ph.dpsi_dpr(pr, gamma) / p_a - k_cyl * eng.air_charge_slope
            step = np.where(done, 0.0, theta / dtheta)
            x_new = x - step
            # keep the iterate inside the subcritical bracket (p_r*, 1)
            x_new = np.clip(x_new, crit * p_a, p_a * (1.0 - 1e-15))
            n += ~done
            done |= np.abs(x_new - x) <= rtol * np.abs(x_new)
            x = x_new
            if done.all():
                break
        p[sub] = x
        iters[sub] = n
        converged[sub] = done
    return SteadyState(
        intake_pressure=p,
        crank_torque=ph.crank_torque(p, w_e, eng),
        fuel_flow=ph.fuel_flow(p, w_e, eng),
        choked=choked,
        iterations=iters,
        converged=converged,
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
    """The maximum-torque line: FQM crank torque at A_eff = A_max."""
    return steady_state(eng.max_throttle_area, w_e, eng).crank_torque


def min_torque(w_e, eng):
    """The engine-braking line: FQM crank torque at A_eff = A_min (closed throttle)."""
    return steady_state(eng.min_throttle_area, w_e, eng).crank_torque


def bqm_fuel_flow(t_cr, w_e, eng):
    """BQM: fuel mass flow (kg/s) for imposed crank torque and engine speed, from delta(p_i) = 0."""
    return ph.fuel_flow(ph.intake_pressure_for_torque(t_cr, w_e, eng), w_e, eng)


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
        return np.interp(w_e, self.max_torque_speed, self.max_torque_values)

    def min_torque(self, w_e):
        """Engine-braking line (FQM at A_min, closed throttle), N m."""
        return np.interp(w_e, self.max_torque_speed, self.min_torque_values)

    def fuel_flow(self, t_cr, w_e):
        if self.exact:
            return bqm_fuel_flow(t_cr, w_e, self.engine)
        return bilinear(self.speed, self.torque, self.table, w_e, t_cr)

    def intake_pressure(self, t_cr, w_e):
        return ph.intake_pressure_for_torque(t_cr, w_e, self.engine)

    def with_exact(self, exact: bool = True) -> GeneratedEngineMap:
        from dataclasses import replace

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
    closed-throttle line's minimum to the max-torque line's maximum; outside it, :func:`bilinear` extrapolates
    linearly, which is exact in torque.
    """
    lo, hi = eng.map_speed_range
    w_max = 1.25 * hi if max_speed is None else max_speed
    w_line = np.linspace(0.0, w_max, int(round(w_max / 1.0)) + 1)
    t_line = max_torque(w_line, eng)
    t_closed = min_torque(w_line, eng)
    t_min = float(np.min(t_closed))
    t_hi = float(np.max(t_line))
    speed = np.linspace(0.0, w_max, int(np.ceil(w_max / speed_step)) + 1)
    n_t = int(np.ceil((t_hi - t_min) / torque_step)) + 1
    torque = np.linspace(t_min, t_hi, max(n_t, 2))
    table = bqm_fuel_flow(torque[None, :], speed[:, None], eng)
    return GeneratedEngineMap(eng, speed, torque, table, w_line, t_line, t_closed, exact)


def bilinear(xg, yg, table, x, y):
    """Bilinear interpolation on a regular-or-not rectilinear grid, linear extrapolation outside."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    i = np.clip(np.searchsorted(xg, x) - 1, 0, len(xg) - 2)
    j = np.clip(np.searchsorted(yg, y) - 1, 0, len(yg) - 2)
    tx = (x - xg[i]) / (xg[i + 1] - xg[i])
    ty = (y - yg[j]) / (yg[j + 1] - yg[j])
    f00 = table[i, j]
    f01 = table[i, j + 1]
    f10 = table[i + 1, j]
    f11 = table[i + 1, j + 1]
    return (1 - tx) * ((1 - ty) * f00 + ty * f01) + tx * ((1 - ty) * f10 + ty * f11)


@functools.lru_cache(maxsize=64)
def cached_engine_map(eng) -> GeneratedEngineMap:
    """:func:`generate_engine_map` with default resolution, cached per (immutable) engine parameter set."""
    return generate_engine_map(eng)
