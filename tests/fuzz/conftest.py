"""The fuzz suite's Hypothesis profile: reproducible in CI (``CI`` set: derandomized), exploring locally.

Every generated case must give a valid result or one clear line (see ``_fuzz.py``); the whole suite runs in
well under a minute on two cores (``max_examples`` is set per test, no per-example deadline).
"""

from __future__ import annotations

import os
import time

import pytest
from hypothesis import settings

settings.register_profile(
    "vpsim-fuzz", deadline=None, derandomize=bool(os.environ.get("CI")), print_blob=True
)
settings.load_profile("vpsim-fuzz")

# the whole fuzz suite, on a 2-core CI machine (it takes about 45 s there)
FUZZ_BUDGET_S = float(os.environ.get("VPSIM_FUZZ_BUDGET_S", "180"))
_spent: list[float] = []


@pytest.fixture(autouse=True)
def _fuzz_clock():
    """Time each fuzz test; the session's teardown below checks the suite kept its budget."""
    t0 = time.perf_counter()
    yield
    _spent.append(time.perf_counter() - t0)


@pytest.fixture(scope="session", autouse=True)
def _fuzz_budget():
    yield
    total = sum(_spent)
    assert total < FUZZ_BUDGET_S, f"the fuzz suite took {total:.0f} s, over its {FUZZ_BUDGET_S:.0f} s budget"
