"""What every stage of the safe MATLAB reader shares: its limits, the value types it returns
(:class:`InlineFunction`, ``MValue``) and its internal error ``_MError``, with ``_short`` for messages.

:mod:`vpsim.engines.matlab` describes the subset and holds the public API (it re-exports the public names of
this module). The stages build on this one: :mod:`vpsim.engines._matlab_tokens` (text to tokens),
:mod:`vpsim.engines._matlab_parser` (tokens to a syntax tree) and :mod:`vpsim.engines._matlab_interp` (runs
the tree, with :mod:`vpsim.engines._matlab_values` and :mod:`vpsim.engines._matlab_builtins`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_FILE_BYTES = 5 * 1024 * 1024  # largest .m file read
MAX_ELEMENTS = 1_000_000  # largest array made
MAX_WORK = 100_000_000  # array elements computed by all operations of one file together
MAX_STATEMENTS = 1_000_000  # statements executed (loop bodies count once per pass)
# tokens (numbers, names, operators) read from one text: ADVISOR's largest data files hold a few thousand
# (FC_SI63_emis.m 2,383; a 2-hour cycle at 1 Hz about 30,000). Reading and parsing run at about 0.1-0.2 M
# tokens per second, so this bounds a hostile file's time to a few seconds (5 MB of them took 30-50 s and
# 900 MB to refuse)
MAX_TOKENS = 200_000
MAX_NESTING = 32  # parentheses / brackets / unary operators nested in one expression
MAX_TREE_DEPTH = 200  # depth of one expression's syntax tree (long chains such as 1+1+...+1)
MAX_EVAL_CHARS = 10_000  # longest text accepted by eval(...)
MAX_NAME_CHARS = 63  # MATLAB's namelengthmax
MAX_CELL_ELEMENTS = MAX_ELEMENTS  # values held by one cell array, counted through nested cells and arrays
MAX_CELL_DEPTH = 32  # cell arrays nested in cell arrays
MAX_EXPORT_ELEMENTS = 10 * MAX_ELEMENTS  # values returned for all variables together (each is a copy)


@dataclass(frozen=True)
class InlineFunction:
    """``inline('expr', 'arg1', ...)`` from a data file: kept as text only, never evaluated or called."""

    expression: str
    args: tuple[str, ...]


MValue = np.ndarray | float | str | tuple | InlineFunction


class _MError(Exception):
    """Internal error carrying the line it refers to; turned into EngineFileError at the top."""

    def __init__(self, line: int, msg: str) -> None:
        super().__init__(msg)
        self.line = line
        self.msg = msg


def _short(text: str, limit: int = 40) -> str:
    """A user-supplied text as a one-line, length-limited repr for messages."""
    if len(text) > limit:
        text = text[:limit] + "..."
    return repr(text)
