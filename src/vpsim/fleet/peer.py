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
No technology parameter of FASTSim is fitted: its errors are not cross-validated, they are FASTSim's own
defaults (``held_out`` concerns vpsim's calibration).
"""

from __future__ import annotations

import math

from ..units import METRES_PER_MILE
from .epa import VehicleRecord

PEER_VERSION = "3.1.0"
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


def peer_vehicle(rec: VehicleRecord, cycle) -> dict:
    """The FASTSim vehicle dict of a record on ``cycle`` (the road load folded over that cycle)."""
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
    return d


def peer_chunk(items: list[tuple[VehicleRecord, str]]) -> list[dict]:
    """FASTSim on each (record, fleet cycle); dicts with ``peer_mpg`` or ``peer_error``."""
    import warnings

    import fastsim as fsim

    from .cycles import fleet_cycle

    cycles = {}
    params = fsim.SimParams.default().to_dict()
    params["trace_miss_opts"] = "Allow"  # a car that cannot follow the trace is reported, not an error
    sim_params = fsim.SimParams.from_dict(params)
    out = []
    for rec, name in items:
        row = {"key": rec.key, "cycle": name, "peer_mpg": math.nan, "peer_error": "", "peer_trace_met": None}
        try:
            cyc = fleet_cycle(name)
            if name not in cycles:
                cycles[name] = fsim.Cycle.from_dict(
                    {"time_seconds": cyc.time_s.tolist(), "speed_meters_per_second": cyc.speed_mps.tolist()}
                )
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                sd = fsim.SimDrive(fsim.Vehicle.from_dict(peer_vehicle(rec, cyc)), cycles[name], sim_params)
                sd.run()
                o = sd.to_dict()
            fuel_j = o["veh"]["pt_type"]["Conv"]["fc"]["state"]["energy_fuel_joules"]
            dist_m = o["veh"]["state"]["dist_meters"]
            row["peer_mpg"] = (dist_m / METRES_PER_MILE) / (fuel_j / GASOLINE_J_PER_GAL)
            row["peer_trace_met"] = bool(o["veh"]["state"]["cyc_met_overall"])
        except Exception as exc:  # FASTSim raises its own error types (Rust errors as RuntimeError)
            text = str(exc).strip().splitlines()
            row["peer_error"] = f"{type(exc).__name__}: {text[0] if text else ''}"[:200]
        out.append(row)
    return out


__all__ = ["PEER_VERSION", "peer_chunk", "peer_vehicle", "status"]
