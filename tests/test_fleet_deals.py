"""``vpsim fleet-deals``: the fleet's figures over several deals of families into folds
(:mod:`vpsim.fleet.deals`), checked against hand values on made-up output folders and against
``vpsim fleet``'s own summary on runs of a made-up list."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from fleet_csv import write_list
from vpsim.cli.main import main
from vpsim.errors import VpsimError
from vpsim.fleet.deals import compare_deals


def _folder(
    path: Path, seed, vp, peer, families=None, cycle="hwy", grouping="family", folds=5, ev=None, deal=None
):
    """A made-up `vpsim fleet --out` folder: a summary with the deal, and vehicles.csv with one row per
    error of ``vp`` (vpsim) and ``peer`` (the calibrated FASTSim; None: not run). ``deal``: written as
    validation.deal when given (folders of earlier versions have none)."""
    path.mkdir(parents=True)
    summary = {"n_vehicles": len(vp), "validation": {"grouping": grouping, "folds": folds, "seed": seed}}
    if deal is not None:
        summary["validation"]["deal"] = deal
    (path / "summary.json").write_text(json.dumps(summary))
    n = len(vp)
    rows = {
        "vehicle_id": [f"V{i}" for i in range(n)],
        "configuration": [0] * n,
        "cycle": [cycle] * n,
        "error_pct": vp,
        "family": families if families is not None else [f"F{i}" for i in range(n)],
    }
    if peer is not None:
        rows["fastsim_calibrated_error_pct"] = peer
    pd.DataFrame(rows).to_csv(path / "vehicles.csv", index=False)
    if ev is not None:
        ev.to_csv(path / "vehicles_ev.csv", index=False)
    return path


def test_hand_values_over_three_deals(tmp_path):
    # vpsim's |errors| 1..5 on every deal but signs and one value moved; FASTSim's 6..10: each family's
    # vpsim error below FASTSim's, so every bootstrap draw puts vpsim lower
    a = _folder(tmp_path / "a", 0, [1, -2, 3, -4, 5], [6, 7, -8, 9, 10])
    b = _folder(tmp_path / "b", 1, [-1, 2, 3, 4, -5.5], [6, 7, 8, 9, 10])
    c = _folder(tmp_path / "c", 2, [1, 2, 3.6, 4, 5], [6, 7, 8, 9, 10])
    r = compare_deals([a, b, c])
    f = r.tests["conventional"]["hwy"]
    assert f["n"] == 5 and f["families"] == 5
    assert f["vpsim_median_abs_error_pct"] == {
        "mean": 3.2,
        "min": 3.0,
        "max": 3.6,
        "by_deal": [3.0, 3.0, 3.6],
    }
    assert f["peer_median_abs_error_pct"]["by_deal"] == [8.0, 8.0, 8.0]
    # numpy's linear 90th percentile of |errors| 1..5 is 4.6; of 1, 2, 3, 4, 5.5 it is 4.9
    assert f["vpsim_p90_abs_error_pct"]["by_deal"] == [4.6, 4.9, 4.6]
    assert f["difference_pts"] == {"mean": -4.8, "min": -5.0, "max": -4.4, "by_deal": [-5.0, -5.0, -4.4]}
    assert (f["deals_vpsim_ahead"], f["deals_not_told_apart"], f["deals_vpsim_behind"]) == (3, 0, 0)
    assert f["verdict"] == "ahead" and f["pooled_share_vpsim_lower"] == 1.0
    # every draw is a median of 5 values drawn from vpsim's and FASTSim's: at most 5 - 6 = -1 apart... and at
    # least 1 - 10; the pooled interval sits inside those bounds
    lo, hi = f["pooled_ci95_pts"]
    assert -9.0 <= lo <= hi <= -1.0
    df = r.to_frame()
    assert len(df) == 3 and list(df["seed"]) == [0, 1, 2]
    assert list(df["difference_pts"]) == [-5.0, -5.0, -4.4]
    text = str(r)
    assert "3 deals of family folds (5 folds), seeds 0, 1, 2" in text
    assert "3.20 [3.00-3.60]" in text and "-4.80 [-5.00, -4.40]" in text and "ahead" in text
    ax = r.plot()
    assert len(ax.get_yticklabels()) == 1


def test_identical_deals_pool_to_each_deals_interval_and_a_tie_is_not_told_apart(tmp_path):
    rng = np.random.default_rng(3)
    vp = rng.normal(0, 5, 60)
    peer = vp + rng.normal(0, 2, 60)  # alike: the bootstrap cannot tell them apart
    fam = [f"F{i // 2}" for i in range(60)]  # two records per family, drawn together
    a = _folder(tmp_path / "a", 4, vp, peer, fam)
    b = _folder(tmp_path / "b", 9, vp, peer, fam)
    f = compare_deals([a, b]).tests["conventional"]["hwy"]
    assert f["families"] == 30
    assert f["ci95_pts_by_deal"][0] == f["ci95_pts_by_deal"][1] == f["pooled_ci95_pts"]  # the same draws
    assert f["mean_ci95_pts"] == f["pooled_ci95_pts"]  # and their mean over two equal deals is each
    lo, hi = f["pooled_ci95_pts"]
    assert lo < 0.0 < hi and f["verdict"] == "not told apart" and f["deals_not_told_apart"] == 2
    point = float(np.median(np.abs(vp)) - np.median(np.abs(peer)))
    assert f["difference_pts"]["mean"] == pytest.approx(point, abs=5e-4)


def test_a_behind_verdict_and_a_part_without_its_peer(tmp_path):
    ev = pd.DataFrame(
        {
            "vehicle_id": ["E1", "E2", "E3"],
            "configuration": 0,
            "cycle": "udds",
            "error_pct": [2.0, -3.0, 4.0],
            "family": ["a", "b", "c"],
        }
    )
    a = _folder(tmp_path / "a", 0, [9, 8, 10, -9], [1, 1, -2, 1], ev=ev)
    b = _folder(tmp_path / "b", 1, [9, 8, 11, -9], [1, 2, -2, 1], ev=ev)
    r = compare_deals([a, b])
    f = r.tests["conventional"]["hwy"]
    assert f["verdict"] == "behind" and f["deals_vpsim_behind"] == 2 and f["pooled_ci95_pts"][0] > 0
    e = r.tests["bev"]["udds"]
    assert e["verdict"] == "no peer" and e["vpsim_median_abs_error_pct"]["by_deal"] == [3.0, 3.0]
    assert e["families"] == 3 and e["n"] == 3
    assert e["difference_pts"]["mean"] is None
    assert "no peer" in str(r)


def test_a_hash_deal_and_a_shuffle_of_one_seed_are_two_deals(tmp_path):
    """validation.deal tells deals apart: seed 0 shuffled (no key: an earlier version's folder) and seed 0
    hashed are two deals, labelled so; the same hash deal twice is refused."""
    a = _folder(tmp_path / "a", 0, [1, 2, 3], [4, 5, 6])
    b = _folder(tmp_path / "b", 0, [1, 2, 4], [4, 5, 6], deal="hash")
    r = compare_deals([a, b])
    assert [(d["seed"], d["deal"]) for d in r.as_dict()["deals"]] == [(0, "shuffle"), (0, "hash")]
    assert list(r.to_frame()["deal"]) == ["shuffle", "hash"]
    assert "2 deals of family folds (5 folds), seeds 0, hash seed 0" in str(r)
    assert r.tests["conventional"]["hwy"]["vpsim_median_abs_error_pct"]["by_deal"] == [2.0, 2.0]
    with pytest.raises(VpsimError, match="same deal \\(hash seed 0\\)"):
        compare_deals([a, b, _folder(tmp_path / "c", 0, [1, 2, 3], [4, 5, 6], deal="hash")])
    with pytest.raises(VpsimError, match="validation.deal 'deck': expected shuffle or hash"):
        compare_deals([a, _folder(tmp_path / "d", 1, [1, 2, 3], [4, 5, 6], deal="deck")])


def test_folders_that_cannot_be_compared_are_one_line(tmp_path, capsys):
    a = _folder(tmp_path / "a", 0, [1, 2, 3], [4, 5, 6])
    cases = {
        "two or more": [a],
        "no summary.json": [a, tmp_path / "nowhere"],
        "same deal (seed 0)": [a, _folder(tmp_path / "dup", 0, [1, 2, 3], [4, 5, 6])],
        "by manufacturer in 5": [
            a,
            _folder(tmp_path / "m", 1, [1, 2, 3], [4, 5, 6], grouping="manufacturer"),
        ],
        "are not those of the first": [a, _folder(tmp_path / "r", 2, [1, 2, 3, 4], [4, 5, 6, 7])],
        "tests us06": [a, _folder(tmp_path / "t", 3, [1, 2, 3], [4, 5, 6], cycle="us06")],
    }
    ev = pd.DataFrame(
        {"vehicle_id": ["E1"], "configuration": 0, "cycle": "udds", "error_pct": 1.0, "family": "x"}
    )
    cases["no vehicles_ev.csv"] = [a, _folder(tmp_path / "e", 4, [1, 2, 3], [4, 5, 6], ev=ev)]
    bad = _folder(tmp_path / "bad", 5, [1, 2, 3], [4, 5, 6])
    (bad / "summary.json").write_text("{not json")
    cases["not valid JSON"] = [a, bad]
    deep = _folder(tmp_path / "deep", 8, [1, 2, 3], [4, 5, 6])
    (deep / "summary.json").write_text("[" * 100_000 + "]" * 100_000)  # was an internal RecursionError
    cases["nested too deeply"] = [a, deep]
    binary = _folder(tmp_path / "binary", 9, [1, 2, 3], [4, 5, 6])
    (binary / "vehicles.csv").write_bytes(b"\x00\xff" * 50)
    cases["vehicles.csv"] = [a, binary]
    old = _folder(tmp_path / "old", 6, [1, 2, 3], [4, 5, 6])
    (old / "summary.json").write_text(json.dumps({"validation": {"grouping": "family", "folds": 5}}))
    cases["no validation.seed"] = [a, old]
    cols = _folder(tmp_path / "cols", 7, [1, 2, 3], [4, 5, 6])
    pd.read_csv(cols / "vehicles.csv").drop(columns="family").to_csv(cols / "vehicles.csv", index=False)
    cases["no column family"] = [a, cols]
    for expected, folders in cases.items():
        with pytest.raises(VpsimError, match=re.escape(expected)):
            compare_deals(folders)
        assert main(["fleet-deals", *map(str, folders)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and expected in err, (expected, err)


def _fleet(tmp_path, lst, seed, peer: bool):
    out = tmp_path / f"seed{seed}"
    args = ["fleet", str(lst), "--out", str(out), "--folds", "3", "--cycles", "hwy,ftp_bag2"]
    assert (
        main([*args, "--seed", str(seed), "--workers", "1", "--quiet", *([] if peer else ["--no-peer"])]) == 0
    )
    return out


def _two_deals(tmp_path, capsys, peer: bool):
    """The made-up list run on seeds 1 and 2 (separate runs), and fleet-deals of the two folders."""
    lst = write_list(tmp_path / "list.csv", bad_rows=False)
    folders = [_fleet(tmp_path, lst, s, peer=peer) for s in (1, 2)]
    capsys.readouterr()
    return folders, compare_deals(folders)


def test_real_runs_without_the_peer_give_vpsim_s_figures_of_each_summary(tmp_path, capsys):
    folders, r = _two_deals(tmp_path, capsys, peer=False)
    for i, d in enumerate(folders):
        s = json.loads((d / "summary.json").read_text())
        for c in ("hwy", "ftp_bag2"):
            f = r.tests["conventional"][c]
            assert f["verdict"] == "no peer"
            assert f["vpsim_median_abs_error_pct"]["by_deal"][i] == pytest.approx(
                s["cycles"][c]["median_abs_error_pct"], abs=2e-3
            )
            assert f["vpsim_p90_abs_error_pct"]["by_deal"][i] == pytest.approx(
                s["cycles"][c]["p90_abs_error_pct"], abs=2e-3
            )
    assert main(["fleet-deals", *map(str, folders), "--json", "--plot", str(tmp_path / "d.png")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [d["seed"] for d in out["deals"]] == [1, 2] and out["grouping"] == "family" and out["folds"] == 3
    assert main(["fleet-deals", *map(str, folders), "--plot", str(tmp_path / "d.nosuchformat")]) == 2
    assert "cannot write" in capsys.readouterr().err


@pytest.mark.skipif(
    importlib.util.find_spec("fastsim") is None, reason="FASTSim 3.1 not installed (.[bench])"
)
def test_real_runs_with_the_peer_reproduce_each_summarys_bootstrap(tmp_path, capsys):
    folders, r = _two_deals(tmp_path, capsys, peer=True)
    for i, d in enumerate(folders):
        diff = json.loads((d / "summary.json").read_text())["peer"][
            "vpsim_minus_fastsim_calibrated_by_powertrain"
        ]
        for c, want in diff["conventional"].items():
            f = r.tests["conventional"][c]
            assert f["difference_pts"]["by_deal"][i] == pytest.approx(want["difference_pts"], abs=2e-3)
            assert f["ci95_pts_by_deal"][i] == pytest.approx(want["ci95_pts"], abs=2e-3)
            assert f["families"] == want["families"]
    assert main(["fleet-deals", *map(str, folders), "--plot", str(tmp_path / "d.png")]) == 0
    assert "2 deals of family folds (3 folds), seeds 1, 2" in capsys.readouterr().out
    assert (tmp_path / "d.png").stat().st_size > 1000


def test_several_seeds_in_one_command_give_the_separate_runs_figures(tmp_path, capsys):
    """`vpsim fleet ... --seed 1 --seed 2` remembers the deal-independent chunk results across the deals
    (vpsim.fleet.run._Remembering): every table and summary equals that of a separate run, byte for byte."""
    lst = write_list(tmp_path / "list.csv", bad_rows=False)
    alone = [_fleet(tmp_path, lst, s, peer=False) for s in (1, 2)]
    out = tmp_path / "both"
    args = ["fleet", str(lst), "--out", str(out), "--folds", "3", "--cycles", "hwy,ftp_bag2", "--no-peer"]
    assert main([*args, "--seed", "1", "--seed", "2", "--workers", "1", "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "2 deals of family folds (3 folds), seeds 1, 2" in text and "wrote" in text
    for s, single in zip((1, 2), alone, strict=True):
        for name in (
            "vehicles.csv",
            "vehicles_ev.csv",
            "vehicles_hev.csv",
            "vehicles_mhev.csv",
            "summary.json",
        ):
            assert (out / f"seed_{s}" / name).read_bytes() == (single / name).read_bytes(), (s, name)
    deals = json.loads((out / "deals.json").read_text())
    assert [d["seed"] for d in deals["deals"]] == [1, 2]
    assert (out / "deals.png").stat().st_size > 1000
    assert main([*args, "--seed", "3", "--seed", "3", "--quiet"]) == 2
    assert "--seed 3 given more than once" in capsys.readouterr().err
    assert main([*args, "--seed", "3", "--seed", "4", "--group-by", "manufacturer", "--quiet"]) == 2
    assert "one deal (a fold per manufacturer)" in capsys.readouterr().err


def test_remembering_executor_runs_each_new_chunk_once_and_keeps_the_order():
    from vpsim.fleet.run import _Remembering, _Serial

    calls = []

    def square(chunk, offset):
        calls.append(chunk)
        return [x * x + offset for x in chunk]

    memory: dict = {}
    ex = _Remembering(_Serial(), memory)
    assert list(ex.map(square, [[1, 2], [3], [1, 2]], 0)) == [[1, 4], [9], [1, 4]]
    assert calls == [[1, 2], [3]]  # the repeated chunk once
    assert list(ex.map(square, [[3], [5]], 0)) == [[9], [25]]
    assert calls == [[1, 2], [3], [5]]  # only the new one
    assert list(ex.map(square, [[3]], 1)) == [[10]]  # other arguments: another result
    assert calls[-1] == [3] and len(memory) == 4
