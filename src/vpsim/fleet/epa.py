"""Reader of the U.S. EPA Test Car List (one row per certification test), grouped per vehicle.

A *vehicle* is one ``Test Vehicle ID`` + ``Test Veh Configuration #``; its tests give the measured fuel
economy per cycle (see :mod:`vpsim.fleet.cycles`):

* ``ftp_bag2``, ``ftp_bag3``: ``FE Bag 2`` / ``FE Bag 3`` of its FTP tests (test category FTP, not the
  ``Cold CO`` procedure);
* ``hwy``: ``RND_ADJ_FE`` of its HWY tests; ``us06``: ``RND_ADJ_FE`` of its US06 tests (the whole cycle).

Only tests on the gasoline certification fuel (``Tier 2 Cert Gasoline``) are used; tests on other fuels
of a gasoline car (cold-CO fuels, low-altitude E10) are skipped, and so are SC03 tests. Several tests of one
vehicle on one cycle are averaged in fuel per distance (the harmonic mean of their mpg).

Exclusion rules (a vehicle excluded is counted under its reason; the first rule that applies wins):

==============================  ==============================================================================
reason                          rule
==============================  ==============================================================================
``electric, <why>``             a test on ``Electricity`` and no gasoline test, or displacement 0 and none:
                                a battery-electric car, read by :mod:`vpsim.fleet.ev` (``ev_vehicles``);
                                excluded only for the reason it gives
``plug-in hybrid``              a charge-depleting (``CD``) or electricity test beside gasoline tests
``fuel cell``                   a test on hydrogen
``diesel``                      a test on diesel fuel
``flex-fuel (E85 test)``        tests on E85 and none on certification gasoline (a flex-fuel car with both is
                                read from its gasoline tests, the E85 ones skipped as other fuels' are)
``mild hybrid, <why>``          a mild hybrid that :mod:`vpsim.fleet.mhev` cannot read (``mhev_vehicles``):
                                no known system for its maker, a missing field, no usable test. A mild hybrid:
                                ``MHEV`` in the model name, or an FTP test with a fourth bag (the 4-bag FTP
                                of electrified vehicles: 48 V start-stop, recuperation and assist)
``plug-in hybrid``              another test vehicle of the same make and model is a plug-in (its
                                charge-depleting tests are often on another test vehicle than its gasoline
                                tests)
``hybrid, <why>``               a full hybrid that :mod:`vpsim.fleet.hev` cannot read (``hev_vehicles``):
                                a plug-in by name, a layout not built (Honda's two-motor e:HEV), no usable
                                test; ``(screened: <rule>)`` says which rule flagged it a hybrid. A hybrid
                                (not flagged in a column): the model name holds ``hybrid``, the word
                                ``HEV``/``FHEV``/``PHEV`` or a Lexus-style ``300h``
                                (:data:`HYBRID_NAME`); or city fuel economy (FTP ``RND_ADJ_FE``) >= highway
                                (HWY ``RND_ADJ_FE``); or hot town fuel economy (FTP bag 2) >=
                                :data:`HOT_TOWN_HYBRID_RATIO` x highway (a conventional car does clearly
                                better on the highway; a hybrid recovers braking energy and switches its
                                engine off in town); or positive wheel work on the HWFET over the fuel's
                                heating value >= :data:`HWY_EFFICIENCY_HYBRID`
                                (:func:`implied_hwy_efficiency`)
``missing <field>``             a field the mapping needs is empty (an empty cylinder count is first taken
                                from the list's other tests where they agree: :func:`fill_cylinders`)
``implausible <field>``         a field is outside its plausible range (:data:`PLAUSIBLE`)
``implausible road load``       the target road load A + B v + C v^2 is not positive at every speed from 0 to
                                the US06's top speed (:func:`road_load_problem`): a car that would be pushed
                                by the air
``implausible rated_hp``        rated power per kilogram of test weight outside :data:`POWER_TO_MASS_W_PER_KG`
                                (:func:`power_to_mass_problem`)
``transmission type other``     transmission code ``OT``
``no usable test``              no FTP, HWY or US06 test on certification gasoline with a plausible value
==============================  ==============================================================================

The list is a CSV file as the EPA publishes it (``,``), or saved with ``;`` or tab between fields (a
spreadsheet's export); the header line tells which (:func:`list_separator`). A FIFO or a device is refused
before it is opened.

Each excluded vehicle, and each skipped or implausible test row, is also listed with a one-line reason
(:attr:`TestCarList.excluded_rows`); a bad row never stops the reading.
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ..errors import VpsimError
from ..model import vehicle as vh
from ..textio import check_regular_file, printable
from ..units import LITRES_PER_GALLON, METRES_PER_MILE, MPH_TO_MPS, mpg_from_l_per_100km

# --- unit conversions (exact definitions) -------------------------------------------------------------------
LB_TO_KG = 0.45359237
LBF_TO_N = 4.4482216152605  # lbf = lb x standard gravity 9.80665 m/s^2
HP_TO_KW = 0.745699871582270  # mechanical horsepower (550 ft lbf/s)


def lbf_per_mph_to_si(b: float) -> float:
    """lbf/mph -> N/(m/s)."""
    return b * LBF_TO_N / MPH_TO_MPS


def lbf_per_mph2_to_si(c: float) -> float:
    """lbf/mph^2 -> N/(m/s)^2."""
    return c * LBF_TO_N / MPH_TO_MPS**2


# --- columns ------------------------------------------------------------------------------------------------
COL = {
    "make": "Represented Test Veh Make",
    "model": "Represented Test Veh Model",
    "manufacturer": "Vehicle Manufacturer Name",
    "vehicle_id": "Test Vehicle ID",
    "configuration": "Test Veh Configuration #",
    "displacement_l": "Test Veh Displacement (L)",
    "rated_hp": "Rated Horsepower",
    "cylinders": "# of Cylinders and Rotors",
    "transmission_code": "Tested Transmission Type Code",
    "n_gears": "# of Gears",
    "lockup": "Transmission Lockup?",
    "drive": "Drive System Code",
    "etw_lb": "Equivalent Test Weight (lbs.)",
    "axle_ratio": "Axle Ratio",
    "nv_ratio": "N/V Ratio",
    "test_number": "Test Number",
    "procedure": "Test Procedure Description",
    "fuel": "Test Fuel Type Description",
    "category": "Test Category",
    "fe": "RND_ADJ_FE",
    "bag1": "FE Bag 1",
    "bag2": "FE Bag 2",
    "bag3": "FE Bag 3",
    "bag4": "FE Bag 4",
    "target_a_lbf": "Target Coef A (lbf)",
    "target_b_lbf_per_mph": "Target Coef B (lbf/mph)",
    "target_c_lbf_per_mph2": "Target Coef C (lbf/mph**2)",
    "engine_code": "Engine Code",
}

CERT_GASOLINE = "Tier 2 Cert Gasoline"
# columns a list may lack (read as empty): bag 1 is read only for the hybrids' cold UDDS (vpsim.fleet.hev),
# the engine code only to fill an empty cylinder count (fill_cylinders)
OPTIONAL_COLUMNS = ("bag1", "engine_code")

# plausible ranges of the record's fields (inclusive); outside => "implausible <field>"
PLAUSIBLE = {
    "etw_lb": (1500.0, 10000.0),
    "target_a_lbf": (1.0, 200.0),
    "target_b_lbf_per_mph": (-3.0, 3.0),
    "target_c_lbf_per_mph2": (0.005, 0.15),
    "displacement_l": (0.5, 10.0),
    "cylinders": (2.0, 16.0),
    "rated_hp": (40.0, 1600.0),
    "nv_ratio": (10.0, 80.0),
    "axle_ratio": (1.5, 8.0),
    "mpg": (5.0, 150.0),
}
NUMERIC = (
    "configuration",
    "displacement_l",
    "rated_hp",
    "cylinders",
    "n_gears",
    "etw_lb",
    "axle_ratio",
    "nv_ratio",
    "fe",
    "bag1",
    "bag2",
    "bag3",
    "bag4",
    "target_a_lbf",
    "target_b_lbf_per_mph",
    "target_c_lbf_per_mph2",
)

# transmission type codes of the list -> the transmission kinds a powertrain engineer distinguishes
TRANSMISSION_KIND = {
    "M": "manual",
    "A": "automatic",
    "SA": "automatic",  # semi-automatic: a torque-converter automatic with a manual mode
    "AM": "amt_dct",  # automated manual (single or dual clutch)
    "AMS": "amt_dct",  # the same, selectable (paddles)
    "CVT": "cvt",
    "SCV": "cvt",  # selectable CVT (stepped "virtual gears" on demand)
    "OT": "other",
}

# 48 V mild hybrids (engine stop, recuperation, electric assist): named MHEV, or certified with the 4-bag FTP
# electrified vehicles are tested with (FE Bag 4 recorded). On the 2022 list these are mostly BMW, Audi,
# Mercedes, Jaguar Land Rover and Ram eTorque models; run as conventional cars they ran 10 % (town) and
# 7.5 % (highway) short of their measured mpg: vpsim.fleet.mhev reads them as mild hybrids.
MILD_HYBRID_NAME = re.compile(r"\bmhev\b|mild hybrid", re.IGNORECASE)
# hybrids: a model name with the word hybrid, HEV (FHEV, PHEV) or a Lexus-style "300h"
HYBRID_NAME = re.compile(r"hybrid|\b[fp]?hev\b|\b\d{3}h\b", re.IGNORECASE)
# a conventional car's hot stabilised town fuel economy (FTP bag 2) is 0.44-0.85 of its highway figure in
# the 2022 list; hybrids (engine off at rest and in slow traffic, braking energy recovered) are above
HOT_TOWN_HYBRID_RATIO = 0.86

# ... or whose highway test implies a tank-to-wheel efficiency no conventional car reaches: on the 2022 list
# conventional cars reach at most 0.34 (Nissan Rogue, variable-compression turbo + CVT), the Hyundai Ioniq
# hybrid 0.37 (its hot town bag is only 0.64 x highway, so the ratio rule misses it)
HWY_EFFICIENCY_HYBRID = 0.35
CERT_FUEL_KG_PER_L = 0.743  # Tier 2 certification gasoline
CERT_FUEL_LHV_J_PER_KG = 42.9e6


def coastdown_record(a_n, b_n_per_mps, c_n_per_mps2, mass_kg=0.0):
    """The fields the model's road load (:func:`vpsim.model.vehicle.road_load`, :func:`~.wheel_force`) reads,
    for a coast-down road load F = A + B v + C v^2 in SI units (and a mass): its equations then evaluate a
    record's road load, here and wherever the fleet needs it."""
    from types import SimpleNamespace

    return SimpleNamespace(
        mass=mass_kg, rolling_force=a_n, road_load_b=b_n_per_mps, aero_coefficient=c_n_per_mps2
    )


# the speeds the fleet's cycles reach: 0 to the US06's top speed (80.3 mph, 35.9 m/s); a road load must stay
# positive over all of them (vpsim.fleet.cycles.fleet_cycle("us06") has this top speed; a test checks it)
ROAD_LOAD_TOP_SPEED_MPH = 80.3

# rated power per kg of equivalent test weight, set from published figures before it was compared with any
# record: the weakest cars sold in the US have about 50 W/kg (Mitsubishi Mirage: 78 hp, 2,500 lb test
# weight, 51 W/kg), the strongest about 500 W/kg (Bugatti Chiron: 1,479 hp, about 4,750 lb, 512 W/kg); the
# band leaves room either side. The EV reader's lower bound is the same (vpsim.fleet.ev.MIN_POWER_W_PER_KG).
POWER_TO_MASS_W_PER_KG = (30.0, 600.0)


def road_load_problem(a_lbf: float, b_lbf_per_mph: float, c_lbf_per_mph2: float) -> str | None:
    """Why the coast-down road load F = A + B v + C v^2 (record units) is not physical, or None: it must be
    positive at every speed from 0 to :data:`ROAD_LOAD_TOP_SPEED_MPH` (its minimum there is at an end or at
    v = -B / 2C)."""
    top = ROAD_LOAD_TOP_SPEED_MPH
    speeds = [0.0, top]
    if c_lbf_per_mph2 > 0.0 and 0.0 < -b_lbf_per_mph / (2.0 * c_lbf_per_mph2) < top:
        speeds.append(-b_lbf_per_mph / (2.0 * c_lbf_per_mph2))
    v = min(speeds, key=lambda x: a_lbf + b_lbf_per_mph * x + c_lbf_per_mph2 * x * x)
    f = a_lbf + b_lbf_per_mph * v + c_lbf_per_mph2 * v * v
    if f > 0.0:
        return None
    return (
        f"implausible road load: target_a_lbf {a_lbf:g}, target_b_lbf_per_mph {b_lbf_per_mph:g}, "
        f"target_c_lbf_per_mph2 {c_lbf_per_mph2:g} give {f:.4g} lbf at {v:.4g} mph; expected a positive "
        f"road load from 0 to {top:g} mph"
    )


def power_to_mass_problem(rated_hp: float, etw_lb: float) -> str | None:
    """Why the rated power does not fit the test weight (:data:`POWER_TO_MASS_W_PER_KG`), or None."""
    w_per_kg = rated_hp * HP_TO_KW * 1e3 / (etw_lb * LB_TO_KG)
    lo, hi = POWER_TO_MASS_W_PER_KG
    if lo <= w_per_kg <= hi:
        return None
    return (
        f"implausible rated_hp: {rated_hp:g} hp at etw_lb {etw_lb:g} is {w_per_kg:.0f} W/kg of test weight, "
        f"expected {lo:g} to {hi:g} W/kg (the weakest to the strongest cars on sale)"
    )


# boosted or naturally aspirated: the list has no column for it
BOOST_SPECIFIC_POWER_KW_PER_L = 75.0


class CertificationRecord:
    """What every certification record derives from its fields (record units in, SI out): key, rated power,
    test mass, road load. Subclassed by the conventional and the battery-electric record."""

    @property
    def key(self) -> str:
        return f"{self.vehicle_id}#{self.configuration}"

    @property
    def rated_power_kw(self) -> float:
        return self.rated_hp * HP_TO_KW

    @property
    def mass_kg(self) -> float:
        return self.etw_lb * LB_TO_KG

    @property
    def road_load_si(self) -> tuple[float, float, float]:
        """Target road load (A, B, C) in N, N/(m/s), N/(m/s)^2."""
        return (
            self.target_a_lbf * LBF_TO_N,
            lbf_per_mph_to_si(self.target_b_lbf_per_mph),
            lbf_per_mph2_to_si(self.target_c_lbf_per_mph2),
        )

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class VehicleRecord(CertificationRecord):
    """What the certification record says about one test vehicle (record units, as in the list)."""

    vehicle_id: str
    configuration: int
    make: str
    model: str
    manufacturer: str
    displacement_l: float
    cylinders: int
    rated_hp: float
    transmission_code: str
    transmission_kind: str  # manual, automatic, amt_dct, cvt
    n_gears: int  # as listed (1 for a CVT)
    lockup: bool
    drive: str
    etw_lb: float
    axle_ratio: float  # nan when not given
    nv_ratio: float  # engine rpm per mph in top gear
    target_a_lbf: float
    target_b_lbf_per_mph: float
    target_c_lbf_per_mph2: float
    boosted: bool
    boost_rule: str  # how ``boosted`` was decided
    measured_mpg: dict[str, float] = field(default_factory=dict)  # fleet cycle -> mpg
    n_tests: dict[str, int] = field(default_factory=dict)
    cylinders_source: str = ""  # "" where the record gives the count, else its source (fill_cylinders)

    @property
    def specific_power_kw_per_l(self) -> float:
        return self.rated_power_kw / self.displacement_l


@dataclass
class TestCarList:
    """The usable vehicles of a test car list, and what was left out and why."""

    path: str
    vehicles: list[VehicleRecord]
    excluded: Counter  # reason -> number of vehicles
    excluded_rows: list[dict]  # one dict per excluded vehicle or skipped/implausible test row
    n_rows: int
    ev_vehicles: list = field(default_factory=list)  # battery-electric records (vpsim.fleet.ev.EVRecord)
    hev_vehicles: list = field(default_factory=list)  # full hybrids (vpsim.fleet.hev.HEVRecord)
    mhev_vehicles: list = field(default_factory=list)  # mild hybrids (vpsim.fleet.mhev.MHEVRecord)

    def find(self, vehicle_id: str, configuration: int | None = None):
        """The conventional record (:class:`VehicleRecord`) or battery-electric one
        (:class:`vpsim.fleet.ev.EVRecord`) of a test vehicle; one-line error if none or several."""
        hits = [
            v
            for v in [*self.vehicles, *self.ev_vehicles, *self.hev_vehicles, *self.mhev_vehicles]
            if v.vehicle_id == vehicle_id and (configuration is None or v.configuration == configuration)
        ]
        if len(hits) == 1:
            return hits[0]
        if len(hits) > 1:
            configs = ", ".join(str(v.configuration) for v in hits)
            raise VpsimError(f"{self.path}: vehicle {vehicle_id} has configurations {configs}; give --config")
        why = [
            r["reason"]
            for r in self.excluded_rows
            if r["vehicle_id"] == vehicle_id
            and r["test_number"] == ""
            and (configuration is None or r["configuration"] == configuration)
        ]
        if why:
            raise VpsimError(f"{self.path}: vehicle {vehicle_id} is excluded: {why[0]}")
        rows = [  # no record was built: each of its test rows was left out (configuration 1.9, ...)
            r["reason"]
            for r in self.excluded_rows
            if r["vehicle_id"] == vehicle_id
            and (configuration is None or r["configuration"] == configuration)
        ]
        if rows:
            reasons = "; ".join(dict.fromkeys(rows))
            raise VpsimError(
                f"{self.path}: vehicle {vehicle_id}: every test row is excluded ({printable(reasons)[:300]})"
            )
        raise VpsimError(
            f"{self.path}: no vehicle {vehicle_id}"
            + ("" if configuration is None else f" config {configuration}")
        )


def _num(x) -> float:
    """A record's number; NaN for anything that is not a finite plain number (``abc``, ``inf``, ``4,000``)."""
    try:
        v = float(x)
    except (TypeError, ValueError):
        return math.nan
    return v if math.isfinite(v) else math.nan


def named_make(make: str, manufacturer: str) -> str:
    """The make a record names: its ``Represented Test Veh Make``, or where that holds no letter (the 2022
    list gives "2022" for the three Lucid Air records) the first word of its ``Vehicle Manufacturer Name``
    ("Lucid USA, Inc" -> "Lucid"). Reports, vehicle names and the rules that go by make read it; the folds
    group by manufacturer and never read it."""
    if any(ch.isalpha() for ch in make):
        return make
    first = manufacturer.replace(",", " ").split()
    return first[0] if first else make


def _text(x) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return ""
    return str(x).strip()


SEPARATORS = (",", ";", "\t")  # as every CSV vpsim reads (README): the header line tells which


def list_separator(path: Path) -> str:
    """The field separator of a list: whichever of ``,``, ``;`` and tab its header line holds most of (the
    EPA's column names hold none of them); ``,`` for a header without any."""
    with path.open("rb") as fh:
        head = fh.readline(1 << 16)
    counts = {sep: head.count(sep.encode()) for sep in SEPARATORS}
    best = max(SEPARATORS, key=lambda sep: counts[sep])
    return best if counts[best] > 0 else ","


def read_test_car_list(path: str | Path) -> TestCarList:
    """Read the list at ``path``; errors about the file itself are one line, bad rows are excluded."""
    import pandas as pd

    path = check_regular_file(path, VpsimError, "CSV test car list")  # before pandas opens a FIFO or device
    ragged: list[tuple[int, list[str]]] = []  # (line, fields) of rows with more fields than the header
    try:
        sep = list_separator(path)
        if _has_ragged_rows(path, sep):  # (pandas would refuse the list, or shift a first such row silently)
            df, ragged = _read_ragged(path, sep)
        else:
            df = pd.read_csv(path, sep=sep, encoding="utf-8-sig", dtype=str, keep_default_na=False)
    except OSError as exc:  # permission denied, an I/O error
        raise VpsimError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except (UnicodeDecodeError, pd.errors.ParserError, pd.errors.EmptyDataError, csv.Error) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise VpsimError(f"{path}: not a readable CSV test car list ({msg})") from None
    df.columns = [c.strip() for c in df.columns]
    lines = df.pop(_LINE).tolist() if _LINE in df.columns else None
    for k in OPTIONAL_COLUMNS:
        if COL[k] not in df.columns:
            df[COL[k]] = ""
    missing = [c for c in COL.values() if c not in df.columns]
    if missing:
        raise VpsimError(f"{path}: not an EPA test car list; missing column(s) {', '.join(missing)}")
    rows = []
    for i, raw in enumerate(df[list(COL.values())].itertuples(index=False, name=None)):
        r = {k: raw[j] for j, k in enumerate(COL)}
        r["not_a_number"] = {}  # field -> the text that is not a number (a problem unlike an empty field)
        for k in NUMERIC:
            text = str(r[k]).strip()
            r[k] = _num(text) if text != "" else math.nan
            if text and not math.isfinite(r[k]):
                r["not_a_number"][k] = text
        for k in COL:
            if k not in NUMERIC:
                r[k] = _text(r[k])
        r["line"] = i + 2 if lines is None else lines[i]  # header is line 1
        rows.append(r)
    for r in rows:
        r["make"] = named_make(r["make"], r["manufacturer"])
    fill_cylinders(rows)
    if not rows and not ragged:
        raise VpsimError(f"{path}: no test rows below the header")
    groups: dict[tuple[str, int], list[dict]] = {}
    excluded_rows: list[dict] = []
    for r in rows:
        if r["vehicle_id"] == "" or not math.isfinite(r["configuration"]):
            bad = r["not_a_number"].get("configuration")
            why = (
                f"configuration {printable(bad)!r} is not a number"
                if bad
                else "missing Test Vehicle ID or configuration"
            )
            excluded_rows.append(_excl(r, why, test=True))
            continue
        if r["configuration"] != int(r["configuration"]):  # 1.9 is no configuration 1
            excluded_rows.append(
                _excl(r, f"configuration {r['configuration']:g} is not a whole number", test=True)
            )
            continue
        groups.setdefault((r["vehicle_id"], int(r["configuration"])), []).append(r)
    excluded: Counter = Counter()
    _exclude_ragged(ragged, list(df.columns), groups, excluded, excluded_rows)
    # what a vehicle's own tests say, then what the other test vehicles of the same model say (a plug-in's
    # charge-depleting tests are often on another test vehicle than its charge-sustaining ones)
    kinds = {key: _classify(tests) for key, tests in groups.items()}
    model_kind: dict[tuple[str, str], str] = {}
    for key, kind in kinds.items():
        if kind is not None and kind.split(":")[0] == "plug-in hybrid":
            model_kind[_model_key(groups[key][0])] = "plug-in hybrid"
    vehicles: list[VehicleRecord] = []
    ev_vehicles: list = []
    hev_vehicles: list = []
    mhev_vehicles: list = []
    for (vid, cfg), tests in groups.items():
        kind = kinds[(vid, cfg)]
        if (kind is None or kind.startswith("mild hybrid")) and _model_key(tests[0]) in model_kind:
            other = model_kind[_model_key(tests[0])]
            kind = f"{other}: another test vehicle of this model is a {other}"
        if kind == "electric":  # a battery-electric car: its own reader (vpsim.fleet.ev)
            from .ev import ev_vehicle

            rec, reason, test_rows = ev_vehicle(vid, cfg, tests)
        elif kind is not None and kind.split(":")[0] == "hybrid":  # a full hybrid: vpsim.fleet.hev
            from .hev import hev_vehicle

            rec, reason, test_rows = hev_vehicle(vid, cfg, tests)
            if rec is not None:
                hev_vehicles.append(rec)
                excluded_rows += test_rows
                continue
            reason = f"{reason} (screened: {kind})"
        elif kind is not None and kind.startswith("mild hybrid"):  # a mild hybrid: vpsim.fleet.mhev
            from .mhev import mhev_vehicle

            rec, reason, test_rows = mhev_vehicle(vid, cfg, tests)
            if rec is not None:
                mhev_vehicles.append(rec)
                excluded_rows += test_rows
                continue
            reason = f"{reason}{'' if ':' in reason else ':'} (screened: {kind})"
        elif kind is not None:
            rec, reason, test_rows = None, kind, []
        else:
            rec, reason, test_rows = _vehicle(vid, cfg, tests)
        excluded_rows += test_rows
        if rec is None:
            excluded[reason.split(":")[0]] += 1
            excluded_rows.append(_excl(tests[0], reason, test=False))
        elif kind == "electric":
            ev_vehicles.append(rec)
        else:
            vehicles.append(rec)
    return TestCarList(
        str(path), vehicles, excluded, excluded_rows, len(rows), ev_vehicles, hev_vehicles, mhev_vehicles
    )


_LINE = "\x00line"  # the line number column of a list read row by row (no header can be named so)
RAGGED_REASON = "unreadable row"


def _has_ragged_rows(path: Path, sep: str) -> bool:
    """Whether a row has more fields than the header. pandas refuses such a list, or, when the first data row
    is the one, takes its first field for an index and shifts every column of every row by one, silently."""
    try:
        with path.open(encoding="utf-8-sig", newline="") as fh:
            reader = csv.reader(fh, delimiter=sep)
            header = next(reader, None)
            return header is not None and any(len(row) > len(header) for row in reader)
    except (csv.Error, UnicodeDecodeError):  # (a NUL, a huge field, not UTF-8: pandas' reader says what)
        return False


def _read_ragged(path: Path, sep: str):
    """The list read row by row when some rows have more fields than the header (a stray separator, a
    broken export): the others as a table (with their line numbers in column ``_LINE``), the ragged ones as
    (line, fields), so that only the vehicles they belong to are left out, not the whole list."""
    import pandas as pd

    with path.open(encoding="utf-8-sig", newline="") as fh:
        reader = csv.reader(fh, delimiter=sep)
        header = next(reader, None)
        if header is None:
            raise pd.errors.EmptyDataError("no header")
        n = len(header)
        good, lines, ragged = [], [], []
        line = 1
        for row in reader:
            if not row:  # a blank line (pandas skips them too and does not count them)
                continue
            line += 1
            if len(row) > n:
                ragged.append((line, row))
            else:
                good.append(row + [""] * (n - len(row)))
                lines.append(line)
    buf = io.StringIO()  # the good rows back through pandas' own reader: the same columns and text as
    csv.writer(buf, delimiter=sep).writerows([header, *good])  # a list without ragged rows gives
    buf.seek(0)
    df = pd.read_csv(buf, sep=sep, dtype=str, keep_default_na=False)
    df[_LINE] = lines
    return df, ragged


def _exclude_ragged(ragged, columns, groups, excluded: Counter, excluded_rows: list) -> None:
    """Leave out each vehicle that a row with extra fields names (its Test Vehicle ID and configuration, read
    at their columns' places): one of its tests cannot be read safely, so none of them is used; the reason
    names the vehicle's first such row. A ragged row whose vehicle cannot be told is listed on its own."""
    pos = {k: columns.index(COL[k]) if COL[k] in columns else -1 for k in ("vehicle_id", "configuration")}

    def field_(fields, k):
        return fields[pos[k]] if 0 <= pos[k] < len(fields) else ""

    done: set = set()
    for line, fields in ragged:
        why = f"{RAGGED_REASON}: line {line} has {len(fields)} fields where the header has {len(columns)}"
        vid, cfg = _text(field_(fields, "vehicle_id")), _num(field_(fields, "configuration").strip())
        key = (vid, int(cfg)) if vid and math.isfinite(cfg) and cfg == int(cfg) else None
        if key in done:
            continue
        row = dict(line=line, vehicle_id=vid, configuration=-1, make="", model="", test_number="")
        if key is not None:  # the vehicle, whether or not it has readable rows beside this one
            done.add(key)
            tests = groups.pop(key, None)
            excluded[RAGGED_REASON] += 1
            row = _excl(tests[0], why, test=False) if tests else dict(row, configuration=key[1])
        excluded_rows.append(dict(row, reason=why))


def _excl(r: dict, reason: str, *, test: bool) -> dict:
    return {
        "line": r["line"],
        "vehicle_id": r["vehicle_id"],
        "configuration": int(r["configuration"]) if math.isfinite(r["configuration"]) else -1,
        "make": r["make"],
        "model": r["model"],
        "test_number": r["test_number"] if test else "",
        "reason": reason,
    }


def _model_key(t: dict) -> tuple[str, str]:
    return (t["make"].lower(), t["model"].lower())


def _classify(tests: list[dict]) -> str | None:
    fuels = {t["fuel"].lower() for t in tests}
    cats = {t["category"].upper() for t in tests}
    gasoline = any("gasoline" in f for f in fuels)
    electric = "electricity" in fuels or "CD" in cats
    disp = [t["displacement_l"] for t in tests if math.isfinite(t["displacement_l"])]
    if electric and not gasoline:
        return "electric"
    if disp and max(disp) == 0.0 and not gasoline:  # no engine, and nothing burnt: an electric car
        return "electric"
    if electric:
        return "plug-in hybrid"
    if any("hydrogen" in f for f in fuels):
        return "fuel cell"
    if any("diesel" in f for f in fuels):
        return "diesel"
    if any("e85" in f for f in fuels) and CERT_GASOLINE.lower() not in fuels:
        # (a flex-fuel car tested on certification gasoline too is a gasoline car: its E85 tests are skipped
        # as other fuels' are, _vehicle)
        return "flex-fuel (E85 test)"
    if any(HYBRID_NAME.search(t["model"]) for t in tests):
        return "hybrid"
    city = [t["fe"] for t in tests if _is_cert_ftp(t) and _plausible_mpg(t["fe"])]
    hot = [t["bag2"] for t in tests if _is_cert_ftp(t) and _plausible_mpg(t["bag2"])]
    hwy = [t["fe"] for t in tests if _is_cert(t, "HWY") and _plausible_mpg(t["fe"])]
    if city and hwy and _harmonic(city) >= _harmonic(hwy):
        return "hybrid: city mpg >= highway mpg"
    if hot and hwy and _harmonic(hot) >= HOT_TOWN_HYBRID_RATIO * _harmonic(hwy):
        return f"hybrid: hot town (FTP bag 2) mpg >= {HOT_TOWN_HYBRID_RATIO} x highway mpg"
    if hwy:
        eff = implied_hwy_efficiency(tests[0], _harmonic(hwy))
        if eff >= HWY_EFFICIENCY_HYBRID:
            return f"hybrid: wheel work / fuel energy on HWY {eff:.3f} >= {HWY_EFFICIENCY_HYBRID}"
    if any(MILD_HYBRID_NAME.search(t["model"]) for t in tests):
        return "mild hybrid"
    if any(_is_cert_ftp(t) and math.isfinite(t["bag4"]) for t in tests):
        return "mild hybrid: FTP with a fourth bag"
    return None


def implied_hwy_efficiency(t: dict, hwy_mpg: float) -> float:
    """Positive work at the wheels on the HWFET (road load A + B v + C v^2 and inertia m a, with the test
    mass) over the heating value of the fuel the HWY test burned (certification gasoline); nan when the
    record lacks a field."""
    import numpy as np

    from .cycles import fleet_cycle

    names = ("target_a_lbf", "target_b_lbf_per_mph", "target_c_lbf_per_mph2", "etw_lb")
    vals = [t[k] for k in names]
    if any(_field_problem(k, t[k]) for k in names) or not hwy_mpg > 0:
        return math.nan  # (an implausible field is reported as such, not screened as a hybrid)
    cyc = fleet_cycle("hwy")
    v = 0.5 * (cyc.speed_mps[1:] + cyc.speed_mps[:-1])
    dt = np.diff(cyc.time_s)
    acc = np.diff(cyc.speed_mps) / dt
    a, b, c = vals[0] * LBF_TO_N, lbf_per_mph_to_si(vals[1]), lbf_per_mph2_to_si(vals[2])
    force = vh.wheel_force(v, acc, coastdown_record(a, b, c, vals[3] * LB_TO_KG))  # (18)
    work = float(np.sum(np.maximum(force, 0.0) * v * dt))
    distance = float(np.sum(v * dt))
    gallons = distance / METRES_PER_MILE / hwy_mpg
    return work / (gallons * LITRES_PER_GALLON * CERT_FUEL_KG_PER_L * CERT_FUEL_LHV_J_PER_KG)


def _is_cert(t: dict, category: str) -> bool:
    return t["category"].upper() == category and t["fuel"] == CERT_GASOLINE


def _is_cert_ftp(t: dict) -> bool:
    return _is_cert(t, "FTP") and "cold co" not in t["procedure"].lower()


def _plausible_mpg(x: float) -> bool:
    lo, hi = PLAUSIBLE["mpg"]
    return math.isfinite(x) and lo <= x <= hi


def _harmonic(xs: list[float]) -> float:
    return len(xs) / sum(1.0 / x for x in xs)


# an empty cylinder count is filled from other test vehicles of the same make and displacement only where at
# least this many of them give one and all give the same (one other car could be the list's own typo)
CYLINDER_WITNESSES = 2


def fill_cylinders(rows: list[dict]) -> None:
    """Fill an empty ``# of Cylinders and Rotors`` from the list's other tests, where they agree: first the
    tests of the same ``Engine Code`` (one engine, one cylinder count), else those of the same make and
    displacement (to 0.01 L) on at least :data:`CYLINDER_WITNESSES` other test vehicles. Where they do not
    agree, or none give one, the field stays empty (``missing cylinders``). Each filled row's
    ``cylinders_source`` says where the count came from (the vehicle file's note on ``engine.bore``).

    On the 2022 list this fills four cars: the BMW 230i (2.0 L: 4, as on 23 other BMW test vehicles of
    2.00 L), the Kia Telluride (6, its engine code's tests on the Palisade and other Tellurides), the Mazda3
    2.0 L (4, two others) and the Audi RS7 (3.996 L: 8, as on four other Audis of 4.00 L: the RS Q8, S8, SQ7
    and SQ8). A field that is not a number is not filled (it is a different problem)."""

    def key_md(r):
        d = r["displacement_l"]
        return (r["make"].strip().upper(), round(d, 2)) if math.isfinite(d) else None

    by_code: dict[str, dict[float, int]] = {}
    by_make: dict[tuple, dict[float, set]] = {}
    for r in rows:
        n = r["cylinders"]
        if not math.isfinite(n):
            continue
        code = r.get("engine_code", "").strip().upper()
        if code:
            by_code.setdefault(code, Counter())[n] += 1
        k = key_md(r)
        if k is not None:
            by_make.setdefault(k, {}).setdefault(n, set()).add(r["vehicle_id"])
    for r in rows:
        if math.isfinite(r["cylinders"]) or "cylinders" in r["not_a_number"]:
            continue
        code = r.get("engine_code", "").strip().upper()
        seen = by_code.get(code) if code else None
        if seen and len(seen) == 1:
            ((n, count),) = seen.items()
            r["cylinders"] = n
            r["cylinders_source"] = (
                f"the field is empty; {n:g} from {count} other test(s) of engine code {printable(code)}"
            )
            continue
        k = key_md(r)
        seen_md = by_make.get(k) if k is not None else None
        if seen_md and len(seen_md) == 1:
            ((n, vids),) = seen_md.items()
            others = vids - {r["vehicle_id"]}
            if len(others) >= CYLINDER_WITNESSES:
                r["cylinders"] = n
                r["cylinders_source"] = (
                    f"the field is empty; {n:g} from {len(others)} other test vehicles of "
                    f"{printable(r['make'].strip())} with {k[1]:.2f} L"
                )


WHOLE = ("cylinders", "n_gears")  # counts: 2.5 cylinders are no engine, 6.7 gears no gearbox


def _field_problem(name: str, value: float, not_a_number: dict | None = None) -> str | None:
    text = (not_a_number or {}).get(name)
    if text is not None:
        return f"not a number: {name} = {printable(text)[:40]!r}"
    if not math.isfinite(value):
        return f"missing {name}"
    lo, hi = PLAUSIBLE[name]
    if not lo <= value <= hi:
        return f"implausible {name}: {value:g} outside [{lo:g}, {hi:g}]"
    if name in WHOLE and value != int(value):
        return f"implausible {name}: {value:g} is not a whole number"
    return None


def _vehicle(vid: str, cfg: int, tests: list[dict]) -> tuple[VehicleRecord | None, str, list[dict]]:
    """(record or None, exclusion reason, excluded test rows) of one conventional vehicle's tests."""
    test_rows: list[dict] = []
    values: dict[str, list[float]] = {c: [] for c in ("ftp_bag2", "ftp_bag3", "hwy", "us06")}
    used: list[dict] = []
    for t in tests:
        cat = t["category"].upper()
        if (
            cat not in ("FTP", "HWY", "US06")
            or t["fuel"] != CERT_GASOLINE
            or "cold co" in t["procedure"].lower()
        ):
            continue  # SC03, cold CO and other-fuel tests: not a cycle of the fleet (not an error)
        picks = {"FTP": (("ftp_bag2", "bag2"), ("ftp_bag3", "bag3")), "HWY": (("hwy", "fe"),)}
        picks["US06"] = (("us06", "fe"),)
        ok = False
        for cyc, col in picks[cat]:
            x = t[col]
            if _plausible_mpg(x):
                values[cyc].append(x)
                ok = True
            else:
                what = "missing" if not math.isfinite(x) else f"{x:g} mpg outside [5, 150]"
                test_rows.append(_excl(t, f"{cat} test: {COL[col]} {what}", test=True))
        if ok:
            used.append(t)
    if not used:
        return None, "no usable test", test_rows
    first = used[0]
    problem = record_problem(first, (*RECORD_FIELDS, "nv_ratio"))
    if problem:
        return None, problem, test_rows
    code = first["transmission_code"].upper()
    kind = TRANSMISSION_KIND.get(code)
    if kind is None:
        return None, f"missing transmission type code: {code or 'empty'}", test_rows
    if kind == "other":
        return None, "transmission type other", test_rows
    n_gears = first["n_gears"]
    if "n_gears" in first["not_a_number"] or not math.isfinite(n_gears):
        return None, _field_problem("n_gears", n_gears, first["not_a_number"]) or "missing n_gears", test_rows
    if n_gears != int(n_gears):
        return None, f"implausible n_gears: {n_gears:g} is not a whole number", test_rows
    if kind == "cvt":
        n_gears = 1
    elif not 3 <= n_gears <= 12:
        return None, f"implausible n_gears: {n_gears:g} for a {kind} transmission", test_rows
    axle = first["axle_ratio"]
    if not (math.isfinite(axle) and PLAUSIBLE["axle_ratio"][0] <= axle <= PLAUSIBLE["axle_ratio"][1]):
        axle = math.nan  # the mapping then uses a default top-gear ratio (vpsim.fleet.vehicle)
    spec = first["rated_hp"] * HP_TO_KW / first["displacement_l"]
    boosted = spec > BOOST_SPECIFIC_POWER_KW_PER_L
    rule = f"specific power {spec:.1f} kW/L {'>' if boosted else '<='} {BOOST_SPECIFIC_POWER_KW_PER_L:g} kW/L"
    rec = VehicleRecord(
        **record_fields(vid, cfg, first, values),
        transmission_kind=kind,
        n_gears=int(n_gears),
        lockup=first["lockup"].upper() == "Y",
        axle_ratio=axle,
        boosted=boosted,
        boost_rule=rule,
    )
    return rec, "", test_rows


# the fields every engine's record must hold plausibly (a conventional car and a mild hybrid add nv_ratio)
RECORD_FIELDS = (
    "etw_lb",
    "target_a_lbf",
    "target_b_lbf_per_mph",
    "target_c_lbf_per_mph2",
    "displacement_l",
    "cylinders",
    "rated_hp",
)


def record_problem(first: dict, names: tuple[str, ...]) -> str | None:
    """Why a vehicle whose first usable test row is ``first`` cannot be read, or None: a field of ``names``
    missing, not a number or implausible (:func:`_field_problem`), then its road load or power to mass."""
    for name in names:
        problem = _field_problem(name, first[name], first["not_a_number"])
        if problem:
            return problem
    return road_load_problem(
        first["target_a_lbf"], first["target_b_lbf_per_mph"], first["target_c_lbf_per_mph2"]
    ) or power_to_mass_problem(first["rated_hp"], first["etw_lb"])


def record_fields(vid: str, cfg: int, first: dict, values: dict[str, list[float]]) -> dict:
    """The fields a conventional, full-hybrid and mild-hybrid record all take alike from the first usable
    test row ``first`` and the tests' figures ``values`` (test -> mpg of each test, averaged in fuel per
    distance)."""
    return {
        "vehicle_id": vid,
        "configuration": cfg,
        "make": first["make"],
        "model": first["model"],
        "manufacturer": first["manufacturer"],
        "displacement_l": first["displacement_l"],
        "cylinders": int(round(first["cylinders"])),
        "rated_hp": first["rated_hp"],
        "transmission_code": first["transmission_code"].upper(),
        "drive": first["drive"],
        "etw_lb": first["etw_lb"],
        "nv_ratio": first["nv_ratio"],
        "target_a_lbf": first["target_a_lbf"],
        "target_b_lbf_per_mph": first["target_b_lbf_per_mph"],
        "target_c_lbf_per_mph2": first["target_c_lbf_per_mph2"],
        "measured_mpg": {c: _harmonic(v) for c, v in values.items() if v},
        "n_tests": {c: len(v) for c, v in values.items() if v},
        "cylinders_source": first.get("cylinders_source", ""),
    }


__all__ = [
    "COL",
    "LBF_TO_N",
    "LB_TO_KG",
    "MPH_TO_MPS",
    "PLAUSIBLE",
    "POWER_TO_MASS_W_PER_KG",
    "ROAD_LOAD_TOP_SPEED_MPH",
    "TestCarList",
    "VehicleRecord",
    "lbf_per_mph2_to_si",
    "lbf_per_mph_to_si",
    "mpg_from_l_per_100km",
    "power_to_mass_problem",
    "read_test_car_list",
    "road_load_problem",
]
