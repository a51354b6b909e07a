"""benchmarks/ab_forward.py: two source trees' forward kernels timed against each other in one process."""

from __future__ import annotations

from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"


def test_ab_forward_times_two_copies_and_compares_their_runs(benchmark_script, tmp_path, capsys):
    """The same tree as A and B: two packages of their own names, compiled and run side by side; the runs
    agree (steps and evaluations "the same", fuel to the last digit) and the pair ratio is a number."""
    ab = benchmark_script("ab_forward")
    assert (
        ab.main([str(SRC), str(SRC / "vpsim"), "--cycles", "nedc", "--runs", "3", "--scratch", str(tmp_path)])
        == 0
    )
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("nedc: "))
    assert "(the same)" in line and "relative difference 0.0e+00" in line, line
    ratio = float(line.split("B/A ")[1].split()[0])
    assert 0.0 < ratio < 100.0
    assert (tmp_path / "vpsim_a" / "methods" / "forward.py").is_file()


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
