"""Hostile files given where vpsim reads one: a FIFO or a device instead of a file (refused before it is
opened: opening a FIFO blocks, /dev/zero never ends), and text nested deeper than a parser recurses (one
line, never a RecursionError)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
from _fuzz import run_cli

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: the made-up list
from fleet_csv import write_list  # noqa: E402

DEEP = 100_000  # far beyond Python's recursion limit (1,000)


def _fifo(tmp_path: Path, name: str) -> Path:
    path = tmp_path / name
    os.mkfifo(path)  # nobody writes: a reader that opened it would block the test for ever
    return path


def _commands(tmp_path: Path, bad: Path) -> dict[str, list]:
    lst = write_list(tmp_path / "list.csv")
    car = tmp_path / "car.toml"
    return {
        "cycle": ["simulate", "--cycle", bad],
        "vehicle": ["simulate", "--vehicle", bad],
        "gears": ["simulate", "--gears", bad],
        "list": ["vehicle", "from-epa", bad, "--id", "T004", "--out", car],
        "technology": ["vehicle", "from-epa", lst, "--id", "T004", "--out", car, "--technology", bad],
        "fleet": ["fleet", bad, "--out", tmp_path / "o", "--no-peer", "--quiet"],
        "sweep": ["sweep", bad, "--out", tmp_path / "o"],
    }


INPUTS = ("cycle", "vehicle", "gears", "list", "technology", "fleet", "sweep")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
@pytest.mark.parametrize("which", INPUTS)
def test_a_fifo_is_refused_before_it_is_opened(tmp_path, capsys, which):
    bad = _fifo(tmp_path, "in.toml" if which in ("vehicle", "sweep") else "in.csv")
    code, _, err = run_cli(capsys, *_commands(tmp_path, bad)[which])
    assert code == 2 and "not a regular file" in err, err


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/null"])
@pytest.mark.parametrize("which", INPUTS)
def test_a_device_is_refused(tmp_path, capsys, which, device):
    if not Path(device).exists():
        pytest.skip(f"no {device} here")
    code, _, err = run_cli(capsys, *_commands(tmp_path, Path(device))[which])
    assert code == 2 and "not a regular file" in err, err


def test_a_technology_file_nested_too_deeply_is_one_line(tmp_path, capsys):
    lst = write_list(tmp_path / "list.csv")
    tech = tmp_path / "technology.json"
    tech.write_text('{"all_vehicles": ' + "[" * DEEP + "]" * DEEP + "}")
    args = ["vehicle", "from-epa", lst, "--id", "T004", "--out", tmp_path / "c.toml", "--technology", tech]
    code, _, err = run_cli(capsys, *args)
    assert code == 2 and "nested too deeply" in err


def test_a_parameter_file_nested_too_deeply_is_one_line(tmp_path, capsys):
    car = tmp_path / "car.toml"
    car.write_text("[vehicle]\nmass = " + "[" * DEEP + "]" * DEEP + "\n")
    code, _, err = run_cli(capsys, "simulate", "--vehicle", car, "--cycle", "ftp_bag2")
    assert code == 2 and "nested too deeply" in err


def test_a_record_block_nested_too_deeply_is_one_line(tmp_path):
    from vpsim.errors import VpsimError
    from vpsim.fleet.vehicle import RECORD_BEGIN, RECORD_END, read_record_block

    car = tmp_path / "car.toml"
    car.write_text(f'base = "hofman2011"\n{RECORD_BEGIN}\n# x = {"[" * DEEP}{"]" * DEEP}\n{RECORD_END}\n')
    with pytest.raises(VpsimError, match="nested too deeply"):
        read_record_block(car)


@pytest.mark.parametrize(
    "text",
    [
        "NaN",
        '{"a": Infinity}',
        "1" * 5000,  # an integer literal beyond Python's 4300 digits
        '{"a": ',
        "",
    ],
)
def test_read_json_answers_every_text_with_one_line(tmp_path, text):
    from vpsim.errors import VpsimError
    from vpsim.textio import read_json

    path = tmp_path / "x.json"
    path.write_text(text)
    with pytest.raises(VpsimError) as exc:
        read_json(path, VpsimError)
    assert "\n" not in str(exc.value) and str(path) in str(exc.value)


def test_an_unreadable_list_is_one_line(tmp_path, capsys, monkeypatch):
    import pandas as pd

    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    lst = write_list(tmp_path / "list.csv")
    monkeypatch.setattr(pd, "read_csv", denied)  # as a file without read permission (root reads any)
    code, _, err = run_cli(capsys, "vehicle", "from-epa", lst, "--id", "T004", "--out", tmp_path / "c.toml")
    assert code == 2 and "cannot read (Permission denied)" in err
