"""FASTSim's runs remembered on disk (vpsim.fleet.peer_cache): a remembered run is the fresh run to the bit,
any change of an input is another run, and a cache that cannot be used never stops one."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from vpsim.cycles import Cycle
from vpsim.fleet import peer_cache


def _cycle(top=10.0):
    t = np.arange(0.0, 21.0)
    return Cycle("c", t, np.interp(t, [0, 5, 15, 20], [0, top, top, 0]))


@pytest.fixture
def fake(monkeypatch, tmp_path):
    """peer_cache with FASTSim replaced by a counting stand-in, its cache in a folder of the test's."""
    calls = []

    def simulate(vehicle, cycle, params):
        calls.append(vehicle["mass_kilograms"])
        fuel = vehicle["mass_kilograms"] * float(np.sum(cycle.speed_mps)) / 3.0  # an exact float to keep
        return {"veh": {"state": {"dist_meters": 1.0 / 3.0, "ok": True}, "pt_type": {"Conv": {"fc": {
            "state": {"energy_fuel_joules": fuel}}}}}}  # fmt: skip

    monkeypatch.setattr(peer_cache, "_STATE", {})
    monkeypatch.setattr(peer_cache, "_simulate", simulate)
    monkeypatch.setattr(peer_cache, "_sim_params", lambda: (None, {"trace_miss_opts": "Allow"}))
    monkeypatch.setenv(peer_cache.ENV_DIR, str(tmp_path / "cache"))
    monkeypatch.delenv(peer_cache.ENV_SWITCH, raising=False)
    return calls


def test_a_remembered_run_is_the_fresh_one_and_fastsim_runs_once(fake):
    v = {"mass_kilograms": 1500.1, "name": "a"}
    first = peer_cache.run(v, _cycle())
    again = peer_cache.run(dict(v), _cycle())  # an equal dict and an equal cycle: the same key
    assert fake == [1500.1]
    assert again == first and json.dumps(again) == json.dumps(first)  # floats read back exactly
    assert peer_cache.entries() == 1 and peer_cache.cache_path().is_file()


def test_any_changed_input_is_another_run(fake):
    v = {"mass_kilograms": 1500.0, "name": "a"}
    peer_cache.run(v, _cycle())
    peer_cache.run(dict(v, mass_kilograms=1500.0 + 1e-9), _cycle())  # the vehicle
    peer_cache.run(v, _cycle(top=10.0 + 1e-12))  # the cycle's samples
    peer_cache.run(dict(v, name="b"), _cycle())  # any field of the dict
    assert len(fake) == 4 and peer_cache.entries() == 4
    keys = {
        peer_cache.digest(v, _cycle(), {"trace_miss_opts": "Allow"}),
        peer_cache.digest(v, _cycle(), {"trace_miss_opts": "Error"}),  # the simulation parameters
    }
    assert len(keys) == 2


def test_switched_off_it_runs_every_time_and_writes_nothing(fake, monkeypatch):
    monkeypatch.setenv(peer_cache.ENV_SWITCH, "0")
    v = {"mass_kilograms": 1200.0}
    assert peer_cache.run(v, _cycle()) == peer_cache.run(v, _cycle())
    assert len(fake) == 2
    assert not peer_cache.cache_path().exists() and peer_cache.entries() is None
    assert peer_cache.describe(None) == {
        "enabled": False, "path": None, "entries_before": None, "entries_after": None
    }  # fmt: skip


def test_a_cache_that_cannot_be_opened_is_left_alone_with_one_warning(fake, monkeypatch, tmp_path, capsys):
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("a file where the cache folder would be\n")
    monkeypatch.setenv(peer_cache.ENV_DIR, str(blocker))
    v = {"mass_kilograms": 1300.0}
    out = [peer_cache.run(v, _cycle()) for _ in range(3)]
    assert len(fake) == 3 and out[0] == out[2]
    err = capsys.readouterr().err
    assert err.count("FASTSim run cache") == 1 and "running FASTSim without it" in err


def test_a_damaged_cache_file_is_left_alone_with_one_warning(fake, capsys):
    path = peer_cache.cache_path()
    path.parent.mkdir(parents=True)
    path.write_bytes(b"this is not an SQLite database" * 100)
    v = {"mass_kilograms": 1400.0}
    assert peer_cache.run(v, _cycle()) == peer_cache.run(v, _cycle())
    assert len(fake) == 2
    assert capsys.readouterr().err.count("FASTSim run cache") == 1


def test_a_damaged_entry_is_run_again_and_replaced(fake):
    v = {"mass_kilograms": 1450.0}
    first = peer_cache.run(v, _cycle())
    con = peer_cache._connection()
    con.execute("UPDATE runs SET outputs = ?", (b"not zlib data",))
    assert peer_cache.run(v, _cycle()) == first and len(fake) == 2
    assert peer_cache.run(v, _cycle()) == first and len(fake) == 2  # replaced: read back again


def test_the_real_peer_gives_the_same_figures_from_the_cache(monkeypatch, tmp_path):
    """FASTSim itself (skipped where it is not installed): a conventional record's peer figures with the
    cache filled, read back, and switched off are equal to the bit."""
    pytest.importorskip("fastsim")
    from fleet_csv import write_list
    from vpsim.fleet import peer
    from vpsim.fleet.epa import read_test_car_list

    if not peer.status()["available"]:
        pytest.skip(peer.status()["reason"])
    monkeypatch.setattr(peer_cache, "_STATE", {})
    monkeypatch.setenv(peer_cache.ENV_DIR, str(tmp_path / "cache"))
    monkeypatch.delenv(peer_cache.ENV_SWITCH, raising=False)
    rec = read_test_car_list(write_list(tmp_path / "list.csv", bad_rows=False)).vehicles[0]
    tech = {"accessory_power_w": 1000.0, "part_load_exponent": 0.7}
    filled = [peer._run(rec, "hwy"), peer._run(rec, "hwy", tech)]
    assert peer_cache.entries() == 2
    remembered = [peer._run(rec, "hwy"), peer._run(rec, "hwy", tech)]
    monkeypatch.setenv(peer_cache.ENV_SWITCH, "0")
    fresh = [peer._run(rec, "hwy"), peer._run(rec, "hwy", tech)]
    assert filled == remembered == fresh
    assert all(math.isfinite(m) and m > 0 for m, _ in fresh) and fresh[0][0] != fresh[1][0]
