"""``vpsim params``: a parameter set with each value's provenance."""

from __future__ import annotations

import click

from ._output import dumps
from .main import cli, vehicle_option


@cli.command("params")
@vehicle_option()
@click.option("--json", "as_json", is_flag=True, help="Print {field: {value, provenance}} as JSON.")
def params_cmd(vehicle, as_json):
    """Show every parameter value (SI) and where it comes from (paper / derived / reconstructed / user)."""
    from ..params import load_parameters

    p = load_parameters(vehicle)
    bev = p.powertrain.type == "bev"
    # the sections that do not act on this powertrain are left out: the engine of a battery-electric car,
    # the electric sections of an engine car
    unused = ("engine.",) if bev else ("battery.", "machine.", "electric.")
    flat = {k: v for k, v in p.flat().items() if not k.startswith(unused)}
    if as_json:
        click.echo(dumps({k: {"value": v, "provenance": p.provenance.get(k, "")} for k, v in flat.items()}))
        return
    click.echo(f"parameter set {p.name}" + (f"\n  {p.citation}" if p.citation else ""))
    if bev:
        from ..model.electric import pack_of

        pk = pack_of(p)
        click.echo(
            f"  battery (derived) {pk.energy_wh / 1e3:.1f} kWh, {pk.ocv_v[len(pk.ocv_v) // 2]:.0f} V at half "
            f"charge, {pk.mass_kg:.0f} kg of cells; total ratio {p.transmission.ratios[0]:.3f}"
        )
    else:
        click.echo(
            f"  displacement (derived) {p.engine.displacement * 1e3:.3f} L; total ratios "
            + " ".join(f"{r:.3f}" for r in p.transmission.ratios)
        )
    for k, v in flat.items():
        val = (
            ", ".join(f"{x:g}" for x in v) if isinstance(v, tuple) else v if isinstance(v, str) else f"{v:g}"
        )
        click.echo(f"  {k:<38} {val:<28} {p.provenance.get(k, '')}")
