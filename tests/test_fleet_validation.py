"""Honest validation of the fleet: folds that hold out whole families or manufacturers, the constants chosen
on the list declared, fitted values on their bounds reported, and a peer calibrated the way vpsim is."""

from __future__ import annotations

import hashlib
import importlib
import json
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet_csv import write_list
from vpsim.cli.main import main
from vpsim.errors import VpsimError
from vpsim.fleet import calibrate as cal
from vpsim.fleet import peer
from vpsim.fleet.epa import read_test_car_list
from vpsim.fleet.run import run_fleet
from vpsim.fleet.tuned import TUNED_ON_THIS_LIST

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def cars(tmp_path_factory):
    return read_test_car_list(write_list(tmp_path_factory.mktemp("list") / "list.csv", bad_rows=False))


def test_family_groups_join_configurations_models_and_twins(cars):
    vs = list(cars.vehicles)
    a = vs[0]
    sibling = replace(a, configuration=a.configuration + 7, etw_lb=a.etw_lb + 250)  # same test vehicle
    same_model = replace(
        vs[1],
        vehicle_id="X900",
        model=a.model,
        displacement_l=a.displacement_l,
        cylinders=a.cylinders,
        manufacturer=a.manufacturer,
    )  # same make, model, engine
    twin = replace(vs[2], vehicle_id="X901", model="Other", manufacturer="Else")  # same inputs as vs[2]
    groups = cal.vehicle_groups([*vs, sibling, same_model, twin], "family")
    assert groups[sibling.key] == groups[a.key] == groups[same_model.key]
    assert groups[twin.key] == groups[vs[2].key]
    assert groups[vs[3].key] != groups[a.key]
    assert cal.vehicle_groups(vs, "record") == {v.key: v.key for v in vs}
    by_maker = cal.vehicle_groups(vs, "manufacturer")
    assert len(set(by_maker.values())) == len({v.manufacturer.upper() for v in vs})
    with pytest.raises(ValueError, match="unknown grouping"):
        cal.vehicle_groups(vs, "make")


def test_a_group_always_shares_a_fold_and_record_folds_are_as_before():
    keys = [f"V{i}#0" for i in range(40)]
    groups = {k: f"G{i // 3}" for i, k in enumerate(keys)}  # groups of 3
    folds = cal.assign_folds(keys, 4, groups=groups)
    for g in set(groups.values()):
        assert len({folds[k] for k in keys if groups[k] == g}) == 1
    sizes = np.bincount(list(folds.values()))
    assert sizes.sum() == 40 and sizes.max() - sizes.min() <= 3  # balanced to within one group
    # one record per group: the round-robin deal of a shuffled order (the folds of earlier versions)
    order = sorted(keys)
    perm = np.random.default_rng(cal.SEED).permutation(len(order))
    assert cal.assign_folds(keys, 5) == {order[j]: i % 5 for i, j in enumerate(perm)}
    with pytest.raises(ValueError, match="cannot fill"):
        cal.assign_folds(keys[:6], 4, groups={k: "one" if i < 4 else "two" for i, k in enumerate(keys[:6])})


def _sha_fold(label: str, k: int, seed: int) -> int:
    """The hash deal's fold by hand: SHA-256 of "<seed>:<label>", first 8 bytes big-endian, mod k."""
    return int.from_bytes(hashlib.sha256(f"{seed}:{label}".encode()).digest()[:8], "big") % k


def test_the_hash_deal_keeps_every_familys_fold_when_others_come_or_go():
    """deal="hash": each group's fold is the hand formula's, its records together, whatever the input order;
    three groups fewer move no other group, where the shuffle deal moves most of them."""
    keys = [f"V{i}#0" for i in range(300)]
    groups = {k: f"G{i // 3}" for i, k in enumerate(keys)}
    full = cal.assign_folds(keys, 5, groups=groups, deal="hash")
    assert full == {k: _sha_fold(groups[k], 5, cal.SEED) for k in keys}
    assert cal.assign_folds(list(reversed(keys)), 5, groups=groups, deal="hash") == full
    assert cal.assign_folds(keys, 5, seed=7, groups=groups, deal="hash") == {
        k: _sha_fold(groups[k], 5, 7) for k in keys
    }
    fewer = [k for k in keys if groups[k] not in {"G0", "G50", "G99"}]
    assert {k: full[k] for k in fewer} == cal.assign_folds(fewer, 5, groups=groups, deal="hash")
    shuffled, shuffled_fewer = (
        cal.assign_folds(keys, 5, groups=groups),
        cal.assign_folds(fewer, 5, groups=groups),
    )
    assert sum(shuffled[k] != shuffled_fewer[k] for k in fewer) > len(fewer) / 2
    sizes = np.bincount(list(full.values()), minlength=5)
    assert sizes.min() > 0 and sizes.sum() == 300  # balanced on average only: 100 groups of 3 in 5 folds
    with pytest.raises(ValueError, match="deal 'deck': expected one of shuffle, hash"):
        cal.assign_folds(keys, 5, groups=groups, deal="deck")


def test_a_hash_deal_that_leaves_a_fold_empty_is_refused():
    labels = ["A", "B", "C", "D", "E"]
    seed = next(s for s in range(100) if len({_sha_fold(x, 5, s) for x in labels}) < 5)
    empty = sorted(set(range(5)) - {_sha_fold(x, 5, seed) for x in labels})
    with pytest.raises(ValueError, match=f"leaves fold\\(s\\) {', '.join(map(str, empty))} of 5 empty"):
        cal.assign_folds(labels, 5, seed=seed, deal="hash")


@settings(max_examples=60, deadline=None)
@given(
    st.sets(st.text(min_size=1, max_size=12), min_size=12, max_size=60),
    st.integers(min_value=0, max_value=2**31),
    st.data(),
)
def test_hash_folds_depend_on_the_group_alone(labels, seed, data):
    labels = sorted(labels)
    keep = data.draw(st.lists(st.sampled_from(labels), min_size=3, unique=True))
    k = 3
    try:
        full = cal.assign_folds(labels, k, seed=seed, deal="hash")
    except ValueError:  # a fold left empty by this draw: refused, as tested above
        return
    try:
        part = cal.assign_folds(keep, k, seed=seed, deal="hash")
    except ValueError:
        return
    assert part == {x: full[x] for x in keep}


def _blocks_by_hand(sizes: dict[str, int], k: int, seed: int) -> dict[str, int]:
    """The blocks deal by hand: groups sorted by the 8-byte SHA-256 integer of "<seed>:<label>", each to the
    block of ``k`` equal shares of the records its middle record falls in (exact fractions)."""
    from fractions import Fraction

    def place(label):
        return int.from_bytes(hashlib.sha256(f"{seed}:{label}".encode()).digest()[:8], "big"), label

    total, before, out = sum(sizes.values()), 0, {}
    for label in sorted(sizes, key=place):
        middle = Fraction(before) + Fraction(sizes[label], 2)
        out[label] = math.floor(middle * k / total)
        before += sizes[label]
    return out


def test_the_blocks_deal_cuts_the_hash_order_into_folds_of_equal_records():
    """deal="blocks": the hand formula's folds, whole groups, whatever the input order; the folds within one
    group's records of a fifth of the list, where the hash deal's are not; three groups fewer move only a
    few groups at the blocks' edges, where the shuffle deal moves most of them."""
    keys = [f"V{i}#0" for i in range(300)]
    groups = {k: f"G{i // 3}" if i < 240 else f"H{i}" for i, k in enumerate(keys)}  # 80 of 3, 60 of 1
    sizes = {g: sum(1 for k in keys if groups[k] == g) for g in set(groups.values())}
    full = cal.assign_folds(keys, 5, groups=groups, deal="blocks")
    hand = _blocks_by_hand(sizes, 5, cal.SEED)
    assert full == {k: hand[groups[k]] for k in keys}
    assert cal.assign_folds(list(reversed(keys)), 5, groups=groups, deal="blocks") == full
    assert np.all(np.abs(np.bincount(list(full.values()), minlength=5) - 60) <= 3)
    hashed = np.bincount(list(cal.assign_folds(keys, 5, groups=groups, deal="hash").values()), minlength=5)
    assert np.abs(hashed - 60).max() > 3  # (this list's hash deal: a fold 4 or more records off its share)
    fewer = [k for k in keys if groups[k] not in {"G0", "G50", "H299"}]
    after = cal.assign_folds(fewer, 5, groups=groups, deal="blocks")
    moved = {groups[k] for k in fewer if after[k] != full[k]}
    assert 0 < len(moved) <= 4 * (7 + 1)  # 7 records fewer: at most 8 groups at each of the 4 edges
    shuffled, shuffled_fewer = (
        cal.assign_folds(keys, 5, groups=groups),
        cal.assign_folds(fewer, 5, groups=groups),
    )
    assert sum(shuffled[k] != shuffled_fewer[k] for k in fewer) > len(fewer) / 2


def test_a_blocks_deal_with_a_group_larger_than_a_folds_share_is_refused():
    """Four groups into four folds, one of them three folds' share: in any order two share a block."""
    keys = [f"V{i}" for i in range(12)]
    groups = {k: "big" if i < 9 else f"small{i}" for i, k in enumerate(keys)}
    for seed in (cal.SEED, 1, 2):
        with pytest.raises(
            ValueError, match=rf"the blocks deal with seed {seed} leaves fold\(s\) .* of 4 empty"
        ):
            cal.assign_folds(keys, 4, seed=seed, groups=groups, deal="blocks")


@settings(max_examples=80, deadline=None)
@given(
    st.dictionaries(st.text(min_size=1, max_size=8), st.integers(1, 6), min_size=8, max_size=40),
    st.integers(min_value=0, max_value=2**31),
    st.integers(2, 5),
    st.data(),
)
def test_blocks_folds_are_balanced_and_a_group_more_moves_few_others(sizes, seed, k, data):
    """Every fold within the largest group's records of its share; one group more (s records) moves at most
    s + 1 other groups at each of the k - 1 edges between blocks."""
    keys = [f"{g}\x00{j}" for g, n in sizes.items() for j in range(n)]
    groups = {key: key.split("\x00")[0] for key in keys}
    new = data.draw(st.sampled_from(sorted(sizes)))
    rest = [key for key in keys if groups[key] != new]
    try:
        full = cal.assign_folds(keys, k, seed=seed, groups=groups, deal="blocks")
        part = cal.assign_folds(rest, k, seed=seed, groups=groups, deal="blocks")
    except ValueError as exc:  # a fold left empty: refused, as tested above
        assert "empty" in str(exc)
        return
    counts = np.bincount(list(full.values()), minlength=k)
    assert np.all(np.abs(counts - len(keys) / k) <= max(sizes.values()))
    moved = {groups[key] for key in rest if part[key] != full[key]}
    assert len(moved) <= (k - 1) * (sizes[new] + 1)


def test_leave_one_manufacturer_out_predicts_each_maker_from_the_others(tmp_path):
    run = run_fleet(
        write_list(tmp_path / "l.csv", bad_rows=False), group_by="manufacturer", peer=False, cycles=("hwy",)
    )
    df = run.frame()
    assert run.grouping == "manufacturer" and run.folds == run.n_groups == df["make"].str.upper().nunique()
    assert df.groupby("fold")["make"].nunique().max() == 1  # one maker per fold
    for name, t in run.technology.items():
        fold, cls = name.split(".")
        if t["basis"] == "class":  # fitted on the other makers' vehicles of its class, none of its own
            others = df[(df["fold"] != int(fold[4:])) & (df["technology_class"] == cls)]
            assert t["n_train"] == len(others)


def test_summary_declares_the_validation(tmp_path, capsys):
    out = tmp_path / "o"
    lst = write_list(tmp_path / "list.csv", bad_rows=False)
    assert (
        main(
            [
                "fleet",
                str(lst),
                "--out",
                str(out),
                "--folds",
                "3",
                "--cycles",
                "hwy",
                "--no-peer",
                "--quiet",
                "--group-by",
                "family",
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "held out by family: 3 folds" in text
    s = json.loads((out / "summary.json").read_text())
    v = s["validation"]
    assert v["grouping"] == "family" and v["folds"] == 3 and v["groups"] >= 3
    assert v["seed"] == cal.SEED  # the fleet's own deal unless --seed says otherwise
    assert v["tuned_on_this_list"] == [dict(t) for t in TUNED_ON_THIS_LIST]
    report = (out / "report.md").read_text()
    assert "Constants chosen while looking at this list" in report
    assert "holding out whole vehicle families" in report
    assert f"shuffled with seed {cal.SEED} and dealt to the emptiest fold" in report
    tech = json.loads((out / "technology.json").read_text())
    assert set(tech["search_bounds"]) == set(cal.TECH_PARAMS)
    for fit, hits in tech["on_search_bound"].items():
        for par, h in hits.items():
            lo, hi = tech["search_bounds"][par]
            assert h["value"] == (lo if h["bound"] == "low" else hi) and h["reason"], (fit, par)
    assert main(["fleet", str(lst), "--out", str(out), "--group-by", "maker"]) == 2
    assert "'maker' is not one of" in capsys.readouterr().err


def test_another_seed_deals_the_families_anew_and_says_so(tmp_path, capsys):
    """``vpsim fleet --seed N``: the same families into other folds (each still whole), the seed in
    summary.json and on the screen; a negative or non-integer seed is one line, exit 2."""
    lst = write_list(tmp_path / "list.csv", bad_rows=False)
    base = run_fleet(lst, cycles=("hwy",), folds=3, peer=False, workers=1)
    other = run_fleet(lst, cycles=("hwy",), folds=3, peer=False, workers=1, seed=7)
    fold = {r["vehicle_id"]: r["fold"] for r in base.rows}
    fold7 = {r["vehicle_id"]: r["fold"] for r in other.rows}
    assert set(fold) == set(fold7) and fold != fold7
    groups = cal.vehicle_groups(base.cars.vehicles, "family")
    for members in {g: [k for k, x in groups.items() if x == g] for g in set(groups.values())}.values():
        assert len({fold7[k.split("#")[0]] for k in members}) == 1
    assert base.seed == cal.SEED and other.seed == 7
    out = tmp_path / "o"
    args = ["fleet", str(lst), "--out", str(out), "--folds", "3", "--cycles", "hwy", "--no-peer", "--quiet"]
    assert main([*args, "--seed", "7"]) == 0
    assert f"dealt with seed 7 (the fleet's: {cal.SEED})" in capsys.readouterr().out
    assert json.loads((out / "summary.json").read_text())["validation"]["seed"] == 7
    assert main([*args, "--seed", "-1"]) == 2
    assert "--seed" in capsys.readouterr().err
    with pytest.raises(VpsimError, match="--seed 1.5: expected a whole number"):
        run_fleet(lst, cycles=("hwy",), folds=3, peer=False, workers=1, seed=1.5)


def test_fleet_with_the_hash_deal_says_so_and_keeps_whole_families(tmp_path, capsys):
    """``vpsim fleet --deal hash``: every row's fold is its family's hash fold, the deal in summary.json and
    on the screen; with --group-by manufacturer (a fold per maker) it is one line, exit 2."""
    lst = write_list(tmp_path / "list.csv", bad_rows=False)
    out = tmp_path / "o"
    args = ["fleet", str(lst), "--out", str(out), "--folds", "3", "--cycles", "hwy", "--no-peer", "--quiet"]
    assert main([*args, "--deal", "hash"]) == 0
    assert "hash deal (the headline's: shuffle)" in capsys.readouterr().out
    v = json.loads((out / "summary.json").read_text())["validation"]
    assert v["deal"] == "hash" and v["seed"] == cal.SEED
    assert f"each to the fold a hash of seed {cal.SEED} and its name picks" in (out / "report.md").read_text()
    rows = pd.read_csv(out / "vehicles.csv")
    assert len(rows) > 0
    assert list(rows["fold"]) == [_sha_fold(f, 3, cal.SEED) for f in rows["family"]]
    assert main([*args, "--deal", "hash", "--group-by", "manufacturer"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "each manufacturer is its own fold" in err
    assert main([*args, "--deal", "deck"]) == 2
    assert "'deck' is not one of" in capsys.readouterr().err


def test_the_command_lines_deals_are_the_fleets():
    """``vpsim fleet --deal`` lists its names without importing the fleet (every command starts faster): the
    same names, in the same order, as :data:`vpsim.fleet.calibrate.DEALS`, the default the same."""
    import vpsim.cli.fleet  # noqa: F401 (registers the command)
    from vpsim.cli.main import cli

    option = next(o for o in cli.commands["fleet"].params if o.name == "deal")
    assert tuple(option.type.choices) == cal.DEALS and option.default == cal.DEFAULT_DEAL


def test_fleet_with_the_blocks_deal_keeps_whole_families_in_the_hand_formulas_folds(tmp_path, capsys):
    """``vpsim fleet --deal blocks``: each row's fold the hand formula's for its family's records on the list
    the fleet used, the deal named in summary.json, report.md and on the screen."""
    lst = write_list(tmp_path / "list.csv", bad_rows=False)
    out = tmp_path / "o"
    args = ["fleet", str(lst), "--out", str(out), "--folds", "3", "--cycles", "hwy", "--no-peer", "--quiet"]
    assert main([*args, "--deal", "blocks"]) == 0
    assert "blocks deal (the headline's: shuffle)" in capsys.readouterr().out
    assert json.loads((out / "summary.json").read_text())["validation"]["deal"] == "blocks"
    assert f"in the order a hash of seed {cal.SEED} and their names gives" in (out / "report.md").read_text()
    rows = pd.read_csv(out / "vehicles.csv")
    sizes = rows.groupby("family").size().to_dict()
    hand = _blocks_by_hand(sizes, 3, cal.SEED)
    assert len(rows) > 0 and list(rows["fold"]) == [hand[f] for f in rows["family"]]


def test_on_bounds_sees_a_value_on_its_bound():
    lo, hi = cal.search_bounds()[cal.TECH_PARAMS[2]]
    assert cal.on_bounds({cal.TECH_PARAMS[2]: hi, cal.TECH_PARAMS[1]: 0.8}) == {cal.TECH_PARAMS[2]: "high"}
    assert cal.on_bounds({cal.TECH_PARAMS[1]: float(cal.GRID[1][0])}) == {cal.TECH_PARAMS[1]: "low"}
    for (par, side), reason in cal.BOUND_REASONS.items():
        assert par in cal.TECH_PARAMS and side in ("low", "high") and len(reason) > 20


# --- the constants chosen on the list: each one's value is the code's ---------------------------------

_WHERE = re.compile(r"^src/vpsim/(?P<path>[\w/]+)\.py: (?P<ident>[A-Za-z_][\w.]*)(?:\[(?P<key>'[^']+')\])?$")


@pytest.mark.parametrize("entry", TUNED_ON_THIS_LIST, ids=[t["name"] for t in TUNED_ON_THIS_LIST])
def test_a_declared_constant_has_the_codes_value(entry):
    assert set(entry) == {"name", "value", "where", "how"} and len(entry["how"]) > 15
    m = _WHERE.match(entry["where"])
    assert m, f"where = {entry['where']!r}: expected 'src/vpsim/<module>.py: <name>'"
    assert (REPO / "src" / "vpsim" / f"{m['path']}.py").is_file()
    obj = importlib.import_module("vpsim." + m["path"].replace("/", "."))
    for part in m["ident"].split("."):
        obj = getattr(obj, part)
    if m["key"]:
        obj = obj[m["key"].strip("'")]
    if callable(obj):  # a rule, not a number: the entry describes it in words
        assert isinstance(entry["value"], str) and len(entry["value"]) > 15, entry["name"]
        return
    value = obj.tolist() if isinstance(obj, np.ndarray) else obj
    value = list(value) if isinstance(value, tuple) else value
    expected = entry["value"]
    if isinstance(expected, float) or isinstance(value, float):
        assert value == pytest.approx(expected, rel=1e-12), entry["name"]
    else:
        assert value == expected, entry["name"]


# --- the calibrated peer -----------------------------------------------------------------------------


def test_peer_fit_recovers_a_known_technology():
    """Synthetic FASTSim-like fuel: ln F = ln(W + a aux) + k (1 - q) (a concave rise with the accessories, a
    part-load term), measured at (s, aux, q) = (1.15, 900 W, 0.8): the fit finds them (the scale exactly
    by the median, the others on their fine grids)."""
    rng = np.random.default_rng(5)
    n = 80
    w = rng.uniform(3.0, 9.0, n)  # L/100 km at no accessory load
    a = rng.uniform(4e-4, 9e-4, n)  # L/100 km per W
    k = rng.uniform(0.2, 0.5, n)

    def ln_f(aux, q):
        return np.log(w[:, None, None] + a[:, None, None] * aux) + k[:, None, None] * (1 - q)

    aux_n = np.asarray(peer.CAL_AUX)[None, :, None]
    q_n = np.asarray(peer.CAL_Q)[None, None, :]
    grid = ln_f(aux_n, q_n)
    meas = (ln_f(900.0, 0.8) - math.log(1.15))[:, 0, 0]
    params, loss = peer.fit_peer(grid, meas)
    assert params["accessory_power_w"] == pytest.approx(900.0, abs=100.0)
    assert params["part_load_exponent"] == pytest.approx(0.8, abs=0.04)
    assert params["efficiency_scale"] == pytest.approx(1.15, rel=0.02)
    assert loss < 0.01


def test_peer_technology_changes_only_what_it_names():
    pytest.importorskip("fastsim")
    base = peer._base_vehicle()
    eff = base["pt_type"]["Conv"]["fc"]["eff_interp_from_pwr_out"]["data"]["values"]["data"]
    d = peer.with_technology(
        base, {"efficiency_scale": 1.1, "accessory_power_w": 1200.0, "part_load_exponent": 1.0}
    )
    new = d["pt_type"]["Conv"]["fc"]["eff_interp_from_pwr_out"]["data"]["values"]["data"]
    assert new == pytest.approx([1.1 * e for e in eff], rel=1e-12) and d["pwr_aux_base_watts"] == 1200.0
    assert base["pt_type"]["Conv"]["fc"]["eff_interp_from_pwr_out"]["data"]["values"]["data"] == eff
    q = peer.with_technology(base, {"part_load_exponent": 0.5})
    vals = q["pt_type"]["Conv"]["fc"]["eff_interp_from_pwr_out"]["data"]["values"]["data"]
    assert max(vals) == pytest.approx(max(eff)) and min(vals) > min(eff)  # the peak kept, part load raised
    assert peer.CAL_Q[0] < 1.0 < peer.CAL_Q[1]  # FASTSim's own curve inside the searched range


def test_calibrated_peer_in_the_summary(tmp_path):
    pytest.importorskip("fastsim")
    from vpsim.fleet.report import summary

    run = run_fleet(write_list(tmp_path / "l.csv", bad_rows=False), folds=3, cycles=("hwy",))
    s = summary(run)
    fc = s["peer"]["fastsim_calibrated"]
    assert set(fc["hwy"]) == {"n", "median_error_pct", "median_abs_error_pct", "p90_abs_error_pct"}
    assert fc["hwy"]["n"] == s["peer"]["fastsim"]["hwy"]["n"]
    assert s["peer"]["fastsim_calibrated_by_powertrain"]["conventional"] == fc
    assert set(run.peer_technology) == {f"fold{f}.{c}" for f in range(3) for c in cal.CLASSES}
    df = run.frame()
    assert np.isfinite(df["fastsim_calibrated_mpg"]).all()
