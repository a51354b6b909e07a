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
"""

from __future__ import annotations

import errno
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import EngineFileError

__all__ = [
    "MAX_ELEMENTS",
    "MAX_FILE_BYTES",
    "MAX_TOKENS",
    "InlineFunction",
    "MValue",
    "evaluate_m_text",
    "read_m_file",
]

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

_EPS = float(np.finfo(float).eps)


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


# --------------------------------------------------------------------------------------------- tokens


@dataclass(slots=True)
class _Tok:
    kind: str  # num str id op cmd nl ; , ( ) [ ] { } eof
    value: Any
    line: int


_KEYWORDS = frozenset(
    {
        "for", "end", "if", "elseif", "else", "while", "function", "return", "break", "continue", "switch",
        "case", "otherwise", "try", "catch", "global", "persistent", "parfor", "spmd", "classdef",
    }
)  # fmt: skip
_TWO_CHAR_OPS = frozenset({".*", "./", ".^", ".'", "==", "~=", "<=", ">=", "&&", "||"})
_ONE_CHAR_OPS = frozenset("+-*/^<>&|~=:")
_OPEN = {"(": ")", "[": "]", "{": "}"}
_CLOSE = {")": "(", "]": "[", "}": "{"}


def _value_end(tok: _Tok, in_brackets: bool) -> bool:
    """Whether ``tok`` can end an operand (so a following ``'`` is a transpose, and space separates)."""
    if tok.kind in ("num", "str", ")", "]", "}"):
        return True
    if tok.kind == "id":
        return tok.value not in _KEYWORDS or (tok.value == "end" and in_brackets)
    return tok.kind == "op" and tok.value in ("'", ".'")


def _too_many_tokens(line: int):
    raise _MError(
        line,
        f"more than {MAX_TOKENS} tokens (numbers, names, operators); an ADVISOR data file has a few thousand",
    )


def _tokenize(text: str) -> list[_Tok]:
    toks: list[_Tok] = []
    stack: list[tuple[str, int]] = []  # open brackets and their lines
    i, n, line = 0, len(text), 1
    space = False  # whitespace seen since the previous token
    stmt_start = True

    def in_matrix() -> bool:
        return bool(stack) and stack[-1][0] in "[{"

    def emit(kind: str, value: Any, starts_value: bool = False) -> None:
        nonlocal space, stmt_start
        # Inside [] and {} whitespace between two operands separates elements: [1 -2], [a' b], [x (1)].
        if starts_value and space and in_matrix() and toks and _value_end(toks[-1], True):
            toks.append(_Tok(",", ",", line))
        if len(toks) >= MAX_TOKENS:
            _too_many_tokens(line)
        toks.append(_Tok(kind, value, line))
        space = False
        stmt_start = False

    while i < n:
        c = text[i]
        if c == "\n":
            if stack and stack[-1][0] == "(":
                raise _MError(line, f"line ends inside '(' opened on line {stack[-1][1]} (missing ')')")
            if stack:
                if len(toks) >= MAX_TOKENS:
                    _too_many_tokens(line)
                toks.append(_Tok(";", ";", line))  # a newline inside [] or {} ends a row
            else:
                toks.append(_Tok("nl", "\n", line))
                stmt_start = True
            line += 1
            i += 1
            space = False
            continue
        if c in " \t\f\v":
            space = True
            i += 1
            continue
        if c in ";,":
            if c == ";" and stack and stack[-1][0] == "(":
                raise _MError(line, f"';' inside '(' opened on line {stack[-1][1]}")
            toks.append(_Tok(c, c, line))
            space = False
            stmt_start = not stack
            i += 1
            continue
        if c == "%":
            i, line = _skip_comment(text, i, line)
            continue
        if text.startswith("...", i):  # continuation: the rest of the line is a comment
            j = text.find("\n", i)
            if j < 0:
                i = n
            else:
                i = j + 1
                line += 1
            space = True
            continue
        if c.isdigit() or (c == "." and i + 1 < n and text[i + 1].isdigit()):
            j = _scan_number(text, i, line)
            literal = text[i:j]
            value = float(literal)
            if not math.isfinite(value):
                raise _MError(line, f"number {_short(literal)} overflows to infinity")
            emit("num", value, starts_value=True)
            i = j
            continue
        if c.isascii() and c.isalpha():
            j = i + 1
            while j < n and (text[j].isascii() and (text[j].isalnum() or text[j] == "_")):
                j += 1
            name = text[i:j]
            if len(name) > MAX_NAME_CHARS:
                raise _MError(line, f"name {_short(name)} is longer than {MAX_NAME_CHARS} characters")
            if stmt_start and not stack and name not in _KEYWORDS:
                # Command syntax ("clear T w"): a name, blanks, then a word on the same line.
                k = j
                while k < n and text[k] in " \t":
                    k += 1
                if k > j and k < n and (text[k].isalnum() or text[k] in "_-*"):
                    m = k
                    while m < n and text[m] not in ";,\n%":
                        m += 1
                    emit("cmd", (name, tuple(text[k:m].split())))
                    i = m
                    continue
            emit("id", name, starts_value=True)
            i = j
            continue
        if c == "'" or c == '"':
            if c == "'" and toks and _value_end(toks[-1], in_matrix()) and not (space and in_matrix()):
                emit("op", "'")
                i += 1
                continue
            value, i = _scan_string(text, i, line)
            emit("str", value, starts_value=True)
            continue
        two = text[i : i + 2]
        if two in _TWO_CHAR_OPS:
            emit("op", two)
            i += 2
            continue
        if c == "!":
            raise _MError(line, "'!' (shell escape) is not allowed in a data file")
        if c == "@":
            raise _MError(line, "function handles '@' are not supported")
        if c == "\\" or two == ".\\":
            raise _MError(line, "left division '\\' is not supported")
        if c == ".":
            raise _MError(line, "struct field access '.' is not supported")
        if c in _ONE_CHAR_OPS:
            # In a matrix, "[a -b]" is two elements but "[a - b]" is one.
            unary_here = c in "+-~" and i + 1 < n and text[i + 1] not in " \t" and text[i + 1] != "="
            emit("op", c, starts_value=unary_here)
            i += 1
            continue
        if c in _OPEN:
            emit(c, c, starts_value=True)  # before the push: "[a (1)]" and "[a [1]]" are two elements
            stack.append((c, line))
            i += 1
            continue
        if c in _CLOSE:
            if not stack or stack[-1][0] != _CLOSE[c]:
                raise _MError(line, f"unmatched {c!r}")
            stack.pop()
            emit(c, c)
            i += 1
            continue
        raise _MError(line, f"unexpected character {c!r}")
    if stack:
        opener, at = stack[-1]
        raise _MError(at, f"{opener!r} opened on line {at} is never closed (file truncated?)")
    toks.append(_Tok("eof", None, line))
    return toks


def _skip_comment(text: str, i: int, line: int) -> tuple[int, int]:
    """Skip a ``%`` comment (to the end of the line) or a ``%{ ... %}`` block; return (index, line)."""
    bol = text.rfind("\n", 0, i) + 1
    eol = text.find("\n", i)
    eol = len(text) if eol < 0 else eol
    if text[bol:eol].strip() != "%{":
        return eol, line
    start, depth, pos = line, 0, bol
    while pos < len(text):
        end = text.find("\n", pos)
        end = len(text) if end < 0 else end
        stripped = text[pos:end].strip()
        if stripped == "%{":
            depth += 1
        elif stripped == "%}":
            depth -= 1
            if depth == 0:
                return end, line
        if end < len(text):
            line += 1
        pos = end + 1
    raise _MError(start, "block comment '%{' is never closed")


def _scan_number(text: str, i: int, line: int) -> int:
    n = len(text)
    j = i
    while j < n and text[j].isdigit():
        j += 1
    # "1./x" is 1 ./ x and "1.'" is a transpose: a dot followed by an operator is not part of the number.
    if j < n and text[j] == "." and not (j + 1 < n and text[j + 1] in "*/\\^'"):
        j += 1
        while j < n and text[j].isdigit():
            j += 1
    if j < n and text[j] in "eE":
        k = j + 1
        if k < n and text[k] in "+-":
            k += 1
        if not (k < n and text[k].isdigit()):
            raise _MError(line, f"malformed number {_short(text[i : k + 1])}")
        while k < n and text[k].isdigit():
            k += 1
        j = k
    if j < n and (text[j].isalpha() or text[j] == "_"):
        raise _MError(line, f"malformed number {_short(text[i : j + 1])} (complex numbers are not supported)")
    return j


def _scan_string(text: str, i: int, line: int) -> tuple[str, int]:
    quote = text[i]
    out: list[str] = []
    j = i + 1
    while True:
        if j >= len(text) or text[j] == "\n":
            raise _MError(line, "text literal is not closed on its line")
        ch = text[j]
        if ch == quote:
            if j + 1 < len(text) and text[j + 1] == quote:
                out.append(quote)
                j += 2
                continue
            return "".join(out), j + 1
        out.append(ch)
        j += 1


# ----------------------------------------------------------------------------------------- syntax tree


@dataclass(slots=True)
class _Node:
    line: int


@dataclass(slots=True)
class _Num(_Node):
    value: float


@dataclass(slots=True)
class _Str(_Node):
    value: str


@dataclass(slots=True)
class _Name(_Node):
    name: str


@dataclass(slots=True)
class _End(_Node):
    pass


@dataclass(slots=True)
class _Colon(_Node):
    pass


@dataclass(slots=True)
class _Matrix(_Node):
    rows: list[list[_Node]]
    cell: bool


@dataclass(slots=True)
class _Unary(_Node):
    op: str
    x: _Node


@dataclass(slots=True)
class _Bin(_Node):
    op: str
    a: _Node
    b: _Node


@dataclass(slots=True)
class _Range(_Node):
    start: _Node
    step: _Node | None
    stop: _Node


@dataclass(slots=True)
class _Index(_Node):
    name: str
    args: list[_Node]
    brace: bool


@dataclass(slots=True)
class _Assign(_Node):
    targets: list[_Node]  # _Name, or _Index for x(i, j) = ...
    expr: _Node


@dataclass(slots=True)
class _ExprStmt(_Node):
    expr: _Node


@dataclass(slots=True)
class _Clear(_Node):
    names: tuple[str, ...]


@dataclass(slots=True)
class _For(_Node):
    var: str
    expr: _Node
    body: list[_Node]


@dataclass(slots=True)
class _If(_Node):
    branches: list[tuple[_Node, list[_Node]]]
    orelse: list[_Node]


_COMPARISONS = ("==", "~=", "<", "<=", ">", ">=")
_BINARY_LEVELS: tuple[tuple[str, ...], ...] = (("||",), ("&&",), ("|",), ("&",), _COMPARISONS)


class _Parser:
    def __init__(self, toks: list[_Tok]) -> None:
        self.toks = toks
        self.pos = 0
        self.nesting = 0
        self.index_depth = 0
        self.depth: dict[int, int] = {}

    # token helpers
    def peek(self, k: int = 0) -> _Tok:
        return self.toks[min(self.pos + k, len(self.toks) - 1)]

    def take(self) -> _Tok:
        tok = self.toks[self.pos]
        self.pos += 1
        return tok

    def is_op(self, value: str, k: int = 0) -> bool:
        tok = self.peek(k)
        return tok.kind == "op" and tok.value == value

    def expect(self, kind: str, what: str) -> _Tok:
        tok = self.peek()
        if tok.kind != kind:
            raise _MError(tok.line, f"expected {what}, found {_describe(tok)}")
        return self.take()

    def matching(self, pos: int) -> int:
        """Index of the bracket closing the one at ``pos`` (brackets are balanced by the tokenizer)."""
        depth = 0
        for k in range(pos, len(self.toks)):
            kind = self.toks[k].kind
            if kind in _OPEN:
                depth += 1
            elif kind in _CLOSE:
                depth -= 1
                if depth == 0:
                    return k
        raise _MError(self.toks[pos].line, "unbalanced brackets")  # pragma: no cover - tokenizer checks

    def node(self, node: _Node, *children: _Node | None) -> _Node:
        d = 1 + max((self.depth.get(id(c), 0) for c in children if c is not None), default=0)
        if d > MAX_TREE_DEPTH:
            raise _MError(node.line, f"expression is too long or too deeply nested (> {MAX_TREE_DEPTH})")
        self.depth[id(node)] = d
        return node

    # statements
    def parse_program(self) -> list[_Node]:
        body, term = self.parse_block(frozenset())
        assert term is None
        return body

    def parse_block(self, terminators: frozenset[str], opened: _Tok | None = None) -> tuple[list, str | None]:
        stmts: list[_Node] = []
        while True:
            tok = self.peek()
            if tok.kind in ("nl", ";", ","):
                self.pos += 1
                continue
            if tok.kind == "eof":
                if opened is not None:
                    msg = f"'{opened.value}' on line {opened.line} has no matching 'end'"
                    raise _MError(opened.line, msg)
                return stmts, None
            if tok.kind == "id" and tok.value in terminators:
                self.pos += 1
                return stmts, tok.value
            stmts.append(self.parse_statement())
            tok = self.peek()
            ends_block = tok.kind == "id" and tok.value in terminators
            if tok.kind not in ("nl", ";", ",", "eof") and not ends_block:
                raise _MError(tok.line, f"expected end of statement, found {_describe(tok)}")

    def parse_statement(self) -> _Node:
        tok = self.peek()
        if tok.kind == "cmd":
            self.pos += 1
            name, words = tok.value
            if name == "clear":
                return _Clear(tok.line, words)
            if name == "disp":
                return _ExprStmt(tok.line, _Num(tok.line, 0.0))
            raise _MError(tok.line, f"command {_short(name + ' ' + ' '.join(words))} is not supported")
        if tok.kind == "id":
            if tok.value == "for":
                return self.parse_for()
            if tok.value == "if":
                return self.parse_if()
            if tok.value in _KEYWORDS:
                raise _MError(tok.line, f"'{tok.value}' is not supported here")
            if self.is_op("=", 1):
                self.pos += 2
                return _Assign(tok.line, [_Name(tok.line, tok.value)], self.parse_expr())
            if self.peek(1).kind in ("(", "{"):
                close = self.matching(self.pos + 1)
                if self.toks[close + 1].kind == "op" and self.toks[close + 1].value == "=":
                    if self.peek(1).kind == "{":
                        raise _MError(tok.line, "assignment to cell elements is not supported")
                    target = self.parse_postfix()
                    if not isinstance(target, _Index) or self.pos != close + 1:
                        raise _MError(tok.line, "unsupported assignment target")
                    self.pos += 1
                    return _Assign(tok.line, [target], self.parse_expr())
        if tok.kind == "[":
            close = self.matching(self.pos)
            if self.toks[close + 1].kind == "op" and self.toks[close + 1].value == "=":
                targets: list[_Node] = []
                for t in self.toks[self.pos + 1 : close]:
                    if t.kind == "id" and t.value not in _KEYWORDS:
                        targets.append(_Name(t.line, t.value))
                    elif t.kind != ",":
                        raise _MError(t.line, "only plain names are supported in [a, b] = ...")
                if not targets:
                    raise _MError(tok.line, "empty assignment target []")
                self.pos = close + 2
                return _Assign(tok.line, targets, self.parse_expr())
        return _ExprStmt(tok.line, self.parse_expr())

    def parse_for(self) -> _Node:
        head = self.take()
        var = self.expect("id", "a loop variable after 'for'")
        if var.value in _KEYWORDS or not self.is_op("="):
            raise _MError(head.line, "expected 'for name = values'")
        self.pos += 1
        expr = self.parse_expr()
        if self.peek().kind not in ("nl", ";", ","):
            raise _MError(head.line, "expected a new line or ',' after the 'for' range")
        body, _ = self.parse_block(frozenset({"end"}), head)
        return _For(head.line, var.value, expr, body)

    def parse_if(self) -> _Node:
        head = self.take()
        branches: list[tuple[_Node, list[_Node]]] = []
        cond = self.parse_expr()
        orelse: list[_Node] = []
        while True:
            body, term = self.parse_block(frozenset({"elseif", "else", "end"}), head)
            branches.append((cond, body))
            if term == "elseif":
                cond = self.parse_expr()
                continue
            if term == "else":
                orelse, _ = self.parse_block(frozenset({"end"}), head)
            return _If(head.line, branches, orelse)

    # expressions
    def parse_expr(self) -> _Node:
        self.nesting += 1
        try:
            if self.nesting > MAX_NESTING:
                raise _MError(self.peek().line, f"expression nested more than {MAX_NESTING} deep")
            return self.parse_level(0)
        finally:
            self.nesting -= 1

    def parse_level(self, level: int) -> _Node:
        if level == len(_BINARY_LEVELS):
            return self.parse_range()
        ops = _BINARY_LEVELS[level]
        left = self.parse_level(level + 1)
        while self.peek().kind == "op" and self.peek().value in ops:
            tok = self.take()
            right = self.parse_level(level + 1)
            left = self.node(_Bin(tok.line, tok.value, left, right), left, right)
        return left

    def parse_range(self) -> _Node:
        start = self.parse_additive()
        if not self.is_op(":"):
            return start
        line = self.take().line
        second = self.parse_additive()
        if self.is_op(":"):
            self.pos += 1
            stop = self.parse_additive()
            return self.node(_Range(line, start, second, stop), start, second, stop)
        return self.node(_Range(line, start, None, second), start, second)

    def parse_additive(self) -> _Node:
        left = self.parse_multiplicative()
        while self.peek().kind == "op" and self.peek().value in ("+", "-"):
            tok = self.take()
            right = self.parse_multiplicative()
            left = self.node(_Bin(tok.line, tok.value, left, right), left, right)
        return left

    def parse_multiplicative(self) -> _Node:
        left = self.parse_unary()
        while self.peek().kind == "op" and self.peek().value in ("*", "/", ".*", "./"):
            tok = self.take()
            right = self.parse_unary()
            left = self.node(_Bin(tok.line, tok.value, left, right), left, right)
        return left

    def parse_unary(self) -> _Node:
        tok = self.peek()
        if tok.kind == "op" and tok.value in ("-", "+", "~"):
            self.pos += 1
            self.nesting += 1
            try:
                if self.nesting > MAX_NESTING:
                    raise _MError(tok.line, f"expression nested more than {MAX_NESTING} deep")
                x = self.parse_unary()
            finally:
                self.nesting -= 1
            return self.node(_Unary(tok.line, tok.value, x), x)
        return self.parse_power()

    def parse_power(self) -> _Node:
        left = self.parse_postfix()
        while self.peek().kind == "op" and self.peek().value in ("^", ".^"):
            tok = self.take()
            right = self.parse_power_operand()
            left = self.node(_Bin(tok.line, tok.value, left, right), left, right)
        return left

    def parse_power_operand(self) -> _Node:
        tok = self.peek()
        if tok.kind == "op" and tok.value in ("-", "+", "~"):  # 2^-1
            self.pos += 1
            self.nesting += 1
            try:
                if self.nesting > MAX_NESTING:
                    raise _MError(tok.line, f"expression nested more than {MAX_NESTING} deep")
                x = self.parse_power_operand()
            finally:
                self.nesting -= 1
            return self.node(_Unary(tok.line, tok.value, x), x)
        return self.parse_postfix()

    def parse_postfix(self) -> _Node:
        tok = self.peek()
        node = self.parse_primary()
        if isinstance(node, _Name) and self.peek().kind in ("(", "{"):
            brace = self.take().kind == "{"
            args = self.parse_args("}" if brace else ")")
            node = self.node(_Index(tok.line, node.name, args, brace), *args)
            if self.peek().kind in ("(", "{"):
                raise _MError(self.peek().line, "chained indexing such as a(1)(2) is not supported")
        while self.peek().kind == "op" and self.peek().value in ("'", ".'"):
            op = self.take()
            node = self.node(_Unary(op.line, "'", node), node)
        return node

    def parse_args(self, closer: str) -> list[_Node]:
        args: list[_Node] = []
        self.index_depth += 1
        try:
            if self.peek().kind == closer:
                self.pos += 1
                return args
            while True:
                tok = self.peek()
                if tok.kind == "op" and tok.value == ":" and self.peek(1).kind in (",", closer):
                    self.pos += 1
                    args.append(_Colon(tok.line))
                else:
                    args.append(self.parse_expr())
                tok = self.take()
                if tok.kind == closer:
                    return args
                if tok.kind != ",":
                    found = _describe(tok)
                    raise _MError(tok.line, f"expected ',' or {closer!r} in argument list, found {found}")
        finally:
            self.index_depth -= 1

    def parse_primary(self) -> _Node:
        tok = self.take()
        if tok.kind == "num":
            return _Num(tok.line, tok.value)
        if tok.kind == "str":
            return _Str(tok.line, tok.value)
        if tok.kind == "id":
            if tok.value == "end":
                if self.index_depth == 0:
                    raise _MError(tok.line, "unexpected 'end'")
                return _End(tok.line)
            if tok.value in _KEYWORDS:
                raise _MError(tok.line, f"unexpected keyword '{tok.value}'")
            return _Name(tok.line, tok.value)
        if tok.kind == "(":
            inner = self.parse_expr()
            self.expect(")", "')'")
            return inner
        if tok.kind in ("[", "{"):
            return self.parse_matrix(tok)
        raise _MError(tok.line, f"unexpected {_describe(tok)}")

    def parse_matrix(self, open_tok: _Tok) -> _Node:
        closer = _OPEN[open_tok.kind]
        rows: list[list[_Node]] = [[]]
        children: list[_Node] = []
        expect_element = True
        while True:
            tok = self.peek()
            if tok.kind == closer:
                self.pos += 1
                break
            if tok.kind == ";":
                self.pos += 1
                rows.append([])
                expect_element = True
                continue
            if tok.kind == ",":
                if expect_element:
                    raise _MError(tok.line, "empty element in matrix (',,')")
                self.pos += 1
                expect_element = True
                continue
            if not expect_element:
                raise _MError(tok.line, f"expected ',' or ';' in matrix, found {_describe(tok)}")
            element = self.parse_expr()
            rows[-1].append(element)
            children.append(element)
            expect_element = False
        rows = [r for r in rows if r]
        return self.node(_Matrix(open_tok.line, rows, open_tok.kind == "{"), *children)


def _describe(tok: _Tok) -> str:
    if tok.kind == "eof":
        return "end of file"
    if tok.kind == "nl":
        return "end of line"
    if tok.kind == "num":
        return f"number {tok.value:g}"
    if tok.kind == "str":
        return f"text {_short(tok.value)}"
    if tok.kind == "id":
        return f"'{tok.value}'"
    if tok.kind == "cmd":
        return f"'{tok.value[0]}'"
    return repr(tok.value)


# ------------------------------------------------------------------------------------------ evaluator

_Builtin = Callable[["_Interp", list, int, int], list]
_BUILTINS: dict[str, _Builtin] = {}
_STATEMENT_ONLY = frozenset({"disp", "eval", "clear"})
_NOT_IN_EVAL = frozenset({"eval", "inline", "disp", "clear"})
_CONSTANTS = {"pi": math.pi, "eps": _EPS, "Inf": math.inf, "inf": math.inf, "true": 1.0, "false": 0.0}
_DENIED = frozenset(
    {
        "system", "unix", "dos", "eval", "evalin", "evalc", "assignin", "feval", "builtin", "run", "load",
        "save", "importdata", "fopen", "fread", "fwrite", "fprintf", "fscanf", "fgetl", "fclose", "delete",
        "cd", "exit", "quit", "input", "keyboard", "str2func", "func2str", "java", "javaObject",
        "javaMethod", "py", "pyrun", "perl", "mex", "web", "websave", "webread", "urlread", "setenv",
        "getenv", "mkdir", "rmdir", "movefile", "copyfile", "winopen", "open", "edit", "cellfun",
        "arrayfun", "str2num", "inputname",
    }
)  # fmt: skip


def _builtin(*names: str) -> Callable[[_Builtin], _Builtin]:
    def register(fn: _Builtin) -> _Builtin:
        for name in names:
            _BUILTINS[name] = fn
        return fn

    return register


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


def _wildcard_match(pattern: str, name: str) -> bool:
    """Whether ``name`` matches a ``clear`` pattern in which ``*`` stands for any run of characters."""
    parts = pattern.split("*")
    if not name.startswith(parts[0]) or len(name) < sum(map(len, parts)):
        return False
    pos = len(parts[0])
    for part in parts[1:-1]:
        found = name.find(part, pos)
        if found < 0:
            return False
        pos = found + len(part)
    return name.endswith(parts[-1]) and len(name) - len(parts[-1]) >= pos


class _Interp:
    def __init__(self) -> None:
        self.vars: dict[str, Any] = {}
        self.work = 0
        self.statements = 0
        self.line = 1
        self.end_stack: list[tuple[Any, int, int] | None] = []
        self.in_eval = False

    # bookkeeping
    def result(self, r: np.ndarray, line: int, *inputs: np.ndarray) -> np.ndarray:
        """Check a freshly computed numeric array: size, work budget, no NaN, no new infinities."""
        self.work += r.size
        if self.work > MAX_WORK:
            raise _MError(line, f"too much computation (more than {MAX_WORK} array elements in total)")
        _check_size(r.size, line, "result")
        if r.dtype != bool and not np.all(np.isfinite(r)):
            if np.any(np.isnan(r)):
                raise _MError(line, "operation gives NaN or a complex number (for example 0/0 or (-1)^0.5)")
            if all(np.all(np.isfinite(x)) for x in inputs if x.dtype != bool):
                raise _MError(line, "operation overflows to infinity or divides by zero")
        return r

    # statements
    def tick(self, line: int) -> None:
        self.statements += 1
        self.line = line
        if self.statements > MAX_STATEMENTS:
            raise _MError(line, f"more than {MAX_STATEMENTS} statements or loop passes executed")

    def run(self, stmts: list[_Node]) -> None:
        for s in stmts:
            self.tick(s.line)
            if isinstance(s, _Assign):
                self.assign(s)
            elif isinstance(s, _ExprStmt):
                self.evaluate(s.expr, nargout=0)
            elif isinstance(s, _For):
                self.run_for(s)
            elif isinstance(s, _If):
                self.run_if(s)
            elif isinstance(s, _Clear):
                self.clear(s.names, s.line)
            else:  # pragma: no cover - the parser makes no other statements
                raise _MError(s.line, "unsupported statement")

    def assign(self, s: _Assign) -> None:
        if len(s.targets) > 1:
            if not isinstance(s.expr, _Index) or s.expr.name in self.vars or s.expr.brace:
                raise _MError(s.line, "[a, b] = ... needs a function call on the right")
            values = self.call(s.expr, len(s.targets))
            for target, value in zip(s.targets, values, strict=True):
                self.store(target, value)
            return
        self.store(s.targets[0], self.value(s.expr))

    def store(self, target: _Node, value: Any) -> None:
        if isinstance(target, _Name):
            self.vars[target.name] = value
            return
        assert isinstance(target, _Index)
        self.indexed_assign(target, value)

    def run_for(self, s: _For) -> None:
        values = self.value(s.expr)
        if isinstance(values, np.ndarray):
            columns = [values[:, k : k + 1] for k in range(values.shape[1])] if values.size else []
        elif isinstance(values, tuple):
            columns = [(v,) for v in values]
        else:
            raise _MError(s.line, "a for loop must run over numbers or a cell array")
        for column in columns:
            self.tick(s.line)
            self.vars[s.var] = column
            self.run(s.body)

    def run_if(self, s: _If) -> None:
        for cond, body in s.branches:
            if self.truth(cond):
                self.run(body)
                return
        self.run(s.orelse)

    def truth(self, node: _Node) -> bool:
        v = _num(self.value(node), node.line, "condition")
        return bool(v.size) and bool(np.all(v != 0))

    def clear(self, names: tuple[str, ...], line: int) -> None:
        if self.in_eval:
            raise _MError(line, "'clear' is not allowed inside eval")
        if not names or names in (("all",), ("variables",)):
            self.vars.clear()
            return
        for name in names:
            plain = name.replace("*", "")
            if "*" in name and name[0] != "*" and plain.isascii() and plain.isidentifier():
                # A wildcard pattern such as "temp*": '*' matches any run of name characters.
                for var in [v for v in self.vars if _wildcard_match(name, v)]:
                    del self.vars[var]
                continue
            if not (name.isascii() and name.isidentifier() and name[0].isalpha()):
                raise _MError(line, f"clear: only variable names are supported, got {_short(name)}")
            self.vars.pop(name, None)

    # expressions
    def value(self, node: _Node) -> Any:
        v = self.evaluate(node, nargout=1)
        if v is None:
            raise _MError(node.line, "this expression gives no value")
        return v

    def evaluate(self, node: _Node, nargout: int) -> Any:
        if isinstance(node, _Num):
            return _scalar(node.value)
        if isinstance(node, _Str):
            return node.value
        if isinstance(node, _Name):
            return self.name(node, nargout)
        if isinstance(node, _Bin):
            return self.binary(node)
        if isinstance(node, _Unary):
            return self.unary(node)
        if isinstance(node, _Range):
            return self.range(node)
        if isinstance(node, _Matrix):
            return self.cell(node) if node.cell else self.matrix(node)
        if isinstance(node, _Index):
            if node.name in self.vars:
                return self.index(node)
            values = self.call(node, nargout)
            return values[0] if values else None
        if isinstance(node, _End):
            return self.end(node)
        if isinstance(node, _Colon):
            raise _MError(node.line, "':' alone is only allowed as an index")
        raise _MError(node.line, "unsupported expression")  # pragma: no cover

    def name(self, node: _Name, nargout: int) -> Any:
        if node.name in self.vars:
            return self.vars[node.name]
        if node.name in _CONSTANTS:
            return _scalar(_CONSTANTS[node.name])
        if node.name in ("NaN", "nan"):
            raise _MError(node.line, "NaN is not allowed in engine data")
        if node.name in _BUILTINS:
            values = self.call(_Index(node.line, node.name, [], False), nargout)
            return values[0] if values else None
        return self.unknown(node.name, node.line, called=False)

    def unknown(self, name: str, line: int, called: bool) -> Any:
        if name in _DENIED:
            raise _MError(line, f"function '{name}' is not allowed in a data file")
        if name in ("i", "j"):
            raise _MError(line, f"undefined variable '{name}' (complex numbers are not supported)")
        if called:
            raise _MError(line, f"unknown function or undefined variable '{name}'")
        raise _MError(line, f"undefined variable '{name}'")

    def call(self, node: _Index, nargout: int) -> list:
        fn = _BUILTINS.get(node.name)
        if fn is None or node.brace:
            if node.name in _CONSTANTS:
                raise _MError(node.line, f"'{node.name}' cannot be called with arguments here")
            return self.unknown(node.name, node.line, called=True)
        if self.in_eval and node.name in _NOT_IN_EVAL:
            raise _MError(node.line, f"'{node.name}' is not allowed inside eval")
        if node.name in _STATEMENT_ONLY and nargout > 0:
            raise _MError(node.line, f"'{node.name}(...)' gives no value")
        self.end_stack.append(None)  # 'end' inside a function's arguments refers to no array
        try:
            args = [self.value(a) for a in node.args]
        finally:
            self.end_stack.pop()
        out = fn(self, args, nargout, node.line)
        if nargout > max(1, len(out)):
            raise _MError(node.line, f"'{node.name}' gives {len(out)} output(s), {nargout} requested")
        return out

    def end(self, node: _End) -> np.ndarray:
        ctx = self.end_stack[-1] if self.end_stack else None
        if ctx is None:
            raise _MError(node.line, "'end' used outside an index")
        value, position, count = ctx
        r, c = _shape(value)
        if count == 1:
            return _scalar(r * c)
        return _scalar((r, c)[position] if position < 2 else 1)

    def index_args(self, node: _Index, base: Any) -> list[Any]:
        if len(node.args) > 2:
            raise _MError(node.line, "only 1 or 2 indices are supported")
        out: list[Any] = []
        for k, a in enumerate(node.args):
            if isinstance(a, _Colon):
                out.append(slice(None))
                continue
            self.end_stack.append((base, k, len(node.args)))
            try:
                out.append(self.value(a))
            finally:
                self.end_stack.pop()
        return out

    def positions(self, v: Any, line: int, limit: int | None, name: str) -> np.ndarray:
        """0-based integer positions from a MATLAB index value (checked against ``limit`` if given)."""
        if isinstance(v, np.ndarray) and v.dtype == bool:
            raise _MError(line, "logical indexing is not supported")
        a = _num(v, line, "index")
        flat = a.ravel(order="F")
        whole = np.all(np.isfinite(flat)) and np.all(flat == np.floor(flat))
        if flat.size and (not whole or np.any(flat < 1)):
            raise _MError(line, f"index into '{name}' must be a positive whole number")
        if limit is not None and flat.size and flat.max() > limit:
            raise _MError(line, f"index {flat.max():g} exceeds the size ({limit}) of '{name}'")
        if flat.size and flat.max() > MAX_ELEMENTS:
            _check_size(int(flat.max()), line, f"'{name}'")
        return flat.astype(np.int64) - 1

    def index(self, node: _Index) -> Any:
        base = self.vars[node.name]
        if isinstance(base, InlineFunction):
            raise _MError(node.line, f"calling the inline function '{node.name}' is not supported")
        args = self.index_args(node, base)
        if node.brace:
            if not isinstance(base, tuple):
                raise _MError(node.line, f"'{node.name}' is not a cell array")
            if len(args) != 1 or isinstance(args[0], slice):
                raise _MError(node.line, "cell contents must be taken one element at a time: c{k}")
            pos = self.positions(args[0], node.line, len(base), node.name)
            if pos.size != 1:
                raise _MError(node.line, "cell contents must be taken one element at a time: c{k}")
            return base[int(pos[0])]
        if isinstance(base, str | tuple):
            if len(args) == 2 and not isinstance(args[0], slice):
                self.positions(args[0], node.line, 1, node.name)  # row index of a row: must be 1
                args = args[1:]
            if len(args) != 1:
                raise _MError(node.line, f"unsupported index into '{node.name}'")
            if isinstance(args[0], slice):
                return base
            pos = self.positions(args[0], node.line, len(base), node.name)
            picked = [base[int(p)] for p in pos]
            return "".join(picked) if isinstance(base, str) else _make_cell(picked, node.line)
        if not node.args:
            return base
        if len(args) == 1:
            flat = base.ravel(order="F")
            if isinstance(args[0], slice):
                return self.result(flat.reshape(-1, 1).copy(), node.line)
            idx_value = args[0]
            pos = self.positions(idx_value, node.line, flat.size, node.name)
            picked = flat[pos]
            ir, ic = _shape(idx_value)
            if (base.shape[0] == 1 or base.shape[1] == 1) and (ir == 1 or ic == 1):
                shape = (1, pos.size) if base.shape[0] == 1 else (pos.size, 1)
            else:
                shape = (ir, ic)
            return self.result(picked.reshape(shape, order="F"), node.line)
        sel = []
        for k, a in enumerate(args):
            if isinstance(a, slice):
                sel.append(np.arange(base.shape[k]))
            else:
                sel.append(self.positions(a, node.line, base.shape[k], node.name))
        return self.result(base[np.ix_(sel[0], sel[1])], node.line)

    def indexed_assign(self, target: _Index, value: Any) -> None:
        name = target.name
        base = self.vars.get(name, np.zeros((0, 0)))
        if not isinstance(base, np.ndarray):
            raise _MError(target.line, f"indexed assignment into '{name}' needs a numeric array")
        if isinstance(value, np.ndarray) and value.size == 0:
            raise _MError(target.line, "deleting elements with x(i) = [] is not supported")
        v = _num(value, target.line, "assigned value")
        base = base.astype(float)
        args = self.index_args(target, base)
        if not args:
            raise _MError(target.line, f"empty index in assignment to '{name}'")
        if len(args) == 1:
            if isinstance(args[0], slice):
                pos = np.arange(base.size)
            else:
                pos = self.positions(args[0], target.line, None, name)
            need = int(pos.max()) + 1 if pos.size else 0
            if need > base.size:
                _check_size(need, target.line, f"'{name}'")
                if base.size == 0 or base.shape[0] == 1:
                    grown = np.zeros((1, need))
                elif base.shape[1] == 1:
                    grown = np.zeros((need, 1))
                else:
                    raise _MError(target.line, f"linear index {need} is outside the matrix '{name}'")
                grown.ravel(order="F")[: base.size] = base.ravel(order="F")
                base = grown
            if v.size not in (1, pos.size):
                raise _MError(target.line, f"assigning {v.size} values to {pos.size} elements of '{name}'")
            flat = base.ravel(order="F").copy()
            flat[pos] = v.ravel(order="F") if v.size > 1 else v.flat[0]
            self.vars[name] = self.result(flat.reshape(base.shape, order="F"), target.line, v)
            return
        sel = []
        for k, a in enumerate(args):
            if isinstance(a, slice):
                sel.append(np.arange(base.shape[k]))
            else:
                sel.append(self.positions(a, target.line, None, name))
        rows = max(base.shape[0], int(sel[0].max()) + 1 if sel[0].size else 0)
        cols = max(base.shape[1], int(sel[1].max()) + 1 if sel[1].size else 0)
        if (rows, cols) != base.shape:
            _check_size(rows * cols, target.line, f"'{name}'")
            grown = np.zeros((rows, cols))
            grown[: base.shape[0], : base.shape[1]] = base
            base = grown
        else:
            base = base.copy()
        count = sel[0].size * sel[1].size
        if v.size == 1:
            base[np.ix_(sel[0], sel[1])] = v.flat[0]
        elif v.size == count and (v.shape == (sel[0].size, sel[1].size) or 1 in (sel[0].size, sel[1].size)):
            base[np.ix_(sel[0], sel[1])] = v.reshape((sel[0].size, sel[1].size), order="F")
        else:
            raise _MError(
                target.line,
                f"assigning a {_fmt_shape(v)} value to a {sel[0].size}x{sel[1].size} block of '{name}'",
            )
        self.vars[name] = self.result(base, target.line, v)

    def matrix(self, node: _Matrix) -> Any:
        rows: list[Any] = []
        for row in node.rows:
            items = [self.value(e) for e in row]
            if any(isinstance(x, tuple | InlineFunction) for x in items):
                raise _MError(node.line, "cell arrays and inline functions cannot be put inside [ ]")
            if any(isinstance(x, str) for x in items):
                parts = []
                for x in items:
                    if isinstance(x, np.ndarray) and x.size == 0:
                        continue
                    if not isinstance(x, str):
                        raise _MError(node.line, "mixing text and numbers in [ ] is not supported")
                    parts.append(x)
                _check_size(sum(len(x) for x in parts), node.line, "text")
                rows.append("".join(parts))
                continue
            arrays = [_num(x, node.line) for x in items]
            arrays = [a for a in arrays if a.size]
            if not arrays:
                continue
            r = arrays[0].shape[0]
            for a in arrays[1:]:
                if a.shape[0] != r:
                    raise _MError(
                        node.line,
                        f"dimensions do not agree in horizontal concatenation ({_fmt_shape(arrays[0])} "
                        f"next to {_fmt_shape(a)})",
                    )
            _check_size(sum(a.size for a in arrays), node.line, "matrix")
            rows.append(np.hstack(arrays) if len(arrays) > 1 else arrays[0])
        rows = [x for x in rows if not (isinstance(x, str) and x == "" and len(rows) > 1)]
        if not rows:
            return np.zeros((0, 0))
        if any(isinstance(x, str) for x in rows):
            if len(rows) > 1:
                raise _MError(node.line, "vertical concatenation of text is not supported")
            return rows[0]
        c = rows[0].shape[1]
        for k, a in enumerate(rows[1:], start=2):
            if a.shape[1] != c:
                raise _MError(
                    node.line,
                    f"dimensions do not agree in vertical concatenation (row {k} has {a.shape[1]} "
                    f"column(s), the rows above have {c})",
                )
        _check_size(sum(a.size for a in rows), node.line, "matrix")
        out = np.vstack(rows) if len(rows) > 1 else rows[0]
        return self.result(np.asarray(out, dtype=float), node.line)

    def cell(self, node: _Matrix) -> tuple:
        if len(node.rows) > 1 and any(len(r) > 1 for r in node.rows):
            raise _MError(node.line, "only one-row or one-column cell arrays are supported")
        return _make_cell([self.value(e) for row in node.rows for e in row], node.line)

    def range(self, node: _Range) -> np.ndarray:
        def scalar(n: _Node, what: str) -> float:
            a = _num(self.value(n), n.line, what)
            if a.size != 1:
                raise _MError(n.line, f"range {what} must be a scalar, got {_fmt_shape(a)}")
            x = float(a.flat[0])
            if not math.isfinite(x):
                raise _MError(n.line, f"range {what} must be finite")
            return x

        start = scalar(node.start, "start")
        step = scalar(node.step, "step") if node.step is not None else 1.0
        stop = scalar(node.stop, "end")
        if step == 0 or (stop - start) / step < 0:
            return np.zeros((1, 0))
        q = (stop - start) / step
        if not math.isfinite(q) or q + 1 > MAX_ELEMENTS:
            msg = f"range {start:g}:{step:g}:{stop:g} has more than {MAX_ELEMENTS} elements"
            raise _MError(node.line, msg)
        count = int(math.floor(q + 1e-10 * max(1.0, abs(q)))) + 1
        values = start + step * np.arange(count, dtype=float)
        if count > 1 and abs(values[-1] - stop) <= 1e-10 * max(abs(stop), abs(step)):
            values[-1] = stop
        return self.result(values.reshape(1, -1), node.line)

    def unary(self, node: _Unary) -> Any:
        v = self.value(node.x)
        if node.op == "'":
            if isinstance(v, tuple):
                return v
            if isinstance(v, str) and len(v) <= 1:
                return v
            return self.result(_num(v, node.line, "transpose").T.copy(), node.line)
        a = _num(v, node.line, f"unary {node.op}")
        if node.op == "-":
            return self.result(-a, node.line, a)
        if node.op == "+":
            return a
        return self.result(a == 0, node.line)  # '~'

    def binary(self, node: _Bin) -> Any:
        op = node.op
        if op in ("&&", "||"):
            left = self.logical_scalar(node.a, op)
            if (op == "&&" and not left) or (op == "||" and left):
                return _scalar(float(left)).astype(bool)
            return _scalar(float(self.logical_scalar(node.b, op))).astype(bool)
        a = _num(self.value(node.a), node.line, f"left of {op}")
        b = _num(self.value(node.b), node.line, f"right of {op}")
        if op == "*" and a.size != 1 and b.size != 1:
            if a.shape[1] != b.shape[0]:
                raise _MError(
                    node.line,
                    f"inner dimensions do not agree in matrix product {_fmt_shape(a)} * {_fmt_shape(b)} "
                    "(use .* for element-wise)",
                )
            _check_size(a.shape[0] * b.shape[1], node.line, "matrix product")
            self.work += a.shape[0] * a.shape[1] * b.shape[1]
            with np.errstate(all="ignore"):
                return self.result(a @ b, node.line, a, b)
        if op == "/" and b.size != 1:
            raise _MError(node.line, "matrix division A/B is not supported (use ./ for element-wise)")
        if op == "^" and (a.size != 1 or b.size != 1):
            raise _MError(node.line, "matrix power is not supported (use .^ for element-wise)")
        if a.shape != b.shape and a.size != 1 and b.size != 1:
            raise _MError(node.line, f"dimensions do not agree: {_fmt_shape(a)} {op} {_fmt_shape(b)}")
        with np.errstate(all="ignore"):
            if op == "+":
                r = a + b
            elif op == "-":
                r = a - b
            elif op in ("*", ".*"):
                r = a * b
            elif op in ("/", "./"):
                r = a / b
            elif op in ("^", ".^"):
                r = np.power(a, b)
            elif op == "==":
                r = a == b
            elif op == "~=":
                r = a != b
            elif op == "<":
                r = a < b
            elif op == "<=":
                r = a <= b
            elif op == ">":
                r = a > b
            elif op == ">=":
                r = a >= b
            elif op == "&":
                r = (a != 0) & (b != 0)
            elif op == "|":
                r = (a != 0) | (b != 0)
            else:  # pragma: no cover - the parser makes no other operators
                raise _MError(node.line, f"unsupported operator {op!r}")
        return self.result(np.asarray(r), node.line, a, b)

    def logical_scalar(self, node: _Node, op: str) -> bool:
        a = _num(self.value(node), node.line, f"operand of {op}")
        if a.size != 1:
            raise _MError(node.line, f"operands of {op} must be scalars, got {_fmt_shape(a)}")
        return bool(a.flat[0] != 0)


# ----------------------------------------------------------------------------------------- functions


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


# ---------------------------------------------------------------------------------------------- API


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
