"""``vpsim simulate``: one method on one cycle."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import VpsimError
from ._output import dumps, number
from .main import cli, vehicle_option


def _ok(text: str) -> bool:
    return not text.startswith("undefined")


def _out_dir(out: str) -> Path:
    """The --out folder, created; one line when it cannot be (a file there, no permission)."""
    path = Path(out)
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".vpsim-write-test"
        probe.write_bytes(b"")
        probe.unlink()
    except FileExistsError:
        raise VpsimError(f"--out {out}: a file is in the way, expected a folder") from None
    except OSError as exc:
        raise VpsimError(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    return path


@cli.command()
@click.option(
    "--cycle",
    "cycle",
    default="nedc",
    show_default=True,
    help="Standard cycle (nedc, ftp75, udds, hwfet, us06, wltc3b), an FTP-75 bag (ftp_bag2, ftp_bag3) or a "
    "CSV file (time_s + speed column).",
)
@click.option(
    "--method", type=click.Choice(["backward", "forward", "inverse"]), default="backward", show_default=True
)
@vehicle_option()
@click.option(
    "--driver",
    type=click.Choice(["1", "2"]),
    default=None,
    help="Driver tuning for forward/inverse (default 2 in the realistic mode, 1 in the paper mode); "
    "not used by backward.",
)
@click.option(
    "--mode",
    type=click.Choice(["realistic", "paper", "extended"]),
    default="realistic",
    show_default=True,
    help="realistic: clutch and idle at standstill, friction brakes; paper: the paper's model (no clutch, no "
    "brakes; what 'vpsim paper' uses). 'extended' is the realistic mode's earlier name.",
)
@click.option(
    "--gears",
    "gears",
    default=None,
    type=click.Path(dir_okay=False),
    help="Gear schedule CSV (time_s,gear); default: derived from the cycle by the documented rule.",
)
@click.option(
    "--speed-unit",
    type=click.Choice(["m/s", "km/h", "mph"]),
    default=None,
    help="Unit of a plain 'speed' column in a cycle CSV.",
)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object with the summary.")
@click.option(
    "--out",
    "out",
    default=None,
    type=click.Path(file_okay=False),
    help="Write timeseries.csv, summary.json and timeseries.png into this folder.",
)
@click.option(
    "--solver",
    type=click.Choice(["rosenbrock", "dopri5"]),
    default=None,
    help="Forward method's integrator: rosenbrock (default, stiffly stable RODAS3) or dopri5 (the paper's "
    "ode45).",
)
@click.option(
    "--ems",
    type=click.Choice(["rule", "ecms", "dp"]),
    default=None,
    help="A hybrid's energy management (default: its hybrid.ems): rule, ecms or dp (dynamic programming, the "
    "optimum; backward method).",
)
def simulate(cycle, method, vehicle, driver, mode, gears, speed_unit, as_json, out, solver, ems):
    """Simulate a vehicle on a drive cycle and report its fuel consumption."""
    from ..cycles import MIN_CONSUMPTION_DISTANCE_M, load_cycle
    from ..gears import load_schedule
    from ..params import HYBRIDS, load_parameters
    from ..simulation import simulate as run
    from ..units import mpg_from_l_per_100km
    from .notices import announce_compilation

    announce_compilation()

    if driver is not None and method == "backward":
        raise VpsimError(
            "--driver applies to --method forward or inverse; the backward method tracks exactly"
        )
    cyc = load_cycle(cycle, speed_unit=speed_unit)
    params = load_parameters(vehicle)
    schedule = None
    if gears is not None:  # read here so that gear times are checked against the cycle
        schedule = load_schedule(gears, params.transmission.n_gears, cycle=cyc)
    if out:
        path = _out_dir(out)
    if solver is not None and method != "forward":
        raise VpsimError("--solver applies to --method forward (the integrator of the dynamic model)")
    options = {} if solver is None else {"solver": solver}
    if ems is not None:
        if params.powertrain.type not in HYBRIDS:
            raise VpsimError(f"--ems applies to a hybrid; {vehicle} is a {params.powertrain.type} car")
        options["ems"] = ems
    result = run(cyc, method=method, params=params, driver=driver, mode=mode, gears=schedule, **options)
    summary = result.summary()
    if not cyc.distance_m >= MIN_CONSUMPTION_DISTANCE_M:  # a method's creep is no basis for L/100 km
        summary["fuel_l_per_100km"] = float("nan")
        summary["fuel_economy_mpg"] = float("nan")
    measured = _measured_mpg(vehicle, result.cycle)
    summary["measured_mpg"] = measured
    summary["measured_error_pct"] = (
        100.0 * (summary["fuel_economy_mpg"] / measured - 1.0) if measured is not None else float("nan")
    )
    measured_mpge = None
    if result.electric:  # a battery-electric vehicle file's record: MPGe per test
        measured_mpge = _measured_mpg(vehicle, result.cycle, "measured_mpge")
        summary["measured_mpge"] = measured_mpge
        summary["measured_error_pct"] = (
            100.0 * (summary["mpge"] / measured_mpge - 1.0) if measured_mpge is not None else float("nan")
        )
    if result.electric and measured is not None:  # a hybrid's record: compared charge-sustaining
        cs_mpg = mpg_from_l_per_100km(summary["fuel_l_per_100km_cs"])
        summary["measured_error_pct"] = 100.0 * (cs_mpg / measured - 1.0)
    written = []
    if out:
        # an undefined sample (intake pressure with the engine decoupled, say) is an empty cell, never nan/inf
        df = result.to_dataframe().replace([float("inf"), float("-inf")], float("nan"))
        df.to_csv(path / "timeseries.csv", index=False, na_rep="", float_format="%.10g")
        (path / "summary.json").write_text(dumps(summary, indent=2) + "\n")
        import matplotlib

        matplotlib.use("Agg")  # the command line draws into files; the library leaves the backend alone
        import matplotlib.pyplot as plt

        fig = result.plot()
        fig.savefig(path / "timeseries.png", dpi=110)
        plt.close(fig)
        written = [path / "timeseries.csv", path / "summary.json", path / "timeseries.png"]
    if as_json:
        click.echo(dumps(summary))
        return
    click.echo(
        f"{method} on {result.cycle} ({result.mode} mode, vehicle {result.vehicle}"
        f"{'' if result.driver is None else ', driver ' + result.driver})"
    )
    if result.electric and result.fuel_kg > 0.0:  # a hybrid: fuel, charge-sustaining fuel, its battery
        lp100 = number(summary["fuel_l_per_100km"], "8.3f", "fuel_l_per_100km")
        click.echo(
            f"  fuel consumption  {lp100}{' L/100 km' if _ok(lp100) else ''} "
            f"(energy management {ems_of(summary)})"
        )
        cs = number(summary["fuel_l_per_100km_cs"], "8.3f", "fuel_l_per_100km_cs")
        click.echo(
            f"  charge-sustaining {cs}{' L/100 km (SAE J1711 net energy correction)' if _ok(cs) else ''}"
        )
        click.echo(
            f"  state of charge   {summary['soc_start']:.4f} -> {summary['soc_end']:.4f}; "
            f"{summary['engine_starts']} engine starts"
        )
        if measured is not None:
            err = number(summary["measured_error_pct"], "+.1f", "measured_error_pct")
            click.echo(
                f"  measured          {measured:8.2f} mpg (the record's test on this cycle); "
                f"charge-sustaining predicted {err}{' %' if _ok(err) else ''}"
            )
    elif result.electric:
        _echo_electric(summary)
        if measured_mpge is not None:
            err = number(summary["measured_error_pct"], "+.1f", "measured_error_pct")
            click.echo(
                f"  measured          {measured_mpge:8.1f} MPGe (the record's test on this cycle); "
                f"predicted {err}{' %' if _ok(err) else ''}"
            )
    else:
        lp100 = number(summary["fuel_l_per_100km"], "8.3f", "fuel_l_per_100km")
        click.echo(f"  fuel consumption  {lp100}{' L/100 km' if _ok(lp100) else ''}")
        mpg = number(summary["fuel_economy_mpg"], "8.2f", "fuel_economy_mpg")
        click.echo(f"  fuel economy      {mpg}{' mpg (US)' if _ok(mpg) else ''}")
        if summary["engine_starts"] is not None:  # an engine car with stop-start
            click.echo(f"  stop-start        {summary['engine_starts']} engine restarts")
    if measured is not None and not result.electric:
        err = number(summary["measured_error_pct"], "+.1f", "measured_error_pct")
        click.echo(
            f"  measured          {measured:8.2f} mpg (the record's test on this cycle); "
            f"predicted {err}{' %' if _ok(err) else ''}"
        )
    if not result.electric:
        click.echo(f"  fuel              {number(result.fuel_kg * 1e3, '8.1f', 'fuel_kg')} g")
    click.echo(f"  distance          {number(result.distance_km, '8.3f', 'distance_km')} km")
    click.echo(f"  CPU time          {result.cpu_time_s * 1e3:8.2f} ms ({result.steps} steps)")
    dev = result.deviations
    click.echo(
        f"  speed not followed      {_seconds(dev.speed_not_followed_s)} outside ±2 km/h "
        f"(max error {dev.max_speed_error_mps:.2f} m/s)"
    )
    click.echo(
        f"  demand not deliverable  {_seconds(dev.demand_not_deliverable_s)}"
        + (f" ({_causes(dev)})" if dev.demand_not_deliverable_s else "")
    )
    click.echo(
        f"  outside physics         {_seconds(dev.outside_physics_s)}"
        + (f" ({_physics(dev)})" if dev.outside_physics_s else "")
    )
    if result.energy is not None:
        res = number(summary["energy_relative_residual"], ".1e", "energy_relative_residual")
        of = " of the energy terms" if result.electric else " of the indicated work"
        click.echo(f"  energy balance    residual {res}{of if _ok(res) else ''}")
    for note in result.notes:
        click.echo(f"  note: {note}")
    for p in written:
        click.echo(f"  wrote {p}")


def _measured_mpg(vehicle: str, cycle: str, table: str = "measured_mpg") -> float | None:
    """The fuel economy the certification record measured on ``cycle``, from the record block a vehicle file
    of ``vpsim vehicle from-epa`` carries (its test names: ftp_bag2, ftp_bag3, hwy for hwfet, us06; a
    battery-electric file's ``measured_mpge``: udds, hwy); None for a preset, another file, or a cycle the
    record has no test on, and None with a note for a value outside the certification reader's plausible range
    (5-150 mpg, :data:`vpsim.fleet.epa.PLAUSIBLE`; 40-300 MPGe, :data:`vpsim.fleet.ev.MPGE_RANGE`): an edited
    0.001 mpg gives no comparison, never an error of millions of percent."""
    from ..cycles import _normalise

    path = Path(vehicle)
    if path.suffix.lower() != ".toml" or not path.is_file():
        return None
    from ..fleet.vehicle import read_record_block

    try:
        record = read_record_block(path).get("record", {})
        tests = record.get(table, {}) if isinstance(record, dict) else {}
    except VpsimError as exc:  # an edited comment block: the run stands, the comparison is left out, said so
        click.echo(f"vpsim: note: no measurement to compare with: {exc}", err=True)
        return None
    if not isinstance(tests, dict):
        return None
    from ..fleet.epa import PLAUSIBLE
    from ..fleet.ev import MPGE_RANGE
    from ..textio import printable

    lo, hi = MPGE_RANGE if table == "measured_mpge" else PLAUSIBLE["mpg"]
    for name, mpg in tests.items():
        if _normalise(str(name)) == cycle and isinstance(mpg, int | float) and not isinstance(mpg, bool):
            if lo <= mpg <= hi:  # (nan is not)
                return float(mpg)
            click.echo(
                f"vpsim: note: no measurement to compare with: {path}: record.{table}.{printable(name)[:40]} "
                f"= {printable(mpg)[:40]} is outside the plausible [{lo:g}, {hi:g}] (the certification "
                "reader's range)",
                err=True,
            )
            return None
    return None


def ems_of(summary: dict) -> str:
    return str(summary.get("ems") or "-")


def _echo_electric(summary: dict) -> None:
    """The battery-electric figures of a run's summary, one per line."""
    for label, key, spec, unit in (
        ("battery energy", "electric_wh_per_km", "8.1f", " Wh/km (terminal, net)"),
        ("wall energy", "wall_wh_per_km", "8.1f", " Wh/km (charger included)"),
        ("economy", "mpge", "8.1f", " MPGe"),
        ("recovered", "regen_wh", "8.1f", " Wh (machine, generating)"),
    ):
        text = number(summary[key], spec, key)
        click.echo(f"  {label:<16}  {text}{unit if _ok(text) else ''}")
    click.echo(f"  state of charge   {summary['soc_start']:.4f} -> {summary['soc_end']:.4f}")
    for key, what in (
        ("machine_at_limit_s", "machine at its limit"),
        ("battery_at_limit_s", "battery at its limit"),
    ):
        click.echo(f"  {what:<22}  {number(summary[key], 'g', key)} s")


def _seconds(x) -> str:
    return "not assessed" if x is None else f"{x:g} s"


def _causes(dev) -> str:
    parts = []
    if dev.torque_beyond_full_load_s:
        extra = (
            f", max shortfall {dev.max_torque_shortfall_nm:.1f} N m" if dev.max_torque_shortfall_nm else ""
        )
        parts.append(f"torque beyond full load {dev.torque_beyond_full_load_s:g} s{extra}")
    if dev.throttle_below_minimum_s:
        parts.append(f"throttle below minimum {dev.throttle_below_minimum_s:g} s")
    if dev.engine_speed_out_of_range_s:
        parts.append(
            f"engine speed out of range {dev.engine_speed_out_of_range_s:g} s, "
            f"max {dev.max_engine_speed_radps:.0f} rad/s"
        )
    return "; ".join(parts)


def _physics(dev) -> str:
    parts = []
    if dev.negative_intake_pressure_s:
        parts.append(f"negative intake pressure {dev.negative_intake_pressure_s:g} s")
    if dev.negative_fuel_flow_s:
        parts.append(f"negative fuel flow {dev.negative_fuel_flow_s:g} s")
    if dev.engine_speed_out_of_range_s:
        parts.append(f"engine over its top speed {dev.engine_speed_out_of_range_s:g} s")
    if dev.speed_not_followed_s:
        parts.append(f"speed outside the band {dev.speed_not_followed_s:g} s")
    return "; ".join(parts)
