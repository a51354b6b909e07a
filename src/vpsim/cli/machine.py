"""``vpsim machine import FILE`` and ``vpsim machine compare FILE``: measured electric machines (ADVISOR
MC_*.m / GC_*.m), summarised and checked against the scalable loss model of :mod:`vpsim.model.machine`."""

from __future__ import annotations

import math

import click
import numpy as np

from ..errors import VpsimError
from ._output import dumps
from .main import cli

CYCLES = ("udds", "hwfet")
NO_CAR = "the battery-electric car is not available in this build"


def _rpm(w: float) -> float:
    return w * 60.0 / (2.0 * math.pi)


def _kind_of(machine, kind: str) -> str:
    """The kind asked for, or (``auto``) the one the file's description names."""
    if kind != "auto":
        return kind
    text = f"{machine.description} {machine.name}".lower()
    if "induction" in text:
        return "induction"
    if "permanent magnet" in text or "permanent-magnet" in text:
        return "pm"
    raise VpsimError(
        f"{machine.source}: the description says neither 'induction' nor 'permanent magnet'; give --kind pm "
        "or --kind induction"
    )


@cli.group()
def machine():
    """Electric machines with inverter: measured maps and the scalable loss model."""


@machine.command("import")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON object.")
@click.option(
    "--plot",
    "plot",
    default=None,
    type=click.Path(dir_okay=False),
    help="Also draw the efficiency map with its torque envelope into this image file (.png).",
)
def import_machine(file, as_json, plot):
    """Read FILE (ADVISOR MC_*.m or GC_*.m, read safely without running it) and summarise its map.

    The rating is the envelope's: peak power, base speed = peak power / peak torque (where constant torque
    turns to constant power), maximum speed = the envelope's last speed. Efficiencies include the inverter.
    """
    from ..engines.machine_map import load_machine

    m = load_machine(file)
    s = m.summary()
    if plot:
        _write_plot(m, plot)
    if as_json:
        click.echo(dumps({**s, "plot": plot}))
        return
    click.echo(f"{s['name']}  ({s['description'] or 'no description'})")
    click.echo(f"  rated (peak) power  {s['rated_power_kw']:.1f} kW")
    click.echo(
        f"  peak torque         {s['peak_torque_nm']:.1f} N m motoring, "
        f"{s['min_generating_torque_nm']:.1f} N m generating"
    )
    click.echo(f"  base speed          {s['base_speed_rpm']:.0f} rpm (peak power / peak torque)")
    click.echo(f"  max speed           {s['max_speed_rpm']:.0f} rpm")
    click.echo(
        f"  map                 {len(s['speed_grid_rpm'])} speeds x {len(s['torque_grid_nm'])} torques, "
        f"{s['torque_grid_nm'][0]:.1f} to {s['torque_grid_nm'][-1]:.1f} N m"
    )
    click.echo(
        f"  efficiency          {s['efficiency_min'] * 100:.1f} to {s['efficiency_max'] * 100:.1f} % over "
        f"{s['n_map_points']} points in the envelope (T, w != 0; inverter included)"
    )
    click.echo(f"  inertia             {s['inertia_kgm2']:.4g} kg m^2")
    click.echo("  envelope            rpm: motoring / generating N m")
    for w, hi, lo in zip(
        s["envelope_speed_rpm"], s["envelope_max_torque_nm"], s["envelope_min_torque_nm"], strict=True
    ):
        click.echo(f"    {w:7.0f}: {hi:7.1f} / {lo:7.1f}")
    if plot:
        click.echo(f"  wrote {plot}")


def _write_plot(m, path: str) -> None:
    from ..plots import plot_machine_efficiency
    from ._output import save_plot

    save_plot(lambda: plot_machine_efficiency(m), path)


def cycle_energy_errors(spec, measured) -> dict:
    """``cycle_energy_error_pct`` per cycle: 100 (E_scaled - E_measured) / E_measured of the battery energy
    the battery-electric car draws on the cycle with the scaled model and with the measured map; null with a
    reason where that car is not part of this build."""
    try:
        from ..powertrains import cycle_battery_energy_j
    except ImportError:
        return {"cycle_energy_error_pct": None, "cycle_energy_error_pct_undefined": NO_CAR}
    out: dict = {}
    energies: dict = {}
    for cycle in CYCLES:
        e_scaled = float(cycle_battery_energy_j(cycle, spec))
        e_measured = float(cycle_battery_energy_j(cycle, measured))
        energies[cycle] = {"scaled_j": e_scaled, "measured_j": e_measured}
        out[cycle] = 100.0 * (e_scaled - e_measured) / e_measured if e_measured != 0 else math.nan
    return {"cycle_energy_error_pct": out, "cycle_battery_energy_j": energies}


@machine.command("compare")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option(
    "--kind",
    type=click.Choice(["auto", "pm", "induction"]),
    default="auto",
    show_default=True,
    help="Machine kind whose default loss coefficients are used; auto reads it from the file's description.",
)
@click.option("--json", "as_json", is_flag=True, help="Print the comparison as one JSON object.")
def compare_machine(file, kind, as_json):
    """Compare FILE's measured efficiency map with the scalable loss model at FILE's rating.

    The model uses the default coefficients of its kind (fitted on the six ADVISOR motor maps, so for those
    files it has seen the map; benchmarks/machine_fit.py gives the leave-one-out figures). Errors are model
    minus map efficiency in percentage points, over the map's points in the torque envelope of both quadrants
    with non-zero torque and speed.
    """
    from ..engines.machine_map import load_machine
    from ..model.machine import MachineSpec, efficiency_errors_pts

    m = load_machine(file)
    kind = _kind_of(m, kind)
    spec = MachineSpec.from_measured(m, kind=kind)
    err, _, _ = efficiency_errors_pts(m, spec)
    out = {
        "file": str(file),
        "name": m.name,
        "kind": kind,
        "rated_power_kw": m.rated_power_w / 1e3,
        "base_speed_rpm": _rpm(m.base_speed_radps),
        "max_speed_rpm": _rpm(m.max_speed_radps),
        "rated_torque_nm": spec.rated_torque_nm,
        "n_points": int(err.size),
        "median_abs_efficiency_error_pts": float(np.median(np.abs(err))),
        "max_abs_efficiency_error_pts": float(np.max(np.abs(err))),
        "mean_efficiency_error_pts": float(np.mean(err)),
        "coefficients": spec.coefficients.as_dict(),
        **cycle_energy_errors(spec, m),
    }
    if as_json:
        click.echo(dumps(out))
        return
    click.echo(
        f"{m.name}: scaled {kind} model at {out['rated_power_kw']:.1f} kW, "
        f"base {out['base_speed_rpm']:.0f} rpm, "
        f"max {out['max_speed_rpm']:.0f} rpm"
    )
    click.echo(f"  efficiency error over {out['n_points']} map points (model - map, percentage points):")
    click.echo(
        f"    median |error| {out['median_abs_efficiency_error_pts']:.2f}, "
        f"max |error| {out['max_abs_efficiency_error_pts']:.1f}, mean {out['mean_efficiency_error_pts']:+.2f}"
    )
    cyc = out["cycle_energy_error_pct"]
    if cyc is None:
        click.echo(f"  cycle energy error: undefined ({out['cycle_energy_error_pct_undefined']})")
    else:
        for name, pct in cyc.items():
            text = f"{pct:+.2f} %" if math.isfinite(pct) else "undefined (the measured map draws no energy)"
            click.echo(f"  cycle energy error {name}: {text}")
