"""The safe MATLAB reader's syntax tree and parser: the node classes (``_Num``, ``_Bin``, ``_Assign``,
``_For`` ...) and ``_Parser``, which reads the tokens of :mod:`vpsim.engines._matlab_tokens` into a list of
statements, bounding how deeply an expression nests.

:mod:`vpsim.engines._matlab_interp` runs the statements; the ``eval`` built-in
(:mod:`vpsim.engines._matlab_builtins`) parses its text with the same parser.
"""

from __future__ import annotations

from dataclasses import dataclass

from ._matlab_base import MAX_NESTING, MAX_TREE_DEPTH, _MError, _short
from ._matlab_tokens import _CLOSE, _KEYWORDS, _OPEN, _Tok

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
