"""The result type: summary, DataFrame, plot, JSON."""

from __future__ import annotations

import json

import matplotlib.pyplot as plt
import numpy as np

import vpsim


def r_params():
    return vpsim.load_parameters("hofman2011")


def test_result_views():
    r = vpsim.simulate("udds", method="backward")
    df = r.to_dataframe()
    assert len(df) == r.steps + 1  # one row per cycle sample (steps: the intervals)
    for col in (
        "time_s",
        "speed_mps",
        "accel_mps2",
        "gear",
        "engine_speed_radps",
        "crank_torque_nm",
        "intake_pressure_pa",
        "fuel_flow_kgps",
        "fuel_flow_used_kgps",
    ):
        assert col in df.columns
    # fuel in the summary is the integral of the per-interval flows; the samples carry their means
    from vpsim.methods import backward

    op = backward.intervals(vpsim.load_cycle("udds"), r_params(), mode="realistic")
    used = np.maximum(op["fuel_flow_kgps"], r_params().simulation.idle_fuel_flow)
    assert np.isclose((used * op["dt_s"]).sum(), r.fuel_kg, rtol=1e-12)
    # (the flows at the samples are means of the two adjacent intervals: their trapezoid is close, not equal)
    assert np.isclose(np.trapezoid(df["fuel_flow_used_kgps"], df["time_s"]), r.fuel_kg, rtol=5e-3)
    d = json.loads(r.to_json())
    assert d["fuel_kg"] == r.fuel_kg and d["cycle"] == "udds"
    assert "L/100 km" in repr(r)
    assert "residual" in str(r.energy)
    fig = r.plot(t_range=(0, 300))
    assert len(fig.axes) >= 5
    plt.close(fig)
    assert r.engine_speed_radps is r.series["engine_speed_radps"]  # series are attributes too


def test_deviations_are_named_alike_in_print_json_and_dataframe():
    """Speed not followed and demand not deliverable (per cause), and states outside physics: the same names
    in the summary (JSON), the DataFrame's flag columns and the printed result; a negative pressure is not
    shown as a plain number."""
    r = vpsim.simulate("nedc", method="backward", mode="paper")
    d = r.summary()
    for key in (
        "speed_not_followed_s",
        "demand_not_deliverable_s",
        "torque_beyond_full_load_s",
        "throttle_below_minimum_s",
        "engine_speed_out_of_range_s",
        "negative_intake_pressure_s",
        "negative_fuel_flow_s",
        "outside_physics_s",
    ):
        assert key in d
    assert d["negative_intake_pressure_s"] > 0  # the paper's model without brakes, at closed throttle
    df = r.to_dataframe()
    assert df["negative_intake_pressure"].sum() > 0
    assert df.loc[df["negative_intake_pressure"], "intake_pressure_pa"].isna().all()
    assert (r.to_dataframe(raw=True)["intake_pressure_pa"] < 0).any()
    assert "outside physics" in repr(r)


def test_realistic_defaults_show_no_state_outside_physics():
    """The default car on NEDC and FTP-75: no state outside physics for any method; US06 asks more than
    full load of the backward method, reported as demand not deliverable."""
    for cycle in ("nedc", "ftp75"):
        for method in ("backward", "forward", "inverse"):
            dev = vpsim.simulate(cycle, method=method).deviations
            assert dev.outside_physics_s == 0.0, (cycle, method, dev)
    us06 = vpsim.simulate("us06").deviations
    assert us06.torque_beyond_full_load_s == 3.0 and us06.demand_not_deliverable_s == 3.0


def test_all_first_gear_is_reported_as_engine_over_speed(tmp_path):
    """A gear schedule that over-revs the engine is not 'trace miss none': seconds and size are reported."""
    c = vpsim.load_cycle("nedc")
    (tmp_path / "g.csv").write_text("time_s,gear\n0,1\n")
    r = vpsim.simulate(c, gears=str(tmp_path / "g.csv"))
    dev = r.deviations
    assert dev.engine_speed_out_of_range_s > 100 and dev.max_engine_speed_radps > 1000
    assert dev.demand_not_deliverable_s >= dev.engine_speed_out_of_range_s


def test_a_run_that_became_non_finite_is_refused_not_shown_as_zero(tmp_path, capsys):
    """A final-drive ratio of 5e-324 passes the range check (> 0) but makes every torque infinite; the run
    must end in one line naming what became non-finite, not 0 L/100 km (as a denormal MG1 base speed once
    gave a power split)."""
    import pytest

    from vpsim.cli.main import main
    from vpsim.errors import NonFiniteRunError

    for base in ("hofman2011", "bev"):
        car = tmp_path / f"{base}.toml"
        car.write_text(f'base = "{base}"\n[transmission]\nfinal_drive = 5e-324\n')
        # (np.errstate: the overflow's own warning, printed by the CLI, is an error under pytest)
        with pytest.raises(NonFiniteRunError, match="non-finite: energy term"), np.errstate(all="ignore"):
            vpsim.simulate("udds", "backward", car)
        with np.errstate(all="ignore"):
            assert main(["simulate", "--vehicle", str(car), "--cycle", "udds", "--json"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "non-finite" in err and "Traceback" not in err


def test_machine_ratings_a_model_cannot_divide_by_are_refused(tmp_path, capsys):
    from vpsim.cli.main import main

    for base, sec, name in (
        ("hev_split", "split", "generator_base_speed"),
        ("hev_split", "split", "generator_rated_power"),
        ("bev", "machine", "base_speed"),
        ("bev", "machine", "rated_power"),
    ):
        car = tmp_path / "car.toml"
        car.write_text(f'base = "{base}"\n[{sec}]\n{name} = 2.225073858507e-311\n')
        assert main(["simulate", "--vehicle", str(car), "--cycle", "udds", "--json"]) == 2
        err = capsys.readouterr().err
        assert f"{sec}.{name} = 2.22507e-311 is outside the plausible range" in err


def test_energy_terms_are_energy_balance_fields_in_order():
    """The kernels return the energy terms in rules.ENERGY_TERMS order and the backward method builds its
    EnergyBalance from them by position: the two orders must be one."""
    import dataclasses

    from vpsim.model.rules import ENERGY_TERMS
    from vpsim.result import EnergyBalance

    assert tuple(f.name for f in dataclasses.fields(EnergyBalance)) == ENERGY_TERMS


def test_one_update_init_keeps_the_dataclass_contract():
    """Result, EnergyBalance and TraceMiss fill their __dict__ in one update (result._one_update_init): the
    same parameters and defaults as the fields, a fresh object from each default factory, frozen after, and
    __post_init__ still run (a non-finite total refused)."""
    import dataclasses
    import inspect

    import pytest

    from vpsim.errors import NonFiniteRunError
    from vpsim.result import EnergyBalance, Result, TraceMiss

    for cls in (Result, EnergyBalance, TraceMiss):
        params = list(inspect.signature(cls).parameters.values())
        fields = dataclasses.fields(cls)
        assert [p.name for p in params] == [f.name for f in fields]
        for p, f in zip(params, fields, strict=True):
            if f.default is not dataclasses.MISSING:
                assert p.default is f.default
            elif f.default_factory is dataclasses.MISSING:
                assert p.default is inspect.Parameter.empty
    a, b = TraceMiss(), TraceMiss(seconds=1.0)
    assert a.details == {} and a.details is not b.details and b.seconds == 1.0
    assert a == TraceMiss(0.0, 0.0, 0.0, 0.0, {})
    e = EnergyBalance(*range(12))
    assert vars(e) == {f.name: float(i) for i, f in enumerate(dataclasses.fields(EnergyBalance))}
    with pytest.raises(dataclasses.FrozenInstanceError):
        e.indicated = 1.0
    kw = dict(method="backward", cycle="c", driver=None, mode="paper", series={}, distance_m=1.0)
    kw.update(fuel_density_kg_per_l=0.745, cpu_time_s=0.0, steps=1)
    r1, r2 = Result(fuel_kg=0.1, **kw), Result(fuel_kg=0.1, **kw)
    assert r1.solver == {} and r1.solver is not r2.solver and r1.limits is not r2.limits
    assert r1.trace_miss == TraceMiss() and r1.energy is None and r1.notes == ()
    assert dataclasses.replace(r1, steps=5).steps == 5
    with pytest.raises(NonFiniteRunError):
        Result(fuel_kg=float("nan"), **kw)
