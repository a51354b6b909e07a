"""Units of parameter values: ``{ value = 3000, unit = "lb" }`` in a TOML file is converted to SI.

Each parameter field has a dimension (:data:`FIELD_DIMENSIONS`); a unit is accepted when it is a unit of
that dimension (:data:`UNITS`) and converted to the SI unit vpsim works in. A unit that is unknown, or of
another dimension, is an error naming the field and the units it accepts.

    >>> round(to_si(3000.0, "lb", "mass"), 3)
    1360.777
    >>> round(to_si(20.0, "degC", "temperature"), 2)
    293.15

Unit text is matched exactly after folding spaces, ``*`` and ``·`` to one space and ``²``/``³`` to
``^2``/``^3`` (so ``"kg m^2"``, ``"kg*m^2"`` and ``"kg·m²"`` are the same unit); letter case matters
(``mPa`` is not ``MPa``).
"""

from __future__ import annotations

import re

# US miles per gallon <-> L/100 km (each the constant over the other): 100 km / 3.785411784 L per 1.609344 km
L_PER_100KM_MPG = 235.2145833


def mpg_from_l_per_100km(l_per_100km):
    """US miles per gallon of a consumption in L/100 km (and the other way round: the map is its own
    inverse)."""
    return L_PER_100KM_MPG / l_per_100km


METRES_PER_MILE = 1609.344  # exact (international mile)
LITRES_PER_GALLON = 3.785411784  # exact (US liquid gallon)
MPH_TO_MPS = METRES_PER_MILE / 3600.0  # 0.44704 exactly

# dimension -> {unit: (factor, offset)}: SI value = factor * value + offset

UNITS: dict[str, dict[str, tuple[float, float]]] = {
    "dimensionless": {"-": (1.0, 0.0), "": (1.0, 0.0), "1": (1.0, 0.0)},
    "fraction": {"-": (1.0, 0.0), "": (1.0, 0.0), "1": (1.0, 0.0), "%": (0.01, 0.0)},
    "count": {"-": (1.0, 0.0), "": (1.0, 0.0), "1": (1.0, 0.0)},
    "mass": {"kg": (1.0, 0.0), "g": (1e-3, 0.0), "t": (1e3, 0.0), "lb": (0.45359237, 0.0)},
    "length": {
        "m": (1.0, 0.0),
        "mm": (1e-3, 0.0),
        "cm": (1e-2, 0.0),
        "in": (0.0254, 0.0),
        "ft": (0.3048, 0.0),
    },
    "area": {
        "m^2": (1.0, 0.0),
        "cm^2": (1e-4, 0.0),
        "mm^2": (1e-6, 0.0),
        "in^2": (0.0254**2, 0.0),
        "ft^2": (0.3048**2, 0.0),
    },
    "volume": {
        "m^3": (1.0, 0.0),
        "L": (1e-3, 0.0),
        "l": (1e-3, 0.0),
        "cc": (1e-6, 0.0),
        "cm^3": (1e-6, 0.0),
        "mL": (1e-6, 0.0),
        "ml": (1e-6, 0.0),
        "in^3": (0.0254**3, 0.0),
    },
    "pressure": {
        "Pa": (1.0, 0.0),
        "hPa": (1e2, 0.0),
        "kPa": (1e3, 0.0),
        "MPa": (1e6, 0.0),
        "mbar": (1e2, 0.0),
        "bar": (1e5, 0.0),
        "atm": (101325.0, 0.0),
        "psi": (6894.757293168361, 0.0),
    },
    "temperature": {
        "K": (1.0, 0.0),
        "degC": (1.0, 273.15),
        "C": (1.0, 273.15),
        "degF": (5.0 / 9.0, 273.15 - 32.0 * 5.0 / 9.0),
        "F": (5.0 / 9.0, 273.15 - 32.0 * 5.0 / 9.0),
    },
    "density": {
        "kg/m^3": (1.0, 0.0),
        "g/L": (1.0, 0.0),
        "g/l": (1.0, 0.0),
        "kg/L": (1e3, 0.0),
        "g/cm^3": (1e3, 0.0),
        "lb/ft^3": (0.45359237 / 0.3048**3, 0.0),
    },
    "fuel_density": {  # vpsim keeps fuel density in kg/L
        "kg/L": (1.0, 0.0),
        "kg/l": (1.0, 0.0),
        "g/cm^3": (1.0, 0.0),
        "g/mL": (1.0, 0.0),
        "g/ml": (1.0, 0.0),
        "kg/m^3": (1e-3, 0.0),
        "g/L": (1e-3, 0.0),
        "g/l": (1e-3, 0.0),
        "lb/gal": (0.45359237 / 3.785411784, 0.0),
    },
    "acceleration": {"m/s^2": (1.0, 0.0), "ft/s^2": (0.3048, 0.0)},
    "speed": {"m/s": (1.0, 0.0), "km/h": (1.0 / 3.6, 0.0), "mph": (MPH_TO_MPS, 0.0)},
    "inertia": {
        "kg m^2": (1.0, 0.0),
        "g cm^2": (1e-7, 0.0),
        "lb ft^2": (0.45359237 * 0.3048**2, 0.0),
        "lb in^2": (0.45359237 * 0.0254**2, 0.0),
    },
    "gas_constant": {
        "J/(kg K)": (1.0, 0.0),
        "J/kg/K": (1.0, 0.0),
        "J/(kg·K)": (1.0, 0.0),
        "kJ/(kg K)": (1e3, 0.0),
        "kJ/kg/K": (1e3, 0.0),
    },
    "specific_energy": {
        "J/kg": (1.0, 0.0),
        "kJ/kg": (1e3, 0.0),
        "MJ/kg": (1e6, 0.0),
        "J/g": (1e3, 0.0),
        "kWh/kg": (3.6e6, 0.0),
    },
    "angular_speed": {
        "rad/s": (1.0, 0.0),
        "rpm": (2.0 * 3.141592653589793 / 60.0, 0.0),
        "r/min": (2.0 * 3.141592653589793 / 60.0, 0.0),
        "1/min": (2.0 * 3.141592653589793 / 60.0, 0.0),
    },
    "mass_flow": {
        "kg/s": (1.0, 0.0),
        "g/s": (1e-3, 0.0),
        "kg/h": (1.0 / 3600.0, 0.0),
        "g/h": (1e-3 / 3600.0, 0.0),
    },
    "time": {"s": (1.0, 0.0), "ms": (1e-3, 0.0), "min": (60.0, 0.0), "h": (3600.0, 0.0)},
    "gain_p": {"m^2/(m/s)": (1.0, 0.0), "m s": (1.0, 0.0)},
    "gain_i": {"m^2/m": (1.0, 0.0), "m": (1.0, 0.0)},
    "power": {"W": (1.0, 0.0), "kW": (1e3, 0.0), "hp": (745.6998715822702, 0.0), "PS": (735.49875, 0.0)},
}

# parameter field ("section.field"; drivers as "drivers.field") -> dimension
FIELD_DIMENSIONS: dict[str, str] = {
    "vehicle.mass": "mass",
    "vehicle.frontal_area": "area",
    "vehicle.drag_coefficient": "dimensionless",
    "vehicle.rolling_resistance": "dimensionless",
    "vehicle.air_density": "density",
    "vehicle.gravity": "acceleration",
    "vehicle.wheel_radius": "length",
    "transmission.efficiency": "fraction",
    "transmission.gearbox_ratios": "dimensionless",
    "transmission.final_drive": "dimensionless",
    "transmission.cvt_ratio_step": "fraction",
    "transmission.shift_engine_speed": "angular_speed",
    "transmission.shift_point_engine_speed": "angular_speed",
    "transmission.shift_point_speed": "speed",
    "transmission.shift_point_speed_step": "speed",
    "engine.bore": "length",
    "engine.stroke": "length",
    "engine.cylinders": "count",
    "engine.inertia": "inertia",
    "engine.revolutions_per_cycle": "count",
    "engine.intake_manifold_volume": "volume",
    "engine.ambient_pressure": "pressure",
    "engine.ambient_temperature": "temperature",
    "engine.intake_temperature": "temperature",
    "engine.exhaust_pressure": "pressure",
    "engine.gas_constant": "gas_constant",
    "engine.specific_heat_ratio": "dimensionless",
    "engine.fuel_heating_value": "specific_energy",
    "engine.thermal_efficiency": "fraction",
    "engine.stoich_air_fuel_ratio": "dimensionless",
    "engine.lambda": "dimensionless",
    "engine.air_charge_slope": "dimensionless",
    "engine.air_charge_intercept": "pressure",
    "engine.friction_coefficient": "dimensionless",
    "engine.boost_layout": "dimensionless",
    "engine.max_throttle_area": "area",
    "engine.min_throttle_area": "area",
    "engine.map_speed_range": "angular_speed",
    "simulation.idle_fuel_flow": "mass_flow",
    "simulation.fuel_density": "fuel_density",
    "simulation.newton_max_iterations": "count",
    "simulation.newton_relative_tolerance": "dimensionless",
    "simulation.ode_relative_tolerance": "dimensionless",
    "simulation.inverse_max_step": "time",
    "battery.cells_in_series": "count",
    "battery.cells_in_parallel": "count",
    "battery.soc_initial": "fraction",
    "battery.soc_min": "fraction",
    "battery.soc_max": "fraction",
    "machine.rated_power": "power",
    "machine.base_speed": "angular_speed",
    "machine.max_speed": "angular_speed",
    "machine.inertia": "inertia",
    "electric.accessory_power": "power",
    "electric.charger_efficiency": "fraction",
    "electric.regen_share": "fraction",
    "electric.regen_speed_low": "speed",
    "electric.regen_speed_high": "speed",
    "electric.forward_max_step": "time",
    "hybrid.soc_target": "fraction",
    "hybrid.engine_on_power": "power",
    "hybrid.engine_off_power": "power",
    "hybrid.soc_low": "fraction",
    "hybrid.soc_hysteresis": "fraction",
    "hybrid.charge_power": "power",
    "hybrid.min_on_time": "time",
    "hybrid.ecms_min_on_time": "time",
    "hybrid.dp_soc_span": "fraction",
    "hybrid.dp_soc_points": "count",
    "hybrid.torque_levels": "count",
    "split.sun_teeth": "count",
    "split.ring_teeth": "count",
    "split.mg2_ratio": "dimensionless",
    "split.engine_max_speed": "angular_speed",
    "split.generator_rated_power": "power",
    "split.generator_base_speed": "angular_speed",
    "split.generator_max_speed": "angular_speed",
    "split.generator_inertia": "inertia",
    "mild.belt_ratio": "dimensionless",
    "mild.belt_efficiency": "fraction",
    "mild.assist_share": "fraction",
    "drivers.forward_kp": "gain_p",
    "drivers.forward_ki": "gain_i",
    "drivers.inverse_a": "time",
}

_NAMES = {
    "dimensionless": "a dimensionless number",
    "fraction": "a fraction",
    "count": "a count",
    "fuel_density": "a density (kg/L)",
    "gas_constant": "a specific gas constant",
    "specific_energy": "a specific energy",
    "angular_speed": "an angular speed",
    "mass_flow": "a mass flow",
    "gain_p": "a PI gain in m^2/(m/s)",
    "gain_i": "a PI gain in m^2/m",
}


def normalise(unit: str) -> str:
    """Unit text folded to one spelling: spaces / ``*`` / ``·`` between factors as one space, ² ³ as ^2 ^3."""
    u = unit.strip().replace("²", "^2").replace("³", "^3").replace("°", "deg")
    u = re.sub(r"\s*[*·]\s*|\s+", " ", u)
    return u


def describe(dimension: str) -> str:
    return _NAMES.get(dimension, f"a {dimension.replace('_', ' ')}")


def dimension_of(unit: str) -> list[str]:
    """The dimensions that ``unit`` is a unit of (empty when it is unknown)."""
    u = normalise(unit)
    return [d for d, table in UNITS.items() if u in table]


def to_si(value: float, unit: str, dimension: str) -> float:
    """``value`` in ``unit`` converted to the SI unit of ``dimension``; ValueError (one line) if it cannot."""
    table = UNITS[dimension]
    u = normalise(unit)
    if u not in table:
        others = [d for d in dimension_of(unit) if d not in ("dimensionless", "fraction", "count")]
        accepted = ", ".join(repr(k) for k in table if k)
        if others:
            raise ValueError(
                f"unit {unit!r} is {describe(others[0])} unit, but this field is {describe(dimension)}; "
                f"expected one of {accepted}"
            )
        raise ValueError(f"unit {unit!r} is not known for {describe(dimension)}; expected one of {accepted}")
    factor, offset = table[u]
    return factor * value + offset


__all__ = ["FIELD_DIMENSIONS", "UNITS", "describe", "dimension_of", "normalise", "to_si"]
