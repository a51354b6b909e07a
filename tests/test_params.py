"""Parameter sets: the preset, its provenance, user TOML files and validation."""

from __future__ import annotations

import math

import pytest

from vpsim.errors import ParameterError
from vpsim.params import load_parameters


def test_preset_values_and_provenance(params):
    assert params.vehicle.mass == 1700.0
    assert math.isclose(params.engine.displacement, 2.29e-3, rel_tol=1e-3)
    assert params.transmission.n_gears == 5
    assert params.provenance["engine.bore"] == "paper"
    assert params.provenance["transmission.final_drive"].startswith("reconstructed")
    assert params.provenance["engine.cylinders"].startswith("derived")
    assert set(params.drivers) == {"1", "2"}
    assert params.driver(2).inverse_a == 1.0


def _write(tmp_path, text, name="car.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_user_file_overrides_base(tmp_path):
    p = load_parameters(
        _write(
            tmp_path, "[vehicle]\nmass = 1200.0\n[engine]\nbore = { value = 0.08, confidence = 'measured' }\n"
        )
    )
    assert p.vehicle.mass == 1200.0
    assert p.engine.bore == 0.08
    assert p.engine.stroke == 0.09  # from the base preset
    assert p.provenance["vehicle.mass"] == "user"
    assert p.provenance["engine.bore"] == "measured"
    assert p.name == "car"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[vehicle]\nmas = 1200.0\n", r"unknown field vehicle\.mas"),
        ("[vehicel]\nmass = 1200.0\n", r"unknown section 'vehicel'"),
        ("[engine]\nbore = 90\n", r"engine\.bore = 90 .*did you mean 0\.09"),
        ("[vehicle]\nmass = -5.0\n", r"vehicle\.mass = -5 .*positive"),
        ("[vehicle]\nmass = 0\n", r"vehicle\.mass = 0"),
        ("[transmission]\nefficiency = 1.2\n", r"transmission\.efficiency = 1\.2 is outside \(0, 1\]"),
        ("[engine]\nthermal_efficiency = 0.0\n", r"engine\.thermal_efficiency"),
        ("[engine]\ncylinders = 0\n", r"engine\.cylinders = 0 must be a positive whole number"),
        ("[engine]\ncylinders = 2.5\n", r"engine\.cylinders = 2\.5 is not a whole number"),
        ("[vehicle]\nmass = 'heavy'\n", r"vehicle\.mass = 'heavy' is not a number"),
        ("[vehicle]\nmass = nan\n", r"vehicle\.mass = nan is not a finite number"),
        ("[transmission]\ngearbox_ratios = []\n", r"gearbox_ratios"),
        ("[drivers.3]\nforward_kp = 1e-4\n", r"drivers\.3 is missing"),
        ("base = 'nope'\n", r"base = 'nope' is not a preset"),
        ("[vehicle\nmass=1\n", r"not valid TOML"),
        (
            "[transmission]\nconverter_coupling_speed_ratio = 1.2\n",
            r"converter_coupling_speed_ratio = 1\.2 is outside the plausible range \[0\.5, 0\.99\]",
        ),
        ("[transmission]\nconverter_capacity_factor = -3\n", r"converter_capacity_factor = -3"),
        ("[transmission]\nlockup_min_gear = 0\n", r"lockup_min_gear = 0 must be a positive whole number"),
        # whole numbers below their range's lower end (2026-12-07: only the upper end and 0 were refused,
        # so a 3-point DP grid ran and reported its coarse optimum as the optimum)
        ("base = 'hev_p2'\n[hybrid]\ndp_soc_points = 3\n", r"dp_soc_points = 3 is outside .* \[11, 2001\]"),
        ("base = 'hev_p2'\n[hybrid]\ntorque_levels = 1\n", r"torque_levels = 1 is outside .* \[2, 200\]"),
        ("base = 'hev_split'\n[split]\nsun_teeth = 5\n", r"sun_teeth = 5 is outside .* \[8, 500\]"),
        (
            "base = 'hev_p2'\n[hybrid]\nengine_off_power = 20e3\nengine_on_power = 10e3\n",
            r"hybrid\.engine_off_power = 20000 W is above engine_on_power = 10000 W",
        ),
    ],
)
def test_validation_errors_are_one_line_and_specific(tmp_path, text, match):
    with pytest.raises(ParameterError, match=match) as exc:
        load_parameters(_write(tmp_path, text))
    assert "\n" not in str(exc.value)
    assert "car.toml" in str(exc.value)


def test_unknown_preset_and_missing_file():
    with pytest.raises(ParameterError, match="unknown preset 'saab'"):
        load_parameters("saab")
    with pytest.raises(ParameterError, match="no such file"):
        load_parameters("/nonexistent/car.toml")


def test_with_changes_validates(params):
    p = params.with_changes(engine={"bore": 0.08}, vehicle={"mass": 1500.0})
    assert p.engine.bore == 0.08 and p.vehicle.mass == 1500.0
    with pytest.raises(ParameterError, match="unknown field engine.bor"):
        params.with_changes(engine={"bor": 0.08})
    with pytest.raises(ParameterError, match="engine.bore = 80"):
        params.with_changes(engine={"bore": 80.0})


def test_complete_file_without_base(tmp_path):
    with pytest.raises(ParameterError, match=r"\[vehicle\] is missing"):
        load_parameters(_write(tmp_path, "base = ''\n[vehicle]\nmass = 1000.0\n"))


def test_fuel_cutoff_below_idle_is_refused_in_one_line():
    """A cut-off below idle would cut an engaged engine at the clutch's own threshold (where the forward
    method's PI then chatters between cut and slipping): refused, naming the field and the idle speed."""
    from vpsim.model.record import IDLE_SPEED
    from vpsim.params import IDLE_CHECK_SPEED

    assert IDLE_CHECK_SPEED == IDLE_SPEED
    p = load_parameters("hofman2011")
    with pytest.raises(ParameterError, match=r"fuel_cutoff_speed = 50 rad/s is below the idle speed 80") as e:
        p.with_changes(simulation={"fuel_cutoff_speed": 50.0})
    assert "\n" not in str(e.value)
    assert p.with_changes(simulation={"fuel_cutoff_speed": 0.0}).simulation.fuel_cutoff_speed == 0.0
    assert p.with_changes(simulation={"fuel_cutoff_speed": 80.0}).simulation.fuel_cutoff_speed == 80.0


def test_a_parameter_set_of_another_type_is_a_type_error_that_says_what_to_pass():
    """A dict (or anything not a name, a path or Parameters) is refused with what to pass instead, not with
    a TypeError from deep inside the path handling."""
    with pytest.raises(TypeError, match=r"not dict; to change values: load_parameters\('hofman2011'\)"):
        load_parameters({"vehicle": {"mass": 1200.0}})
