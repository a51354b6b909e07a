"""The electric machine: envelope, loss model, scaling, ADVISOR map reader, the LOO check and the CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vpsim.cli.main import main
from vpsim.engines.machine_map import MeasuredMachine, load_machine
from vpsim.errors import EngineFileError, MachineFileError, ParameterError
from vpsim.model.machine import (
    DEFAULT_COEFFICIENTS,
    RECORD_FIELDS,
    LossCoefficients,
    MachineSpec,
    efficiency_table,
    electric_power,
    loss_w,
    machine_record,
    max_torque,
    min_torque,
)

MC_FILES = ("MC_AC59", "MC_AC75", "MC_PM32", "MC_PM49", "MC_PM58", "MC_PRIUS_JPN")
GC_FILES = ("GC_PM32", "GC_PRIUS_JPN")
# Leave-one-out median |efficiency error| (percentage points) that benchmarks/machine_fit.py reports and
# docs/model.md states; the test holds them to within 0.05 points.
LOO_MEDIAN_PTS = {
    "MC_AC59": 3.22,
    "MC_AC75": 2.05,
    "MC_PM32": 2.21,
    "MC_PM49": 1.32,
    "MC_PM58": 4.25,
    "MC_PRIUS_JPN": 4.15,
}


def _advisor(shared_dir: Path, name: str) -> Path:
    return shared_dir / "data" / "raw" / "advisor" / f"{name}.m"


SPEC = MachineSpec(rated_power_w=50e3, base_speed_radps=300.0, max_speed_radps=1000.0, kind="pm")


# ------------------------------------------------------------------------------------ envelope and loss


def test_envelope_limits() -> None:
    m = machine_record(SPEC)
    w = np.array([0.0, 150.0, 300.0, 600.0, 1000.0, 1000.1, -600.0])
    t_max = max_torque(w, m)
    t_r = 50e3 / 300.0
    np.testing.assert_allclose(t_max, [t_r, t_r, t_r, t_r / 2, t_r * 0.3, 0.0, t_r / 2])
    np.testing.assert_allclose(min_torque(w, m), -t_max)
    assert np.all(t_max[(w >= 300) & (w <= 1000)] * w[(w >= 300) & (w <= 1000)] <= 50e3 * (1 + 1e-12))
    assert m.rated_torque == pytest.approx(t_r)


@settings(max_examples=200, deadline=None)
@given(
    t=st.floats(-2000, 2000),
    w=st.floats(-3000, 3000),
    power=st.floats(1e3, 1e6),
    base=st.floats(10, 2000),
    kind=st.sampled_from(["pm", "induction"]),
)
def test_loss_nonnegative_and_energy_conserved(t, w, power, base, kind) -> None:
    m = machine_record(MachineSpec(power, base, base * 3, kind=kind))
    loss = loss_w(t, w, m)
    assert loss >= 0 and math.isfinite(loss)
    assert electric_power(t, w, m) - t * w == pytest.approx(loss, rel=1e-9, abs=1e-9 * power)


@settings(max_examples=200, deadline=None)
@given(
    tau=st.floats(-1.5, 1.5),
    omega=st.floats(0, 5),
    power=st.floats(1e3, 5e5),
    base=st.floats(10, 2000),
    factor=st.floats(0.1, 10),
    kind=st.sampled_from(["pm", "induction"]),
)
def test_loss_scales_with_rating(tau, omega, power, base, factor, kind) -> None:
    """Same base speed, rating times k: at the same normalised point (T / T_r, w / w_b), k times the loss."""
    small = machine_record(MachineSpec(power, base, base * 5, kind=kind))
    big = machine_record(MachineSpec(power * factor, base, base * 5, kind=kind))
    l_small = loss_w(tau * small.rated_torque, omega * base, small)
    l_big = loss_w(tau * big.rated_torque, omega * base, big)
    assert l_big == pytest.approx(factor * l_small, rel=1e-9, abs=1e-12)


def test_copper_loss_follows_torque_not_speed_rating() -> None:
    """Same peak torque, rated to run twice as fast: below both base speeds the same copper loss in W at the
    same torque and speed; the speed terms are taken at the same fraction of the maximum speed."""
    copper = LossCoefficients(k0=0, k_sw=0, k_cu=0.2, k_fw=0.05, k_fe_h=0, k_fe_e=0, k_mech=0)
    iron = LossCoefficients(k0=0, k_sw=0, k_cu=0, k_fw=0, k_fe_h=0.03, k_fe_e=0.01, k_mech=0.02)
    slow_cu, fast_cu = (
        machine_record(MachineSpec(p, b, 3 * b, coefficients=copper)) for p, b in ((5e4, 3e2), (1e5, 6e2))
    )
    for w in (50.0, 150.0, 300.0):
        assert loss_w(120.0, w, fast_cu) == pytest.approx(loss_w(120.0, w, slow_cu), rel=1e-12)
    slow_fe, fast_fe = (
        machine_record(MachineSpec(p, b, 3 * b, coefficients=iron)) for p, b in ((5e4, 3e2), (1e5, 6e2))
    )
    for w in (100.0, 450.0, 900.0):
        assert loss_w(120.0, 2.0 * w, fast_fe) == pytest.approx(2.0 * loss_w(120.0, w, slow_fe), rel=1e-12)


def test_doubling_rating_doubles_losses_on_a_grid() -> None:
    a = machine_record(SPEC)
    b = machine_record(MachineSpec(100e3, 300.0, 1000.0, kind="pm"))
    tau, omega = np.meshgrid(np.linspace(-1, 1, 9), np.linspace(0, 3, 7))
    np.testing.assert_allclose(
        loss_w(tau * b.rated_torque, omega * 300.0, b), 2 * loss_w(tau * a.rated_torque, omega * 300.0, a)
    )


def test_equations_compile_and_agree_with_python() -> None:
    @numba.njit(cache=False)
    def kernel(t, w, m):
        return loss_w(t, w, m), electric_power(t, w, m), max_torque(w, m), min_torque(w, m)

    m = machine_record(MachineSpec(30e3, 400.0, 1200.0, kind="induction"))
    for t, w in ((50.0, 100.0), (-20.0, 900.0), (0.0, 0.0), (80.0, 1300.0)):
        got = kernel(t, w, m)
        want = (loss_w(t, w, m), electric_power(t, w, m), max_torque(w, m), min_torque(w, m))
        np.testing.assert_allclose(got, want, rtol=1e-12)


def test_record_fields_and_read_only() -> None:
    m = machine_record(SPEC)
    assert m.dtype.names == RECORD_FIELDS
    assert m.k_cu == DEFAULT_COEFFICIENTS["pm"].k_cu
    with pytest.raises(ValueError):
        m.rated_power = 1.0


@pytest.mark.parametrize(
    ("kwargs", "what"),
    [
        ({"rated_power_w": 0.0}, "rated_power_w = 0"),
        ({"rated_power_w": -5.0}, "rated_power_w = -5"),
        ({"base_speed_radps": float("nan")}, "base_speed_radps = nan"),
        ({"max_speed_radps": 100.0}, "below base_speed_radps"),
        ({"kind": "dc"}, "kind = 'dc'"),
        ({"inertia_kgm2": -1.0}, "inertia_kgm2 = -1"),
        ({"rated_power_w": "big"}, "is not a number"),
    ],
)
def test_spec_validation(kwargs, what) -> None:
    args = {"rated_power_w": 50e3, "base_speed_radps": 300.0, "max_speed_radps": 1000.0, **kwargs}
    with pytest.raises(ParameterError) as info:
        MachineSpec(**args)
    assert what in str(info.value) and "\n" not in str(info.value)


def test_coefficient_validation() -> None:
    good = DEFAULT_COEFFICIENTS["pm"].as_dict()
    with pytest.raises(ParameterError, match="k_cu = -0.1"):
        LossCoefficients(**{**good, "k_cu": -0.1})
    with pytest.raises(ParameterError, match="k0 = inf"):
        LossCoefficients(**{**good, "k0": math.inf})


def test_efficiency_table_of_spec() -> None:
    eff = efficiency_table(SPEC, [0.0, 100.0, 600.0], [-100.0, 0.0, 100.0, 160.0])
    assert np.all(np.isnan(eff[0])) and np.all(np.isnan(eff[:, 1]))
    assert np.isnan(eff[2, 3])  # 160 N m is above the envelope at 600 rad/s
    assert 0.5 < eff[1, 2] < 1 and 0.5 < eff[1, 0] < 1


# ------------------------------------------------------------------------------------ measured maps


@pytest.mark.parametrize("name", MC_FILES + GC_FILES)
def test_reader_on_advisor_files(shared_dir: Path, name: str) -> None:
    m = load_machine(_advisor(shared_dir, name))
    assert isinstance(m, MeasuredMachine)
    t, w, eff = m.map_points()
    assert t.size > 80 and np.all((eff > 0) & (eff <= 1))
    assert np.any(t > 0) and np.any(t < 0)
    assert m.speed_grid[0] == 0 and m.max_speed_radps > m.base_speed_radps > 0
    grid_t, grid_w = np.meshgrid(m.torque_grid, m.speed_grid)
    loss = m.loss_w(grid_t, grid_w)
    assert np.all(np.isfinite(loss)) and np.all(loss >= 0)
    # the map's own efficiency is reproduced at its nodes (motoring T w / P_elec, generating P_elec / T w)
    p_mech = t * w
    p_elec = m.electric_power_w(t, w)
    np.testing.assert_allclose(np.where(t > 0, p_mech / p_elec, p_elec / p_mech), eff, rtol=1e-12)
    summary = m.summary()
    assert summary["rated_power_kw"] == pytest.approx(m.rated_power_w / 1e3)


def test_reader_ratings(shared_dir: Path) -> None:
    ratings = {n: load_machine(_advisor(shared_dir, n)) for n in MC_FILES}
    kw = {n: round(m.rated_power_w / 1e3, 1) for n, m in ratings.items()}
    assert kw == {
        "MC_AC59": 58.6,
        "MC_AC75": 74.6,
        "MC_PM32": 33.0,
        "MC_PM49": 49.0,
        "MC_PM58": 58.1,
        "MC_PRIUS_JPN": 30.5,
    }
    pm49 = ratings["MC_PM49"]
    assert pm49.min_torque_at(0.0) == -170.0  # its own generating envelope, not the mirror
    assert pm49.base_speed_radps * 30 / math.pi == pytest.approx(49.0e3 / 274.4 * 30 / math.pi, rel=1e-2)


def test_gc_prius_negative_speeds_fold(shared_dir: Path) -> None:
    m = load_machine(_advisor(shared_dir, "GC_PRIUS_JPN"))
    assert m.speed_grid[0] == 0.0 and m.speed_grid.size == 10
    assert m.loss_w(20.0, -300.0) == pytest.approx(m.loss_w(-20.0, 300.0))


def test_loss_between_nodes_and_outside(shared_dir: Path) -> None:
    m = load_machine(_advisor(shared_dir, "MC_PM49"))
    t0, t1 = m.torque_grid[11], m.torque_grid[12]
    w0 = m.speed_grid[5]
    mid = m.loss_w(0.5 * (t0 + t1), w0)
    assert min(m.loss_w(t0, w0), m.loss_w(t1, w0)) <= mid <= max(m.loss_w(t0, w0), m.loss_w(t1, w0))
    assert not m.inside_grid(1000.0, 100.0)
    assert m.loss_w(1000.0, 100.0) == pytest.approx(m.loss_w(m.torque_grid[-1], 100.0))


def test_leave_one_out_figures(shared_dir: Path, benchmark_script) -> None:
    """The figures docs/model.md reports, re-derived: each file predicted from the other files' fit."""
    fit = benchmark_script("machine_fit")
    machines = fit.load_all(shared_dir / "data" / "raw" / "advisor")
    rows = {r["file"]: r for r in fit.leave_one_out(machines)}
    for name, want in LOO_MEDIAN_PTS.items():
        assert rows[name]["median_abs_efficiency_error_pts"] == pytest.approx(want, abs=0.05), name
    # the form's floor: each file fitted on itself does at least as well as from the others, and MC_PM32
    # stays above 2 points even so (the 2-point target is beyond this form on that map)
    for name, r in rows.items():
        assert r["own_fit_median_abs_efficiency_error_pts"] <= r["median_abs_efficiency_error_pts"] + 0.05, (
            name
        )
    assert rows["MC_PM32"]["own_fit_median_abs_efficiency_error_pts"] == pytest.approx(2.13, abs=0.05)
    assert rows["MC_AC59"]["fitted_on"] == ["MC_AC75", "MC_PM32", "MC_PM49", "MC_PM58", "MC_PRIUS_JPN"]
    assert rows["MC_PM49"]["fitted_on"] == ["MC_AC59", "MC_AC75", "MC_PM32", "MC_PM58", "MC_PRIUS_JPN"]
    # the shipped defaults are the fit on all six, both kinds pooled
    for kind, coeffs in fit.fitted_defaults(machines).items():
        for key, value in coeffs.as_dict().items():
            assert getattr(DEFAULT_COEFFICIENTS[kind], key) == pytest.approx(value, rel=1e-5, abs=1e-9), key


def test_loss_variants_script_transcribes_the_model(shared_dir: Path, benchmark_script) -> None:
    """benchmarks/machine_loss_variants.py writes the model's seven terms out again (so its variants can
    differ from it): its ``base`` columns equal vpsim.model.machine.loss_w's at every map point, so the
    variants' figures in docs/model.md are measured against the shipped form, not a copy that drifted."""
    var = benchmark_script("machine_loss_variants")
    fit = benchmark_script("machine_fit")
    machines = fit.load_all(shared_dir / "data" / "raw" / "advisor")
    for name, m in machines.items():
        x, _, _, t, w, _ = var.design(m, var.BASE)
        model_basis, _ = fit.design(m)  # the model's loss_w with one coefficient at a time
        assert x == pytest.approx(model_basis, rel=1e-12, abs=1e-15), name
    # and a point checked by hand: at the base speed and rated torque every base term is its coefficient
    # times 1, except the speed terms at nu = w_b / w_max and the field-weakening term (0 at base speed)
    m = machines["MC_PM49"]
    c = var.columns(m, np.array([m.rated_power_w / m.base_speed_radps]), np.array([m.base_speed_radps]))
    nu = m.base_speed_radps / m.max_speed_radps
    assert c["k_sw"][0] == pytest.approx(1.0) and c["k_fw"][0] == pytest.approx(0.0, abs=1e-15)
    assert c["k_fe_h"][0] == pytest.approx(nu) and c["k_mech"][0] == pytest.approx(nu**3)


# ------------------------------------------------------------------------------------ hostile files

_GOOD = """mc_description='test permanent magnet motor';
mc_map_spd=[0 100 200];
mc_map_trq=[-10 0 10];
mc_eff_map=[0.5 0.5 0.5
0.9 0.5 0.9
0.9 0.5 0.9];
mc_max_trq=[10 10 5];
mc_max_gen_trq=-[10 10 5];
mc_inertia=0.01;
"""

HOSTILE = [
    ("truncated", _GOOD[: _GOOD.index("0.9 0.5 0.9\n0.9") + 5], "never closed"),
    ("truncated_before_table", _GOOD[:70], "'mc_map_trq' is not assigned"),
    ("nan_table", _GOOD.replace("0.9 0.5 0.9\n0.9", "NaN 0.5 0.9\n0.9"), "NaN"),
    ("missing_envelope", _GOOD.replace("mc_max_trq=[10 10 5];\n", ""), "'mc_max_trq' is not assigned"),
    ("ragged_table", _GOOD.replace("0.9 0.5 0.9];", "0.9 0.5];"), "vertical concatenation"),
    ("short_table", _GOOD.replace("\n0.9 0.5 0.9];", "];"), "has shape (2, 3), expected (3, 3)"),
    ("short_envelope", _GOOD.replace("mc_max_trq=[10 10 5]", "mc_max_trq=[10 10]"), "2 values, expected 3"),
    ("percent_efficiency", _GOOD.replace("0.9 0.5 0.9\n0.9", "90 0.5 0.9\n0.9"), "expected a fraction"),
    ("zero_efficiency", _GOOD.replace("0.9 0.5 0.9\n0.9", "0 0.5 0.9\n0.9"), "efficiency = 0 at"),
    ("unsorted_speeds", _GOOD.replace("[0 100 200]", "[0 200 100]"), "strictly increasing"),
    ("positive_gen_envelope", _GOOD.replace("-[10 10 5]", "[10 10 5]"), "non-positive"),
    ("no_map", "x = 1;\n", "expected an ADVISOR MC_*.m or GC_*.m file"),
    ("scaled", _GOOD + "mc_trq_scale=2;\n", "mc_trq_scale = 2"),
    ("text_table", _GOOD.replace("mc_map_trq=[-10 0 10]", "mc_map_trq='abc'"), "must be numeric"),
    ("shell", _GOOD + "!rm -rf /\n", "shell escape"),
]


@pytest.mark.parametrize(("text", "what"), [h[1:] for h in HOSTILE], ids=[h[0] for h in HOSTILE])
def test_hostile_files_one_line(tmp_path: Path, text: str, what: str) -> None:
    f = tmp_path / "MC_BAD.m"
    f.write_text(text)
    with pytest.raises(MachineFileError) as info:
        load_machine(f)
    message = str(info.value)
    assert "\n" not in message and str(f) in message and what in message, message
    assert isinstance(info.value, EngineFileError)


def test_good_toy_file_reads(tmp_path: Path) -> None:
    f = tmp_path / "MC_TOY.m"
    f.write_text(_GOOD)
    m = load_machine(f)
    assert m.rated_power_w == 1000.0 and m.base_speed_radps == 100.0
    assert m.loss_w(10.0, 100.0) == pytest.approx(1000 / 0.9 - 1000)
    assert m.loss_w(-10.0, 100.0) == pytest.approx(100.0)
    assert m.loss_w(0.0, 100.0) == pytest.approx(m.loss_w(10.0, 100.0))  # zero torque: next column
    assert m.loss_w(10.0, 0.0) == pytest.approx(m.loss_w(10.0, 100.0))  # zero speed: lowest moving row


# ------------------------------------------------------------------------------------ CLI


def test_cli_import_and_compare(shared_dir: Path, tmp_path: Path, capsys) -> None:
    path = str(_advisor(shared_dir, "MC_PM49"))
    png = tmp_path / "pm49.png"
    assert main(["machine", "import", path, "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert "49.0 kW" in out and "base speed" in out and png.stat().st_size > 10_000
    assert main(["machine", "import", path, "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["name"] == "MC_PM49" and s["max_speed_rpm"] == pytest.approx(8500)
    assert main(["machine", "compare", path, "--json"]) == 0
    c = json.loads(capsys.readouterr().out)
    for key in ("median_abs_efficiency_error_pts", "max_abs_efficiency_error_pts", "n_points"):
        assert key in c
    assert c["rated_power_kw"] == pytest.approx(49.0, abs=0.05)
    assert c["kind"] == "pm" and c["n_points"] == 167
    assert "cycle_energy_error_pct" in c
    if c["cycle_energy_error_pct"] is None:
        assert "not available" in c["cycle_energy_error_pct_undefined"]
    assert main(["machine", "compare", str(_advisor(shared_dir, "MC_AC75"))]) == 0
    assert "scaled induction model" in capsys.readouterr().out


def test_cli_compare_without_the_car(shared_dir: Path, capsys, monkeypatch) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "vpsim.powertrains", None)  # import fails as in a build without it
    assert main(["machine", "compare", str(_advisor(shared_dir, "MC_AC59")), "--json"]) == 0
    c = json.loads(capsys.readouterr().out)
    assert c["cycle_energy_error_pct"] is None
    assert c["cycle_energy_error_pct_undefined"] == "the battery-electric car is not available in this build"


def test_cli_compare_with_a_car(tmp_path: Path, capsys, monkeypatch) -> None:
    import sys
    import types

    fake = types.ModuleType("vpsim.powertrains")
    fake.cycle_battery_energy_j = lambda cycle, machine: 1.1e6 if isinstance(machine, MachineSpec) else 1.0e6
    monkeypatch.setitem(sys.modules, "vpsim.powertrains", fake)
    f = tmp_path / "MC_TOY.m"
    f.write_text(_GOOD)
    assert main(["machine", "compare", str(f), "--json"]) == 0
    c = json.loads(capsys.readouterr().out)
    assert c["cycle_energy_error_pct"] == {"udds": pytest.approx(10.0), "hwfet": pytest.approx(10.0)}


@pytest.mark.parametrize(("text", "what"), [h[1:] for h in HOSTILE], ids=[h[0] for h in HOSTILE])
@pytest.mark.parametrize("command", ["import", "compare"])
def test_cli_hostile_exit_2_one_line(tmp_path: Path, capfd, command: str, text: str, what: str) -> None:
    f = tmp_path / "MC_BAD.m"
    f.write_text(text)
    assert main(["machine", command, str(f)]) == 2
    out, err = capfd.readouterr()
    assert err.count("\n") == 1 and err.startswith("vpsim: error: ") and what in err, err
    assert out == ""


def test_cli_unknown_kind_and_missing_file(tmp_path: Path, capfd) -> None:
    f = tmp_path / "MC_X.m"
    f.write_text(_GOOD.replace("permanent magnet", "mystery"))
    assert main(["machine", "compare", str(f)]) == 2
    assert "--kind" in capfd.readouterr().err
    assert main(["machine", "compare", str(f), "--kind", "pm"]) == 0
    capfd.readouterr()
    assert main(["machine", "import", str(tmp_path / "absent.m")]) == 2
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and "absent.m" in err
