"""Fixed structures declared once as data, used by the fast path, the dump and the columnar decode alike.

A Layout lists its fields in wire order as (registry name, struct code). It compiles to one
`struct.Struct`, so the fast path unpacks a whole header in one call and works on the tuple; the
dump asks the same Layout to annotate that tuple (offset, length, raw bytes, shown value); the
columnar decode asks it for numpy columns of the structure at many offsets at once (`columns`). There
is no second parser, so the paths cannot disagree.
"""

from __future__ import annotations

import struct
import uuid
from collections.abc import Callable, Mapping, Sequence
from socket import inet_ntoa
from typing import TYPE_CHECKING

from pd_analyze.model import fields as registry
from pd_analyze.model.shown import Annotated, Converter, Field, Shower, View
from pd_analyze.model.values import flag_names, name_of

if TYPE_CHECKING:
    import numpy as np


class Layout:
    """A fixed-size structure: fields in wire order with struct codes, one byte order."""

    __slots__ = ("_columnar", "codes", "defs", "names", "offsets", "order", "positions", "size", "sizes", "struct",
                 "title", "view")

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
        # what annotate needs per field, decided here rather than for every frame of a dump
        self.view = self.shown(*self.names)
        # numpy record types for `columns`, by the tuple of fields asked for; built on first use, so the
        # per-frame path never imports numpy
        self._columnar: dict[tuple[tuple[str, ...], bool], tuple[int, np.dtype]] = {}

    def unpack(self, buf: bytes, offset: int = 0) -> tuple:
        return self.struct.unpack_from(buf, offset)

    def index(self, name: str) -> int:
        return self.positions[name]

    def columns(self, data: np.ndarray, at: np.ndarray, names: Sequence[str] | None = None,
                valid: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """The structure at every offset of `at` in `data`, as one numpy column per field.

        `data` is a uint8 array, `at` an int64 array of offsets. Integer fields come as arrays of their width
        in native byte order, read in the Layout's; 's' fields as (len(at), size) uint8 arrays (`be_uint`,
        `be_halves` read them as big-endian integers). `names` (in any order) limits the result to those
        fields, and the bytes read to the span they cover. Each structure must lie wholly inside `data`,
        except where `valid` (a bool array) is False: those rows are not read, and their fields are 0."""
        wanted = self.names if names is None else tuple(names)
        lo, rtype = self._record_type(wanted, False)
        return _fields(_gather(data, at, rtype.itemsize, valid, lo).view(rtype), wanted)

    def records(self, data: np.ndarray, at: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
        """The whole structure at every offset of `at`, as raw records of `size` bytes (`columns` says which
        rows are read), for `fields` of this Layout or of any other of the same size: the other byte order,
        another variant of a header, chosen per row afterwards."""
        return _gather(data, at, self.size, valid)

    def fields(self, records: np.ndarray, names: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """The named fields (default: all) of raw records of this size (`records`), as `columns` gives them."""
        wanted = self.names if names is None else tuple(names)
        return _fields(records.view(self._record_type(wanted, True)[1]), wanted)

    def _record_type(self, names: tuple[str, ...], whole: bool) -> tuple[int, np.dtype]:
        """The numpy record type of the named fields, over the whole structure or over the bytes they span
        only, and that span's offset in the structure (0 for the whole); made once per Layout and names."""
        plan = self._columnar.get((names, whole))
        if plan is not None:
            return plan
        import numpy as np

        idx = [self.positions[name] for name in names]
        lo = 0 if whole else min(self.offsets[i] for i in idx)
        hi = self.size if whole else max(self.offsets[i] + self.sizes[i] for i in idx)
        formats = []
        for i in idx:
            code = self.codes[i]
            if code.endswith("s"):
                formats.append((np.uint8, (self.sizes[i],)))
            elif code in _NUMPY_INTEGERS:
                formats.append(np.dtype(_NUMPY_INTEGERS[code]).newbyteorder(self.order))
            else:
                raise ValueError(f"{self.title}: no columnar form for struct code {code!r} of {self.names[i]}")
        plan = self._columnar[(names, whole)] = (lo, np.dtype({
            "names": list(names), "formats": formats, "offsets": [self.offsets[i] - lo for i in idx],
            "itemsize": hi - lo}))
        return plan

    def shown(self, *fields: str | tuple[str, str, Callable[[int], int]] | tuple[str, str, Callable[[int], int],
                                                                                 Shower]) -> View:
        """What the dump shows of this structure, in order: a field by its name, or a field derived from one
        (name, source field, function of the source's value, optionally how it is shown): a bit field, shown
        at its source's offset and bytes. `self.view` shows every field as declared."""
        little = self.order == "<"
        entries = []
        for spec in fields:
            if isinstance(spec, str):
                i = self.positions[spec]
                fdef = self.defs[i]
                conv, show_value = _converter(fdef, little), shower(fdef)
            else:
                name, source, derive, *how = spec
                i = self.positions[source]
                fdef = registry.field(name)
                conv, show_value = derive, (how[0] if how else shower(fdef))
            entries.append((fdef.name, self.offsets[i], self.sizes[i], {}, conv, show_value, i, len(entries)))
        return View(tuple(entries))

    def annotate(self, buf: bytes, offset: int, values: tuple, base: int = 0) -> Annotated:
        """Fields of the structure at `offset` in `buf` (`values` as unpacked by this Layout's struct);
        `base` is added to shown offsets. See View.annotate."""
        return self.view.annotate(buf, offset, values, base)


# struct codes with a numpy integer of the same width and signedness (the byte order is the Layout's)
_NUMPY_INTEGERS = {"B": "u1", "H": "u2", "I": "u4", "Q": "u8", "b": "i1", "h": "i2", "i": "i4", "q": "i8"}


def _gather(data: np.ndarray, at: np.ndarray, width: int, valid: np.ndarray | None, skip: int = 0) -> np.ndarray:
    """`width`-byte raw records at the offsets `at` (+ `skip`) of `data`; rows not `valid` are zero bytes, unread."""
    import numpy as np

    n = len(at)
    kind = np.dtype((np.void, width))
    count = n if valid is None else int(np.count_nonzero(valid))
    if count == 0 or len(data) < skip + width:  # nothing to read (a valid row would lie inside data)
        return np.zeros(n, kind)
    # every offset of data (from `skip` on) as the start of one `width`-byte record: indexing copies whole
    # records, several times faster than gathering their bytes one by one
    windows = np.ndarray((len(data) - skip - width + 1,), kind, data, skip, (1,))
    if count == n:
        return windows[at]
    if count > n // 2:  # mostly valid: read every row (the invalid ones at 0, inside data) and clear those
        out = windows[np.where(valid, at, 0)]
        out.view(np.uint8).reshape(n, width)[np.flatnonzero(~valid)] = 0
        return out
    out = np.zeros(n, kind)  # mostly not: read only the valid rows
    rows = np.flatnonzero(valid)
    out[rows] = windows[at[rows]]
    return out


def _fields(records: np.ndarray, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The columns of structured records: integers in native byte order, byte strings as (n, size) views."""
    out = {}
    for name in names:
        column = records[name]
        out[name] = column if column.ndim == 2 else column.astype(column.dtype.newbyteorder("="))
    return out


def fields_by_order(little: Layout, big: Layout, records: np.ndarray, is_little: np.ndarray,
                    names: Sequence[str]) -> dict[str, np.ndarray]:
    """The named fields of raw records (`Layout.records`) whose byte order is chosen per row (`is_little`, e.g.
    from a DREP byte) between two declarations of one structure, `little` and `big`."""
    import numpy as np

    if is_little.all():
        return little.fields(records, names)
    if not is_little.any():
        return big.fields(records, names)
    le, be = little.fields(records, names), big.fields(records, names)
    out = {}
    for name in names:
        i, j = little.positions[name], big.positions[name]
        if little.offsets[i] == big.offsets[j] and (little.sizes[i] == 1 or little.codes[i].endswith("s")):
            out[name] = be[name]  # the same bytes in either order
        else:
            out[name] = np.where(is_little if le[name].ndim == 1 else is_little[:, None], le[name], be[name])
    return out


def be_uint(raw: np.ndarray) -> np.ndarray:
    """Rows of 1, 2, 4 or 8 bytes (an 's' column) as unsigned big-endian integers (IPv4 addresses ...)."""
    import numpy as np

    size = raw.shape[1]
    return np.ascontiguousarray(raw).view(f">u{size}")[:, 0].astype(f"u{size}")


def be_halves(raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of 16 bytes (a UUID column) as two uint64: the big-endian integers of bytes 0-7 and 8-15."""
    import numpy as np

    both = np.ascontiguousarray(raw).view(">u8").astype(np.uint64)
    return both[:, 0], both[:, 1]


def convert(name: str, value: object, little: bool = False) -> object:
    """The registry value of a raw unpacked item (UUIDs to text, byte strings kept)."""
    conv = _converter(registry.field(name), little)
    return value if conv is None else conv(value)


def _converter(fdef: registry.FieldDef, little: bool) -> Converter | None:
    if fdef.type == registry.UUID:
        return _uuid_le if little else _uuid_be
    if fdef.type == registry.IPV4:
        return lambda value: inet_ntoa(value) if isinstance(value, bytes) else value
    return None


def _uuid_be(value: object) -> object:
    # formatted from the hex digits: uuid.UUID objects cost several times more, once per UUID field
    if not isinstance(value, bytes):
        return value
    if len(value) != 16:
        return str(uuid.UUID(bytes=value))  # its error for a wrong length
    h = value.hex()
    return f"{h[:8]}-{h[8:12]}-{h[12:16]}-{h[16:20]}-{h[20:]}"


def _uuid_le(value: object) -> object:
    # the first three groups little-endian (DCE NDR), the rest as on the wire
    if not isinstance(value, bytes):
        return value
    if len(value) != 16:
        return str(uuid.UUID(bytes_le=value))  # its error for a wrong length
    return _uuid_be(value[3::-1] + value[5:3:-1] + value[7:5:-1] + value[8:])


def show(name: str, value: object) -> str:
    """How a value is shown: hex or decimal by type, with its value-table name."""
    found = _SHOW_BY_NAME.get(name)
    if found is None:
        found = shower(registry.field(name))
        if len(_SHOW_BY_NAME) < 65_536:  # concrete indexed names; beyond that, looked up each time
            _SHOW_BY_NAME[name] = found
    return found(value)


def show_def(fdef: registry.FieldDef, value: object) -> str:
    """The definition of how a value is shown; `shower` gives the same text faster (tests hold the two equal)."""
    kind = fdef.type
    if kind == registry.UINT and fdef.values is None:
        return str(value)
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


def shower(fdef: registry.FieldDef) -> Shower:
    """show_def for one field, with its type, value table, flag bits and hex width resolved once."""
    found = _SHOWERS.get(fdef.name)
    if found is None:
        found = _SHOWERS[fdef.name] = _with_meaning(_text_of(fdef), fdef.values)
    return found


_SHOWERS: dict[str, Shower] = {}  # by registry (template) name
_SHOW_BY_NAME: dict[str, Shower] = {}  # by concrete name, for show()


def _text_of(fdef: registry.FieldDef) -> Shower:
    kind = fdef.type
    if kind == registry.HEX:
        width = _hex_width(fdef.name, 0)  # the width a small value gets; only 2 grows with the value
        if width == 2:
            return lambda v: (f"0x{v:04x}" if v > 0xFF else f"0x{v:02x}") if isinstance(v, int) else str(v)
        form = f"0x{{:0{width}x}}".format
        return lambda v: form(v) if isinstance(v, int) else str(v)
    if kind == registry.FLAGS:
        bits = sorted((fdef.flags or {}).items(), reverse=True)  # as flag_names orders them

        def flags(v: object) -> str:
            if not isinstance(v, int):
                return str(v)
            names = ", ".join(name for bit, name in bits if v & bit)
            return f"0x{v:02x} ({names})" if names else f"0x{v:02x}"
        return flags
    if kind == registry.BYTES:
        return lambda v: _bytes_text(bytes(v)) if isinstance(v, bytes | bytearray) else str(v)
    if kind == registry.TIME:
        return lambda v: f"{v:.9f}" if isinstance(v, float) else str(v)
    if kind == registry.FLOAT:
        return lambda v: f"{v:.6f} s" if isinstance(v, float) else str(v)
    if kind == registry.LIST:
        return lambda v: ", ".join(str(x) for x in v) if isinstance(v, tuple | list) else str(v)
    return str


def _with_meaning(text: Shower, table: Mapping[int, str] | None) -> Shower:
    if table is None:
        return text
    get = table.get

    def shown(v: object) -> str:
        meaning = get(v, "") if isinstance(v, int) else ""
        return f"{text(v)} ({meaning})" if meaning else text(v)
    return shown


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
