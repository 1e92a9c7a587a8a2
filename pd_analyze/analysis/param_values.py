"""Parameter values as the tables hold them (text cells), taken apart per array element and compared in
the wire format the capture shows.

A `values_written` / `values_read` cell holds one text per value (profidrive_view.cell_text; Byte, Word,
Double word, V2 and L2 as 0x.. hex), separated by spaces, except for VisibleString, OctetString and
UnicodeString, whose whole access is one value. Two values are equal when they are the same bytes on the
wire: an intended 0.1 is packed as the FloatingPoint32 the drive sent (0x3dcccccd) and compared with the
cell read back under the same format, so the comparison does not depend on how many digits a cell shows.
Scaled formats (N2, N4, E2, C4, T2, ...) compare their raw integer, as the tables show it.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Mapping
from types import MappingProxyType

from pd_analyze.model import pd_values as pt
from pd_analyze.protocol.profidrive_view import cell_text

FORMAT_BY_NAME: Mapping[str, pt.Format] = MappingProxyType({f.name: f for f in pt.FORMATS.values()})
ONE_VALUE_KINDS = frozenset({"string", "octets", "unicode"})  # an access is one value, in its first subindex
TEXT_KINDS = frozenset({"string", "unicode"})
SIGNED_KINDS = frozenset({"int", "n2", "n4", "e2", "c4"})
UNSIGNED_KINDS = frozenset({"bool", "uint", "hex", "bits", "nibbles", "t2", "time_date"})
NUMERIC_KINDS = SIGNED_KINDS | UNSIGNED_KINDS | {"float"}
_HEX_INT = re.compile(r"[+-]?0[xX][0-9a-fA-F]+")
_DEC_INT = re.compile(r"[+-]?[0-9]+")
_BOOL_WORDS = MappingProxyType({"true": 1, "false": 0})


class NotAValueError(ValueError):
    """A text that is no value of the format (the reason is the message)."""


def _spec(fmt: str) -> pt.Format | None:
    return FORMAT_BY_NAME.get(fmt)


def one_value(fmt: str) -> bool:
    """Whether an access of this format is one value (strings, octets; a format of unknown size)."""
    spec = _spec(fmt)
    return spec is None or spec.kind in ONE_VALUE_KINDS


def split_cell(fmt: str, cell: str | None) -> list[str]:
    """The values of a cell, one per array element (a string access: one value)."""
    if not cell:
        return []
    return [cell] if one_value(fmt) else cell.split()


def parse_int(text: str) -> int:
    """A whole number: decimal, 0x hex, or a float that is whole (1500.0)."""
    t = text.strip()
    if _HEX_INT.fullmatch(t):
        return int(t, 16)
    if _DEC_INT.fullmatch(t):
        return int(t, 10)
    if t.lower() in _BOOL_WORDS:
        return _BOOL_WORDS[t.lower()]
    try:
        f = float(t)
    except ValueError:
        raise NotAValueError(f"{text!r} is not a number") from None
    if not f.is_integer():
        raise NotAValueError(f"{text} is not a whole number")
    return int(f)


def _octets(text: str) -> bytes:
    t = re.sub(r"[\s:.-]", "", text.strip())
    t = t[2:] if t[:2].lower() == "0x" else t
    try:
        return bytes.fromhex(t)
    except ValueError:
        raise NotAValueError(f"{text!r} is not hex bytes") from None


def wire(fmt: str, text: str, from_cell: bool = False) -> bytes | str:
    """The value `text` as the format carries it: its bytes, or for text formats the cell it makes.

    `from_cell`: `text` is a table cell (a string value already shown as cell_text), else a value as a
    user writes it (plain text). Raises NotAValueError when the text is no value of the format."""
    spec = _spec(fmt)
    if spec is None or spec.kind in TEXT_KINDS:
        return text if from_cell or spec is None else cell_text(text, 0)  # (a text has no width)
    kind, size = spec.kind, spec.size
    if kind == "octets":
        return _octets(text)
    if kind == "date":
        raw = _octets(text)
        if len(raw) != size:
            raise NotAValueError(f"{text!r} is not the {size} bytes of {fmt}")
        return raw
    if kind == "float":
        try:
            value = float(text)
            return struct.pack(">f" if size == 4 else ">d", value)
        except (ValueError, OverflowError):
            raise NotAValueError(f"{text!r} is no {fmt} value") from None
    if kind in SIGNED_KINDS or kind in UNSIGNED_KINDS:
        number = parse_int(text)
        try:
            return number.to_bytes(size, "big", signed=kind in SIGNED_KINDS)
        except OverflowError:
            raise NotAValueError(f"{text} is outside the range of {fmt}") from None
    return text  # Zero, Error: no value to compare


def number(fmt: str, raw: bytes | str) -> float | None:
    """The number wire bytes of a numeric format stand for (None for other formats)."""
    spec = _spec(fmt)
    if spec is None or spec.kind not in NUMERIC_KINDS or not isinstance(raw, bytes):
        return None
    if spec.kind == "float":
        return struct.unpack(">f" if spec.size == 4 else ">d", raw)[0]
    return float(int.from_bytes(raw, "big", signed=spec.kind in SIGNED_KINDS))


def same(fmt: str, cell: str, other: bytes | str, tolerance: float = 0.0) -> bool:
    """Whether a cell of format `fmt` holds the wire value `other` (within `tolerance` for numbers)."""
    try:
        seen = wire(fmt, cell, from_cell=True)
    except NotAValueError:
        return cell == other  # a cell the format cannot read back (e.g. "nan" text): as text
    if seen == other:
        return True
    if tolerance > 0:
        a, b = number(fmt, seen), number(fmt, other)
        return a is not None and b is not None and not math.isnan(a - b) and abs(a - b) <= tolerance
    return False


def cells_agree(fmt_a: str, cell_a: str | None, fmt_b: str, cell_b: str | None) -> bool:
    """Two cells hold the same value: the same format and the same wire value."""
    if cell_a is None or cell_b is None:
        return cell_a is cell_b
    if fmt_a != fmt_b:
        return False
    try:
        return same(fmt_a, cell_a, wire(fmt_b, cell_b, from_cell=True))
    except NotAValueError:
        return cell_a == cell_b
