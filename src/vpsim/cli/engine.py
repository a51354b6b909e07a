"""``vpsim engine import FILE``: read a measured engine (ADVISOR ``.m`` or ``.json``) and summarise it."""

from __future__ import annotations

import math

import click

from ..errors import VpsimError
from ._output import dumps
from .main import cli


def _rpm(w: float) -> str:
    return f"{w * 60 / (2 * math.pi):.0f} rpm"


@cli.group()
def engine():
    """Measured engines: fuel maps from ADVISOR fuel-converter files."""


@engine.command("import")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option(
    "--out",
    "out",
    default=None,
    type=click.Path(dir_okay=False),
    help="Also write vpsim's JSON form of the engine to this .json file (load_engine reads it back).",
)
@click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON object.")
def import_engine(file, out, as_json):
    """Read FILE (ADVISOR fuel-converter .m, read safely without running it, or .json) and summarise it.

    Units: speeds rad/s, torques N m, fuel g/s in the file and kg/s inside vpsim.
    """
    from ..engines import load_engine

    e = load_engine(file)
    s = e.summary()
    if out:
        try:
            e.write_json(out)
        except OSError as exc:
            raise VpsimError(f"--out {out}: cannot write ({exc.strerror or exc})") from None
    if as_json:
        click.echo(dumps({**s, "written": out}))
        return
    w_lo, w_hi, n_w = s["speed_grid_radps"]
    t_lo, t_hi, n_t = s["torque_grid_nm"]
    click.echo(f"{s['name']}  ({s['source']})")
    click.echo(f"  displacement   {s['displacement_l']:.3f} L, inertia {s['inertia_kgm2']:.3g} kg m^2")
    click.echo(f"  speed grid     {n_w} points, {w_lo:.1f}-{w_hi:.1f} rad/s ({_rpm(w_lo)[:-4]}-{_rpm(w_hi)})")
    zero = "with a zero-torque column" if s["zero_torque_column"] else "no zero-torque column"
    click.echo(f"  torque grid    {n_t} points, {t_lo:.1f}-{t_hi:.1f} N m ({zero})")
    click.echo(
        f"  peak torque    {s['peak_torque_nm']:.1f} N m at {s['peak_torque_speed_radps']:.1f} rad/s "
        f"({_rpm(s['peak_torque_speed_radps'])})"
    )
    click.echo(
        f"  peak power     {s['peak_power_kw']:.1f} kW at {s['peak_power_speed_radps']:.1f} rad/s "
        f"({_rpm(s['peak_power_speed_radps'])})"
    )
    if s["min_bsfc_g_per_kwh"] is not None:
        click.echo(
            f"  min BSFC       {s['min_bsfc_g_per_kwh']:.5g} g/kWh at {s['min_bsfc_torque_nm']:.1f} N m, "
            f"{s['min_bsfc_speed_radps']:.1f} rad/s"
        )
    if s["full_load_above_grid"]:
        click.echo("  note: the full-load curve rises above the highest torque column (extrapolated there)")
    for w in s["warnings"]:
        click.echo(f"  warning: {w}")
    if out:
        click.echo(f"  wrote {out}")
