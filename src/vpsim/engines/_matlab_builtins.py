"""The safe MATLAB reader's built-in functions (``zeros``, ``size``, ``max``, ``interp1``, ``find``, ``eval``
...) and their table ``_BUILTINS``, which the ``_builtin`` decorator and the assignments below fill when this
module is imported.

Each built-in takes the interpreter, its evaluated arguments, the number of outputs requested and the line,
and returns its outputs. :mod:`vpsim.engines._matlab_interp` imports the table from here, so the table is
complete before any interpreter runs; the interpreter is only named in annotations here.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from ._matlab_base import MAX_EVAL_CHARS, InlineFunction, _MError, _short
from ._matlab_parser import _Assign, _Name, _Parser
from ._matlab_tokens import _tokenize
from ._matlab_values import _check_size, _fmt_shape, _int_arg, _num, _scalar, _shape

if TYPE_CHECKING:
    from ._matlab_interp import _Interp

_Builtin = Callable[["_Interp", list, int, int], list]
_BUILTINS: dict[str, _Builtin] = {}


def _builtin(*names: str) -> Callable[[_Builtin], _Builtin]:
    def register(fn: _Builtin) -> _Builtin:
        for name in names:
            _BUILTINS[name] = fn
        return fn

    return register


def _nargs(name: str, args: list, line: int, low: int, high: int) -> None:
    if not low <= len(args) <= high:
        want = str(low) if low == high else f"{low} to {high}"
        raise _MError(line, f"{name} takes {want} argument(s), got {len(args)}")


def _dims(name: str, args: list, line: int) -> tuple[int, int]:
    if not args:
        return 1, 1
    if len(args) == 1:
        a = _num(args[0], line, f"{name} size")
        if a.size == 1:
            n = max(0, _int_arg(a, line, f"{name} size", minimum=-(2**62)))
            return n, n
        if a.size == 2:
            r, c = (max(0, _int_arg(_scalar(x), line, f"{name} size", -(2**62))) for x in a.ravel())
            return r, c
        raise _MError(line, f"{name}: only 2-D sizes are supported")
    if len(args) == 2:
        r, c = (max(0, _int_arg(x, line, f"{name} size", -(2**62))) for x in args)
        return r, c
    raise _MError(line, f"{name}: only 2-D sizes are supported")


def _make_filler(fill: float) -> _Builtin:
    def filler(ip: _Interp, args: list, nargout: int, line: int) -> list:
        r, c = _dims("zeros" if fill == 0.0 else "ones", args, line)
        _check_size(r * c, line, "zeros/ones")
        return [ip.result(np.full((r, c), fill), line)]

    return filler


_BUILTINS["zeros"] = _make_filler(0.0)
_BUILTINS["ones"] = _make_filler(1.0)


@_builtin("size")
def _f_size(ip: _Interp, args: list, nargout: int, line: int) -> list:
    _nargs("size", args, line, 1, 2)
    r, c = _shape(args[0])
    if len(args) == 2:
        d = _int_arg(args[1], line, "size dimension", minimum=1)
        return [_scalar((r, c)[d - 1] if d <= 2 else 1)]
    if nargout >= 2:
        if nargout > 2:
            raise _MError(line, "size: only 2-D arrays are supported")
        return [_scalar(r), _scalar(c)]
    return [np.array([[float(r), float(c)]])]


@_builtin("length")
def _f_length(ip: _Interp, args: list, nargout: int, line: int) -> list:
    _nargs("length", args, line, 1, 1)
    r, c = _shape(args[0])
    return [_scalar(0 if r * c == 0 else max(r, c))]


@_builtin("numel")
def _f_numel(ip: _Interp, args: list, nargout: int, line: int) -> list:
    _nargs("numel", args, line, 1, 1)
    r, c = _shape(args[0])
    return [_scalar(r * c)]


def _reduce_dim(a: np.ndarray, args: list, dim_pos: int, line: int, name: str) -> int:
    if len(args) > dim_pos:
        d = _int_arg(args[dim_pos], line, f"{name} dimension", minimum=1)
        if d > 2:
            raise _MError(line, f"{name}: only dimensions 1 and 2 are supported")
        return d - 1
    return 1 if a.shape[0] == 1 else 0


def _make_minmax(name: str) -> _Builtin:
    pick = np.maximum if name == "max" else np.minimum
    arg = np.argmax if name == "max" else np.argmin

    def minmax(ip: _Interp, args: list, nargout: int, line: int) -> list:
        _nargs(name, args, line, 1, 3)
        if len(args) == 2:
            if nargout > 1:
                raise _MError(line, f"[m, i] = {name}(a, b) is not supported")
            a = _num(args[0], line, name)
            b = _num(args[1], line, name)
            if a.shape != b.shape and a.size != 1 and b.size != 1:
                raise _MError(line, f"{name}: dimensions do not agree ({_fmt_shape(a)}, {_fmt_shape(b)})")
            return [ip.result(pick(a, b), line, a, b)]
        a = _num(args[0], line, name)
        if len(args) == 3 and _shape(args[1]) != (0, 0):
            raise _MError(line, f"{name}(x, [], dim): the second argument must be []")
        dim = _reduce_dim(a, args, 2, line, name)
        if a.size == 0:
            return [np.zeros((0, 0)), np.zeros((0, 0))]
        k = arg(a, axis=dim)
        k = np.expand_dims(k, axis=dim)
        values = np.take_along_axis(a, k, axis=dim)
        return [ip.result(values, line), ip.result(k.astype(float) + 1.0, line)]

    return minmax


_BUILTINS["max"] = _make_minmax("max")
_BUILTINS["min"] = _make_minmax("min")


@_builtin("sum")
def _f_sum(ip: _Interp, args: list, nargout: int, line: int) -> list:
    _nargs("sum", args, line, 1, 2)
    a = _num(args[0], line, "sum")
    if a.shape == (0, 0) and len(args) == 1:
        return [_scalar(0.0)]
    dim = _reduce_dim(a, args, 1, line, "sum")
    with np.errstate(all="ignore"):
        return [ip.result(a.sum(axis=dim, keepdims=True), line, a)]


def _make_elementwise(name: str, fn: Callable[[np.ndarray], np.ndarray]) -> _Builtin:
    def elementwise(ip: _Interp, args: list, nargout: int, line: int) -> list:
        _nargs(name, args, line, 1, 1)
        a = _num(args[0], line, name)
        if name == "sqrt" and np.any(a < 0):
            raise _MError(line, "sqrt of a negative number (complex numbers are not supported)")
        with np.errstate(all="ignore"):
            return [ip.result(fn(a), line, a)]

    return elementwise


_BUILTINS["abs"] = _make_elementwise("abs", np.abs)
_BUILTINS["sqrt"] = _make_elementwise("sqrt", np.sqrt)
_BUILTINS["floor"] = _make_elementwise("floor", np.floor)
_BUILTINS["ceil"] = _make_elementwise("ceil", np.ceil)
# MATLAB rounds halves away from zero (numpy rounds them to even).
_BUILTINS["round"] = _make_elementwise("round", lambda a: np.sign(a) * np.floor(np.abs(a) + 0.5))


@_builtin("interp1")
def _f_interp1(ip: _Interp, args: list, nargout: int, line: int) -> list:
    _nargs("interp1", args, line, 3, 4)
    if len(args) == 4 and not (isinstance(args[3], str) and args[3].lower() == "linear"):
        raise _MError(line, "interp1: only the 'linear' method is supported")
    x = _num(args[0], line, "interp1 x")
    y = _num(args[1], line, "interp1 y")
    xi = _num(args[2], line, "interp1 xi")
    if 1 not in x.shape or 1 not in y.shape or x.size != y.size or x.size < 2:
        raise _MError(line, f"interp1: x and y must be vectors of equal length >= 2, got {_fmt_shape(x)}, "
                      f"{_fmt_shape(y)}")  # fmt: skip
    xv, yv = x.ravel(), y.ravel()
    if np.all(np.diff(xv) < 0):
        xv, yv = xv[::-1], yv[::-1]
    if not np.all(np.diff(xv) > 0):
        raise _MError(line, "interp1: x must be strictly monotonic")
    if xi.size and (xi.min() < xv[0] or xi.max() > xv[-1]):
        raise _MError(line, "interp1: query point outside the range of x (MATLAB would give NaN)")
    return [ip.result(np.interp(xi, xv, yv), line, xi)]


@_builtin("meshgrid")
def _f_meshgrid(ip: _Interp, args: list, nargout: int, line: int) -> list:
    _nargs("meshgrid", args, line, 1, 2)
    if nargout > 2:
        raise _MError(line, "meshgrid: only 2-D grids are supported")
    x = _num(args[0], line, "meshgrid x")
    y = _num(args[-1], line, "meshgrid y")
    if (x.size and 1 not in x.shape) or (y.size and 1 not in y.shape):
        raise _MError(line, "meshgrid: arguments must be vectors")
    _check_size(x.size * y.size, line, "meshgrid")
    xx, yy = np.meshgrid(x.ravel(), y.ravel())
    return [ip.result(xx, line), ip.result(yy, line)]


@_builtin("find")
def _f_find(ip: _Interp, args: list, nargout: int, line: int) -> list:
    _nargs("find", args, line, 1, 1)
    if nargout > 1:
        raise _MError(line, "[i, j] = find(x) is not supported; use k = find(x)")
    a = _num(args[0], line, "find")
    # 1-based linear positions of the non-zero elements, in MATLAB's column-major order; a row vector
    # gives a row (1x0 when nothing is found), anything else a column.
    k = np.flatnonzero(a.ravel(order="F") != 0).astype(float) + 1.0
    shape = (1, k.size) if a.shape[0] == 1 and a.size else (k.size, 1)
    if a.size == 0:
        shape = (0, 0)
    return [ip.result(k.reshape(shape), line)]


def _make_flip(name: str, axis: int) -> _Builtin:
    def flip(ip: _Interp, args: list, nargout: int, line: int) -> list:
        _nargs(name, args, line, 1, 1)
        a = _num(args[0], line, name)
        return [ip.result(np.flip(a, axis=axis).copy(), line)]

    return flip


_BUILTINS["fliplr"] = _make_flip("fliplr", 1)
_BUILTINS["flipud"] = _make_flip("flipud", 0)


@_builtin("isempty")
def _f_isempty(ip: _Interp, args: list, nargout: int, line: int) -> list:
    _nargs("isempty", args, line, 1, 1)
    r, c = _shape(args[0])
    return [_scalar(1.0 if r * c == 0 else 0.0)]


@_builtin("linspace")
def _f_linspace(ip: _Interp, args: list, nargout: int, line: int) -> list:
    _nargs("linspace", args, line, 2, 3)
    a = _num(args[0], line, "linspace start")
    b = _num(args[1], line, "linspace end")
    if a.size != 1 or b.size != 1:
        raise _MError(line, "linspace: start and end must be scalars")
    n = _int_arg(args[2], line, "linspace count") if len(args) == 3 else 100
    _check_size(n, line, "linspace")
    with np.errstate(all="ignore"):
        return [ip.result(np.linspace(a.flat[0], b.flat[0], n).reshape(1, -1), line, a, b)]


@_builtin("exist")
def _f_exist(ip: _Interp, args: list, nargout: int, line: int) -> list:
    _nargs("exist", args, line, 1, 2)
    if not isinstance(args[0], str):
        raise _MError(line, "exist: the name must be text")
    if len(args) == 2 and args[1] != "var":
        raise _MError(line, "exist: only exist(name) and exist(name, 'var') are supported")
    return [_scalar(1.0 if args[0] in ip.vars else 0.0)]


@_builtin("disp")
def _f_disp(ip: _Interp, args: list, nargout: int, line: int) -> list:
    _nargs("disp", args, line, 1, 1)
    return []  # reading a data file prints nothing


@_builtin("clear")
def _f_clear(ip: _Interp, args: list, nargout: int, line: int) -> list:
    if not all(isinstance(a, str) for a in args):
        raise _MError(line, "clear: arguments must be variable names as text")
    ip.clear(tuple(args), line)
    return []


@_builtin("inline")
def _f_inline(ip: _Interp, args: list, nargout: int, line: int) -> list:
    if not args or not all(isinstance(a, str) for a in args):
        raise _MError(line, "inline: arguments must be text")
    return [InlineFunction(args[0], tuple(args[1:]))]


@_builtin("eval")
def _f_eval(ip: _Interp, args: list, nargout: int, line: int) -> list:
    if len(args) != 1 or not isinstance(args[0], str):
        raise _MError(line, "eval: only eval(text) with one text argument is supported")
    text = args[0]
    if len(text) > MAX_EVAL_CHARS:
        raise _MError(line, f"eval: text longer than {MAX_EVAL_CHARS} characters")
    try:
        stmts = _Parser(_tokenize(text)).parse_program()
    except _MError as e:
        raise _MError(line, f"in eval text {_short(text)}: {e.msg}") from None
    single = len(stmts) == 1 and isinstance(stmts[0], _Assign) and len(stmts[0].targets) == 1
    if not single or not isinstance(stmts[0].targets[0], _Name):
        msg = f"eval is only supported for one assignment 'name = expression', got {_short(text)}"
        raise _MError(line, msg)
    ip.in_eval = True
    try:
        ip.run(stmts)
    except _MError as e:
        raise _MError(line, f"in eval text {_short(text)}: {e.msg}") from None
    finally:
        ip.in_eval = False
    return []
