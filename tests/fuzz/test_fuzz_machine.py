"""Hostile ADVISOR motor files (MC_*.m): a valid machine with finite, non-negative losses, or one line."""

from __future__ import annotations

import numpy as np
import pytest
from _fuzz import SHARED as SHARED_ROOT
from _fuzz import check_answer, run_cli
from hypothesis import given, settings
from hypothesis import strategies as st

from vpsim.engines.machine_map import load_machine
from vpsim.errors import MachineFileError

PM49 = SHARED_ROOT / "data" / "raw" / "advisor" / "MC_PM49.m"

TOY = """mc_description='toy permanent magnet motor';
mc_map_spd=[0 100 200 300];
mc_map_trq=[-20 -10 0 10 20];
mc_eff_map=[0.5 0.5 0.5 0.5 0.5
0.80 0.85 0.5 0.85 0.80
0.85 0.90 0.5 0.90 0.85
0.86 0.91 0.5 0.91 0.86];
mc_max_trq=[20 20 15 10];
mc_max_gen_trq=-[20 20 15 10];
mc_inertia=0.02;
"""

MC_CASES = [
    ("mc_map_spd=[0 100 200 300];", "mc_map_spd=[0 100 200 1e400];", "overflows"),
    ("mc_max_trq=[20 20 15 10];", "mc_max_trq=[20 20 15 NaN];", "NaN"),
    ("mc_max_trq=[20 20 15 10];", "mc_max_trq=[20 20 15 10 5];", "expected 4"),
    ("mc_max_trq=[20 20 15 10];", "mc_max_trq=[0 0 0 0];", "zero everywhere"),
    ("mc_max_trq=[20 20 15 10];", "mc_max_trq=[20 -20 15 10];", "non-negative"),
    ("mc_max_gen_trq=-[20 20 15 10];", "mc_max_gen_trq=-[20 20 15];", "expected 4"),
    ("mc_map_trq=[-20 -10 0 10 20];", "mc_map_trq=[-20 -10 0 10 20 30];", "expected (4, 6)"),
    ("mc_map_trq=[-20 -10 0 10 20];", "mc_map_trq=[-20 -10 0 10 10];", "strictly increasing"),
    ("mc_map_spd=[0 100 200 300];", "mc_map_spd=[0 0 0 0];", "strictly increasing"),
    ("0.86 0.91 0.5 0.91 0.86];", "0.86 0.91 0.5 0.91 1.5];", "expected a fraction"),
    ("0.86 0.91 0.5 0.91 0.86];", "0.86 0.91 0.5 0.91 -0.86];", "expected a fraction"),
    ("0.86 0.91 0.5 0.91 0.86];", "0.86 0.91 0.5 0.91];", "vertical concatenation"),
    ("mc_map_spd=[0 100 200 300];", "mc_map_spd=zeros(1e6, 1e6);", "more than the limit"),
    ("mc_inertia=0.02;", "mc_inertia=-1;", "inertia"),
    ("mc_inertia=0.02;", "mc_inertia=[1 2];", "'mc_inertia' must be a number"),
    ("mc_map_spd=[0 100 200 300];", "mc_map_spd={0 100 200 300};", "must be numeric"),
]


@pytest.mark.parametrize(("old", "new", "match"), MC_CASES, ids=[f"mc{k}" for k in range(len(MC_CASES))])
def test_hostile_mc_file_one_line(tmp_path, capsys, old, new, match):
    assert old in TOY
    p = tmp_path / "MC_HOSTILE.m"
    p.write_text(TOY.replace(old, new))
    with pytest.raises(MachineFileError) as exc:
        load_machine(p)
    msg = str(exc.value)
    assert "\n" not in msg and str(p) in msg and match in msg, msg
    for command in ("import", "compare"):
        code, out, err = run_cli(capsys, "machine", command, p, "--json")
        check_answer(code, out, err, as_json=True)
        assert code == 2 and match in err


def test_toy_file_is_valid(tmp_path, capsys):
    p = tmp_path / "MC_TOY.m"
    p.write_text(TOY)
    code, out, err = run_cli(capsys, "machine", "compare", p, "--json")
    check_answer(code, out, err, as_json=True)
    assert code == 0


@settings(max_examples=150, deadline=None)
@given(
    cut=st.integers(0, len(TOY)),
    k=st.integers(0, 40),
    number=st.sampled_from(["0", "-1", "1e308", "1e-320", "2", "0.0", "-0", "Inf", "[]", "[1 2]", "'x'"]),
)
def test_mutated_mc_files_give_a_machine_or_one_line(tmp_path_factory, cut, k, number):
    """Truncate the toy file and replace its k-th number: either a machine with finite losses >= 0, or one
    MachineFileError line."""
    text = TOY[:cut]
    tokens = text.split(" ")
    if tokens:
        i = k % len(tokens)
        tokens[i] = "".join(number if c.isdigit() else c for c in tokens[i][:1]) + tokens[i][1:]
    p = tmp_path_factory.mktemp("mc") / "MC_MUT.m"
    p.write_text(" ".join(tokens))
    try:
        m = load_machine(p)
    except MachineFileError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 1100
        return
    t, w = np.meshgrid(np.linspace(-30, 30, 13), np.linspace(-10, 400, 11))
    loss = m.loss_w(t, w)
    assert np.all(np.isfinite(loss)) and np.all(loss >= 0)


@pytest.mark.skipif(not PM49.is_file(), reason=f"reference data not found at {PM49} (set VPSIM_SHARED)")
@settings(max_examples=60, deadline=None)
@given(lines=st.integers(1, 200))
def test_truncated_real_file_is_one_line_or_valid(tmp_path_factory, lines):
    text = "\n".join(PM49.read_text(encoding="latin-1").splitlines()[:lines])
    p = tmp_path_factory.mktemp("pm49") / "MC_PM49_cut.m"
    p.write_text(text)
    try:
        m = load_machine(p)
    except MachineFileError as exc:
        assert "\n" not in str(exc)
        return
    assert m.rated_power_w > 0
