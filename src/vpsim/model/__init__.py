"""The physical powertrain model, written once: every method, map, batch run and study computes from here.

* :mod:`~vpsim.model.engine`: the mean-value SI engine, eqs (1)-(13), and the FQM / BQM solves (19),
* :mod:`~vpsim.model.vehicle`: driveline and vehicle, eqs (14)-(18), and the affine form (21),
* :mod:`~vpsim.model.rules`: the realistic car's clutch, idle and brake rules, the idle fuel floor and the
  power of every energy term,
* :mod:`~vpsim.model.record`: the one parameter record compiled code reads (fields named as in
  :class:`vpsim.params.Parameters`),
* :mod:`~vpsim.model.maps`: the quasi-static maps generated from the model, and the
  :class:`~vpsim.model.maps.EngineMap` protocol every engine map (generated, measured) implements.

Each equation is a plain function of scalars and the record ``c``; compiled kernels inline it, Python calls
it directly (on arrays too, for the equations without branches; :func:`engine.psi_array` and
:func:`engine.steady_pressure_array` are the array views of the others). ``docs/model.md`` maps the paper's
equation numbers to these functions.
"""

from . import engine, rules, vehicle
from .record import IDLE_SPEED, record, record_array, records

__all__ = ["IDLE_SPEED", "engine", "record", "record_array", "records", "rules", "vehicle"]
