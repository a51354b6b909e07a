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
  corrected figure. Not calibrated (FASTSim's defaults: the ``fastsim_by_powertrain.hev`` figures); a
  calibrated hybrid peer is not built.

Fuel: FASTSim's fuel energy over 33.7 kWh per gallon (as :mod:`vpsim.fleet.peer`).
"""

from __future__ import annotations

import copy
import math

PEER_HEV_VEHICLE = {
    "hev_split": "2016_TOYOTA_Prius_Two.yaml",
    "hev_p2": "2021_Hyundai_Sonata_Hybrid_Blue_thrml.yaml",
}
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


def hev_peer_vehicle(rec, cycle_name: str) -> dict:
    """The FASTSim hybrid dict of a :class:`vpsim.fleet.hev.HEVRecord` (module docstring)."""
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
    return d


def run_hev_peer(d: dict, cycle_name: str) -> dict:
    """FASTSim on ``d`` over ``cycle_name`` (a vpsim cycle): ``peer_mpg``, ``trace_miss``."""
    import warnings

    import fastsim as fsim

    from ..cycles import load_cycle
    from ..units import METRES_PER_MILE
    from .peer import GASOLINE_J_PER_GAL, _sim_params

    cyc = load_cycle(cycle_name)
    fc = fsim.Cycle.from_dict(
        {"time_seconds": cyc.time_s.tolist(), "speed_meters_per_second": cyc.speed_mps.tolist()}
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        sd = fsim.SimDrive(fsim.Vehicle.from_dict(d), fc, _sim_params())
        sd.run()
        o = sd.to_dict()
    state = o["veh"]["state"]
    fuel_j = float(o["veh"]["pt_type"]["HEV"]["fc"]["state"]["energy_fuel_joules"])
    dist_m = float(state["dist_meters"])
    return {
        "peer_mpg": (dist_m / METRES_PER_MILE) / (fuel_j / GASOLINE_J_PER_GAL),
        "trace_miss": not bool(state["cyc_met_overall"]),
    }


def hev_peer_chunk(items: list[tuple]) -> list[dict]:
    """FASTSim's hybrid on each (record, test): dicts with ``key``, ``cycle``, ``peer_mpg`` or
    ``peer_error``."""
    from .hev import SIM_CYCLE
    from .peer_bev import _error_text

    out = []
    for rec, name in items:
        r = {"key": rec.key, "cycle": name, "peer_mpg": math.nan, "peer_error": "", "trace_miss": None}
        try:
            r.update(run_hev_peer(hev_peer_vehicle(rec, SIM_CYCLE[name]), SIM_CYCLE[name]))
        except Exception as exc:  # FASTSim raises its own error types (Rust errors as RuntimeError)
            r["peer_error"] = _error_text(exc)
        out.append(r)
    return out


__all__ = ["PEER_HEV_VEHICLE", "hev_peer_chunk", "hev_peer_vehicle", "run_hev_peer"]
