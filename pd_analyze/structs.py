"""Fixed structures declared once as data, used by the fast path and the dump alike.

A Layout lists its fields in wire order as (registry name, struct code). It compiles to one
`struct.Struct`, so the fast path unpacks a whole header in one call and works on the tuple; the
dump asks the same Layout to annotate that tuple (offset, length, raw bytes, shown value). There is
no second parser, so the two paths cannot disagree.
"""

from __future__ import annotations

import struct
import uuid
from dataclasses import dataclass
from socket import inet_ntoa

from pd_analyze import registry
from pd_analyze.tables import flag_names, name_of


@dataclass(slots=True)
class Field:
    """One annotated field of a dissected frame."""

    name: str
    offset: int
    length: int
    raw: bytes
    value: object
    show: str
    check: str = ""

    def as_dict(self) -> dict[str, object]:
        return {"name": self.name, "offset": self.offset, "length": self.length,
                "raw": self.raw.hex(), "value": json_value(self.value), "show": self.show,
                "check": self.check}


def json_value(value: object) -> object:
    if isinstance(value, bytes | bytearray | memoryview):
        return bytes(value).hex()
    if isinstance(value, tuple):
        return list(value)
    return value


class Layout:
    """A fixed-size structure: fields in wire order with struct codes, one byte order."""

    __slots__ = ("codes", "defs", "names", "offsets", "order", "positions", "size", "sizes", "struct", "title")

    def __init__(self, title: str, order: str, fields: tuple[tuple[str, str], ...]) -> None:
        self.title = title
        self.order = order
        self.names = tuple(name for name, _ in fields)
        self.codes = tuple(code for _, code in fields)
        self.struct = struct.Struct(order + "".join(self.codes))
        self.size = self.struct.size
        offsets, sizes, pos = [], [], 0
        for code in self.codes:
            size = struct.calcsize(order + code)
            offsets.append(pos)
            sizes.append(size)
            pos += size
        self.offsets = tuple(offsets)
        self.sizes = tuple(sizes)
        self.positions = {name: i for i, name in enumerate(self.names)}
        # registry entries resolved once (a typo in a declaration fails at import, not at run time)
        self.defs = tuple(registry.field(name) for name in self.names)

    def unpack(self, buf: bytes, offset: int = 0) -> tuple:
        return self.struct.unpack_from(buf, offset)

    def index(self, name: str) -> int:
        return self.positions[name]

    def annotate(self, buf: bytes, offset: int, values: tuple, base: int = 0) -> list[Field]:
        """Fields of the structure at `offset` in `buf`; `base` is added to shown offsets."""
        little = self.order == "<"
        out = []
        for fdef, rel, size, value in zip(self.defs, self.offsets, self.sizes, values, strict=True):
            start = offset + rel
            if fdef.type in _CONVERTED:
                value = _convert(fdef, value, little)
            out.append(Field(fdef.name, base + start, size, bytes(buf[start:start + size]), value,
                             show_def(fdef, value)))
        return out


_CONVERTED = frozenset({registry.UUID, registry.IPV4})


def convert(name: str, value: object, little: bool = False) -> object:
    """The registry value of a raw unpacked item (UUIDs to text, byte strings kept)."""
    return _convert(registry.field(name), value, little)


def _convert(fdef: registry.FieldDef, value: object, little: bool) -> object:
    if fdef.type == registry.UUID and isinstance(value, bytes):
        return str(uuid.UUID(bytes_le=value) if little else uuid.UUID(bytes=value))
    if fdef.type == registry.IPV4 and isinstance(value, bytes):
        return inet_ntoa(value)
    return value


def show(name: str, value: object) -> str:
    """How a value is shown: hex or decimal by type, with its value-table name."""
    return show_def(registry.field(name), value)


def show_def(fdef: registry.FieldDef, value: object) -> str:
    kind = fdef.type
    if kind == registry.UINT and fdef.values is None:
        return str(value)  # the commonest case, first
    if kind == registry.HEX and isinstance(value, int):
        text = f"0x{value:0{_hex_width(fdef.name, value)}x}"
    elif kind == registry.FLAGS and isinstance(value, int):
        names = flag_names(fdef.flags or {}, value)
        text = f"0x{value:02x}" + (f" ({names})" if names else "")
    elif kind == registry.BYTES and isinstance(value, bytes | bytearray):
        text = _bytes_text(bytes(value))
    elif kind == registry.TIME and isinstance(value, float):
        text = f"{value:.9f}"
    elif kind == registry.FLOAT and isinstance(value, float):
        text = f"{value:.6f} s"
    elif kind == registry.LIST and isinstance(value, tuple | list):
        text = ", ".join(str(v) for v in value)
    else:
        text = str(value)
    meaning = name_of(fdef.values, value)
    return f"{text} ({meaning})" if meaning else text


def _hex_width(name: str, value: int) -> int:
    if name.endswith((".api", ".fault_status")):
        return 8
    return 4 if value > 0xFF or name.endswith((".index", ".block_type", "hint", ".subslot", ".id")) else 2


def _bytes_text(raw: bytes, limit: int = 32) -> str:
    if len(raw) == 6:  # MAC address
        return ":".join(f"{b:02x}" for b in raw)
    text = raw[:limit].hex(" ")
    return text + (f" ... ({len(raw)} bytes)" if len(raw) > limit else "")


def plain(name: str, offset: int, buf: bytes, length: int, value: object, base: int = 0) -> Field:
    """A field outside any Layout (variable-length parts, derived values)."""
    raw = bytes(buf[offset:offset + length]) if length else b""
    return Field(name, base + offset, length, raw, value, show(name, value))


def derived(name: str, value: object) -> Field:
    """A field computed by the analyser, not read from the wire (links, reassembly)."""
    return Field(name, -1, 0, b"", value, show(name, value))
