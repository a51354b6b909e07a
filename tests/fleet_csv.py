"""A tiny made-up EPA-style test car list, written by the tests themselves (no row of the real file)."""

from __future__ import annotations

import csv
from pathlib import Path

from vpsim.fleet.epa import COL

EXTRA = ("Model Year", "Vehicle Type", "FE Bag 1")

# made-up gasoline cars: id, make, model, litres, cylinders, hp, code, gears, etw, axle, n/v, A, B, C, mpg
# (bag 2, bag 3, hwy, us06 or None)
CARS = [
    (
        "T001",
        "Acme",
        "Runabout",
        1.5,
        4,
        110,
        "CVT",
        1,
        3000,
        4.0,
        30.0,
        28.0,
        0.20,
        0.018,
        (33, 35, 44, None),
    ),
    ("T002", "Acme", "Family", 2.0, 4, 150, "A", 6, 3500, 3.5, 26.0, 32.0, 0.25, 0.020, (27, 29, 38, 24)),
    ("T003", "Acme", "Wagon", 2.5, 4, 180, "SA", 8, 4000, 3.2, 25.0, 36.0, 0.30, 0.022, (25, 27, 36, None)),
    (
        "T004",
        "Bolt&Nut",
        "Coupe",
        2.0,
        4,
        250,
        "AMS",
        7,
        3625,
        3.6,
        27.0,
        30.0,
        0.20,
        0.019,
        (26, 28, 37, 23),
    ),
    (
        "T005",
        "Bolt&Nut",
        "Truck",
        3.5,
        6,
        300,
        "SA",
        10,
        5000,
        3.3,
        26.0,
        45.0,
        0.40,
        0.030,
        (18, 19, 25, None),
    ),
    ("T006", "Bolt&Nut", "Sport", 3.0, 6, 380, "SA", 8, 4250, 3.0, 24.0, 38.0, 0.30, 0.022, (22, 24, 32, 20)),
    ("T007", "Cogs", "Mini", 1.2, 3, 90, "M", 5, 2750, 4.1, 34.0, 26.0, 0.15, 0.017, (36, 37, 47, None)),
    ("T008", "Cogs", "Saloon", 1.8, 4, 140, "CVT", 1, 3250, 4.2, 28.0, 30.0, 0.20, 0.019, (31, 33, 42, None)),
    ("T009", "Cogs", "Van", 3.6, 6, 280, "A", 9, 5000, 3.5, 27.0, 48.0, 0.45, 0.032, (17, 18, 26, None)),
    ("T010", "Cogs", "Estate", 2.0, 4, 240, "SA", 8, 4000, 3.1, 25.0, 34.0, 0.25, 0.021, (24, 27, 35, None)),
    ("T011", "Dyna", "Hatch", 1.6, 4, 120, "M", 6, 3000, 3.9, 31.0, 27.0, 0.18, 0.018, (32, 34, 43, None)),
    ("T012", "Dyna", "Cruiser", 5.0, 8, 450, "SA", 10, 5500, 3.2, 23.0, 50.0, 0.50, 0.034, (15, 16, 23, 15)),
]


def _row(car, category, procedure, fuel, fe, bag2="", bag3="", test="", model=None, **override):
    vid, make, mdl, disp, cyl, hp, code, gears, etw, axle, nv, a, b, c, _ = car
    r = {
        COL["make"]: make,
        COL["model"]: model or mdl,
        COL["manufacturer"]: make.upper(),
        COL["vehicle_id"]: vid,
        COL["configuration"]: 0,
        COL["displacement_l"]: disp,
        COL["rated_hp"]: hp,
        COL["cylinders"]: cyl,
        COL["transmission_code"]: code,
        COL["n_gears"]: gears,
        COL["lockup"]: "Y",
        COL["drive"]: "F",
        COL["etw_lb"]: etw,
        COL["axle_ratio"]: axle,
        COL["nv_ratio"]: nv,
        COL["test_number"]: test or f"{vid}-{category}",
        COL["procedure"]: procedure,
        COL["fuel"]: fuel,
        COL["category"]: category,
        COL["fe"]: fe,
        COL["bag2"]: bag2,
        COL["bag3"]: bag3,
        COL["target_a_lbf"]: a,
        COL["target_b_lbf_per_mph"]: b,
        COL["target_c_lbf_per_mph2"]: c,
        "Model Year": 2022,
        "Vehicle Type": "Car",
        "FE Bag 1": "",
        COL["bag4"]: "",
    }
    r.update({COL[k]: v for k, v in override.items()})
    return r


def car_rows(car, fuel="Tier 2 Cert Gasoline", scale=1.0, model=None, **override):
    b2, b3, hwy, us06 = car[-1]
    city = 1.0 / (0.43 / b3 + 0.57 / b2)
    rows = [
        _row(
            car,
            "FTP",
            "Federal fuel 2-day exhaust (w/can load)",
            fuel,
            round(city * scale, 1),
            bag2=b2 * scale,
            bag3=b3 * scale,
            model=model,
            **override,
        ),
        _row(car, "HWY", "HWFE", fuel, hwy * scale, model=model, **override),
    ]
    if us06 is not None:
        rows.append(_row(car, "US06", "US06", fuel, us06 * scale, model=model, **override))
    return rows


def write_list(
    path: Path, *, perturb: str | None = None, bad_rows: bool = True, twin: str | None = None
) -> Path:
    """The made-up list; ``perturb``: a vehicle id whose measured mpg are all x 0.6; ``twin``: a vehicle id
    that gets a twin (id + "T", every field equal) whose measured mpg are all x 1.3."""
    rows = []
    for car in CARS:
        rows += car_rows(car, scale=0.6 if car[0] == perturb else 1.0)
        if car[0] == twin:
            rows += car_rows((car[0] + "T",) + car[1:], scale=1.3)
    if bad_rows:
        base = CARS[1]
        rows += car_rows(("X100",) + base[1:], model="Family Hybrid")  # hybrid by name
        rows += car_rows(("X101",) + base[1:], fuel="Federal Cert Diesel 7-15 PPM Sulfur")
        rows += car_rows(("X102",) + base[1:], fuel="Electricity", displacement_l=0.001)
        e85 = "E85 (85% Ethanol 15% EPA Unleaded Gasoline)"
        # a flex-fuel car tested on both fuels (read from its gasoline tests), and one on E85 only (excluded)
        rows += car_rows(("X103",) + base[1:]) + car_rows(("X103",) + base[1:], fuel=e85, scale=0.75)
        rows += car_rows(("X114",) + base[1:], fuel=e85)
        rows += car_rows(("X104",) + base[1:], etw_lb=150)  # implausible mass (lb)
        rows += car_rows(("X105",) + base[1:], target_a_lbf="")  # missing road load A
        hy = list(base)
        hy[-1] = (50, 52, 45, None)  # city better than highway: a hybrid by the rule
        rows += car_rows(tuple(["X106"] + hy[1:]), model="Saver")
        hot = list(base)
        hot[-1] = (40, 38, 44, None)  # hot town (bag 2) mpg 0.91 x highway: a hybrid by the rule
        rows += car_rows(tuple(["X110"] + hot[1:]))
        rows += car_rows(("X111",) + base[1:], model="Cruiser HEV")  # hybrid by name
        eff = list(base)
        eff[-1] = (30, 32, 120, None)  # 120 mpg on the highway: more wheel work than an engine can give
        rows += car_rows(tuple(["X112"] + eff[1:]))
        plug = car_rows(("X109",) + base[1:], model="Plugger")
        plug.append(dict(plug[0], **{COL["category"]: "CD", COL["test_number"]: "X109-CD", COL["fe"]: ""}))
        rows += plug
        rows += car_rows(("X108",) + base[1:], model="Plugger")  # gasoline tests only; its model is a plug-in
        mild = car_rows(("X113",) + base[1:])
        mild[0][COL["bag4"]] = 28.5  # a 4-bag FTP: a 48 V mild hybrid
        rows += mild
        bag = car_rows(("X107",) + base[1:])
        bag[0][COL["bag2"]] = 999  # an implausible bag value: that bag is excluded, the car stays
        rows += bag
    with path.open("w", newline="", encoding="utf-8-sig") as fh:
        w = csv.DictWriter(fh, fieldnames=list(EXTRA) + list(COL.values()))
        w.writeheader()
        w.writerows(rows)
    return path


# made-up battery-electric cars: id, make, model, hp, etw, axle, n/v, A, B, C, (UDDS, HWY MPGe) (or kWh/100 mi
# below 60, as some manufacturers list them)
EVS = [
    ("E001", "Volt&Amp", "Zip", 200, 3875, 7.05, 96.0, 30.0, 0.10, 0.017, (170.0, 140.0)),
    ("E002", "Volt&Amp", "Zip Long", 300, 4500, 9.0, 115.0, 32.0, 0.20, 0.018, (150.0, 130.0)),
    ("E003", "Ohm", "Glide", 400, 5000, 1.0, 110.0, 35.0, 0.25, 0.019, (22.0, 26.0)),  # kWh/100 mi
    ("E004", "Ohm", "Hauler", 600, 6500, 9.5, 105.0, 45.0, 0.40, 0.030, (110.0, 100.0)),
    ("E005", "Watt", "City", 150, 3500, 8.2, 112.0, 28.0, 0.15, 0.016, (180.0, 145.0)),
    ("E006", "Watt", "Tourer", 450, 5250, 4.7, 127.0, 38.0, 0.22, 0.021, (135.0, 120.0)),
    ("E007", "Farad", "Coupe", 500, 4750, 9.04, 108.0, 30.0, 0.18, 0.017, (160.0, 150.0)),
]


def ev_rows(ev, **override) -> list[dict]:
    """The two charge-depleting tests of a made-up EV (``override``: fields of vpsim.fleet.epa.COL)."""
    vid, make, model, hp, etw, axle, nv, a, b, c, (udds, hwy) = ev
    car = (vid, make, model, 0.001, "", hp, "A", 1, etw, axle, nv, a, b, c, None)
    return [
        _row(car, "CD", "Charge Depleting UDDS", "Electricity", udds, test=f"{vid}-UDDS", **override),
        _row(car, "CD", "Charge Depleting Highway", "Electricity", hwy, test=f"{vid}-HWY", **override),
    ]


def write_ev_list(path: Path, evs=EVS, **override) -> Path:
    """The made-up conventional list without its bad rows, and the made-up EVs."""
    write_list(path, bad_rows=False)
    with path.open(newline="", encoding="utf-8-sig") as f:
        header = next(csv.reader(f))
    with path.open("a", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=header)
        for ev in evs:
            w.writerows(ev_rows(ev, **override))
    return path
