"""``vpsim maps``: the torque lines (paper Figure 2) and the fuel map (Figure 3), as PNG and CSV."""

from __future__ import annotations

import click

from .main import cli, vehicle_option
from .simulate import _out_dir


@cli.command()
@click.option("--out", "out", required=True, type=click.Path(file_okay=False), help="Output folder.")
@vehicle_option()
def maps(out, vehicle):
    """Write the FQM torque lines and the BQM fuel map of an engine (PNG + CSV)."""
    import matplotlib

    matplotlib.use("Agg")  # files only: the command line never opens a window

    from ..params import load_parameters
    from ..plots import write_map_figures

    params = load_parameters(vehicle)
    written = write_map_figures(params.engine, _out_dir(out))
    for p in written:
        click.echo(f"wrote {p}")
