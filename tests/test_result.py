"""The result type: summary, DataFrame, plot, JSON."""

from __future__ import annotations

import json

import matplotlib.pyplot as plt
import numpy as np

import vpsim


def test_result_views():
    r = vpsim.simulate("udds", method="backward")
    df = r.to_dataframe()
    assert len(df) == r.steps
    for col in (
        "time_s",
        "speed_mps",
        "accel_mps2",
        "gear",
        "engine_speed_radps",
        "crank_torque_nm",
        "intake_pressure_pa",
        "fuel_flow_kgps",
        "fuel_flow_used_kgps",
    ):
        assert col in df.columns
    # fuel in the summary is the integral of the series
    dt = np.diff(vpsim.load_cycle("udds").time_s)
    assert np.isclose((df["fuel_flow_used_kgps"] * dt).sum(), r.fuel_kg, rtol=1e-12)
    d = json.loads(r.to_json())
    assert d["fuel_kg"] == r.fuel_kg and d["cycle"] == "udds"
    assert "L/100 km" in repr(r)
    assert "residual" in str(r.energy)
    fig = r.plot(t_range=(0, 300))
    assert len(fig.axes) >= 5
    plt.close(fig)
    assert r.engine_speed_radps is r.series["engine_speed_radps"]  # series are attributes too
