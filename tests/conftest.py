"""Shared fixtures. Reference data lives in ``../shared`` beside the repository and is never copied in."""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib
import pytest

matplotlib.use("Agg")

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("VPSIM_SHARED", REPO.parent / "shared"))


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The reference-data folder ``../shared``; tests that need it skip with a reason when it is absent."""
    if not (SHARED / "data").is_dir():
        pytest.skip(f"reference data not found at {SHARED} (set VPSIM_SHARED to its location)")
    return SHARED


@pytest.fixture(scope="session")
def params():
    from vpsim.params import load_parameters

    return load_parameters("hofman2011")
