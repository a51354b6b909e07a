"""benchmarks/ab_forward.py: two source trees' forward kernels timed against each other in one process."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

SRC = Path(__file__).resolve().parents[1] / "src"


def test_ab_forward_times_two_copies_and_compares_their_runs(tmp_path):
    """The same tree as A and B: two packages of their own names, imported and run side by side; the runs
    agree (steps and evaluations "the same", fuel to the last digit) and the pair ratio is a number. Run with
    Numba's JIT off (``NUMBA_DISABLE_JIT=1``): compiling two renamed copies of the forward kernel took 2-5
    minutes of CI, and what is tested here is the script's copying, capture and comparison, not the kernel's
    speed (the kernels run as Python; the script's figures are only meaningful compiled)."""
    script = Path(__file__).resolve().parents[1] / "benchmarks" / "ab_forward.py"
    args = [str(SRC), str(SRC / "vpsim"), "--cycles", "us06", "--runs", "1", "--warmup", "0"]
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1", "PYTHONPATH": str(SRC)}
    done = subprocess.run(
        [sys.executable, str(script), *args, "--scratch", str(tmp_path)],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    line = next(x for x in done.stdout.splitlines() if x.startswith("us06: "))
    assert "(the same)" in line and "relative difference 0.0e+00" in line, line
    ratio = float(line.split("B/A ")[1].split()[0])
    assert 0.0 < ratio < 100.0
    assert (tmp_path / "vpsim_a" / "methods" / "forward.py").is_file()


def test_ab_forward_refuses_a_negative_warmup(benchmark_script, tmp_path):
    ab = benchmark_script("ab_forward")
    with pytest.raises(SystemExit):
        ab.main([str(SRC), str(SRC), "--warmup", "-1", "--scratch", str(tmp_path)])


def test_ab_forward_refuses_a_folder_without_vpsim(benchmark_script, tmp_path):
    ab = benchmark_script("ab_forward")
    with pytest.raises(SystemExit, match="no vpsim package here"):
        ab.main([str(tmp_path), str(SRC), "--scratch", str(tmp_path / "s")])


def test_ab_forward_says_which_cycle_it_cannot_run(benchmark_script, tmp_path):
    """An unknown cycle: one line naming it (the package's own message), no traceback."""
    ab = benchmark_script("ab_forward")
    args = [str(SRC), str(SRC), "--cycles", "no_such_cycle", "--runs", "1", "--scratch", str(tmp_path)]
    with pytest.raises(SystemExit, match="ab_forward: no_such_cycle: .*no_such_cycle"):
        ab.main(args)


def test_engine_fuel_matrix_finds_a_moved_fuel_and_a_moved_series(benchmark_script):
    """benchmarks/engine_fuel_matrix.py's comparison: identical files give nothing; a fuel moved by one part
    in 1e12 and a series changed in one run are reported, each where it happened."""
    efm = benchmark_script("engine_fuel_matrix")
    a = {
        "x/udds/backward/paper": {"fuel_kg": 0.5, "trace_miss_s": 0.0, "series_sha1": "aa", "sum_abs.v": 3.0},
        "batch/udds/paper/0": {"fuel_kg": 0.25, "trace_miss_s": 1.0},
    }
    assert efm.compare(a, a) == ((0.0, None), (0.0, None), [])
    b = {
        "x/udds/backward/paper": {"fuel_kg": 0.5, "trace_miss_s": 0.0, "series_sha1": "ab", "sum_abs.v": 3.0},
        "batch/udds/paper/0": {"fuel_kg": 0.25 * (1 + 1e-12), "trace_miss_s": 1.0},
    }
    (rf, kf), (ra, ka), moved = efm.compare(a, b)
    assert kf == "batch/udds/paper/0" and rf == pytest.approx(1e-12, rel=1e-3)
    assert ka == "batch/udds/paper/0 fuel_kg"
    assert moved == ["x/udds/backward/paper"]


def test_engine_fuel_matrix_series_figures_see_one_ulp(benchmark_script):
    """A series one ulp apart has another digest (the sum of |x| may round it away: it is the magnitude of a
    larger move, 1e-12 here)."""
    efm = benchmark_script("engine_fuel_matrix")
    x = np.linspace(0.0, 1.0, 11)
    y = x.copy()
    y[5] = np.nextafter(y[5], 2.0)
    z = x.copy()
    z[5] *= 1.0 + 1e-12
    dx, sx = efm._series_figures({"v": x, "gear": np.ones(11, int)})
    dy, _ = efm._series_figures({"v": y, "gear": np.ones(11, int)})
    _, sz = efm._series_figures({"v": z})
    assert dx != dy and "sum_abs.gear" not in sx
    assert sz["sum_abs.v"] - sx["sum_abs.v"] == pytest.approx(0.5e-12, rel=1e-3)


def test_design_first_runs_times_every_preset_three_ways(benchmark_script):
    """benchmarks/design_first_runs.py: a figure per preset for the same set, a new vehicle and (not for the
    battery-electric car) a new engine, each a positive time."""
    res = benchmark_script("design_first_runs").measure(runs=2)
    assert set(res) == {"hofman2011", "bev", "hev_p2", "hev_split", "mhev"}
    for name, row in res.items():
        keys = {"same", "new_vehicle"} | ({"new_engine"} if name != "bev" else set())
        assert set(row) == keys, name
        assert all(v > 0.0 for v in row.values()), name
