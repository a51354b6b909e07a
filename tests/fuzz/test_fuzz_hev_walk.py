"""The P2 ECMS's walk over the engine's torque levels (vpsim.model.hybrid.ecms_cheapest_level) against the
search that tries every level, on P2 cars drawn around the preset: mass, machine rating, pack size and
starting charge, the number of levels and the equivalence factor and its gain. Where the walk is used
(hybrid.running_cost_convex) it must make the same choice at every step: the same fuel and engine torque,
bit for bit."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from vpsim.cycles import load_cycle
from vpsim.methods import hev
from vpsim.model import electric as el
from vpsim.model import hybrid as hy
from vpsim.model.record import kernel_records
from vpsim.params import load_parameters

BASE = load_parameters("hev_p2")
CYCLES = {c: load_cycle(c) for c in ("udds", "us06")}


@settings(max_examples=12, deadline=None)
@given(
    mass=st.floats(0.7, 1.5),
    machine_w=st.floats(10e3, 80e3),
    cells=st.integers(30, 120),
    soc0=st.floats(0.45, 0.75),
    levels=st.integers(2, 40),
    s0=st.floats(1.5, 4.0),
    gain=st.floats(0.0, 60.0),
    cycle=st.sampled_from(sorted(CYCLES)),
)
def test_ecms_walk_makes_the_exhaustive_searchs_choices(
    mass, machine_w, cells, soc0, levels, s0, gain, cycle
):
    p = BASE.with_changes(
        vehicle={"mass": BASE.vehicle.mass * mass},
        machine={"rated_power": machine_w},
        battery={"cells_in_series": cells, "soc_initial": soc0},
        hybrid={"torque_levels": levels, "ecms_factor": s0, "ecms_gain": gain},
    )
    assert hy.running_cost_convex(kernel_records(p)[0], el.electric_records(p)[0])
    walk = hev.run(CYCLES[cycle], p, ems="ecms")
    every = hev.run(CYCLES[cycle], p, ems="ecms", exhaustive=True)
    assert walk.fuel_kg == every.fuel_kg
    assert np.array_equal(walk.series["engine_torque_nm"], every.series["engine_torque_nm"])
    assert np.array_equal(walk.series["soc"], every.series["soc"])
