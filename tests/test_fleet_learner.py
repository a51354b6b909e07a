"""benchmarks/fleet_learner.py: the folds it holds out by group; its one-line answer without scikit-learn."""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd


def test_group_folds_keep_a_group_together_and_deal_the_groups_evenly(benchmark_script):
    mod = benchmark_script("fleet_learner")
    keys = pd.Series([f"maker{i % 7}" for i in range(70)])
    folds = mod.group_folds(keys, k=5)
    for key in keys.unique():
        assert np.unique(folds[keys.to_numpy() == key]).size == 1  # one fold per group
    sizes = np.bincount([folds[keys.to_numpy() == key][0] for key in keys.unique()], minlength=5)
    assert sorted(sizes.tolist()) == [1, 1, 1, 2, 2]  # 7 groups dealt over 5 folds
    np.testing.assert_array_equal(folds, mod.group_folds(keys, k=5))  # seeded: the same folds every run


def test_without_scikit_learn_it_says_so_in_one_line(tmp_path, monkeypatch, capsys, benchmark_script):
    mod = benchmark_script("fleet_learner")
    monkeypatch.setitem(sys.modules, "sklearn", None)  # import sklearn raises ImportError
    assert mod.main([str(tmp_path), str(tmp_path / "list.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "scikit-learn" in err
