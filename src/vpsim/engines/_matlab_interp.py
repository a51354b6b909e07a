"""The safe MATLAB reader's interpreter: ``_Interp`` runs the statements of
:mod:`vpsim.engines._matlab_parser` over numpy, within the limits on work, statements and sizes, and calls the
built-in functions of :mod:`vpsim.engines._matlab_builtins`, whose table it imports (complete once that
module is loaded). Beside it, the names it treats specially: constants, functions refused in a data file,
built-ins allowed only as statements or not inside ``eval``.

:func:`vpsim.engines.matlab.evaluate_m_text` runs it and exports the variables it leaves.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ._matlab_base import MAX_ELEMENTS, MAX_STATEMENTS, MAX_WORK, InlineFunction, _MError, _short
from ._matlab_builtins import _BUILTINS
from ._matlab_parser import (
    _Assign,
    _Bin,
    _Clear,
    _Colon,
    _End,
    _ExprStmt,
    _For,
    _If,
    _Index,
    _Matrix,
    _Name,
    _Node,
    _Num,
    _Range,
    _Str,
    _Unary,
)
from ._matlab_values import _check_size, _fmt_shape, _make_cell, _num, _scalar, _shape

_EPS = float(np.finfo(float).eps)
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
