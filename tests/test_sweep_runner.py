"""Running sweeps: serial, local processes and a real Dask LocalCluster give the same rows; failures are
rows."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from vpsim.sweep import load_results, make_spec, plan, run_sweep
from vpsim.sweep import runner as runner_mod
from vpsim.sweep.runner import make_chunks, result_schema

# columns that say when/where a row was computed, not what it is
BOOKKEEPING = ["run_id", "computed_at", "worker", "compute_time_s"]

SPEC = {
    "parameters": {"engine.bore": {"range": [0.08, 0.095], "n": 3}, "transmission.final_drive": [3.9, 4.45]},
    "cycles": ["nedc", "hwfet"],
}


def _same_rows(a: pd.DataFrame, b: pd.DataFrame) -> None:
    pd.testing.assert_frame_equal(a.drop(columns=BOOKKEEPING), b.drop(columns=BOOKKEEPING))


def test_rows_columns_and_baseline():
    run = run_sweep(make_spec(**SPEC), workers=1)
    df = run.results
    assert run.n_rows == len(df) == (1 + 6) * 2 and run.n_failed == 0
    assert df["point_id"].is_unique
    assert list(df.columns) == list(result_schema(make_spec(**SPEC)))
    assert df.groupby("design_id")["accel_0_100_s"].nunique().eq(1).all()  # one acceleration per design
    base = df[df["is_baseline"]]
    assert set(base["cycle"]) == {"nedc", "hwfet"}
    assert (base["engine.bore"] == 0.09).all() and (base["transmission.final_drive"] == 4.45).all()
    assert np.isfinite(df["fuel_l_per_100km"]).all() and np.isfinite(df["accel_0_100_s"]).all()
    assert df["displacement_l"].between(1.8, 2.6).all()


def test_a_run_prints_plots_and_is_a_dataframe(tmp_path):
    """SweepRun: print gives the command line's rows line and where the results are; to_dataframe is the
    results; plot draws the Pareto front where acceleration was computed (the baseline and the fastest
    design among its points), fuel against displacement where it was not."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run = run_sweep(make_spec(**SPEC), out=tmp_path / "s", workers=1)
    text = str(run)
    assert text.splitlines()[0] == run.rows_line()
    assert text.startswith("14 rows: 14 computed now, 0 already present, 0 failed")
    assert text.splitlines()[-1] == f"results in {run.path}"
    assert run.to_dataframe() is run.results
    fig = run.plot(cycle="hwfet")
    ax = fig.axes[0]
    assert "hwfet" in ax.get_title() and "0-100" in ax.get_xlabel()
    plt.close(fig)
    no_accel = run_sweep(make_spec(**SPEC, acceleration={"enabled": False}), workers=1)
    assert str(no_accel).endswith("results in memory")
    fig = no_accel.plot()
    assert "displacement" in fig.axes[0].get_xlabel().lower()
    plt.close(fig)
    empty = runner_mod.SweepRun(no_accel.results.iloc[:0], "x", 0, 0, 0, 0, 0.0)
    with pytest.raises(runner_mod.VpsimError, match="no results to plot"):
        empty.plot()
    with pytest.raises(
        runner_mod.VpsimError, match="cycle 'udds' is not in the sweep's results; it has hwfet, nedc"
    ):
        run.plot(cycle="udds")


def test_same_rows_on_a_local_cluster_with_two_workers(tmp_path):
    spec = make_spec(**SPEC)
    serial = run_sweep(spec, tmp_path / "serial", workers=1, chunk_size=2)
    cluster = run_sweep(spec, tmp_path / "cluster", local_cluster=2, chunk_size=2)
    assert cluster.n_computed == serial.n_computed == 14
    _same_rows(serial.results, cluster.results)
    assert cluster.results["worker"].nunique() == 2  # both workers took chunks
    _same_rows(load_results(tmp_path / "cluster"), serial.results)


def test_same_rows_on_local_processes_even_when_one_dies(tmp_path):
    import multiprocessing
    import os
    import signal

    spec = make_spec(**SPEC)
    serial = run_sweep(spec, workers=1)
    killed = []

    def progress(done: int, total: int) -> None:
        children = multiprocessing.active_children()
        if done > 0 and not killed and children:
            os.kill(children[0].pid, signal.SIGKILL)  # the pool breaks; its chunks are resubmitted
            killed.append(children[0].pid)

    pool = run_sweep(spec, tmp_path, workers=2, fmt="csv", chunk_size=1, progress=progress)
    assert killed and pool.chunk_errors == []
    _same_rows(serial.results, pool.results)
    raw = load_results(tmp_path / "results.csv", dedupe=False)
    assert raw["point_id"].is_unique
    _same_rows(serial.results, raw.sort_values(["design", "cycle"]).reset_index(drop=True))


def test_invalid_combinations_are_rows_with_an_error(tmp_path):
    # each value is valid alone, but a min throttle area above the max is not
    spec = make_spec(
        parameters={"engine.min_throttle_area": [1e-6, 5e-4], "engine.max_throttle_area": [2e-3, 3e-4]},
        baseline=False,
    )
    run = run_sweep(spec, tmp_path, workers=1)
    df = run.results
    bad = df[df["error"].notna()]
    assert len(bad) == 1 and run.n_failed == 1
    assert "min_throttle_area must be smaller" in bad["error"].iloc[0] and "\n" not in bad["error"].iloc[0]
    assert bad[["fuel_l_per_100km", "accel_0_100_s"]].isna().all().all()
    assert df["error"].isna().sum() == 3


def test_a_failing_solver_does_not_stop_the_sweep(monkeypatch):
    real = runner_mod._simulate_row

    def flaky(cycle, method, driver, params, mode, schedule=None):
        if params.engine.bore > 0.09:
            raise FloatingPointError("solver failed\nat step 12")
        return real(cycle, method, driver, params, mode, schedule)

    monkeypatch.setattr(runner_mod, "_simulate_row", flaky)
    df = run_sweep(make_spec(**SPEC, gears="per_design"), workers=1).results
    failed = df[df["error"].notna()]
    assert len(failed) == 4 and (failed["engine.bore"] > 0.09).all(), failed["error"].unique()
    assert (failed["error"] == "FloatingPointError: solver failed at step 12").all()
    assert failed[["fuel_l_per_100km", "trace_miss_s", "accel_0_100_s"]].isna().all().all()  # NaN objectives
    assert df["error"].isna().sum() == 10


def test_compiled_batch_and_one_by_one_paths_agree(monkeypatch):
    spec = make_spec(**SPEC, acceleration=False)
    batch = run_sweep(spec, workers=1).results
    monkeypatch.setattr(runner_mod, "batch_available", lambda: False)
    single = run_sweep(spec, workers=1).results
    cols = [
        "point_id",
        "fuel_l_per_100km",
        "fuel_kg",
        "distance_km",
        "trace_miss_s",
        "trace_miss_max_torque_shortfall_nm",
        "max_speed_error_mps",
    ]
    pd.testing.assert_frame_equal(batch[cols], single[cols], rtol=1e-12)
    assert batch["warning"].eq(single["warning"]).all() and batch["error"].isna().all()


def test_forward_rows_through_the_batch_equal_one_by_one(monkeypatch):
    """Forward rows of a chunk go through vpsim.batch (one compiled call): the same rows as one by one."""
    import vpsim.batch

    calls = []
    real = vpsim.batch.run_batch

    def counting(*args, **kwargs):
        calls.append(args[2] if len(args) > 2 else kwargs.get("method"))
        return real(*args, **kwargs)

    spec = make_spec(
        parameters={"engine.bore": [0.085, 0.09]},
        cycles=["nedc"],
        methods=["forward"],
        drivers=["2"],
        acceleration=False,
    )
    monkeypatch.setattr(vpsim.batch, "run_batch", counting)
    batch = run_sweep(spec, workers=1).results
    assert "forward" in calls
    monkeypatch.setattr(runner_mod, "batch_available", lambda: False)
    single = run_sweep(spec, workers=1).results
    cols = [
        "point_id",
        "fuel_kg",
        "distance_km",
        "trace_miss_s",
        "trace_miss_max_torque_shortfall_nm",
        "max_speed_error_mps",
    ]
    pd.testing.assert_frame_equal(batch[cols], single[cols], rtol=1e-12)
    assert batch["error"].isna().all()


def test_a_failing_batch_falls_back_to_one_by_one(monkeypatch):
    import vpsim.batch

    def broken(*args, **kwargs):
        raise RuntimeError("kernel failure")

    spec = make_spec(**SPEC, acceleration=False)
    good = run_sweep(spec, workers=1).results
    monkeypatch.setattr(vpsim.batch, "run_batch", broken)
    again = run_sweep(spec, workers=1).results
    assert again["error"].isna().all()
    pd.testing.assert_series_equal(good["fuel_kg"], again["fuel_kg"], rtol=1e-12)


def test_per_design_gears_differ_from_the_baseline_schedule():
    a = run_sweep(make_spec(**SPEC, acceleration=False), workers=1).results
    b = run_sweep(make_spec(**SPEC, acceleration=False, gears="per_design"), workers=1).results
    assert not set(a["point_id"]) & set(b["point_id"])  # the gear rule is part of a point's identity
    base_a, base_b = a[a["is_baseline"]], b[b["is_baseline"]]
    np.testing.assert_allclose(base_a["fuel_kg"], base_b["fuel_kg"], rtol=1e-12)  # the base's own schedule


def test_chunks_hold_whole_designs_and_scale_with_cost():
    spec = make_spec(parameters={"engine.bore": {"range": [0.08, 0.095], "n": 200}}, cycles=["nedc", "hwfet"])
    p = plan(spec)
    chunks = make_chunks(p.tasks, p, run_id="r", workers=2, chunk_size=None, schema={})
    assert sum(c.n_rows for c in chunks) == p.n_rows
    assert all(len(t.rows) == 2 for c in chunks for t in c.tasks)
    assert 8 <= len(chunks) <= 40  # several per worker, each some tenths of a second
    fixed = make_chunks(p.tasks, p, run_id="r", workers=2, chunk_size=10, schema={})
    assert max(c.n_rows for c in fixed) == 10


def test_accel_disabled_leaves_it_nan():
    df = run_sweep(make_spec(parameters={"engine.bore": [0.08]}, acceleration=False), workers=1).results
    assert df["accel_0_100_s"].map(math.isnan).all()


def test_bad_execution_options():
    from vpsim.errors import VpsimError

    with pytest.raises(VpsimError, match="not both"):
        run_sweep(make_spec(**SPEC), scheduler="tcp://x:1", local_cluster=2)
    with pytest.raises(VpsimError, match="workers"):
        run_sweep(make_spec(**SPEC), workers=0)
