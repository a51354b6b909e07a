"""Nothing lost: kill a sweep midway (the client; one Dask worker) and resume.

Every point must end up stored exactly once, and the rows stored before the kill must be untouched by the
resume (same run id and compute time: not recomputed).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from vpsim.sweep import load_results, load_spec, plan, run_sweep

SPEC_TEXT = """
name = "kill_test"
cycles = ["nedc"]
methods = ["backward"]
[parameters]
"engine.bore" = { range = [0.080, 0.095], n = 23 }
"""


@pytest.fixture()
def spec_file(tmp_path) -> Path:
    f = tmp_path / "spec.toml"
    f.write_text(SPEC_TEXT)
    return f


def _expected_ids(spec_file: Path) -> set[str]:
    return {r[0] for t in plan(load_spec(spec_file)).tasks for r in t.rows}


def _parts(out: Path) -> list[Path]:
    return list((out / "results.parquet").glob("part-*.parquet"))


def _start(spec_file: Path, out: Path, *extra: str) -> subprocess.Popen:
    cmd = [
        sys.executable,
        "-m",
        "vpsim",
        "sweep",
        str(spec_file),
        "--out",
        str(out),
        "--chunk-size",
        "1",
        "--no-plots",
        *extra,
    ]
    # a session of its own, like a job started from a terminal: a signal can go to all of its processes; and
    # Ctrl-C's default action, as a terminal gives it: a test run started in the background of a shell without
    # job control inherits SIGINT ignored, and Python then installs no KeyboardInterrupt handler (the sweep
    # ran to the end and the Ctrl-C test saw exit 0)
    return subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def _wait_for_parts(proc: subprocess.Popen, out: Path, n: int, timeout: float = 90.0) -> None:
    t0 = time.monotonic()
    while len(_parts(out)) < n:
        if proc.poll() is not None:
            raise AssertionError(f"the sweep ended before it could be interrupted: {proc.communicate()}")
        if time.monotonic() - t0 > timeout:
            proc.kill()
            raise AssertionError("the sweep wrote no results in time")
        time.sleep(0.02)


def _check_complete_and_untouched(out: Path, spec_file: Path, before) -> None:
    raw = load_results(out, dedupe=False)
    assert raw["point_id"].is_unique, "a point was stored twice"
    assert set(raw["point_id"]) == _expected_ids(spec_file), "a point is missing"
    after = raw.set_index("point_id")
    for pid, row in before.set_index("point_id").iterrows():
        assert after.loc[pid, "run_id"] == row["run_id"]
        assert after.loc[pid, "computed_at"] == row["computed_at"]
    assert after["run_id"].nunique() == 2  # the interrupted run and the resume


def test_sigkill_of_the_client_then_resume(spec_file, tmp_path):
    out = tmp_path / "out"
    proc = _start(spec_file, out, "--workers", "1", "--quiet")
    _wait_for_parts(proc, out, 3)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    before = load_results(out, dedupe=False)
    assert 3 <= len(before) < 24
    run = run_sweep(spec_file, out, workers=1, resume=True)
    assert run.n_skipped == len(before) and run.n_computed == 24 - len(before)
    _check_complete_and_untouched(out, spec_file, before)


def test_ctrl_c_on_local_processes_then_resume_from_the_command_line(spec_file, tmp_path):
    out = tmp_path / "out"
    proc = _start(spec_file, out, "--workers", "2")
    _wait_for_parts(proc, out, 3)
    os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in a terminal does: the whole foreground group
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "--resume" in err
    before = load_results(out, dedupe=False)
    assert 3 <= len(before) < 24
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "vpsim",
            "sweep",
            str(spec_file),
            "--out",
            str(out),
            "--resume",
            "--workers",
            "1",
            "--no-plots",
            "--quiet",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert f"{len(before)} already present" in done.stdout
    _check_complete_and_untouched(out, spec_file, before)


def test_killing_a_dask_worker_loses_and_duplicates_nothing(spec_file, tmp_path):
    from dask.distributed import Client, LocalCluster

    out = tmp_path / "out"
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster,
        Client(cluster) as client,
    ):
        pids = sorted(client.run(os.getpid).values())
        killed = []

        def progress(done: int, total: int) -> None:
            if done > 0 and not killed:  # a chunk is stored, the others are in flight on both workers
                os.kill(pids[0], signal.SIGKILL)
                killed.append(pids[0])

        run = run_sweep(spec_file, out, scheduler=cluster.scheduler_address, chunk_size=1, progress=progress)
    assert killed and run.chunk_errors == []
    raw = load_results(out, dedupe=False)
    assert raw["point_id"].is_unique
    assert set(raw["point_id"]) == _expected_ids(spec_file)
    assert raw["error"].isna().all()
    workers = {w.rsplit(":", 1)[1] for w in raw["worker"]}
    assert str(pids[1]) in workers and len(workers) >= 2
