"""Mild-hybrid records (vpsim.fleet.mhev): the maker's system, bags 2 and 3 read from the 4-bag FTP, the
vehicle mapping, the vehicle file, and the fleet's mild-hybrid summary keys."""

from __future__ import annotations

import math

import pytest

from vpsim.fleet import mhev
from vpsim.fleet.epa import read_test_car_list


def _real_list(shared_dir):
    lst = shared_dir / "data" / "epa" / "22-tstcar.csv"
    if not lst.exists():
        pytest.skip(f"{lst} not found")
    return lst


def test_system_rules():
    assert mhev.system_of("Mercedes-Benz", "E 450 4MATIC", 2.999)[0] == "mercedes"
    assert mhev.system_of("BMW", "M340i", 3.0)[0] == "bmw"
    assert mhev.system_of("AUDI", "S8", 3.996)[0] == "audi48"
    assert mhev.system_of("Audi", "A3 quattro", 1.984)[0] == "audi_a3"
    assert mhev.system_of("Audi", "Q5", 1.984)[0] == "audi12"
    assert mhev.system_of("Volvo", "XC60 B5 AWD", 1.969)[0] == "volvo"
    assert mhev.system_of("RAM", "1500 4X4", 5.7)[0] == "etorque"
    assert mhev.system_of("Range Rover", "Velar MHEV", 3.0)[0] == "jlr"
    key, why = mhev.system_of("Dodge", "Charger", 3.6)
    assert key is None and why.startswith("mild hybrid, no known system: Dodge Charger")
    assert mhev.SYSTEMS["mercedes"].layout == "mhev_p1"
    assert {s.layout for k, s in mhev.SYSTEMS.items() if k != "mercedes"} == {"mhev_p0"}
    # the assist each maker publishes: none for Audi's 6- and 8-cylinder 48 V system, 9 of the A3's 12 kW,
    # 1 of the 12 V system's 5 kW, the machine's whole envelope for the others
    share = {k: s.assist_share for k, s in mhev.SYSTEMS.items()}
    assert share == {
        "mercedes": 1.0, "bmw": 1.0, "audi48": 0.0, "audi_a3": 0.75, "audi12": 0.2, "volvo": 1.0,
        "etorque": 1.0, "jlr": 1.0,
    }  # fmt: skip


def _ftp(b1, b2, b3, b4, fe):
    return {"bag1": b1, "bag2": b2, "bag3": b3, "bag4": b4, "fe": fe}


def test_bags_by_hand():
    # the BMW 540i's 4-bag FTP (GM46485): 30.0, 31.2, 34.5, 31.6 mpg, RND_ADJ_FE 31.8. Cold UDDS
    # 7.50 / (3.59 / 30.0 + 3.91 / 31.2) = 30.61, hot 7.50 / (3.59 / 34.5 + 3.91 / 31.6) = 32.92;
    # 1 / (0.43 / 30.61 + 0.57 / 32.92) = 31.88 mpg, within 3 % of 31.8: bags 2 and 3 are read
    got, how = mhev._bags(_ftp(30.0, 31.2, 34.5, 31.6, 31.8))
    assert got == {"ftp_bag2": 31.2, "ftp_bag3": 34.5} and how.startswith("4-bag")
    assert "not within 3 %" in mhev._bags(_ftp(30.0, 31.2, 34.5, 31.6, 35.0))
    # a 3-bag FTP is a conventional car's: bags 2 and 3
    got, how = mhev._bags(_ftp(30.0, 31.2, 34.5, math.nan, 31.8))
    assert got == {"ftp_bag2": 31.2, "ftp_bag3": 34.5} and how.startswith("3-bag")
    assert "missing or implausible" in mhev._bags(_ftp(30.0, math.nan, 34.5, 31.6, 31.8))


def test_real_mild_hybrids_are_read(shared_dir):
    cars = read_test_car_list(_real_list(shared_dir))
    recs = {v.key: v for v in cars.mhev_vehicles}
    assert len(recs) >= 85
    # the other powertrains are read as before (the engine cars since 2026-12-07 with the 12 flex-fuel cars
    # tested on gasoline too: 976 before; the 2 with E85 tests only stay out; since 2026-12-07 also the 3
    # whose empty cylinder count the list's other tests give: 988 before)
    assert len(cars.vehicles) == 991 and len(cars.hev_vehicles) == 71
    assert cars.excluded["flex-fuel (E85 test)"] == 2
    assert not any("cylinders" in reason for reason in cars.excluded)
    assert sum(v.layout == "mhev_p1" for v in recs.values()) >= 15
    # only what cannot be modelled stays out, each with its reason (the Audi RS7, its cylinder count empty,
    # is read since 2026-12-07 with the 8 of the list's other 4.0 L Audis)
    left = [r for r in cars.excluded_rows if r["test_number"] == "" and r["reason"].startswith("mild")]
    assert {r["model"] for r in left} == {"Charger", "Charger AWD"}
    assert all("no known system" in r["reason"] for r in left)
    rs7 = recs["LNAU-RS7#0"]
    assert rs7.cylinders == 8 and rs7.cylinders_source.endswith("other test vehicles of AUDI with 4.00 L")
    epace = recs["4GMTT255#0"]
    assert epace.system == "jlr" and epace.measured_mpg["ftp_bag2"] == pytest.approx(26.4, abs=0.05)
    p = mhev.mhev_parameters(epace, "ftp_bag2")
    assert p.powertrain.type == "mhev" and p.machine.rated_power == pytest.approx(12e3)
    assert p.mild.belt_ratio == pytest.approx(2.7) and p.battery.cells_in_series == 13
    assert p.engine.rated_power == pytest.approx(epace.rated_power_kw * 1e3)
    assert p.vehicle.mass == pytest.approx(epace.mass_kg) and len(p.transmission.gearbox_ratios) == 9
    e450 = mhev.mhev_parameters(recs["W213E30DETC-Z2165#2"], "hwy")
    assert e450.mild.belt_ratio == 1.0 and e450.mild.belt_efficiency == 1.0
    assert e450.machine.rated_power == pytest.approx(16e3)
    q5 = mhev.mhev_parameters(recs["NA7E-Q5-278#1"], "hwy")
    assert q5.battery.cells_in_series == 4 and q5.machine.rated_power == pytest.approx(5e3)
    assert q5.mild.assist_share == 0.2


def test_from_epa_writes_a_mild_hybrid_that_simulates_against_its_record(shared_dir, tmp_path, capsys):
    import json

    from vpsim.cli.main import main
    from vpsim.params import load_parameters
    from vpsim.units import mpg_from_l_per_100km

    lst = _real_list(shared_dir)
    car = tmp_path / "epace.toml"
    assert (
        main(["vehicle", "from-epa", str(lst), "--id", "4GMTT255", "--config", "0", "--out", str(car)]) == 0
    )
    p = load_parameters(car)
    rec = read_test_car_list(lst).find("4GMTT255", 0)
    want = mhev.mhev_parameters(rec).flat()
    got = p.flat()
    for sec, fields_ in mhev.TOML_FIELDS:
        for f in fields_:
            k = f"{sec}.{f}"
            if k in want and want[k] is not None:
                w = want[k]
                exact = isinstance(w, str | int) and not isinstance(w, float)
                assert got[k] == (w if exact else pytest.approx(w, rel=1e-5)), k
    capsys.readouterr()
    assert main(["simulate", "--vehicle", str(car), "--cycle", "ftp_bag3", "--ems", "ecms", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["measured_mpg"] == pytest.approx(rec.measured_mpg["ftp_bag3"], rel=1e-6)
    cs = mpg_from_l_per_100km(s["fuel_l_per_100km_cs"])
    assert s["measured_error_pct"] == pytest.approx(100 * (cs / s["measured_mpg"] - 1), rel=1e-9)


def test_from_epa_takes_the_fleets_mild_hybrid_fit(shared_dir, tmp_path, capsys):
    import json

    from vpsim.cli.main import main
    from vpsim.params import load_parameters

    lst = _real_list(shared_dir)
    tech = tmp_path / "technology.json"
    fit = {"engine.thermal_efficiency": 0.4125, "electric.accessory_power": 1150.0}
    tech.write_text(json.dumps({"mhev": {"all_vehicles": {"mhev_p0": fit}}}))
    car = tmp_path / "c.toml"
    args = ["vehicle", "from-epa", str(lst), "--id", "4GMTT255", "--config", "0", "--out", str(car)]
    assert main([*args, "--technology", str(tech)]) == 0
    p = load_parameters(car)
    assert p.engine.thermal_efficiency == pytest.approx(0.4125)
    assert p.electric.accessory_power == pytest.approx(1150.0)
    tech.write_text(json.dumps({"mhev": {"all_vehicles": {"mhev_p1": fit}}}))
    capsys.readouterr()
    assert main([*args, "--technology", str(tech)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "mhev.all_vehicles has no fit for this car's class mhev_p0" in err


def test_the_three_parameter_fit_recovers_a_known_technology():
    """The mild hybrids' fit (efficiency, accessories, friction) on a grid made from a known law recovers the
    law's parameters: fuel per row = (a + b xi) / eta + c P (the indicated work and the friction's over the
    efficiency, the accessories' fuel linear in their power), rows of different a, b, c (the cycles'
    weights); the law is linear in xi between the friction nodes, as the fit interpolates it, and the true
    values sit on the fine axes."""
    import numpy as np

    rng = np.random.default_rng(3)
    n = 40
    a, b, c = rng.uniform(4.0, 8.0, n), rng.uniform(0.5, 2.0, n), rng.uniform(2e-4, 8e-4, n)

    def law(eta, xi, acc):
        return (a + b * xi) / eta + c * acc

    eta_k, acc_k = mhev.EFFICIENCY_AXIS, mhev.ACCESSORY_NODES_W
    grid = np.empty((n, eta_k.size, mhev.FRICTION_AXIS.size, len(acc_k)))
    for i, e in enumerate(eta_k):
        for f, xi in enumerate(mhev.FRICTION_AXIS):
            for j, p in enumerate(acc_k):
                grid[:, i, f, j] = np.log(law(e, xi, p))
    truth = {
        "engine.thermal_efficiency": 0.46,
        "engine.friction_coefficient": 0.8,
        "electric.accessory_power": 1200.0,
    }
    measured = np.log(
        law(
            *(
                truth[k]
                for k in (
                    "engine.thermal_efficiency",
                    "engine.friction_coefficient",
                    "electric.accessory_power",
                )
            )
        )
    )
    params, loss = mhev.fit(grid, measured)
    assert set(params) == set(mhev.TECH_PARAMS)
    assert params["engine.thermal_efficiency"] == pytest.approx(0.46, abs=1e-9)
    assert params["engine.friction_coefficient"] == pytest.approx(0.8, abs=1e-9)
    assert params["electric.accessory_power"] == pytest.approx(1200.0, abs=1e-6)
    assert loss < 1e-9
    assert mhev.on_bounds(params) == {}
    assert mhev.on_bounds({**params, "engine.friction_coefficient": 0.1}) == {
        "engine.friction_coefficient": "low"
    }
