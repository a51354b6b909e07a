"""The fuzz suite's Hypothesis profile: derandomized by default, so a commit's test run is the same on every
machine (a clean run here is a clean CI run); ``VPSIM_FUZZ_EXPLORE=1`` draws fresh random cases to look for
new failures (a failure prints the blob that reproduces it).

Every generated case must give a valid result or one clear line (see ``_fuzz.py``); the whole suite runs in
well under a minute on two cores (``max_examples`` is set per test, no per-example deadline).
"""

from __future__ import annotations

import os
import time

import pytest
from hypothesis import settings

settings.register_profile(
    "vpsim-fuzz", deadline=None, derandomize=not os.environ.get("VPSIM_FUZZ_EXPLORE"), print_blob=True
)
settings.load_profile("vpsim-fuzz")

# the fuzz suite's own time, printed at the end of a run (about 45-50 s on two quiet cores). It is reported,
# not asserted: a timed test fails on a loaded machine, not on slow code (speed lives in the benchmarks)
_spent: list[float] = []


@pytest.fixture(autouse=True)
def _fuzz_clock():
    """Time each fuzz test, for the summary line below."""
    t0 = time.perf_counter()
    yield
    _spent.append(time.perf_counter() - t0)


def pytest_terminal_summary(terminalreporter):
    if _spent:
        terminalreporter.write_line(f"fuzz suite: {len(_spent)} tests in {sum(_spent):.0f} s")
