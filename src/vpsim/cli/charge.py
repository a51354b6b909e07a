"""``vpsim charge-balance``: SAE J1711's regression of a hybrid's fuel on its battery's net energy change."""

from __future__ import annotations

import click

from ..errors import VpsimError
from ._output import dumps, save_plot
from .main import cli, vehicle_option


def _offsets(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(","))
    except ValueError:
        msg = f"--soc-offsets {text!r}: expected numbers separated by commas, e.g. -0.05,0,0.05"
        raise VpsimError(msg) from None


@cli.command("charge-balance")
@click.option("--cycle", default="udds", show_default=True, help="Standard cycle or a cycle CSV.")
@vehicle_option(default="hev_p2", help="A hybrid's preset or TOML file.")
@click.option(
    "--method", type=click.Choice(["backward", "forward", "inverse"]), default="backward", show_default=True
)
@click.option(
    "--ems",
    type=click.Choice(["rule", "ecms"]),
    default=None,
    help="The management (default: the vehicle's hybrid.ems); the DP sustains its charge from any start.",
)
@click.option(
    "--soc-offsets",
    default=None,
    help="Starting charges about battery.soc_initial, comma-separated (default -0.06,-0.03,0,0.03,0.06).",
)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("--plot", "plot", default=None, type=click.Path(dir_okay=False), help="Write the fit's figure.")
def charge_balance(cycle, vehicle, method, ems, soc_offsets, as_json, plot):
    """The fuel at zero net energy change of the battery, by J1711's regression over several starts."""
    from ..charge_balance import regression
    from .notices import announce_compilation

    announce_compilation()
    offsets = None if soc_offsets is None else _offsets(soc_offsets)
    cb = regression(cycle, vehicle, method=method, ems=ems, soc_offsets=offsets)
    if plot:
        save_plot(cb.plot, plot)
    click.echo(dumps(cb.as_dict()) if as_json else str(cb))
