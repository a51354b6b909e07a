"""``vpsim sweep``: a design-space sweep from a TOML spec, on local cores or a Dask cluster, resumable."""

from __future__ import annotations

import re
import sys
import time

import click

from ..errors import VpsimError
from .main import cli


class _Progress:
    """A one-line progress bar on stderr with rate and ETA (a line every few seconds when not a terminal)."""

    def __init__(self, enabled: bool = True, width: int = 28, banner: str = ""):
        self.enabled = enabled
        self.banner = banner  # printed when the work starts, so that an error before it stays one line
        self.width = width
        self.tty = sys.stderr.isatty()
        self.t0 = None
        self.last = -1e9
        self.total = 0

    def __call__(self, done: int, total: int) -> None:
        if self.enabled and self.banner:
            click.echo(self.banner, err=True)
            self.banner = ""
        if not self.enabled or total == 0:
            return
        self.total = total
        now = time.perf_counter()
        if self.t0 is None:  # the first call comes when the work starts (after a cluster is up)
            self.t0 = now
        final = done >= total
        if not final and now - self.last < (0.2 if self.tty else 5.0):
            return
        self.last = now
        elapsed = now - self.t0
        rate = done / elapsed if elapsed > 0 and done else 0.0
        eta = (total - done) / rate if rate > 0 else float("nan")
        frac = done / total if total else 1.0
        bar = "#" * int(round(frac * self.width))
        line = (
            f"[{bar:<{self.width}}] {done}/{total} rows {frac:4.0%}  {rate:7.1f} rows/s  "
            f"ETA {_hms(eta)}  elapsed {_hms(elapsed)}"
        )
        if self.tty:
            click.echo("\r" + line, err=True, nl=final)
        else:
            click.echo(line, err=True)

    def close(self) -> None:
        if self.enabled and self.tty and self.last > -1e9:
            click.echo("", err=True)


def _hms(s: float) -> str:
    if s != s or s == float("inf"):
        return "--:--"
    s = int(round(s))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60:02d}:{s % 60:02d}"


def _installed(module: str) -> bool:
    import importlib.util

    try:  # (find_spec of "a.b" imports "a": without it, ModuleNotFoundError, not None)
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False


def _check_requirements(out, fmt, resume: bool, *, cluster: bool):
    """Check the optional packages this sweep needs before anything is computed; return the format to use.

    pyarrow is a dependency of vpsim, so it is normally present; should it be missing (an install with
    ``--no-deps``, a platform without its wheels) a new sweep writes CSV and says so in one line.
    """
    from pathlib import Path

    if cluster and not _installed("dask.distributed"):
        raise VpsimError("--scheduler and --local-cluster need Dask: pip install 'vpsim[cluster]'")
    if _installed("pyarrow"):
        return fmt
    if resume and (Path(out) / "results.parquet").exists():
        raise VpsimError(f"{out} holds Parquet results, which need pyarrow: pip install pyarrow")
    if fmt == "parquet":
        raise VpsimError("--format parquet needs pyarrow: pip install pyarrow (or use --format csv)")
    if fmt is None and not resume:
        click.echo("vpsim: pyarrow is not installed: writing results.csv instead of Parquet", err=True)
        return "csv"
    return fmt


def _announce_compilation(methods, quiet: bool) -> None:
    """Say at once if the kernels this sweep needs are not compiled yet (its workers will compile them)."""
    from .notices import announce_compilation, cold_kernels, echo

    cold = cold_kernels(methods)
    if cold and not quiet:
        echo(
            f"vpsim: compiling the {' and '.join(cold)} on first use (one-time: cached on disk for later "
            "runs; typically 10-60 s before the first rows)"
        )
    elif not quiet:
        announce_compilation()  # anything compiled in this process after all is announced when it starts


_ADDRESS = r"([a-z][a-z0-9+.-]*://)?\[?[\w.:-]+\]?:\d{1,5}"  # a Dask scheduler: [proto://]host:port


@cli.command()
@click.argument("spec", type=click.Path(dir_okay=False))
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(file_okay=False),
    help="Output folder: results.parquet (or results.csv), sweep.json, figures.",
)
@click.option("--scheduler", default=None, metavar="ADDRESS", help="Run on a Dask cluster (tcp://host:8786).")
@click.option(
    "--local-cluster",
    "local_cluster",
    type=int,
    default=None,
    metavar="N",
    help="Run on an embedded Dask LocalCluster of N single-threaded worker processes.",
)
@click.option(
    "--workers",
    type=int,
    default=None,
    metavar="N",
    help="Local worker processes (default: all cores; 1 runs in this process).",
)
@click.option("--resume", is_flag=True, help="Complete the sweep in --out: compute only the missing rows.")
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["parquet", "csv"]),
    default=None,
    help="Output format of a new sweep [default: parquet]; a resumed sweep keeps its own.",
)
@click.option(
    "--chunk-size",
    "chunk_size",
    type=int,
    default=None,
    metavar="ROWS",
    help="Rows per chunk of work (default: sized to a few tenths of a second each).",
)
@click.option(
    "--plots/--no-plots",
    default=True,
    show_default=True,
    help="Write fuel_vs_displacement.png and pareto_<cycle>.png into --out at the end.",
)
@click.option("--quiet", is_flag=True, help="No progress bar.")
def sweep(spec, out, scheduler, local_cluster, workers, resume, fmt, chunk_size, plots, quiet):
    """Run the design-space sweep described by SPEC (a TOML file); results are appended as chunks finish."""
    from ..sweep import load_spec, run_sweep

    if scheduler is not None and local_cluster is not None:
        raise VpsimError("--scheduler and --local-cluster exclude each other")
    if workers is not None and (scheduler is not None or local_cluster is not None):
        raise VpsimError("--workers applies to local processes; with a Dask cluster its workers do the work")
    if workers is not None and workers < 1:
        raise VpsimError(f"--workers {workers}: give at least 1")
    if local_cluster is not None and local_cluster < 1:
        raise VpsimError(f"--local-cluster {local_cluster}: give at least 1")
    from ..sweep.runner import max_local_workers

    for opt, n in (("--workers", workers), ("--local-cluster", local_cluster)):
        if n is not None and n > max_local_workers():
            raise VpsimError(
                f"{opt} {n}: at most {max_local_workers()} local processes (4 per core of this machine)"
            )
    if chunk_size is not None and chunk_size < 1:
        raise VpsimError(f"--chunk-size {chunk_size}: give at least 1 row")
    if scheduler is not None and not re.fullmatch(_ADDRESS, scheduler):
        raise VpsimError(f"--scheduler {scheduler!r}: expected an address such as tcp://host:8786")
    sp = load_spec(spec)
    fmt = _check_requirements(out, fmt, resume, cluster=scheduler is not None or local_cluster is not None)
    where = (
        f"Dask scheduler {scheduler}"
        if scheduler
        else (
            f"a local Dask cluster of {local_cluster} workers"
            if local_cluster
            else (
                "this process"
                if workers == 1
                else f"{workers} local worker processes"
                if workers
                else "local cores"
            )
        )
    )
    extra = " (resuming)" if resume else ""
    bar = _Progress(
        enabled=not quiet,
        banner=f"sweep {sp.name!r}: {sp.n_designs} design points{' and the baseline' if sp.baseline else ''} "
        f"x {len(sp.combos)} cycle/method/driver combinations on {where}{extra}",
    )
    _announce_compilation(sp.methods, quiet)
    try:
        run = run_sweep(
            sp,
            out,
            workers=workers,
            scheduler=scheduler,
            local_cluster=local_cluster,
            resume=resume,
            fmt=fmt,
            chunk_size=chunk_size,
            progress=bar,
        )
    except KeyboardInterrupt:
        bar.close()
        click.echo(
            f"vpsim: interrupted; the rows finished so far are kept in {out}; "
            "run the same command with --resume to complete the sweep",
            err=True,
        )
        raise
    bar.close()
    if run.damaged:
        click.echo(
            f"found {len(run.damaged)} damaged result part(s) in {out} and computed their rows again: "
            f"{run.damaged[0]}" + (f" (and {len(run.damaged) - 1} more)" if len(run.damaged) > 1 else "")
        )
    click.echo(run.rows_line())
    click.echo(f"wrote {run.path}")
    if plots and not run.results.empty:
        import matplotlib

        matplotlib.use("Agg")  # files only: the command line never opens a window

        from ..sweep.plots import write_sweep_figures

        for p in write_sweep_figures(run.results, out):
            click.echo(f"wrote {p}")
    if run.chunk_errors:
        raise VpsimError(
            f"{len(run.chunk_errors)} chunk(s) could not be computed ({run.chunk_errors[0]}); "
            "run again with --resume to retry them"
        )
