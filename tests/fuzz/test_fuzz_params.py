"""Hostile vehicle/engine TOML files: a valid, finite parameter set (units converted) or one line."""

from __future__ import annotations

import math

import pytest
from _fuzz import run_cli, run_limited
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vpsim.errors import ParameterError
from vpsim.params import IDLE_CHECK_SPEED, load_parameters

CASES = [
    # the examples
    ("[engine]\ncylinders = 100000\n", "engine.cylinders = 100000 is outside the plausible range [1, 16]"),
    ("[engine]\nbore = 0.5\nstroke = 0.5\ncylinders = 16\n", "displacement 1571 L"),
    (
        "[engine]\nmap_speed_range = [50, 300, 650]\n",
        "engine.map_speed_range = [50, 300, 650] is not a list of 2",
    ),
    ("[engine]\nair_charge_slope = 0.1\n", "the engine cannot idle"),
    ("[engine]\nambient_pressure = 20001\n", "the engine cannot idle"),
    ("[transmission]\ngearbox_ratios = [3.38, true, 1.12, 0.89, 0.70]\n", "gearbox_ratios"),
    ('[vehicle]\nmass = { value = 3000, unit = "furlong" }\n', "unit 'furlong' is not known for a mass"),
    ('[vehicle]\nmass = { value = 3000, unit = "m" }\n', "unit 'm' is a length unit"),
    ("[vehicle]\nmass = { value = 3000, unit = 5 }\n", "must be a text"),
    ('[vehicle]\nmass = { value = 3000, units = "lb" }\n', "unknown key 'units'"),
    ("[vehicle]\nmass = { confidence = 'x' }\n", "without a 'value'"),
    ("[vehicle]\nmass = { value = 1200, confidence = 3 }\n", "confidence = 3 must be a text"),
    ("[drivers.1]\ninverse_a = { confidence = 'x' }\n", "without a 'value'"),
    ('[engine]\ncylinders = { value = 4, unit = "%" }\n', "is not known for a count"),
    # types
    ("[vehicle]\nmass = '1500'\n", "is not a number"),
    ("[vehicle]\nmass = true\n", "is not a number"),
    ("[vehicle]\nmass = [1500]\n", "is not a number"),
    ("[vehicle]\nmass = { value = { value = 1 } }\n", "is not a number"),
    ("[vehicle]\nmass = 1979-05-27\n", "is not a number"),
    ("[vehicle]\nmass = inf\n", "not a finite number"),
    ("[vehicle]\nmass = -inf\n", "not a finite number"),
    ("[vehicle]\nmass = 1e400\n", "not a finite number"),
    ("[vehicle]\nmass = 99999999999999999999999999999\n", "outside the plausible range"),
    ("[vehicle]\nmass = 1e308\n", "outside the plausible range"),
    ("[vehicle]\nmass = -0.0\n", "positive"),
    ("[engine]\ncylinders = 4.5\n", "is not a whole number"),
    ("[engine]\ncylinders = 99999999999999999999999999999\n", "outside the plausible range"),
    ("[engine]\ncylinders = -3\n", "positive whole number"),
    ("[engine]\nrevolutions_per_cycle = 3\n", "outside the plausible range [1, 2]"),
    ("[simulation]\ninverse_max_step = 1e9\n", "outside the plausible range"),
    ("[simulation]\ninverse_max_step = 1e-300\n", "outside the plausible range"),
    ("[simulation]\node_relative_tolerance = 1e-300\n", "outside the plausible range"),
    ("[transmission]\ngearbox_ratios = []\n", "gearbox_ratios"),
    ("[transmission]\ngearbox_ratios = [[1.0]]\n", "gearbox_ratios"),
    ("[transmission]\ngearbox_ratios = " + str([1.0] * 10000) + "\n", "gearbox_ratios"),
    ("[transmission]\ngearbox_ratios = [3.0, 'x']\n", "gearbox_ratios"),
    ("[transmission]\ngearbox_ratios = [3.0, nan]\n", "not a finite number"),
    ("[engine]\nmap_speed_range = [650, 50]\n", "must be increasing"),
    ("[engine]\nmap_speed_range = [50]\n", "is not a list of 2"),
    ("[engine]\nmap_speed_range = 650\n", "is not a list of 2"),
    ("[engine]\nfuel_heating_value = 1.5e8\nthermal_efficiency = 0.55\nlambda = 0.6\n", "full-load BMEP"),
    ("[engine]\nfriction_coefficient = 10\nboost_layout = 10\n", "motoring BMEP"),
    # structure
    ("vehicle = 3\n", "[vehicle] must be a table"),
    ("[vehicle.mass]\nvalue = 1\nunit = 'kg'\nextra = 1\n", "unknown key 'extra'"),
    ("[drivers]\n1 = 5\n", "drivers.1 must be a table"),
    ("drivers = [1, 2]\n", "[drivers] must be a table"),
    ("[drivers.1]\nforward_kp = 'fast'\n", "is not a number"),
    ("[drivers.1]\nforward_kp = -1.0\n", "must be a positive number"),
    ("[drivers.9]\nforward_kp = 1e-4\n", "drivers.9 is missing"),
    ("[vehicle]\nlambda_ = 1\n", "unknown field"),
    ("[engine]\nlambda_ = 1\n", "unknown field engine.lambda_"),
    ("[nonsense]\n", "unknown section"),
    ("base = 3\n", "is not a preset"),
    ("base = ['hofman2011']\n", "is not a preset"),
    ("base = ''\n", "is missing"),
    ("[vehicle\n", "not valid TOML"),
    ("a = " + "[" * 3000 + "]" * 3000 + "\n", "not valid TOML"),
    ("[vehicle]\nmass = 1\nmass = 2\n", "not valid TOML"),
    # a stepped gearbox lists first gear first: ascending or repeated ratios are a typo (or reversed list)
    (
        "[transmission]\ngearbox_ratios = [0.70, 0.89, 1.12, 1.76, 3.38]\n",
        "gearbox_ratios[2] = 0.89 is not below",
    ),
    ("[transmission]\ngearbox_ratios = [3.38, 1.76, 1.76, 0.70]\n", "gearbox_ratios[3] = 1.76 is not below"),
    ("[engine]\nthermal_efficiency = 1.0\n", "engine.thermal_efficiency = 1 is not below 0.6"),
    ("[engine]\nthermal_efficiency = 0.6\n", "engine.thermal_efficiency = 0.6 is not below 0.6"),
    ("[vehicle]\nmass = 1e-6\n", "vehicle.mass = 1e-06 is outside the plausible range [50, 100000] (in kg"),
    ('[vehicle]\nmass = { value = 1, unit = "mg" }\n', "vehicle.mass"),
    # Python's parser says "at end of document" of a quote, string or array left open: the line it opens on
    ("[vehicle]\nname = 'x\nmass = 1200\n", "(at line 2, where it opens and is never closed)"),
    ('[vehicle]\nmass = [1,\n2,\n3]\n[engine]\nbore = 0.07\nx = """abc\n\ny=1\n', "(at line 7, where it"),
    ("[vehicle]\nmass = 1200\nname = [\n'a',\n", "(at line 3, where it opens"),
    ("[vehicle]\nname = 'x\n" + "# c\n" * 6000, "(at end of document)"),  # too long to search: as parsed
]


def _write(tmp_path, text: str | bytes, name="car.toml"):
    p = tmp_path / name
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    return p


@pytest.mark.parametrize(("text", "match"), CASES, ids=[f"case{k}" for k in range(len(CASES))])
def test_hostile_parameter_file(tmp_path, text, match):
    p = _write(tmp_path, text)
    with pytest.raises(ParameterError) as exc:
        load_parameters(p)
    msg = str(exc.value)
    assert match in msg, msg
    assert "\n" not in msg and len(msg) < 600 and "car.toml" in msg


@pytest.mark.parametrize(
    ("text", "field", "expected"),
    [
        ('[vehicle]\nmass = { value = 3000, unit = "lb" }\n', "vehicle.mass", 3000 * 0.45359237),
        ('[vehicle]\nmass = { value = 1.5, unit = "t", confidence = "measured" }\n', "vehicle.mass", 1500.0),
        ('[vehicle]\nmass = { value = 1500, unit = "kg" }\n', "vehicle.mass", 1500.0),
        (
            '[vehicle]\nfrontal_area = { value = 25, unit = "ft^2" }\n',
            "vehicle.frontal_area",
            25 * 0.09290304,
        ),
        ('[vehicle]\nwheel_radius = { value = 300, unit = "mm" }\n', "vehicle.wheel_radius", 0.3),
        ('[vehicle]\nwheel_radius = { value = 12, unit = "in" }\n', "vehicle.wheel_radius", 0.3048),
        ('[engine]\nbore = { value = 9, unit = "cm" }\n', "engine.bore", 0.09),
        (
            '[engine]\nintake_manifold_volume = { value = 2.5, unit = "L" }\n',
            "engine.intake_manifold_volume",
            2.5e-3,
        ),
        (
            '[engine]\nintake_manifold_volume = { value = 2500, unit = "cc" }\n',
            "engine.intake_manifold_volume",
            2.5e-3,
        ),
        (
            '[engine]\nambient_pressure = { value = 1.013, unit = "bar" }\n',
            "engine.ambient_pressure",
            1.013e5,
        ),
        (
            '[engine]\nambient_pressure = { value = 14.7, unit = "psi" }\n',
            "engine.ambient_pressure",
            101352.93,
        ),
        ('[engine]\nexhaust_pressure = { value = 110, unit = "kPa" }\n', "engine.exhaust_pressure", 1.1e5),
        (
            '[engine]\nambient_temperature = { value = 20, unit = "degC" }\n',
            "engine.ambient_temperature",
            293.15,
        ),
        ('[engine]\ninertia = { value = 0.2, unit = "kg*m^2" }\n', "engine.inertia", 0.2),
        (
            '[engine]\nfuel_heating_value = { value = 44, unit = "MJ/kg" }\n',
            "engine.fuel_heating_value",
            44e6,
        ),
        ('[simulation]\nfuel_density = { value = 745, unit = "kg/m^3" }\n', "simulation.fuel_density", 0.745),
        (
            '[simulation]\nidle_fuel_flow = { value = 0.13, unit = "g/s" }\n',
            "simulation.idle_fuel_flow",
            1.3e-4,
        ),
        ('[transmission]\nefficiency = { value = 90, unit = "%" }\n', "transmission.efficiency", 0.9),
    ],
)
def test_units_are_converted(tmp_path, text, field, expected):
    p = load_parameters(_write(tmp_path, text))
    assert math.isclose(p.flat()[field], expected, rel_tol=1e-4), p.flat()[field]


def test_map_speed_range_in_rpm_and_encodings(tmp_path):
    p = load_parameters(
        _write(tmp_path, '[engine]\nmap_speed_range = { value = [500, 6000], unit = "rpm" }\n')
    )
    assert math.isclose(p.engine.map_speed_range[1], 6000 * 2 * math.pi / 60)
    p = load_parameters(_write(tmp_path, b"\xef\xbb\xbf[vehicle]\r\nmass = 1200\r\n"))
    assert p.vehicle.mass == 1200.0
    for data, match in [
        (b"[vehicle]\nmass = 1200 # \xe9\n", "not a text file in UTF-8"),
        ("[vehicle]\nmass = 1200\n".encode("utf-16"), "not a text file"),
        (b"\x00\x01\x02", "not a text file"),
    ]:
        with pytest.raises(ParameterError, match=match):
            load_parameters(_write(tmp_path, data))


def test_paths_that_are_not_files(tmp_path):
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    a.symlink_to(b)
    b.symlink_to(a)
    with pytest.raises(ParameterError, match="symbolic link loop"):
        load_parameters(a)
    (tmp_path / "dir.toml").mkdir()
    with pytest.raises(ParameterError, match="is a folder"):
        load_parameters(tmp_path / "dir.toml")
    with pytest.raises(ParameterError, match="no such file"):
        load_parameters(tmp_path / "missing.toml")


def test_idle_check_speed_is_the_methods_idle_speed():
    from vpsim.model import IDLE_SPEED

    assert IDLE_CHECK_SPEED == IDLE_SPEED


def test_cli_params_and_simulate_answer_in_one_line(capsys, tmp_path):
    for k, (text, match) in enumerate(CASES[:20]):
        p = _write(tmp_path, text, f"c{k}.toml")
        code, _, err = run_cli(capsys, "params", "--vehicle", p)
        assert code == 2 and match in err
    code, out, _ = run_cli(capsys, "params", "--json")
    assert code == 0


@pytest.mark.parametrize(
    "text",
    [
        "[engine]\ncylinders = 100000\n",
        "[engine]\nbore = 0.5\nstroke = 0.5\ncylinders = 16\n",
        # every field inside the bounds, the largest engine they allow: its map must stay small
        "[engine]\nbore = 0.2\nstroke = 0.2\ncylinders = 2\nrevolutions_per_cycle = 1\n"
        "friction_coefficient = 1.34\nmap_speed_range = [50, 2000]\n",
    ],
)
def test_large_engines_stay_within_memory(tmp_path, text):
    _write(tmp_path, text)
    run_limited(["simulate", "--vehicle", "car.toml", "--json"], cwd=tmp_path, timeout=120)


def test_forward_method_on_a_low_slope_engine_is_one_line(capsys, tmp_path):
    p = _write(tmp_path, "[engine]\nair_charge_slope = 0.1\n")
    code, _, err = run_cli(capsys, "simulate", "--vehicle", p, "--method", "forward")
    assert code == 2 and "cannot idle" in err


_FIELDS = {
    "vehicle": ["mass", "frontal_area", "drag_coefficient", "rolling_resistance", "wheel_radius"],
    "engine": [
        "bore",
        "stroke",
        "cylinders",
        "ambient_pressure",
        "air_charge_slope",
        "air_charge_intercept",
        "friction_coefficient",
        "map_speed_range",
        "lambda",
        "thermal_efficiency",
    ],
    "transmission": ["gearbox_ratios", "final_drive", "efficiency"],
    "simulation": ["fuel_density", "idle_fuel_flow", "inverse_max_step", "fuel_cutoff_speed", "stop_start"],
}
_SWITCHES = {"simulation.stop_start"}  # the fields that take true or false
_scalar = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**25), 10**25),
    st.booleans(),
    st.text(max_size=5),
)
_value = st.one_of(_scalar, st.lists(_scalar, max_size=6))
_units = st.sampled_from(
    ["kg", "lb", "m", "mm", "rpm", "bar", "degC", "L", "-", "%", "furlong", "", "kg m^2"]
)


def _toml(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return '"' + v.encode("unicode_escape").decode().replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    raise TypeError(v)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    entries=st.lists(
        st.tuples(
            st.sampled_from([(s, f) for s, fs in _FIELDS.items() for f in fs]),
            _value,
            st.one_of(st.none(), _units),
        ),
        max_size=4,
    )
)
def test_random_parameter_files_are_valid_or_one_line(tmp_path, entries):
    lines: dict[str, list[str]] = {}
    for (sec, name), value, unit in entries:
        val = _toml(value) if unit is None else f"{{ value = {_toml(value)}, unit = {_toml(unit)} }}"
        lines.setdefault(sec, []).append(f"{name} = {val}")
    text = "".join(f"[{sec}]\n" + "\n".join(dict.fromkeys(ls)) + "\n" for sec, ls in lines.items())
    p = _write(tmp_path, text)
    try:
        params = load_parameters(p)
    except ParameterError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 800
        return
    for key, v in params.flat().items():
        for x in v if isinstance(v, tuple) else (v,):
            if isinstance(x, str):  # a name: powertrain.type, machine.kind, battery.cell, machine.map_file
                continue
            if key in _SWITCHES:
                assert isinstance(x, bool), (key, x)
                continue
            assert not isinstance(x, bool) and math.isfinite(x), (key, x)
    assert 0.04e-3 <= params.engine.displacement <= 16e-3


@pytest.mark.parametrize(
    "text",
    [
        "[transmission]\ngearbox_ratios = [2.6, 0.4]\ncvt_ratio_step = 0.02\n",  # a CVT's [launch, overdrive]
        "[transmission]\ngearbox_ratios = [3.9]\n",  # one ratio
        "[vehicle]\nmass = 50\n[engine]\nthermal_efficiency = 0.59\n",  # the limits themselves
    ],
)
def test_what_the_new_bounds_still_accept(tmp_path, text):
    load_parameters(_write(tmp_path, text))


def test_a_single_reduction_bev_still_loads():
    assert load_parameters("bev").transmission.gearbox_ratios == (1.0,)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[vehicle]\nroad_load_a = 5\nroad_load_b = -3\nroad_load_c = 0.05\n", "give a road load of"),
        (
            "[vehicle]\nroad_load_a = 0\nroad_load_b = -1\nroad_load_c = 0.5\n",
            "from 0 to 36 m/s",
        ),
    ],
)
def test_a_road_load_that_pushes_the_car_is_refused(tmp_path, text, match):
    with pytest.raises(ParameterError, match=match):
        load_parameters(_write(tmp_path, text))


@settings(max_examples=30)
@given(
    data=st.lists(
        st.tuples(
            st.floats(0.5, 4.0),  # gear 2
            st.floats(0.5, 4.0),  # gear 3
            st.floats(0.0, 300.0),  # road load A
            st.floats(-20.0, 10.0),  # B
            st.floats(0.0, 1.0),  # C
        ),
        min_size=1,
        max_size=6,
    )
)
def test_batch_variants_are_refused_exactly_when_one_of_them_is(data):
    """The batch's vectorised checks of coupled fields (descending gears, a road load >= 0) agree with each
    variant's own parameter check: a bad combination is never found only mid-run."""
    import numpy as np

    from vpsim.batch import validate_variants, variant_parameters

    params = load_parameters("hofman2011")
    names = [
        "transmission.gearbox_ratios[2]",
        "transmission.gearbox_ratios[3]",
        "vehicle.road_load_a",
        "vehicle.road_load_b",
        "vehicle.road_load_c",
    ]
    values = np.array(data, dtype=float)
    any_bad = False
    for row in values:
        try:
            variant_parameters(params, names, row)
        except ParameterError:
            any_bad = True
    if any_bad:
        with pytest.raises(ParameterError, match=r"^variant \d+: "):
            validate_variants(params, names, values)
    else:
        validate_variants(params, names, values)
