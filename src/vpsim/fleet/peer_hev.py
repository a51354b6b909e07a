"""The hybrid peer: FASTSim 3.1's hybrid (``HEV``) on the EPA 2022 list's full-hybrid records.

Each record becomes a FASTSim hybrid built from one of the two hybrids FASTSim ships, by layout
(:data:`PEER_HEV_VEHICLE`): the ``2016_TOYOTA_Prius_Two.yaml`` for a power split, the
``2021_Hyundai_Sonata_Hybrid_Blue_thrml.yaml`` for a P2 (FASTSim's hybrid model is one generic parallel
powertrain with its own rule-based control; the resource sets its engine and motor curves and control
constants). What the record gives is put in as vpsim's :mod:`vpsim.fleet.hev` does:

* the resources as FASTSim ships them otherwise: the Prius has no thermal model; the Sonata's thermal
  models (engine, battery, cabin, HVAC) stay, because FASTSim 3.1 fails at the first step with them removed
  (``None``, as the BEV peer does with the Model 3's) and with the control's engine-temperature thresholds
  cleared as well;
* mass: the equivalent test weight (``mass_kilograms``); road load: the same fold of the record's A/B/C
  into c_r and C_d A as vpsim's over the cycle run (:func:`vpsim.fleet.vehicle.fold_road_load`), wheel radius
  as vpsim's;
* the engine's maximum power: the record's rated power; the motor's: vpsim's rule
  (:func:`vpsim.fleet.hev.machine_sizes`);
* everything else FASTSim's defaults, among them its state-of-charge balancing (the run is repeated until
  the battery ends where it began, FASTSim's ``balance_soc``): its fuel is charge-sustaining, as vpsim's
  corrected figure.

Two peers, as for the conventional and electric cars: ``fastsim`` (FASTSim's defaults, nothing fitted:
``fastsim_by_powertrain.hev``) and a calibrated one given the same chance as vpsim's hybrids, whose
technology (thermal efficiency, accessory power) is fitted per class out of fold. The peer's two
parameters (:data:`HEV_PEER_PARAMS`) are their analogues:

* ``efficiency_scale`` s: the engine's efficiency curve (``fc.eff_interp_from_pwr_out``) times s. On the
  Prius the fuel is exactly proportional to 1/s (checked: 0.9000 on UDDS, HWFET and US06); on the Sonata it
  is not (0.92: its engine's thermal model and its control react to the fuel burned), so s is searched,
  not solved;
* ``accessory_power_w``: FASTSim's ``pwr_aux_base_watts``.

FASTSim runs each record and test at :data:`CAL_SCALE` x :data:`CAL_AUX` (:func:`hev_calibration_chunk`);
ln fuel is interpolated quadratically in ln s (exact where the fuel is proportional to 1/s) and in the
accessory power on a fine grid, and the pair minimising vpsim's loss (mean |ln(pred / meas)| over the
training vehicles' tests) is taken per fold and class, the classes vpsim's
(:func:`vpsim.fleet.hev.hev_class`), by vpsim's own cross-validation procedure
(:func:`calibrate_hev_peer`). Every record is then run once more at its fold's values
(:func:`hev_peer_chunk` with a technology): the ``fastsim_calibrated_by_powertrain.hev`` figures.

Fuel: FASTSim's fuel energy over 33.7 kWh per gallon (as :mod:`vpsim.fleet.peer`).
"""

from __future__ import annotations

import copy
import math

import numpy as np

PEER_HEV_VEHICLE = {
    "hev_split": "2016_TOYOTA_Prius_Two.yaml",
    "hev_p2": "2021_Hyundai_Sonata_Hybrid_Blue_thrml.yaml",
}
HEV_PEER_PARAMS = ("efficiency_scale", "accessory_power_w")
CAL_SCALE = (0.6, 1.0, 1.6)  # the engine-efficiency scales FASTSim runs at (the conventional peer's bounds)
CAL_AUX = (0.0, 1000.0, 2500.0)  # W (the conventional and electric peers' nodes)
SCALE_FINE = np.exp(np.linspace(math.log(CAL_SCALE[0]), math.log(CAL_SCALE[-1]), 97))
AUX_FINE = np.arange(0.0, 2500.1, 25.0)
_BASE: dict = {}


def _base_vehicle(layout: str) -> dict:
    if layout not in _BASE:
        import fastsim as fsim

        d = fsim.Vehicle.from_resource(PEER_HEV_VEHICLE[layout]).to_dict()
        hev = d["pt_type"]["HEV"]
        d["save_interval"] = None
        for part in ("res", "fc", "em", "transmission"):
            if isinstance(hev.get(part), dict) and "save_interval" in hev[part]:
                hev[part]["save_interval"] = None
        _BASE[layout] = d
    return _BASE[layout]


def hev_peer_vehicle(rec, cycle_name: str, technology: dict | None = None) -> dict:
    """The FASTSim hybrid dict of a :class:`vpsim.fleet.hev.HEVRecord` (module docstring), with
    ``technology`` (:data:`HEV_PEER_PARAMS`; default FASTSim's own)."""
    from ..cycles import load_cycle
    from ..params import load_parameters
    from .hev import PRESET, machine_sizes
    from .vehicle import FRONTAL_AREA_M2, WHEEL_RADIUS_M, fold_road_load

    c_r, c_d, _ = fold_road_load(rec, [load_cycle(cycle_name)])
    d = copy.deepcopy(_base_vehicle(rec.layout))
    d["name"] = f"HEV peer {rec.key}"
    d["mass_kilograms"] = float(rec.mass_kg)
    ch = d["chassis"]
    ch["drag_coef"] = c_d
    ch["frontal_area_square_meters"] = FRONTAL_AREA_M2
    ch["wheel_rr_coef"] = c_r
    ch["wheel_radius_meters"] = WHEEL_RADIUS_M
    hev = d["pt_type"]["HEV"]
    hev["mass_kilograms"] = None
    hev["fc"]["pwr_out_max_watts"] = float(rec.rated_power_kw * 1e3)
    hev["em"]["pwr_out_max_watts"] = float(machine_sizes(rec, load_parameters(PRESET[rec.layout]))["machine"])
    return with_hev_technology(d, technology)


def with_hev_technology(d: dict, technology: dict | None) -> dict:
    """``d`` (from :func:`hev_peer_vehicle`) with ``technology`` put in (:data:`HEV_PEER_PARAMS`); a new
    dict sharing everything else with ``d``."""
    if not technology:
        return d
    unknown = set(technology) - set(HEV_PEER_PARAMS)
    if unknown:
        raise ValueError(f"unknown hybrid peer parameter(s) {', '.join(sorted(unknown))}")
    out = dict(d)
    if "efficiency_scale" in technology:
        s = float(technology["efficiency_scale"])
        if not s > 0.0:
            raise ValueError(
                f"efficiency_scale = {s!r}: expected a positive scale of the engine's efficiency"
            )
        pt = dict(d["pt_type"])
        hev = dict(pt["HEV"])
        fc = dict(hev["fc"])
        interp = dict(fc["eff_interp_from_pwr_out"])
        data = dict(interp["data"])
        values = dict(data["values"])
        values["data"] = [
            s * e for e in d["pt_type"]["HEV"]["fc"]["eff_interp_from_pwr_out"]["data"]["values"]["data"]
        ]
        data["values"], interp["data"], fc["eff_interp_from_pwr_out"] = values, data, interp
        hev["fc"], pt["HEV"], out["pt_type"] = fc, hev, pt
    if "accessory_power_w" in technology:
        out["pwr_aux_base_watts"] = float(technology["accessory_power_w"])
    return out


def run_hev_peer(d: dict, cycle_name: str) -> dict:
    """FASTSim on ``d`` over ``cycle_name`` (a vpsim cycle): ``peer_mpg``, ``trace_miss``."""
    from ..cycles import load_cycle
    from ..units import METRES_PER_MILE
    from . import peer_cache
    from .peer import GASOLINE_J_PER_GAL

    o = peer_cache.run(d, load_cycle(cycle_name))  # (remembered: vpsim.fleet.peer_cache)
    state = o["veh"]["state"]
    fuel_j = float(o["veh"]["pt_type"]["HEV"]["fc"]["state"]["energy_fuel_joules"])
    dist_m = float(state["dist_meters"])
    return {
        "peer_mpg": (dist_m / METRES_PER_MILE) / (fuel_j / GASOLINE_J_PER_GAL),
        "trace_miss": not bool(state["cyc_met_overall"]),
    }


def hev_peer_chunk(items: list[tuple]) -> list[dict]:
    """FASTSim's hybrid on each (record, test[, technology]): dicts with ``key``, ``cycle``, ``peer_mpg`` or
    ``peer_error``."""
    from .hev import SIM_CYCLE
    from .peer_bev import _error_text

    out = []
    for item in items:
        rec, name = item[0], item[1]
        tech = item[2] if len(item) > 2 else None
        r = {"key": rec.key, "cycle": name, "peer_mpg": math.nan, "peer_error": "", "trace_miss": None}
        try:
            r.update(run_hev_peer(hev_peer_vehicle(rec, SIM_CYCLE[name], tech), SIM_CYCLE[name]))
        except Exception as exc:  # FASTSim raises its own error types (Rust errors as RuntimeError)
            r["peer_error"] = _error_text(exc)
        out.append(r)
    return out


def hev_calibration_chunk(items: list[tuple]) -> list[dict]:
    """FASTSim's hybrid on each (record, test) at every (scale, accessory power) of :data:`CAL_SCALE` x
    :data:`CAL_AUX`: ``log_l100`` (len(CAL_SCALE), len(CAL_AUX)) of charge-sustaining L/100 km, or
    ``peer_error``."""
    from ..units import mpg_from_l_per_100km
    from .hev import SIM_CYCLE
    from .peer_bev import _error_text

    out = []
    for rec, name in items:
        r = {"key": rec.key, "cycle": name, "log_l100": None, "peer_error": ""}
        try:
            d = hev_peer_vehicle(rec, SIM_CYCLE[name])  # the record's vehicle once, its technology varied
            grid = np.empty((len(CAL_SCALE), len(CAL_AUX)))
            for i, s in enumerate(CAL_SCALE):
                for j, aux in enumerate(CAL_AUX):
                    tech = {"efficiency_scale": s, "accessory_power_w": aux}
                    mpg = run_hev_peer(with_hev_technology(d, tech), SIM_CYCLE[name])["peer_mpg"]
                    grid[i, j] = math.log(mpg_from_l_per_100km(mpg))
            if not np.all(np.isfinite(grid)):
                raise ValueError("non-finite fuel on the calibration grid")
            r["log_l100"] = grid
        except Exception as exc:  # FASTSim raises its own error types (Rust errors as RuntimeError)
            r["peer_error"] = _error_text(exc)
        out.append(r)
    return out


def _hev_surrogate(grid: np.ndarray) -> np.ndarray:
    """ln fuel on (SCALE_FINE, AUX_FINE) for each row of ``grid`` (rows, len(CAL_SCALE), len(CAL_AUX)):
    quadratic through the three nodes of each axis, in ln s on the scale's."""
    from .peer_bev import _lagrange

    lag_s = _lagrange(np.log(CAL_SCALE), np.log(SCALE_FINE))
    return np.einsum("rij,ia,jb->rab", grid, lag_s, _lagrange(CAL_AUX, AUX_FINE))


def fit_hev_peer(grid: np.ndarray, log_measured: np.ndarray) -> tuple[dict, float]:
    """The hybrid peer's technology minimising mean |ln(pred / meas)| over the rows (ln L/100 km, measured
    and on the grid); (params, loss)."""
    if grid.shape[0] == 0:
        raise ValueError("no vehicle to fit the hybrid peer's technology on")
    resid = _hev_surrogate(grid) - np.asarray(log_measured)[:, None, None]
    loss = np.mean(np.abs(resid), axis=0)
    i, j = np.unravel_index(int(np.argmin(loss)), loss.shape)
    return {"efficiency_scale": float(SCALE_FINE[i]), "accessory_power_w": float(AUX_FINE[j])}, float(
        loss[i, j]
    )


def calibrate_hev_peer(grid, log_measured, vehicle_fold, vehicle_class, k, classes) -> dict:
    """The hybrid peer's technology per (fold, class), each fitted without that fold's rows, by vpsim's own
    cross-validation procedure (:func:`vpsim.fleet.calibrate.per_fold_and_class`); ``vehicle_class``:
    vpsim's class of each row, so that the peer gets the same split."""
    from .calibrate import per_fold_and_class

    return per_fold_and_class(
        lambda rows: fit_hev_peer(grid[rows], log_measured[rows]),
        np.asarray(vehicle_fold),
        np.asarray(vehicle_class, dtype=object),
        k,
        classes,
    )


__all__ = [
    "CAL_AUX",
    "CAL_SCALE",
    "HEV_PEER_PARAMS",
    "PEER_HEV_VEHICLE",
    "calibrate_hev_peer",
    "fit_hev_peer",
    "hev_calibration_chunk",
    "hev_peer_chunk",
    "hev_peer_vehicle",
    "run_hev_peer",
    "with_hev_technology",
]
