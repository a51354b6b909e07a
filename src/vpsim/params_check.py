"""Plausibility limits and checks of parameter sets: the range of every field, the limits of a whole car and
engine (:data:`DISPLACEMENT_RANGE`, :data:`MAX_FULL_LOAD_BMEP`, ...), :func:`validate`, :func:`check_field`,
:func:`engine_check_figures`, and the helpers that turn a file's value into its field's type and SI unit.

:mod:`vpsim.params` holds the dataclasses and the readers; it calls these checks and re-exports the names used
from it. The checks read the dataclasses' names from :mod:`vpsim.params` inside their functions, so either
module may be imported first.
"""

from __future__ import annotations

import functools
import json
import math
import numbers
from dataclasses import fields
from typing import TYPE_CHECKING, Any

import numpy as np

from .errors import ParameterError
from .textio import printable
from .units import FIELD_DIMENSIONS, to_si

if TYPE_CHECKING:
    from .params import Engine, Parameters

# the lightest road vehicle vpsim simulates: a 50 kg frame carries no driver, engine or battery (the lightest
# quadricycles weigh some 350 kg); below it a mass is a unit slip (tonnes for kg) or an injection (1 mg)
MIN_VEHICLE_MASS_KG = 50.0
# no engine converts more of its fuel's heat than this: the air-standard Otto cycle at a 14:1 compression
# ratio (gamma 1.35) reaches 1 - 14^-0.35 = 0.60, the best production gasoline engines about 0.45-0.50
# indicated (the fleet's search stops at 0.54, vpsim.fleet.calibrate.EFFICIENCY_AXIS)
MAX_THERMAL_EFFICIENCY = 0.6

# a coast-down road load (vehicle.road_load_a/b/c) may not push the car: A + B v + C v^2 >= 0 from rest to the
# US06's top speed (35.9 m/s, 80.3 mph), the fastest of the standard cycles
ROAD_LOAD_CHECK_SPEED = 36.0

# Plausible ranges (SI). A value outside is rejected with a hint, which catches unit-scale slips such as a
# bore given in millimetres. Bounds are (low, high, low_inclusive).
_RANGES: dict[str, tuple[float, float, bool]] = {
    "vehicle.mass": (MIN_VEHICLE_MASS_KG, 1.0e5, True),
    "vehicle.frontal_area": (0.0, 50.0, False),
    "vehicle.drag_coefficient": (0.0, 3.0, False),
    "vehicle.rolling_resistance": (0.0, 0.5, True),
    "vehicle.air_density": (0.0, 5.0, False),
    "vehicle.gravity": (0.0, 30.0, False),
    "vehicle.wheel_radius": (0.05, 2.0, False),
    "transmission.final_drive": (0.0, 50.0, False),
    "transmission.converter_capacity_factor": (0.0, 200.0, True),
    "transmission.converter_stall_torque_ratio": (1.0, 4.0, True),
    "transmission.converter_coupling_speed_ratio": (0.5, 0.99, True),
    "transmission.lockup_min_speed": (0.0, 100.0, True),
    "transmission.cvt_ratio_step": (0.0, 0.2, True),
    "transmission.shift_engine_speed": (20.0, 1000.0, True),
    "transmission.shift_point_engine_speed": (0.0, 1000.0, True),
    "transmission.shift_point_speed": (0.0, 100.0, True),
    "transmission.shift_point_speed_step": (0.0, 100.0, True),
    "engine.bore": (0.02, 0.5, False),
    "engine.stroke": (0.02, 0.5, False),
    "engine.inertia": (0.0, 50.0, False),
    "engine.intake_manifold_volume": (1e-5, 0.1, False),
    "engine.ambient_pressure": (2.0e4, 2.0e5, False),
    "engine.ambient_temperature": (150.0, 400.0, False),
    "engine.intake_temperature": (150.0, 600.0, False),
    "engine.exhaust_pressure": (2.0e4, 5.0e5, False),
    "engine.gas_constant": (100.0, 1000.0, False),
    "engine.specific_heat_ratio": (1.0, 2.0, False),
    "engine.fuel_heating_value": (1.0e6, 1.5e8, False),
    "engine.stoich_air_fuel_ratio": (1.0, 40.0, False),
    "engine.lambda": (0.5, 3.0, False),
    "engine.air_charge_slope": (0.0, 2.0, False),
    "engine.air_charge_intercept": (-1.0e5, 1.0e5, True),
    "engine.friction_coefficient": (0.0, 10.0, True),
    "engine.boost_layout": (0.0, 10.0, False),
    "engine.max_throttle_area": (0.0, 0.1, False),
    "engine.min_throttle_area": (0.0, 0.1, True),
    "simulation.idle_fuel_flow": (0.0, 0.1, True),
    "simulation.fuel_density": (0.3, 2.0, False),
    "simulation.ode_relative_tolerance": (1e-10, 0.5, True),
    "simulation.inverse_max_step": (1e-3, 100.0, True),
    "simulation.fuel_cutoff_speed": (0.0, 2000.0, True),
    "vehicle.road_load_a": (0.0, 1.0e4, True),
    "vehicle.road_load_b": (-1.0e3, 1.0e3, True),
    "vehicle.road_load_c": (0.0, 100.0, True),
    "engine.accessory_power": (0.0, 1.0e5, True),
    "engine.boost_pressure": (0.0, 4.0e5, True),
    "engine.rated_power": (0.0, 2.0e6, True),
    "engine.boost_enrichment": (0.0, 0.5, True),  # lambda down to 0.67 at full boost
    "battery.soc_initial": (0.0, 1.0, True),
    "battery.soc_min": (0.0, 1.0, True),
    "battery.soc_max": (0.0, 1.0, True),
    "machine.rated_power": (100.0, 2.0e6, True),  # W: lower bounds keep T_r = P_r / w_b finite
    "machine.base_speed": (1.0, 5000.0, True),  # rad/s: about 10 rpm up
    "machine.max_speed": (1.0, 5000.0, True),
    "machine.inertia": (0.0, 10.0, True),
    "machine.loss_scale": (0.0, 10.0, False),
    "electric.accessory_power": (0.0, 1.0e5, True),
    "electric.charger_efficiency": (0.1, 1.0, True),  # real chargers 0.8 to 0.95
    "electric.regen_share": (0.0, 1.0, True),
    "electric.regen_speed_low": (0.0, 50.0, True),
    "electric.regen_speed_high": (0.0, 50.0, True),
    "electric.forward_kp": (0.0, 100.0, False),
    "electric.forward_ki": (0.0, 100.0, False),
    "electric.forward_max_step": (1e-3, 1.0, False),
    "hybrid.soc_target": (0.0, 1.0, False),
    "hybrid.engine_on_power": (0.0, 1.0e6, True),
    "hybrid.engine_off_power": (0.0, 1.0e6, True),
    "hybrid.soc_low": (0.0, 1.0, True),
    "hybrid.soc_hysteresis": (0.0, 0.5, True),
    "hybrid.charge_power": (0.0, 1.0e6, True),
    "hybrid.min_on_time": (0.0, 600.0, True),
    "hybrid.ecms_factor": (0.0, 20.0, True),
    "hybrid.ecms_gain": (0.0, 1000.0, True),
    "hybrid.ecms_min_on_time": (0.0, 600.0, True),
    "hybrid.engine_start_fuel": (0.0, 0.1, True),
    "hybrid.dp_soc_span": (0.01, 1.0, True),
    "split.mg2_ratio": (0.1, 20.0, True),
    "split.engine_max_speed": (100.0, 2000.0, True),
    "split.generator_rated_power": (100.0, 1.0e6, True),
    "split.generator_base_speed": (1.0, 5000.0, True),
    "split.generator_max_speed": (1.0, 5000.0, True),
    "split.generator_inertia": (0.0, 10.0, True),
    "mild.belt_ratio": (0.2, 10.0, True),  # 1: on the crank; belt starter-generators 2.5-3
    "mild.assist_share": (0.0, 1.0, True),
}
# Whole numbers: (low, high). Production piston engines have 1 to 16 cylinders and are two-stroke (1
# revolution per cycle) or four-stroke (2); Newton converges in a handful of iterations or not at all.
_INT_RANGES: dict[str, tuple[int, int]] = {
    "engine.cylinders": (1, 16),
    "engine.revolutions_per_cycle": (1, 2),
    "transmission.lockup_min_gear": (1, 21),  # above the number of gears: never locked
    "battery.cells_in_series": (1, 2000),
    "battery.cells_in_parallel": (1, 2000),
    "hybrid.torque_levels": (2, 200),
    "hybrid.dp_soc_points": (11, 2001),
    "split.sun_teeth": (8, 500),
    "split.ring_teeth": (8, 1000),
}
_MAX_LIST = 20  # gears of a gearbox (heavy trucks have up to 18)
_LIST_LENGTHS = {"engine.map_speed_range": 2}
# Derived engine limits (SI), from real engines; together they bound the generated map's grid (its torque
# span is (peak BMEP - motoring BMEP) x V_d / (2 pi n_r)), so memory and time cannot grow with a typo.
DISPLACEMENT_RANGE = (0.04e-3, 16.0e-3)  # m^3: a 40 cc moped engine to a 16 L truck engine
MAX_FULL_LOAD_BMEP = 40.0e5  # Pa: production SI engines reach about 25-30 bar (turbocharged)
MIN_MOTORING_BMEP = -60.0e5  # Pa: friction + pumping at the top of the map, real engines -2 to -6 bar
IDLE_CHECK_SPEED = 80.0  # rad/s: the idle speed of the methods (vpsim.model.record.IDLE_SPEED)
_EFFICIENCIES = ("transmission.efficiency", "engine.thermal_efficiency", "mild.belt_efficiency")


def _fmt_range(key: str) -> str:
    lo, hi, inc = _RANGES[key]
    return f"{'[' if inc else '('}{lo:g}, {hi:g}]"


def _coerce(sec: str, name: str, value: Any, where: str, unit: Any = None) -> Any:
    """Turn a TOML value into the field's Python type (in SI, converting ``unit``), with a clear error."""
    from .params import _ATTR_ALIASES, _FIELD_NAMES, _SECTIONS

    key = f"{sec}.{_FIELD_NAMES.get(name, name)}"
    typ = {f.name: f.type for f in fields(_SECTIONS[sec])}[_ATTR_ALIASES.get(name, name)]
    out = _typed(typ, value)
    if out is not None and key in _LIST_LENGTHS and len(out) != _LIST_LENGTHS[key]:
        out = None
    if out is None:
        raise ParameterError(f"{where}: {key} = {_short(value)} is not a {_describe(typ, key)}")
    if unit is not None:
        out = _convert(key, out, unit, where)
    return out


def _is_number(v: Any) -> bool:
    """A real number (Python or NumPy), not a boolean."""
    return isinstance(v, numbers.Real) and not isinstance(v, bool | np.bool_)


def _typed(typ: str, value: Any) -> Any:
    """``value`` as the field type ``typ`` ("int", "float", "tuple[...]"), or None if it is not one."""
    if typ == "int":
        if not _is_number(value):
            return None
        if isinstance(value, numbers.Integral):
            return int(value)
        f = float(value)
        return int(f) if f.is_integer() else None
    if typ == "str":
        return value if isinstance(value, str) else None
    if typ == "bool":
        return value if isinstance(value, bool) else None
    if typ == "float":
        if not _is_number(value):
            return None
        try:
            return float(value)
        except OverflowError:  # an integer beyond the float range: reported by the range check
            return math.inf if value > 0 else -math.inf
    if typ.startswith("tuple"):
        if isinstance(value, np.ndarray) and value.ndim == 1:
            value = value.tolist()
        if not isinstance(value, list | tuple) or not value or not all(_is_number(v) for v in value):
            return None
        if len(value) > _MAX_LIST:
            return None
        out = []
        for v in value:
            try:
                out.append(float(v))
            except OverflowError:
                out.append(math.inf if v > 0 else -math.inf)
        return tuple(out)
    return None


def _convert(key: str, value: Any, unit: Any, where: str) -> Any:
    """``value`` given in ``unit`` converted to the SI unit of field ``key``."""
    dim = FIELD_DIMENSIONS.get(key if not key.startswith("drivers.") else "drivers." + key.rsplit(".", 1)[1])
    if not isinstance(unit, str):
        raise ParameterError(f'{where}: {key}: unit = {_short(unit)} must be a text such as "kg"')
    if dim is None:
        raise ParameterError(f"{where}: {key}: this field takes no unit")
    try:
        if isinstance(value, tuple):
            return tuple(to_si(v, unit, dim) for v in value)
        if isinstance(value, int) and not isinstance(value, bool):
            if to_si(1.0, unit, dim) != 1.0:  # counts take only dimensionless units
                raise ValueError(f"unit {unit!r} cannot scale a whole number")
            return value
        return to_si(value, unit, dim)
    except ValueError as exc:
        raise ParameterError(f"{where}: {key}: {exc}") from None


def _short(value: Any, limit: int = 60) -> str:
    """A value's repr for a one-line message, cut to ``limit`` characters."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _describe(typ: str, key: str = "") -> str:
    if key in _LIST_LENGTHS:
        n = _LIST_LENGTHS[key]
        return f"list of {n} numbers ([low, high])" if n == 2 else f"list of {n} numbers"
    if typ.startswith("tuple"):
        return f"non-empty list of at most {_MAX_LIST} numbers (true/false and text are not numbers)"
    names = {"int": "whole number", "float": "number", "str": "text", "bool": "true or false"}
    return names.get(typ, "number")


def check_field(key: str, value: Any, where: str) -> float:
    """One number for field ``key`` (``"engine.thermal_efficiency"``) read from outside a parameter file (a
    fleet's technology.json), as a float; :class:`ParameterError` (one line) if it is not a number (true and
    false are not numbers), not finite, or outside the field's range (as :func:`validate` checks it)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        try:  # as the file wrote it (true, null, "0.4"), not Python's True/None
            shown = printable(json.dumps(value))
        except (TypeError, ValueError):
            shown = _short(value)
        shown = shown if len(shown) <= 40 else shown[:37] + "..."
        raise ParameterError(f"{where}: {key} = {shown} is not a number")
    v = float(value)
    if not math.isfinite(v):
        raise ParameterError(f"{where}: {key} = {v} is not a finite number")
    if key in _EFFICIENCIES and not 0.0 < v < 1.0:
        raise ParameterError(f"{where}: {key} = {v:g} is outside (0, 1); an efficiency is a fraction below 1")
    if key == "engine.thermal_efficiency" and not v < MAX_THERMAL_EFFICIENCY:
        raise ParameterError(
            f"{where}: {key} = {v:g} is not below {MAX_THERMAL_EFFICIENCY:g}, the ideal Otto cycle's at 14:1 "
            "compression"
        )
    if key in _RANGES:
        lo, hi, inc = _RANGES[key]
        if not ((v >= lo if inc else v > lo) and v <= hi):
            raise ParameterError(f"{where}: {key} = {v:g} is outside the plausible range {_fmt_range(key)}")
    return v


def validate(p: Parameters, where: str = "parameters") -> None:
    """Check that every value is physical and plausibly in SI units; raise :class:`ParameterError` if not."""
    from .params import MAX_CVT_STEPS

    flat = p.flat()
    for key, value in flat.items():
        vals = value if isinstance(value, tuple) else (value,)
        for v in vals:
            if isinstance(v, float) and not math.isfinite(v):
                raise ParameterError(f"{where}: {key} = {v} is not a finite number")
    for key in _EFFICIENCIES:
        v = flat[key]
        if not 0.0 < v <= 1.0:
            raise ParameterError(f"{where}: {key} = {v:g} is outside (0, 1]; an efficiency is a fraction")
    if not p.engine.thermal_efficiency < MAX_THERMAL_EFFICIENCY:
        raise ParameterError(
            f"{where}: engine.thermal_efficiency = {p.engine.thermal_efficiency:g} is not below "
            f"{MAX_THERMAL_EFFICIENCY:g}, the ideal Otto cycle's at 14:1 compression; real engines reach "
            "0.45-0.50"
        )
    for key, (lo, hi) in _INT_RANGES.items():
        v = flat[key]
        if isinstance(v, bool) or not isinstance(v, int):
            raise ParameterError(f"{where}: {key} = {_short(v)} is not a whole number")
        if v < 1:
            raise ParameterError(f"{where}: {key} = {v} must be a positive whole number")
        if not lo <= v <= hi:
            raise ParameterError(f"{where}: {key} = {_short(v)} is outside the plausible range [{lo}, {hi}]")
    for key, (lo, hi, inc) in _RANGES.items():
        v = flat[key]
        ok = (v >= lo if inc else v > lo) and v <= hi
        if not ok:
            hint = ""
            if key in ("engine.bore", "engine.stroke") and v > 10:
                hint = f" (values are in metres: did you mean {v / 1000:g}?)"
            elif key == "engine.intake_manifold_volume" and v > 0.1:
                hint = f" (values are in m^3: did you mean {v / 1000:g}?)"
            elif v <= 0.0 <= lo:
                hint = " (it must be positive)"
            elif key == "vehicle.mass" and v < lo:
                hint = f" (in kg; {MIN_VEHICLE_MASS_KG:g} kg is the lightest vehicle vpsim simulates)"
            raise ParameterError(
                f"{where}: {key} = {v:g} is outside the plausible range {_fmt_range(key)}{hint}"
            )
    veh = p.vehicle
    a, b, c = veh.road_load_a, veh.road_load_b, veh.road_load_c
    if a != 0.0 or b != 0.0 or c != 0.0:  # a coast-down road load F = A + B v + C v^2 replaces the physics
        top = ROAD_LOAD_CHECK_SPEED
        speeds = [0.0, top] + ([-b / (2.0 * c)] if c > 0.0 and 0.0 < -b / (2.0 * c) < top else [])
        v = min(speeds, key=lambda x: a + b * x + c * x * x)  # where the parabola is lowest on [0, top]
        f = a + b * v + c * v * v
        if f < 0.0:
            raise ParameterError(
                f"{where}: vehicle.road_load_a/b/c = {a:g}, {b:g}, {c:g} give a road load of {f:.4g} N at "
                f"{v:.4g} m/s; expected A + B v + C v^2 >= 0 from 0 to {top:g} m/s (the US06's top speed)"
            )
    cut = p.simulation.fuel_cutoff_speed
    if 0.0 < cut < IDLE_CHECK_SPEED:
        raise ParameterError(
            f"{where}: simulation.fuel_cutoff_speed = {cut:g} rad/s is below the idle speed "
            f"{IDLE_CHECK_SPEED:g} rad/s ({IDLE_CHECK_SPEED * 30 / math.pi:.0f} rpm): a cut-off must lie "
            "above idle (0 disables it)"
        )
    if len(p.transmission.gearbox_ratios) > _MAX_LIST:
        raise ParameterError(
            f"{where}: transmission.gearbox_ratios has {len(p.transmission.gearbox_ratios)} gears, "
            f"more than {_MAX_LIST}"
        )
    for i, g in enumerate(p.transmission.gearbox_ratios, 1):
        if not 0.0 < g <= 20.0:
            raise ParameterError(f"{where}: transmission.gearbox_ratios[{i}] = {g:g} is outside (0, 20]")
    tr = p.transmission
    ratios = tr.gearbox_ratios
    if not tr.is_cvt:  # a stepped gearbox: first gear the largest ratio (a single reduction is one ratio)
        for i in range(1, len(ratios)):
            if not ratios[i] < ratios[i - 1]:
                raise ParameterError(
                    f"{where}: transmission.gearbox_ratios[{i + 1}] = {ratios[i]:g} is not below gear "
                    f"{i}'s {ratios[i - 1]:g}; a stepped gearbox lists its ratios from first gear down "
                    f"(descending), got {list(ratios)}"
                )
    if tr.is_cvt and tr.shift_point_speed > 0.0:
        raise ParameterError(
            f"{where}: transmission.shift_point_speed = {tr.shift_point_speed:g} m/s is a stepped gearbox's "
            "table of upshift speeds; a CVT (cvt_ratio_step set) chooses its ratio: set it to 0"
        )
    if tr.is_cvt:
        r = tr.gearbox_ratios
        if len(r) != 2 or not r[0] > r[1]:
            raise ParameterError(
                f"{where}: with transmission.cvt_ratio_step set (a CVT), transmission.gearbox_ratios must be "
                f"its range [launch, overdrive], launch > overdrive; got {list(r)}"
            )
        if tr.cvt_ratio_step < 0.005:
            raise ParameterError(
                f"{where}: transmission.cvt_ratio_step = {tr.cvt_ratio_step:g} is below 0.005 (0.5 % between "
                "neighbouring ratios); 0 for a stepped gearbox"
            )
        if math.log(r[0] / r[1]) / math.log1p(tr.cvt_ratio_step) + 1 > MAX_CVT_STEPS:
            raise ParameterError(
                f"{where}: a CVT range {r[0]:g} / {r[1]:g} at steps of {tr.cvt_ratio_step:g} needs more than "
                f"{MAX_CVT_STEPS} ratios; take a larger cvt_ratio_step"
            )
    if len(p.engine.map_speed_range) != 2:
        raise ParameterError(
            f"{where}: engine.map_speed_range has {len(p.engine.map_speed_range)} values, "
            "expected [low, high]"
        )
    lo, hi = p.engine.map_speed_range
    if not 0.0 < lo < hi <= 2000.0:
        raise ParameterError(
            f"{where}: engine.map_speed_range = [{lo:g}, {hi:g}] must be increasing positive rad/s below 2000"
        )
    if p.engine.min_throttle_area >= p.engine.max_throttle_area:
        raise ParameterError(
            f"{where}: engine.min_throttle_area must be smaller than engine.max_throttle_area"
        )
    _check_engine(p.engine, where)
    _check_electric(p, where)
    for k, d in p.drivers.items():
        for f in fields(d):
            v = getattr(d, f.name)
            if not (math.isfinite(v) and v > 0):
                raise ParameterError(f"{where}: drivers.{k}.{f.name} = {v!r} must be a positive number")


def _check_electric(p: Parameters, where: str) -> None:
    """The electric sections as a whole: a known powertrain and machine kind, a cell that exists, an SOC
    window that holds the start, a base speed below the top speed."""
    from .params import EMS, HYBRIDS, MACHINE_KINDS, POWERTRAINS

    if p.powertrain.type not in POWERTRAINS:
        raise ParameterError(
            f"{where}: powertrain.type = {p.powertrain.type!r}; expected one of {', '.join(POWERTRAINS)}"
        )
    if p.machine.kind not in MACHINE_KINDS:
        raise ParameterError(
            f"{where}: machine.kind = {p.machine.kind!r}; expected one of {', '.join(MACHINE_KINDS)}"
        )
    b = p.battery
    if not b.soc_min < b.soc_max:
        raise ParameterError(
            f"{where}: battery.soc_min = {b.soc_min:g} must be below battery.soc_max = {b.soc_max:g}"
        )
    if not b.soc_min <= b.soc_initial <= b.soc_max:
        raise ParameterError(
            f"{where}: battery.soc_initial = {b.soc_initial:g} is outside the window "
            f"[soc_min, soc_max] = [{b.soc_min:g}, {b.soc_max:g}]"
        )
    m = p.machine
    if not m.base_speed < m.max_speed:
        raise ParameterError(
            f"{where}: machine.base_speed = {m.base_speed:g} rad/s must be below machine.max_speed = "
            f"{m.max_speed:g}"
        )
    e = p.electric
    if e.regen_speed_high < e.regen_speed_low:
        raise ParameterError(
            f"{where}: electric.regen_speed_high = {e.regen_speed_high:g} m/s is below regen_speed_low = "
            f"{e.regen_speed_low:g}"
        )
    if p.hybrid.ems not in EMS:
        raise ParameterError(f"{where}: hybrid.ems = {p.hybrid.ems!r}; expected one of {', '.join(EMS)}")
    h = p.hybrid
    if h.engine_off_power > h.engine_on_power:  # the rule's hysteresis in power
        raise ParameterError(
            f"{where}: hybrid.engine_off_power = {h.engine_off_power:g} W is above engine_on_power = "
            f"{h.engine_on_power:g} W; the rule stops the engine below the first and starts it above the "
            "second, so the first must not exceed the second"
        )
    if p.powertrain.type in HYBRIDS and not b.soc_min < p.hybrid.soc_target < b.soc_max:
        raise ParameterError(
            f"{where}: hybrid.soc_target = {p.hybrid.soc_target:g} is outside the battery's window "
            f"({b.soc_min:g}, {b.soc_max:g})"
        )
    if p.powertrain.type in ("bev", *HYBRIDS):
        from .model.battery import CELLS

        if b.cell not in CELLS and not b.cell.lower().endswith(".m"):
            raise ParameterError(
                f"{where}: battery.cell = {b.cell!r}; expected one of {', '.join(CELLS)} or an ADVISOR "
                "ESS_*.m file"
            )
    if p.powertrain.type == "hev_split":
        _check_split(p, where)
    if p.powertrain.type == "bev":
        if len(p.transmission.gearbox_ratios) != 1 or p.transmission.is_cvt:
            raise ParameterError(
                f"{where}: a battery-electric car has a single reduction: transmission.gearbox_ratios must "
                "hold "
                f"one ratio, got {len(p.transmission.gearbox_ratios)}"
            )


def _check_split(p: Parameters, where: str) -> None:
    """A power-split gear set that can turn: a ring larger than the sun by an even number of teeth (the
    pinions between them have (Z_r - Z_s) / 2 teeth), one ratio from the ring to the wheels, a generator whose
    base speed is below its top speed, and an engine that reaches its idle speed."""
    sp = p.split
    if not sp.ring_teeth > sp.sun_teeth:
        raise ParameterError(
            f"{where}: split.ring_teeth = {sp.ring_teeth} must exceed split.sun_teeth = {sp.sun_teeth}: with "
            "the ring no larger than the sun there is no room for the pinions, and the gear set locks"
        )
    if (sp.ring_teeth - sp.sun_teeth) % 2:
        raise ParameterError(
            f"{where}: split.ring_teeth - split.sun_teeth = {sp.ring_teeth - sp.sun_teeth} must be even (the "
            "pinions between sun and ring have half the difference in teeth)"
        )
    if not sp.generator_base_speed < sp.generator_max_speed:
        raise ParameterError(
            f"{where}: split.generator_base_speed = {sp.generator_base_speed:g} rad/s must be below "
            f"split.generator_max_speed = {sp.generator_max_speed:g}"
        )
    if not sp.engine_max_speed > IDLE_CHECK_SPEED:
        raise ParameterError(
            f"{where}: split.engine_max_speed = {sp.engine_max_speed:g} rad/s must exceed the idle speed "
            f"{IDLE_CHECK_SPEED:g} rad/s"
        )
    if len(p.transmission.gearbox_ratios) != 1 or p.transmission.is_cvt:
        raise ParameterError(
            f"{where}: a power-split hybrid drives the wheels from the ring through one reduction: "
            f"transmission.gearbox_ratios must hold one ratio, got {len(p.transmission.gearbox_ratios)}"
        )


def engine_check_figures(c) -> dict:
    """The whole-engine figures :func:`_check_engine` tests, for an engine record or an array of records
    (vpsim.batch checks every design variant at once): displacement, full-load BMEP at ambient pressure,
    motoring BMEP at 1.25 x the map's top speed, the intake pressure of zero torque at idle and the throttle
    area that holds it, and whether each is plausible (``ok``)."""
    from .model import engine as en

    w_top = 1.25 * c.map_speed_high
    with np.errstate(all="ignore"):
        peak = en.bmep_from_pressure(c.ambient_pressure, 0.0, c)
        motoring = en.bmep_from_pressure(0.0, w_top, c)
        p_idle = en.intake_pressure_for_torque(0.0, IDLE_CHECK_SPEED, c)
        flow = en.cylinder_air_flow(p_idle, IDLE_CHECK_SPEED, c)
        pressure_ok = np.isfinite(p_idle) & (0.0 < p_idle) & (p_idle < c.ambient_pressure)
        p_area = np.where(pressure_ok, p_idle, 0.5 * c.ambient_pressure)
        if np.ndim(p_area) == 0:  # one engine: plain Python, no compiled loop to load when parameters load
            area = en.throttle_for_flow(float(p_area), float(flow), c)
        else:
            area = en.throttle_for_flow_array(p_area, flow, c)
    lo, hi = DISPLACEMENT_RANGE
    f = {
        "displacement": c.displacement,
        "w_top": w_top,
        "peak": peak,
        "motoring": motoring,
        "p_idle": p_idle,
        "idle_area": area,
        "displacement_ok": (lo <= c.displacement) & (c.displacement <= hi),
        "peak_ok": np.isfinite(peak) & (peak <= MAX_FULL_LOAD_BMEP),
        "motoring_ok": np.isfinite(motoring) & (motoring >= MIN_MOTORING_BMEP),
        "idle_ok": pressure_ok & np.isfinite(area) & (0.0 < area) & (area <= c.max_throttle_area),
    }
    f["ok"] = f["displacement_ok"] & f["peak_ok"] & f["motoring_ok"] & f["idle_ok"]
    return f


@functools.lru_cache(maxsize=256)
def _engine_figures(eng: Engine) -> dict:
    """:func:`engine_check_figures` of one engine, once per (immutable) engine: a parameter set is checked
    whenever it is made (``with_changes``), and a grid of technologies makes hundreds that share an engine.
    On the engine's :func:`vpsim.model.record.engine_fields` (the record's values, read as plain
    attributes), so the same figures as on its record."""
    from .model.record import engine_fields

    return engine_check_figures(engine_fields(eng))


def _check_engine(eng: Engine, where: str) -> None:
    """The engine as a whole: displacement, peak and motoring BMEP, and that it can idle (module limits)."""
    f = _engine_figures(eng)
    if not f["displacement_ok"]:
        lo, hi = DISPLACEMENT_RANGE
        raise ParameterError(
            f"{where}: displacement {eng.displacement * 1e3:.4g} L (engine.cylinders {eng.cylinders} x pi/4 "
            f"x engine.bore {eng.bore:g}^2 x engine.stroke {eng.stroke:g} m) is outside the plausible range "
            f"[{lo * 1e3:g}, {hi * 1e3:g}] L"
        )
    if not f["peak_ok"]:
        raise ParameterError(
            f"{where}: the engine's full-load BMEP would be {float(f['peak']) / 1e5:.4g} bar at ambient "
            f"pressure, more than the {MAX_FULL_LOAD_BMEP / 1e5:g} bar of any production engine; check "
            "engine.fuel_heating_value, thermal_efficiency, stoich_air_fuel_ratio, lambda, air_charge_slope"
        )
    if not f["motoring_ok"]:
        raise ParameterError(
            f"{where}: the engine's motoring BMEP would be {float(f['motoring']) / 1e5:.4g} bar at "
            f"{float(f['w_top']):g} rad/s (friction and pumping), below {MIN_MOTORING_BMEP / 1e5:g} bar; "
            f"check engine.friction_coefficient {eng.friction_coefficient:g}, boost_layout "
            f"{eng.boost_layout:g}, stroke {eng.stroke:g} m and map_speed_range"
        )
    if not f["idle_ok"]:
        raise ParameterError(
            f"{where}: the engine cannot idle: zero torque at {IDLE_CHECK_SPEED:g} rad/s needs an intake "
            f"pressure of {float(f['p_idle']):.4g} Pa with ambient {eng.ambient_pressure:.4g} Pa "
            f"(engine.air_charge_slope {eng.air_charge_slope:g}, air_charge_intercept "
            f"{eng.air_charge_intercept:g} Pa, exhaust_pressure {eng.exhaust_pressure:.4g} Pa), which the "
            "throttle cannot hold between 0 and the ambient pressure"
        )
