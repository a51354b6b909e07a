"""A newcomer's first hour: the README's install line in a fresh virtual environment, then every command.

The package is installed into a new venv exactly as the README says (``pip install .`` in a copy of the
checkout, with build isolation, so a dependency missing from ``pyproject.toml`` fails here), and every
command of the README's and docs/'s ``bash`` blocks, and each ``python`` block, is run as a user would: in
a folder of their own, in a new process, with the kernels the install compiled. Each must exit 0 without a
traceback or a compilation. Commands of ``text`` blocks run too when the files they name exist
(``../shared`` ones when the
reference data is there); those naming a user's own spec or a cluster address are shown, not run.

It takes a few minutes (the install and the first compilation); deselect it with ``-m "not fresh_venv"``.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from test_docs import REPO, SKIP_PREFIXES, _blocks, make_scratch, shell_commands

# as tests/conftest.py (importing that module by name would find tests/fuzz/conftest.py first)
SHARED = Path(os.environ.get("VPSIM_SHARED", REPO.parent / "shared"))

pytestmark = pytest.mark.fresh_venv

INSTALL = "pip install ."  # the README's install line; the fixture does exactly this
TIMEOUT_S = 900
FILE_ARG = re.compile(r"\.(toml|csv|m|mat|json)$")
# bench in its few-second variant: the full and quick ones are timed runs, measured by hand
SUBSTITUTE = {("vpsim", "bench"): ["--tiny", "--no-peer"]}


def _env(venv: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "NUMBA_CACHE_DIR")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["VIRTUAL_ENV"] = str(venv)
    env.pop("MPLBACKEND", None)
    return env


@pytest.fixture(scope="module")
def fresh(tmp_path_factory):
    """A venv with vpsim installed by the README's line, and the output of the README's first command."""
    root = tmp_path_factory.mktemp("fresh_venv")
    src = root / "vpsim"
    shutil.copytree(
        REPO,
        src,
        ignore=shutil.ignore_patterns(
            ".git", "__pycache__", "build", "dist", "*.egg-info", ".*_cache", ".hypothesis", "*.nbi", "*.nbc"
        ),
    )
    venv = root / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    env = _env(venv)
    # the README's quick start, literally: install, then the main job (first run: nothing compiled yet)
    first = subprocess.run(
        ["bash", "-c", f"{INSTALL} -q && vpsim simulate --cycle nedc"],
        cwd=src,
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert first.returncode == 0, f"the README's quick start failed:\n{first.stdout}\n{first.stderr}"
    return venv, env, first


def test_readme_install_line_is_what_this_test_runs():
    commands = [c for _, _, c, _ in shell_commands() if c.startswith("pip install")]
    assert commands and commands[0] == INSTALL, commands


def test_quick_start_says_what_it_waits_for(fresh):
    _, _, first = fresh
    assert "Traceback" not in first.stdout + first.stderr
    assert "L/100 km" in first.stdout
    # the install compiled the kernels into the package (setup.py): the first run loads them, compiles none
    assert "vpsim: compiling" not in first.stderr, first.stderr


def test_install_built_every_kernel_a_command_uses(fresh):
    """Every kernel of the installed package has a cache entry from the install: none is cold."""
    venv, env, _ = fresh
    code = (
        "from vpsim.cli.notices import cold_kernels; print(cold_kernels(['backward', 'forward', 'inverse']))"
    )
    out = subprocess.run(
        [str(venv / "bin" / "python"), "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def _cases():
    for doc, line, cmd, lang in shell_commands(("bash", "text")):
        if cmd.startswith(SKIP_PREFIXES):
            continue
        args = shlex.split(cmd)
        if args[0] not in ("vpsim", "python"):
            continue
        yield pytest.param(args, lang, id=f"{doc.name}:{line}:{' '.join(args[:3])[:50]}")


@pytest.mark.parametrize(("args", "lang"), list(_cases()))
def test_command_runs_in_fresh_venv(fresh, tmp_path, args, lang):
    venv, env, _ = fresh
    work = make_scratch(tmp_path)
    if "--scheduler" in args:
        pytest.skip("needs a running Dask cluster at the address shown")
    if "--local-cluster" in args:  # (the README's install has no Dask; tests/test_sweep_*.py run these)
        pytest.skip("needs Dask, an optional extra: pip install 'vpsim[cluster]'")
    uses_shared = any("../shared" in a for a in args)
    if uses_shared:
        if not (SHARED / "data").is_dir():
            pytest.skip(f"needs the reference data at {SHARED}")
        args = [a.replace("../shared", str(SHARED)) for a in args]
    if lang == "text":
        outs = {args[k + 1] for k, a in enumerate(args[:-1]) if a == "--out"}
        missing = [a for a in args[1:] if FILE_ARG.search(a) and a not in outs and not (work / a).exists()]
        if missing:
            pytest.skip(f"names a user's own file: {', '.join(missing)}")
    args = args + SUBSTITUTE.get(tuple(args[:2]), [])
    if args[0] == "python":
        args = [str(venv / "bin" / "python"), *args[1:]]
    proc = subprocess.run(args, cwd=work, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    output = proc.stdout + proc.stderr
    assert proc.returncode == 0, f"{shlex.join(args)} exited {proc.returncode}:\n{output[-3000:]}"
    assert "Traceback" not in output, output[-3000:]
    # what the install compiled serves every command: nothing compiles on a user's first run
    assert "vpsim: compiling" not in output, output[-3000:]


@pytest.mark.parametrize(("doc", "code"), list(_blocks("python")))
def test_python_example_runs_in_fresh_venv(fresh, tmp_path, doc, code):
    """The Python examples too, with what the README's install brought (the sweep's Parquet, say)."""
    venv, env, _ = fresh
    work = make_scratch(tmp_path)
    script = work / "example.py"
    script.write_text(code)
    proc = subprocess.run(
        [str(venv / "bin" / "python"), str(script)],
        cwd=work,
        env={**env, "MPLBACKEND": "Agg"},  # a script without a display, as on a server
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    output = proc.stdout + proc.stderr
    assert proc.returncode == 0 and "Traceback" not in output, f"{doc.name}:\n{output[-3000:]}"
