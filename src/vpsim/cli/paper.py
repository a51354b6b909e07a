"""``vpsim paper``: the paper's study (Tables 1-3, Figures 2-6, tracking, inversion check, report.md)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click

from ..errors import VpsimError
from ._output import number
from .main import cli
from .simulate import _out_dir


@cli.command()
@click.option("--out", "out", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option(
    "--vehicle", default="hofman2011", show_default=True, help="Preset name or a TOML parameter file."
)
@click.option(
    "--advisor-dir",
    "advisor_dir",
    default=None,
    type=click.Path(),
    help="Folder with ADVISOR's FC_SI41_emis.m and FC_SI63_emis.m: adds the engine-scaling section.",
)
@click.option(
    "--repeats",
    default=9,
    show_default=True,
    type=click.IntRange(1, 1000),
    help="Runs per case; Table 3 reports the smallest CPU time.",
)
def paper(out, vehicle, advisor_dir, repeats):
    """Run every method x driver on NEDC and FTP-75 (paper mode) and write the paper's tables and figures."""
    from ..study import _scaling_function, run_study

    if advisor_dir is not None:
        _scaling_function()  # fail before the long run if engine scaling is missing
        if not Path(advisor_dir).is_dir():
            raise VpsimError(f"--advisor-dir {advisor_dir}: no such folder")
    from ..params import load_parameters

    load_parameters(vehicle)  # fail before the progress bar starts if the vehicle is invalid
    _out_dir(out)  # and if --out cannot be written
    start = time.perf_counter()
    with click.progressbar(length=1, label="vpsim paper", file=sys.stderr, show_pos=True) as bar:
        state = {"done": 0}

        def progress(done, total, label):
            bar.length = total
            bar.label = f"vpsim paper: {label:<34.34}"
            bar.update(done - state["done"])
            state["done"] = done

        result = run_study(out, params=vehicle, repeats=repeats, progress=progress, advisor_dir=advisor_dir)
    for row in result.table2:
        click.echo(
            f"  {row['method']:<9} driver {row['driver']:<4} {row['cycle']:<6} "
            f"{number(row['fuel_l_per_100km'], '8.3f', 'fuel_l_per_100km')} L/100 km  "
            f"{number(row['diff_vs_bqm_pct'], '+7.2f', 'diff_vs_bqm_pct')} %"
        )
    click.echo(
        f"wrote {len(result.files)} files into {out} in {time.perf_counter() - start:.1f} s (see report.md)"
    )
