"""Parameter sets: vehicle, transmission, engine, simulation settings and drivers.

A parameter set is plain, immutable data in SI units. Named presets (``hofman2011``) ship with the package
and carry each value's provenance (paper / derived / reconstructed). Users bring their own vehicles and
engines as TOML files with the same fields; a file may start from a preset (``base = "hofman2011"``, the
default) and override only what differs.

    >>> from vpsim.params import load_parameters
    >>> p = load_parameters("hofman2011")
    >>> round(p.engine.displacement * 1e3, 2)   # litres
    2.29

A value in a file is a plain number (SI) or a table ``{ value = 3000, unit = "lb", confidence = "..." }``;
a known unit of the field's dimension is converted to SI (:mod:`vpsim.units`), any other is refused. Files
are UTF-8 (with or without BOM). Every value must lie in its plausible range, and the engine as a whole must
be one that exists, which also bounds the work of the generated map (its grid grows with the torque span,
(peak BMEP - motoring BMEP) x V_d / (2 pi n_r)):

* 1 to 16 cylinders, two- or four-stroke, displacement 0.04 to 16 L (:data:`DISPLACEMENT_RANGE`);
* full-load BMEP at ambient pressure at most 40 bar, motoring BMEP at 1.25 x the top map speed not below
  -60 bar (:data:`MAX_FULL_LOAD_BMEP`, :data:`MIN_MOTORING_BMEP`);
* it can idle: zero torque at 80 rad/s needs an intake pressure between 0 and ambient that the throttle
  (at most ``max_throttle_area``) can hold; otherwise the forward method's idle throttle is undefined.

The limits, each field's range and the checks are defined in :mod:`vpsim.params_check`; :func:`validate`,
:func:`check_field`, :func:`engine_check_figures` and the limits are importable from here as well.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import tomllib
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any

from .errors import ParameterError

# the limits and checks (vpsim.params_check): those this module calls, and those imported from here
from .params_check import (  # noqa: F401
    _INT_RANGES,
    _RANGES,
    DISPLACEMENT_RANGE,
    IDLE_CHECK_SPEED,
    MAX_FULL_LOAD_BMEP,
    MAX_THERMAL_EFFICIENCY,
    MIN_MOTORING_BMEP,
    MIN_VEHICLE_MASS_KG,
    ROAD_LOAD_CHECK_SPEED,
    _coerce,
    _convert,
    _short,
    check_field,
    engine_check_figures,
    validate,
)
from .textio import check_path, read_text, toml_error

PRESETS = ("hofman2011", "geo_metro_1l", "saturn_1_9l", "bev", "hev_p2", "hev_split", "mhev")


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
    # torque converter between engine and gearbox (realistic mode; docs/model.md): capacity factor
    # K = w_pump / sqrt(T_pump) at stall, rad/s per sqrt(N m) (0: none, the driveline of the paper);
    # torque ratio at stall and the speed ratio of the coupling point
    converter_capacity_factor: float = 0.0
    converter_stall_torque_ratio: float = 2.0
    converter_coupling_speed_ratio: float = 0.85
    # the lock-up clutch closes from this gear at or above this vehicle speed (m/s)
    lockup_min_gear: int = 2
    lockup_min_speed: float = 0.0
    # a CVT (> 0): gearbox_ratios is its range [launch, overdrive], and the ratio is chosen on each cycle
    # interval from a geometric grid over the range whose neighbours differ by at most this fraction
    # (gearbox_steps); 0: a stepped gearbox, gearbox_ratios are its gears
    cvt_ratio_step: float = 0.0
    # the gear rule (vpsim.gears.default_schedule) of a schedule not given: shift up once the next gear keeps
    # the engine at or above this speed (rad/s; rule 3) and, with a shift point > 0, while accelerating leave
    # a gear only once the engine in it has reached that speed (rad/s; rule 4, a manual's driver); with a
    # shift speed > 0, while accelerating gear k + 1 only from the vehicle speed shift_point_speed + (k - 1)
    # shift_point_speed_step (m/s; rule 4, an owner's manual's table of upshift speeds)
    shift_engine_speed: float = 200.0
    shift_point_engine_speed: float = 0.0
    shift_point_speed: float = 0.0
    shift_point_speed_step: float = 0.0

    @property
    def is_cvt(self) -> bool:
        return self.cvt_ratio_step > 0.0

    @property
    def gearbox_steps(self) -> tuple[float, ...]:
        """The gearbox ratios a gear number (1-based) selects: the gears of a stepped gearbox, or a CVT's grid
        from its launch ratio (1) to its overdrive, neighbours at most ``cvt_ratio_step`` apart
        (:func:`cvt_grid`)."""
        if self.is_cvt:
            return cvt_grid(self.gearbox_ratios[0], self.gearbox_ratios[-1], self.cvt_ratio_step)
        return tuple(self.gearbox_ratios)

    @property
    def ratios(self) -> tuple[float, ...]:
        """Total ratios i = gearbox x final drive, one per gear (gear 1 first; a CVT's grid point)."""
        from .model.vehicle import total_ratio

        return tuple(total_ratio(g, self.final_drive) for g in self.gearbox_steps)

    @property
    def n_gears(self) -> int:
        """Gears of a stepped gearbox, or points of a CVT's grid."""
        return len(self.gearbox_steps)


MAX_CVT_STEPS = 500  # points of a CVT's ratio grid (a range of 20 at 0.6 % steps)


def cvt_grid(launch: float, overdrive: float, step: float) -> tuple[float, ...]:
    """A CVT's gearbox ratios from ``launch`` down to ``overdrive`` in equal relative steps of at most
    ``step`` (a fraction): launch * (overdrive / launch) ** (k / (n - 1)), k = 0 .. n - 1."""
    if not (launch > overdrive > 0.0 and step > 0.0):
        return (float(launch),)
    n = max(2, math.ceil(math.log(launch / overdrive) / math.log1p(step) - 1e-9) + 1)
    if n > MAX_CVT_STEPS:
        raise ParameterError(
            f"a CVT range {launch:g} / {overdrive:g} at steps of {step:g} needs {n} ratios, more than "
            f"{MAX_CVT_STEPS}; take a larger cvt_ratio_step"
        )
    return tuple(launch * (overdrive / launch) ** (k / (n - 1)) for k in range(n))


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
    boost_pressure: float = 0.0  # Pa absolute, full-load intake pressure of a boosted engine (0: aspirated)
    rated_power: float = 0.0  # W, the full-load line is capped at rated_power / w_e (0: no cap)
    # a boosted engine's full-load enrichment: fuel supplied over fuel burned, less 1, at full boost; rises
    # linearly with the pressure above ambient (0: none; 0.15 is lambda 0.87). vpsim.model.engine.enrichment
    boost_enrichment: float = 0.0

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
    # an engine car's stop-start: the engine stops at rest and a restart costs hybrid.engine_start_fuel
    # (backward and inverse methods; off: every figure as before)
    stop_start: bool = False


@dataclass(frozen=True)
class Driver:
    """Driver tuning: the forward PI gains and the inverse method's smoothing half-width."""

    forward_kp: float  # m^2 per m/s
    forward_ki: float  # m^2 per m
    inverse_a: float  # s


@dataclass(frozen=True)
class Powertrain:
    """What drives the car: ``conventional`` (the engine, gearbox and the sections above) or ``bev`` (a
    battery-electric car: [battery], [machine], [electric]; the [engine] is not used)."""

    type: str = "conventional"


@dataclass(frozen=True)
class Battery:
    """The traction battery (:mod:`vpsim.model.battery`): ``cells_in_series`` x ``cells_in_parallel`` cells
    of ``cell`` (a preset: nmc, lfp, nimh; or an ADVISOR ESS_*.m file)."""

    cell: str = "nmc"
    cells_in_series: int = 96
    cells_in_parallel: int = 30
    soc_initial: float = 0.9  # state of charge at the start of a run (fraction)
    soc_min: float = 0.05  # no discharge at or below
    soc_max: float = 0.98  # no charge at or above


@dataclass(frozen=True)
class Machine:
    """The traction machine with its inverter (:mod:`vpsim.model.machine`): the scalable loss model at this
    rating, or a measured map (``map_file``: an ADVISOR MC_*.m file; its envelope and efficiency)."""

    rated_power: float = 150.0e3  # W, peak
    base_speed: float = 420.0  # rad/s: constant torque below, constant power above
    max_speed: float = 920.0  # rad/s
    kind: str = "pm"  # pm (permanent magnet) or induction
    inertia: float = 0.05  # kg m^2, the rotor
    map_file: str = ""
    # the machine's and inverter's losses times this (1: the loss model as fitted, or the map as measured):
    # the drive-efficiency level of a technology, fitted per class by the fleet (vpsim.fleet.ev)
    loss_scale: float = 1.0


@dataclass(frozen=True)
class Electric:
    """The electric powertrain's own settings (:mod:`vpsim.model.electric`)."""

    accessory_power: float = 300.0  # W, constant electric load
    charger_efficiency: float = 0.88  # wall to battery
    regen_share: float = 1.0  # the share of braking the driven axle's machine may take
    regen_speed_low: float = 1.0  # m/s: no regeneration below
    regen_speed_high: float = 3.0  # m/s: the full share above (linear between)
    forward_kp: float = 4.0  # 1/s: the forward driver's P gain on the speed error (per unit mass)
    forward_ki: float = 4.0  # 1/s^2: its I gain
    forward_max_step: float = 0.25  # s: the forward method's step


@dataclass(frozen=True)
class Hybrid:
    """A hybrid's energy management (:mod:`vpsim.model.hybrid`, :mod:`vpsim.methods.hev`)."""

    ems: str = "ecms"  # rule, ecms or dp (dynamic programming; backward method only)
    soc_target: float = 0.6  # the state of charge the management sustains
    # rule: the engine starts above this demand at the gearbox input (W), or below soc_low; stops below
    # engine_off_power once it has run min_on_time and the charge is above soc_low + the hysteresis
    engine_on_power: float = 15.0e3
    engine_off_power: float = 8.0e3
    soc_low: float = 0.5
    soc_hysteresis: float = 0.05
    charge_power: float = 5.0e3  # W: the load-point shift that recharges at soc_low (linear to 0 at target)
    min_on_time: float = 5.0  # s
    # ECMS: equivalence factor s = s0 + ecms_gain (soc_target - soc): fuel + s P_chem / q_hv is minimised
    ecms_factor: float = 2.5
    ecms_gain: float = 20.0
    # an engine the ECMS starts runs at least this long (s); the start's fuel is spread over it in the choice
    ecms_min_on_time: float = 0.0
    engine_start_fuel: float = 0.3e-3  # kg of fuel one engine start costs (cranking, enrichment)
    torque_levels: int = 24  # engine torques the ECMS and DP choose from at each step (between its lines)
    dp_soc_points: int = 121  # the DP's state-of-charge grid
    dp_soc_span: float = 0.2  # its width around soc_target


@dataclass(frozen=True)
class Split:
    """A power-split hybrid's planetary gear set and generator (:mod:`vpsim.model.split`): the engine on the
    carrier, MG1 on the sun, the ring to the wheels (through ``transmission.final_drive``) with MG2 (the
    [machine]) through ``mg2_ratio``. Defaults: the 2016-2022 Prius / Corolla Hybrid transaxle (P610)."""

    sun_teeth: int = 30
    ring_teeth: int = 78
    mg2_ratio: float = 3.824  # MG2 to ring speed ratio
    engine_max_speed: float = 545.0  # rad/s, the engine's top speed (5,200 rpm)
    generator_rated_power: float = 23.0e3  # W, MG1's peak
    generator_base_speed: float = 575.0  # rad/s: MG1's constant-torque range (23 kW / 40 N m)
    generator_max_speed: float = 1780.0  # rad/s (17,000 rpm)
    generator_inertia: float = 0.01  # kg m^2, MG1's rotor


@dataclass(frozen=True)
class Mild:
    """A 48 V mild hybrid's machine on the crank (powertrain type ``mhev``, :mod:`vpsim.model.hybrid`): a P0
    belt starter-generator (``belt_ratio`` machine to crank speed, ``belt_efficiency`` either way) or, with
    ratio 1 and efficiency 1, a P1 machine on the crank itself."""

    belt_ratio: float = 2.7
    belt_efficiency: float = 0.95
    # the share of the machine's motoring torque the system gives the crank as assist (1: its whole envelope;
    # 0: a system that recuperates, starts and stops the engine and gives no torque, as Audi's 48 V V6/V8
    # system; vpsim.fleet.mhev.SYSTEMS): the motoring envelope times it, the generating one whole
    assist_share: float = 1.0


@dataclass(frozen=True)
class Parameters:
    """A complete parameter set. ``provenance`` maps ``"section.field"`` to its confidence label/note."""

    name: str
    vehicle: Vehicle
    transmission: Transmission
    engine: Engine
    simulation: Simulation
    drivers: dict[str, Driver]
    powertrain: Powertrain = field(default_factory=Powertrain)
    battery: Battery = field(default_factory=Battery)
    machine: Machine = field(default_factory=Machine)
    electric: Electric = field(default_factory=Electric)
    hybrid: Hybrid = field(default_factory=Hybrid)
    split: Split = field(default_factory=Split)
    mild: Mild = field(default_factory=Mild)
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
            new = replace(new, **{sec: changed_section(new, sec, changes)})
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


def changed_section(params: Parameters, sec: str, changes: dict[str, Any]):
    """Section ``sec`` of ``params`` with ``changes`` (TOML names, values coerced as the loader does), not yet
    validated as a whole: what :meth:`Parameters.with_changes` builds before it validates."""
    if sec not in _SECTIONS:
        raise ParameterError(f"unknown section {sec!r}; expected one of {', '.join(_SECTIONS)}")
    obj = getattr(params, sec)
    names = {f.name for f in fields(obj)}
    kw = {}
    for k, v in changes.items():
        attr = _ATTR_ALIASES.get(k, k)
        if attr not in names:
            raise ParameterError(f"unknown field {sec}.{k}")
        kw[attr] = _coerce(sec, k, v, "with_changes")
    return replace(obj, **kw)


_SECTIONS = {
    "vehicle": Vehicle,
    "transmission": Transmission,
    "engine": Engine,
    "simulation": Simulation,
    "powertrain": Powertrain,
    "battery": Battery,
    "machine": Machine,
    "electric": Electric,
    "hybrid": Hybrid,
    "split": Split,
    "mild": Mild,
}
POWERTRAINS = ("conventional", "bev", "hev_p2", "hev_split", "mhev")
HYBRIDS = ("hev_p2", "hev_split", "mhev")
EMS = ("rule", "ecms", "dp")
MACHINE_KINDS = ("pm", "induction")
_ATTR_ALIASES = {"lambda": "lambda_"}  # TOML name -> attribute
_FIELD_NAMES = {v: k for k, v in _ATTR_ALIASES.items()}

# fields of earlier versions that no longer exist: read and ignored, with the reason
_RETIRED = {
    "simulation.newton_max_iterations": "the FQM's Newton solve always converges to 1e-12 (at most 30 steps)",
    "simulation.newton_relative_tolerance": "the FQM's Newton solve always converges to 1e-12",
}


_ENTRY_KEYS = ("value", "unit", "confidence", "note")


def _raw_value(entry: Any, key: str = "", where: str = "") -> tuple[Any, str, Any]:
    """(value, provenance note, unit or None) of a plain value or a ``{ value = ..., unit = ... }`` table."""
    if isinstance(entry, dict):
        if "value" not in entry:
            raise ParameterError(f"{where}: {key} is a table without a 'value'")
        extra = sorted(set(entry) - set(_ENTRY_KEYS))
        if extra:
            raise ParameterError(
                f"{where}: {key}: unknown key {extra[0]!r} in the table; expected {', '.join(_ENTRY_KEYS)}"
            )
        for k in ("confidence", "note"):
            if k in entry and not isinstance(entry[k], str):
                raise ParameterError(f"{where}: {key}: {k} = {_short(entry[k])} must be a text")
        note = entry.get("confidence", "user")
        if "note" in entry:
            note += f" ({entry['note']})"
        return entry["value"], note, entry.get("unit")
    return entry, "user", None


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
            value, note, unit = _raw_value(entry, f"{sec}.{name}", where)
            kw[attr] = _coerce(sec, name, value, where, unit)
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
            value, note, unit = _raw_value(e, f"drivers.{k}.{name}", where)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ParameterError(f"{where}: drivers.{k}.{name} = {_short(value)} is not a number")
            try:
                kw[name] = float(value)
            except OverflowError:
                kw[name] = math.inf
            if unit is not None:
                kw[name] = _convert(f"drivers.{k}.{name}", kw[name], unit, where)
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


@functools.cache
def _preset(name: str) -> Parameters:
    """A preset, parsed once per process (parameter sets are frozen: the same object serves every caller,
    and what is cached per parameter set, :func:`vpsim.model.record.memo`, serves them too)."""
    text = resources.files("vpsim.presets").joinpath(f"{name}.toml").read_text()
    data = tomllib.loads(text)
    data.setdefault("name", name)
    return _from_mapping(data, f"preset {name}", _preset(data["base"]) if data.get("base") else None)


def read_toml(path: Path, error: type[Exception]) -> dict[str, Any]:
    """Parse a TOML file; a missing, unreadable, non-UTF-8 or malformed file raises ``error`` (one line)."""
    text = read_text(path, error, what="TOML file")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML ({toml_error(exc, text)})") from None
    except RecursionError:
        raise error(f"{path}: not valid TOML (arrays or tables nested too deeply)") from None


def load_parameters(source: str | Path = "hofman2011") -> Parameters:
    """A parameter set from a preset name (``"hofman2011"``) or a TOML file path.

    A file may hold ``base = "PRESET"`` (default ``"hofman2011"``; ``base = ""`` for a complete file) and any
    subset of the sections ``[vehicle]``, ``[transmission]``, ``[engine]``, ``[simulation]``,
    ``[drivers.N]``. Values are plain numbers or tables ``{ value = ..., confidence = "..." }``.
    """
    if not isinstance(source, str | os.PathLike):
        raise TypeError(
            f"a parameter set is a preset's name, a TOML file's path or a vpsim.params.Parameters, not "
            f"{type(source).__name__}; to change values: "
            "load_parameters('hofman2011').with_changes(vehicle={'mass': 1200.0})"
        )
    if isinstance(source, str) and source in PRESETS:
        return _preset(source)
    if not str(source).strip():
        raise ParameterError(
            f"empty parameter set name; available presets: {', '.join(PRESETS)} (or a .toml file)"
        )
    path = check_path(source, ParameterError, "parameter file")
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
    _files_beside(data, path.parent)
    return _from_mapping(data, str(path), base)


def _files_beside(data: dict[str, Any], folder: Path) -> None:
    """A data file a parameter file names (battery.cell as an ESS_*.m, machine.map_file) is found beside it
    when its path is relative."""
    for sec, key in (("battery", "cell"), ("machine", "map_file")):
        section = data.get(sec)
        if not isinstance(section, dict) or key not in section:
            continue
        entry = section[key]
        value = entry.get("value") if isinstance(entry, dict) else entry
        if not isinstance(value, str) or not value.lower().endswith(".m") or Path(value).is_absolute():
            continue
        resolved = str(folder / value)
        if isinstance(entry, dict):
            section[key] = {**entry, "value": resolved}
        else:
            section[key] = resolved


def as_dict(p: Parameters) -> dict[str, Any]:
    """Nested plain-dict form (JSON-friendly)."""
    d = dataclasses.asdict(p)
    d.pop("provenance", None)
    d["engine"]["lambda"] = d["engine"].pop("lambda_")
    return d
