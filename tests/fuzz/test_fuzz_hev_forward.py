"""Hostile forward-hybrid inputs: driver gains and steps that make the sampled driver unstable, managements
the forward method cannot run. Every answer is one line and exit 2, or a run whose figures are finite and
whose speed error, if any, is counted (never a traceback, a NaN or a number from an oscillating driver)."""

from __future__ import annotations

import json
import math

import pytest
from _fuzz import run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    car=st.sampled_from(["hev_p2", "hev_split"]),
    kp=st.floats(1e-3, 100.0),
    ki=st.floats(1e-3, 100.0),
    step=st.floats(1e-2, 1.0),
)
def test_driver_gains_and_steps_are_a_run_or_one_line(tmp_path, capsys, car, kp, ki, step):
    path = tmp_path / "car.toml"
    path.write_text(
        f'base = "{car}"\n[electric]\nforward_kp = {kp!r}\nforward_ki = {ki!r}\nforward_max_step = {step!r}\n'
    )
    code, out, err = run_cli(
        capsys,
        "simulate",
        "--vehicle",
        path,
        "--cycle",
        "hwfet",
        "--method",
        "forward",
        "--ems",
        "rule",
        "--json",
    )
    assert code in (0, 2), err
    if code == 2:
        assert "unstable" in err or "forward_" in err, err
        return
    s = json.loads(out)
    assert math.isfinite(s["fuel_l_per_100km_cs"]) and 0.0 <= s["soc_end"] <= 1.0
    # a sluggish driver (small gains) may fall far behind: counted as speed not followed, not hidden
    if s["max_speed_error_mps"] > 2.0 / 3.6 + 1e-6:
        assert s["speed_not_followed_s"] > 0.0


@pytest.mark.parametrize(
    ("kp", "ki", "step"),
    [(4.0, 4.0, 1.0), (10.0, 4.0, 0.25), (100.0, 100.0, 1.0)],
)
def test_an_unstable_sampled_driver_is_refused(tmp_path, capsys, kp, ki, step):
    """Those gave 17.6, 20.9 and 38.8 L/100 km on UDDS (the P2's 2.9), the car oscillating about the trace."""
    path = tmp_path / "car.toml"
    path.write_text(
        f'base = "hev_p2"\n[electric]\nforward_kp = {kp}\nforward_ki = {ki}\nforward_max_step = {step}\n'
    )
    code, _, err = run_cli(capsys, "simulate", "--vehicle", path, "--cycle", "udds", "--method", "forward")
    assert code == 2 and "unstable" in err and "electric.forward_kp" in err


def test_dp_on_the_forward_method_is_one_line(capsys):
    code, _, err = run_cli(
        capsys, "simulate", "--vehicle", "hev_p2", "--cycle", "udds", "--method", "forward", "--ems", "dp"
    )
    assert code == 2 and "backward method only" in err
