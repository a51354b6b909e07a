"""Hostile power-split hybrid inputs: gear sets that lock, empty charge windows, generators too weak to hold
the engine. Every answer is one line and exit 2, or a run whose figures are finite and whose misses are
counted (never a traceback, a NaN or a silent clip)."""

from __future__ import annotations

import json
import math

import pytest
from _fuzz import run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

_values = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False, min_value=-1e5, max_value=1e5),
    st.integers(-5, 3000),
    st.sampled_from(["", "x" * 300, True, "pm"]),
)
_FIELDS = [
    ("split", "sun_teeth"),
    ("split", "ring_teeth"),
    ("split", "mg2_ratio"),
    ("split", "engine_max_speed"),
    ("split", "generator_rated_power"),
    ("split", "generator_base_speed"),
    ("split", "generator_max_speed"),
    ("split", "generator_inertia"),
    ("battery", "soc_min"),
    ("battery", "soc_max"),
    ("hybrid", "soc_target"),
]


def _toml(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    return repr(v)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(entries=st.lists(st.tuples(st.sampled_from(_FIELDS), _values), max_size=3))
def test_random_split_files_are_valid_or_one_line(tmp_path, capsys, entries):
    sections: dict[str, dict[str, str]] = {}
    for (sec, name), value in entries:
        sections.setdefault(sec, {})[name] = _toml(value)
    text = 'base = "hev_split"\n' + "".join(
        f"[{sec}]\n" + "".join(f"{k} = {v}\n" for k, v in kv.items()) for sec, kv in sections.items()
    )
    path = tmp_path / "car.toml"
    path.write_text(text)
    code, out, err = run_cli(
        capsys, "simulate", "--vehicle", path, "--cycle", "udds", "--ems", "rule", "--json"
    )
    assert code in (0, 2), err
    if code == 0:
        s = json.loads(out)
        assert math.isfinite(s["fuel_l_per_100km_cs"]) and 0.0 <= s["soc_end"] <= 1.0


@pytest.mark.parametrize(
    ("section", "text"),
    [
        ("[split]\nring_teeth = 30\n", "gear set locks"),
        ("[split]\nsun_teeth = 90\n", "gear set locks"),
        ("[split]\nring_teeth = 79\n", "must be even"),
        ("[split]\nsun_teeth = 0\n", "split.sun_teeth"),
        ("[split]\nsun_teeth = 30.5\n", "whole number"),
        ("[split]\nmg2_ratio = 0\n", "split.mg2_ratio"),
        ("[split]\ngenerator_base_speed = 2000.0\n", "split.generator_base_speed"),
        ("[split]\nengine_max_speed = 50.0\n", "split.engine_max_speed"),
        ("[battery]\nsoc_min = 0.7\nsoc_max = 0.7\nsoc_initial = 0.7\n", "battery.soc_min"),
        ("[hybrid]\nsoc_target = 0.9\n", "hybrid.soc_target"),
        ("[transmission]\ngearbox_ratios = [2.0, 1.0]\n", "gearbox_ratios must hold one ratio"),
    ],
)
def test_bad_split_fields_are_one_line(tmp_path, capsys, section, text):
    path = tmp_path / "car.toml"
    path.write_text('base = "hev_split"\n' + section)
    code, _, err = run_cli(capsys, "simulate", "--vehicle", path, "--cycle", "udds")
    assert code == 2 and text in err
    assert len([ln for ln in err.splitlines() if ln.startswith("vpsim: error")]) == 1


def test_a_generator_too_weak_to_hold_the_engine_is_a_counted_miss(tmp_path, capsys):
    """A 2 kW MG1 holds little of the engine's torque: the car drives on MG2 and the pack until it cannot;
    the run finishes with its misses counted and its balance closed."""
    path = tmp_path / "weak.toml"
    path.write_text(
        'base = "hev_split"\n[split]\ngenerator_rated_power = 2000.0\ngenerator_base_speed = 100.0\n'
    )
    code, out, _ = run_cli(
        capsys, "simulate", "--vehicle", path, "--cycle", "us06", "--ems", "ecms", "--json"
    )
    s = json.loads(out)
    assert code == 0 and s["trace_miss_s"] > 10 and math.isfinite(s["fuel_l_per_100km_cs"])
