"""``vpsim sweep`` from the command line, the README's example, and the sweep figures."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
import pytest

from vpsim.cli.main import main
from vpsim.sweep import load_results
from vpsim.sweep.plots import pareto_front, plot_fuel_vs_displacement, plot_pareto, write_sweep_figures

matplotlib.use("Agg")

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "sweep_small.toml"


def test_readme_example_runs(tmp_path, capsys):
    out = tmp_path / "sweep_small"
    assert main(["sweep", str(EXAMPLE), "--out", str(out), "--workers", "1"]) == 0
    captured = capsys.readouterr()
    assert "41 rows: 41 computed now, 0 already present, 0 failed" in captured.out
    assert "rows/s" in captured.err and "ETA" in captured.err  # the progress bar
    df = load_results(out)
    assert len(df) == 41 and df["point_id"].is_unique and (df["cycle"] == "nedc").all()
    assert df["error"].isna().all() and np.isfinite(df["accel_0_100_s"]).all()
    assert (out / "results.parquet").is_dir() and (out / "sweep.json").is_file()
    assert (out / "fuel_vs_displacement.png").stat().st_size > 0 and (
        out / "pareto_nedc.png"
    ).stat().st_size > 0
    # again without --resume: refused, nothing touched; with --resume: nothing to do
    assert main(["sweep", str(EXAMPLE), "--out", str(out), "--workers", "1"]) == 2
    assert "--resume" in capsys.readouterr().err
    assert main(["sweep", str(EXAMPLE), "--out", str(out), "--workers", "1", "--resume", "--no-plots"]) == 0
    assert "0 computed now, 41 already present" in capsys.readouterr().out
    assert len(load_results(out, dedupe=False)) == 41


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--scheduler", "tcp://127.0.0.1:1", "--local-cluster", "2"], "exclude each other"),
        (["--workers", "2", "--local-cluster", "2"], "--workers applies to local processes"),
    ],
)
def test_option_errors_are_one_line(tmp_path, capsys, args, message):
    assert main(["sweep", str(EXAMPLE), "--out", str(tmp_path / "o"), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_spec_errors_are_one_line(tmp_path, capsys):
    spec = tmp_path / "bad.toml"
    spec.write_text('[parameters]\n"engine.bore" = { range = [80, 95], n = 3 }\n')
    assert main(["sweep", str(spec), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("vpsim: error: ") and "bad.toml" in err and "0.08" in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_pareto_front_keeps_the_non_dominated():
    df = pd.DataFrame(
        {
            "accel_0_100_s": [10.0, 11.0, 12.0, 12.0, 13.0, np.inf, 9.0],
            "fuel_l_per_100km": [9.0, 8.0, 8.5, 7.0, 7.5, 5.0, np.nan],
        }
    )
    front = pareto_front(df)
    assert list(front.index) == [0, 1, 3]


def test_figures_mark_the_baseline(tmp_path):
    rng = np.random.default_rng(0)
    n = 30
    df = pd.DataFrame(
        {
            "cycle": ["nedc"] * n + ["ftp75"] * n,
            "method": "backward",
            "driver": "",
            "is_baseline": ([True] + [False] * (n - 1)) * 2,
            "displacement_l": np.tile(rng.uniform(1.0, 2.5, n), 2),
            "fuel_l_per_100km": rng.uniform(6, 10, 2 * n),
            "accel_0_100_s": np.tile(rng.uniform(8, 20, n), 2),
            "error": [None] * (2 * n),
        }
    )
    df.loc[5, "error"] = "ParameterError: x"
    ax = plot_fuel_vs_displacement(df)
    assert {t.get_text() for t in ax.get_legend().get_texts()} == {"nedc", "ftp75", "baseline"}
    ax, front = plot_pareto(df, cycle="ftp75")
    assert "baseline" in [t.get_text() for t in ax.get_legend().get_texts()]
    assert (front["cycle"] == "ftp75").all() and len(front) >= 1
    written = write_sweep_figures(df, tmp_path)
    assert [p.name for p in written] == ["fuel_vs_displacement.png", "pareto_nedc.png", "pareto_ftp75.png"]
    import matplotlib.pyplot as plt

    plt.close("all")


def _without(monkeypatch, *modules):
    import vpsim.cli.sweep as cli_sweep

    real = cli_sweep._installed
    monkeypatch.setattr(cli_sweep, "_installed", lambda m: m not in modules and real(m))


def test_without_pyarrow_a_new_sweep_writes_csv_and_says_so(tmp_path, capsys, monkeypatch):
    _without(monkeypatch, "pyarrow")
    out = tmp_path / "s"
    assert main(["sweep", str(EXAMPLE), "--out", str(out), "--workers", "1", "--no-plots"]) == 0
    err = capsys.readouterr().err
    assert "pyarrow is not installed: writing results.csv instead of Parquet" in err
    assert (out / "results.csv").is_file() and not (out / "results.parquet").exists()


@pytest.mark.parametrize(
    ("missing", "args", "message"),
    [
        ("pyarrow", ["--format", "parquet"], "--format parquet needs pyarrow"),
        ("dask.distributed", ["--local-cluster", "2"], "pip install 'vpsim[cluster]'"),
    ],
)
def test_missing_packages_are_refused_before_computing(tmp_path, capsys, monkeypatch, missing, args, message):
    _without(monkeypatch, missing)
    out = tmp_path / "s"
    assert main(["sweep", str(EXAMPLE), "--out", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not out.exists()  # refused before the output folder was made, let alone anything computed


def test_without_dask_at_all_local_cluster_is_one_line(tmp_path, capsys, monkeypatch):
    """Without the dask package (not only dask.distributed), find_spec("dask.distributed") raises instead of
    returning None: that was an internal error (exit 3) in a fresh install."""
    import importlib.util

    real = importlib.util.find_spec

    def find_spec(name, *a, **k):
        if name.split(".")[0] == "dask":
            raise ModuleNotFoundError("No module named 'dask'", name="dask")
        return real(name, *a, **k)

    monkeypatch.setattr(importlib.util, "find_spec", find_spec)
    out = tmp_path / "s"
    assert main(["sweep", str(EXAMPLE), "--out", str(out), "--local-cluster", "2"]) == 2
    err = capsys.readouterr().err
    assert "need Dask: pip install 'vpsim[cluster]'" in err and err.count("\n") == 1
