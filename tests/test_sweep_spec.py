"""Sweep specification: parsing, sampling, validation and stable point identities."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vpsim.sweep import SpecError, apply_changes, load_spec, make_spec, plan
from vpsim.sweep.store import design_identity

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "sweep_small.toml"


def test_example_spec_is_about_40_points():
    spec = load_spec(EXAMPLE)
    assert spec.sampling == "factorial"
    assert spec.cycles == ("nedc",) and spec.methods == ("backward",)
    assert spec.n_designs == 40
    designs = spec.designs()
    assert len(designs) == 41 and designs[0].is_baseline and designs[0].changes == {}
    assert {d.changes["engine.cylinders"] for d in designs[1:]} == {3, 4}
    bores = sorted({d.changes["engine.bore"] for d in designs[1:]})
    assert bores == pytest.approx([0.08, 0.085, 0.09, 0.095])


def test_toml_and_python_call_are_the_same_spec(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text(
        'cycles = ["nedc", "ftp75"]\nmethods = ["backward"]\nsampling = "lhs"\nsamples = 7\nseed = 3\n'
        "[parameters.engine]\nbore = { range = [0.08, 0.095] }\ncylinders = [3, 4, 5]\n"
        '[parameters]\n"vehicle.mass" = { range = [1200, 1700] }\n'
    )
    a = load_spec(f)
    b = make_spec(
        cycles=["nedc", "ftp75"],
        methods=["backward"],
        sampling="lhs",
        samples=7,
        seed=3,
        parameters={
            "engine.bore": {"range": [0.08, 0.095]},
            "engine.cylinders": [3, 4, 5],
            "vehicle.mass": {"range": [1200, 1700]},
        },
    )
    assert [d.changes for d in a.designs()] == [d.changes for d in b.designs()]
    assert [t.rows for t in plan(a).tasks] == [t.rows for t in plan(b).tasks]


def test_latin_hypercube_is_stratified_seeded_and_typed():
    kw = {
        "parameters": {
            "engine.bore": {"range": [0.08, 0.1]},
            "engine.cylinders": {"range": [2, 6]},
            "transmission.final_drive": [3.5, 4.0, 4.5, 5.0],
        },
        "sampling": "lhs",
        "samples": 20,
        "baseline": False,
    }
    d1 = make_spec(seed=1, **kw).designs()
    assert len(d1) == 20
    bore = np.array([d.changes["engine.bore"] for d in d1])
    strata = np.floor((bore - 0.08) / 0.02 * 20).astype(int)
    assert sorted(strata) == list(range(20))  # one sample per stratum
    assert all(isinstance(d.changes["engine.cylinders"], int) for d in d1)
    fd = [d.changes["transmission.final_drive"] for d in d1]
    assert all(fd.count(v) == 5 for v in (3.5, 4.0, 4.5, 5.0))  # list levels: equal strata
    assert [d.changes for d in make_spec(seed=1, **kw).designs()] == [d.changes for d in d1]
    assert [d.changes for d in make_spec(seed=2, **kw).designs()] != [d.changes for d in d1]


def test_gear_axes_and_ratio_sets(params):
    spec = make_spec(
        parameters={"transmission.gearbox_ratios[5]": {"range": [0.6, 0.8], "n": 3}}, baseline=False
    )
    p = apply_changes(params, spec.designs()[0].changes)
    assert p.transmission.gearbox_ratios[4] == pytest.approx(0.6)
    assert p.transmission.gearbox_ratios[:4] == params.transmission.gearbox_ratios[:4]
    spec = make_spec(
        parameters={"transmission.gearbox_ratios": {"values": [[3.0, 2.0, 1.0], [3.5, 1.9, 1.2, 0.9]]}},
        gears="per_design",
    )
    assert [apply_changes(params, d.changes).transmission.n_gears for d in spec.designs()] == [5, 3, 4]


@pytest.mark.parametrize(
    ("keys", "message"),
    [
        ({"parameters": {"engine.bore": {"range": [80, 95], "n": 3}}}, "did you mean 0.08"),
        ({"parameters": {"engine.bores": [0.08]}}, "unknown parameter"),
        ({"parameters": {"bore": [0.08]}}, "did you mean 'engine.bore'"),
        ({"parameters": {"engine.bore": {"range": [0.09, 0.08]}}}, "low < high"),
        ({"parameters": {"engine.bore": {"range": [0.08, 0.09], "n": 0}}}, "n = 0"),
        ({"parameters": {"engine.bore": {"range": [0.08, 0.09], "step": 1}}}, "unknown key 'step'"),
        ({"parameters": {"engine.cylinders": [3, 3.5]}}, "not a whole number"),
        ({"parameters": {"engine.cylinders": [3, 3]}}, "values repeat"),
        ({"parameters": {"engine.map_speed_range": [1.0]}}, "cannot be swept"),
        ({"parameters": {"drivers.1.forward_kp": [1e-4]}}, "drivers = [...]"),
        ({"parameters": {"transmission.gearbox_ratios[7]": [1.0]}}, "gear 7 does not exist"),
        ({"sampling": "sobol"}, "sampling = 'sobol'"),
        ({"sampling": "lhs"}, "needs samples"),
        ({"samples": 10}, "applies to sampling"),
        ({"methods": ["backwards"]}, "unknown method 'backwards'"),
        ({"drivers": [3], "methods": ["forward"]}, "driver '3' is not defined"),
        ({"cycles": ["nedcx"]}, "cycles:"),
        ({"mode": "sport"}, "mode = 'sport'"),
        ({"acceleration": {"shift_speed": 5500}}, "rad/s, not rpm"),
        ({"acceleration": {"shift_speed": 200.0}}, "above launch_speed"),
        (
            {"parameters": {"transmission.gearbox_ratios": {"values": [[3.0, 2.0, 1.0]]}}},
            'gears = "per_design"',
        ),
        ({"gears": "auto"}, "gears = 'auto'"),
        ({"colour": "red"}, "unknown key 'colour'"),
    ],
)
def test_invalid_specs_say_what_is_wrong(keys, message):
    with pytest.raises(SpecError, match="make_spec") as info:
        make_spec(**keys)
    assert message in str(info.value)


def test_spec_file_errors_name_the_file(tmp_path):
    f = tmp_path / "bad.toml"
    f.write_text("[parameters\n")
    with pytest.raises(SpecError, match="bad.toml: not valid TOML"):
        load_spec(f)
    with pytest.raises(SpecError, match="no such file"):
        load_spec(tmp_path / "missing.toml")


def test_point_ids_are_stable_across_processes():
    spec = load_spec(EXAMPLE)
    ids = [r[0] for t in plan(spec).tasks for r in t.rows]
    assert len(set(ids)) == len(ids) == 41
    code = (
        "import json, sys; from vpsim.sweep import load_spec, plan; "
        f"print(json.dumps([r[0] for t in plan(load_spec({str(EXAMPLE)!r})).tasks for r in t.rows]))"
    )
    env = dict(os.environ, PYTHONHASHSEED="12345")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    assert json.loads(out.stdout) == ids


def test_design_identity_depends_on_values_not_spelling(params):
    flat = params.flat()
    assert design_identity(flat, {}) == design_identity(flat, {"engine.bore": 0.09})  # the base value
    assert design_identity(flat, {"engine.bore": 0.085}) != design_identity(flat, {"engine.bore": 0.0850001})
    g = design_identity(flat, {"transmission.gearbox_ratios[1]": 3.5})
    full = list(params.transmission.gearbox_ratios)
    full[0] = 3.5
    assert g == design_identity(flat, {"transmission.gearbox_ratios": tuple(full)})


@settings(max_examples=25, deadline=None)
@given(n=st.integers(1, 60), seed=st.integers(0, 2**32 - 1))
def test_latin_hypercube_property(n, seed):
    spec = make_spec(
        parameters={"vehicle.mass": {"range": [1000.0, 2000.0]}, "engine.bore": {"range": [0.07, 0.1]}},
        sampling="lhs",
        samples=n,
        seed=seed,
        baseline=False,
        acceleration=False,
    )
    designs = spec.designs()
    assert len(designs) == n
    for name, (lo, hi) in (("vehicle.mass", (1000.0, 2000.0)), ("engine.bore", (0.07, 0.1))):
        x = np.array([d.changes[name] for d in designs])
        assert np.all((x >= lo) & (x <= hi))
        strata = np.minimum(np.floor((x - lo) / (hi - lo) * n), n - 1).astype(int)
        assert sorted(strata) == list(range(n))


@settings(max_examples=25, deadline=None)
@given(bore=st.floats(0.05, 0.12), mass=st.floats(800.0, 3000.0))
def test_design_identity_ignores_the_order_of_changes(params, bore, mass):
    flat = params.flat()
    a = design_identity(flat, {"engine.bore": bore, "vehicle.mass": mass})
    b = design_identity(flat, {"vehicle.mass": mass, "engine.bore": bore})
    assert a == b
