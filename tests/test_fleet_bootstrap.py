"""The family bootstrap behind ``peer.vpsim_minus_fastsim_calibrated_by_powertrain`` (vpsim.fleet.report):
its weighted median against NumPy's median of the repeated values, and the interval's behaviour in cases
whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vpsim.fleet.report import paired_difference, weighted_medians


@settings(max_examples=200, deadline=None)
@given(
    values=st.lists(st.floats(-1e6, 1e6), min_size=1, max_size=25),
    data=st.data(),
)
def test_weighted_median_is_numpys_median_of_the_repetition(values, data):
    x = np.sort(np.asarray(values))
    row = st.lists(st.integers(0, 4), min_size=x.size, max_size=x.size)
    w = np.asarray(data.draw(st.lists(row, min_size=1, max_size=4)))
    w[:, 0] += 1  # (no empty repetition)
    got = weighted_medians(x, w)
    want = np.array([np.median(np.repeat(x, row)) for row in w])
    np.testing.assert_array_equal(got, want)


def test_the_same_errors_differ_by_nothing():
    e = np.random.default_rng(3).normal(0.0, 5.0, 60)
    d = paired_difference(e, e, np.arange(60) // 3)
    assert d["difference_pts"] == 0.0 and d["ci95_pts"] == [0.0, 0.0] and d["share_vpsim_lower"] == 0.0
    assert d["n"] == 60 and d["families"] == 20


def test_one_family_leaves_nothing_to_resample():
    # every row drawn together: each draw is the whole sample, so the interval is the point
    rng = np.random.default_rng(4)
    e, q = rng.normal(0, 4, 40), rng.normal(0, 5, 40)
    d = paired_difference(e, q, ["one"] * 40)
    assert d["families"] == 1
    assert d["ci95_pts"][0] == d["ci95_pts"][1] == pytest.approx(d["difference_pts"], abs=5e-4)


def test_a_clearly_better_tool_is_told_apart_and_a_tie_is_not():
    rng = np.random.default_rng(5)
    q = rng.normal(0.0, 6.0, 300)
    better = paired_difference(0.5 * q, q, np.arange(300))
    assert better["ci95_pts"][1] < 0.0 and better["share_vpsim_lower"] == 1.0
    assert better["difference_pts"] == pytest.approx(-0.5 * np.median(np.abs(q)), abs=1e-3)
    tie = paired_difference(rng.permutation(q), q, np.arange(300))  # the same errors on other rows
    assert tie["ci95_pts"][0] < 0.0 < tie["ci95_pts"][1]


def test_rows_missing_either_prediction_are_left_out():
    e = np.array([1.0, np.nan, 3.0, 4.0])
    q = np.array([2.0, 2.0, np.nan, 5.0])
    d = paired_difference(e, q, ["a", "b", "c", "d"])
    assert d["n"] == 2 and d["median_abs_error_pct"] == 2.5 and d["peer_median_abs_error_pct"] == 3.5
    assert paired_difference([np.nan], [1.0], ["a"]) == {
        "n": 0,
        "measured": False,
        "reason": "no row with both predictions",
    }
