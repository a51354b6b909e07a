"""Helpers on the safe MATLAB reader's run-time values (2-D numpy arrays, texts, cell arrays, inline
functions): their shapes, their conversion to numbers and whole numbers, cell arrays with their bounded
size (``_Cell``) and the check of an array's size against the element limit.

Shared by the interpreter (:mod:`vpsim.engines._matlab_interp`) and its built-in functions
(:mod:`vpsim.engines._matlab_builtins`); :func:`vpsim.engines.matlab.evaluate_m_text` reads a ``_Cell``'s size
when it exports the variables.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ._matlab_base import MAX_CELL_DEPTH, MAX_CELL_ELEMENTS, MAX_ELEMENTS, _MError, _short


def _shape(v: Any) -> tuple[int, int]:
    if isinstance(v, np.ndarray):
        return v.shape[0], v.shape[1]
    if isinstance(v, str | tuple):
        return (1, len(v)) if len(v) else (0, 0)
    return 1, 1


def _fmt_shape(v: Any) -> str:
    r, c = _shape(v)
    return f"{r}x{c}"


def _scalar(x: float) -> np.ndarray:
    return np.array([[float(x)]])


def _num(v: Any, line: int, what: str = "operand") -> np.ndarray:
    if isinstance(v, np.ndarray):
        return v.astype(float) if v.dtype == bool else v
    if isinstance(v, str):
        raise _MError(line, f"text {_short(v)} used as a number ({what}); text arithmetic is not supported")
    if isinstance(v, tuple):
        raise _MError(line, f"a cell array used as a number ({what})")
    raise _MError(line, f"an inline function used as a number ({what})")


def _int_arg(v: Any, line: int, what: str, minimum: int = 0) -> int:
    a = _num(v, line, what)
    if a.size != 1:
        raise _MError(line, f"{what} must be a scalar, got {_fmt_shape(a)}")
    x = float(a.flat[0])
    if not math.isfinite(x) or x != math.floor(x):
        raise _MError(line, f"{what} must be a whole number, got {x:g}")
    if x < minimum:
        raise _MError(line, f"{what} must be at least {minimum}, got {x:g}")
    return int(x)


class _Cell(tuple):
    """A cell array with the size of its expanded contents: ``count`` values (array elements, texts and
    inner cells' values; a shared inner cell counts once per occurrence, as the export copies it) and
    ``depth`` (cells nested), both bounded so that nothing built from a small file can blow up."""

    count: int
    depth: int


def _make_cell(items, line: int) -> _Cell:
    count, depth = 0, 0
    for x in items:
        if isinstance(x, _Cell):
            count += x.count
            depth = max(depth, x.depth)
        elif isinstance(x, np.ndarray):
            count += max(int(x.size), 1)
        else:
            count += 1
    cell = _Cell(items)
    cell.count, cell.depth = count, depth + 1
    if cell.depth > MAX_CELL_DEPTH:
        raise _MError(line, f"cell arrays nested {cell.depth} deep, more than the limit of {MAX_CELL_DEPTH}")
    if count > MAX_CELL_ELEMENTS:
        raise _MError(
            line,
            f"cell array would hold {count} values (nested cells counted in full), more than the limit of "
            f"{MAX_CELL_ELEMENTS}",
        )
    return cell


def _check_size(count: int, line: int, what: str) -> None:
    if count > MAX_ELEMENTS:
        raise _MError(line, f"{what} would have {count} elements, more than the limit of {MAX_ELEMENTS}")
