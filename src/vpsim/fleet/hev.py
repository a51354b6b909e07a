"""The full-hybrid records of a test car list: reader, layout, vehicle mapping, the hybrids' technology.

Which records (:func:`hev_vehicle`): the vehicles :mod:`vpsim.fleet.epa` flags ``hybrid`` (by name, or by
their town-versus-highway fuel economy). Each gets a layout (:func:`layout`), the first rule that applies:

* a plug-in by name (``PHEV``, ``Prime``, ``Plug-in``, a Lexus ``450h+``), or a series range-extender
  (Karma Revero): excluded (``hybrid, plug-in``), its charge-sustaining test alone does not say what it is;
* Honda and Acura (two-motor e:HEV / i-MMD series-parallel; the NSX's three motors): excluded, no built
  layout fits (``hybrid, no built layout``);
* Lexus LC 500h and LS 500h (the Multi Stage Hybrid: a power split followed by a 4-speed gearbox):
  excluded the same way;
* Toyota, Lexus, Ford, Lincoln with a ``CVT`` or ``SCV`` transmission code: ``hev_split`` (Toyota Hybrid
  System, Ford's eCVT in the Escape, Maverick and Corsair; one planetary gear set, the record's CVT is that
  set);
* Hyundai and Kia, and Ford and Toyota with a stepped gearbox (codes ``A``, ``SA``, ``AM``, ``AMS``; the
  Explorer, F-150 PowerBoost and Police Interceptor's 10-speed with a machine in its housing, the Tundra
  i-FORCE MAX's 10-speed): ``hev_p2`` (engine, disconnect clutch, machine, gearbox);
* any other: excluded (``hybrid, no built layout``).

The tests (the 2022 list's hybrid rows, read for this module): the FTP of a hybrid is the 4-bag FTP
(``Federal fuel 2-day exhaust``, test category FTP): bag 1 the cold 505 s, bag 2 the stabilised 867 s,
bag 3 the hot 505 s, bag 4 the stabilised 867 s again; ``FE Bag 1``..``FE Bag 4`` are each bag's mpg,
uncorrected for the battery's charge change, and a single bag is far from charge-sustaining (the Elantra
Hybrid's bag 2: 142 mpg, bag 4: 68 mpg). Ford's records give two figures instead: ``FE Bag 1`` the cold
UDDS (bags 1+2) and ``FE Bag 2`` the hot UDDS (bags 3+4). ``RND_ADJ_FE`` of the FTP is the composite,
0.43 cold UDDS + 0.57 hot UDDS in fuel per distance. What is compared, ``udds_hot``: the hot-start UDDS,
bags 3 and 4 together (their fuel per distance weighted by the bags' distances, 3.59 and 3.91 mi), or
Ford's bag 2; used only where the cold UDDS from the other bags and this hot UDDS give the test's composite
``RND_ADJ_FE`` within :data:`COMPOSITE_TOLERANCE` (the check that the bags were read as what they are). Its
net charge change over the two bags is small where a single bag's is not; the model runs the whole UDDS warm
and reports the charge-sustaining figure (``fuel_l_per_100km_cs``). Bag 2 and bag 3 alone are not compared:
their charge swing, not the powertrain, sets their figure. ``hwy``: ``RND_ADJ_FE`` of the HWFE test;
``us06``: of the US06 test (both uncorrected, as the model's charge-sustaining figure is corrected). Tests
on certification gasoline only; repeated tests averaged in fuel per distance.

The vehicle (:func:`hev_parameters`), from the layout's preset (``hev_split`` after the Corolla Hybrid,
``hev_p2`` after the Ioniq Hybrid; their sources are in the presets), what the record holds replacing it:

* test weight, target road load A/B/C (as the conventional cars), engine displacement and cylinders (bore
  and stroke as :func:`vpsim.fleet.vehicle.bore_stroke`, the engine scaled by :func:`vpsim.scaling.
  scale_engine`), rated power = the engine's (the record's rated horsepower is the engine's for these cars:
  Corolla 96 hp, Ioniq 104 hp, Tundra 389 hp; not the system's) and, above
  :data:`vpsim.fleet.epa.BOOST_SPECIFIC_POWER_KW_PER_L`, boost as for a conventional car;
* the machines, which the record does not hold, by a rule set from public specifications before any
  vpsim hybrid result: a power split's traction machine (MG2) and generator (MG1) scale with the engine's
  rated power over the preset's (Toyota: Corolla 96 hp / 53 kW, Camry and RAV4 176 hp / 88 kW, Highlander
  186 hp / 134 kW: the machines grow with the engine, MG1 must hold its torque); a P2's machine with the
  test weight over the preset's, within :data:`P2_MACHINE_SCALE` of it (Ioniq 3,250 lb / 32 kW, Sorento
  4,500 lb / 44 kW, but F-150 6,000 lb / 35 kW, Tundra 6,000 lb / 36 kW: the P2 machines of the list are
  32-47 kW whatever the car);
* the battery: the preset's pack (hybrid packs are 0.75-1.9 kWh across the range, by the makers'
  specifications: Prius 0.75 / 1.31, Corolla 1.31, Camry 1.0-1.6, RAV4 1.59, Highlander and Sienna 1.9,
  Escape and Maverick 1.1, Ioniq 1.56, Sonata 1.76, Tucson 1.49, F-150 1.5, Tundra 1.87 kWh): the preset's
  one string for either layout (:func:`battery_strings`; the power split's 1.31 kWh, the P2's 1.54 kWh). A
  split's pack sized to MG2's rating had been 6.6 kWh for the Camry; a P2's sized to its machine's rated
  power at the cell's discharge limit (:func:`pack_strings`) had been two strings, 3.1 kWh, for every P2 of
  the list, the Ioniq itself included (one string gives 31 kW at the cell's 20 C against its 32 kW machine);
* the machines' losses: the loss model (:mod:`vpsim.model.machine`, fitted on 1990s maps) times
  ``machine.loss_scale``, fitted per class (below); without a fleet fit :data:`MACHINE_LOSS_SCALE`, the level
  the 2022 single-machine permanent-magnet EVs' drive units fit out of fold (``vpsim fleet``, class ``bev``:
  0.14-0.15 in every fold); MG1 of a split shares it;
* transmission: a power split's ring-to-wheel ratio is the record's axle ratio where plausible
  (:data:`SPLIT_AXLE_RANGE`), else the preset's; the wheel radius the fleet's default; a P2's gearbox as a
  conventional car's of the same code and gears (:func:`vpsim.fleet.vehicle.gear_ratios`, from N/V and the
  axle ratio);
* energy management: ECMS (the presets'), the charge-sustaining figure reported.

Technology per class (:data:`CLASSES`; :data:`TECH_PARAMS`, fitted out of fold by family folds as the other
classes): ``engine.thermal_efficiency`` (the engine's efficiency level), ``electric.accessory_power`` (the
12 V loads the DC/DC converter feeds, pumps) and ``machine.loss_scale`` (the electric path's loss level,
searched in the EV class's range; :data:`MACHINE_LOSS_SCALE` is the level a vehicle file takes without a
fleet fit).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from .epa import (
    BOOST_SPECIFIC_POWER_KW_PER_L,
    HP_TO_KW,
    TRANSMISSION_KIND,
    CertificationRecord,
)
from .ev import BOUND_REASONS as EV_BOUND_REASONS
from .ev import LOSS_SCALE_FINE
from .techgrid import TechGrid, ThirdAxis

HEV_CYCLES = ("udds_hot", "hwy", "us06")
# measured test -> vpsim cycle the model runs (the hot UDDS is the whole UDDS, run warm)
SIM_CYCLE = {"udds_hot": "udds", "hwy": "hwfet", "us06": "us06"}
# the technology classes (:func:`hev_class`): the layouts, the P2 split by its gearbox after the one P2
# class's errors were seen (fleet/tuned.py declares it)
CLASSES = ("hev_split", "hev_p2", "hev_p2_converter")
CONVERTER_CODES = ("A", "SA")  # a torque-converter automatic (the trucks' longitudinal 10-speeds)
PRESET = {"hev_split": "hev_split", "hev_p2": "hev_p2"}  # layout -> preset
COMPOSITE_TOLERANCE = 0.03  # |composite from the bags / RND_ADJ_FE - 1|: the rounding and the adjustment
COLD_WEIGHT = 0.43  # the FTP composite's weights (40 CFR 600.113): 0.43 cold UDDS, 0.57 hot UDDS
BAG_MILES = (3.59, 3.91)  # the 505 s and the 867 s phase of the UDDS
SPLIT_AXLE_RANGE = (2.5, 4.5)  # a power split's final drive (Corolla 2.834, Camry 3.542, Highlander 3.605)
PLUGIN_NAME = re.compile(r"\bphev\b|\bprime\b|plug-in|\d{3}h\+|revero", re.IGNORECASE)
NO_LAYOUT_MAKES = {
    "HONDA": "two-motor series-parallel (e:HEV / i-MMD)",
    "ACURA": "two-motor series-parallel or the NSX's three motors",
}
MULTI_STAGE = re.compile(r"\b(LC|LS) 500h\b", re.IGNORECASE)
SPLIT_MAKES = ("TOYOTA", "LEXUS", "FORD", "LINCOLN")
P2_MAKES = ("HYUNDAI", "KIA", "FORD", "TOYOTA")
STEPPED_CODES = ("A", "SA", "AM", "AMS")
SPLIT_CODES = ("CVT", "SCV")  # SCV: the selectable CVT (the RAV4 Hybrid's "sequential shiftmatic")
# a P2's machine: 32-47 kW on the 2022 list whatever the car's size (Ioniq 32, Sonata 38, Tucson, Santa Fe
# and Sorento 44, Explorer 35, F-150 35, Tundra 36 kW): the preset's x the test-weight ratio, within
# this range of the preset's (set from those specifications; the uncapped ratio gave the trucks 57-64 kW)
P2_MACHINE_SCALE = (1.0, 1.4)
MPG_RANGE = (5.0, 150.0)
CELL_STRING_MARGIN = 1.0  # the pack gives the machine's rated power at the cell's discharge limit
# the hybrids' machine and inverter losses times this: the 2022 single-machine PM EVs' fitted drive-loss level
# (vpsim.fleet.ev class bev, 0.14-0.15 in every out-of-fold fit of the 2022 list); fleet/tuned.py declares it
MACHINE_LOSS_SCALE = 0.15

# --- technology: three parameters, the first two's search bounds set before any vpsim hybrid result --------
# the third, the machines' loss level, was the EV fit's fixed 0.15 (MACHINE_LOSS_SCALE) until the P2s' errors
# were seen to fall with higher losses (a trial of one value, 2, out of fold); it is fitted per class since,
# in the EV class's search range set before any hybrid result (vpsim.fleet.ev; fleet/tuned.py declares it)
TECH_PARAMS = ("engine.thermal_efficiency", "electric.accessory_power", "machine.loss_scale")
EFFICIENCY_AXIS = np.array([0.34, 0.38, 0.42, 0.46, 0.50, 0.54])
EFFICIENCY_FINE = np.round(np.arange(0.34, 0.54001, 0.0025), 5)
ACCESSORY_NODES_W = (0.0, 1000.0)
ACCESSORY_AXIS = np.arange(0.0, 1500.1, 25.0)
BOUND_REASONS = {
    ("engine.thermal_efficiency", "low"): "0.34 indicated efficiency is below any hybrid's Atkinson engine",
    ("engine.thermal_efficiency", "high"): "0.54 indicated efficiency is beyond the best production engines",
    ("electric.accessory_power", "low"): "no accessory load is the physical lower end",
    ("electric.accessory_power", "high"): "1.5 kW with climate control off is beyond a car's 12 V loads",
    # the loss level's search range and its reasons are the EV class's
    **{k: r for k, r in EV_BOUND_REASONS.items() if k[0] == "machine.loss_scale"},
}
# the loss level's run nodes and its fine axis (the EV class's). Between the nodes, ln fuel interpolated is
# within 0.5 % of a real run (one car of each class, its tests, at 0.05-1.25), but 1.3 % once where the
# ECMS's choices jump (a Hyundai P2's highway at 0.35); the reported figures come from real runs
LOSS_SCALE_AXIS = np.array([0.01, 0.15, 0.5, 1.0, 1.5])


@dataclass(frozen=True)
class HEVRecord(CertificationRecord):
    """What the certification record says about one full-hybrid test vehicle (record units)."""

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
    drive: str
    etw_lb: float
    axle_ratio: float
    nv_ratio: float
    target_a_lbf: float
    target_b_lbf_per_mph: float
    target_c_lbf_per_mph2: float
    boosted: bool
    layout: str  # hev_split or hev_p2
    layout_rule: str
    udds_rule: str  # how the hot UDDS was read from the FTP bags
    measured_mpg: dict[str, float] = field(default_factory=dict)
    n_tests: dict[str, int] = field(default_factory=dict)
    cylinders_source: str = ""  # "" where the record gives the count (vpsim.fleet.epa.fill_cylinders)

    powertrain = "hev"

    @property
    def specific_power_kw_per_l(self) -> float:
        return self.rated_power_kw / self.displacement_l


def layout(make: str, model: str, transmission_code: str) -> tuple[str | None, str]:
    """(layout or None, the rule or the exclusion reason) by the module's rules."""
    mk, code = make.strip().upper(), transmission_code.strip().upper()
    if PLUGIN_NAME.search(model):
        return None, f"hybrid, plug-in: {printable_name(make, model)} is a plug-in by its name"
    if mk in NO_LAYOUT_MAKES:
        return None, f"hybrid, no built layout: {printable_name(make, model)}, {NO_LAYOUT_MAKES[mk]}"
    if MULTI_STAGE.search(model):
        return None, (
            f"hybrid, no built layout: {printable_name(make, model)}, a power split followed by a 4-speed "
            "gearbox (Multi Stage Hybrid)"
        )
    if mk in SPLIT_MAKES and code in SPLIT_CODES:
        return "hev_split", f"{mk.title()} with a {code} code: one planetary gear set (power split)"
    if mk in P2_MAKES and code in STEPPED_CODES:
        return "hev_p2", f"{mk.title()} with a stepped gearbox ({code}): machine between clutch and gearbox"
    return None, (
        f"hybrid, no built layout: {printable_name(make, model)} with transmission code {code or 'empty'}"
    )


def printable_name(make: str, model: str) -> str:
    from ..textio import printable

    return printable(f"{make} {model}".strip())[:60]


def _plausible(x: float) -> bool:
    return math.isfinite(x) and MPG_RANGE[0] <= x <= MPG_RANGE[1]


def _pair(mpg_a: float, mpg_b: float) -> float:
    """mpg over a 505 s bag then an 867 s bag (fuel per distance weighted by the bags' distances)."""
    a, b = BAG_MILES
    return (a + b) / (a / mpg_a + b / mpg_b)


def hot_udds(t: dict) -> tuple[float, str] | str:
    """(hot-UDDS mpg, how) of one FTP row, or why not: bags 3 and 4 of a 4-bag FTP, or Ford's two-figure
    form (bag 1 cold UDDS, bag 2 hot UDDS), checked against the test's composite ``RND_ADJ_FE``."""
    b1, b2, b3, b4, comp = t["bag1"], t["bag2"], t["bag3"], t["bag4"], t["fe"]
    if all(_plausible(x) for x in (b1, b2, b3, b4)):
        cold, hot, how = _pair(b1, b2), _pair(b3, b4), "4-bag FTP: bags 3 and 4"
    elif _plausible(b1) and _plausible(b2) and not math.isfinite(b3) and not math.isfinite(b4):
        cold, hot, how = b1, b2, "two-figure FTP: bag 1 cold UDDS, bag 2 hot UDDS"
    else:
        return "FTP bags neither four figures nor the two-figure form"
    if not _plausible(comp):
        return "FTP RND_ADJ_FE missing or implausible"
    c = 1.0 / (COLD_WEIGHT / cold + (1.0 - COLD_WEIGHT) / hot)
    if abs(c / comp - 1.0) > COMPOSITE_TOLERANCE:
        return (
            f"FTP bags give a composite {c:.4g} mpg, RND_ADJ_FE {comp:g}: not within "
            f"{100 * COMPOSITE_TOLERANCE:g} %"
        )
    return hot, how


def _ftp(t: dict) -> tuple[dict[str, float], str] | str:
    """{udds_hot: mpg} of one FTP row and how it was read (:func:`hot_udds`), or why not."""
    got = hot_udds(t)
    return got if isinstance(got, str) else ({"udds_hot": got[0]}, got[1])


def hev_vehicle(vid: str, cfg: int, tests: list[dict]) -> tuple[HEVRecord | None, str, list[dict]]:
    """(record or None, exclusion reason, excluded test rows) of one hybrid's parsed test rows."""
    from .epa import RECORD_FIELDS, _field_problem, record_fields
    from .hybrids import read_tests

    first = tests[0]
    lay, rule = layout(first["make"], first["model"], first["transmission_code"])
    if lay is None:
        return None, rule, []
    figures = "no hot UDDS, HWY or US06 figure"
    values, hows, first, test_rows, why = read_tests(
        tests, HEV_CYCLES, _ftp, "hybrid", RECORD_FIELDS, figures
    )
    if why:
        return None, why, test_rows
    code = first["transmission_code"].upper()
    n_gears = first["n_gears"]
    if lay == "hev_p2":
        if not (math.isfinite(n_gears) and n_gears == int(n_gears) and 4 <= n_gears <= 12):
            return None, f"hybrid, implausible n_gears: {n_gears:g} for a stepped gearbox", test_rows
        problem = _field_problem("nv_ratio", first["nv_ratio"], first["not_a_number"])
        if problem:
            return None, f"hybrid, {problem}", test_rows
    axle = first["axle_ratio"]
    spec = first["rated_hp"] * HP_TO_KW / first["displacement_l"]
    rec = HEVRecord(
        **record_fields(vid, cfg, first, values),
        transmission_kind=TRANSMISSION_KIND.get(code, "other"),
        n_gears=int(n_gears) if lay == "hev_p2" else 1,
        axle_ratio=axle if math.isfinite(axle) else math.nan,
        boosted=spec > BOOST_SPECIFIC_POWER_KW_PER_L,
        layout=lay,
        layout_rule=rule,
        udds_rule="; ".join(sorted(hows)),
    )
    return rec, "", test_rows


# --- the vehicle ------------------------------------------------------------------------------------------


def pack_strings(base, machine_power_w: float) -> int:
    """Strings in parallel of the preset's pack (``base.battery``) that give ``machine_power_w`` at the cell's
    discharge limit at nominal voltage, at least the preset's."""
    from ..model.battery import CELLS

    cell = CELLS[base.battery.cell]
    nominal_v = float(np.mean(cell.ocv_v))
    string_w = base.battery.cells_in_series * nominal_v * cell.capacity_ah * cell.max_discharge_c
    need = math.ceil(CELL_STRING_MARGIN * machine_power_w / string_w)
    return int(max(base.battery.cells_in_parallel, need))


def battery_strings(rec: HEVRecord, base, machine_power_w: float) -> int:
    """The pack's strings in parallel by the module's rule: the preset's (one string, 1.31 kWh for a power
    split, 1.54 kWh for a P2: the makers' hybrid packs are 0.75-1.9 kWh whatever the car). ``rec`` and
    ``machine_power_w`` are kept for the callers; the machine's power is not what sizes a hybrid's pack."""
    if rec.layout not in PRESET:
        raise ValueError(f"unknown hybrid layout {rec.layout!r}")
    return int(base.battery.cells_in_parallel)


def machine_sizes(rec: HEVRecord, base) -> dict[str, float]:
    """The machines' rated powers (W) by the module's rule: ``machine`` and, for a power split,
    ``generator``."""
    if rec.layout == "hev_split":
        k = rec.rated_power_kw * 1e3 / base.engine.rated_power
        return {"machine": base.machine.rated_power * k, "generator": base.split.generator_rated_power * k}
    from ..scaling import mass_ratio

    return {"machine": base.machine.rated_power * mass_ratio(rec.mass_kg, base.vehicle, P2_MACHINE_SCALE)}


def hev_parameters(rec: HEVRecord, technology: dict | None = None):
    """The hybrid :class:`~vpsim.params.Parameters` of a record; ``technology`` overrides."""
    from dataclasses import replace

    from ..cycles import load_cycle
    from ..errors import VpsimError
    from ..params import load_parameters
    from ..scaling import scale_engine, scaled_machine
    from .vehicle import (
        AIR_DENSITY,
        FRONTAL_AREA_M2,
        FUEL_DENSITY_KG_PER_L,
        FUEL_LHV_J_PER_KG,
        MAX_BOOST_PA,
        RATED_SPEED_RADPS,
        WHEEL_RADIUS_M,
        bore_stroke,
        converter_fields,
        fold_road_load,
        gear_ratios,
    )

    base = load_parameters(PRESET[rec.layout])
    a, b, c = rec.road_load_si
    c_r, c_d, _ = fold_road_load(rec, [load_cycle(SIM_CYCLE[x]) for x in HEV_CYCLES])
    bore, stroke = bore_stroke(rec.displacement_l, rec.cylinders)
    eng = scale_engine(base.engine, bore=bore, stroke=stroke, cylinders=rec.cylinders)
    sizes = machine_sizes(rec, base)
    sections = {
        "vehicle": {
            "mass": rec.mass_kg,
            "frontal_area": FRONTAL_AREA_M2,
            "drag_coefficient": c_d,
            "rolling_resistance": c_r,
            "air_density": AIR_DENSITY,
            "wheel_radius": WHEEL_RADIUS_M,
            "road_load_a": a,
            "road_load_b": b,
            "road_load_c": c,
        },
        "engine": {
            "bore": eng.bore,
            "stroke": eng.stroke,
            "cylinders": eng.cylinders,
            "inertia": eng.inertia,
            "intake_manifold_volume": eng.intake_manifold_volume,
            "max_throttle_area": eng.max_throttle_area,
            "min_throttle_area": eng.min_throttle_area,
            "map_speed_range": list(eng.map_speed_range),
            "fuel_heating_value": FUEL_LHV_J_PER_KG,
            "rated_power": rec.rated_power_kw * 1e3,
        },
        "machine": {**scaled_machine(base.machine, sizes["machine"]), "loss_scale": MACHINE_LOSS_SCALE},
        "battery": {"cells_in_parallel": battery_strings(rec, base, sizes["machine"])},
        "electric": {},
        "simulation": {"fuel_density": FUEL_DENSITY_KG_PER_L},
    }
    if rec.layout == "hev_split":
        axle = rec.axle_ratio
        ok = math.isfinite(axle) and SPLIT_AXLE_RANGE[0] <= axle <= SPLIT_AXLE_RANGE[1]
        sections["transmission"] = {"final_drive": axle if ok else base.transmission.final_drive}
        sections["split"] = {"generator_rated_power": sizes["generator"]}
    else:
        ratios, final = gear_ratios(rec)
        # a torque-converter automatic (codes A, SA: Ford's and Toyota's 10-speeds keep their converter
        # between the machine and the gearbox) gets the conventional automatics' converter and lock-up
        sections["transmission"] = {"gearbox_ratios": ratios, "final_drive": final, **converter_fields(rec)}
    for key, value in (technology or {}).items():
        sec, _, fld = key.partition(".")
        if not fld or not hasattr(base, sec):
            raise VpsimError(f"technology parameter {key!r} is not section.field")
        sections.setdefault(sec, {})[fld] = value
    p = base.with_changes(**sections)
    if rec.boosted:
        from ..model import engine as en
        from ..model.record import record
        from .vehicle import BOOST_ENRICHMENT

        cr = record(p)
        boost = float(en.boost_for_power(rec.rated_power_kw * 1e3, RATED_SPEED_RADPS, cr))
        boost = min(max(boost, 1.05 * cr.ambient_pressure), MAX_BOOST_PA)
        p = p.with_changes(engine={"boost_pressure": boost, "boost_enrichment": BOOST_ENRICHMENT})
    return replace(p, name=f"{rec.make} {rec.model} ({rec.key})")


def hev_class(rec: HEVRecord) -> str:
    """The technology class: ``hev_split``; ``hev_p2_converter`` for a P2 with a torque-converter automatic
    (transmission code ``A`` or ``SA``: the Explorer, F-150 and Police Interceptor's 10R80-based and the
    Tundra's 10-speed, longitudinal, a large engine; the model's P2 has no converter, and the converter's
    slip at launch and its pump are in this class's technology); else ``hev_p2`` (Hyundai/Kia: a
    6-speed with the machine in place of a converter)."""
    if rec.layout == "hev_p2" and rec.transmission_code.upper() in CONVERTER_CODES:
        return "hev_p2_converter"
    return rec.layout


def family_labels(rec: HEVRecord):
    """The labels that join hybrid records into one family: the same test vehicle; the same manufacturer,
    model (wheel and trim notes dropped) and engine; or equal in every field the model reads."""
    model = re.sub(r"\(.*?\)", "", rec.model).strip().upper()
    inputs = (
        rec.etw_lb,
        rec.target_a_lbf,
        rec.target_b_lbf_per_mph,
        rec.target_c_lbf_per_mph2,
        rec.rated_hp,
        rec.displacement_l,
        rec.axle_ratio,
        rec.nv_ratio,
    )
    return (
        ("vehicle", rec.vehicle_id),
        ("family", rec.manufacturer.strip().upper(), model, rec.displacement_l, rec.cylinders),
        ("inputs", inputs),
    )


__all__ = [
    "CLASSES",
    "HEVRecord",
    "HEV_CYCLES",
    "TECH_PARAMS",
    "family_labels",
    "hev_class",
    "hev_parameters",
    "hev_vehicle",
    "hot_udds",
    "layout",
]


# --- the vehicle file ---------------------------------------------------------------------------------------

TOML_FIELDS = (
    (
        "vehicle",
        ("mass", "frontal_area", "drag_coefficient", "rolling_resistance", "air_density", "wheel_radius")
        + ("road_load_a", "road_load_b", "road_load_c"),
    ),
    ("transmission", ("efficiency", "gearbox_ratios", "final_drive")),
    (
        "engine",
        ("bore", "stroke", "cylinders", "inertia", "intake_manifold_volume", "max_throttle_area")
        + ("min_throttle_area", "map_speed_range", "fuel_heating_value", "thermal_efficiency", "rated_power")
        + ("boost_pressure", "boost_enrichment", "accessory_power"),
    ),
    ("machine", ("rated_power", "base_speed", "max_speed", "kind", "inertia", "loss_scale")),
    ("battery", ("cell", "cells_in_series", "cells_in_parallel", "soc_initial", "soc_min", "soc_max")),
    ("electric", ("accessory_power",)),
    ("simulation", ("fuel_density",)),
    ("hybrid", ("ems", "soc_target", "ecms_min_on_time")),
    (
        "split",
        ("sun_teeth", "ring_teeth", "mg2_ratio", "engine_max_speed", "generator_rated_power")
        + ("generator_base_speed", "generator_max_speed", "generator_inertia"),
    ),
)
# the measured tests under the names ``vpsim simulate --cycle`` gives the cycle the model runs
TOML_TEST_NAME = {"udds_hot": "udds", "hwy": "hwy", "us06": "us06"}


def hev_vehicle_toml(rec: HEVRecord, params, source: str = "", technology_note: str = "") -> str:
    """An editable hybrid TOML (``vpsim simulate --vehicle``, type ``hev_split`` or ``hev_p2``) with the
    record block; ``[record.measured_mpg]`` holds ``udds`` (the hot UDDS, FTP bags 3 + 4), ``hwy``, ``us06``:
    ``vpsim simulate`` compares them with the charge-sustaining figure."""
    from ..textio import printable
    from .vehicle import cylinders_note, hybrid_sections, record_block, toml_head, with_record_block

    sizes = "the layout's rule (vpsim.fleet.hev): the preset's, scaled"
    notes = {
        "engine.bore": "record: displacement and cylinders" + cylinders_note(rec),
        "engine.rated_power": "record: rated power (the engine's, W)",
        "engine.thermal_efficiency": technology_note or "the preset's",
        "electric.accessory_power": technology_note or "the preset's (W)",
        "machine.rated_power": f"{sizes} (W)",
        "battery.cells_in_parallel": "the preset's pack (one string)",
        "machine.loss_scale": technology_note
        or "the 2022 PM EVs' fitted drive-loss level (vpsim.fleet.hev.MACHINE_LOSS_SCALE)",
        "split.generator_rated_power": f"{sizes} (W)",
        "transmission.final_drive": (
            "record: axle ratio" if rec.layout == "hev_split" else "record: N/V and axle ratio"
        ),
    }
    about = [printable(f"# layout {rec.layout}: {rec.layout_rule}")]
    lines = toml_head(rec, source, "hev", PRESET[rec.layout], params.name, about, rec.layout)
    fields = [(sec, f) for sec, f in TOML_FIELDS if sec != "split" or rec.layout == "hev_split"]
    lines += hybrid_sections(params, fields, notes)
    measured = {TOML_TEST_NAME[c]: v for c, v in rec.measured_mpg.items()}
    block = record_block(
        rec,
        rec.road_load_si,
        "measured_mpg",
        measured,
        "unadjusted; udds = the hot UDDS of the 4-bag FTP (bags 3 + 4), compared charge-sustaining",
        {"powertrain": rec.layout},
    )
    return with_record_block(lines, block)


# --- technology fit ----------------------------------------------------------------------------------------


def _cycle(name: str):
    """The cycle the model runs for the test ``name`` (:data:`SIM_CYCLE`)."""
    from ..cycles import load_cycle

    return load_cycle(SIM_CYCLE[name])


def grid_chunk(items: list[tuple[HEVRecord, tuple[str, ...]]]) -> list[dict]:
    """Backward ECMS runs of each (record, tests) at every efficiency and loss-level node and both accessory
    nodes: ``log_fuel`` (len(EFFICIENCY_AXIS), len(LOSS_SCALE_AXIS), 2) of ln charge-sustaining L/100 km,
    or ``error``."""
    from .hybrids import cs_fuel_of

    return TECH.grid_chunk(items, lambda rec, _: hev_parameters(rec), cs_fuel_of(_cycle), "log_fuel", "fuel")


GRID = TechGrid(
    TECH_PARAMS[:2], EFFICIENCY_AXIS, EFFICIENCY_FINE, ACCESSORY_NODES_W, ACCESSORY_AXIS, "hybrid"
)
TECH = ThirdAxis(TECH_PARAMS[2], LOSS_SCALE_AXIS, LOSS_SCALE_FINE, GRID)
fit, search_bounds, on_bounds = TECH.fit, TECH.search_bounds, TECH.on_bounds


def predict_chunk(items: list[tuple[HEVRecord, str, dict]]) -> list[dict]:
    """One backward ECMS run per (record, test, technology): ``l_per_100km_cs``, ``trace_miss_s``, or
    ``error``."""
    from . import hybrids

    return hybrids.predict_chunk(items, TECH_PARAMS, lambda rec, _, tech: hev_parameters(rec, tech), _cycle)
