"""``vpsim bench``: a smoke test of the tiny profile (seconds), the JSON contract, and a missing peer.

No timing is asserted: machines are noisy. The figures themselves come from ``vpsim bench`` (see
benchmarks/README.md).
"""

from __future__ import annotations

import importlib.util
import json
import sys

import pytest

from vpsim.bench import format_report, peer_status, run_benchmarks
from vpsim.cli.main import main

REQUIRED = {
    "ratios",
    "batch_backward_runs_per_s",
    "batch_forward_runs_per_s",
    "cold_start_s",
    "linearity_max_dev",
}
RATIOS = {"backward_vs_fastsim_udds", "forward_vs_fastsim_udds", "inverse_vs_backward"}
HAVE_FASTSIM = importlib.util.find_spec("fastsim") is not None


def test_bench_tiny_cli_writes_json_and_prints_one_table(capsys, tmp_path):
    out = tmp_path / "sub" / "bench.json"
    code = main(["bench", "--tiny", "--json", str(out)])
    text, err = capsys.readouterr()
    assert code == 0, err
    report = json.loads(out.read_text())
    assert REQUIRED <= set(report)
    assert RATIOS <= set(report["ratios"])
    assert report["batch_backward_runs_per_s"] > 0
    b = report["batch"]["batch_backward"]  # the one-thread figure beside the threads' (None on one thread)
    assert b["threads"] >= 1 and (b["one_thread_runs_per_s"] is None) == (b["threads"] == 1)
    if b["threads"] > 1:
        assert b["one_thread_runs_per_s"] > 0 and "on one thread" in text
    assert report["linearity_max_dev"] >= 0
    row = next(r for r in report["rows"] if r["tool"] == "vpsim" and r["method"] == "backward")
    assert row["cycle"] == "udds" and row["steps"] == 1369 and row["median_ms"] > 0 and row["py_peak_kib"] > 0
    assert "backward" in text and "targets:" in text and "vpsim backward on udds" in err
    if report["peer"]["available"]:
        assert report["ratios"]["backward_vs_fastsim_udds"] > 0
        peer = next(r for r in report["rows"] if r["tool"].startswith("fastsim"))
        assert peer["cycle"] == "udds" and peer["steps"] == 1369 and 3 < peer["fuel_l_per_100km"] < 15
        # the electric cars' ratios: each side at the fastest of its own row and its interleaved blocks
        for key in ("bev_backward", "bev_forward", "hev_ecms_backward", "hev_ecms_forward"):
            paired = report["ratios_paired"][f"{key}_vs_fastsim_udds"]
            fastsim_ms, vpsim_ms = paired["best_ms"]
            assert paired["ratio"] > 0
            assert fastsim_ms <= paired["a_median_ms"] and vpsim_ms <= paired["b_median_ms"]
            assert report["ratios"][f"{key}_vs_fastsim_udds"] == pytest.approx(fastsim_ms / vpsim_ms)
    else:
        assert report["ratios"]["backward_vs_fastsim_udds"] is None
        assert "not measured" in text


def test_electric_ratio_takes_each_side_at_its_fastest():
    """The BEV's and the hybrid's ratios: each tool at the faster of its own row and its paired blocks (hand
    values); no figure where a side has none."""
    from vpsim.bench_powertrains import best_ratio

    peer, own = {"median_ms": 40.0}, {"median_ms": 0.8}
    assert best_ratio(peer, own, None) == (50.0, [40.0, 0.8])
    assert best_ratio(peer, own, {"a_median_ms": 36.0, "b_median_ms": 0.9}) == (45.0, [36.0, 0.8])
    assert best_ratio(peer, own, {"a_median_ms": 44.0, "b_median_ms": 0.5}) == (80.0, [40.0, 0.5])
    assert best_ratio({}, own, None) == (None, [None, 0.8])  # FASTSim not installed
    assert best_ratio(peer, None, None) == (None, [40.0, None])  # the row failed


def test_missing_peer_is_reported_not_faked(monkeypatch):
    monkeypatch.setitem(sys.modules, "fastsim", None)  # import fastsim -> ImportError
    status = peer_status()
    assert not status["available"] and "not installed" in status["reason"]
    report = run_benchmarks("tiny")
    assert not report["peer"]["available"]
    assert not any(r["tool"].startswith("fastsim") for r in report["rows"])
    assert report["ratios"]["backward_vs_fastsim_udds"] is None
    target = next(t for t in report["targets"] if t["figure"] == "backward_vs_fastsim_udds")
    assert target["met"] is None
    text = format_report(report)
    assert "fastsim 3.1.0  not measured: not installed" in text


@pytest.mark.skipif(not HAVE_FASTSIM, reason="fastsim 3.1.0 is not installed (pip install 'vpsim[bench]')")
def test_peer_is_the_pinned_fastsim():
    status = peer_status()
    assert status["version"] is not None
    assert status["available"] == (status["version"] == "3.1.0")


def test_unknown_profile_is_an_error():
    with pytest.raises(ValueError, match="profile must be one of"):
        run_benchmarks("huge")


def test_forward_steps_per_cycle_second_counted_in_both_modes():
    """The issue's step target (<= 2 accepted steps per second of UDDS) as counts: the forward runs' own
    accepted steps over the cycle's 1369 s, paper and realistic mode; a profile without the forward method
    reports it as not measured."""
    from dataclasses import replace

    from vpsim.bench import PROFILES, TARGETS, _forward_steps, _targets
    from vpsim.simulation import simulate

    steps = _forward_steps(replace(PROFILES["tiny"], methods=(("forward", "1"),)))
    for mode in ("paper", "realistic"):
        r = simulate("udds", "forward", driver="1", mode=mode, keep_series=False)
        assert steps[mode]["accepted_steps"] == r.solver["accepted_steps"]
        assert steps[mode]["per_cycle_s"] == pytest.approx(r.solver["accepted_steps"] / 1369.0)
        assert f"forward_udds_steps_per_cycle_s_{mode}" in TARGETS
    assert _forward_steps(PROFILES["tiny"]) == {}
    report = {"ratios": {}, "forward_udds_steps_per_cycle_s_paper": 1.5}
    met = {t["figure"]: t["met"] for t in _targets(report)}
    assert met["forward_udds_steps_per_cycle_s_paper"] is True
    assert met["forward_udds_steps_per_cycle_s_realistic"] is None


def test_vpsim_is_timed_in_fresh_processes_as_the_peer_is():
    """The rule held against the targets is the same for both tools: vpsim's runs also get fresh processes of
    their own (as many as FASTSim's), after the same warm-up; the child times what the in-process row times
    (the steps and fuel are the row's), and the report says which processes it took."""
    from dataclasses import replace

    from vpsim.bench import PROFILES, _vpsim_fresh
    from vpsim.simulation import simulate

    settings = replace(PROFILES["tiny"], peer_processes=2, peer_warm_up_s=0.05)
    fresh = _vpsim_fresh(settings, lambda line: None)
    entry = fresh["backward/-/udds"]
    per = entry["median_ms_per_process"]
    assert len(per) == 2 and entry["best_ms"] == min(per) and all(0 < m < 1e3 for m in per)
    r = simulate("udds", "backward")
    assert entry["steps"] == r.steps and entry["fuel_kg"] == pytest.approx(r.fuel_kg, rel=1e-12)
    assert list(fresh) == ["backward/-/udds"]  # only the methods the profile runs
    assert _vpsim_fresh(PROFILES["tiny"], lambda line: None) == {}  # no peer processes, none of vpsim
