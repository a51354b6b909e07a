"""``vpsim bench``: speed of every method side by side with FASTSim 3.1, batch throughput, cold start."""

from __future__ import annotations

import math
from pathlib import Path

import click

from ..errors import VpsimError
from ._output import dumps
from .main import cli


@cli.command()
@click.option(
    "--quick", is_flag=True, help="Shorter measurements (under a minute); no first-compilation run."
)
@click.option(
    "--json",
    "json_path",
    default=None,
    type=click.Path(dir_okay=False),
    help="Also write every figure to this JSON file.",
)
@click.option("--no-peer", is_flag=True, help="Do not run FASTSim (reported as not measured).")
@click.option("--tiny", is_flag=True, hidden=True, help="A few seconds, backward only (for tests).")
def bench(quick, json_path, no_peer, tiny):
    """Time the methods on UDDS, NEDC, FTP-75 against FASTSim 3.1 (pip install 'vpsim[bench]')."""
    from ..bench import format_report, run_benchmarks
    from .notices import announce_compilation

    announce_compilation()

    profile = "tiny" if tiny else "quick" if quick else "full"
    if json_path:  # fail before minutes of measuring, not after
        path = Path(json_path)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with path.open("a"):
                pass
        except OSError as exc:
            raise VpsimError(f"--json {json_path}: cannot write ({exc.strerror})") from None
    report = run_benchmarks(
        profile, peer=not no_peer, progress=lambda line: click.echo(f"  {line}", err=True)
    )
    if json_path:
        path.write_text(dumps(report, indent=2, default=_jsonable) + "\n")
    click.echo(format_report(report))
    if json_path:
        click.echo(f"wrote {json_path}")


def _jsonable(obj):
    try:
        x = float(obj)
    except (TypeError, ValueError):
        return str(obj)
    return x if math.isfinite(x) else None
