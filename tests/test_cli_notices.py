"""The command line says what it waits for: kernel compilation (one-time) and long work."""

from __future__ import annotations

import os
import subprocess
import sys

import numba
import pytest
from numba.core import event

from vpsim.cli import notices


@pytest.fixture
def heard(monkeypatch):
    """A fresh compile listener whose messages are collected instead of printed."""
    said: list[str] = []
    monkeypatch.setattr(notices, "_listener", None)
    assert notices.announce_compilation(say=said.append)
    yield said
    event.unregister("numba:compile", notices._listener)


def _jitted_in(module: str, body: str):
    """A jitted function whose source module is ``module`` (as the kernels' are vpsim's)."""
    ns = {"__name__": module}
    exec(f"def f(x):\n    {body}\n", ns)
    return numba.njit(ns["f"])


def test_compilation_of_a_vpsim_kernel_is_announced_once_as_one_time(heard):
    f = _jitted_in("vpsim.methods._fdm_rosenbrock", "return x + 1.0")
    g = _jitted_in("vpsim.methods._fdm_rosenbrock", "return x * 2.0")
    assert f(1.0) == 2.0 and g(1.0) == 2.0 and f(2.0) == 3.0
    assert len(heard) == 1, heard
    assert "compiling the forward integrator" in heard[0] and "one-time" in heard[0]


def test_other_compilations_are_not_announced(heard):
    f = _jitted_in("someone_else", "return x - 1.0")
    assert f(1.0) == 0.0
    assert heard == []


def test_nested_compilation_is_part_of_the_outer_one(heard):
    inner = _jitted_in("vpsim.model.engine", "return x + 1.0")
    ns = {"__name__": "vpsim.methods.inverse", "inner": inner}
    exec("def outer(x):\n    return inner(x) * 2.0\n", ns)
    outer = numba.njit(ns["outer"])
    assert outer(1.0) == 4.0
    assert len(heard) == 1 and "inverse kernels" in heard[0], heard


def test_cold_kernels_sees_an_empty_disk_cache(tmp_path):
    code = "from vpsim.cli.notices import cold_kernels; print(cold_kernels(['forward', 'inverse']))"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert "forward integrator" in out.stdout and "inverse kernels" in out.stdout, out


def test_cold_kernels_is_empty_once_compiled():
    from vpsim.methods import forward

    forward.warm_up()  # loads or compiles, and so fills the disk cache
    assert "forward integrator" not in notices.cold_kernels(["forward"])
