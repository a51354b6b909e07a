"""Shared checks of the fuzz suite: what every answer to hostile input must look like.

An answer is either exit status 2 with exactly one line on stderr (``vpsim: error: ...``), or exit status 0
with a meaningful result: no ``nan``/``inf`` in what is printed, and ``--json`` output that is valid JSON
(``NaN`` and ``Infinity`` rejected). Never a traceback, never the last-resort ``internal error`` line.
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

from vpsim.cli.main import main

REPO = Path(__file__).resolve().parents[2]
SHARED = Path(os.environ.get("VPSIM_SHARED", REPO.parent / "shared"))  # as tests/conftest.py
NAN_WORD = re.compile(r"(?<![\w.])-?(nan|inf|infinity)(?![\w])", re.IGNORECASE)
MEMORY_LIMIT_BYTES = 4 * 1024**3  # the stated bound for any single command on hostile input


def _no_constant(token: str):
    raise ValueError(f"{token} is not JSON")


def check_json(text: str) -> object:
    """``text`` parsed as strict JSON (NaN/Infinity refused); no float in it is non-finite."""
    data = json.loads(text, parse_constant=_no_constant)

    def walk(x):
        if isinstance(x, float):
            assert math.isfinite(x), x
        elif isinstance(x, dict):
            for v in x.values():
                walk(v)
        elif isinstance(x, list):
            for v in x:
                walk(v)

    walk(data)
    return data


# the one-time notice a command prints before compiling kernels the on-disk cache lacks (vpsim.cli.notices):
# not part of an answer; an installed package has its kernels cached, a development checkout may not
COMPILE_NOTICE = re.compile(r"^vpsim: compiling .*\(one-time: cached on disk.*\n", re.MULTILINE)


def check_answer(code: int, out: str, err: str, *, as_json: bool = False) -> None:
    """The contract of every command on any input (module docstring)."""
    err = COMPILE_NOTICE.sub("", err)
    assert "Traceback" not in err and "Traceback" not in out, err
    assert "internal error" not in err, err
    if code == 0:
        assert not NAN_WORD.search(out), out
        if as_json:
            check_json(out)
    else:
        assert code == 2, (code, err)
        assert err.count("\n") == 1 and err.startswith("vpsim: error: "), repr(err)
        assert len(err) < 1200, len(err)


def run_cli(capsys, *args) -> tuple[int, str, str]:
    """Run ``vpsim ARGS`` in this process; check the answer; return (status, stdout, stderr)."""
    argv = [str(a) for a in args]
    code = main(argv)
    out, err = capsys.readouterr()
    check_answer(code, out, err, as_json="--json" in argv and argv[0] != "bench")
    return code, out, err


def child_env(**extra) -> dict:
    """The environment of a vpsim subprocess: this checkout's package whatever its working folder (with the
    relative PYTHONPATH=src the tests are run with, a subprocess in a temporary folder imported whichever
    vpsim was installed)."""
    env = dict(os.environ, **extra)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src"), *filter(None, [env.get("PYTHONPATH")])])
    return env


def run_limited(args, *, cwd: Path, timeout: float = 60.0, memory: int = MEMORY_LIMIT_BYTES):
    """Run ``python -m vpsim ARGS`` in a subprocess under an address-space limit and a time limit; check the
    answer; return the CompletedProcess. Exceeding either limit fails the test."""
    code = (
        "import resource, sys\n"
        f"resource.setrlimit(resource.RLIMIT_AS, ({memory}, {memory}))\n"
        "from vpsim.cli.main import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    env = child_env(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    p = subprocess.run(
        [sys.executable, "-c", code, *[str(a) for a in args]],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )
    check_answer(p.returncode, p.stdout, p.stderr, as_json="--json" in args)
    assert "out of memory" not in p.stderr, p.stderr  # the limit was reached: the bound did not hold
    return p
