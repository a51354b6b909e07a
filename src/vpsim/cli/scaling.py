"""``vpsim scaling``: the model engine scaled to a measured one, compared (Figure 7) and calibrated."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import VpsimError
from ._output import dumps, number
from .main import cli, vehicle_option
from .simulate import _out_dir

# a scaled engine whose displacement differs more than this from the measured file's fc_disp is flagged
DISPLACEMENT_TOLERANCE = 0.10


def _names(text: str, what: str) -> list[str]:
    names = [c.strip() for c in text.split(",") if c.strip()]
    if not names:
        raise VpsimError(f"{what}: give at least one cycle name, e.g. nedc,ftp75")
    return names


def _check_cycles(names: list[str], what: str) -> None:
    """Each cycle loads and drives some distance (fuel per distance is undefined otherwise)."""
    from ..cycles import MIN_CONSUMPTION_DISTANCE_M, load_cycle

    for name in names:
        cyc = load_cycle(name)
        if not cyc.distance_m >= MIN_CONSUMPTION_DISTANCE_M:
            raise VpsimError(
                f"{what}: cycle {name} drives no distance ({cyc.distance_m:.3g} m), so its fuel per 100 km "
                "is undefined; "
                "give a cycle that moves"
            )


@cli.command()
@click.option(
    "--measured",
    required=True,
    type=click.Path(dir_okay=False),
    help="Measured engine: ADVISOR fuel-converter .m or its .json form.",
)
@click.option("--bore", required=True, type=float, help="Bore B of the scaled engine, in metres (0.074).")
@click.option("--stroke", required=True, type=float, help="Stroke S of the scaled engine, in metres (0.077).")
@click.option("--cylinders", required=True, type=int, help="Number of cylinders z.")
@click.option(
    "--inertia",
    default=None,
    type=float,
    help="Engine inertia J_e (kg m^2); default: the measured file's fc_inertia.",
)
@vehicle_option(help="Preset or TOML file giving the vehicle, gears, idle flow and the engine to scale from.")
@click.option(
    "--cycles",
    default="nedc,ftp75",
    show_default=True,
    help="Cycles for the fuel comparison (backward method), comma-separated.",
)
@click.option(
    "--calibrate",
    is_flag=True,
    help="Also fit eta_th and xi_aux to the measured map (bounded least squares) and compare again.",
)
@click.option(
    "--calibration-cycles",
    default="wltc3b",
    show_default=True,
    help="Cycles whose operating points (time-weighted) the calibration fits.",
)
@click.option("--out", "out", required=True, type=click.Path(file_okay=False), help="Output folder.")
def scaling(measured, bore, stroke, cylinders, inertia, vehicle, cycles, calibrate, calibration_cycles, out):
    """Scale the model engine to a measured one; write Figure 7, statistics and a fuel table.

    Writes figure7.png, map_comparison.csv (measured vs generated at every measured node),
    map_stats.json (median and 90th percentile of the fuel-flow error, over the nodes and weighted by cycle
    time) and fuel.csv (backward-method L/100 km per cycle with each map, the error, the share of cycle time
    outside the measured map); with --calibrate also calibration.json (fitted values, standard errors,
    correlations).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..calibration import calibrate as fit
    from ..cycles import load_cycle
    from ..engines import load_engine
    from ..params import load_parameters
    from ..scaling import (
        TABLE4_COLUMNS,
        compare_maps,
        compare_on_cycle,
        coverage_rows,
        cycle_points,
        plot_figure7,
        scaled_parameters,
        write_csv,
    )
    from .notices import announce_compilation, echo

    announce_compilation()
    cycle_names = _names(cycles, "--cycles")
    cal_cycles = _names(calibration_cycles, "--calibration-cycles")
    _check_cycles(cycle_names, "--cycles")
    if calibrate:
        _check_cycles(cal_cycles, "--calibration-cycles")
    eng = load_engine(measured)
    base = load_parameters(vehicle)
    eng.check_gasoline(base.simulation.fuel_density)  # litres of gasoline only compare with gasoline
    params = scaled_parameters(
        base,
        bore=bore,
        stroke=stroke,
        cylinders=cylinders,
        inertia=eng.inertia if inertia is None else inertia,
    )
    warnings = eng.sanity_warnings()
    vd = params.engine.displacement
    if abs(vd / eng.displacement - 1.0) > DISPLACEMENT_TOLERANCE:
        warnings.append(
            f"the scaled displacement {vd * 1e3:.3f} L (B {bore:g} m, S {stroke:g} m, z {cylinders}) differs "
            f"from the measured engine's fc_disp {eng.displacement * 1e3:.3f} L by "
            f"{100 * (vd / eng.displacement - 1.0):+.0f} %"
        )
    for c in dict.fromkeys(cycle_names + (cal_cycles if calibrate else [])):
        load_cycle(c)  # bad input is one line and nothing else, before any announcement
    path = _out_dir(out)
    echo(
        f"vpsim scaling: {Path(measured).name} against the scaled model, fuel on {', '.join(cycle_names)}"
        + (f", calibrating on {', '.join(cal_cycles)}" if calibrate else "")
        + " (a few seconds)"
    )
    mmap = eng.engine_map()
    cmp = compare_maps(eng, params.engine, name=eng.name)
    cal = fit(mmap, params, cycles=cal_cycles) if calibrate else None
    cells = [
        compare_on_cycle(mmap, params, c, label=eng.name, calibrated_engine=cal.engine if cal else None)
        for c in cycle_names
    ]

    fig = plot_figure7(
        [cmp],
        path / "figure7.png",
        points=[cycle_points(mmap, params, cycle_names)],
        points_label=" + ".join(cycle_names) + " points",
    )
    plt.close(fig)
    write_csv(path / "map_comparison.csv", cmp.rows())
    rows = [{**c.table4_row(), **cov} for c, cov in zip(cells, coverage_rows(cells), strict=True)]
    extra = [k for k in rows[0] if k not in TABLE4_COLUMNS]
    write_csv(path / "fuel.csv", rows, list(TABLE4_COLUMNS) + extra)
    stats = {"nodes": cmp.stats(), **{f"time_on_{c.cycle}": c.point_stats for c in cells}}
    (path / "map_stats.json").write_text(dumps(stats, indent=2) + "\n")
    if cal is not None:
        (path / "calibration.json").write_text(dumps(cal.as_dict(), indent=2) + "\n")

    e = params.engine
    click.echo(
        f"{eng.name} vs the model scaled to B {e.bore * 1e3:.1f} mm, S {e.stroke * 1e3:.1f} mm, "
        f"z {e.cylinders} (V_d {e.displacement * 1e3:.3f} L), in vehicle {params.name}"
    )
    s = cmp.stats()
    click.echo(
        f"  map: |generated/measured - 1| median {number(s['median_abs_pct'], '.1f')} %, "
        f"90th percentile {number(s['p90_abs_pct'], '.1f')} % over {s['n']} measured nodes"
    )
    for c in cells:
        line = (
            f"  {c.cycle:8s} measured {number(c.measured_l_per_100km, '6.3f', 'fuel_l_per_100km')}  "
            f"generated {number(c.generated_l_per_100km, '6.3f', 'fuel_l_per_100km')} L/100 km "
            f"({number(c.error_pct, '+.1f')} %)"
        )
        if cal is not None:
            line += (
                f"  calibrated {number(c.calibrated_l_per_100km, '6.3f', 'fuel_l_per_100km')} "
                f"({number(c.calibrated_error_pct, '+.1f')} %)"
            )
        outside = number(100 * c.coverage["outside"], ".1f")
        click.echo(line + f"; {outside} % of the time outside the measured map")
    if cal is not None:
        for k, n in enumerate(cal.names):
            err = number(cal.std_errors[k], ".2g", "std_error")
            click.echo(f"  fitted {n} = {number(cal.values[k], '.4g')} +- {err}")
        if cal.message:
            click.echo(f"  note: {cal.message}")
    for w in warnings:
        click.echo(f"  warning: {w}")
    names = ["figure7.png", "map_comparison.csv", "map_stats.json", "fuel.csv"]
    names += ["calibration.json"] if cal is not None else []
    click.echo(f"  wrote {path / names[0]}, " + ", ".join(names[1:]))
