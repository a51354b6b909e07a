"""Powertrains built from the model's components, for the checks that need a whole car.

:func:`cycle_battery_energy_j` puts a machine (the scalable loss model at some rating, or a measured map)
into the ``bev`` preset and returns the battery's energy on a cycle: the measured-map check of
``vpsim machine compare`` (the paper's Table 4, for electric machines) runs the same car with the scaled
model and with the map.
"""

from __future__ import annotations

import math

from .errors import VpsimError

# the speed at which the car's reduction takes the machine to its top speed: the bev preset's 150 km/h
DESIGN_TOP_SPEED_MPS = 150.0 / 3.6


def car_with_machine(machine, base=None):
    """The ``bev`` preset (or ``base``) with ``machine`` (:class:`vpsim.model.machine.MachineSpec`, or a
    :class:`vpsim.engines.machine_map.MeasuredMachine`) and the reduction that gives the machine's top speed
    at :data:`DESIGN_TOP_SPEED_MPS`."""
    from .params import load_parameters

    params = base if base is not None else load_parameters("bev")
    if hasattr(machine, "envelope_speed"):  # a measured map
        section = {
            "rated_power": machine.rated_power_w,
            "base_speed": machine.base_speed_radps,
            "max_speed": machine.max_speed_radps,
            "map_file": machine.source,
        }
        if machine.inertia > 0:
            section["inertia"] = machine.inertia
    else:
        section = {
            "rated_power": machine.rated_power_w,
            "base_speed": machine.base_speed_radps,
            "max_speed": machine.max_speed_radps,
            "kind": machine.kind,
            "map_file": "",
        }
        if machine.inertia_kgm2 > 0:
            section["inertia"] = machine.inertia_kgm2
    from .model.electric import ratio_for_speed

    ratio = ratio_for_speed(section["max_speed"], DESIGN_TOP_SPEED_MPS, params.vehicle.wheel_radius)
    return params.with_changes(machine=section, transmission={"final_drive": ratio})


def cycle_battery_energy_j(cycle: str, machine, base=None) -> float:
    """The chemical energy (J) the battery gives on ``cycle`` (backward method) with ``machine`` in the car
    of :func:`car_with_machine`."""
    from .simulation import simulate

    r = simulate(cycle, "backward", car_with_machine(machine, base))
    energy = r.energy.terms["chemical"]
    if not math.isfinite(energy):
        raise VpsimError(f"the battery energy on {cycle} is not a number")
    return energy
