"""Parameter sets: vehicle, transmission, engine, simulation settings and drivers.

A parameter set is plain, immutable data in SI units. Named presets (``hofman2011``) ship with the package
and carry each value's provenance (paper / derived / reconstructed). Users bring their own vehicles and
engines as TOML files with the same fields; a file may start from a preset (``base = "hofman2011"``, the
default) and override only what differs.

    >>> from vpsim.params import load_parameters
    >>> p = load_parameters("hofman2011")
    >>> round(p.engine.displacement * 1e3, 2)   # litres
    2.29
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any

from .errors import ParameterError

PRESETS = ("hofman2011", "geo_metro_1l", "saturn_1_9l")


@dataclass(frozen=True)
class Vehicle:
    mass: float  # kg
    frontal_area: float  # m^2
    drag_coefficient: float
    rolling_resistance: float
    air_density: float  # kg/m^3
    gravity: float  # m/s^2
    wheel_radius: float  # m
    # coast-down road load F = A + B v + C v^2 (certification data); when any is set it replaces
    # m g c_r and 1/2 rho c_d A_f (docs/model.md)
    road_load_a: float = 0.0  # N
    road_load_b: float = 0.0  # N per m/s
    road_load_c: float = 0.0  # N per (m/s)^2


@dataclass(frozen=True)
class Transmission:
    efficiency: float
    gearbox_ratios: tuple[float, ...]
    final_drive: float

    @property
    def ratios(self) -> tuple[float, ...]:
        """Total ratios i = gearbox x final drive, one per gear (gear 1 first)."""
        return tuple(g * self.final_drive for g in self.gearbox_ratios)

    @property
    def n_gears(self) -> int:
        return len(self.gearbox_ratios)


@dataclass(frozen=True)
class Engine:
    bore: float  # m
    stroke: float  # m
    cylinders: int
    inertia: float  # kg m^2
    revolutions_per_cycle: int
    intake_manifold_volume: float  # m^3
    ambient_pressure: float  # Pa
    ambient_temperature: float  # K
    intake_temperature: float  # K
    exhaust_pressure: float  # Pa
    gas_constant: float  # J/(kg K)
    specific_heat_ratio: float
    fuel_heating_value: float  # J/kg
    thermal_efficiency: float
    stoich_air_fuel_ratio: float
    lambda_: float
    air_charge_slope: float
    air_charge_intercept: float  # Pa
    friction_coefficient: float
    boost_layout: float
    max_throttle_area: float  # m^2
    min_throttle_area: float  # m^2
    map_speed_range: tuple[float, float]  # rad/s
    accessory_power: float = 0.0  # W, mechanical load of the accessories (alternator, pumps) while running

    @property
    def displacement(self) -> float:
        """Swept volume V_d (m^3), :func:`vpsim.model.engine.displacement`."""
        from .model.engine import displacement

        return displacement(self)


@dataclass(frozen=True)
class Simulation:
    idle_fuel_flow: float  # kg/s
    fuel_density: float  # kg/L
    ode_relative_tolerance: float
    inverse_max_step: float  # s
    fuel_cutoff_speed: float = 0.0  # rad/s; realistic mode: fuel cut in overrun above this speed (0: never)


@dataclass(frozen=True)
class Driver:
    """Driver tuning: the forward PI gains and the inverse method's smoothing half-width."""

    forward_kp: float  # m^2 per m/s
    forward_ki: float  # m^2 per m
    inverse_a: float  # s


@dataclass(frozen=True)
class Parameters:
    """A complete parameter set. ``provenance`` maps ``"section.field"`` to its confidence label/note."""

    name: str
    vehicle: Vehicle
    transmission: Transmission
    engine: Engine
    simulation: Simulation
    drivers: dict[str, Driver]
    provenance: dict[str, str] = field(default_factory=dict, compare=False, repr=False)
    citation: str = field(default="", compare=False, repr=False)

    def driver(self, key: int | str) -> Driver:
        k = str(key)
        if k not in self.drivers:
            raise ParameterError(
                f"driver {key!r} is not defined; available: {', '.join(sorted(self.drivers))}"
            )
        return self.drivers[k]

    def with_changes(self, **sections: dict[str, Any]) -> Parameters:
        """A copy with some fields changed, validated: ``p.with_changes(vehicle={"mass": 1200.0})``."""
        new = self
        for sec, changes in sections.items():
            if sec not in _SECTIONS:
                raise ParameterError(f"unknown section {sec!r}; expected one of {', '.join(_SECTIONS)}")
            obj = getattr(new, sec)
            names = {f.name for f in fields(obj)}
            kw = {}
            for k, v in changes.items():
                attr = _ATTR_ALIASES.get(k, k)
                if attr not in names:
                    raise ParameterError(f"unknown field {sec}.{k}")
                kw[attr] = _coerce(sec, k, v, "with_changes")
            new = replace(new, **{sec: replace(obj, **kw)})
        validate(new)
        return new

    def flat(self) -> dict[str, Any]:
        """All values as a flat ``{"section.field": value}`` dict (drivers included)."""
        out: dict[str, Any] = {}
        for sec in _SECTIONS:
            obj = getattr(self, sec)
            for f in fields(obj):
                out[f"{sec}.{_FIELD_NAMES.get(f.name, f.name)}"] = getattr(obj, f.name)
        for k, d in self.drivers.items():
            for f in fields(d):
                out[f"drivers.{k}.{f.name}"] = getattr(d, f.name)
        return out


_SECTIONS = {"vehicle": Vehicle, "transmission": Transmission, "engine": Engine, "simulation": Simulation}
_ATTR_ALIASES = {"lambda": "lambda_"}  # TOML name -> attribute
_FIELD_NAMES = {v: k for k, v in _ATTR_ALIASES.items()}

# Plausible ranges (SI). A value outside is rejected with a hint, which catches unit-scale slips such as a
# bore given in millimetres. Bounds are (low, high, low_inclusive).
_RANGES: dict[str, tuple[float, float, bool]] = {
    "vehicle.mass": (0.0, 1.0e5, False),
    "vehicle.frontal_area": (0.0, 50.0, False),
    "vehicle.drag_coefficient": (0.0, 3.0, False),
    "vehicle.rolling_resistance": (0.0, 0.5, True),
    "vehicle.air_density": (0.0, 5.0, False),
    "vehicle.gravity": (0.0, 30.0, False),
    "vehicle.wheel_radius": (0.05, 2.0, False),
    "transmission.final_drive": (0.0, 50.0, False),
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
    "simulation.ode_relative_tolerance": (0.0, 0.5, False),
    "simulation.inverse_max_step": (0.0, 100.0, False),
    "simulation.fuel_cutoff_speed": (0.0, 2000.0, True),
    "vehicle.road_load_a": (0.0, 1.0e4, True),
    "vehicle.road_load_b": (-1.0e3, 1.0e3, True),
    "vehicle.road_load_c": (0.0, 100.0, True),
    "engine.accessory_power": (0.0, 1.0e5, True),
}
_EFFICIENCIES = ("transmission.efficiency", "engine.thermal_efficiency")
_POSITIVE_INTS = ("engine.cylinders", "engine.revolutions_per_cycle")
# fields of earlier versions that no longer exist: read and ignored, with the reason
_RETIRED = {
    "simulation.newton_max_iterations": "the FQM's Newton solve always converges to 1e-12 (at most 30 iterations)",
    "simulation.newton_relative_tolerance": "the FQM's Newton solve always converges to 1e-12 (at most 30 iterations)",
}


def _fmt_range(key: str) -> str:
    lo, hi, inc = _RANGES[key]
    return f"{'[' if inc else '('}{lo:g}, {hi:g}]"


def _coerce(sec: str, name: str, value: Any, where: str) -> Any:
    """Turn a TOML value into the field's Python type, with a clear error."""
    key = f"{sec}.{name}"
    typ = {f.name: f.type for f in fields(_SECTIONS[sec])}[_ATTR_ALIASES.get(name, name)]
    try:
        if typ == "int":
            if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
                raise TypeError
            return int(value)
        if typ == "float":
            if isinstance(value, bool):
                raise TypeError
            return float(value)
        if typ.startswith("tuple"):
            if not isinstance(value, list | tuple) or not value:
                raise TypeError
            return tuple(float(v) for v in value if not isinstance(v, bool))
    except (TypeError, ValueError):
        pass
    else:
        return value
    raise ParameterError(f"{where}: {key} = {value!r} is not a {_describe(typ)}")


def _describe(typ: str) -> str:
    return {"int": "whole number", "float": "number"}.get(typ, "non-empty list of numbers")


def validate(p: Parameters, where: str = "parameters") -> None:
    """Check that every value is physical and plausibly in SI units; raise :class:`ParameterError` if not."""
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
    for key in _POSITIVE_INTS:
        v = flat[key]
        if v < 1:
            raise ParameterError(f"{where}: {key} = {v} must be a positive whole number")
    for key, (lo, hi, inc) in _RANGES.items():
        v = flat[key]
        ok = (v >= lo if inc else v > lo) and v <= hi
        if not ok:
            hint = ""
            if key in ("engine.bore", "engine.stroke") and v > 10:
                hint = f" (values are in metres: did you mean {v / 1000:g}?)"
            elif key == "engine.intake_manifold_volume" and v > 0.1:
                hint = f" (values are in m^3: did you mean {v / 1000:g}?)"
            elif v <= lo and lo == 0.0:
                hint = " (it must be positive)"
            raise ParameterError(
                f"{where}: {key} = {v:g} is outside the plausible range {_fmt_range(key)}{hint}"
            )
    for i, g in enumerate(p.transmission.gearbox_ratios, 1):
        if not 0.0 < g <= 20.0:
            raise ParameterError(f"{where}: transmission.gearbox_ratios[{i}] = {g:g} is outside (0, 20]")
    lo, hi = p.engine.map_speed_range
    if not 0.0 < lo < hi <= 2000.0:
        raise ParameterError(
            f"{where}: engine.map_speed_range = [{lo:g}, {hi:g}] must be increasing positive rad/s below 2000"
        )
    if p.engine.min_throttle_area >= p.engine.max_throttle_area:
        raise ParameterError(
            f"{where}: engine.min_throttle_area must be smaller than engine.max_throttle_area"
        )
    for k, d in p.drivers.items():
        for f in fields(d):
            v = getattr(d, f.name)
            if not (math.isfinite(v) and v > 0):
                raise ParameterError(f"{where}: drivers.{k}.{f.name} = {v!r} must be a positive number")


def _raw_value(entry: Any) -> tuple[Any, str]:
    if isinstance(entry, dict):
        if "value" not in entry:
            raise KeyError("value")
        note = entry.get("confidence", "user")
        if "note" in entry:
            note += f" ({entry['note']})"
        return entry["value"], note
    return entry, "user"


def _from_mapping(data: dict[str, Any], where: str, base: Parameters | None) -> Parameters:
    known_top = set(_SECTIONS) | {"drivers", "base", "name", "citation"}
    for key in data:
        if key not in known_top:
            raise ParameterError(
                f"{where}: unknown section {key!r}; expected one of {', '.join(sorted(known_top))}"
            )
    provenance = dict(base.provenance) if base else {}
    sections: dict[str, Any] = {}
    for sec, cls in _SECTIONS.items():
        given = data.get(sec, {})
        if not isinstance(given, dict):
            raise ParameterError(f"{where}: [{sec}] must be a table")
        attrs = {f.name for f in fields(cls)}
        kw: dict[str, Any] = {}
        for name, entry in given.items():
            if f"{sec}.{name}" in _RETIRED:
                import warnings

                warnings.warn(f"{where}: {sec}.{name} is ignored: {_RETIRED[f'{sec}.{name}']}", stacklevel=2)
                continue
            attr = _ATTR_ALIASES.get(name, name)
            if attr not in attrs or name == "lambda_":
                raise ParameterError(
                    f"{where}: unknown field {sec}.{name}; expected one of "
                    f"{', '.join(sorted(_FIELD_NAMES.get(a, a) for a in attrs))}"
                )
            try:
                value, note = _raw_value(entry)
            except KeyError:
                raise ParameterError(f"{where}: {sec}.{name} is a table without a 'value'") from None
            kw[attr] = _coerce(sec, name, value, where)
            provenance[f"{sec}.{name}"] = note
        if base is not None:
            sections[sec] = replace(getattr(base, sec), **kw)
        else:
            required = {f.name for f in fields(cls) if f.default is dataclasses.MISSING}
            missing = required - set(kw)
            if missing:
                raise ParameterError(f"{where}: [{sec}] is missing {', '.join(sorted(missing))}")
            sections[sec] = cls(**kw)
    drivers = dict(base.drivers) if base else {}
    given_drivers = data.get("drivers", {})
    if not isinstance(given_drivers, dict):
        raise ParameterError(f"{where}: [drivers] must be a table of tables ([drivers.1], [drivers.2], ...)")
    dnames = {f.name for f in fields(Driver)}
    for k, entry in given_drivers.items():
        if not isinstance(entry, dict):
            raise ParameterError(f"{where}: drivers.{k} must be a table")
        kw = {}
        for name, e in entry.items():
            if name not in dnames:
                raise ParameterError(
                    f"{where}: unknown field drivers.{k}.{name}; expected {', '.join(sorted(dnames))}"
                )
            value, note = _raw_value(e)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ParameterError(f"{where}: drivers.{k}.{name} = {value!r} is not a number")
            kw[name] = float(value)
            provenance[f"drivers.{k}.{name}"] = note
        if str(k) in drivers:
            drivers[str(k)] = replace(drivers[str(k)], **kw)
        else:
            missing = dnames - set(kw)
            if missing:
                raise ParameterError(f"{where}: drivers.{k} is missing {', '.join(sorted(missing))}")
            drivers[str(k)] = Driver(**kw)
    name = str(data.get("name", base.name if base else where))
    p = Parameters(
        name=name,
        drivers=drivers,
        provenance=provenance,
        citation=str(data.get("citation", base.citation if base else "")),
        **sections,
    )
    validate(p, where)
    return p


def _preset(name: str) -> Parameters:
    text = resources.files("vpsim.presets").joinpath(f"{name}.toml").read_text()
    data = tomllib.loads(text)
    data.setdefault("name", name)
    return _from_mapping(data, f"preset {name}", _preset(data["base"]) if data.get("base") else None)


def read_toml(path: Path, error: type[Exception]) -> dict[str, Any]:
    """Parse a TOML file; a missing, unreadable or malformed file raises ``error`` with a one-line message."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise error(f"{path}: no such file") from None
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML ({exc})") from None


def load_parameters(source: str | Path = "hofman2011") -> Parameters:
    """A parameter set from a preset name (``"hofman2011"``) or a TOML file path.

    A file may hold ``base = "PRESET"`` (default ``"hofman2011"``; ``base = ""`` for a complete file) and any
    subset of the sections ``[vehicle]``, ``[transmission]``, ``[engine]``, ``[simulation]``,
    ``[drivers.N]``. Values are plain numbers or tables ``{ value = ..., confidence = "..." }``.
    """
    if isinstance(source, str) and source in PRESETS:
        return _preset(source)
    path = Path(source)
    if not path.suffix and not path.exists():
        raise ParameterError(
            f"unknown preset {str(source)!r}; available presets: {', '.join(PRESETS)} (or a .toml file)"
        )
    data = read_toml(path, ParameterError)
    base_name = data.get("base", "hofman2011")
    if base_name in ("", None):
        base = None
    elif base_name in PRESETS:
        base = _preset(base_name)
    else:
        raise ParameterError(f"{path}: base = {base_name!r} is not a preset; available: {', '.join(PRESETS)}")
    data.setdefault("name", path.stem)
    return _from_mapping(data, str(path), base)


def as_dict(p: Parameters) -> dict[str, Any]:
    """Nested plain-dict form (JSON-friendly)."""
    d = dataclasses.asdict(p)
    d.pop("provenance", None)
    d["engine"]["lambda"] = d["engine"].pop("lambda_")
    return d
