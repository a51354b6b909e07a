"""The fuzz suite's Hypothesis profile: reproducible in CI (``CI`` set: derandomized), exploring locally.

Every generated case must give a valid result or one clear line (see ``_fuzz.py``); the whole suite runs in
well under a minute on two cores (``max_examples`` is set per test, no per-example deadline).
"""

from __future__ import annotations

import os

from hypothesis import settings

settings.register_profile(
    "vpsim-fuzz", deadline=None, derandomize=bool(os.environ.get("CI")), print_blob=True
)
settings.load_profile("vpsim-fuzz")
