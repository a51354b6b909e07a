"""The peer: FASTSim 3.1 (``pip install 'vpsim[bench]'``) on the same records and cycles.

Each record becomes a FASTSim conventional vehicle: FASTSim's own 2012 Ford Fusion resource (the
conventional vehicle it ships) with what the record gives put in:

* mass: the equivalent test weight (FASTSim's top-level ``mass_kilograms``);
* road load: the *same* fold of the record's A/B/C into c_r and C_d A as vpsim's, over the same cycle
  (:func:`vpsim.fleet.vehicle.fold_road_load`; FASTSim's road load is m g c_r + 1/2 rho C_d A v^2 too, with
  rho = 1.2 kg/m^3 in its standard conditions, the value of the fold), wheel radius as vpsim's;
* rated power: the fuel converter's maximum power, its initial (ramp) power in the Fusion's proportion;
* everything else FASTSim's own defaults: the Fusion's efficiency curve against the fraction of rated
  power, its power ramp (6 s from the initial power), transmission efficiency 0.875, 700 W of
  accessories, no fuel cut-off. A car that cannot follow the trace (the ramp limits the launches of US06)
  is run with FASTSim's ``trace_miss_opts = "Allow"`` and reported as a trace miss.

Fuel energy is turned into gallons with EPA's 33.7 kWh per gallon of gasoline (as ``vpsim bench`` does).

Two peers are reported. ``fastsim``: FASTSim's own defaults, nothing fitted. ``fastsim_calibrated``: FASTSim
given the same chance as vpsim, three technology parameters per class (:data:`PEER_PARAMS`) fitted on the
same folds by the same loss (mean |ln(predicted / measured)| over the training vehicles' cycles, an L1
loss), then every vehicle run once more at its own fold's values:

* ``efficiency_scale`` s: the fuel converter's efficiency curve times s (the analogue of vpsim's thermal
  efficiency): FASTSim's fuel is exactly proportional to 1/s (checked), so s is solved, not searched;
* ``accessory_power_w``: FASTSim's ``pwr_aux_base_watts`` (vpsim's accessory power);
* ``part_load_exponent`` q: the curve's shape, eff(x) = s e_peak (e(x) / e_peak)^q: below 1 it raises the
  part-load efficiency relative to the peak, above 1 it lowers it (the analogue of vpsim's friction, which
  sets the part-load efficiency). Searched over 0.7-1.3, the scale over 0.6-1.6, the accessories over
  0-2.5 kW.

FASTSim runs each record and cycle at :data:`CAL_AUX` x :data:`CAL_Q` (s = 1); the fit interpolates ln fuel
(quadratically in the accessory power, linearly in q) on a fine grid, the scale by the loss's median
(the L1 minimiser). :func:`calibrate_peer` does it for any powertrain's rows, so the battery-electric and
hybrid peers use the same method (``peer.fastsim_calibrated_by_powertrain``).
"""

from __future__ import annotations

import math

import numpy as np

from ..units import METRES_PER_MILE, mpg_from_l_per_100km
from .epa import VehicleRecord

PEER_VERSION = "3.1.0"
PEER_PARAMS = ("efficiency_scale", "accessory_power_w", "part_load_exponent")
CAL_AUX = (0.0, 1000.0, 2500.0)  # W: the accessory powers FASTSim runs at
CAL_Q = (0.7, 1.3)  # the part-load exponents it runs at (1: FASTSim's own curve)
AUX_FINE = np.arange(0.0, 2500.1, 25.0)
Q_FINE = np.linspace(0.7, 1.3, 25)
SCALE_BOUNDS = (0.6, 1.6)
PEER_VEHICLE = "2012_Ford_Fusion.yaml"
GASOLINE_J_PER_GAL = 33.7 * 3.6e6


def status() -> dict:
    """{"available": bool, "version": str | None, "reason": str}: whether the peer can be measured."""
    try:
        import fastsim
    except Exception as exc:  # not installed, or broken
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        return {
            "available": False,
            "version": None,
            "reason": f"not installed ({first}); pip install 'vpsim[bench]'",
        }
    version = getattr(fastsim, "__version__", None)
    if version is None:
        try:
            from importlib.metadata import version as _v

            version = _v("fastsim")
        except Exception:
            version = None
    if version != PEER_VERSION:
        return {
            "available": False,
            "version": version,
            "reason": f"fastsim {version} installed; needs {PEER_VERSION}",
        }
    return {"available": True, "version": version, "reason": ""}


_BASE: dict = {}


def _base_vehicle() -> dict:
    if not _BASE:
        import fastsim as fsim

        d = fsim.Vehicle.from_resource(PEER_VEHICLE).to_dict()
        d["save_interval"] = None
        conv = d["pt_type"]["Conv"]
        conv["fc"]["save_interval"] = None
        conv["transmission"]["save_interval"] = None
        _BASE.update(d)
    return _BASE


def peer_vehicle(rec: VehicleRecord, cycle, technology: dict | None = None) -> dict:
    """The FASTSim vehicle dict of a record on ``cycle`` (the road load folded over that cycle), with
    ``technology`` (:data:`PEER_PARAMS`; default FASTSim's own)."""
    import copy

    from .vehicle import FRONTAL_AREA_M2, WHEEL_RADIUS_M, fold_road_load

    d = copy.deepcopy(_base_vehicle())
    c_r, c_d, _ = fold_road_load(rec, [cycle])
    d["name"] = f"{rec.make} {rec.model} ({rec.key})"
    d["mass_kilograms"] = rec.mass_kg
    ch = d["chassis"]
    ch["drag_coef"] = c_d
    ch["frontal_area_square_meters"] = FRONTAL_AREA_M2
    ch["wheel_rr_coef"] = c_r
    ch["wheel_radius_meters"] = WHEEL_RADIUS_M
    fc = d["pt_type"]["Conv"]["fc"]
    ratio = fc["pwr_out_max_init_watts"] / fc["pwr_out_max_watts"]
    fc["pwr_out_max_watts"] = rec.rated_power_kw * 1e3
    fc["pwr_out_max_init_watts"] = rec.rated_power_kw * 1e3 * ratio
    return with_technology(d, technology)


def with_technology(d: dict, technology: dict | None) -> dict:
    """``d`` (from :func:`peer_vehicle`, FASTSim's defaults) with ``technology`` put in (:data:`PEER_PARAMS`);
    a new dict sharing everything else with ``d``."""
    if not technology:
        return d
    out = dict(d)
    pt = dict(d["pt_type"])
    conv = dict(pt["Conv"])
    fc = dict(conv["fc"])
    interp = dict(fc["eff_interp_from_pwr_out"])
    data = dict(interp["data"])
    values = dict(data["values"])
    eff = _base_vehicle()["pt_type"]["Conv"]["fc"]["eff_interp_from_pwr_out"]["data"]["values"]["data"]
    peak = max(eff)
    s = technology.get("efficiency_scale", 1.0)
    q = technology.get("part_load_exponent", 1.0)
    values["data"] = [s * peak * (e / peak) ** q for e in eff]
    data["values"], interp["data"], fc["eff_interp_from_pwr_out"] = values, data, interp
    conv["fc"], pt["Conv"], out["pt_type"] = fc, conv, pt
    if "accessory_power_w" in technology:
        out["pwr_aux_base_watts"] = float(technology["accessory_power_w"])
    return out


def _sim_params():
    import fastsim as fsim

    params = fsim.SimParams.default().to_dict()
    params["trace_miss_opts"] = "Allow"  # a car that cannot follow the trace is reported, not an error
    return fsim.SimParams.from_dict(params)


def _run(rec, name, technology=None, vehicle=None) -> tuple[float, bool]:
    """(mpg, trace met) of FASTSim on one record and fleet cycle (``vehicle``: its :func:`peer_vehicle`
    dict with FASTSim's defaults, if at hand); the run remembered (:mod:`vpsim.fleet.peer_cache`)."""
    from . import peer_cache
    from .cycles import fleet_cycle

    cyc = fleet_cycle(name)
    d = peer_vehicle(rec, cyc) if vehicle is None else vehicle
    o = peer_cache.run(with_technology(d, technology), cyc)
    fuel_j = o["veh"]["pt_type"]["Conv"]["fc"]["state"]["energy_fuel_joules"]
    dist_m = o["veh"]["state"]["dist_meters"]
    return (dist_m / METRES_PER_MILE) / (fuel_j / GASOLINE_J_PER_GAL), bool(
        o["veh"]["state"]["cyc_met_overall"]
    )


def _error_text(exc) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}"[:200]


def peer_chunk(items: list[tuple]) -> list[dict]:
    """FASTSim on each (record, fleet cycle[, technology]); dicts with ``peer_mpg`` or ``peer_error``."""
    out = []
    for item in items:
        rec, name = item[0], item[1]
        tech = item[2] if len(item) > 2 else None
        row = {"key": rec.key, "cycle": name, "peer_mpg": math.nan, "peer_error": "", "peer_trace_met": None}
        try:
            row["peer_mpg"], row["peer_trace_met"] = _run(rec, name, tech)
        except Exception as exc:  # FASTSim raises its own error types (Rust errors as RuntimeError)
            row["peer_error"] = _error_text(exc)
        out.append(row)
    return out


def calibration_chunk(items: list[tuple]) -> list[dict]:
    """FASTSim on each (record, fleet cycle) at every (accessory power, part-load exponent) of
    :data:`CAL_AUX` x :data:`CAL_Q`: ``log_l100`` (len(CAL_AUX), len(CAL_Q)), or ``peer_error``."""
    out = []
    for rec, name in items:
        row = {"key": rec.key, "cycle": name, "log_l100": None, "peer_error": ""}
        try:
            from .cycles import fleet_cycle

            d = peer_vehicle(rec, fleet_cycle(name))  # the record's vehicle once, its technology varied
            grid = np.empty((len(CAL_AUX), len(CAL_Q)))
            for i, aux in enumerate(CAL_AUX):
                for j, q in enumerate(CAL_Q):
                    tech = {"accessory_power_w": aux, "part_load_exponent": q}
                    mpg, _ = _run(rec, name, tech, vehicle=d)
                    grid[i, j] = math.log(mpg_from_l_per_100km(mpg))  # L/100 km
            if not np.all(np.isfinite(grid)):
                raise ValueError("non-finite fuel on the calibration grid")
            row["log_l100"] = grid
        except Exception as exc:
            row["peer_error"] = _error_text(exc)
        out.append(row)
    return out


def _surrogate(grid: np.ndarray) -> np.ndarray:
    """ln fuel at s = 1 on (AUX_FINE, Q_FINE) for each row of ``grid`` (rows, len(CAL_AUX), len(CAL_Q)):
    quadratic through the three accessory powers, linear in the exponent."""
    x = np.asarray(CAL_AUX)
    lag = np.empty((len(x), AUX_FINE.size))
    for i in range(len(x)):
        others = [k for k in range(len(x)) if k != i]
        lag[i] = np.prod([(AUX_FINE - x[k]) / (x[i] - x[k]) for k in others], axis=0)
    in_aux = np.einsum("rij,ia->raj", grid, lag)  # (rows, aux, q nodes)
    w = (Q_FINE - CAL_Q[0]) / (CAL_Q[1] - CAL_Q[0])
    return in_aux[:, :, :1] * (1 - w)[None, None, :] + in_aux[:, :, 1:2] * w[None, None, :]


def fit_peer(grid: np.ndarray, log_measured: np.ndarray) -> tuple[dict, float]:
    """The peer technology minimising mean |ln(pred / meas)| over the rows; (params, loss)."""
    if grid.shape[0] == 0:
        raise ValueError("no vehicle to fit the peer's technology on")
    sur = _surrogate(grid)  # ln fuel at s = 1
    resid = sur - log_measured[:, None, None]  # ln pred - ln meas = resid - ln s
    ln_s = np.clip(np.median(resid, axis=0), *np.log(SCALE_BOUNDS))
    loss = np.mean(np.abs(resid - ln_s[None]), axis=0)
    i, j = np.unravel_index(int(np.argmin(loss)), loss.shape)
    params = {
        "efficiency_scale": float(np.exp(ln_s[i, j])),
        "accessory_power_w": float(AUX_FINE[i]),
        "part_load_exponent": float(Q_FINE[j]),
    }
    return params, float(loss[i, j])


def calibrate_peer(grid, log_measured, vehicle_fold, vehicle_class, k, classes) -> dict:
    """The peer's technology per (fold, class), each fitted without that fold's rows, by vpsim's own
    cross-validation procedure (:func:`vpsim.fleet.calibrate.per_fold_and_class`)."""
    from .calibrate import per_fold_and_class

    return per_fold_and_class(
        lambda rows: fit_peer(grid[rows], log_measured[rows]), vehicle_fold, vehicle_class, k, classes
    )


__all__ = [
    "PEER_PARAMS",
    "PEER_VERSION",
    "calibrate_peer",
    "calibration_chunk",
    "fit_peer",
    "peer_chunk",
    "peer_vehicle",
    "status",
]
