"""``vpsim vehicle from-epa``: a vehicle parameter file from a certification record."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import VpsimError
from .main import cli


@cli.group()
def vehicle():
    """Vehicles from other sources (certification records)."""


@vehicle.command("from-epa")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--id", "vehicle_id", required=True, help="Test Vehicle ID of the record.")
@click.option("--config", "config", type=int, default=None, help="Test Veh Configuration # (when several).")
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(dir_okay=False),
    help="TOML file to write (vpsim simulate --vehicle reads it).",
)
@click.option(
    "--technology",
    "technology",
    default=None,
    type=click.Path(dir_okay=False),
    help="technology.json of a `vpsim fleet` run: use its all-vehicle fit for this car's technology class.",
)
def from_epa(file, vehicle_id, config, out, technology):
    """Write the parameters of test vehicle --id of the EPA test car list FILE as an editable TOML."""
    from ..fleet.calibrate import vehicle_class
    from ..fleet.epa import read_test_car_list
    from ..fleet.vehicle import record_parameters, vehicle_toml
    from ..textio import printable

    _not_an_input(out, file, technology)
    cars = read_test_car_list(file)
    rec = cars.find(vehicle_id, config)
    if getattr(rec, "powertrain", "conventional") == "bev":
        _from_epa_bev(rec, file, out, technology)
        return
    if getattr(rec, "powertrain", "conventional") == "hev":
        _from_epa_hev(rec, file, out, technology)
        return
    if getattr(rec, "powertrain", "conventional") == "mhev":
        _from_epa_mhev(rec, file, out, technology)
        return
    tech, note = _fit(technology, "conventional", vehicle_class(rec))
    params = record_parameters(rec, technology=tech)
    text = vehicle_toml(rec, params, source=Path(file).name, technology_note=note)
    Path(out).write_text(text)
    meas = ", ".join(f"{c} {v:.1f} mpg" for c, v in rec.measured_mpg.items())
    tr = params.transmission
    box = (
        f"CVT {tr.gearbox_ratios[0]:.3g}-{tr.gearbox_ratios[1]:.3g} ({tr.n_gears} ratios, steps of "
        f"{tr.cvt_ratio_step:.0%})"
        if tr.is_cvt
        else f"{rec.transmission_kind} {tr.n_gears} ratios"
    )
    engine = f"{rec.displacement_l:g} L {rec.cylinders} cyl. {'boosted' if rec.boosted else 'NA'}"
    click.echo(
        printable(
            f"wrote {out}: {rec.make} {rec.model} ({rec.key}), {rec.mass_kg:.0f} kg, {engine}, {box}; "
            f"measured {meas or 'nothing usable'}"
        )
    )


def _fit(technology, powertrain: str, cls: str) -> tuple[dict | None, str]:
    """(the fit, its note) for class ``cls`` of ``powertrain`` in a fleet run's technology.json
    ``technology`` (:func:`vpsim.fleet.technology.read_technology`), or (None, "") without one."""
    from ..fleet.technology import read_technology

    return read_technology(technology, powertrain, cls) if technology else (None, "")


def _not_an_input(out, *inputs) -> None:
    """--out may not name an input: writing it would replace what is being read."""
    target = Path(out).resolve()
    for name in inputs:
        if name and Path(name).resolve() == target:
            raise VpsimError(f"--out {out}: that is an input of this command ({name}); choose another file")


def _from_epa_bev(rec, file, out, technology) -> None:
    """A battery-electric record's vehicle file (:mod:`vpsim.fleet.ev`); ``technology``: a fleet run's
    technology.json, its battery-electric fit on all vehicles."""
    from ..fleet import ev
    from ..textio import printable

    tech, note = _fit(technology, "bev", ev.ev_class(rec))
    params = ev.ev_parameters(rec, technology=tech)
    Path(out).write_text(ev.ev_vehicle_toml(rec, params, source=Path(file).name, technology_note=note))
    meas = ", ".join(f"{c} {v:.1f} MPGe" for c, v in rec.measured_mpge.items())
    m = params.machine
    click.echo(
        printable(
            f"wrote {out}: {rec.make} {rec.model} ({rec.key}), battery-electric, {rec.mass_kg:.0f} kg, "
            f"{m.rated_power / 1e3:.0f} kW, reduction {params.transmission.final_drive:.3g} on "
            f"{params.vehicle.wheel_radius:.3f} m wheels; measured {meas or 'nothing usable'}"
        )
    )


def _from_epa_hev(rec, file, out, technology) -> None:
    """A full hybrid's vehicle file (:mod:`vpsim.fleet.hev`); ``technology``: a fleet run's
    technology.json, its hybrid fit on all vehicles of the layout's class."""
    from ..fleet import hev
    from ..textio import printable

    tech, note = _fit(technology, "hev", hev.hev_class(rec))
    params = hev.hev_parameters(rec, technology=tech)
    Path(out).write_text(hev.hev_vehicle_toml(rec, params, source=Path(file).name, technology_note=note))
    meas = ", ".join(f"{hev.TOML_TEST_NAME[c]} {v:.1f} mpg" for c, v in rec.measured_mpg.items())
    click.echo(
        printable(
            f"wrote {out}: {rec.make} {rec.model} ({rec.key}), {rec.layout}, {rec.mass_kg:.0f} kg, "
            f"{rec.displacement_l:g} L engine {rec.rated_power_kw:.0f} kW, machine "
            f"{params.machine.rated_power / 1e3:.0f} kW; measured {meas or 'nothing usable'} "
            "(udds: the hot UDDS, FTP bags 3 + 4)"
        )
    )


def _from_epa_mhev(rec, file, out, technology) -> None:
    """A mild hybrid's vehicle file (:mod:`vpsim.fleet.mhev`); ``technology``: a fleet run's
    technology.json, its mild-hybrid fit on all vehicles of the layout's class."""
    from ..fleet import mhev
    from ..textio import printable

    tech, note = _fit(technology, "mhev", mhev.mhev_class(rec))
    params = mhev.mhev_parameters(rec, technology=tech)
    Path(out).write_text(mhev.mhev_vehicle_toml(rec, params, source=Path(file).name, technology_note=note))
    meas = ", ".join(f"{c} {v:.1f} mpg" for c, v in rec.measured_mpg.items())
    click.echo(
        printable(
            f"wrote {out}: {rec.make} {rec.model} ({rec.key}), mild hybrid {rec.layout}, "
            f"{rec.mass_kg:.0f} kg, {rec.displacement_l:g} L engine {rec.rated_power_kw:.0f} kW, machine "
            f"{params.machine.rated_power / 1e3:.0f} kW; measured {meas or 'nothing usable'}"
        )
    )
