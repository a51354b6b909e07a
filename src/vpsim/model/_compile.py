"""How vpsim compiles: one decorator for every kernel, and an on-disk cache that knows the whole model.

Kernels are compiled by Numba on first use and cached on disk (``__pycache__`` beside the module, or
``$NUMBA_CACHE_DIR``). Numba keys a kernel's cache on its own source file only, but vpsim's kernels inline
the model's equations from other files (:mod:`vpsim.model.engine`, ...): an edited equation would leave a
stale kernel on disk. The cache locator below therefore stamps every vpsim kernel with a hash of all the
package's compiled sources (the model, the methods, the drivers, the batch), so a change anywhere in them
recompiles every kernel. Installed packages never change, so this costs nothing there.
"""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path

import numba
from numba.core import caching

_PACKAGE = Path(__file__).resolve().parent.parent  # src/vpsim
_COMPILED_SOURCES = ("model", "methods", "drivers", "batch.py")


@functools.lru_cache(maxsize=1)
def _sources_digest() -> bytes:
    h = hashlib.sha256()
    files: list[Path] = []
    for name in _COMPILED_SOURCES:
        p = _PACKAGE / name
        files += sorted(p.rglob("*.py")) if p.is_dir() else [p]
    for f in files:
        try:
            h.update(f.relative_to(_PACKAGE).as_posix().encode())
            h.update(f.read_bytes())
        except OSError:  # pragma: no cover - a file removed while running
            continue
    return h.digest()


def _in_package(py_file: str) -> bool:
    try:
        Path(py_file).resolve().relative_to(_PACKAGE)
    except (ValueError, OSError):
        return False
    return True


def _locator(base):
    class _VpsimLocator(base):
        """``base`` for vpsim's files, with the whole model's sources in the cache stamp."""

        def get_source_stamp(self):
            return (super().get_source_stamp(), _sources_digest())

        @classmethod
        def from_function(cls, py_func, py_file):
            if not _in_package(py_file):
                return None
            return super().from_function(py_func, py_file)

    _VpsimLocator.__name__ = f"Vpsim{base.__name__.lstrip('_')}"
    return _VpsimLocator


def _install() -> bool:
    """Put vpsim's locators first; False (numba's own, per-file stamps) if this Numba's internals differ."""
    try:
        impl = caching.CacheImpl if hasattr(caching, "CacheImpl") else caching._CacheImpl
        names = (
            ("UserProvidedCacheLocator", "_UserProvidedCacheLocator"),
            ("InTreeCacheLocator", "_InTreeCacheLocator"),
        )
        bases = [getattr(caching, a, None) or getattr(caching, b) for a, b in names]
        ours = [_locator(b) for b in bases]
        if not any(getattr(c, "_vpsim", False) for c in impl._locator_classes):
            for c in ours:
                c._vpsim = True
            impl._locator_classes = [*ours, *impl._locator_classes]
    except AttributeError:  # pragma: no cover - a Numba whose caching module moved
        return False
    return True


WHOLE_SOURCE_STAMPS = _install()  # whether edits anywhere in the model recompile every kernel

_OPTIONS = {"cache": True, "nogil": True, "error_model": "numpy"}


def kernel(fn=None, **options):
    """``numba.njit`` with vpsim's options (on-disk cache, GIL released, NumPy's float error model)."""
    if fn is None:
        return functools.partial(kernel, **options)
    return numba.njit(**{**_OPTIONS, **options})(fn)
