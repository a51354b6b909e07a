"""The mild-hybrid records of a test car list: reader, layout, vehicle mapping, their technology.

Which records (:func:`mhev_vehicle`): the vehicles :mod:`vpsim.fleet.epa` flags ``mild hybrid`` (``MHEV`` in
the model name, or an FTP with a fourth bag, after the full-hybrid screens). Each gets a layout by its maker's
published system (:func:`layout`, :data:`SYSTEMS`; the record names no machine or battery), the first rule
that applies:

* Mercedes-Benz: ``mhev_p1``, 16 kW. EQ Boost: an integrated starter-generator between engine and gearbox,
  16 kW / 250 Nm (the M256 straight six; the S 580's V8 has a 48 V ISG too), a 48 V pack of about 1 kWh;
* BMW: ``mhev_p0``, 8 kW. A 48 V starter-generator on the belt, "up to 8 kW (11 PS)" (BMW, 2019-2020: the
  5 Series, then the B58 engines);
* Audi 2.9-4.0 L: ``mhev_p0``, 12 kW, no assist (``mild.assist_share`` 0). A 48 V belt alternator starter
  with "a high recuperation power of up to 12 kW plus start-stop operation from 22 km/h" and engine-off
  coasting at 55-160 km/h, a 10 Ah lithium-ion pack (Audi Technology Portal, "Audi A8 - MHEV components",
  2017; the Volkswagen Group's description of the 6- and 8-cylinder system: "a recuperation power of up to
  12 kW and 60 Nm"); neither names an assist, where the A3's does;
* the A3: ``mhev_p0``, 12 kW, assist 0.75 of it: "the BAS can recuperate up to 12 kW ... it assists the
  TFSI with up to 9 kW and 50 Nm" (Audi Technology Portal, "Audi A3 Sportback 48 V mild-hybrid system");
* Audi's other 2.0 L (A4, A5, A6, Q5, allroad): ``mhev_p0`` on 12 V, 5 kW, assist 0.2 of it. The 12 V
  MHEV: a belt starter-generator on a 12 V lithium-ion battery (11 Ah), "recuperation of at most 5 kW; the
  generator can also assist the engine with up to 1 kW" (elektroniknet.de on Audi's 12 V mild hybrid,
  2015; until 2026-12-07 the fleet took 3 kW, a 12 V machine's current, and the whole envelope as assist);
* Volvo (B5, B6): ``mhev_p0``, 10 kW. A 48 V integrated starter-generator module on the belt, 10 kW;
* RAM, Jeep (eTorque): ``mhev_p0``, 12 kW. A 48 V belt motor-generator in place of the alternator, a 430 Wh
  lithium-ion pack, 90 lb-ft (V6) / 130 lb-ft (V8) at the crank; no power published: the preset's 12 kW;
* Jaguar, Land Rover, Range Rover: ``mhev_p0``, 12 kW. A 48 V belt-integrated starter-generator (BiSG): the
  preset ``mhev`` is their E-PACE P300 (12 kW; the class's machines are 10-15 kW);
* any other: excluded, ``mild hybrid, no known system`` (on the 2022 list the Dodge Charger 3.6 L: a 4-bag
  FTP, and no mild-hybrid system sold for it).

The tests: a mild hybrid's FTP is the 4-bag FTP of electrified cars (``FE Bag 1``..``FE Bag 4``: the cold
505 s, the stabilised 867 s, the hot 505 s, the stabilised 867 s again; :mod:`vpsim.fleet.hev`). The bags
a conventional car's FTP measures are the same phases: ``ftp_bag2`` is ``FE Bag 2`` (the stabilised 867 s)
and ``ftp_bag3`` ``FE Bag 3`` (the hot 505 s), read where the four bags give the test's composite
``RND_ADJ_FE`` within :data:`vpsim.fleet.hev.COMPOSITE_TOLERANCE` (the check that the bags are what they
are; a 3-bag FTP, as some ``MHEV``-named records have, is read as a conventional car's). Bag 4 repeats bag
2's phase and is not compared. The pack is small (0.2-1 kWh) and a bag's charge swing a few tens of Wh; the
model reports the charge-sustaining figure (``fuel_l_per_100km_cs``). ``hwy``, ``us06``: ``RND_ADJ_FE`` of
the HWFE and US06 tests.

The vehicle (:func:`mhev_parameters`): the preset ``mhev`` with what the record holds put in as for a
conventional car (:func:`vpsim.fleet.vehicle.record_parameters`: test weight, road load folded over the
cycle, the engine scaled to displacement and cylinders, rated power and boost, the gearbox from N/V and the
axle ratio, the fleet's wheel radius, driveline efficiency and measured idle), the machine of its layout
(:data:`SYSTEMS`): a P0 on the belt at the preset's ratio 2.7 and efficiency 0.95, a P1 on the crank (ratio
1, no belt); the preset's 48 V pack (13 cells in series; 4 for a 12 V system) with as many strings as the
machine's power needs at the cell's limit (:func:`vpsim.fleet.hev.pack_strings`). Energy management: ECMS.

Technology per class (``mhev_p0``, ``mhev_p1``: the layouts; :data:`TECH_PARAMS`, fitted out of fold by
family as the other classes): ``engine.thermal_efficiency``, ``electric.accessory_power`` and
``engine.friction_coefficient`` (the conventional classes' engine parameters, :mod:`vpsim.fleet.calibrate`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from . import calibrate as cal
from .epa import (
    BOOST_SPECIFIC_POWER_KW_PER_L,
    HP_TO_KW,
    TRANSMISSION_KIND,
    CertificationRecord,
)
from .techgrid import TechGrid, ThirdAxis

MHEV_CYCLES = ("ftp_bag2", "ftp_bag3", "hwy", "us06")
CLASSES = ("mhev_p0", "mhev_p1")
PRESET = "mhev"


@dataclass(frozen=True)
class System:
    """A maker's mild-hybrid system: layout, machine power (kW), pack voltage class, the source."""

    layout: str  # mhev_p0 (belt) or mhev_p1 (crank)
    machine_kw: float
    cells_in_series: int
    source: str
    # the share of the machine's motoring torque the system gives as assist (params.mild.assist_share): 1
    # where the maker publishes a boost of the machine's size, less where it publishes a smaller one, 0 where
    # it publishes recuperation, starts and coasting only
    assist_share: float = 1.0


V48, V12 = 13, 4  # cells in series of the nmc_hev cell: 48 V and 12 V nominal
# The published assist where it is less than the machine's motoring envelope, as a share of it, and the 12 V
# system's published recuperation power: looked up after the 2026-12-07 run had Audi's 6- and 8-cylinder
# cars 10-14 % too frugal in town and on US06 (until then every system assisted with its whole machine and
# the 12 V machine was 3 kW, a 12 V machine's current); fleet/tuned.py declares both, docs/fleet.md has
# the figures
ASSIST_SHARE = {"audi48": 0.0, "audi_a3": 0.75, "audi12": 0.2}
AUDI_12V_MACHINE_KW = 5.0
SYSTEMS = {
    "mercedes": System("mhev_p1", 16.0, V48, "Mercedes-Benz EQ Boost ISG (P1), 16 kW / 250 Nm"),
    "bmw": System("mhev_p0", 8.0, V48, "BMW 48 V starter-generator (P0), 8 kW"),
    "audi48": System(
        "mhev_p0",
        12.0,
        V48,
        "Audi 48 V belt alternator starter (P0), 12 kW recuperation, no assist published",
        ASSIST_SHARE["audi48"],
    ),
    "audi_a3": System(
        "mhev_p0",
        12.0,
        V48,
        "Audi A3 48 V belt alternator starter (P0), 12 kW, 9 kW assist",
        ASSIST_SHARE["audi_a3"],
    ),
    "audi12": System(
        "mhev_p0",
        AUDI_12V_MACHINE_KW,
        V12,
        "Audi 12 V MHEV belt starter-generator (P0), 5 kW, 1 kW assist",
        ASSIST_SHARE["audi12"],
    ),
    "volvo": System("mhev_p0", 10.0, V48, "Volvo 48 V ISGM on the belt (P0), 10 kW"),
    "etorque": System("mhev_p0", 12.0, V48, "RAM/Jeep eTorque belt motor-generator (P0), the preset's 12 kW"),
    "jlr": System("mhev_p0", 12.0, V48, "Jaguar Land Rover 48 V BiSG (P0), the preset's 12 kW"),
}
# a P1's machine sits on the crank: its base speed where 250 Nm meet 16 kW, its top speed the engine's
P1_BASE_SPEED = 64.0  # rad/s (16 kW / 250 Nm)
P1_MAX_SPEED = 700.0  # rad/s (6,700 rpm)
P1_INERTIA = 0.04  # kg m^2: a disc rotor of some 0.25 m between engine and gearbox (reconstructed)

# --- technology: three parameters, the conventional classes' -----------------------------------------------
# the engine's indicated efficiency and friction coefficient, as the conventional classes fit them
# (vpsim.fleet.calibrate), and the accessories' power, on the electric network (the 12 V loads, and what else
# costs fuel per second). The friction was the preset's (hofman2011, 1.34) until the mild hybrids' own
# friction was fitted out of fold like the conventional cars' (docs/fleet.md, "Mild hybrids")
# whether a torque-converter automatic (codes A, SA) gets its converter in the model (the crank its pump below
# lock-up, vpsim.model.hybrid.p2_interval) or, as the fleet runs, a clutch that slips below idle speed:
# compared out of fold after the mild hybrids' bag 2 errors were looked into, not kept (fleet/tuned.py;
# docs/fleet.md, "Mild hybrids"); benchmarks/mhev_oof.py --converter runs it
CONVERTER = False
TECH_PARAMS = ("engine.thermal_efficiency", "electric.accessory_power", "engine.friction_coefficient")
# the full hybrids' efficiency axis: 0.30-0.50 was set first, and the fit on the first 20 mild hybrids sat
# on its 0.50 (fleet/tuned.py declares the change)
EFFICIENCY_AXIS = np.array([0.34, 0.38, 0.42, 0.46, 0.50, 0.54])
EFFICIENCY_FINE = np.round(np.arange(0.34, 0.54001, 0.0025), 5)
ACCESSORY_NODES_W = (0.0, 1000.0)
ACCESSORY_AXIS = np.arange(0.0, 3000.1, 25.0)  # the conventional classes' accessory range (calibrate)
FRICTION_AXIS = cal.FRICTION_AXIS  # the conventional classes' friction nodes (0.1-2.9) and search
FRICTION_FINE = np.round(np.linspace(FRICTION_AXIS[0], FRICTION_AXIS[-1], cal.FINE), 5)
BOUND_REASONS = {
    ("engine.thermal_efficiency", "low"): "0.34 indicated efficiency is below any 2022 engine's",
    ("engine.thermal_efficiency", "high"): "0.54 indicated efficiency is beyond the best production engines",
    ("electric.accessory_power", "low"): "no accessory load is the physical lower end",
    ("electric.accessory_power", "high"): "3 kW is the conventional classes' bound (vpsim.fleet.calibrate)",
    ("engine.accessory_power", "low"): "no accessory load is the physical lower end",
    ("engine.accessory_power", "high"): "3 kW is the conventional classes' bound (vpsim.fleet.calibrate)",
    ("engine.friction_coefficient", "low"): cal.BOUND_REASONS[("engine.friction_coefficient", "low")],
    ("engine.friction_coefficient", "high"): "2.9 is the conventional classes' bound (vpsim.fleet.calibrate)",
}


@dataclass(frozen=True)
class MHEVRecord(CertificationRecord):
    """What the certification record says about one mild-hybrid test vehicle (record units)."""

    vehicle_id: str
    configuration: int
    make: str
    model: str
    manufacturer: str
    displacement_l: float
    cylinders: int
    rated_hp: float
    transmission_code: str
    transmission_kind: str
    n_gears: int
    lockup: bool
    drive: str
    etw_lb: float
    axle_ratio: float
    nv_ratio: float
    target_a_lbf: float
    target_b_lbf_per_mph: float
    target_c_lbf_per_mph2: float
    boosted: bool
    boost_rule: str
    system: str  # a key of SYSTEMS
    layout: str  # mhev_p0 or mhev_p1
    bag_rule: str  # how the FTP's bags were read
    measured_mpg: dict[str, float] = field(default_factory=dict)
    n_tests: dict[str, int] = field(default_factory=dict)
    cylinders_source: str = ""  # "" where the record gives the count (vpsim.fleet.epa.fill_cylinders)

    powertrain = "mhev"

    @property
    def specific_power_kw_per_l(self) -> float:
        return self.rated_power_kw / self.displacement_l


AUDI_12V = re.compile(r"\b(A4|A5|A6|Q5)\b|allroad", re.IGNORECASE)


def system_of(make: str, model: str, displacement_l: float) -> tuple[str | None, str]:
    """(a key of :data:`SYSTEMS` or None, the rule or the exclusion reason) by the module's table."""
    mk = make.strip().upper()
    if mk == "MERCEDES-BENZ":
        return "mercedes", "Mercedes-Benz: EQ Boost"
    if mk == "BMW":
        return "bmw", "BMW: 48 V starter-generator"
    if mk == "AUDI":
        if math.isfinite(displacement_l) and displacement_l >= 2.5:
            return "audi48", "Audi 2.9-4.0 L: 48 V MHEV"
        if re.search(r"\bA3\b", model, re.IGNORECASE):
            return "audi_a3", "Audi A3: 48 V MHEV"
        if AUDI_12V.search(model):
            return "audi12", "Audi 2.0 L (A4, A6, Q5): 12 V MHEV"
    if mk == "VOLVO":
        return "volvo", "Volvo B5/B6: 48 V ISGM"
    if mk in ("RAM", "JEEP"):
        return "etorque", "RAM/Jeep: eTorque"
    if mk in ("JAGUAR", "LAND ROVER", "RANGE ROVER"):
        return "jlr", "Jaguar Land Rover: 48 V BiSG"
    from ..textio import printable

    return (
        None,
        f"mild hybrid, no known system: {printable(make)} {printable(model)} (none published)",
    )


def _bags(t: dict) -> tuple[dict[str, float], str] | str:
    """{ftp_bag2, ftp_bag3: mpg} of one FTP test row and how they were read, or why not."""
    from .epa import _plausible_mpg
    from .hev import BAG_MILES, COLD_WEIGHT, COMPOSITE_TOLERANCE

    b = [t[f"bag{i}"] for i in (1, 2, 3, 4)]
    if not (_plausible_mpg(b[1]) and _plausible_mpg(b[2])):
        return "FE Bag 2 or FE Bag 3 missing or implausible"
    if not math.isfinite(b[3]):
        return {"ftp_bag2": b[1], "ftp_bag3": b[2]}, "3-bag FTP: bags 2 and 3"
    if not (all(_plausible_mpg(x) for x in b) and _plausible_mpg(t["fe"])):
        return "4-bag FTP with a bag or RND_ADJ_FE missing or implausible"
    m1, m2 = BAG_MILES
    cold = (m1 + m2) / (m1 / b[0] + m2 / b[1])
    hot = (m1 + m2) / (m1 / b[2] + m2 / b[3])
    comp = 1.0 / (COLD_WEIGHT / cold + (1.0 - COLD_WEIGHT) / hot)
    if abs(comp / t["fe"] - 1.0) > COMPOSITE_TOLERANCE:
        return (
            f"FTP bags give a composite {comp:.4g} mpg, RND_ADJ_FE {t['fe']:g}: not within "
            f"{100 * COMPOSITE_TOLERANCE:g} %"
        )
    return {"ftp_bag2": b[1], "ftp_bag3": b[2]}, "4-bag FTP: bags 2 and 3 (composite checked)"


def mhev_vehicle(vid: str, cfg: int, tests: list[dict]) -> tuple[MHEVRecord | None, str, list[dict]]:
    """(record or None, exclusion reason, excluded test rows) of one mild hybrid's parsed test rows."""
    from .epa import RECORD_FIELDS, record_fields
    from .hybrids import read_tests

    first = tests[0]
    key, rule = system_of(first["make"], first["model"], first["displacement_l"])
    if key is None:
        return None, rule, []
    fields, figures = (*RECORD_FIELDS, "nv_ratio"), "no FTP bag, HWY or US06 figure"
    values, hows, first, test_rows, why = read_tests(
        tests, MHEV_CYCLES, _bags, "mild hybrid", fields, figures
    )
    if why:
        return None, why, test_rows
    code = first["transmission_code"].upper()
    kind = TRANSMISSION_KIND.get(code, "other")
    n_gears = first["n_gears"]
    if kind in ("cvt", "other") or not (
        math.isfinite(n_gears) and n_gears == int(n_gears) and 4 <= n_gears <= 12
    ):
        return None, f"mild hybrid, no stepped gearbox: code {code or 'empty'}, {n_gears:g} gears", test_rows
    axle = first["axle_ratio"]
    if not (math.isfinite(axle) and 1.5 <= axle <= 8.0):
        axle = math.nan
    spec = first["rated_hp"] * HP_TO_KW / first["displacement_l"]
    boosted = spec > BOOST_SPECIFIC_POWER_KW_PER_L
    sys_ = SYSTEMS[key]
    rec = MHEVRecord(
        **record_fields(vid, cfg, first, values),
        transmission_kind=kind,
        n_gears=int(n_gears),
        lockup=first["lockup"].upper() == "Y",
        axle_ratio=axle,
        boosted=boosted,
        boost_rule=f"specific power {spec:.1f} kW/L, {BOOST_SPECIFIC_POWER_KW_PER_L:g} the threshold",
        system=key,
        layout=sys_.layout,
        bag_rule="; ".join(sorted(hows)) + f"; {rule}",
    )
    return rec, "", test_rows


# --- the vehicle ------------------------------------------------------------------------------------------


def mhev_parameters(rec: MHEVRecord, cycle_name: str | None = None, technology: dict | None = None):
    """The mild hybrid's :class:`~vpsim.params.Parameters` of a record (road load folded over the cycle
    ``cycle_name``, default all four); ``technology`` overrides (:data:`TECH_PARAMS`)."""
    from dataclasses import replace

    from ..errors import VpsimError
    from ..params import load_parameters
    from ..scaling import scaled_machine
    from .cycles import FLEET_CYCLES, fleet_cycle
    from .hev import pack_strings
    from .vehicle import CONVERTER_KEYS, record_parameters

    names = MHEV_CYCLES if cycle_name is None else (cycle_name,)
    cycles = [fleet_cycle(c) for c in names if c in FLEET_CYCLES]
    # the conventional car of the record (engine, boost, gearbox, road load, idle), with its torque converter
    # where CONVERTER (else the clutch slips below idle speed), the accessories on the electric network
    conv = record_parameters(rec, cycles, {"engine.accessory_power": 0.0}, converter=CONVERTER)
    base = load_parameters(PRESET)
    sys_ = SYSTEMS[rec.system]
    machine_w = sys_.machine_kw * 1e3
    machine = scaled_machine(base.machine, machine_w)
    mild = {"assist_share": sys_.assist_share}
    if sys_.layout == "mhev_p1":
        machine.update(base_speed=P1_BASE_SPEED, max_speed=P1_MAX_SPEED, inertia=P1_INERTIA)
        mild.update(belt_ratio=1.0, belt_efficiency=1.0)
    battery_base = base.with_changes(battery={"cells_in_series": sys_.cells_in_series})
    strings = pack_strings(battery_base, machine_w)
    flat = conv.flat()
    sections: dict[str, dict] = {
        "vehicle": {k: flat[f"vehicle.{k}"] for k in _VEHICLE},
        "transmission": {
            k: _plain(flat[f"transmission.{k}"])
            for k in (*_TRANSMISSION, *(CONVERTER_KEYS if CONVERTER else ()))
        },
        "engine": {k: _plain(flat[f"engine.{k}"]) for k in _ENGINE},
        "simulation": {k: flat[f"simulation.{k}"] for k in _SIMULATION},
        "machine": machine,
        "battery": {"cells_in_series": sys_.cells_in_series, "cells_in_parallel": strings},
        "electric": {},
    }
    sections["mild"] = mild
    for key, value in (technology or {}).items():
        sec, _, fld = key.partition(".")
        if sec not in sections:
            raise VpsimError(f"technology parameter {key!r} is not section.field")
        sections[sec][fld] = value
    p = base.with_changes(**sections)
    return replace(p, name=f"{rec.make} {rec.model} ({rec.key})")


_VEHICLE = ("mass", "frontal_area", "drag_coefficient", "rolling_resistance", "air_density", "wheel_radius")
_VEHICLE += ("road_load_a", "road_load_b", "road_load_c")
_TRANSMISSION = ("efficiency", "gearbox_ratios", "final_drive", "shift_engine_speed")
_ENGINE = ("bore", "stroke", "cylinders", "inertia", "intake_manifold_volume", "max_throttle_area")
_ENGINE += ("min_throttle_area", "map_speed_range", "fuel_heating_value", "rated_power", "boost_pressure")
_ENGINE += ("boost_enrichment",)
_SIMULATION = ("fuel_density", "idle_fuel_flow", "fuel_cutoff_speed")


def _plain(v):
    return list(v) if isinstance(v, tuple) else v


def mhev_class(rec: MHEVRecord) -> str:
    """The technology class: the layout (``mhev_p0`` on the belt, ``mhev_p1`` on the crank)."""
    return rec.layout


def family_labels(rec: MHEVRecord):
    """The labels that join mild-hybrid records into one family (:func:`vpsim.fleet.hev.family_labels`)."""
    from .hev import family_labels as labels

    return labels(rec)


# --- technology fit ----------------------------------------------------------------------------------------


def _cycle(name: str):
    """The fleet cycle of the test ``name``."""
    from .cycles import fleet_cycle

    return fleet_cycle(name)


def grid_chunk(items: list[tuple[MHEVRecord, tuple[str, ...]]]) -> list[dict]:
    """Backward ECMS runs of each (record, tests) at every efficiency and friction node and both accessory
    nodes: ``log_fuel`` (len(EFFICIENCY_AXIS), len(FRICTION_AXIS), 2) of ln charge-sustaining L/100 km, or
    ``error``; the vehicle is built per test (its road load folded over that cycle)."""
    from .hybrids import cs_fuel_of

    return TECH.grid_chunk(items, mhev_parameters, cs_fuel_of(_cycle), "log_fuel", "fuel", per_test=True)


# (efficiency, accessories) at one friction, the friction its third axis: at each friction of FRICTION_FINE,
# ln fuel is interpolated linearly in the friction between its nodes (the friction mean effective pressure is
# linear in the coefficient, as the conventional grid takes it)
def fit_accessories_on(where: str) -> None:
    """Where the fitted accessory load sits: ``"electric"`` (the electric network, as the fleet runs) or
    ``"engine"`` (the crank, ``engine.accessory_power``, while the engine turns; the electric network then
    keeps the preset's load). Tried out of fold on 2026-12-07 and not kept (docs/fleet.md, "Mild hybrids";
    ``benchmarks/mhev_oof.py --crank-accessories``). Sets :data:`TECH_PARAMS` and the grid in this process."""
    global TECH_PARAMS, GRID, TECH, fit, search_bounds, on_bounds
    if where not in ("electric", "engine"):
        raise ValueError(f"accessories on {where!r}: expected 'electric' or 'engine'")
    TECH_PARAMS = (TECH_PARAMS[0], f"{where}.accessory_power", TECH_PARAMS[2])
    GRID = TechGrid(
        TECH_PARAMS[:2], EFFICIENCY_AXIS, EFFICIENCY_FINE, ACCESSORY_NODES_W, ACCESSORY_AXIS, "mild hybrid"
    )
    TECH = ThirdAxis(TECH_PARAMS[2], FRICTION_AXIS, FRICTION_FINE, GRID)
    fit, search_bounds, on_bounds = TECH.fit, TECH.search_bounds, TECH.on_bounds


fit_accessories_on("electric")


def predict_chunk(items: list[tuple[MHEVRecord, str, dict]]) -> list[dict]:
    """One backward ECMS run per (record, test, technology): ``l_per_100km_cs``, ``trace_miss_s``, or
    ``error``."""
    from . import hybrids

    return hybrids.predict_chunk(items, TECH_PARAMS, mhev_parameters, _cycle)


__all__ = [
    "CLASSES",
    "MHEVRecord",
    "MHEV_CYCLES",
    "SYSTEMS",
    "TECH_PARAMS",
    "family_labels",
    "mhev_class",
    "mhev_parameters",
    "mhev_vehicle",
    "system_of",
]


# --- the vehicle file ---------------------------------------------------------------------------------------

TOML_FIELDS = (
    ("vehicle", _VEHICLE),
    ("transmission", _TRANSMISSION),
    ("engine", (*_ENGINE, "thermal_efficiency", "friction_coefficient", "accessory_power")),
    ("machine", ("rated_power", "base_speed", "max_speed", "kind", "inertia")),
    ("battery", ("cell", "cells_in_series", "cells_in_parallel", "soc_initial", "soc_min", "soc_max")),
    ("electric", ("accessory_power",)),
    ("simulation", _SIMULATION),
    ("hybrid", ("ems", "soc_target")),
    ("mild", ("belt_ratio", "belt_efficiency", "assist_share")),
)


def mhev_vehicle_toml(rec: MHEVRecord, params, source: str = "", technology_note: str = "") -> str:
    """An editable mild-hybrid TOML (``vpsim simulate --vehicle``, type ``mhev``) with the record block;
    ``[record.measured_mpg]`` holds the fleet's tests (``ftp_bag2``, ``ftp_bag3``, ``hwy``, ``us06``), which
    ``vpsim simulate`` compares with the charge-sustaining figure."""
    from ..textio import printable
    from .vehicle import cylinders_note, hybrid_sections, record_block, toml_head, with_record_block

    sys_ = SYSTEMS[rec.system]
    notes = {
        "engine.bore": "record: displacement and cylinders" + cylinders_note(rec),
        "engine.rated_power": "record: rated power (W)",
        "engine.thermal_efficiency": technology_note or "the preset's",
        "engine.friction_coefficient": technology_note or "the preset's",
        "electric.accessory_power": technology_note or "the preset's (W)",
        "machine.rated_power": f"{sys_.source} (vpsim.fleet.mhev.SYSTEMS; W)",
        "battery.cells_in_parallel": "the preset's cell, strings for the machine's rated power",
        "transmission.final_drive": "record: N/V and axle ratio",
    }
    about = [printable(f"# mild hybrid {rec.layout}: {sys_.source}")]
    lines = toml_head(rec, source, "mhev", PRESET, params.name, about, "mhev")
    lines += hybrid_sections(params, TOML_FIELDS, notes)
    block = record_block(
        rec,
        rec.road_load_si,
        "measured_mpg",
        dict(rec.measured_mpg),
        "unadjusted; ftp_bag2 / ftp_bag3 = FE Bag 2 / 3 of the 4-bag FTP, compared charge-sustaining",
        {"powertrain": "mhev", "layout": rec.layout},
    )
    return with_record_block(lines, block)
