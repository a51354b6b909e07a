"""Every example in the README and docs/ runs: Python blocks are executed, `vpsim ...` lines are invoked.

Here in this process, with whatever is installed; ``test_readme_fresh_venv.py`` runs the same shell commands
in a fresh virtual environment after the README's install line.

Files the examples name as a user's own (``my_trip.csv``, ``my_car.toml``) are created in a scratch folder
first: the TOML from the README's own block, the trip as a short speed trace.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import textwrap
from pathlib import Path

import pytest

from vpsim.cli.main import main

REPO = Path(__file__).resolve().parents[1]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
FENCE = re.compile(r"^[ \t]*```(\w+)\n(.*?)^[ \t]*```", re.S | re.M)
# commands that install or test rather than use vpsim, and the long study runs that have their own tests
SKIP_PREFIXES = ("pip ", "pytest", "python -m pytest", "cd ", "git ")


def _blocks(lang):
    for doc in DOCS:
        for m in FENCE.finditer(doc.read_text()):
            if m.group(1) == lang:
                yield pytest.param(
                    doc,
                    textwrap.dedent(m.group(2)),
                    id=f"{doc.name}:{doc.read_text()[: m.start()].count(chr(10)) + 1}",
                )


def shell_commands(langs=("bash",)):
    """Every command of the fenced blocks in ``langs``: (doc, line number, command, block language).

    A line is split at ``&&``; comments are dropped. Install and test commands (``SKIP_PREFIXES``) are
    included: the caller decides what to do with them.
    """
    for doc in DOCS:
        text = doc.read_text()
        for m in FENCE.finditer(text):
            if m.group(1) not in langs:
                continue
            first = text[: m.start(2)].count("\n") + 1
            lines = textwrap.dedent(m.group(2)).splitlines()
            for k, line in enumerate(lines):
                if k and lines[k - 1].rstrip().endswith("\\"):
                    continue  # joined to the line it continues
                j = k
                while line.rstrip().endswith("\\") and j + 1 < len(lines):
                    j += 1
                    line = line.rstrip()[:-1] + " " + lines[j].strip()
                cmd = line.split("#", 1)[0].strip()
                for part in (p.strip() for p in cmd.split("&&")):
                    if part:
                        yield doc, first + k, part, m.group(1)


def make_scratch(path: Path) -> Path:
    """A user's working folder: the examples, and the files the README names as the user's own."""
    shutil.copytree(REPO / "examples", path / "examples")
    toml = next(
        textwrap.dedent(m.group(2))
        for m in FENCE.finditer((REPO / "README.md").read_text())
        if m.group(1) == "toml"
    )
    (path / "my_car.toml").write_text(toml)
    (path / "my_trip.csv").write_text(
        "time_s,speed_kmh\n" + "".join(f"{t},{min(t, 40 - t, 10) * 5}\n" for t in range(41))
    )
    return path


@pytest.fixture
def scratch(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return make_scratch(tmp_path)


@pytest.mark.parametrize(("doc", "code"), list(_blocks("python")))
def test_python_examples_run(scratch, doc, code):
    import matplotlib.pyplot as plt

    exec(compile(code, str(doc), "exec"), {"__name__": "__doc_example__"})
    plt.close("all")


@pytest.mark.parametrize(("doc", "code"), list(_blocks("bash")))
def test_shell_examples_run(scratch, doc, code, capsys):
    ran = 0
    for line in code.splitlines():
        cmd = line.split("#", 1)[0].strip()
        for part in (p.strip() for p in cmd.split("&&")):
            if not part or part.startswith(SKIP_PREFIXES):
                continue
            args = shlex.split(part)
            assert args[0] == "vpsim", f"{doc.name}: unexpected command {part!r}"
            code_ = main(args[1:])
            out, err = capsys.readouterr()
            assert code_ == 0, f"{part}: {err}"
            ran += 1
    assert ran or "pip install" in code, "a shell block with nothing to run"
    assert os.getcwd() == str(scratch)
