"""The append-only result store: atomic parts, CSV repair, the writer's lock, dedupe, resume checks."""

from __future__ import annotations

import pandas as pd
import pytest

from vpsim.sweep import SpecError, load_results, make_spec, run_sweep
from vpsim.sweep.store import PARQUET_NAME, ResultStore

SPEC = {"parameters": {"engine.bore": [0.08, 0.09, 0.1]}, "acceleration": False, "baseline": False}
SCHEMA = {"point_id": "str", "x": "float", "n": "int", "ok": "bool", "error": "str", "computed_at": "float"}


def _rows(ids, t=0.0):
    return pd.DataFrame(
        {
            "point_id": ids,
            "x": [1.5] * len(ids),
            "n": [2] * len(ids),
            "ok": [True] * len(ids),
            "error": [None] * len(ids),
            "computed_at": [t] * len(ids),
        }
    )


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_append_read_and_dedupe(tmp_path, fmt):
    s = ResultStore(tmp_path / "o", fmt, SCHEMA)
    s.open(resume=False, meta={})
    s.append(_rows(["a", "b"], 1.0))
    s.append(_rows(["c"], 2.0))
    s.append(_rows(["a"], 3.0))  # a duplicate can only come from merged copies; the first computed wins
    assert s.completed() == {"a", "b", "c"}
    df = s.read()
    assert sorted(df["point_id"]) == ["a", "b", "c"]
    assert df.set_index("point_id").loc["a", "computed_at"] == 1.0
    assert len(s.read(dedupe=False)) == 4
    assert df["error"].isna().all() and df["n"].dtype == "int64" and df["ok"].dtype == bool
    s.close()
    assert sorted(load_results(tmp_path / "o")["point_id"]) == ["a", "b", "c"]


def test_parquet_folder_reads_with_pandas_and_ignores_unfinished_parts(tmp_path):
    s = ResultStore(tmp_path, "parquet", SCHEMA)
    s.open(resume=False, meta={})
    s.append(_rows(["a", "b"]))
    s.close()
    (tmp_path / PARQUET_NAME / ".part-x-000009.parquet.tmp").write_bytes(b"half a file")
    assert len(pd.read_parquet(tmp_path / PARQUET_NAME)) == 2
    s = ResultStore(tmp_path, None, SCHEMA)
    s.open(resume=True, meta={})
    assert not list((tmp_path / PARQUET_NAME).glob(".*tmp"))  # removed on resume
    assert s.completed() == {"a", "b"}
    s.close()


def test_csv_line_cut_by_a_kill_is_dropped_on_resume(tmp_path):
    s = ResultStore(tmp_path, "csv", SCHEMA)
    s.open(resume=False, meta={})
    s.append(_rows(["a", "b"]))
    s.close()
    with open(tmp_path / "results.csv", "ab") as fh:
        fh.write(b"c,1.5,2,Tr")  # a write cut short
    s = ResultStore(tmp_path, None, SCHEMA)
    s.open(resume=True, meta={})
    assert s.completed() == {"a", "b"}
    s.append(_rows(["c"]))
    assert sorted(s.read()["point_id"]) == ["a", "b", "c"]
    s.close()


def test_one_writer_at_a_time_and_no_silent_overwrite(tmp_path):
    a = ResultStore(tmp_path, "parquet", SCHEMA)
    a.open(resume=False, meta={})
    b = ResultStore(tmp_path, "parquet", SCHEMA)
    with pytest.raises(SpecError, match="being written by another sweep"):
        b.open(resume=True, meta={})
    a.close()
    with pytest.raises(SpecError, match="--resume"):
        b.open(resume=False, meta={})
    with pytest.raises(SpecError, match="holds parquet results"):
        ResultStore(tmp_path, "csv", SCHEMA).open(resume=True, meta={})


def test_resume_refuses_a_spec_with_other_parameters(tmp_path):
    run_sweep(make_spec(**SPEC), tmp_path, workers=1)
    other = make_spec(parameters={"vehicle.mass": [1200.0, 1300.0]}, acceleration=False)
    with pytest.raises(SpecError, match="parameters differ"):
        run_sweep(other, tmp_path, workers=1, resume=True)


def test_resume_with_more_cycles_computes_only_the_new_rows(tmp_path):
    first = run_sweep(make_spec(**SPEC), tmp_path, workers=1)
    assert first.n_computed == 3
    more = run_sweep(make_spec(**SPEC, cycles=["nedc", "hwfet"]), tmp_path, workers=1, resume=True)
    assert (more.n_skipped, more.n_computed, more.n_rows) == (3, 3, 6)
    df = load_results(tmp_path, dedupe=False)
    assert len(df) == 6 and df["point_id"].is_unique
    assert set(df.loc[df["cycle"] == "nedc", "run_id"]) == {first.run_id}
