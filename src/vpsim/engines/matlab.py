"""Safe reader for ADVISOR data files, which are small MATLAB scripts that assign numbers.

Nothing in a file is ever run by Python or by MATLAB. The text is tokenised, parsed into a syntax tree and
evaluated here, over numpy, for a small MATLAB subset: the subset NREL ADVISOR 2003's fuel-converter files
(``FC_SI41_emis.m``, ``FC_SI63_emis.m``) use, plus a few obvious siblings. Everything else is refused with
:class:`vpsim.errors.EngineFileError` and a one-line message ``FILE:LINE: what is wrong``.

    >>> from vpsim.engines.matlab import evaluate_m_text
    >>> v = evaluate_m_text("x = [1 2; 3 4]';  y = x(end, :) .* 2;  n = length(x(:));")
    >>> v["y"].tolist(), v["n"]
    ([4.0, 8.0], 4.0)

Supported
    * Literals: numbers (``3``, ``1e-3``, ``.5``, ``1E-04``), text ``'it''s'`` / ``"text"`` (both become
      Python ``str``), matrices ``[a b; c d]`` (spaces, commas, ``;`` or newlines; nested concatenation),
      1-D cell arrays of any values ``{'a', 'b'}``.
    * Operators, with MATLAB precedence: ``+ - * / ^ .* ./ .^``, unary ``- + ~``, transpose ``'`` and ``.'``,
      ranges ``a:b`` and ``a:s:b``, comparisons ``== ~= < <= > >=``, ``& | && ||``, parentheses.
      ``*`` is the matrix product; ``/`` and ``^`` need a scalar divisor or scalar operands.
      Operands of element-wise operators must have equal sizes, or one of them must be a scalar
      (MATLAB's implicit expansion is not done, so a size mismatch is an error, as in MATLAB before 2016b).
    * Indexing of variables: ``x(3)``, ``x(end)``, ``x(:)``, ``x(2:end)``, ``x(i, j)``, ``x(i, :)``, cell
      contents ``c{i}``; indexed assignment ``x(i, :) = ...`` (growing with zeros as in MATLAB); multiple
      assignment ``[a, b] = f(...)``.
    * Statements: ``;`` ``,`` or newline separators, ``%`` and ``%{ ... %}`` comments, ``...``
      continuations, ``for v = expr ... end``, ``if / elseif / else ... end``, ``clear`` (command or
      function syntax; names may hold ``*`` wildcards, as in ``clear temp*``).
    * Constants ``pi``, ``eps``, ``Inf``/``inf``, ``true``, ``false``. ``NaN`` is refused.
    * Functions: ``zeros ones size length numel max min sum abs sqrt round floor ceil interp1 meshgrid
      linspace find fliplr flipud isempty exist disp inline eval``.
        - ``find(x)`` gives the 1-based linear positions of the non-zero elements (column-major): a row
          for a row vector, a column otherwise; ``[i, j] = find(x)`` and ``find(x, n)`` are refused.
        - ``disp`` prints nothing (it is accepted and ignored).
        - ``exist(name)`` / ``exist(name, 'var')`` only looks at the variables assigned so far (1 or 0),
          never at files or the MATLAB path.
        - ``inline(expr, args...)`` is stored as an :class:`InlineFunction` holding the text; it is never
          evaluated or called.
        - ``eval(text)`` is accepted only in the form ADVISOR uses to build its cold-start maps: the text must
          be one plain assignment ``name = expression``, which is then tokenised, parsed and evaluated by
          this same reader (never by Python or MATLAB). Calls to ``eval``, ``inline``, ``disp`` and
          ``clear`` are not allowed inside it. Any other use of ``eval`` is an error.
        - ``interp1(x, y, xi)`` is linear; query points outside ``x`` are an error (MATLAB gives NaN).

Refused (EngineFileError)
    unknown functions and commands (``system``, ``load``, ``evalin``, ``feval`` ...), shell escapes ``!``,
    function handles ``@``, struct fields ``a.b``, ``while``/``switch``/``function``/``try`` blocks,
    references to undefined variables, unclosed brackets or strings, inconsistent sizes in concatenation or
    arithmetic, number literals that overflow (``1e400``), any NaN, any operation that overflows or divides
    by zero, complex results, files over 5 MB, arrays over 1e6 elements (ranges such as ``1:1e12`` are
    checked before they are made), more than 1e8 array elements computed in total, more than 1e6
    statements executed, expressions nested more than 32 deep, cell arrays holding more than 1e6 values
    (nested cells counted in full: ``c = {c c}`` doubles the count, so a shared cell tree cannot grow
    exponentially) or nested more than 32 deep, and more than 1e7 values left in the variables at the end.

Values returned by :func:`read_m_file`: numeric 1x1 -> ``float``; 1xN or Nx1 -> 1-D ``np.ndarray``;
other numeric -> 2-D ``np.ndarray`` (float64; MATLAB logicals become 0.0/1.0); text -> ``str``; cell
array -> ``tuple``; ``inline`` -> :class:`InlineFunction`.

The reader's parts are private modules beside this one, which holds the public API:
:mod:`vpsim.engines._matlab_tokens` (the tokenizer), :mod:`vpsim.engines._matlab_parser` (the syntax tree and
the parser), :mod:`vpsim.engines._matlab_interp` (the interpreter) with :mod:`vpsim.engines._matlab_builtins`
(the built-in functions) and :mod:`vpsim.engines._matlab_values` (helpers on values), all on
:mod:`vpsim.engines._matlab_base` (the limits, :class:`InlineFunction`, ``MValue`` and the internal error).
"""

from __future__ import annotations

import errno
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import EngineFileError
from ._matlab_base import (
    MAX_ELEMENTS,
    MAX_EXPORT_ELEMENTS,
    MAX_FILE_BYTES,
    MAX_TOKENS,
    InlineFunction,
    MValue,
    _MError,
)
from ._matlab_interp import _Interp
from ._matlab_parser import _Parser
from ._matlab_tokens import _tokenize
from ._matlab_values import _Cell

__all__ = [
    "MAX_ELEMENTS",
    "MAX_FILE_BYTES",
    "MAX_TOKENS",
    "InlineFunction",
    "MValue",
    "evaluate_m_text",
    "read_m_file",
]


def _export(v: Any) -> MValue:
    if isinstance(v, np.ndarray):
        a = np.asarray(v, dtype=float)
        if a.shape == (1, 1):
            return float(a[0, 0])
        if a.size == 0 or 1 in a.shape:
            return a.ravel().copy()
        return a.copy()
    if isinstance(v, tuple):
        return tuple(_export(x) for x in v)
    return v


def evaluate_m_text(text: str, source: str = "<text>") -> dict[str, MValue]:
    """Evaluate MATLAB data-file text safely; return every variable left assigned at the end.

    ``source`` names the text in error messages (``source:LINE: what is wrong``).
    """
    if len(text) > MAX_FILE_BYTES:
        raise EngineFileError(f"{source}:1: text is longer than the {MAX_FILE_BYTES}-byte limit")
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    ip = _Interp()
    parser: _Parser | None = None
    try:
        parser = _Parser(_tokenize(text))
        program = parser.parse_program()
        parser = None
        ip.run(program)
    except _MError as e:
        raise EngineFileError(f"{source}:{e.line}: {e.msg}") from None
    except (RecursionError, MemoryError):
        line = parser.peek().line if parser is not None else ip.line
        raise EngineFileError(f"{source}:{line}: input too complex to read safely") from None
    total = sum(_exported_size(v) for v in ip.vars.values())
    if total > MAX_EXPORT_ELEMENTS:
        raise EngineFileError(
            f"{source}:{ip.line}: the variables left at the end hold {total} values, more than the limit "
            f"of {MAX_EXPORT_ELEMENTS}"
        )
    return {name: _export(v) for name, v in ip.vars.items()}


def _exported_size(v: Any) -> int:
    if isinstance(v, _Cell):
        return v.count
    if isinstance(v, np.ndarray):
        return int(v.size)
    return 1


def read_m_file(path: str | Path) -> dict[str, MValue]:
    """Read an ADVISOR ``.m`` data file without running it; return its variables.

    The file is evaluated by the safe subset described in this module's docstring, with ADVISOR's
    defaults (``fc_spd_scale = fc_trq_scale = 1``, as the files themselves assign). Any problem raises
    :class:`~vpsim.errors.EngineFileError` with the message ``FILE:LINE: what is wrong``.
    """
    from ..textio import check_path

    p = check_path(path, EngineFileError, "engine file")
    try:
        size = p.stat().st_size
        if not p.is_file():
            raise EngineFileError(f"{p}:1: not a regular file")
        if size > MAX_FILE_BYTES:
            raise EngineFileError(f"{p}:1: file is {size} bytes, more than the {MAX_FILE_BYTES}-byte limit")
        with p.open("rb") as f:
            raw = f.read(MAX_FILE_BYTES + 1)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise EngineFileError(f"{p}: symbolic link loop (too many levels of symbolic links)") from None
        raise EngineFileError(f"{p}:1: cannot read file ({e.strerror or e})") from None
    if len(raw) > MAX_FILE_BYTES:
        raise EngineFileError(f"{p}:1: file is more than the {MAX_FILE_BYTES}-byte limit")
    nul = raw.find(b"\x00")
    if nul >= 0:
        line = raw.count(b"\n", 0, nul) + 1
        raise EngineFileError(f"{p}:{line}: NUL byte: this is a binary file, not a MATLAB text file")
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise EngineFileError(f"{p}:1: not a text file in UTF-8 (UTF-16 byte-order mark); save it as UTF-8")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")  # old ADVISOR files are ISO-8859-1; only comments hold such bytes
    return evaluate_m_text(text, str(p))
