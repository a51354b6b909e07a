"""The PI driver of the forward dynamic method (paper section 2 and Table 1).

The driver compares the cycle speed with the vehicle speed, e = v_cycle - v, and commands a pedal signal

    u_raw = K_p e + z,          dz/dt = K_i e + (u - u_raw) / T_t,          u = clip(u_raw, u_lo, u_hi),

in m² of effective throttle area. ``z`` is the integral state; the second term of dz/dt is back-calculation
anti-windup (Astrom & Hagglund): while the command is saturated, the integral is pulled towards the limit
with time constant T_t instead of winding up, and the right side stays continuous, which is what an
adaptive integrator with error control needs (conditional integration would switch discontinuously).
T_t defaults to half the integral time K_p / K_i.

How the command acts (see :func:`pedal_split`):

* ``paper`` mode (no brakes): u_lo = A_min, u_hi = A_max and the throttle area is u.
* A boosted engine's command continues above A_max to 2 A_max: the throttle stays wide open and the boost
  rises (:func:`vpsim.model.engine.throttle_upstream`).
* ``extended`` mode: the range continues below zero into the brake pedal, u_lo = -A_max. The throttle is
  max(u, A_min); for u < 0 the friction brakes give the force ``brake_gain * (-u)`` with
  ``brake_gain = m g / A_max``, so the full negative range is a 1 g stop. Brakes act only once the throttle is
  closed, i.e. they take what engine braking cannot.

:func:`pi_law` and :func:`pedal_split` are plain Python functions that numba also compiles into the forward
integrator (``register_jitable``); the forward method's pure-Python reference path calls them as they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba.extending import register_jitable

from ..errors import VpsimError


@register_jitable
def pi_law(e, z, kp, ki, u_lo, u_hi, antiwindup_gain):
    """Saturated PI command and integral-state rate with back-calculation anti-windup: (u, dz/dt).

    ``antiwindup_gain`` is 1 / T_t (1/s).
    """
    raw = kp * e + z
    u = raw
    if u < u_lo:
        u = u_lo
    elif u > u_hi:
        u = u_hi
    return u, ki * e + (u - raw) * antiwindup_gain


@register_jitable
def pedal_split(u, a_min, brake_gain):
    """Throttle area (m²) and brake force (N) for a pedal command ``u`` (brake_gain = 0: no brakes)."""
    throttle = u if u > a_min else a_min
    brake = -u * brake_gain if u < 0.0 else 0.0
    return throttle, brake


def command_limits(vehicle, engine, u_max, mode: str):
    """(u_lo, u_hi, A_min, brake gain) of the PI command in ``mode``; ``u_max`` is the command's upper end
    (:func:`vpsim.model.engine.max_command`). Fields may be arrays over design variants (vpsim.batch).

    ``paper``: the command spans the throttle, [A_min, u_max], and there are no brakes. ``realistic``: below
    A_min the pedal brakes, down to -A_max, where the brake force is the car's weight (gain m g / A_max).
    """
    from ..model.rules import canonical_mode

    mode = canonical_mode(mode)
    if mode == "paper":
        return engine.min_throttle_area, u_max, engine.min_throttle_area, 0.0
    if mode == "realistic":
        gain = vehicle.mass * vehicle.gravity / engine.max_throttle_area
        return -engine.max_throttle_area, u_max, engine.min_throttle_area, gain
    raise VpsimError(f"unknown mode {mode!r}; expected paper or extended")


@dataclass(frozen=True)
class PIDriver:
    """A PI driver's gains and command range (SI: m² per m/s, m² per m, m², s, N/m²)."""

    kp: float
    ki: float
    u_lo: float
    u_hi: float
    a_min: float
    tracking_time_s: float
    brake_gain: float = 0.0

    def __post_init__(self):
        for name in ("kp", "ki", "tracking_time_s"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise VpsimError(f"PI driver: {name} = {v!r} must be a positive number")
        if not self.u_lo < self.u_hi:
            raise VpsimError(f"PI driver: command range [{self.u_lo:g}, {self.u_hi:g}] is empty")

    @classmethod
    def from_params(
        cls, params, driver, mode: str = "paper", tracking_time_s: float | None = None
    ) -> PIDriver:
        """The driver ``driver`` ("1", "2") of a parameter set, for ``mode`` ``paper`` or ``extended``."""
        from ..result import limits_of

        d = params.driver(driver)
        u_max = limits_of(params)["max_throttle_command_m2"]  # A_max; 2 A_max boosted (full boost)
        tt = 0.5 * d.forward_kp / d.forward_ki if tracking_time_s is None else float(tracking_time_s)
        u_lo, u_hi, a_min, gain = command_limits(params.vehicle, params.engine, u_max, mode)
        return cls(d.forward_kp, d.forward_ki, u_lo, u_hi, a_min, tt, gain)

    @property
    def integral_time_s(self) -> float:
        """T_i = K_p / K_i."""
        return self.kp / self.ki

    def command(self, e, z):
        """(u, dz/dt) for speed error(s) ``e`` and integral state(s) ``z`` (arrays broadcast)."""
        e, z = np.broadcast_arrays(np.asarray(e, float), np.asarray(z, float))
        raw = self.kp * e + z
        u = np.clip(raw, self.u_lo, self.u_hi)
        return u, self.ki * e + (u - raw) / self.tracking_time_s

    def pedal(self, u):
        """(throttle area, brake force) for command(s) ``u``."""
        u = np.asarray(u, float)
        return np.maximum(u, self.a_min), np.where(u < 0.0, -u * self.brake_gain, 0.0)

    def as_array(self) -> np.ndarray:
        """[K_p, K_i, u_lo, u_hi, 1/T_t, A_min, brake_gain] for the compiled integrator."""
        return np.array(
            [self.kp, self.ki, self.u_lo, self.u_hi, 1.0 / self.tracking_time_s, self.a_min, self.brake_gain],
            dtype=float,
        )
