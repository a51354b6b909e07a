"""Calibration of the physical engine model to a measured fuel map by bounded least squares.

A user with one measured engine wants a physical model that reproduces it and then scales. This module fits
the model's uncertain engine parameters (by default the thermal efficiency eta_th and Soltic's friction
factor xi_aux) so that the BQM fuel flow (paper section 3) matches the measured map, with
:func:`scipy.optimize.least_squares` inside physical bounds, and reports the uncertainty of the fit from its
Jacobian: covariance = s^2 (J^T J)^-1 with s^2 = sum(r^2) / (n - p).

    >>> from vpsim.calibration import DEFAULT_PARAMETERS, DEFAULT_BOUNDS
    >>> DEFAULT_PARAMETERS
    ('thermal_efficiency', 'friction_coefficient')
    >>> DEFAULT_BOUNDS["thermal_efficiency"]
    (0.25, 0.45)

What can be identified from a fuel map. The BQM fuel flow is
mdot_f = w_e V_d / (4 pi R T_i (A/F)_s lambda) * [X(T_cr, w_e) - y_i/s_i] / (Q + 1/s_i), with Q proportional
to eta_th and X = BMEP + FMEP + p_e from (2)-(6) (friction (5) by Soltic's law). So eta_th, the
air-charge slope s_i and intercept y_i enter only through two combinations, Q + 1/s_i and y_i/s_i: the three
cannot all be fitted (J^T J is singular; the standard errors reported are then infinite). y_i/s_i is a
constant next to the constant part of the friction, so y_i, even fitted alone with eta_th and xi_aux,
correlates strongly with xi_aux (|rho| > 0.9 on the ADVISOR engines, standard error ~ its value). Hence the
default pair (eta_th, xi_aux); any float fields of :class:`vpsim.params.Engine` may be passed.

What the fit matches (``data``):

* ``"cycle"`` (default): the measured map as the backward method reads it
  (:class:`vpsim.engines.measured.MeasuredEngineMap`, interpolation and extrapolation rules included) at
  the operating points a vehicle visits with traction (T_cr > 0) on the calibration cycles, each point
  weighted by its duration. The residual is the difference in fuel flow (kg/s, after the idle floor of
  both), divided by the mean measured flow: points count by the fuel they burn, as in the cycle total.
  Relative residuals would give the many near-zero-flow points at light load unbounded weight. The default
  calibration cycle is the WLTC class 3b, which is not one of the paper's Table 4 cycles, so Table 4's
  calibrated column is an out-of-sample check.
* ``"map"``: the measured nodes with positive torque on or below the full-load curve, each with the same
  weight, residual = relative error. This fits the whole map, including regions a car seldom visits.

The covariance treats the residuals as independent. Neighbouring seconds of a cycle are not, and the model
misses part of the map's structure, so the standard errors are lower bounds on the real uncertainty.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .errors import VpsimError
from .params import MAX_THERMAL_EFFICIENCY

DEFAULT_PARAMETERS = ("thermal_efficiency", "friction_coefficient")

# Physical bounds (SI). eta_th: gross indicated efficiency of SI engines; xi_aux: Soltic's law scaled by at
# most 3x either way; y_i: volumetric efficiency at wide-open throttle s_i - y_i/p_a between ~0.75 and s_i;
# s_i: Froberg's slope 0.95 within +-25 %.
DEFAULT_BOUNDS: dict[str, tuple[float, float]] = {
    "thermal_efficiency": (0.25, 0.45),
    "friction_coefficient": (0.3, 3.0),
    "air_charge_intercept": (0.0, 2.0e4),
    "air_charge_slope": (0.7, 1.2),
}
DEFAULT_CALIBRATION_CYCLES = ("wltc3b",)
_COND_LIMIT = 1e10  # condition number of J^T J (scaled) beyond which parameters are not identifiable


@dataclass(frozen=True, eq=False)
class Calibration:
    """The result of :func:`calibrate`. ``engine`` is the calibrated :class:`vpsim.params.Engine`."""

    names: tuple[str, ...]
    initial: tuple[float, ...]
    values: tuple[float, ...]
    std_errors: tuple[float, ...]  # inf where not identifiable, nan where the value sits on a bound
    bounds: tuple[tuple[float, float], ...]
    at_bound: tuple[bool, ...]
    correlation: np.ndarray = field(repr=False)
    covariance: np.ndarray = field(repr=False)
    data: str = "cycle"
    cycles: tuple[str, ...] = ()
    n_points: int = 0
    rms_residual: float = float("nan")
    condition_number: float = float("nan")
    engine: Any = field(default=None, repr=False)
    message: str = ""

    def value(self, name: str) -> float:
        return self.values[self.names.index(name)]

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly summary: per parameter its initial and fitted value, standard error, bounds."""

        def num(x: float) -> float | str:
            return float(x) if np.isfinite(x) else str(x)

        return {
            "data": self.data,
            "cycles": list(self.cycles),
            "n_points": self.n_points,
            "rms_residual": num(self.rms_residual),
            "condition_number": num(self.condition_number),
            "message": self.message,
            "parameters": {
                n: {
                    "initial": self.initial[k],
                    "value": self.values[k],
                    "std_error": num(self.std_errors[k]),
                    "bounds": list(self.bounds[k]),
                    "at_bound": self.at_bound[k],
                }
                for k, n in enumerate(self.names)
            },
            "correlation": [[num(c) for c in row] for row in self.correlation],
        }


def cycle_operating_points(measured_map, params, cycles) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(T_cr, w_e, dt) of the traction intervals (T_cr > 0) of ``cycles`` in ``params``'s vehicle.

    The gear schedule is the documented default rule with the measured full-load curve, as in Table 4.
    """
    from .cycles import load_cycle
    from .gears import default_schedule
    from .methods import backward

    torques, speeds, durations = [], [], []
    for c in cycles:
        cyc = load_cycle(c) if isinstance(c, str) else c
        schedule = default_schedule(cyc, params, measured_map)
        op = backward.intervals(cyc, params, engine_map=measured_map, schedule=schedule, mode="paper")
        t_cr = op["crank_torque_nm"]
        w_e = op["engine_speed_radps"]
        dt = op["dt_s"]
        trac = t_cr > 0
        torques.append(t_cr[trac])
        speeds.append(w_e[trac])
        durations.append(dt[trac])
    return np.concatenate(torques), np.concatenate(speeds), np.concatenate(durations)


def calibrate(
    measured_map,
    params,
    *,
    parameters: tuple[str, ...] = DEFAULT_PARAMETERS,
    data: str = "cycle",
    cycles=DEFAULT_CALIBRATION_CYCLES,
    bounds: dict[str, tuple[float, float]] | None = None,
) -> Calibration:
    """Fit ``parameters`` of ``params.engine`` to ``measured_map`` (a MeasuredEngineMap).

    ``params`` gives the engine to start from (e.g. the scaled engine of a preset), and for ``data="cycle"``
    the vehicle, gears rule and idle flow. See the module docstring for ``data`` and the identifiability of
    the parameters. Raises :class:`vpsim.errors.VpsimError` for unknown parameters or bad bounds.
    """
    from scipy.optimize import least_squares

    from .model.maps import bqm_fuel_flow

    eng = params.engine
    names = tuple(parameters)
    known = {f for f in eng.__dataclass_fields__ if isinstance(getattr(eng, f), float)}
    for n in names:
        if n not in known:
            raise VpsimError(f"cannot calibrate {n!r}; numeric engine fields are {', '.join(sorted(known))}")
    if len(set(names)) != len(names) or not names:
        raise VpsimError("calibration parameters must be distinct and at least one")
    bnds = {**DEFAULT_BOUNDS, **(bounds or {})}
    lo, hi = [], []
    for n in names:
        if n not in bnds:
            raise VpsimError(f"no bounds for {n!r}: pass bounds={{{n!r}: (low, high)}}")
        a, b = bnds[n]
        if not a < b:
            raise VpsimError(f"bounds for {n!r} must be increasing, got ({a}, {b})")
        if n == "thermal_efficiency" and not 0.0 < a < b < MAX_THERMAL_EFFICIENCY:
            raise VpsimError(
                f"bounds for 'thermal_efficiency' ({a}, {b}) must lie in (0, {MAX_THERMAL_EFFICIENCY:g}): no "
                "engine converts more of its fuel's heat (vpsim.params.MAX_THERMAL_EFFICIENCY)"
            )
        lo.append(float(a))
        hi.append(float(b))
    x0 = np.clip([float(getattr(eng, n)) for n in names], lo, hi)
    idle = params.simulation.idle_fuel_flow

    if data == "cycle":
        t, w, dt = cycle_operating_points(measured_map, params, cycles)
        if t.size <= len(names):
            raise VpsimError("the calibration cycles give too few operating points with traction")
        f_meas = np.maximum(measured_map.fuel_flow(t, w), idle)
        weight = np.sqrt(dt / dt.sum())
        scale = float(np.sum(f_meas * dt) / dt.sum())

        def residuals(x):
            e = replace(eng, **dict(zip(names, x, strict=True)))
            return weight * (np.maximum(bqm_fuel_flow(t, w, e), idle) - f_meas) / scale

        cycle_names = tuple(getattr(c, "name", c) for c in cycles)
    elif data == "map":
        m = measured_map.engine
        tg = measured_map.loaded_torque_grid
        cols = np.isin(m.torque_grid, tg)
        t_node, w_node = np.meshgrid(tg, m.speed_grid)
        f_node = m.fuel_flow[:, cols]
        use = (t_node > 0) & (t_node <= m.max_torque_at(w_node) + 1e-9) & (f_node > 0)
        t, w, f_meas = t_node[use], w_node[use], f_node[use]

        def residuals(x):
            e = replace(eng, **dict(zip(names, x, strict=True)))
            return bqm_fuel_flow(t, w, e) / f_meas - 1.0

        cycle_names = ()
    else:
        raise VpsimError(f"data must be 'cycle' or 'map', got {data!r}")

    x_scale = np.maximum(np.abs(x0), 1e-3 * (np.array(hi) - np.array(lo)))
    sol = least_squares(residuals, x0, bounds=(lo, hi), x_scale=x_scale, method="trf")
    r = sol.fun
    n, p = r.size, len(names)
    at_bound = tuple(bool(a != 0) for a in sol.active_mask)
    free = np.array([not a for a in at_bound])
    cov = np.full((p, p), np.nan)
    std = np.full(p, np.nan)
    cond = float("nan")
    message = ""
    if free.any() and n > p:
        s2 = float(r @ r) / (n - p)
        jf = sol.jac[:, free] * x_scale[free]  # scaled columns: the conditioning of the problem itself
        jtj = jf.T @ jf
        cond = float(np.linalg.cond(jtj))
        if cond > _COND_LIMIT:
            std[free] = np.inf
            message = (
                f"J^T J is singular (condition number {cond:.1e}): "
                f"{', '.join(np.array(names)[free])} cannot all be identified from this data"
            )
        else:
            cf = s2 * np.linalg.inv(jtj) * np.outer(x_scale[free], x_scale[free])
            idx = np.flatnonzero(free)
            cov[np.ix_(idx, idx)] = cf
            std[idx] = np.sqrt(np.diag(cf))
    if any(at_bound):
        hit = ", ".join(n for n, a in zip(names, at_bound, strict=True) if a)
        message = (message + "; " if message else "") + f"at a bound: {hit} (no standard error)"
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    values = tuple(float(v) for v in sol.x)
    return Calibration(
        names=names,
        initial=tuple(float(v) for v in x0),
        values=values,
        std_errors=tuple(float(s) for s in std),
        bounds=tuple(zip(lo, hi, strict=True)),
        at_bound=at_bound,
        correlation=corr,
        covariance=cov,
        data=data,
        cycles=tuple(str(c) for c in cycle_names),
        n_points=int(n),
        rms_residual=float(np.sqrt(np.mean(r**2))) if data == "map" else float(np.sqrt(r @ r)),
        condition_number=cond,
        engine=replace(eng, **dict(zip(names, values, strict=True))),
        message=message,
    )
