"""Shared fixtures. Reference data lives in ``../shared`` beside the repository and is never copied in."""

from __future__ import annotations

import importlib.util
import os
import tempfile
from pathlib import Path

import matplotlib
import pytest

matplotlib.use("Agg")

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("VPSIM_SHARED", REPO.parent / "shared"))
# FASTSim's remembered runs (vpsim.fleet.peer_cache) in a folder of this test session's, not the user's
# cache: every test run starts without them (the commands the tests start inherit it)
os.environ["VPSIM_CACHE_DIR"] = tempfile.mkdtemp(prefix="vpsim-test-cache-")


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


@pytest.fixture(scope="session")
def benchmark_script():
    """Load a script of ``benchmarks/`` (not a package) as a module: ``benchmark_script("readme_table")``."""

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, REPO / "benchmarks" / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod

    return load
