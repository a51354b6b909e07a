"""The one parameter record of compiled code, built from :class:`vpsim.params.Parameters` in one place.

Compiled kernels and NumPy callers read the model's constants from a NumPy structured record whose fields
are named as in ``Parameters`` (``rec.mass``, ``rec.bore``, ``rec.lambda_`` ...), plus a few *derived*
fields (displacement, friction factor, ...) that :func:`pack` fills by calling the model's own equations
(:mod:`vpsim.model.engine`, :mod:`vpsim.model.vehicle`), so no formula is written here.

* :func:`record` gives the record of one parameter set (a ``numpy.record``: attribute access in Python, a
  Numba ``Record`` in compiled code).
* :func:`records` gives an array of records, one per design variant, from sections whose fields may be arrays
  (how :mod:`vpsim.batch` evaluates thousands of variants in one call).

Records are read-only and cached per (immutable) parameter set.
"""

from __future__ import annotations

import functools
from types import SimpleNamespace

import numpy as np

# Fields of the record: (name, section of Parameters or None for derived values). Parameters keep their
# names; engine.map_speed_range becomes map_speed_low / map_speed_high.
_PARAMETER_FIELDS = {
    "vehicle": (
        "mass",
        "frontal_area",
        "drag_coefficient",
        "rolling_resistance",
        "air_density",
        "gravity",
        "wheel_radius",
        "road_load_a",
        "road_load_b",
        "road_load_c",
    ),
    "transmission": (
        "efficiency",
        "final_drive",
        "converter_capacity_factor",
        "converter_stall_torque_ratio",
        "converter_coupling_speed_ratio",
        "lockup_min_gear",
        "lockup_min_speed",
    ),
    "engine": (
        "bore",
        "stroke",
        "cylinders",
        "inertia",
        "revolutions_per_cycle",
        "intake_manifold_volume",
        "ambient_pressure",
        "ambient_temperature",
        "intake_temperature",
        "exhaust_pressure",
        "gas_constant",
        "specific_heat_ratio",
        "fuel_heating_value",
        "thermal_efficiency",
        "stoich_air_fuel_ratio",
        "lambda_",
        "air_charge_slope",
        "air_charge_intercept",
        "friction_coefficient",
        "boost_layout",
        "max_throttle_area",
        "min_throttle_area",
        "accessory_power",
        "boost_pressure",
        "rated_power",
        "boost_enrichment",
    ),
    "simulation": ("idle_fuel_flow", "fuel_density", "fuel_cutoff_speed"),
}
# model constants that are not (yet) parameters, and values derived from the parameters by the model
MODEL_FIELDS = ("idle_speed",)
DERIVED_FIELDS = (
    "displacement",  # V_d
    "friction_factor",  # k_f of (5)
    "bmep_per_net_mep",  # 1 / (the divisor of (5) solved for BMEP) (engine.bmep_per_net_mep)
    "heat_factor",  # Q = q_hv eta_th / ((A/F)_s lambda R T_i): IMEP per unit (s_i p_i - y_i)
    "mep_to_torque",  # V_d / (2 pi n_r) of (3)
    "air_per_charge",  # V_d / (R T_i): air charge per unit (s_i p_i - y_i) of (8)
    "fuel_per_air",  # 1 / ((A/F)_s lambda) of (7) (engine.fuel_per_air)
    "rt_intake",  # R T_i of (8),(9)
    "sqrt_rt_ambient",  # sqrt(R T_a) of (10)
    "critical_ratio",  # p_r* of (11)
    "psi_choked",  # Psi in the choked region (12)
    "rolling_force",  # m g c_r of (18), or the coast-down A
    "aero_coefficient",  # 1/2 c_d rho A of (18), or the coast-down C
    "torque_slope",  # dT_cr/dp_i (engine.torque_slope)
    "enrichment_slope",  # d(enrichment)/dp_i above ambient (engine.enrichment_slope)
    "idle_speed_power",  # c_m^1.8 of (5) at the idle speed (engine.speed_power): the engine held at idle
    # reciprocals, so the equations multiply (as bmep_per_net_mep and fuel_per_air above): a division's
    # latency on the chain from a demand to its fuel flow is what bounds the backward kernels
    "cycles_per_radian",  # 1 / (2 pi n_r) (engine.cycles_per_radian)
    "pressure_per_torque",  # 1 / (dT_cr/dp_i) (engine.pressure_per_torque)
)
FIELDS = tuple(f for fs in _PARAMETER_FIELDS.values() for f in fs) + (
    "map_speed_low",
    "map_speed_high",
    *MODEL_FIELDS,
    *DERIVED_FIELDS,
)
DTYPE = np.dtype([(name, np.float64) for name in FIELDS], align=True)

IDLE_SPEED = 80.0  # rad/s: the engine speed held below which the clutch slips or opens (extended mode)


def _scalar(v) -> float:
    return float(v) if not isinstance(v, np.ndarray) or v.ndim == 0 else float(v.reshape(-1)[0])


def _fill(rec, vehicle, transmission, engine, simulation, n: int) -> None:
    import types

    from . import engine as eq_engine
    from . import vehicle as eq_vehicle

    # the fields on a plain namespace (floats, or arrays of the n variants), which the model's equations read
    # as they read a record, at a fraction of the cost of a record's attribute access; written once at the end
    r = types.SimpleNamespace()
    sections = {"vehicle": vehicle, "transmission": transmission, "engine": engine, "simulation": simulation}
    for sec, names in _PARAMETER_FIELDS.items():
        obj = sections[sec]
        for name in names:
            v = getattr(obj, name)
            scalar = n == 1 and not (isinstance(v, np.ndarray) and v.ndim > 0)
            setattr(r, name, float(v) if scalar else np.asarray(v, dtype=float))
    r.map_speed_low, r.map_speed_high = engine.map_speed_range
    r.idle_speed = IDLE_SPEED
    # derived values, each computed by the model's own equation (in dependency order)
    r.displacement = eq_engine.displacement(r)
    r.friction_factor = eq_engine.friction_factor(r)
    r.bmep_per_net_mep = eq_engine.bmep_per_net_mep(r)
    r.cycles_per_radian = eq_engine.cycles_per_radian(r)
    r.rt_intake = eq_engine.intake_rt(r)
    r.fuel_per_air = eq_engine.fuel_per_air(r)
    r.heat_factor = eq_engine.heat_factor(r)
    r.mep_to_torque = eq_engine.mep_to_torque(1.0, r)
    r.air_per_charge = eq_engine.air_per_charge_pressure(r)
    r.sqrt_rt_ambient = eq_engine.ambient_rt_sqrt(r)
    r.critical_ratio = eq_engine.critical_pressure_ratio(r.specific_heat_ratio)
    r.psi_choked = eq_engine.psi_choked(r.specific_heat_ratio)
    r.rolling_force = eq_vehicle.rolling_force_moving(r)
    r.aero_coefficient = eq_vehicle.aero_coefficient(r)
    r.torque_slope = 1.0  # a placeholder crank_torque does not read; the slope follows from it
    r.torque_slope = eq_engine.torque_slope(r)
    r.pressure_per_torque = eq_engine.pressure_per_torque(r)
    r.enrichment_slope = eq_engine.enrichment_slope(r)
    r.idle_speed_power = eq_engine.speed_power(r.idle_speed, r)
    values = {name: getattr(r, name) for name in FIELDS}
    varying = {
        name: v for name, v in values.items() if isinstance(v, np.ndarray) and v.ndim > 0 and v.size > 1
    }
    # the values every variant shares as one record, copied to every row at once, then the fields that vary
    # (a strided pass each): writing all 65 fields of 20,000 variants one field at a time took 8 ms, this 2
    rec[0] = tuple(0.0 if name in varying else _scalar(v) for name, v in values.items())
    if n > 1:
        rows = rec.view(np.uint8).reshape(n, rec.dtype.itemsize)  # (a record as bytes: copied 4x faster)
        rows[1:] = rows[0]
        for name, v in varying.items():
            rec[name] = np.broadcast_to(np.asarray(v, dtype=float), (n,))


def _sections_len(*sections) -> int:
    n = 1
    for obj in sections:
        for v in vars(obj).values() if hasattr(obj, "__dict__") else ():
            if isinstance(v, np.ndarray) and v.ndim == 1:
                n = max(n, v.size)
    return n


def records(vehicle, transmission, engine, simulation) -> np.ndarray:
    """An array of records, one per variant; section attributes may be scalars or 1-D arrays (broadcast)."""
    n = _sections_len(vehicle, transmission, engine, simulation)
    rec = np.zeros(n, dtype=DTYPE)
    _fill(rec, vehicle, transmission, engine, simulation, n)
    return rec.view(np.recarray)


@functools.lru_cache(maxsize=256)
def _record_of(vehicle, transmission, engine, simulation) -> np.ndarray:
    rec = records(vehicle, transmission, engine, simulation)
    rec.flags.writeable = False
    return rec


def memo(obj, key: str, build):
    """``build(obj)``, computed once per (immutable) object and kept on the object itself.

    Parameter sets are frozen, so what is derived from one never changes; keeping it on the object (not in a
    module-level table) makes the look-up an attribute access, free of hashing and of shared state. Two
    threads may both build it the first time; they build the same value.
    """
    cache = obj.__dict__.get("_derived")
    if cache is None:
        cache = {}
        object.__setattr__(obj, "_derived", cache)
    hit = cache.get(key)
    if hit is None:
        hit = cache[key] = build(obj)
    return hit


def readonly(arrays: tuple) -> tuple:
    """``arrays`` (a tuple; None entries left as they are) made read-only in place and returned: what
    :func:`memo` keeps on an immutable object is shared by every caller, so nobody may write into it."""
    for x in arrays:
        if x is not None:
            x.setflags(write=False)
    return arrays


def record_array(params) -> np.ndarray:
    """The read-only record array (shape (1,)) of one parameter set, cached per parameter set."""
    return memo(params, "record", lambda p: _record_of(p.vehicle, p.transmission, p.engine, p.simulation))


def kernel_records(params) -> np.ndarray:
    """The record of one parameter set as a plain structured array of shape (1,), which compiled kernels
    take and index (``c = recs[0]``): the dispatch of an array is cheaper than that of a record."""
    return memo(params, "kernel_records", lambda p: np.asarray(record_array(p)).view(np.ndarray))


def record(params):
    """The record of one parameter set (``rec.mass``, ``rec.displacement``, ...), cached."""
    return memo(params, "record_0", lambda p: record_array(p)[0])


def engine_record(engine):
    """The record of an engine alone (maps, checks of an engine): the other sections are neutral values the
    engine's equations never read."""
    vehicle, transmission, simulation = _neutral_sections()
    return _record_of(vehicle, transmission, engine, simulation)[0]


@functools.cache
def _neutral_sections():
    from ..params import Simulation, Transmission, Vehicle

    return (
        Vehicle(
            mass=1.0,
            frontal_area=1.0,
            drag_coefficient=0.0,
            rolling_resistance=0.0,
            air_density=1.2,
            gravity=9.81,
            wheel_radius=0.3,
        ),
        Transmission(efficiency=1.0, gearbox_ratios=(1.0,), final_drive=1.0),
        Simulation(idle_fuel_flow=0.0, fuel_density=0.745, ode_relative_tolerance=1e-3, inverse_max_step=1.0),
    )


def fields(rec) -> SimpleNamespace:
    """The fields of one record (``rec.mass``, ``rec.k_cu`` ...), or of an array of records (each attribute
    then the field's column, a view), as plain attributes, for the model's equations evaluated by NumPy in
    Python (the lines and maps built once per parameter set, the 0-100 km/h run of a sweep's designs).

    A ``numpy.record`` reads a field through NumPy's Python-level ``__getattribute__``, about 1-2 us a
    field; an equation reads dozens of fields per call, so on small arrays that look-up, not the arithmetic,
    took most of the time (the power split's lines: 2.5 million look-ups for 240 parameter sets). The values
    are the record's own NumPy scalars (``rec[name]``), so every result is the same to the bit. Compiled
    kernels and the ``*_array`` loops take the record itself, never this."""
    return SimpleNamespace(**{name: rec[name] for name in rec.dtype.names})


@functools.lru_cache(maxsize=256)
def engine_fields(engine) -> SimpleNamespace:
    """:func:`fields` of :func:`engine_record`, cached per (immutable) engine."""
    return fields(engine_record(engine))


def ratios(transmission) -> np.ndarray:
    """Total ratio per gear (gearbox x final drive), read-only, cached per transmission."""
    return memo(transmission, "ratios", _ratios)


def _ratios(transmission) -> np.ndarray:
    r = np.asarray(transmission.ratios, dtype=float)
    r.flags.writeable = False
    return r
