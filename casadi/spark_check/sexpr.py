"""Neutral S-expression text -> CasADi SX.

Owns the translation of the grammar documented on ``SystemSource`` in
``spark-runtime/src/system.rs``::

    expr  := number | "t" | "pi" | "(q " name ")" | "(v " name ")" | "(p " name ")"
           | "(psi " index ")" | "(" op expr+ ")"
    op    := "+" | "*"                        (n-ary)
           | "-" | "/" | "^" | "atan2"        (binary)
           | "neg" | "sqrt" | "exp" | "ln" | "sin" | "cos" | "tan"
           | "sinh" | "cosh" | "tanh"       (unary)

The text is tokenized and parsed here into a small tree, then each node is
mapped onto the corresponding CasADi call. Nothing produced by Rust is ever
evaluated as code: the only inputs are tokens of this grammar. ``(psi j)`` (the
0-based multiplier of constraint ``j``) is only resolvable in an :class:`Env`
built with multipliers, i.e. for the non-ideal force ``N(t,q,v,ψ)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Dict, List, Union

import casadi as ca


class SexprError(ValueError):
    """The source text does not follow the grammar (message says where)."""


@dataclass(frozen=True)
class Num:
    """A numeric literal."""

    value: float


@dataclass(frozen=True)
class Sym:
    """``t``, ``(q x)``, ``(v x)``, ``(p name)`` or ``(psi j)``."""

    kind: str  # "t", "q", "v", "p" or "psi"
    name: str


@dataclass(frozen=True)
class App:
    """An operator applied to its arguments."""

    op: str
    args: tuple


Node = Union[Num, Sym, App]

NARY = {"+", "*"}
BINARY = {"-", "/", "^", "atan2"}
UNARY = {"neg", "sqrt", "exp", "ln", "sin", "cos", "tan", "sinh", "cosh", "tanh"}


def tokenize(text: str) -> List[tuple]:
    """Split into ``(token, offset)`` pairs: parentheses and whitespace-separated atoms."""
    tokens = []
    i = 0
    while i < len(text):
        ch = text[i]
        if ch.isspace():
            i += 1
        elif ch in "()":
            tokens.append((ch, i))
            i += 1
        else:
            j = i
            while j < len(text) and not text[j].isspace() and text[j] not in "()":
                j += 1
            tokens.append((text[i:j], i))
            i = j
    return tokens


def _parse_number(tok: str, offset: int) -> float:
    try:
        value = float(tok)
    except ValueError:
        raise SexprError(f"unknown atom {tok!r} at offset {offset}") from None
    if not math.isfinite(value):
        raise SexprError(f"non-finite literal {tok!r} at offset {offset}")
    return value


def parse(text: str) -> Node:
    """Parse one expression; the whole text must be consumed."""
    tokens = tokenize(text)
    if not tokens:
        raise SexprError("empty expression")
    pos = 0

    def expr() -> Node:
        nonlocal pos
        if pos >= len(tokens):
            raise SexprError("unexpected end of expression")
        tok, off = tokens[pos]
        pos += 1
        if tok == ")":
            raise SexprError(f"unexpected ')' at offset {off}")
        if tok != "(":
            if tok == "t":
                return Sym("t", "t")
            if tok == "pi":
                return Num(math.pi)
            return Num(_parse_number(tok, off))
        if pos >= len(tokens):
            raise SexprError(f"unclosed '(' at offset {off}")
        head, hoff = tokens[pos]
        pos += 1
        if head in ("q", "v", "p", "psi"):
            if pos >= len(tokens):
                raise SexprError(f"missing name after {head!r} at offset {hoff}")
            name, noff = tokens[pos]
            if name in "()":
                raise SexprError(f"expected a name after {head!r} at offset {noff}")
            pos += 1
            close(off)
            if head == "psi" and not (name.isdigit() and str(int(name)) == name):
                raise SexprError(f"multiplier index {name!r} at offset {noff} is not a non-negative integer")
            return Sym(head, name)
        if head not in NARY | BINARY | UNARY:
            raise SexprError(f"unknown operator {head!r} at offset {hoff}")
        args = []
        while pos < len(tokens) and tokens[pos][0] != ")":
            args.append(expr())
        close(off)
        if head in UNARY and len(args) != 1:
            raise SexprError(f"{head!r} at offset {hoff} takes 1 argument, got {len(args)}")
        if head in BINARY and len(args) != 2:
            raise SexprError(f"{head!r} at offset {hoff} takes 2 arguments, got {len(args)}")
        if head in NARY and len(args) < 1:
            raise SexprError(f"{head!r} at offset {hoff} needs at least 1 argument")
        return App(head, tuple(args))

    def close(open_off: int) -> None:
        nonlocal pos
        if pos >= len(tokens) or tokens[pos][0] != ")":
            raise SexprError(f"unclosed '(' at offset {open_off}")
        pos += 1

    node = expr()
    if pos != len(tokens):
        raise SexprError(f"trailing input at offset {tokens[pos][1]}")
    return node


_UNARY_SX: Dict[str, Callable] = {
    "neg": lambda a: -a,
    "sqrt": ca.sqrt,
    "exp": ca.exp,
    "ln": ca.log,
    "sin": ca.sin,
    "cos": ca.cos,
    "tan": ca.tan,
    "sinh": ca.sinh,
    "cosh": ca.cosh,
    "tanh": ca.tanh,
}


def _power(a, b):
    # Integer constant exponents become CasADi's constpow/sq, as a human
    # would write them; anything else is the general pow.
    return a**b


_BINARY_SX: Dict[str, Callable] = {
    "-": lambda a, b: a - b,
    "/": lambda a, b: a / b,
    "^": _power,
    "atan2": ca.atan2,
}


class Env:
    """Maps the symbols of one system onto CasADi SX scalars.

    ``psi`` lists the multipliers ``ψ_0..ψ_{m-1}``; without it (``None``) a
    ``(psi j)`` is an error, since only ``N(t,q,v,ψ)`` may use multipliers.
    """

    def __init__(self, t, q: Dict[str, object], v: Dict[str, object], p: Dict[str, object], psi=None):
        self.t = t
        self.tables = {"q": q, "v": v, "p": p}
        self.psi = psi

    def lookup(self, sym: Sym):
        if sym.kind == "t":
            return self.t
        if sym.kind == "psi":
            if self.psi is None:
                raise SexprError(f"(psi {sym.name}): multipliers may only appear in the non-ideal force")
            j = int(sym.name)
            if j >= len(self.psi):
                raise SexprError(f"(psi {sym.name}): the system has {len(self.psi)} constraints (0-based index)")
            return self.psi[j]
        table = self.tables[sym.kind]
        if sym.name not in table:
            known = ", ".join(table) or "(none)"
            raise SexprError(f"unknown {sym.kind} name {sym.name!r}; known: {known}")
        return table[sym.name]


def to_sx(node: Node, env: Env):
    """Build the CasADi SX expression of a parsed tree."""
    if isinstance(node, Num):
        return ca.SX(node.value)
    if isinstance(node, Sym):
        return env.lookup(node)
    args = [to_sx(a, env) for a in node.args]
    if node.op == "+":
        out = args[0]
        for a in args[1:]:
            out = out + a
        return out
    if node.op == "*":
        out = args[0]
        for a in args[1:]:
            out = out * a
        return out
    if node.op in _BINARY_SX:
        return _BINARY_SX[node.op](args[0], args[1])
    return _UNARY_SX[node.op](args[0])


def translate(text: str, env: Env):
    """Parse ``text`` and build its SX expression in ``env``."""
    return to_sx(parse(text), env)
