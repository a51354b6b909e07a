"""The electric machine with its inverter: torque envelope and a scalable loss model, written once.

A machine is described by its rating, as an engine is by bore, stroke and cylinders: the peak (rated) power
``P_r``, the base (corner) speed ``w_b`` where the envelope turns from constant torque to constant power,
the maximum speed ``w_max``, the kind (``"pm"`` permanent-magnet synchronous or ``"induction"``) and seven
normalised loss coefficients. With ``T_r = P_r / w_b`` (the peak torque), ``tau = T / T_r``,
``omega = |w| / w_b``, ``nu = |w| / w_max`` and the fixed reference speed ``w_0``
(:data:`REFERENCE_SPEED_RADPS`, 1000 rpm), the loss of machine and inverter together is

    P_loss / P_r = k0                                  inverter standby, gate drives, control
                 + k_sw |tau|                          inverter switching and the constant voltage drop
                                                       of its semiconductors (both proportional to current)
                 + (w_0 / w_b) k_cu tau^2              stator (and rotor) copper, the inverter's resistive
                                                       conduction: proportional to current squared
                 + (w_0 / w_b) k_fw tau^2 (max(omega, 1)^2 - 1)
                                                       the extra current of field weakening above base
                                                       speed: at constant power the flux falls as 1/omega,
                                                       so the current per unit torque rises with omega
                 + k_fe_h nu                           hysteresis iron loss and bearing friction (per cycle)
                 + k_fe_e nu^2                         eddy-current iron loss
                 + k_mech nu^3                         windage

the textbook decomposition of machine losses (Guzzella & Sciarretta, *Vehicle Propulsion Systems*, 3rd ed.
2013, sec. 4.3; Larminie & Lowry, *Electric Vehicle Technology Explained*, 2nd ed. 2012, sec. 7.2, whose
loss model is ``k_c T^2 + k_i w + k_w w^3 + C``; Mellor, Roberts & Turner, IEE Proc. B 138 (1991) for the
iron-loss split). Every term is >= 0 for non-negative coefficients, so ``loss_w >= 0`` everywhere; the loss
is the same for motoring and generating at the same |T| and |w|, and ``electric_power = T w + loss`` is the
DC power drawn (negative when generating).

Two normalisations differ from scaling everything by ``P_r`` at ``omega``: the copper terms scale with the
peak *torque* (``P_r (w_0 / w_b) = T_r w_0``): the copper loss at peak torque grows with the machine's size,
which its torque sets, not with how fast it is rated to run; and the speed terms are taken at the fraction
of the *maximum* speed, since iron and windage loss are set by the speed the machine is built for. Both were
chosen by the leave-one-out check of ``benchmarks/machine_fit.py`` on six ADVISOR maps (docs/model.md,
"Electric machine"), where they lowered the median efficiency error from 4.1 to 2.9 points on average.

Scaling: at the same normalised point (tau, omega) and the same speeds the loss is proportional to ``P_r``, so
doubling the rating (the torque) at the same base and maximum speed doubles the loss and keeps the efficiency
map the same, as ADVISOR's ``mc_trq_scale`` does; a machine of the same torque rated to run faster loses
the same copper loss at the same torque, so it is more efficient there.

Each function marked :func:`~vpsim.model.engine.equation` is a plain function of scalars and the machine
record ``m`` (:func:`machine_record`); compiled kernels inline it, and Python calls it on NumPy arrays
(the functions are branch-free).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from ..errors import ParameterError
from .engine import equation

__all__ = [
    "DEFAULT_COEFFICIENTS",
    "KINDS",
    "REFERENCE_SPEED_RADPS",
    "LossCoefficients",
    "MachineSpec",
    "RECORD_DTYPE",
    "efficiency_errors_pts",
    "efficiency_table",
    "electric_power",
    "loss_polynomial",
    "loss_w",
    "machine_record",
    "max_torque",
    "min_torque",
    "torque_of_power",
]

KINDS = ("pm", "induction")
REFERENCE_SPEED_RADPS = 1000.0 * math.pi / 30.0  # w_0 of the copper terms: 1000 rpm


@dataclass(frozen=True)
class LossCoefficients:
    """The normalised loss coefficients (dimensionless, >= 0) of the model in this module's docstring."""

    k0: float
    k_sw: float
    k_cu: float
    k_fw: float
    k_fe_h: float
    k_fe_e: float
    k_mech: float

    def __post_init__(self) -> None:
        for f in fields(self):
            x = getattr(self, f.name)
            try:
                x = float(x)
            except (TypeError, ValueError):
                raise ParameterError(f"machine loss coefficient {f.name} = {x!r} is not a number") from None
            if not math.isfinite(x) or x < 0:
                raise ParameterError(
                    f"machine loss coefficient {f.name} = {x:g}; expected a finite number >= 0"
                )
            object.__setattr__(self, f.name, x)

    def as_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


COEFFICIENT_NAMES = tuple(f.name for f in fields(LossCoefficients))

# Defaults, fitted by benchmarks/machine_fit.py (ordinary least squares with non-negative coefficients on
# P_loss / P_r, over every map point in the torque envelope of both quadrants with T != 0 and w != 0) on all
# six ADVISOR 2003 motor maps of shared/data/raw/advisor, both kinds pooled (MC_AC59, MC_AC75, MC_PM32,
# MC_PM49, MC_PM58, MC_PRIUS_JPN): with two induction and four PM maps a fit per kind predicted a left-out
# map worse than the pooled fit, so both kinds share one set for now.
# Re-derive with `python benchmarks/machine_fit.py`; its leave-one-out table is in docs/model.md.
_POOLED = LossCoefficients(
    k0=0.00109615,
    k_sw=0.0386631,
    k_cu=0.191661,
    k_fw=0.0669655,
    k_fe_h=0.0321006,
    k_fe_e=0.0,
    k_mech=0.0262234,
)
DEFAULT_COEFFICIENTS: dict[str, LossCoefficients] = {"pm": _POOLED, "induction": _POOLED}


@dataclass(frozen=True)
class MachineSpec:
    """A machine with inverter, scaled by its rating (SI units).

    ``rated_power_w`` peak mechanical power (W); ``base_speed_radps`` corner speed of the envelope (rad/s);
    ``max_speed_radps`` highest speed (rad/s, >= base speed); ``kind`` ``"pm"`` or ``"induction"``;
    ``coefficients`` the normalised loss coefficients (``None``: :data:`DEFAULT_COEFFICIENTS` of the kind);
    ``inertia_kgm2`` rotor inertia (kg*m^2, 0 where unknown). Invalid values raise
    :class:`~vpsim.errors.ParameterError` with one line.
    """

    rated_power_w: float
    base_speed_radps: float
    max_speed_radps: float
    kind: str = "pm"
    coefficients: LossCoefficients | None = field(default=None)
    inertia_kgm2: float = 0.0

    def __post_init__(self) -> None:
        for name, positive in (
            ("rated_power_w", True),
            ("base_speed_radps", True),
            ("max_speed_radps", True),
            ("inertia_kgm2", False),
        ):
            x = getattr(self, name)
            try:
                x = float(x)
            except (TypeError, ValueError):
                raise ParameterError(f"machine {name} = {x!r} is not a number") from None
            if not math.isfinite(x) or x < 0 or (positive and x == 0):
                want = "a finite number > 0" if positive else "a finite number >= 0"
                raise ParameterError(f"machine {name} = {x:g}; expected {want}")
            object.__setattr__(self, name, x)
        if self.max_speed_radps < self.base_speed_radps:
            raise ParameterError(
                f"machine max_speed_radps = {self.max_speed_radps:g} is below base_speed_radps = "
                f"{self.base_speed_radps:g}; expected max speed >= base speed"
            )
        t_r = self.rated_power_w / self.base_speed_radps
        copper = REFERENCE_SPEED_RADPS / self.base_speed_radps
        if not (math.isfinite(t_r) and t_r > 0.0 and math.isfinite(copper)):
            raise ParameterError(
                f"machine rated torque P_r / w_b = {self.rated_power_w:g} W / {self.base_speed_radps:g} "
                f"rad/s = {t_r:g} N*m; expected a finite torque > 0"
            )
        if self.kind not in KINDS:
            raise ParameterError(f"machine kind = {self.kind!r}; expected one of {', '.join(KINDS)}")
        if self.coefficients is None:
            object.__setattr__(self, "coefficients", DEFAULT_COEFFICIENTS[self.kind])
        elif not isinstance(self.coefficients, LossCoefficients):
            raise ParameterError("machine coefficients must be a LossCoefficients (or None for the defaults)")

    @property
    def rated_torque_nm(self) -> float:
        """T_r = P_r / w_b, the peak torque of the constant-torque range (N*m)."""
        return self.rated_power_w / self.base_speed_radps

    @classmethod
    def from_measured(cls, machine, kind: str = "pm", coefficients: LossCoefficients | None = None):
        """The spec with a measured machine's rating: its peak power, corner speed and highest speed."""
        return cls(
            rated_power_w=machine.rated_power_w,
            base_speed_radps=machine.base_speed_radps,
            max_speed_radps=machine.max_speed_radps,
            kind=kind,
            coefficients=coefficients,
            inertia_kgm2=machine.inertia,
        )


RECORD_FIELDS = (
    "rated_power",  # P_r, W
    "base_speed",  # w_b, rad/s
    "max_speed",  # w_max, rad/s
    "rated_torque",  # T_r = P_r / w_b, N*m
    "inertia",  # kg*m^2
    "copper_scale",  # w_0 / w_b: the copper terms scale with T_r w_0
    *COEFFICIENT_NAMES,
)
RECORD_DTYPE = np.dtype([(name, np.float64) for name in RECORD_FIELDS])


def machine_record(spec: MachineSpec):
    """The machine as a read-only NumPy record (``m.rated_power``, ``m.k_cu`` ...) for the equations below:
    attribute access in Python, a Numba ``Record`` in compiled code. Fields: :data:`RECORD_FIELDS`."""
    if not isinstance(spec, MachineSpec):
        raise ParameterError(f"machine_record needs a MachineSpec, got {type(spec).__name__}")
    rec = np.zeros(1, dtype=RECORD_DTYPE).view(np.recarray)
    rec.rated_power = spec.rated_power_w
    rec.base_speed = spec.base_speed_radps
    rec.max_speed = spec.max_speed_radps
    rec.rated_torque = spec.rated_torque_nm
    rec.inertia = spec.inertia_kgm2
    rec.copper_scale = REFERENCE_SPEED_RADPS / spec.base_speed_radps
    for name in COEFFICIENT_NAMES:
        rec[name] = getattr(spec.coefficients, name)
    rec.flags.writeable = False
    return rec[0]


# --- equations -------------------------------------------------------------------------------------------


@equation
def _max2(a, b):
    """max(a, b) without a branch (scalars in kernels, arrays in Python)."""
    return 0.5 * (a + b + abs(a - b))


@equation
def max_torque(w, m):
    """Motoring torque limit (N*m) at speed ``w`` (rad/s, either sign): T_r up to the base speed, P_r / |w|
    above it (constant power), 0 above the maximum speed."""
    aw = abs(w)
    return m.rated_torque * m.base_speed / _max2(aw, m.base_speed) * (aw <= m.max_speed)


@equation
def min_torque(w, m):
    """Generating torque limit (N*m, <= 0): the motoring envelope mirrored, -max_torque(w). (ADVISOR's own
    estimate where a map gives no generating envelope; of the six measured maps only MC_PM49 has a lower
    generating limit at low speed.)"""
    return -max_torque(w, m)


@equation
def loss_w(t, w, m):
    """Loss of machine and inverter (W, >= 0) at torque ``t`` (N*m) and speed ``w`` (rad/s): the model of this
    module's docstring, the same for motoring and generating."""
    tau = t / m.rated_torque
    over = _max2(abs(w) / m.base_speed, 1.0)
    nu = abs(w) / m.max_speed
    tau2 = tau * tau
    return m.rated_power * (
        m.k0
        + m.k_sw * abs(tau)
        + m.copper_scale * tau2 * (m.k_cu + m.k_fw * (over * over - 1.0))
        + nu * (m.k_fe_h + nu * (m.k_fe_e + nu * m.k_mech))
    )


@equation
def electric_power(t, w, m):
    """DC electrical power (W) of machine and inverter: t w + loss_w(t, w, m); negative when generating."""
    return t * w + loss_w(t, w, m)


@equation
def loss_polynomial(w, sign, m):
    """(a, b, c) with loss_w(T, w, m) = a T^2 + b T + c for the torques T of sign ``sign`` (+1: T >= 0, -1:
    T <= 0) at speed w: :func:`loss_w`'s terms grouped by powers of T (at fixed w the loss is a quadratic in
    |T|: copper and field weakening in T^2, switching in |T|, standby, iron and windage constant)."""
    over = _max2(abs(w) / m.base_speed, 1.0)
    nu = abs(w) / m.max_speed
    tr = m.rated_torque
    a = m.rated_power * m.copper_scale * (m.k_cu + m.k_fw * (over * over - 1.0)) / (tr * tr)
    b = sign * m.rated_power * m.k_sw / tr
    c = m.rated_power * (m.k0 + nu * (m.k_fe_h + nu * (m.k_fe_e + nu * m.k_mech)))
    return a, b, c


@equation
def torque_of_power(p, w, lo, hi, m):
    """The torque T in [lo, hi] (a bracket on one side of 0) whose :func:`electric_power` at w is ``p``, where
    the power rises through ``p`` (electric_power(lo) <= p < electric_power(hi), the caller's bracket): the
    larger root of a T^2 + (w + b) T + (c - p) = 0 (:func:`loss_polynomial`; a >= 0, and with the power
    below p at lo and above it at hi the larger root is the bracket's one crossing). Closed form, without
    cancellation; NaN where rounding puts it outside the bracket (the caller then bisects)."""
    sign = 1.0 if lo + hi > 0.0 else -1.0
    a, b, c = loss_polynomial(w, sign, m)
    bb = w + b
    cc = c - p
    if a > 0.0:
        disc = bb * bb - 4.0 * a * cc
        if disc < 0.0:
            return math.nan
        sq = math.sqrt(disc)
        r = (sq - bb) / (2.0 * a) if bb <= 0.0 else -2.0 * cc / (bb + sq)
    elif bb > 0.0:
        r = -cc / bb
    else:
        return math.nan
    slack = 1e-12 * (hi - lo)
    if r < lo - slack or r > hi + slack:
        return math.nan
    return min(max(r, lo), hi)


# --- maps --------------------------------------------------------------------------------------------------


def efficiency_table(machine, speeds, torques) -> np.ndarray:
    """Efficiency on a grid, rows ``speeds`` (rad/s) x columns ``torques`` (N*m), for a :class:`MachineSpec`
    or a measured machine (:class:`vpsim.engines.machine_map.MeasuredMachine`).

    Motoring ``T w / P_elec``, generating ``P_elec / (T w)``; NaN where the mechanical power is zero (the
    efficiency is undefined) and where the point is outside the torque envelope. A generating point whose loss
    exceeds the mechanical power (the machine draws power while braking) has a negative efficiency.
    """
    w = np.asarray(speeds, dtype=float)
    t = np.asarray(torques, dtype=float)
    tt, ww = np.meshgrid(t, w)
    if isinstance(machine, MachineSpec):
        m = machine_record(machine)
        loss = loss_w(tt, ww, m)
        upper, lower = max_torque(ww, m), min_torque(ww, m)
    else:
        loss = machine.loss_w(tt, ww)
        upper, lower = machine.max_torque_at(ww), machine.min_torque_at(ww)
    p_mech = tt * ww
    with np.errstate(all="ignore"):
        eff = np.where(p_mech > 0, p_mech / (p_mech + loss), (np.abs(p_mech) - loss) / np.abs(p_mech))
    slack = 1e-9 * np.max(np.abs(t)) if t.size else 0.0
    eff[(p_mech == 0) | (tt > upper + slack) | (tt < lower - slack)] = np.nan
    return eff


def efficiency_errors_pts(measured, spec: MachineSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Efficiency of ``spec`` minus that of the measured map, in percentage points, at the map's points.

    The points are ``measured.map_points()``: every node in the torque envelope of both quadrants with
    non-zero torque and speed (docs/model.md, "Electric machine"). Returns (error_pts, torque, speed).
    """
    t, w, eff = measured.map_points()
    m = machine_record(spec)
    p_mech = np.abs(t * w)
    loss = loss_w(t, w, m)
    model = np.where(t * w > 0, p_mech / (p_mech + loss), (p_mech - loss) / p_mech)
    return 100.0 * (model - eff), t, w
