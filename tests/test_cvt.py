"""A CVT: its ratio grid, the shift rule choosing on it without a hold, and the three methods on one car."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import vpsim
from vpsim.batch import run_batch
from vpsim.cycles import load_cycle
from vpsim.gears import GearRule, default_schedule, interval_demand
from vpsim.methods import backward
from vpsim.model.maps import generate_engine_map, max_torque
from vpsim.params import MAX_CVT_STEPS, ParameterError, cvt_grid

RANGE = [2.6, 0.4]  # launch, overdrive (gearbox), spread 6.5


@pytest.fixture(scope="module")
def cvt(params):
    return params.with_changes(transmission={"gearbox_ratios": RANGE, "cvt_ratio_step": 0.02})


def test_grid_by_hand():
    # ln 6.5 / ln 1.02 = 94.52: 96 points, neighbours 6.5^(1/95) = 1.01990 apart
    g = cvt_grid(2.6, 0.4, 0.02)
    assert len(g) == 96 and g[0] == 2.6 and g[-1] == pytest.approx(0.4, rel=1e-14)
    assert np.allclose(np.asarray(g[:-1]) / np.asarray(g[1:]), 1.0198991, rtol=1e-6)
    assert len(cvt_grid(2.0, 1.0, 0.5)) == 3  # 2, sqrt 2, 1: steps of 41 % <= 50 %


@settings(max_examples=300, deadline=None)
@given(
    overdrive=st.floats(0.05, 5.0),
    spread=st.floats(1.01, 20.0),
    step=st.floats(0.005, 0.2),
)
def test_grid_properties(overdrive, spread, step):
    """From launch to overdrive, falling, every step at most ``step`` and equal, and no point to spare: one
    point fewer would need a larger step."""
    launch = overdrive * spread
    if math.log(spread) / math.log1p(step) + 1 > MAX_CVT_STEPS - 1:
        with pytest.raises(ParameterError, match="more than 500"):
            cvt_grid(launch, overdrive / 2, step)  # a range 2x wider: at least 3.8 points more
        assume(False)
    g = np.asarray(cvt_grid(launch, overdrive, step))
    assert g[0] == launch and g[-1] == pytest.approx(overdrive, rel=1e-12)
    r = g[:-1] / g[1:]
    assert np.all(r > 1.0) and np.all(r <= 1.0 + step + 1e-12)
    np.testing.assert_allclose(r, r[0], rtol=1e-9)
    if g.size > 2:
        assert spread ** (1.0 / (g.size - 2)) > 1.0 + step - 1e-9


def test_total_ratios_and_gear_numbers(cvt):
    tr = cvt.transmission
    assert tr.is_cvt and tr.n_gears == 96
    assert tr.ratios[0] == pytest.approx(2.6 * tr.final_drive) and tr.ratios[-1] == pytest.approx(
        0.4 * tr.final_drive
    )


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"gearbox_ratios": [2.6, 1.5, 0.4]}, r"must be its range \[launch, overdrive\]"),
        ({"gearbox_ratios": [0.4, 2.6]}, "launch > overdrive"),
        ({"cvt_ratio_step": 0.001}, "below 0.005"),
        ({"cvt_ratio_step": 0.3}, r"outside the plausible range \[0, 0.2\]"),
        ({"gearbox_ratios": [20.0, 0.01], "cvt_ratio_step": 0.005}, "needs more than 500 ratios"),
    ],
)
def test_bad_cvt_fields_are_one_line_errors(cvt, change, match):
    with pytest.raises(ParameterError, match=match) as err:
        cvt.with_changes(transmission=change)
    assert "\n" not in str(err.value)


def test_rule_keeps_the_lowest_engine_speed_that_carries_the_load(cvt):
    """On every moving interval the chosen ratio is the lowest admissible one at or above the speed kept:
    the next lower ratio is below that speed or not admissible (the no-upshift-while-decelerating rule
    aside); where the speed kept is the binding limit (not the reserve, nor the overdrive) the engine runs
    within one step (2 %) above it. No
    short engagement is merged (a CVT holds nothing)."""
    c = load_cycle("ftp75")
    rule = GearRule(min_engine_speed=130.0)
    gear = default_schedule(c, cvt, rule=rule).gear[:-1]
    ratios = np.asarray(cvt.transmission.ratios)
    _, a, w_e, _, t_cr, _ = interval_demand(c, ratios[:, None], cvt)
    t_max = max_torque(w_e, cvt.engine)  # exact full-load line (the rule interpolates it for a grid)
    admissible = (w_e <= rule.max_engine_speed) & (t_cr <= rule.torque_reserve * t_max + 1e-6 * np.abs(t_max))
    k = np.arange(gear.size)
    moving = w_e[0] > 0
    w = w_e[gear - 1, k]
    lower_ok = np.zeros(gear.size, bool)
    has_lower = gear < cvt.transmission.n_gears
    g_next = np.minimum(gear, cvt.transmission.n_gears - 1)  # index of the next lower ratio
    lower_ok[has_lower] = (admissible[g_next, k] & (w_e[g_next, k] >= rule.min_engine_speed))[has_lower]
    check = moving & (w >= rule.min_engine_speed) & (a >= 0)
    assert check.sum() > 600
    assert not np.any(lower_ok[check])
    speed_bound = check & has_lower & admissible[g_next, k]  # the lower ratio fails on speed alone
    assert speed_bound.sum() > 300
    assert np.all(w[speed_bound] <= rule.min_engine_speed * 1.0199 + 1e-9)
    # more ratio changes than a stepped gearbox has shifts, some after 1 s (no hold)
    changes = np.flatnonzero(np.diff(gear) != 0)
    assert changes.size > 300 and np.min(np.diff(changes)) == 1


@pytest.mark.parametrize("cycle", ["udds", "hwfet"])
def test_three_methods_agree_on_a_cvt(cvt, cycle):
    """Backward, inverse and forward on one CVT car and its schedule: fuel within 0.5 % of each other
    (measured: forward +0.22 / +0.09 %, inverse -0.34 / -0.13 % on UDDS / HWFET), both energy balances
    closed to rounding (3e-15 measured), the trace followed (largest error 0.33 m/s on UDDS)."""
    c = load_cycle(cycle)
    sched = default_schedule(c, cvt)
    b = vpsim.simulate(c, "backward", cvt, gears=sched)
    f = vpsim.simulate(c, "forward", cvt, gears=sched)
    i = vpsim.simulate(c, "inverse", cvt, gears=sched)
    assert b.trace_miss.seconds == 0
    assert f.fuel_kg == pytest.approx(b.fuel_kg, rel=0.005)
    assert i.fuel_kg == pytest.approx(b.fuel_kg, rel=0.005)
    assert f.energy.relative_residual < 1e-12
    assert b.energy.relative_residual < 1e-12
    assert f.trace_miss.max_speed_error_mps < 0.5


def test_a_cvt_beats_its_eight_ratio_twin_in_town(cvt):
    """The grid's finer ratios run the engine nearer the speed kept: less fuel on UDDS than 8 ratios over
    the same range with the stepped rule's hold: 6.5 % measured, asserted within 4-9 %."""
    c = load_cycle("udds")
    eight = cvt.with_changes(
        transmission={"gearbox_ratios": list(2.6 * 6.5 ** (-np.arange(8) / 7)), "cvt_ratio_step": 0.0}
    )
    rule = GearRule(min_engine_speed=130.0)
    f_cvt = vpsim.simulate(c, "backward", cvt, gears=default_schedule(c, cvt, rule=rule)).fuel_kg
    f_8 = vpsim.simulate(c, "backward", eight, gears=default_schedule(c, eight, rule=rule)).fuel_kg
    assert 0.04 < 1 - f_cvt / f_8 < 0.09


def test_batch_on_a_cvt_equals_single_runs_and_refuses_to_vary_its_grid(cvt):
    c = load_cycle("udds")
    sched = default_schedule(c, cvt)
    masses = {"vehicle.mass": [1500.0, 1800.0]}
    for method in ("backward", "forward"):
        df = run_batch(c, masses, method=method, params=cvt, mode="realistic", gears=sched)
        for m, fuel in zip(masses["vehicle.mass"], df["fuel_kg"], strict=True):
            p = cvt.with_changes(vehicle={"mass": m})
            if method == "backward":  # the batch's closed-form BQM: the exact map (the default's table: 1e-5)
                single = backward.run(
                    c,
                    p,
                    engine_map=generate_engine_map(p.engine, exact=True),
                    schedule=sched,
                    mode="realistic",
                )
            else:
                single = vpsim.simulate(c, method, p, gears=sched, driver="1")
            assert fuel == pytest.approx(single.fuel_kg, rel=1e-12)
    for name in ("transmission.gearbox_ratios[2]", "transmission.cvt_ratio_step"):
        with pytest.raises(ParameterError, match="ratio grid of a CVT"):
            run_batch(c, {name: [0.4, 0.5]}, method="backward", params=cvt)
    assert math.isfinite(df["fuel_kg"].sum())


def test_results_show_a_cvts_ratio(cvt, params):
    """Every method's series carry the gearbox ratio engaged; a CVT's plot shows it (its gear numbers are
    grid points), a stepped gearbox's the gear."""
    c = load_cycle("udds")
    for method in ("backward", "forward", "inverse"):
        df = vpsim.simulate(c, method, cvt).to_dataframe()
        by_hand = 2.6 * (0.4 / 2.6) ** ((df["gear"] - 1) / 95)  # the grid's formula, 96 points
        np.testing.assert_allclose(df["gearbox_ratio"], by_hand, rtol=1e-13)
        assert df["gearbox_ratio"].between(0.4 - 1e-12, 2.6).all()
    fig = vpsim.simulate(c, "backward", cvt).plot()
    assert fig.axes[1].get_ylabel() == "gearbox ratio"
    fig = vpsim.simulate(c, "backward", params).plot()
    assert fig.axes[1].get_ylabel() == "gear"
