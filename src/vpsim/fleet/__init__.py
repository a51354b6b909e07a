"""Real cars: vehicles built from certification records, and the fleet's measured fuel economy predicted.

* :mod:`vpsim.fleet.epa` reads the U.S. EPA Test Car List (one row per certification test), excludes
  what today's model cannot represent by documented rules, and groups the tests per vehicle.
* :mod:`vpsim.fleet.vehicle` maps a record to a :class:`vpsim.params.Parameters` and writes it as TOML.
* :mod:`vpsim.fleet.cycles` gives the cycle pieces the tests measure (FTP bags 2 and 3, HWFET, US06).
* :mod:`vpsim.fleet.calibrate` fits a few global technology parameters by k-fold cross-validation.
* :mod:`vpsim.fleet.run` runs the fleet (serial or on Dask) and :mod:`vpsim.fleet.report` writes the
  table, the summary, the report (:mod:`vpsim.fleet.report_md`) and the figures
  (:mod:`vpsim.fleet.report_figures`); :mod:`vpsim.fleet.peer` runs FASTSim on the same records.
  The run's battery-electric and hybrid parts are in :mod:`vpsim.fleet.run_electrified`.
"""

from __future__ import annotations

from .cycles import FLEET_CYCLES, fleet_cycle
from .epa import TestCarList, VehicleRecord, read_test_car_list
from .vehicle import record_parameters

__all__ = [
    "FLEET_CYCLES",
    "TestCarList",
    "VehicleRecord",
    "fleet_cycle",
    "read_test_car_list",
    "record_parameters",
]
