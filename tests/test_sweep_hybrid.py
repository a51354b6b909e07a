"""The hybrid sizing study (issue 29): sweeps over a hybrid base, its sizing rules, its charge-sustaining
columns and feasibility flag, the same rows on a Dask LocalCluster, and the example spec."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import vpsim
from vpsim.params import load_parameters
from vpsim.sweep import load_results, load_spec, make_spec, plan, run_sweep
from vpsim.sweep.hybrid import HYBRID_COLUMNS, flag_feasibility
from vpsim.sweep.spec import SpecError, apply_changes

REPO = Path(__file__).resolve().parents[1]
BOOKKEEPING = ["run_id", "computed_at", "worker", "compute_time_s"]
# the baseline and one design too small for the UDDS: a 0.47 L engine, a 10 kW machine and 16 cells
SMALL = {
    "base": "hev_p2",
    "ems": "dp",
    "cycles": ["udds"],
    "mode": "realistic",
    "parameters": {
        "engine.scale": [0.3],
        "machine.rated_power": [10000.0],
        "battery.cells_in_series": [16],
    },
}


def test_sizing_rules():
    p = load_parameters("hev_p2")
    q = apply_changes(p, {"engine.scale": 0.5, "machine.rated_power": 64e3, "battery.cells_in_series": 96})
    assert q.engine.displacement / p.engine.displacement == pytest.approx(0.5, rel=1e-12)
    assert q.engine.bore == pytest.approx(p.engine.bore * math.sqrt(0.5), rel=1e-12)
    assert (q.engine.stroke, q.engine.cylinders) == (p.engine.stroke, p.engine.cylinders)
    assert q.engine.map_speed_range == p.engine.map_speed_range  # the same speeds: the stroke is kept
    assert q.engine.max_throttle_area / p.engine.max_throttle_area == pytest.approx(0.5, rel=1e-12)
    assert q.machine.rated_power == 64e3 and q.machine.inertia == pytest.approx(2 * p.machine.inertia)
    assert q.battery.cells_in_series == 96
    # a swept inertia is the user's own, not the rule's
    r = apply_changes(p, {"machine.rated_power": 64e3, "machine.inertia": 0.05})
    assert r.machine.inertia == 0.05


@pytest.mark.parametrize(
    ("keys", "message"),
    [
        ({"base": "hofman2011", "ems": "dp"}, "ems applies to a hybrid base"),
        ({"base": "hev_p2", "ems": "dp", "methods": ["backward", "inverse"]}, "backward method only"),
        ({"base": "hev_p2", "ems": "mpc"}, "expected one of rule, ecms, dp"),
        ({"base": "hev_p2", "methods": ["forward"], "ems": "dp"}, "backward method only"),
        ({"base": "hev_split"}, "power-split hybrid is not modelled; set acceleration = false"),
        (
            {"base": "hev_p2", "parameters": {"engine.scale": [0.8], "engine.bore": [0.07]}},
            "engine.scale or the engine's bore",
        ),
        ({"base": "hev_p2", "parameters": {"machine.rated_power": [32.0, 50.0]}}, "machine.rated_power = 32"),
        ({"base": "hev_p2", "parameters": {"engine.scale": [0.0, 1.0]}}, "must be a positive"),
    ],
)
def test_spec_errors_name_the_field(keys, message):
    with pytest.raises(SpecError, match=message):
        make_spec(**keys)


def test_hybrid_rows_flag_what_is_infeasible_and_agree_with_simulate():
    run = run_sweep(make_spec(**SMALL), workers=1)
    df = run.results.set_index("design")
    assert run.n_failed == 0 and set(HYBRID_COLUMNS) <= set(df.columns)
    base, small = df.loc[0], df.loc[1]
    r = vpsim.simulate("udds", "backward", "hev_p2", ems="dp").summary()
    assert base["feasible"] and base["infeasible_reason"] is None
    assert base["fuel_l_per_100km_cs"] == pytest.approx(r["fuel_l_per_100km_cs"], rel=1e-12)
    assert base["soc_end"] == pytest.approx(r["soc_end"], rel=1e-12)
    assert base["accel_0_100_s"] == pytest.approx(
        vpsim.performance.acceleration_time(load_parameters("hev_p2")).time_s
    )
    # the small design cannot deliver the UDDS's demand: flagged, no charge-sustaining figure
    assert not small["feasible"]
    assert small["infeasible_reason"].startswith("cannot follow the cycle")
    assert small["demand_not_deliverable_s"] > 0
    assert math.isnan(small["fuel_l_per_100km_cs"]) and np.isfinite(small["fuel_l_per_100km"])
    assert small["accel_0_100_s"] > base["accel_0_100_s"]


def test_not_charge_sustaining_and_failed_rows_are_flagged():
    rows = pd.DataFrame(
        {
            "error": [None, None, "ParameterError: x"],
            "fuel_l_per_100km": [3.0, 3.0, math.nan],
            "fuel_l_per_100km_cs": [3.0, 3.1, math.nan],
            "trace_miss_s": [0.0, 0.0, math.nan],
            "speed_not_followed_s": [0.0, 0.0, math.nan],
            "demand_not_deliverable_s": [0.0, 0.0, math.nan],
            "soc_start": [0.6, 0.6, math.nan],
            "soc_end": [0.59, 0.5, math.nan],
            "net_energy_change_ratio": [0.005, 0.04, math.nan],  # within J1711's 1 %, and beyond it
        }
    )
    out = flag_feasibility(rows)
    assert out["feasible"].tolist() == [True, False, False]
    assert out["infeasible_reason"][1].startswith("not charge-sustaining: SOC 0.600 -> 0.500")
    assert out["infeasible_reason"][2] == "the run failed (error)"
    assert out["fuel_l_per_100km_cs"].tolist()[0] == 3.0 and out["fuel_l_per_100km_cs"][1:].isna().all()


def test_same_rows_on_a_local_cluster(tmp_path):
    pytest.importorskip("dask.distributed")
    spec = make_spec(**SMALL)
    serial = run_sweep(spec, tmp_path / "serial", workers=1)
    cluster = run_sweep(spec, tmp_path / "cluster", local_cluster=2, chunk_size=1)
    assert cluster.n_computed == serial.n_computed == 2
    pd.testing.assert_frame_equal(
        serial.results.drop(columns=BOOKKEEPING), cluster.results.drop(columns=BOOKKEEPING)
    )
    pd.testing.assert_frame_equal(
        load_results(tmp_path / "cluster").drop(columns=BOOKKEEPING), serial.results.drop(columns=BOOKKEEPING)
    )


def test_the_example_spec_and_its_figure(tmp_path):
    spec = load_spec(REPO / "examples" / "hybrid_sizing.toml")
    assert spec.hybrid and spec.ems == "dp" and spec.cycles == ("ftp75",)
    p = plan(spec)
    assert len(p.tasks) == 28  # 3 x 3 x 3 and the baseline
    assert {a.name for a in spec.axes} == {"engine.scale", "machine.rated_power", "battery.cells_in_series"}
    # the Pareto figure from a small table: the front is drawn on the charge-sustaining fuel, the
    # infeasible design left out
    import matplotlib

    matplotlib.use("Agg")
    from vpsim.sweep.plots import plot_pareto, write_sweep_figures

    df = run_sweep(make_spec(**SMALL), workers=1).results
    ax, front = plot_pareto(df)
    assert front["feasible"].all() and len(front) == 1
    assert "charge-sustaining" in ax.get_ylabel()
    written = write_sweep_figures(df, tmp_path)
    assert (tmp_path / "pareto_udds.png") in written


def test_a_forward_hybrid_row_is_the_forward_run():
    # (HWFET: the P2's forward ECMS ends it charged; on UDDS it draws 1.07 % of its fuel's energy from the
    # pack, beyond J1711's band, and the sweep flags that row as not charge-sustaining)
    spec = make_spec(
        base="hev_p2", ems="ecms", cycles=["hwfet"], methods=["forward"], parameters={}, acceleration=False
    )
    df = run_sweep(spec, workers=1).results
    r = vpsim.simulate("hwfet", "forward", "hev_p2", ems="ecms")
    assert df["fuel_l_per_100km_cs"].iloc[0] == r.summary()["fuel_l_per_100km_cs"] and df["feasible"].all()
