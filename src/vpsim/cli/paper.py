"""``vpsim paper``: the paper's study (Tables 1-3, Figures 2-6, tracking, inversion check, report.md)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click

from ..errors import VpsimError
from .main import cli, vehicle_option
from .simulate import _out_dir


@cli.command()
@click.option("--out", "out", required=True, type=click.Path(file_okay=False), help="Output folder.")
@vehicle_option()
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
    import matplotlib

    matplotlib.use("Agg")  # files only: the command line never opens a window

    from ..study import _scaling_function, run_study
    from .notices import announce_compilation, echo

    announce_compilation()

    if advisor_dir is not None:
        _scaling_function()  # fail before the long run if engine scaling is missing
        if not Path(advisor_dir).is_dir():
            raise VpsimError(f"--advisor-dir {advisor_dir}: no such folder")
    from ..params import load_parameters

    params = load_parameters(vehicle)  # bad input: one line, before anything is announced
    _out_dir(out)  # and if --out cannot be written
    start = time.perf_counter()
    before = _files(out)
    echo(
        f"vpsim paper: 3 methods x 2 drivers x 2 modes on NEDC and FTP-75, best of {repeats} runs each, "
        "figures and report"
        + (", engine scaling" if advisor_dir is not None else "")
        + " (10-60 s on 2 cores once compiled)"
    )
    _load_kernels(params)  # compiled (and announced) now, if ever, so the bar's rate and ETA are the study's
    with click.progressbar(length=1, label="vpsim paper", file=sys.stderr, show_pos=True) as bar:
        state = {"done": 0}

        def progress(done, total, label):
            bar.length = total
            bar.label = f"vpsim paper: {label:<40.40}"
            if done == state["done"]:  # what is running now, before it is done
                bar.render_progress()
            else:
                bar.update(done - state["done"])
            state["done"] = done

        result = run_study(out, params=params, repeats=repeats, progress=progress, advisor_dir=advisor_dir)
    click.echo(str(result))  # Table 2
    after = _files(out)
    written = {p for p, stamp in after.items() if before.get(p) != stamp} | {Path(p) for p in result.files}
    click.echo(
        f"wrote {len(written)} files into {out} in {time.perf_counter() - start:.1f} s "
        f"(see {Path(out) / 'report.md'})"
    )


def _files(folder) -> dict:
    """Every file under ``folder`` with its modification stamp: what the study wrote is what changed."""
    root = Path(folder)
    if not root.is_dir():
        return {}
    return {p: (p.stat().st_mtime_ns, p.stat().st_size) for p in root.rglob("*") if p.is_file()}


def _load_kernels(params) -> None:
    """Load every method's compiled kernels (compiling them the first time) with one short run each."""
    from ..simulation import simulate

    for method, driver in (("backward", None), ("forward", 1), ("inverse", 1)):
        simulate("nedc", method=method, params=params, driver=driver)
