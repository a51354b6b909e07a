"""The safe MATLAB reader's tokenizer: ``_tokenize`` turns a data file's text into tokens (``_Tok``: numbers,
texts, names, operators, brackets, commands, separators), refusing what the subset does not know.

:mod:`vpsim.engines._matlab_parser` reads the tokens; the subset is described in :mod:`vpsim.engines.matlab`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ._matlab_base import MAX_NAME_CHARS, MAX_TOKENS, _MError, _short


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
