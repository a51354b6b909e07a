"""Hostile mild-hybrid and stop-start inputs: belts that gear the machine down to nothing, lossless or lossy
beyond physics, packs of one cell, machines too weak to start anything, stop-start given as a number. Every
answer is one line and exit 2, or a run whose figures are finite and whose misses are counted (never a
traceback, a NaN or a silent clip)."""

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
    st.sampled_from(["", "x" * 300, True, False, "pm"]),
)
_FIELDS = [
    ("mild", "belt_ratio"),
    ("mild", "belt_efficiency"),
    ("machine", "rated_power"),
    ("machine", "base_speed"),
    ("battery", "cells_in_series"),
    ("battery", "cells_in_parallel"),
    ("battery", "soc_min"),
    ("battery", "soc_max"),
    ("hybrid", "soc_target"),
    ("hybrid", "charge_power"),
    ("simulation", "stop_start"),
]


def _toml(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    return repr(v)


def _file(base: str, entries) -> str:
    sections: dict[str, dict[str, str]] = {}
    for (sec, name), value in entries:
        sections.setdefault(sec, {})[name] = _toml(value)
    return f'base = "{base}"\n' + "".join(
        f"[{sec}]\n" + "".join(f"{k} = {v}\n" for k, v in kv.items()) for sec, kv in sections.items()
    )


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    entries=st.lists(st.tuples(st.sampled_from(_FIELDS), _values), max_size=3),
    ems=st.sampled_from(["rule", "ecms"]),
)
def test_random_mild_hybrid_files_are_valid_or_one_line(tmp_path, capsys, entries, ems):
    path = tmp_path / "car.toml"
    path.write_text(_file("mhev", entries))
    code, out, err = run_cli(capsys, "simulate", "--vehicle", path, "--cycle", "udds", "--ems", ems, "--json")
    assert code in (0, 2), err
    if code == 0:
        s = json.loads(out)
        assert math.isfinite(s["fuel_l_per_100km_cs"]) and 0.0 <= s["soc_end"] <= 1.0
        assert abs(s["energy_relative_residual"]) < 1e-9


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(value=_values, method=st.sampled_from(["backward", "inverse"]))
def test_random_stop_start_values_are_valid_or_one_line(tmp_path, capsys, value, method):
    path = tmp_path / "car.toml"
    path.write_text(_file("hofman2011", [(("simulation", "stop_start"), value)]))
    code, out, err = run_cli(
        capsys, "simulate", "--vehicle", path, "--cycle", "udds", "--method", method, "--json"
    )
    assert code in (0, 2), err
    if code == 0:
        s = json.loads(out)
        assert math.isfinite(s["fuel_l_per_100km"])
        assert (s["engine_starts"] is not None) == (value is True)


@pytest.mark.parametrize(
    ("section", "text"),
    [
        ("[mild]\nbelt_ratio = 0\n", "mild.belt_ratio"),
        ("[mild]\nbelt_ratio = 50.0\n", "mild.belt_ratio"),
        ("[mild]\nbelt_efficiency = 1.5\n", "mild.belt_efficiency"),
        ("[mild]\nbelt_efficiency = 0\n", "mild.belt_efficiency"),
        ('[mild]\nbelt_ratio = "2.7"\n', "mild.belt_ratio"),
        ("[mild]\ngear = 2\n", "unknown field mild.gear"),
        ("[simulation]\nstop_start = 1\n", "true or false"),
        ('[simulation]\nstop_start = "yes"\n', "true or false"),
        ("[hybrid]\nsoc_target = 0.9\n", "hybrid.soc_target"),
    ],
)
def test_bad_mild_fields_are_one_line(tmp_path, capsys, section, text):
    path = tmp_path / "car.toml"
    path.write_text('base = "mhev"\n' + section)
    code, _, err = run_cli(capsys, "simulate", "--vehicle", path, "--cycle", "udds")
    assert code == 2 and text in err, err
    assert len([ln for ln in err.splitlines() if ln.startswith("vpsim: error")]) == 1


def test_a_machine_too_weak_to_recharge_is_counted_not_hidden(tmp_path, capsys):
    """A 500 W machine on a one-cell-wide pack: the pack runs to its limits, the car still drives on its
    engine (the mild hybrid cannot drive electrically); the run finishes finite and its balance closed."""
    path = tmp_path / "weak.toml"
    path.write_text('base = "mhev"\n[machine]\nrated_power = 500.0\n[battery]\ncells_in_parallel = 1\n')
    code, out, _ = run_cli(
        capsys, "simulate", "--vehicle", path, "--cycle", "us06", "--ems", "ecms", "--json"
    )
    s = json.loads(out)
    assert code == 0 and s["trace_miss_s"] == 0.0 and math.isfinite(s["fuel_l_per_100km_cs"])
    assert abs(s["energy_relative_residual"]) < 1e-9
