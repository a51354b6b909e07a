"""How vpsim compiles: one decorator for every kernel, and an on-disk cache stamped with what each uses.

Kernels are compiled by Numba on first use and cached on disk (``__pycache__`` beside the module, or
``$NUMBA_CACHE_DIR``); ``pip install .`` builds that cache for the installed package (``setup.py``,
:mod:`vpsim.precompile`), so a first run loads kernels instead of compiling them. Numba stamps a kernel's
cache with its own file's modification time and size, but vpsim's kernels inline the model's equations
from other files (:mod:`vpsim.model.engine`, ...), and an installed file's modification time is the
install's. The cache locator below therefore stamps each kernel with a digest of the sources it uses: its
own function and, transitively, every vpsim function, compiled dispatcher and module-level constant it
reaches (:func:`kernel_digest`). An edited equation recompiles only the kernels that include it, a
kernel built at install is valid wherever the package lands, and nothing depends on file times.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import sys
import types

import numba
import numpy as np
from numba.core import caching

_PACKAGE_PREFIX = "vpsim."
_PLAIN = (bool, int, float, complex, str, bytes, type(None))


def _code_names(code: types.CodeType) -> set[str]:
    names = set(code.co_names)
    for k in code.co_consts:
        if isinstance(k, types.CodeType):
            names |= _code_names(k)
    return names


def _code_token(code: types.CodeType) -> str:
    """What a function compiles from, without where its file lies: its bytecode, the names and constants it
    uses (nested code too) and its first line. Faster than reading the source (microseconds, at every
    import), and the same wherever the package is installed."""
    consts = tuple(_const_token(k) for k in code.co_consts)
    return repr(
        (
            code.co_qualname,
            code.co_firstlineno,
            code.co_argcount,
            code.co_kwonlyargcount,
            code.co_code.hex(),
            code.co_names,
            code.co_varnames,
            code.co_freevars,
            code.co_cellvars,
            consts,
        )
    )


def _const_token(k) -> str:
    if isinstance(k, types.CodeType):
        return _code_token(k)
    if isinstance(k, frozenset):  # (``x in {"a", "b"}``): its order follows the string hash of the process
        return "frozenset" + repr(sorted(repr(x) for x in k))
    return repr(k)


def _source(fn) -> str:
    return _code_token(fn.__code__)


def _ours(obj) -> bool:
    return (getattr(obj, "__module__", None) or "").startswith(_PACKAGE_PREFIX) or (
        getattr(obj, "__module__", None) == "vpsim"
    )


def _value_token(value) -> str | None:
    """A constant's contribution to a kernel's stamp (Numba freezes module-level constants into the code)."""
    if isinstance(value, _PLAIN):
        return repr(value)
    if isinstance(value, tuple) and all(isinstance(v, _PLAIN) for v in value):
        return repr(value)
    if isinstance(value, np.ndarray):
        return f"ndarray{value.dtype.str}{value.shape}:{hashlib.sha256(value.tobytes()).hexdigest()}"
    if isinstance(value, np.dtype):
        return repr(value)
    return None


def _python_function(obj):
    """The Python function behind a compiled dispatcher or a plain function; None for anything else."""
    py = getattr(obj, "py_func", None)
    if isinstance(py, types.FunctionType):
        return py
    return obj if isinstance(obj, types.FunctionType) else None


def _closure(fn) -> list[tuple[str, str]]:
    """(what, token) of every vpsim function and constant ``fn`` reaches, ``fn`` included, transitively."""
    seen: dict[int, None] = {}
    parts: list[tuple[str, str]] = []
    todo = [fn]
    while todo:
        f = todo.pop()
        if id(f) in seen:
            continue
        seen[id(f)] = None
        # how it is compiled into its callers is part of what they compile from: an equation turned into an
        # IR-inlined one (or back) leaves its bytecode as it was
        how = f"|inline={getattr(f, '_vpsim_inline', None)}"
        if hasattr(f, "_vpsim_options"):  # a kernel's own compiler options (fastmath, parallel, ...): not in
            how += f"|options={f._vpsim_options}"  # its bytecode either
        parts.append((f"{f.__module__}.{f.__qualname__}", _source(f) + how))
        names = _code_names(f.__code__)
        values = [(n, f.__globals__[n]) for n in sorted(names) if n in f.__globals__]
        values += [(f"<default {i}>", d) for i, d in enumerate(f.__defaults__ or ())]
        values += [(f"<cell {i}>", c.cell_contents) for i, c in enumerate(f.__closure__ or ())]
        for name, value in values:
            if isinstance(value, types.ModuleType):
                if not (value.__name__ == "vpsim" or value.__name__.startswith(_PACKAGE_PREFIX)):
                    continue
                # an attribute of one of vpsim's modules (``en.idle_throttle``): its names in the code
                for attr in sorted(names):
                    if attr in vars(value):
                        _visit(f"{value.__name__}.{attr}", vars(value)[attr], parts, todo)
                continue
            _visit(f"{f.__module__}:{name}", value, parts, todo)
    return parts


def _visit(name, value, parts, todo) -> None:
    fn = _python_function(value)
    if fn is not None:
        if _ours(fn):
            todo.append(fn)
        return
    token = _value_token(value)
    if token is not None:
        parts.append((name, token))


@functools.cache
def kernel_digest(py_func) -> bytes:
    """The digest of everything ``py_func`` compiles from: its source, the sources of the vpsim functions and
    kernels it calls (transitively) and the values of the module-level constants they read."""
    h = hashlib.sha256()
    for what, token in sorted(set(_closure(py_func))):
        h.update(what.encode())
        h.update(b"\0")
        h.update(token.encode())
        h.update(b"\1")
    return h.digest()


def _locator(base):
    class _VpsimLocator(base):
        """``base`` for vpsim's kernels, stamped with :func:`kernel_digest` instead of the file's time."""

        def get_source_stamp(self):
            return ("vpsim-kernel-digest", kernel_digest(self._vpsim_py_func))

        @classmethod
        def from_function(cls, py_func, py_file):
            if not _ours(py_func):
                return None
            self = super().from_function(py_func, py_file)
            if self is not None:
                self._vpsim_py_func = py_func
            return self

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


KERNEL_STAMPS = _install()  # whether each kernel's cache is stamped with the sources it uses (see above)


def _scipy_present() -> None:
    """Numba's BLAS probe answered without importing SciPy: raises ImportError where SciPy is absent."""
    if importlib.util.find_spec("scipy") is None:
        raise ImportError("scipy 0.16+ is required for linear algebra")


def _load_arraymath_without_scipy_linalg() -> bool:
    """Import ``numba.np.arraymath`` with its BLAS probe answered by whether SciPy is installed; True if done.

    Numba imports that module when its CPU target first loads (the first kernel compiled, or loaded from
    the cache), and the module asks at import whether BLAS is there by importing ``scipy.linalg``: 0.22-0.26
    s on the 2-core development machine, a quarter of a fresh process's first run (2026-12-06, UDDS from
    the cache: 1.00-1.09 s wall, 0.75-0.88 s without it). The answer (``arraymath._HAVE_BLAS``) only chooses
    how compiled ``np.correlate``/``np.convolve`` multiply, which no vpsim kernel uses; compiling any BLAS
    call still goes through Numba's own check (restored here), which imports SciPy then. Left to Numba
    where its module layout differs or the module is already loaded."""
    if "numba.np.arraymath" in sys.modules:
        return False
    try:
        from numba.np import linalg
    except ImportError:  # pragma: no cover - a Numba whose linalg module moved
        return False
    real = getattr(linalg, "ensure_blas", None)
    if real is None:  # pragma: no cover
        return False
    linalg.ensure_blas = _scipy_present
    try:
        from numba.np import arraymath
    finally:
        linalg.ensure_blas = real
    if getattr(arraymath, "ensure_blas", None) is _scipy_present:
        arraymath.ensure_blas = real
    return True


ARRAYMATH_EARLY = _load_arraymath_without_scipy_linalg()

_OPTIONS = {"cache": True, "nogil": True, "error_model": "numpy"}


def kernel(fn=None, **options):
    """``numba.njit`` with vpsim's options (on-disk cache, GIL released, NumPy's float error model)."""
    if fn is None:
        return functools.partial(kernel, **options)
    if options:  # part of the kernel's cache stamp (:func:`kernel_digest`)
        fn._vpsim_options = repr(sorted((k, repr(v)) for k, v in options.items()))
    return numba.njit(**{**_OPTIONS, **options})(fn)


def compiled(*kernels) -> bool:
    """Whether every kernel is compiled (or loaded from the cache) already; True for plain Python functions,
    as the kernels are with Numba's JIT disabled (``NUMBA_DISABLE_JIT=1``, for debugging)."""
    return all(getattr(k, "overloads", True) for k in kernels)
