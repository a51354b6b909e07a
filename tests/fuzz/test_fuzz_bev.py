"""Hostile battery-electric inputs: vehicle files, energy-storage files, cars that cannot follow the cycle.

Every answer is one line and exit 2, or a run whose figures are finite or null with a reason, and whose
misses are counted (never a traceback, a NaN or a silent clip).
"""

from __future__ import annotations

import json
import math

import pytest
from _fuzz import SHARED as SHARED_ROOT
from _fuzz import check_answer, run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vpsim.errors import ParameterError
from vpsim.model import battery as bt

_values = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6),
    st.integers(-5, 5000),
    st.sampled_from(["nmc", "lfp", "", "x" * 300, "ESS_none.m", "pm", "induction", "bev", True]),
)
_FIELDS = [
    ("battery", "cell"),
    ("battery", "cells_in_series"),
    ("battery", "cells_in_parallel"),
    ("battery", "soc_initial"),
    ("battery", "soc_min"),
    ("battery", "soc_max"),
    ("machine", "rated_power"),
    ("machine", "base_speed"),
    ("machine", "max_speed"),
    ("machine", "kind"),
    ("machine", "inertia"),
    ("electric", "accessory_power"),
    ("electric", "charger_efficiency"),
    ("electric", "regen_share"),
    ("electric", "regen_speed_low"),
    ("electric", "regen_speed_high"),
    ("transmission", "final_drive"),
    ("vehicle", "mass"),
]


def _toml(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    return repr(v)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(entries=st.lists(st.tuples(st.sampled_from(_FIELDS), _values), max_size=4))
def test_random_bev_files_are_valid_or_one_line(tmp_path, capsys, entries):
    sections: dict[str, dict[str, str]] = {}
    for (sec, name), value in entries:
        sections.setdefault(sec, {})[name] = _toml(value)
    text = 'base = "bev"\n' + "".join(
        f"[{sec}]\n" + "".join(f"{k} = {v}\n" for k, v in kv.items()) for sec, kv in sections.items()
    )
    path = tmp_path / "car.toml"
    path.write_text(text)
    code, out, _ = run_cli(capsys, "simulate", "--vehicle", path, "--cycle", "udds", "--json")
    if code == 0:
        s = json.loads(out)
        for key in ("electric_wh_per_km", "soc_end", "regen_wh"):
            assert s[key] is not None or f"{key}_undefined" in s
        assert s["soc_end"] is None or -1e-9 <= s["soc_end"] <= 1.0 + 1e-9


@pytest.mark.parametrize(
    ("section", "text"),
    [
        ("[battery]\nsoc_initial = 1.5\n", "battery.soc_initial"),
        ("[battery]\nsoc_initial = -0.1\n", "battery.soc_initial"),
        ("[battery]\ncells_in_parallel = 0\n", "cells_in_parallel"),
        ("[battery]\ncells_in_series = 2.5\n", "whole number"),
        ("[machine]\nrated_power = 0\n", "machine.rated_power"),
        ("[machine]\nkind = 3\n", "machine.kind"),
        ("[electric]\ncharger_efficiency = 0\n", "electric.charger_efficiency"),
        ('[battery]\ncell = "ESS_missing.m"\n', "no such file"),
        ('[powertrain]\ntype = "fuel cell"\n', "powertrain.type"),
    ],
)
def test_bad_bev_fields_are_one_line(tmp_path, capsys, section, text):
    path = tmp_path / "car.toml"
    path.write_text('base = "bev"\n' + section)
    code, _, err = run_cli(capsys, "simulate", "--vehicle", path, "--cycle", "udds")
    assert code == 2 and text in err


def test_a_car_that_cannot_start_is_a_counted_miss(tmp_path, capsys):
    """An envelope too weak to climb the cycle's launches: the run finishes, the miss is counted."""
    path = tmp_path / "weak.toml"
    path.write_text('base = "bev"\n[machine]\nrated_power = 1000.0\n')
    code, out, _ = run_cli(capsys, "simulate", "--vehicle", path, "--cycle", "us06", "--json")
    s = json.loads(out)
    assert code == 0 and s["trace_miss_s"] > 100 and s["machine_at_limit_s"] > 100
    code, out, _ = run_cli(
        capsys, "simulate", "--vehicle", path, "--cycle", "us06", "--method", "forward", "--json"
    )
    s = json.loads(out)
    assert code == 0 and s["speed_not_followed_s"] > 100


ESS = """ess_description='toy NiMH module';
ess_soc=[0 0.5 1];
ess_tmp=[0 25];
ess_max_ah_cap=[6 6.5];
ess_voc=[7 7.5 8; 7.1 7.6 8.1];
ess_r_dis=[0.02 0.02 0.02; 0.02 0.02 0.02];
ess_r_chg=[0.02 0.02 0.02; 0.02 0.02 0.02];
ess_min_volts=6;
ess_max_volts=9;
ess_coulombic_eff=[0.9 0.9];
"""


def test_the_toy_ess_file_is_a_cell(tmp_path):
    p = tmp_path / "ESS_TOY.m"
    p.write_text(ESS)
    cell = bt.cell_from_ess_file(p)
    assert cell.ocv_v == pytest.approx((7.1, 7.6, 8.1)) and cell.capacity_ah == pytest.approx(6.5)


ESS_CASES = [
    ("ess_soc=[0 0.5 1];", "ess_soc=[0 0.5 0.5];", "ess_soc"),
    ("ess_soc=[0 0.5 1];", "ess_soc=[0 0.5 1.5];", "ess_soc"),
    ("ess_voc=[7 7.5 8; 7.1 7.6 8.1];", "ess_voc=[7 7.5; 7.1 7.6];", "ess_voc"),
    ("ess_voc=[7 7.5 8; 7.1 7.6 8.1];", "ess_voc=[7 7.5 8; 7.1 -7.6 8.1];", "ocv_v"),
    ("ess_r_dis=[0.02 0.02 0.02; 0.02 0.02 0.02];", "ess_r_dis=[0 0 0; 0 0 0];", "resistances"),
    ("ess_min_volts=6;", "", "ess_min_volts"),
    ("ess_max_volts=9;", "ess_max_volts=5;", "v_min"),
    ("ess_max_ah_cap=[6 6.5];", "ess_max_ah_cap=[-6 -6.5];", "capacity_ah"),
    ("ess_description='toy NiMH module';", "ess_description=system('rm');", "system"),
    ("ess_r_chg=[0.02 0.02 0.02; 0.02 0.02 0.02];", "ess_r_chg=[0.02 0.02 0.02; 0.02 0.02", "ess_r_chg"),
]


@pytest.mark.parametrize(("old", "new", "text"), ESS_CASES)
def test_hostile_ess_files_are_one_line(tmp_path, capsys, old, new, text):
    ess = tmp_path / "ESS_BAD.m"
    ess.write_text(ESS.replace(old, new))
    car = tmp_path / "car.toml"
    car.write_text(
        'base = "bev"\n[battery]\ncell = "ESS_BAD.m"\ncells_in_series = 50\ncells_in_parallel = 4\n'
    )
    code, _, err = run_cli(capsys, "simulate", "--vehicle", car, "--cycle", "udds")
    assert code == 2, err
    assert "ESS_BAD.m" in err or text in err, err


def test_a_real_ess_file_drives_the_car(tmp_path, capsys):
    src = SHARED_ROOT / "data" / "raw" / "advisor" / "ESS_NIMH60_OVONIC.m"
    if not src.is_file():
        pytest.skip(f"{src} is not there (reference data)")
    car = tmp_path / "car.toml"
    car.write_text(f'base = "bev"\n[battery]\ncell = "{src}"\ncells_in_series = 28\ncells_in_parallel = 3\n')
    code, out, _ = run_cli(capsys, "simulate", "--vehicle", car, "--cycle", "udds", "--json")
    s = json.loads(out)
    assert code == 0 and math.isfinite(s["electric_wh_per_km"]) and s["soc_end"] < s["soc_start"]


def test_bad_cells_in_code_are_one_line():
    with pytest.raises(ParameterError, match="rise strictly"):
        bt.Cell("x", "x", 1.0, (0.0, 0.0), (3.0, 3.1), (0.1, 0.1), (0.1, 0.1), 2.5, 4.2, 1.0, 1.0)
    with pytest.raises(ParameterError, match="finite"):
        bt.Cell("x", "x", 1.0, (0.0, 1.0), (3.0, float("nan")), (0.1, 0.1), (0.1, 0.1), 2.5, 4.2, 1.0, 1.0)


def test_check_answer_accepts_a_bev_json(capsys):
    code, out, err = run_cli(capsys, "simulate", "--vehicle", "bev", "--cycle", "hwfet", "--json")
    check_answer(code, out, err, as_json=True)


@pytest.mark.parametrize("kind", ["fifo", "folder", "missing"])
def test_a_cell_file_that_is_not_a_file_is_named_as_such(tmp_path, capsys, kind):
    """battery.cell naming a FIFO or a folder: 'not a regular file' (it said 'no such file', and opening a
    FIFO would block)."""
    import os

    ess = tmp_path / "ESS_X.m"
    if kind == "fifo":
        os.mkfifo(ess)
    elif kind == "folder":
        ess.mkdir()
    car = tmp_path / "car.toml"
    car.write_text('base = "bev"\n[battery]\ncell = "ESS_X.m"\n')
    code, _, err = run_cli(capsys, "simulate", "--vehicle", car, "--cycle", "udds")
    assert code == 2 and ("no such file" if kind == "missing" else "not a regular file") in err, err
