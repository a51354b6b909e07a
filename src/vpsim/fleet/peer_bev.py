"""The battery-electric peer: FASTSim 3.1's BEV on the EPA 2022 list's electric records (UDDS and HWFET).

Each record becomes a FASTSim battery-electric vehicle built from one of the BEVs FASTSim ships,
``2022 Tesla Model 3 RWD thrml.yaml`` (:data:`PEER_BEV_VEHICLE`), with what the record gives put in:

* why that resource: of the four BEVs FASTSim ships it is the one of the list's model year and market
  (2022, U.S.); its motor efficiency curve (0.84-0.95 against the fraction of rated power), its constant
  battery efficiency (0.985) and its 250 W of base accessories are FASTSim's generic BEV values (the 2016
  Leaf and the Zoe carry the same curve and battery), and its transmission efficiency, 0.98, is that of
  three of the four (the Zoe's 0.92 is that car's own). The Bolt's motor curve and C-rate/temperature
  battery map are fitted to one car;
* its thermal models are removed (battery thermal model, cabin, HVAC: ``None``, the form the Zoe ships
  in): the EPA's two tests are run at room temperature with climate control off, so the run is the
  room-temperature one with no heating or cooling load;
* mass: the equivalent test weight (FASTSim's top-level ``mass_kilograms``), the same as the conventional
  peer (:mod:`vpsim.fleet.peer`);
* road load: the *same* fold of the record's A/B/C into c_r and C_d A as vpsim's
  (:func:`vpsim.fleet.vehicle.fold_road_load`, nominal frontal area, rho = 1.2 kg/m^3), over the cycle it
  is run on (``fold_cycles``; :func:`bev_peer_chunk` folds over the one cycle run, as the conventional peer
  does), wheel radius as vpsim's;
* rated power: the motor's maximum output power (``em.pwr_out_max_watts``); the battery's maximum power is
  raised to at least :data:`BATTERY_POWER_MARGIN` x that so the battery never limits the motor;
* battery: :data:`BATTERY_KWH` usable between SOC 0 and 1 (FASTSim starts a BEV at its maximum SOC): one
  cycle uses 1-5 kWh, so it never depletes; the charge taken from it is what the test measures at the wall;
* everything else FASTSim's own defaults, among them its regenerative braking (every braking power the
  motor can absorb is recovered; friction brakes only beyond the motor's power) and its wheel inertia.
  A car that cannot follow the trace is run with ``trace_miss_opts = "Allow"`` and reported
  (``trace_miss``).

Cycles: UDDS and HWFET as vpsim ships them (``vpsim.cycles.load_cycle``), handed to FASTSim as the
conventional peer does; they equal FASTSim's own ``udds.csv`` / ``hwfet.csv`` within 5e-7 m/s.

Energy and MPGe. FASTSim 3.1 models no charger: the battery reports terminal energy
(``energy_out_electrical_joules``) and chemical energy (``energy_out_chemical_joules``, terminal plus the
battery's internal loss), both net over the cycle (regeneration subtracted). The EPA's figure is the energy
drawn from the wall to recharge the battery. The peer takes the net *chemical* energy (the charge the
battery lost, which recharging must put back; ``battery_wh_per_km``) over :data:`CHARGER_EFFICIENCY`, 0.86,
the wall-to-battery efficiency FASTSim's own earlier vehicle model carries (``chg_eff``, the value FASTSim
3.1 still writes when it exports a vehicle to that model): ``wall_wh_per_km``; MPGe = miles per 33.705 kWh
of wall energy (:data:`KWH_PER_GALLON_EQUIVALENT`).

Two peers, as for the conventional cars: ``fastsim`` (FASTSim's defaults, nothing fitted) and a calibrated
one with the BEV's technology (:data:`BEV_PEER_PARAMS`):

* ``drivetrain_efficiency_scale`` s: the motor's efficiency curve times s (clipped at
  :data:`MAX_MOTOR_EFFICIENCY`). With regeneration the energy is *not* proportional to 1/s (the energy
  recovered grows with s), so s cannot be solved by a median as the conventional peer's scale is;
* ``accessory_power_w``: FASTSim's ``pwr_aux_base_watts``.

Hence a BEV-specific but analogous fit (:func:`fit_bev_peer`): FASTSim runs each record and cycle at
:data:`CAL_SCALE` x :data:`CAL_AUX` (:func:`bev_calibration_chunk`); ln wall energy is interpolated
quadratically in both on a fine grid, and the pair minimising the same L1 loss (mean |ln(pred / meas)|
over the training vehicles' cycles) is taken; :func:`calibrate_bev_peer` runs it by vpsim's own
cross-validation procedure (:func:`vpsim.fleet.calibrate.per_fold_and_class`), one class ``bev``.
"""

from __future__ import annotations

import copy
import math
from types import SimpleNamespace

import numpy as np

from ..units import METRES_PER_MILE

PEER_BEV_VEHICLE = "2022 Tesla Model 3 RWD thrml.yaml"
BEV_CYCLES = ("udds", "hwfet")
BATTERY_KWH = 200.0
BATTERY_POWER_MARGIN = 1.5
CHARGER_EFFICIENCY = 0.86  # wall -> battery: FASTSim's chg_eff
KWH_PER_GALLON_EQUIVALENT = 33.705
MAX_MOTOR_EFFICIENCY = 0.99
BEV_PEER_PARAMS = ("drivetrain_efficiency_scale", "accessory_power_w")
BEV_CLASSES = ("bev",)
CAL_SCALE = (0.8, 0.925, 1.05)  # the motor-efficiency scales FASTSim runs at (1.05 x 0.95 peak < 1)
CAL_AUX = (0.0, 1000.0, 2500.0)  # W
SCALE_FINE = np.linspace(CAL_SCALE[0], CAL_SCALE[-1], 51)
AUX_FINE = np.arange(0.0, 2500.1, 25.0)

_BASE: dict = {}


def _base_vehicle() -> dict:
    """FASTSim's Model 3 resource as a dict, thermal models removed, nothing saved per step."""
    if not _BASE:
        import fastsim as fsim

        d = fsim.Vehicle.from_resource(PEER_BEV_VEHICLE).to_dict()
        bev = d["pt_type"]["BEV"]
        bev["res"]["thrml"] = "None"
        d["cabin"] = "None"
        d["hvac"] = "None"
        d["save_interval"] = None
        for part in ("res", "em", "transmission"):
            bev[part]["save_interval"] = None
        _BASE.update(d)
    return _BASE


def bev_peer_vehicle(
    mass_kg: float,
    road_load_a_n: float,
    road_load_b_n_per_mps: float,
    road_load_c_n_per_mps2: float,
    rated_power_w: float,
    technology: dict | None = None,
    *,
    fold_cycles: tuple[str, ...] = BEV_CYCLES,
) -> dict:
    """The FASTSim BEV dict of a record (module docstring), its road load folded over ``fold_cycles``
    (vpsim cycle names), with ``technology`` (:data:`BEV_PEER_PARAMS`; default FASTSim's own)."""
    from ..cycles import load_cycle
    from .vehicle import FRONTAL_AREA_M2, WHEEL_RADIUS_M, fold_road_load

    rec = SimpleNamespace(
        mass_kg=mass_kg, road_load_si=(road_load_a_n, road_load_b_n_per_mps, road_load_c_n_per_mps2)
    )
    c_r, c_d, _ = fold_road_load(rec, [load_cycle(c) for c in fold_cycles])
    d = copy.deepcopy(_base_vehicle())
    d["name"] = f"BEV peer ({mass_kg:.0f} kg, {rated_power_w / 1e3:.0f} kW)"
    d["mass_kilograms"] = float(mass_kg)
    ch = d["chassis"]
    ch["drag_coef"] = c_d
    ch["frontal_area_square_meters"] = FRONTAL_AREA_M2
    ch["wheel_rr_coef"] = c_r
    ch["wheel_radius_meters"] = WHEEL_RADIUS_M
    bev = d["pt_type"]["BEV"]
    bev["em"]["pwr_out_max_watts"] = float(rated_power_w)
    res = bev["res"]
    res["energy_capacity_joules"] = BATTERY_KWH * 3.6e6
    res["min_soc"], res["max_soc"] = 0.0, 1.0
    res["pwr_out_max_watts"] = max(res["pwr_out_max_watts"], BATTERY_POWER_MARGIN * float(rated_power_w))
    return with_bev_technology(d, technology)


def _motor_curves(scale: float) -> tuple[dict, dict]:
    """FASTSim's two motor-efficiency interpolators (by output and by input power) with the curve x scale."""
    em = _base_vehicle()["pt_type"]["BEV"]["em"]
    achieved = copy.deepcopy(em["eff_interp_achieved"])
    at_input = copy.deepcopy(em["eff_interp_at_max_input"])
    frac_out = np.asarray(achieved["data"]["grid"][0]["data"], dtype=float)
    eff = np.minimum(
        np.asarray(achieved["data"]["values"]["data"], dtype=float) * scale, MAX_MOTOR_EFFICIENCY
    )
    achieved["data"]["values"]["data"] = eff.tolist()
    at_input["data"]["grid"][0]["data"] = (frac_out / eff).tolist()  # input fraction = output / efficiency
    at_input["data"]["values"]["data"] = eff.tolist()
    return achieved, at_input


def with_bev_technology(d: dict, technology: dict | None) -> dict:
    """``d`` (from :func:`bev_peer_vehicle`) with ``technology`` put in (:data:`BEV_PEER_PARAMS`); a new
    dict sharing everything else with ``d``."""
    if not technology:
        return d
    unknown = set(technology) - set(BEV_PEER_PARAMS)
    if unknown:
        raise ValueError(f"unknown BEV peer parameter(s) {', '.join(sorted(unknown))}")
    out = dict(d)
    if "drivetrain_efficiency_scale" in technology:
        pt = dict(d["pt_type"])
        bev = dict(pt["BEV"])
        em = dict(bev["em"])
        em["eff_interp_achieved"], em["eff_interp_at_max_input"] = _motor_curves(
            float(technology["drivetrain_efficiency_scale"])
        )
        bev["em"], pt["BEV"], out["pt_type"] = em, bev, pt
    if "accessory_power_w" in technology:
        out["pwr_aux_base_watts"] = float(technology["accessory_power_w"])
    return out


def _sim_params():
    """The conventional peer's simulation parameters (a trace miss is reported, not an error)."""
    from .peer import _sim_params as conventional

    return conventional()


def _bev_cycle(cycle_name: str):
    """The vpsim cycle of a BEV test (:data:`BEV_CYCLES`), or ValueError."""
    from ..cycles import load_cycle

    if cycle_name not in BEV_CYCLES:
        raise ValueError(f"unknown BEV test cycle {cycle_name!r}; expected one of {', '.join(BEV_CYCLES)}")
    return load_cycle(cycle_name)


def _fastsim_cycle(cycle_name: str):
    """FASTSim's cycle of a BEV test (one per process: :func:`vpsim.fleet.peer_cache._fastsim_cycle`)."""
    from .peer_cache import _fastsim_cycle

    return _fastsim_cycle(_bev_cycle(cycle_name))


def run_bev_peer(vehicle_dict: dict, cycle_name: str) -> dict:
    """FASTSim on ``vehicle_dict`` (:func:`bev_peer_vehicle`) over ``cycle_name`` ('udds' or 'hwfet').

    Returns ``mpge`` (wall energy), ``wall_wh_per_km``, ``battery_wh_per_km`` (net chemical),
    ``terminal_wh_per_km`` (net at the battery's terminals), ``distance_m``, ``trace_miss`` (True when the
    car fell behind the trace), ``trace_miss_m`` (distance short of the trace's), the wheel's road-load
    energies ``rolling_wh`` and ``drag_wh``, ``friction_brake_wh`` and ``aux_wh``."""
    from . import peer_cache

    o = peer_cache.run(vehicle_dict, _bev_cycle(cycle_name))  # (remembered: vpsim.fleet.peer_cache)
    state = o["veh"]["state"]
    res = o["veh"]["pt_type"]["BEV"]["res"]["state"]
    dist_m = float(state["dist_meters"])
    chem_j = float(res["energy_out_chemical_joules"])
    wall_j = chem_j / CHARGER_EFFICIENCY
    trace = _trace_distance(cycle_name)
    km = dist_m / 1e3
    return {
        "mpge": (dist_m / METRES_PER_MILE) / (wall_j / 3.6e6 / KWH_PER_GALLON_EQUIVALENT),
        "wall_wh_per_km": wall_j / 3600.0 / km,
        "battery_wh_per_km": chem_j / 3600.0 / km,
        "terminal_wh_per_km": float(res["energy_out_electrical_joules"]) / 3600.0 / km,
        "distance_m": dist_m,
        "trace_miss": not bool(state["cyc_met_overall"]),
        "trace_miss_m": trace - dist_m,
        "rolling_wh": float(state["energy_rr_joules"]) / 3600.0,
        "drag_wh": float(state["energy_drag_joules"]) / 3600.0,
        "friction_brake_wh": float(state["energy_brake_joules"]) / 3600.0,
        "aux_wh": float(state["energy_aux_joules"]) / 3600.0,
    }


def _trace_distance(cycle_name: str) -> float:
    from ..cycles import load_cycle

    cyc = load_cycle(cycle_name)
    return float(np.sum(0.5 * (cyc.speed_mps[1:] + cyc.speed_mps[:-1]) * np.diff(cyc.time_s)))


def _vehicle_of(row, cycle_name: str, technology: dict | None = None) -> dict:
    """The peer vehicle of a record row (:func:`ev_records`' columns), its road load folded over the cycle."""
    return bev_peer_vehicle(
        row["mass_kg"],
        row["a_n"],
        row["b_n_per_mps"],
        row["c_n_per_mps2"],
        row["rated_power_w"],
        technology,
        fold_cycles=(cycle_name,),
    )


def _error_text(exc) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}"[:200]


def bev_peer_chunk(items: list[tuple]) -> list[dict]:
    """FASTSim's BEV on each (record row, cycle name[, technology]): a record row is a mapping with
    :func:`ev_records`' columns; dicts with ``key``, ``cycle`` and :func:`run_bev_peer`'s figures, or
    ``peer_error``. The road load is folded over the cycle run (as :func:`vpsim.fleet.peer.peer_chunk`)."""
    out = []
    for item in items:
        row, name = item[0], item[1]
        tech = item[2] if len(item) > 2 else None
        r = {"key": _key(row), "cycle": name, "mpge": math.nan, "peer_error": ""}
        try:
            r.update(run_bev_peer(_vehicle_of(row, name, tech), name))
        except Exception as exc:  # FASTSim raises its own error types (Rust errors as RuntimeError)
            r["peer_error"] = _error_text(exc)
        out.append(r)
    return out


def _key(row) -> str:
    return f"{row['test_vehicle_id']}#{row['config']}#{row.get('variant', 0)}"


def bev_calibration_chunk(items: list[tuple]) -> list[dict]:
    """FASTSim's BEV on each (record row, cycle name) at every (scale, accessory power) of
    :data:`CAL_SCALE` x :data:`CAL_AUX`: ``log_wh_per_km`` (len(CAL_SCALE), len(CAL_AUX)) of wall energy,
    or ``peer_error``."""
    out = []
    for row, name in items:
        r = {"key": _key(row), "cycle": name, "log_wh_per_km": None, "peer_error": ""}
        try:
            d = _vehicle_of(row, name)  # the record's vehicle once, its technology varied
            grid = np.empty((len(CAL_SCALE), len(CAL_AUX)))
            for i, s in enumerate(CAL_SCALE):
                for j, aux in enumerate(CAL_AUX):
                    tech = {"drivetrain_efficiency_scale": s, "accessory_power_w": aux}
                    grid[i, j] = math.log(run_bev_peer(with_bev_technology(d, tech), name)["wall_wh_per_km"])
            if not np.all(np.isfinite(grid)):
                raise ValueError("non-finite energy on the calibration grid")
            r["log_wh_per_km"] = grid
        except Exception as exc:
            r["peer_error"] = _error_text(exc)
        out.append(r)
    return out


def _lagrange(nodes, fine) -> np.ndarray:
    x = np.asarray(nodes, dtype=float)
    lag = np.empty((len(x), fine.size))
    for i in range(len(x)):
        others = [k for k in range(len(x)) if k != i]
        lag[i] = np.prod([(fine - x[k]) / (x[i] - x[k]) for k in others], axis=0)
    return lag


def _bev_surrogate(grid: np.ndarray) -> np.ndarray:
    """ln energy on (SCALE_FINE, AUX_FINE) for each row of ``grid`` (rows, len(CAL_SCALE), len(CAL_AUX)):
    quadratic through the three nodes of each axis."""
    return np.einsum("rij,ia,jb->rab", grid, _lagrange(CAL_SCALE, SCALE_FINE), _lagrange(CAL_AUX, AUX_FINE))


def fit_bev_peer(grid: np.ndarray, log_measured: np.ndarray) -> tuple[dict, float]:
    """The BEV peer technology minimising mean |ln(pred / meas)| over the rows (ln wall energy per
    distance, measured and on the grid); (params, loss)."""
    if grid.shape[0] == 0:
        raise ValueError("no vehicle to fit the BEV peer's technology on")
    resid = _bev_surrogate(grid) - np.asarray(log_measured)[:, None, None]
    loss = np.mean(np.abs(resid), axis=0)
    i, j = np.unravel_index(int(np.argmin(loss)), loss.shape)
    return {
        "drivetrain_efficiency_scale": float(SCALE_FINE[i]),
        "accessory_power_w": float(AUX_FINE[j]),
    }, float(loss[i, j])


def calibrate_bev_peer(grid, log_measured, vehicle_fold, k, vehicle_class=None, classes=BEV_CLASSES) -> dict:
    """The BEV peer's technology per (fold, class), each fitted without that fold's rows, by vpsim's own
    cross-validation procedure (:func:`vpsim.fleet.calibrate.per_fold_and_class`). ``vehicle_class``: each
    row's class (vpsim's, :func:`vpsim.fleet.ev.ev_class`, so that the peer gets the same split); default
    all ``"bev"``."""
    from .calibrate import per_fold_and_class

    vehicle_fold = np.asarray(vehicle_fold)
    if vehicle_class is None:
        vehicle_class = np.full(vehicle_fold.shape, BEV_CLASSES[0], dtype=object)
    return per_fold_and_class(
        lambda rows: fit_bev_peer(grid[rows], log_measured[rows]), vehicle_fold, vehicle_class, k, classes
    )


def wh_per_km_from_mpge(mpge):
    """Wall energy per distance (Wh/km) of a fuel economy in MPGe (33.705 kWh per gallon equivalent)."""
    return KWH_PER_GALLON_EQUIVALENT * 1e3 / (np.asarray(mpge, dtype=float) * METRES_PER_MILE / 1e3)


# --- the EPA list's electric records ------------------------------------------------------------------------
EV_FUEL = "Electricity"
EV_TESTS = {"Charge Depleting UDDS": "udds", "Charge Depleting Highway": "hwy"}
# RND_ADJ_FE of an electric test is MPGe, but some manufacturers' rows (FE_UNIT still "MPG") hold kWh per
# 100 miles: 17-38 with the UDDS figure *below* the highway one (an EV uses less energy in town). No 2022 EV
# reaches below 60 MPGe unadjusted; a value under this is read as kWh/100 mi, MPGe = 3370.5 / value.
KWH_PER_100MI_BELOW = 60.0
EV_COLUMNS = (
    "test_vehicle_id",
    "config",
    "make",
    "model",
    "mass_kg",
    "a_n",
    "b_n_per_mps",
    "c_n_per_mps2",
    "rated_power_w",
    "udds_mpge",
    "hwy_mpge",
)


def ev_records(csv_path, report: dict | None = None):
    """The list's battery-electric records, one row per vehicle (``Test Vehicle ID`` + configuration, and
    the record's own model, test weight, road load and rated power: one ID + configuration is sometimes
    tested as two represented models), with its two charge-depleting tests paired: columns
    :data:`EV_COLUMNS` (SI units, measured unadjusted MPGe) plus ``variant``, ``n_udds``, ``n_hwy``,
    ``drive`` and ``fe_in_kwh_per_100mi`` (the record's figures were kWh/100 mi, converted).

    Repeated tests of a vehicle on one cycle are averaged in energy per distance (the harmonic mean of
    MPGe). ``report``, if given, is filled with ``n_rows``, ``n_vehicles``, ``n_paired`` and
    ``unpaired`` (a list of (vehicle, why))."""
    import pandas as pd

    from ..errors import VpsimError
    from ..textio import check_regular_file
    from .epa import (
        HP_TO_KW,
        LB_TO_KG,
        LBF_TO_N,
        lbf_per_mph2_to_si,
        lbf_per_mph_to_si,
        list_separator,
        named_make,
    )

    csv_path = check_regular_file(csv_path, VpsimError, "CSV test car list")
    df = pd.read_csv(
        csv_path, sep=list_separator(csv_path), encoding="utf-8-sig", dtype=str, keep_default_na=False
    )
    df.columns = [c.strip() for c in df.columns]
    ev = df[(df["Test Fuel Type Description"].str.strip() == EV_FUEL)]
    ev = ev[ev["Test Procedure Description"].str.strip().isin(EV_TESTS)]
    key_cols = [
        "Test Vehicle ID",
        "Test Veh Configuration #",
        "Represented Test Veh Make",
        "Represented Test Veh Model",
        "Equivalent Test Weight (lbs.)",
        "Target Coef A (lbf)",
        "Target Coef B (lbf/mph)",
        "Target Coef C (lbf/mph**2)",
        "Rated Horsepower",
    ]
    rows, unpaired = [], []
    variants: dict = {}
    for key, g in ev.groupby(key_cols, sort=False):
        vid, cfg, model = key[0].strip(), key[1].strip(), key[3].strip()
        maker = g["Vehicle Manufacturer Name"].iloc[0] if "Vehicle Manufacturer Name" in g else ""
        make = named_make(key[2].strip(), maker.strip())
        name = f"{vid}#{cfg} {make} {model}"
        try:
            etw, a, b, c, hp = (float(x) for x in key[4:])
            fe = {
                t: [float(x) for x in g.loc[g["Test Procedure Description"].str.strip() == p, "RND_ADJ_FE"]]
                for p, t in EV_TESTS.items()
            }
        except ValueError:
            unpaired.append((name, "a field is not a number"))
            continue
        missing = [t for t, xs in fe.items() if not xs]
        if missing:
            unpaired.append((name, f"no {' / '.join(missing)} test"))
            continue
        if not all(math.isfinite(x) and x > 0 for xs in fe.values() for x in xs):
            unpaired.append((name, "an RND_ADJ_FE is not a positive number"))
            continue
        low = [x < KWH_PER_100MI_BELOW for xs in fe.values() for x in xs]
        if any(low) and not all(low):
            unpaired.append((name, "one test in MPGe, the other apparently in kWh/100 mi"))
            continue
        in_kwh = all(low)
        mpge = {}
        for t, xs in fe.items():
            vals = [KWH_PER_GALLON_EQUIVALENT * 100.0 / x for x in xs] if in_kwh else xs
            mpge[t] = len(vals) / sum(1.0 / v for v in vals)
        variant = variants.setdefault((vid, cfg), 0)
        variants[(vid, cfg)] += 1
        rows.append(
            {
                "test_vehicle_id": vid,
                "config": int(float(cfg)),
                "make": make,
                "model": model,
                "mass_kg": etw * LB_TO_KG,
                "a_n": a * LBF_TO_N,
                "b_n_per_mps": lbf_per_mph_to_si(b),
                "c_n_per_mps2": lbf_per_mph2_to_si(c),
                "rated_power_w": hp * HP_TO_KW * 1e3,
                "udds_mpge": mpge["udds"],
                "hwy_mpge": mpge["hwy"],
                "variant": variant,
                "n_udds": len(fe["udds"]),
                "n_hwy": len(fe["hwy"]),
                "drive": g["Drive System Code"].iloc[0].strip(),
                "fe_in_kwh_per_100mi": in_kwh,
            }
        )
    out = pd.DataFrame(
        rows, columns=[*EV_COLUMNS, "variant", "n_udds", "n_hwy", "drive", "fe_in_kwh_per_100mi"]
    )
    if report is not None:
        report.update(
            n_rows=len(ev), n_vehicles=len(out) + len(unpaired), n_paired=len(out), unpaired=unpaired
        )
    return out


__all__ = [
    "BEV_PEER_PARAMS",
    "CHARGER_EFFICIENCY",
    "EV_COLUMNS",
    "KWH_PER_GALLON_EQUIVALENT",
    "PEER_BEV_VEHICLE",
    "bev_calibration_chunk",
    "bev_peer_chunk",
    "bev_peer_vehicle",
    "calibrate_bev_peer",
    "ev_records",
    "fit_bev_peer",
    "run_bev_peer",
    "wh_per_km_from_mpge",
    "with_bev_technology",
]
