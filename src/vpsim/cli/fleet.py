"""``vpsim fleet``: every usable vehicle of a test car list on the cycles its tests measured."""

from __future__ import annotations

import shlex
import sys

import click

from ._output import dumps, save_plot
from .main import cli


@cli.command()
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--out", "out", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option(
    "--cycles",
    "cycles",
    default="ftp_bag2,ftp_bag3,hwy,us06",
    show_default=True,
    help="Comma-separated subset of ftp_bag2, ftp_bag3, hwy, us06: the engine cars' tests. The EVs (udds, "
    "hwy), full hybrids (udds_hot, hwy, us06) and mild hybrids (ftp_bag2, ftp_bag3, hwy, us06) run all of "
    "theirs.",
)
@click.option(
    "--folds",
    type=int,
    default=5,
    show_default=True,
    help="Cross-validation folds (not used with --group-by manufacturer: one fold per manufacturer).",
)
@click.option(
    "--group-by",
    "group_by",
    type=click.Choice(["family", "manufacturer", "record"]),
    default="family",
    show_default=True,
    help="What a fold holds out together: a vehicle family (same test vehicle, model and engine, or same "
    "model inputs), a manufacturer (leave one out), or single records.",
)
@click.option(
    "--seed",
    "seeds",
    type=click.IntRange(min=0),
    multiple=True,
    help="The order the groups are dealt into folds in (default: the fleet's fixed seed, "
    "vpsim.fleet.calibrate.SEED); another seed is an equally valid deal: how much the figures move with it. "
    "Given several times, each deal is written to OUT/seed_<N>/ (the technology grids and FASTSim's "
    "deal-independent runs computed once) and `vpsim fleet-deals` of them to OUT/deals.json and deals.png.",
)
@click.option(
    "--deal",
    type=click.Choice(["shuffle", "hash", "blocks"]),
    default="shuffle",
    show_default=True,
    help="How the groups are dealt into folds: shuffled with the seed and dealt to the emptiest fold (the "
    "headline's: balanced folds); each group to the fold a hash of the seed and its own name gives (folds "
    "balanced on average; a family the list gains or loses moves no other family); or the groups in the "
    "order of that hash cut into blocks of equal records (balanced folds; a family gained or lost moves "
    'only a few at the blocks\' edges). docs/fleet.md, "How sure the comparison is".',
)
@click.option("--method", type=click.Choice(["backward", "forward"]), default="backward", show_default=True)
@click.option("--local-cluster", "local_cluster", type=int, default=None, help="Run on N local Dask workers.")
@click.option("--scheduler", default=None, help="Run on the Dask scheduler at this address.")
@click.option(
    "--workers",
    type=int,
    default=None,
    help="Local processes without Dask (default: the cores, for fleets of 256+ vehicles; 1: this process).",
)
@click.option("--no-peer", "no_peer", is_flag=True, help="Do not run FASTSim beside vpsim.")
@click.option(
    "--no-peer-cache",
    "no_peer_cache",
    is_flag=True,
    help="Run FASTSim for every record, not reading or writing its remembered runs "
    "(vpsim.fleet.peer_cache: $VPSIM_CACHE_DIR, else ~/.cache/vpsim; VPSIM_PEER_CACHE=0 does the same).",
)
@click.option(
    "--limit",
    type=int,
    default=None,
    help="Only the first N usable vehicles (a quick look; exclusions: whole file).",
)
@click.option("--quiet", is_flag=True, help="No progress on stderr.")
def fleet(
    file,
    out,
    cycles,
    folds,
    group_by,
    seeds,
    deal,
    method,
    local_cluster,
    scheduler,
    workers,
    no_peer,
    no_peer_cache,
    limit,
    quiet,
):
    """Predict the measured fuel economy of the vehicles of an EPA test car list FILE."""
    import os

    import matplotlib

    matplotlib.use("Agg")
    from ..errors import VpsimError
    from ..fleet.calibrate import SEED
    from ..fleet.report import prepare_output_folder, summary_lines, write_outputs
    from ..fleet.run import run_fleet

    if no_peer_cache:  # (in the environment: worker processes started from here read it too)
        os.environ["VPSIM_PEER_CACHE"] = "0"
    names = tuple(c.strip() for c in cycles.split(",") if c.strip())
    twice = sorted({c for c in names if names.count(c) > 1})
    if twice:
        raise VpsimError(f"--cycles names {', '.join(twice)} more than once; give each cycle once")
    if limit is not None and limit < 1:
        raise VpsimError(f"--limit {limit}: expected a positive number of vehicles")
    options = dict(
        cycles=names,
        folds=folds,
        method=method,
        local_cluster=local_cluster,
        scheduler=scheduler,
        progress=not quiet,
        limit=limit,
        peer=not no_peer,
        workers=workers,
        group_by=group_by,
        deal=deal,
    )
    if len(seeds) > 1:
        return _several_deals(file, out, seeds, options)
    prepare_output_folder(out, [file])  # before the work: a folder that cannot be written fails now
    run = run_fleet(file, **options, seed=seeds[0] if seeds else SEED)
    s, info = write_outputs(run, out, command=_command())
    click.echo("\n".join(summary_lines(s, info, names)))
    click.echo(
        f"wrote {out}/vehicles.csv, vehicles_ev.csv, vehicles_hev.csv, summary.json, run.json, report.md, "
        "excluded.csv, technology.json, figures"
    )


def _several_deals(file, out, seeds, options: dict):
    """`vpsim fleet ... --seed A --seed B ...`: each deal into OUT/seed_<N>/, one memory of chunk results
    across them (vpsim.fleet.run._Remembering), then the deals side by side (vpsim.fleet.deals)."""
    import time
    from pathlib import Path

    from ..errors import VpsimError
    from ..fleet.deals import compare_deals
    from ..fleet.report import prepare_output_folder, write_outputs
    from ..fleet.run import run_fleet

    twice = sorted({s for s in seeds if seeds.count(s) > 1})
    if twice:
        raise VpsimError(f"--seed {', '.join(map(str, twice))} given more than once; give each deal once")
    if options["group_by"] == "manufacturer":  # one fold per manufacturer: every seed deals alike
        raise VpsimError("--group-by manufacturer has one deal (a fold per manufacturer): give one --seed")
    folders = [Path(out) / f"seed_{s}" for s in seeds]
    for f in folders:
        prepare_output_folder(f, [file])
    memory: dict = {}
    for seed, folder in zip(seeds, folders, strict=True):
        t0 = time.perf_counter()
        run = run_fleet(file, **options, seed=seed, memory=memory)
        write_outputs(run, folder, command=_command(f"the deal --seed {seed} of"))
        click.echo(f"seed {seed}: wrote {folder} ({time.perf_counter() - t0:.0f} s)")
    comparison = compare_deals(folders)
    (Path(out) / "deals.json").write_text(dumps(comparison.as_dict()) + "\n")
    save_plot(comparison.plot, str(Path(out) / "deals.png"))
    click.echo(str(comparison))
    click.echo(f"wrote {out}/deals.json, deals.png")


def _command(prefix: str = "") -> str:
    """The command line that ran (for report.md), when this process was started as `vpsim fleet`."""
    if sys.argv[1:2] != ["fleet"]:
        return ""
    line = "vpsim fleet " + " ".join(shlex.quote(a) for a in sys.argv[2:])
    return f"{prefix} {line}" if prefix else line


@cli.command("fleet-deals")
@click.argument("folders", nargs=-1, type=click.Path(file_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option(
    "--plot",
    "plot",
    default=None,
    type=click.Path(dir_okay=False),
    help="Write a figure: each deal's difference from FASTSim with its interval, and the pooled interval.",
)
def fleet_deals(folders, as_json, plot):
    """vpsim against the calibrated FASTSim over several deals of families into folds: FOLDERS are the
    output folders of `vpsim fleet FILE --out DIR --seed N`, one per seed (docs/fleet.md, "How sure the
    comparison is")."""
    from ..fleet.deals import compare_deals

    comparison = compare_deals(folders)
    if plot:
        save_plot(comparison.plot, plot)
    click.echo(dumps(comparison.as_dict()) if as_json else str(comparison))
