"""Full-hybrid records (vpsim.fleet.hev): layout, the hot UDDS read from the 4-bag FTP, the vehicle mapping,
the vehicle file and the fleet's hybrid summary keys."""

from __future__ import annotations

import math

import pytest

from vpsim.errors import VpsimError
from vpsim.fleet import hev
from vpsim.fleet.epa import read_test_car_list
from vpsim.params import load_parameters


def _real_list(shared_dir):
    lst = shared_dir / "data" / "epa" / "22-tstcar.csv"
    if not lst.exists():
        pytest.skip(f"{lst} not found")
    return lst


def test_layout_rules():
    assert hev.layout("TOYOTA", "COROLLA HYBRID", "CVT")[0] == "hev_split"
    assert hev.layout("TOYOTA", "RAV4 HYBRID AWD", "SCV")[0] == "hev_split"
    assert hev.layout("Ford", "Escape FHEV", "CVT")[0] == "hev_split"
    assert hev.layout("HYUNDAI", "IONIQ", "AMS")[0] == "hev_p2"
    assert hev.layout("Ford", "F150 HYBRID", "SA")[0] == "hev_p2"
    assert hev.layout("TOYOTA", "TUNDRA 2WD", "A")[0] == "hev_p2"
    lay, why = hev.layout("HONDA", "ACCORD HYBRID", "CVT")
    assert lay is None and why.startswith("hybrid, no built layout: HONDA ACCORD HYBRID, two-motor")
    lay, why = hev.layout("TOYOTA", "PRIUS PRIME", "CVT")
    assert lay is None and why.startswith("hybrid, plug-in: ")
    assert hev.layout("LEXUS", "NX 450h+ AWD", "CVT")[0] is None
    assert "Multi Stage" in hev.layout("LEXUS", "LC 500h", "SA")[1]


def _ftp(b1, b2, b3, b4, fe):
    return {"bag1": b1, "bag2": b2, "bag3": b3, "bag4": b4, "fe": fe}


def test_hot_udds_by_hand():
    # the Corolla Hybrid's 4-bag FTP (20-ZE1H): bags 53.30, 120.93, 60.94, 117.08 mpg, RND_ADJ_FE 78.1;
    # hot UDDS = 7.50 mi / (3.59 / 60.94 + 3.91 / 117.08) = 81.25 mpg; cold 75.2; 0.43/0.57 composite 78.5
    hot, how = hev.hot_udds(_ftp(53.3041115, 120.9279022, 60.9440804, 117.0789642, 78.1))
    assert hot == pytest.approx(7.50 / (3.59 / 60.9440804 + 3.91 / 117.0789642), rel=1e-12)
    assert hot == pytest.approx(81.25, abs=0.01) and how.startswith("4-bag")
    # Ford's two-figure form (LUA00075): bag 1 the cold UDDS 59.94, bag 2 the hot 63.93; composite 62.1
    hot, how = hev.hot_udds(_ftp(59.9385059, 63.9279505, math.nan, math.nan, 61.4))
    assert hot == pytest.approx(63.9279505) and how.startswith("two-figure")
    # bags that do not give the test's composite are not read as the hot UDDS
    assert "not within 3 %" in hev.hot_udds(_ftp(53.3, 120.9, 60.9, 117.1, 90.0))
    assert "neither" in hev.hot_udds(_ftp(53.3, 120.9, 60.9, math.nan, 78.1))


def test_real_hybrids_are_read(shared_dir):
    cars = read_test_car_list(_real_list(shared_dir))
    recs = {v.key: v for v in cars.hev_vehicles}
    assert len(recs) >= 70
    by_layout = {lay: sum(v.layout == lay for v in recs.values()) for lay in hev.CLASSES}
    assert by_layout["hev_split"] >= 35 and by_layout["hev_p2"] >= 25
    corolla = recs["20-ZE1H#0"]
    assert corolla.layout == "hev_split"
    assert corolla.measured_mpg["udds_hot"] == pytest.approx(81.25, abs=0.01)
    assert corolla.measured_mpg["hwy"] == pytest.approx(76.2)
    assert recs["AE-U0G6GD048F#0"].layout == "hev_p2"
    honda = [r for r in cars.excluded_rows if r["make"] == "HONDA" and r["test_number"] == ""]
    assert honda and all(r["reason"].startswith("hybrid, no built layout") for r in honda)
    # the preset's own record maps back to the preset's sizes
    p = hev.hev_parameters(corolla)
    assert p.powertrain.type == "hev_split"
    assert p.machine.rated_power == pytest.approx(53e3, rel=0.01)  # 96 hp is the preset's 71.6 kW
    assert p.transmission.final_drive == pytest.approx(2.83)
    ioniq = hev.hev_parameters(recs["AE-U0G6GD048F#0"])
    assert ioniq.machine.rated_power == pytest.approx(32e3)  # the preset's test weight: its 32 kW
    assert ioniq.transmission.gearbox_ratios.__len__() == 6
    # the pack: a split's is the preset's 1.31 kWh whatever its MG2 (a Camry's is 88-97 kW; sized to it the
    # pack was 6.6 kWh where Toyota's are 1.0-1.6), a P2's the preset's one string too (1.54 kWh; the
    # makers' P2 packs are 1.5-1.9 kWh), not the two its machine's power at the cell's 20 C would take
    camry = hev.hev_parameters(recs["18-AV2H#0"])
    assert camry.machine.rated_power > 85e3 and camry.battery.cells_in_parallel == 1
    assert ioniq.battery.cells_in_parallel == 1 < hev.pack_strings(load_parameters("hev_p2"), 32e3)
    assert camry.machine.loss_scale == ioniq.machine.loss_scale == hev.MACHINE_LOSS_SCALE
    # a change goes into any section of the parameters, one the record does not fill too; a key that names
    # no section is one line, not a silently ignored change
    changed = hev.hev_parameters(recs["AE-U0G6GD048F#0"], {"hybrid.ecms_min_on_time": 5.0})
    assert changed.hybrid.ecms_min_on_time == 5.0 and ioniq.hybrid.ecms_min_on_time == 0.0
    for bad in ("hybridx.ecms_min_on_time", "hybrid"):
        with pytest.raises(VpsimError, match="is not section.field"):
            hev.hev_parameters(corolla, {bad: 5.0})


def test_from_epa_writes_a_hybrid_that_simulates_against_its_record(shared_dir, tmp_path, capsys):
    from vpsim.cli.main import main
    from vpsim.params import load_parameters

    lst = _real_list(shared_dir)
    # a split, a Hyundai P2, a Ford P2 with its torque converter (the converter's fields written too)
    for vid, layout_ in (("20-ZE1H", "hev_split"), ("TM-U1G6HA025A", "hev_p2"), ("LGA00706", "hev_p2")):
        car = tmp_path / f"{vid}.toml"
        assert main(["vehicle", "from-epa", str(lst), "--id", vid, "--config", "0", "--out", str(car)]) == 0
        p = load_parameters(car)
        assert p.powertrain.type == layout_
        rec = read_test_car_list(lst).find(vid, 0)
        want = hev.hev_parameters(rec).flat()
        got = p.flat()
        for sec, fields_ in hev.TOML_FIELDS:
            if sec == "transmission":
                fields_ = (*fields_, "converter_capacity_factor", "lockup_min_gear", "lockup_min_speed")
            for f in fields_:
                k = f"{sec}.{f}"
                if k in want and want[k] is not None and not (sec == "split" and layout_ != "hev_split"):
                    w = want[k]  # (the file holds 6 significant digits)
                    exact = isinstance(w, str | int) and not isinstance(w, float)
                    assert got[k] == (w if exact else pytest.approx(w, rel=1e-5)), k
        assert (got["transmission.converter_capacity_factor"] > 0) == (vid == "LGA00706")
        capsys.readouterr()
        assert main(["simulate", "--vehicle", str(car), "--cycle", "udds", "--json"]) == 0
        import json

        s = json.loads(capsys.readouterr().out)
        assert s["measured_mpg"] == pytest.approx(rec.measured_mpg["udds_hot"], rel=1e-5)  # 6 digits
        from vpsim.units import mpg_from_l_per_100km

        cs = mpg_from_l_per_100km(s["fuel_l_per_100km_cs"])
        assert s["measured_error_pct"] == pytest.approx(100 * (cs / s["measured_mpg"] - 1), rel=1e-9)


def test_fit_recovers_a_known_technology():
    """Synthetic fuel: F = W (0.44 / eta) + m L + a P_acc, measured at eta 0.47, loss level L 0.63, 600 W:
    the fit finds them on its fine axes (ln F is linear in neither eta nor L: within the interpolation's
    error)."""
    import numpy as np

    rng = np.random.default_rng(3)
    n = 40
    w = rng.uniform(3.0, 9.0, n)
    m = rng.uniform(0.5, 2.0, n)  # the loss level's weight differs from car to car, or it would not be found
    a = rng.uniform(2e-4, 6e-4, n)

    def fuel(eta, scale, acc):
        return w * 0.44 / eta + m * scale + a * acc

    grid = np.stack(
        [
            [
                [[math.log(fuel(e, x, acc)[k]) for acc in hev.ACCESSORY_NODES_W] for x in hev.LOSS_SCALE_AXIS]
                for e in hev.EFFICIENCY_AXIS
            ]
            for k in range(n)
        ]
    )
    assert grid.shape == (n, hev.EFFICIENCY_AXIS.size, hev.LOSS_SCALE_AXIS.size, 2)
    params, loss = hev.fit(grid, np.log(fuel(0.47, 0.63, 600.0)))
    assert params["engine.thermal_efficiency"] == pytest.approx(0.47, abs=0.005)
    assert params["machine.loss_scale"] == pytest.approx(0.63, abs=0.03)
    assert params["electric.accessory_power"] == pytest.approx(600.0, abs=50.0)
    assert loss < 0.005
    assert hev.on_bounds(
        {"engine.thermal_efficiency": 0.54, "electric.accessory_power": 0.0, "machine.loss_scale": 1.5}
    ) == {
        "engine.thermal_efficiency": "high",
        "electric.accessory_power": "low",
        "machine.loss_scale": "high",
    }
    with pytest.raises(ValueError, match="no hybrid"):
        hev.fit(grid[:0], np.log(fuel(0.47, 0.63, 600.0))[:0])


def test_from_epa_takes_the_fleets_hybrid_fit(shared_dir, tmp_path, capsys):
    import json

    from vpsim.cli.main import main
    from vpsim.params import load_parameters

    lst = _real_list(shared_dir)
    tech = tmp_path / "technology.json"
    fit = {"engine.thermal_efficiency": 0.5175, "electric.accessory_power": 375.0, "machine.loss_scale": 0.42}
    tech.write_text(json.dumps({"hev": {"all_vehicles": {"hev_split": fit}}}))
    car = tmp_path / "c.toml"
    args = ["vehicle", "from-epa", str(lst), "--id", "20-ZE1H", "--config", "0", "--out", str(car)]
    assert main([*args, "--technology", str(tech)]) == 0
    p = load_parameters(car)
    assert p.engine.thermal_efficiency == pytest.approx(0.5175)
    assert p.electric.accessory_power == pytest.approx(375.0)
    assert p.machine.loss_scale == pytest.approx(0.42)
    assert "fleet fit" in car.read_text().split("loss_scale", 1)[1].splitlines()[0]
    # a technology.json without a hybrid fit: one line naming what is missing
    tech.write_text(json.dumps({"bev": {}}))
    capsys.readouterr()
    assert main([*args, "--technology", str(tech)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "hev.all_vehicles.hev_split" in err
