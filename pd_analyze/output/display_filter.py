"""Display filters (`-Y`): tshark 4.0's expression language over the field registry, parsed by a small
recursive-descent parser into closures (never Python's eval).

    expr    := and_expr (("or" | "||") and_expr)*        "and" binds tighter than "or", as in tshark
    and_expr:= unary (("and" | "&&") unary)*
    unary   := ("not" | "!") unary | "(" expr ")" | test
    test    := FIELD                                     the field is present
             | FIELD relation value                      == != ~= === < <= > >= (or eq ne any_ne all_eq lt le gt ge)
             | FIELD "in" "{" member ([","] member)* "}"  member: value, or value..value (a range)
             | FIELD ("&" | "bitwise_and") value            an integer field: some bit of the mask set
             | FIELD "contains" value                      a text field: a substring (case-sensitive); bytes: a run
             | FIELD ("matches" | "~") "string"            a text or bytes field: a regular expression, case-
                                                           insensitive unless it starts with (?-i), as tshark's PCRE2
    value   := number (decimal, 0x hex, float) | "string" | word (an address, a UUID, a name)

On a repeated field (pd.addr.pnu of a multi-parameter request) the semantics of tshark 4: `==`, `<`, `in`,
`contains`... match when any occurrence does; `!=` when the field is present and no occurrence equals;
`~=` when any occurrence differs; `===` when it is present and every occurrence equals. A test on an absent
field is false. A literal is checked against the field's type when the filter is parsed: `==` and `in` against
the field's value names too (`txn.verdict == "late"` is an error, "late" being no verdict), `contains` and
`matches` search the text of any text field, the analysis fields included (`txn.verdict contains "out"`). Sets
take elements separated by commas (tshark 4.0 requires them) or by spaces.
"""

from __future__ import annotations

import ipaddress
import re
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

from pd_analyze.model import fields as registry
from pd_analyze.model.rules import RULES, SEVERITIES
from pd_analyze.model.verdicts import VERDICTS
from pd_analyze.output.filter_tree import All, Any, Node, Not, Predicate, Test, compiled
from pd_analyze.output.frame_view import ANALYSIS, FieldRef, resolve

RELATIONS = {"==": "eq", "eq": "eq", "any_eq": "eq", "!=": "all_ne", "ne": "all_ne", "all_ne": "all_ne",
             "~=": "any_ne", "any_ne": "any_ne", "===": "all_eq", "all_eq": "all_eq", "<": "lt", "lt": "lt",
             "<=": "le", "le": "le", ">": "gt", "gt": "gt", ">=": "ge", "ge": "ge"}
_SYMBOLS = ("===", "==", "!=", "~=", "<=", ">=", "&&", "||", "<", ">", "!", "&", "(", ")", "{", "}", ",", "~")
_KEYWORDS = {"and": "and", "&&": "and", "or": "or", "||": "or", "not": "not", "!": "not", "in": "in",
             "&": "bitand", "bitwise_and": "bitand",
             "contains": "contains", "matches": "matches", "~": "matches"}
_WORD = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_.:-/[]")
_INTEGER = frozenset({registry.UINT, registry.HEX, registry.INT, registry.FLAGS, registry.FRAMEREF, registry.LIST})
_NUMBER = frozenset({registry.FLOAT, registry.TIME})
_CHOICES = {"txn.verdict": ("verdict", VERDICTS), "finding.severity": ("severity", SEVERITIES),
            "finding.rule": ("rule id", tuple(sorted({r.id for r in RULES.values()})))}


class FilterError(ValueError):
    """A filter that does not parse: the message and the 1-based column it points at."""

    def __init__(self, message: str, column: int) -> None:
        super().__init__(message)
        self.message, self.column = message, column

    def __str__(self) -> str:
        return f"column {self.column}: {self.message}"


class Token(NamedTuple):
    kind: str  # "word", "string", "rel", "and", "or", "not", "in", "bitand", "contains", "matches", a bracket or
    # comma, "end"
    text: str
    column: int


def tokens(text: str) -> list[Token]:
    out = []
    i, n = 0, len(text)
    while i < n:
        ch = text[i]
        if ch.isspace():
            i += 1
        elif ch == '"':
            value, end = _string(text, i)
            out.append(Token("string", value, i + 1))
            i = end
        elif ch in _WORD:
            start = i
            while i < n and text[i] in _WORD:
                i += 1
            word = text[start:i]
            out.append(Token(_KEYWORDS.get(word, "rel" if word in RELATIONS else "word"), word, start + 1))
        else:
            symbol = next((s for s in _SYMBOLS if text.startswith(s, i)), None)
            if symbol is None:
                raise FilterError(f"unexpected character {ch!r}", i + 1)
            kind = _KEYWORDS.get(symbol, "rel" if symbol in RELATIONS else symbol)
            out.append(Token(kind, symbol, i + 1))
            i += len(symbol)
    out.append(Token("end", "", n + 1))
    return out


def _string(text: str, start: int) -> tuple[str, int]:
    """A double-quoted string from text[start] ('"'): its value and the index after it."""
    out = []
    i = start + 1
    escapes = {'"': '"', "\\": "\\", "n": "\n", "t": "\t", "r": "\r"}
    while i < len(text):
        ch = text[i]
        if ch == '"':
            return "".join(out), i + 1
        if ch == "\\" and i + 1 < len(text):
            nxt = text[i + 1]
            if nxt == "x" and _is_hex(text[i + 2:i + 4]):
                out.append(chr(int(text[i + 2:i + 4], 16)))
                i += 4
                continue
            if nxt in escapes:
                out.append(escapes[nxt])
                i += 2
                continue
            raise FilterError(f"unknown escape \\{nxt} in a string", i + 1)
        out.append(ch)
        i += 1
    raise FilterError("string not closed (a \" is missing)", start + 1)


def _is_hex(text: str) -> bool:
    return len(text) == 2 and all(c in "0123456789abcdefABCDEF" for c in text)


@dataclass(frozen=True)
class DisplayFilter:
    """A parsed filter: `matches(view)`, its tree (`node`); `needs_analysis`: it names txn.* or finding.* (the
    report's analysis is read first)."""

    text: str
    matches: Predicate
    refs: tuple[FieldRef, ...]
    node: Node

    @property
    def needs_analysis(self) -> bool:
        return any(r.kind == ANALYSIS for r in self.refs)


def parse(text: str) -> DisplayFilter:
    """The filter of `text`; FilterError (message, column) when it does not parse or names an unknown field."""
    parser = _Parser(text)
    if parser.peek().kind == "end":
        raise FilterError("empty filter", 1)
    node = parser.expr()
    tok = parser.peek()
    if tok.kind != "end":
        raise FilterError(f"unexpected {tok.text!r}" + (" (a missing ( ?)" if tok.kind == ")" else ""), tok.column)
    return DisplayFilter(text, compiled(node), tuple(parser.refs), node)


class _Parser:
    def __init__(self, text: str) -> None:
        self.toks = tokens(text)
        self.pos = 0
        self.refs: list[FieldRef] = []

    def peek(self) -> Token:
        return self.toks[self.pos]

    def take(self) -> Token:
        tok = self.toks[self.pos]
        self.pos += 1
        return tok

    def expr(self) -> Node:
        terms = [self.and_expr()]
        while self.peek().kind == "or":
            self.take()
            terms.append(self.and_expr())
        return terms[0] if len(terms) == 1 else Any(tuple(terms))

    def and_expr(self) -> Node:
        terms = [self.unary()]
        while self.peek().kind == "and":
            self.take()
            terms.append(self.unary())
        return terms[0] if len(terms) == 1 else All(tuple(terms))

    def unary(self) -> Node:
        tok = self.take()
        if tok.kind == "not":
            return Not(self.unary())
        if tok.kind == "(":
            inner = self.expr()
            close = self.take()
            if close.kind != ")":
                raise FilterError(f"expected ) to close the ( at column {tok.column}, found "
                                  f"{_found(close)}", close.column)
            return inner
        if tok.kind == "word":
            return self.test(tok)
        raise FilterError(f"expected a field name, found {_found(tok)}", tok.column)

    def test(self, name: Token) -> Test:
        ref = resolve(name.text)
        if ref is None:
            raise FilterError(f"{name.text!r} is neither a field of the registry nor a tshark name it maps "
                              "(see `pd-analyze fields`)", name.column)
        self.refs.append(ref)
        tok = self.peek()
        if tok.kind == "rel":
            self.take()
            relation = RELATIONS[tok.text]
            literal = self.literal(ref, self.value(tok))
            if relation in ("lt", "le", "gt", "ge") and isinstance(literal, ipaddress.IPv4Network) \
                    and literal.num_addresses > 1:
                raise FilterError(f"{tok.text} needs an address, not a network", tok.column + len(tok.text) + 1)
            return _relation(ref, relation, literal)
        if tok.kind == "in":
            self.take()
            members = self.members(ref)
            return Test(ref, lambda x: any(m(x) for m in members))
        if tok.kind == "bitand":
            self.take()
            value_tok = self.value(tok)
            if ref.fdef.type not in _INTEGER or ref.names[0] in _CHOICES:
                raise FilterError(f"{tok.text} needs an integer field, {ref.text} holds {_holds(ref)}", tok.column)
            mask = self.literal(ref, value_tok)
            assert isinstance(mask, int)  # (literal: an integer field's literal is an integer)
            return Test(ref, lambda x: isinstance(x, int) and not isinstance(x, bool) and x & mask != 0)
        if tok.kind == "contains":
            self.take()
            value_tok = self.value(tok)
            if ref.fdef.type not in (registry.TEXT, registry.BYTES):
                raise FilterError(f"contains needs a text or bytes field, {ref.text} holds {_holds(ref)}", tok.column)
            # the text as written, whatever value names the field has: a part of a name is no name
            literal = value_tok.text if ref.fdef.type == registry.TEXT else self.literal(ref, value_tok)
            return Test(ref, lambda x: _contains(x, literal))
        if tok.kind == "matches":
            self.take()
            pattern = self.pattern(ref, tok)
            return Test(ref, lambda x: _matches(x, pattern))
        return Test(ref, lambda _x: True)

    def pattern(self, ref: FieldRef, tok: Token) -> re.Pattern[str]:
        """The regular expression after `matches`: a double-quoted string, case-insensitive as tshark's (PCRE2)
        unless it starts with (?-i)."""
        if ref.fdef.type not in (registry.TEXT, registry.BYTES):
            raise FilterError(f"{tok.text} needs a text or bytes field, {ref.text} holds {_holds(ref)}", tok.column)
        value_tok = self.take()
        if value_tok.kind != "string":
            raise FilterError(f"{tok.text} needs a regular expression in double quotes, found {_found(value_tok)}",
                              value_tok.column)
        text, flags = value_tok.text, re.IGNORECASE
        if text.startswith("(?-i)"):
            text, flags = text[len("(?-i)"):], 0
        try:
            return re.compile(text, flags)
        except re.error as exc:
            raise FilterError(f"{value_tok.text!r} is not a regular expression ({exc.msg})", value_tok.column) \
                from None

    def value(self, after: Token) -> Token:
        tok = self.take()
        if tok.kind not in ("word", "string"):
            raise FilterError(f"expected a value after {after.text}, found {_found(tok)}", tok.column)
        return tok

    def members(self, ref: FieldRef) -> list[Callable[[object], bool]]:
        brace = self.take()
        if brace.kind != "{":
            raise FilterError(f"expected {{ after in, found {_found(brace)}", brace.column)
        out: list[Callable[[object], bool]] = []
        while True:
            tok = self.take()
            if tok.kind == "}" and out:
                return out
            if tok.kind == "," and out:
                continue
            if tok.kind not in ("word", "string"):
                raise FilterError(f"expected a set element or }}, found {_found(tok)}", tok.column)
            if tok.kind == "word" and ".." in tok.text.strip("."):
                lo_text, _, hi_text = tok.text.partition("..")
                lo = self.literal(ref, Token("word", lo_text, tok.column))
                hi = self.literal(ref, Token("word", hi_text, tok.column + len(lo_text) + 2))
                out.append(_between(lo, hi))
            else:
                out.append(_equals(self.literal(ref, tok)))

    def literal(self, ref: FieldRef, tok: Token) -> object:
        """The typed value a literal means for the field; FilterError at its column when it cannot."""
        kind, text = ref.fdef.type, tok.text
        choices = _CHOICES.get(ref.names[0])
        if choices is not None:
            what, allowed = choices
            if text not in allowed:
                raise FilterError(f"{text!r} is not a {what} ({', '.join(allowed)})", tok.column)
            return text
        if kind in _INTEGER or (kind in _NUMBER and tok.kind == "word"):
            number = _number(text) if tok.kind == "word" else None
            if number is None and ref.fdef.values:
                number = next((k for k, name in ref.fdef.values.items() if name.lower() == text.lower()), None)
            if number is None or (kind in _INTEGER and not isinstance(number, int)):
                raise FilterError(f"{text!r} is not {'an integer' if kind in _INTEGER else 'a number'} "
                                  f"({ref.text} holds {'integers' if kind in _INTEGER else 'numbers'})", tok.column)
            return number
        if kind == registry.IPV4:
            try:
                return ipaddress.IPv4Network(text, strict=False)
            except ValueError:
                raise FilterError(f"{text!r} is not an IPv4 address or network", tok.column) from None
        if kind == registry.BYTES:
            return text.encode("utf-8", "surrogateescape") if tok.kind == "string" else _bytes(text, tok)
        if kind == registry.UUID and tok.kind == "word":
            try:
                return str(uuid.UUID(text))
            except ValueError:
                raise FilterError(f"{text!r} is not a UUID", tok.column) from None
        if tok.kind == "word":
            number = _number(text)
            return text if number is None else number
        return text


def _holds(ref: FieldRef) -> str:
    kind = ref.fdef.type
    return "integers" if kind in _INTEGER else "numbers" if kind in _NUMBER else "addresses" \
        if kind == registry.IPV4 else "UUIDs" if kind == registry.UUID else kind


def _found(tok: Token) -> str:
    return "the end" if tok.kind == "end" else repr(tok.text)


def _number(text: str) -> int | float | None:
    body = text[1:] if text[:1] == "-" else text
    sign = -1 if body is not text else 1
    try:
        if body[:2].lower() == "0x":
            return sign * int(body[2:], 16)
        if body.isdigit():
            return sign * int(body)
        return sign * float(body) if body and body[0].isdigit() else None
    except ValueError:
        return None


def _bytes(text: str, tok: Token) -> bytes:
    digits = text.replace(":", "").replace("-", "").replace(".", "")
    try:
        if len(digits) % 2:
            raise ValueError
        return bytes.fromhex(digits)
    except ValueError:
        raise FilterError(f"{text!r} is not a byte string (hex digits, e.g. 02:00:00:00:01:01)", tok.column) from None


def _comparable(value: object, literal: object) -> object:
    """`value` in the literal's terms (None when they cannot be compared: another type)."""
    if isinstance(literal, ipaddress.IPv4Network):
        try:
            return ipaddress.IPv4Address(value)  # type: ignore[arg-type]
        except ValueError:
            return None
    if isinstance(literal, int | float) and not isinstance(literal, bool):
        return value if isinstance(value, int | float) and not isinstance(value, bool) else None
    if isinstance(literal, bytes):
        return bytes(value) if isinstance(value, bytes | bytearray) else None
    if isinstance(literal, str):
        return value.lower() if isinstance(value, str) and _is_uuid_text(literal) else \
            value if isinstance(value, str) else None
    return None


def _is_uuid_text(text: str) -> bool:
    return len(text) == 36 and text.count("-") == 4


def _equals(literal: object) -> Callable[[object], bool]:
    if isinstance(literal, ipaddress.IPv4Network):
        return lambda x: (a := _comparable(x, literal)) is not None and a in literal
    return lambda x: (a := _comparable(x, literal)) is not None and a == literal


_ORDER = {"lt": lambda a, b: a < b, "le": lambda a, b: a <= b, "gt": lambda a, b: a > b, "ge": lambda a, b: a >= b}


def _ordered(relation: str, literal: object) -> Callable[[object], bool]:
    compare = _ORDER[relation]
    bound = literal.network_address if isinstance(literal, ipaddress.IPv4Network) else literal
    return lambda x: (a := _comparable(x, literal)) is not None and compare(a, bound)


def _between(lo: object, hi: object) -> Callable[[object], bool]:
    low, high = _ordered("ge", lo), _ordered("le", hi)
    return lambda x: low(x) and high(x)


def _contains(value: object, literal: str | bytes) -> bool:
    if isinstance(literal, bytes):
        return isinstance(value, bytes | bytearray) and literal in value
    return isinstance(value, str) and literal in value


def _matches(value: object, pattern: re.Pattern[str]) -> bool:
    if isinstance(value, bytes | bytearray):  # bytes as the regular expression sees them, one character each
        value = bytes(value).decode("latin-1")
    return isinstance(value, str) and pattern.search(value) is not None


def _relation(ref: FieldRef, relation: str, literal: object) -> Test:
    if relation in _ORDER:
        return Test(ref, _ordered(relation, literal))
    equal = _equals(literal)
    if relation == "eq":
        return Test(ref, equal)
    if relation in ("all_ne", "any_ne"):  # present and none equal; some occurrence differs
        return Test(ref, lambda x: not equal(x), every=relation == "all_ne")
    return Test(ref, equal, every=True)  # all_eq
