"""Batch evaluation (vpsim.batch): one row per variant, equal to the individual runs; clear errors."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from vpsim.batch import METHODS, run_batch, variant_parameters
from vpsim.cycles import Cycle, load_cycle
from vpsim.errors import ParameterError, VpsimError
from vpsim.gears import default_schedule
from vpsim.methods import backward
from vpsim.model.maps import cached_engine_map, generate_engine_map

RTOL = 1e-9

# a spread wide enough that some variants cannot follow the cycle (trace misses at the max-torque line)
VARIANTS = {
    "engine.bore": [0.09, 0.07, 0.095, 0.06, 0.085, 0.1],
    "engine.stroke": [0.09, 0.065, 0.1, 0.07, 0.09, 0.08],
    "transmission.final_drive": [4.45, 3.2, 4.9, 3.0, 4.0, 5.5],
    "vehicle.mass": [1700.0, 2600.0, 1300.0, 3200.0, 1500.0, 1900.0],
}


def _launch() -> Cycle:
    t = np.arange(0.0, 31.0)
    return Cycle("launch", t, np.minimum(t * (100 / 3.6) / 5.0, 100 / 3.6))


def _individual(cycle, params, names, row, *, mode="paper", schedule="baseline"):
    p = variant_parameters(params, names, row)
    em = generate_engine_map(p.engine, exact=True)
    if schedule == "baseline":
        schedule = default_schedule(cycle, params, cached_engine_map(params.engine))
    elif schedule == "per_variant":
        schedule = None
    return backward.run(cycle, p, engine_map=em, schedule=schedule, mode=mode)


def _assert_row_equals(row, r):
    assert row["fuel_kg"] == pytest.approx(r.fuel_kg, rel=RTOL)
    assert row["fuel_l_per_100km"] == pytest.approx(r.fuel_l_per_100km, rel=RTOL)
    assert row["distance_km"] == pytest.approx(r.distance_km, rel=RTOL)
    assert row["trace_miss_s"] == pytest.approx(r.trace_miss.seconds, rel=RTOL, abs=1e-12)
    assert row["trace_miss_max_torque_shortfall_nm"] == pytest.approx(
        r.trace_miss.max_torque_shortfall_nm, rel=RTOL, abs=1e-9
    )


@pytest.mark.parametrize("cycle", ["udds", "us06", "launch"])
@pytest.mark.parametrize("mode", ["paper", "extended"])
def test_backward_batch_rows_equal_individual_runs(params, cycle, mode):
    cyc = _launch() if cycle == "launch" else load_cycle(cycle)
    df = run_batch(cyc, VARIANTS, params=params, mode=mode)
    names = list(VARIANTS)
    assert len(df) == len(VARIANTS["engine.bore"])
    assert list(df.columns[: len(names)]) == names
    for i in range(len(df)):
        _assert_row_equals(
            df.iloc[i], _individual(cyc, params, names, [VARIANTS[k][i] for k in names], mode=mode)
        )
    if cycle != "udds":
        assert (df["trace_miss_s"] > 0).any()  # the lazily evaluated max-torque line is exercised


def test_per_variant_gears_equal_runs_with_their_own_schedule(params):
    cyc = load_cycle("nedc")
    variants = {"transmission.final_drive": [3.5, 4.45, 5.0], "vehicle.mass": [1400.0, 1700.0, 2000.0]}
    df = run_batch(cyc, variants, params=params, gears="per_variant")
    names = list(variants)
    for i in range(3):
        r = _individual(cyc, params, names, [variants[k][i] for k in names], schedule="per_variant")
        _assert_row_equals(df.iloc[i], r)


def test_baseline_row_is_the_base_design(params):
    cyc = load_cycle("ftp75")
    df = run_batch(cyc, None, params=params)
    assert len(df) == 1
    r = backward.run(cyc, params, engine_map=cached_engine_map(params.engine).with_exact())
    _assert_row_equals(df.iloc[0], r)
    # the closed-form BQM of the batch and the default table lookup differ by < 1e-5
    assert df["fuel_kg"][0] == pytest.approx(backward.run(cyc, params).fuel_kg, rel=1e-5)


def test_input_forms_give_the_same_rows(params):
    cyc = load_cycle("nedc")
    as_dict = {"engine.bore": np.array([0.085, 0.09, 0.095]), "vehicle.mass": 1600.0}
    as_frame = pd.DataFrame({"engine.bore": [0.085, 0.09, 0.095], "vehicle.mass": [1600.0] * 3})
    as_list = [
        {"engine.bore": 0.085, "vehicle.mass": 1600.0},
        {"engine.bore": 0.09, "vehicle.mass": 1600},
        {"engine.bore": 0.095, "vehicle.mass": 1600.0},
    ]
    frames = [run_batch(cyc, v, params=params) for v in (as_dict, as_frame, as_list)]
    for f in frames[1:]:
        pd.testing.assert_frame_equal(f, frames[0])
    # a parameter missing from a dict keeps the base value
    partial = run_batch(cyc, [{"engine.bore": 0.085}, {"vehicle.mass": 1600.0}], params=params)
    assert partial["vehicle.mass"][0] == params.vehicle.mass
    assert partial["engine.bore"][1] == params.engine.bore


def test_gear_ratio_and_aliased_names(params):
    cyc = load_cycle("udds")
    names = ["transmission.gearbox_ratios[2]", "engine.lambda", "engine.cylinders"]
    rows = [[1.9, 1.0, 4], [1.6, 1.05, 6]]
    df = run_batch(cyc, pd.DataFrame(rows, columns=names), params=params)
    for i, row in enumerate(rows):
        _assert_row_equals(df.iloc[i], _individual(cyc, params, names, row))
    assert variant_parameters(params, names, rows[1]).transmission.gearbox_ratios[1] == 1.6


@pytest.mark.parametrize(
    ("variants", "match"),
    [
        ({"engine.bor": [0.09]}, r"unknown parameter 'engine.bor'; did you mean engine.bore"),
        ({"bore": [0.09]}, r"unknown parameter 'bore'"),
        ({"engine.bore": [0.09, 90.0]}, r"variant 1: engine.bore = 90 .*did you mean 0.09"),
        ({"vehicle.mass": [1500.0, -3.0, 1600.0]}, r"variant 1: vehicle.mass = -3 is outside"),
        ({"vehicle.mass": [1500.0, float("nan")]}, r"variant 1: .*vehicle.mass = nan is not a finite number"),
        ({"engine.cylinders": [4, 5.5, 6]}, r"variant 1: engine.cylinders = 5.5 is not a whole number"),
        ({"vehicle.mass": ["heavy"]}, r"variant 0: vehicle.mass = 'heavy' is not a number"),
        ({"transmission.gearbox_ratios": [3.0]}, r"is a list; vary one entry"),
        ({"transmission.gearbox_ratios[7]": [3.0]}, r"gear 7 does not exist"),
        (
            {"transmission.efficiency": [0.9, 1.2]},
            r"variant 1: transmission.efficiency = 1.2 is outside \(0, 1\]",
        ),
        ({"engine.min_throttle_area": [1e-6, 3e-3]}, r"variant 1: engine.min_throttle_area must be smaller"),
        ({"vehicle.mass": [1500.0, 1600.0], "engine.bore": [0.09]}, r"different lengths"),
        ({"engine.lambda": [1.0], "engine.lambda_": [1.0]}, r"names the same parameter"),
    ],
)
def test_bad_variants_give_clear_errors(params, variants, match):
    with pytest.raises(ParameterError, match=match):
        run_batch("nedc", variants, params=params)


def test_bad_calls_give_clear_errors(params):
    with pytest.raises(ParameterError, match="no variant"):
        run_batch("nedc", pd.DataFrame({"vehicle.mass": []}), params=params)
    with pytest.raises(ParameterError, match="must be a pandas DataFrame"):
        run_batch("nedc", 3.0, params=params)
    with pytest.raises(VpsimError, match="batch method 'inverse' is not available"):
        run_batch("nedc", {"vehicle.mass": [1500.0]}, method="inverse", params=params)
    with pytest.raises(VpsimError, match="takes no driver"):
        run_batch("nedc", {"vehicle.mass": [1500.0]}, params=params, driver=1)
    with pytest.raises(VpsimError, match="gears must be"):
        run_batch("nedc", {"vehicle.mass": [1500.0]}, params=params, gears=3)


def test_forward_batch_per_variant_schedules(params):
    # each variant on its own schedule (different numbers of gear changes): rows as forward.run gives them
    from vpsim.methods import forward

    cyc = load_cycle("nedc")
    variants = {"transmission.final_drive": [3.2, 4.9], "vehicle.mass": [1300.0, 1800.0]}
    df = run_batch(cyc, variants, method="forward", params=params, gears="per_variant")
    shifts = []
    for i in range(2):
        p = variant_parameters(params, list(variants), [variants[k][i] for k in variants])
        schedule = default_schedule(cyc, p, generate_engine_map(p.engine, exact=True))
        shifts.append(schedule.shift_times.size)
        r = forward.run(cyc, p, schedule=schedule, keep_series=False)
        assert df["fuel_kg"][i] == r.fuel_kg and df["steps"][i] == r.steps
    assert shifts[0] != shifts[1]


def test_variants_are_checked_as_whole_engines(params):
    # bore 0.2 m and stroke 0.2 m are each plausible with the base engine's other field, not together
    crossed = {"engine.bore": [0.09, 0.2], "engine.stroke": [0.09, 0.2]}
    for method in METHODS:
        with pytest.raises(ParameterError, match=r"^variant 1: displacement 25\.13 L .* outside the plaus"):
            run_batch("nedc", crossed, method=method, params=params)
    df = run_batch("nedc", {"engine.bore": [0.09, 0.2], "engine.stroke": [0.2, 0.09]}, params=params)
    assert np.isfinite(df["fuel_kg"]).all()


def test_whole_engine_check_of_all_variants_agrees_with_each_engine_alone(params):
    # random engines, many implausible as a whole (full-load BMEP, motoring BMEP, idle), none in one field:
    # the vectorised check flags exactly the variants whose own parameter set is refused
    from vpsim.batch import _sections
    from vpsim.model.record import records
    from vpsim.params import engine_check_figures

    rng = np.random.default_rng(3)
    n = 80
    cols = {
        "engine.friction_coefficient": rng.uniform(1.0, 10.0, n),
        "engine.boost_layout": rng.uniform(0.5, 3.0, n),
        "engine.thermal_efficiency": rng.uniform(0.3, 0.59, n),  # below the ceiling 0.6
        "engine.air_charge_slope": rng.uniform(0.8, 1.5, n),
        "engine.air_charge_intercept": rng.uniform(-9e4, 5e4, n),
        "engine.max_throttle_area": 10.0 ** rng.uniform(-5.5, -3.0, n),
    }
    names = list(cols)
    values = np.column_stack([cols[k] for k in names])
    ok = engine_check_figures(records(*_sections(params, names, values)[0]))["ok"]
    refused = []
    for i in range(n):
        try:
            variant_parameters(params, names, values[i])
            refused.append(False)
        except ParameterError:
            refused.append(True)
    assert list(~ok) == refused
    assert 10 < sum(refused) < n - 10


def test_forward_batch_rows_equal_individual_runs(params):
    from vpsim.methods import forward

    cyc = load_cycle("nedc")
    # the variants differ in what sets each run's own start, command range, brake gain, idle throttle and
    # error scales (the throttle's size, a boosted engine: its command goes on to 2 A_max)
    variants = {
        "vehicle.mass": [1500.0, 1900.0, 1700.0],
        "transmission.final_drive": [4.0, 4.45, 4.9],
        "engine.max_throttle_area": [params.engine.max_throttle_area, 1.2e-4, 0.9e-4],
        "engine.boost_pressure": [0.0, 1.6e5, 0.0],
        "engine.bore": [0.086, 0.080, 0.092],
    }
    schedule = default_schedule(cyc, params, cached_engine_map(params.engine))
    for driver, mode in (("1", "paper"), ("2", "extended")):
        df = run_batch(cyc, variants, method="forward", params=params, driver=driver, mode=mode)
        assert list(df.columns[: len(variants)]) == list(variants)
        for i in range(3):
            p = variant_parameters(params, list(variants), [variants[k][i] for k in variants])
            r = forward.run(cyc, p, driver=driver, schedule=schedule, mode=mode)
            row = df.iloc[i]
            assert row["fuel_kg"] == pytest.approx(r.fuel_kg, rel=RTOL)
            assert row["fuel_l_per_100km"] == pytest.approx(r.fuel_l_per_100km, rel=RTOL)
            assert row["distance_km"] == pytest.approx(r.distance_km, rel=RTOL)
            assert row["steps"] == r.steps
            assert row["max_speed_error_mps"] == pytest.approx(r.trace_miss.max_speed_error_mps, rel=RTOL)
            assert row["trace_miss_s"] == pytest.approx(r.trace_miss.seconds, rel=RTOL, abs=1e-12)
