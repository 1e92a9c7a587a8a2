"""How a parsed PROFIdrive record is shown: each value as an engineer reads it (signed, scaled, text),
and the dump's tree of the record, field by field with offsets and checks. The report path calls
`values_of` for table cells; only the dump annotates."""

from __future__ import annotations

import math
import struct
from datetime import date, timedelta
from typing import Any, Protocol

from pd_analyze.model import pd_values as pt
from pd_analyze.model.layout import Field, Layout, show
from pd_analyze.model.shown import SharedField
from pd_analyze.protocol.profidrive import HEADER, RESPONSE_HEADER, Address, Block, Parsed, as_value, error_meaning
from pd_analyze.protocol.profiles import DEFAULT, VendorIds, VendorRequest

_EPOCH_1984 = date(1984, 1, 1)


# --- presentation -----------------------------------------------------------------------------
def values_of(block: Block) -> list[tuple[int, int, object, str]]:
    """(offset, length, value, shown) per value of a value block; one entry for string formats."""
    spec = pt.FORMATS.get(block.format)
    start = block.offset + 2
    if spec is None or block.unknown_size:
        return [(start, len(block.data), block.data, f"{len(block.data)} bytes, undecoded: {block.data.hex(' ')}")]
    if spec.kind == "string":
        text = block.data.decode("latin-1")
        return [(start, len(block.data), text, repr(text)[1:-1] if not text.isprintable() else f'"{text}"')]
    if spec.kind == "octets":
        return [(start, len(block.data), block.data.hex(), block.data.hex(" ") or "(empty)")]
    if spec.kind == "unicode":
        text = block.data.decode("utf-16-be", errors="replace")
        return [(start, len(block.data), text, f'"{text}"')]
    out = []
    for j in range(block.n_values):
        raw = block.data[j * block.size:(j + 1) * block.size]
        value, shown = value_of(block.format, raw)
        out.append((start + j * block.size, block.size, value, shown))
    return out


def cell_text(value: object, size: int) -> str:
    """One value as a table cell shows it: text quoted when it has spaces, escaped when not printable, a
    float as the shortest text of its width (size bytes) that reads back to the same bits."""
    if isinstance(value, str):
        return repr(value) if not value.isprintable() else value if " " not in value else f'"{value}"'
    if isinstance(value, float):
        return pt.float_text(value, size)
    return str(value)


def value_of(fmt: int, raw: bytes) -> tuple[object, str]:
    """One value as an engineer reads it: signed/unsigned/float/scaled, with the scaling stated."""
    spec = pt.FORMATS[fmt]
    kind = spec.kind
    unsigned = int.from_bytes(raw, "big")
    signed = int.from_bytes(raw, "big", signed=True)
    if kind == "bool":
        return unsigned, {0: "false", 1: "true"}.get(unsigned, f"{unsigned} (not 0/1)")
    if kind == "int":
        return signed, str(signed) + (f" ({spec.scale})" if spec.scale else "")
    if kind == "uint":
        return unsigned, str(unsigned) + (f" ({spec.scale})" if spec.scale else "")
    if kind == "float":
        value = struct.unpack(">f" if len(raw) == 4 else ">d", raw)[0]
        if math.isnan(value) or math.isinf(value):
            return str(value), str(value)
        shown = pt.float_text(value, len(raw))
        return float(shown), shown  # a Float32 as the double its shortest text reads as: 0.1, not 0.100000001
    if kind == "hex":
        return unsigned, f"0x{unsigned:0{2 * len(raw)}x}"
    if kind == "n2":
        return signed, f"{signed * 100 / 16384:.4f} % (raw {signed}; {spec.scale})"
    if kind == "n4":
        return signed, f"{signed * 100 / 2**30:.6f} % (raw {signed}; {spec.scale})"
    if kind == "e2":
        return signed, f"{signed / 128:g} (raw {signed}; {spec.scale})"
    if kind == "c4":
        return signed, f"{signed / 10000:.4f} (raw {signed}; {spec.scale})"
    if kind == "t2":
        eff = 0 if unsigned > 32767 else unsigned
        return unsigned, f"{eff} x Ts" + (" (> 32767 means 0)" if unsigned > 32767 else "")
    if kind == "bits":
        bits = [str(b) for b in range(16) if unsigned >> b & 1]
        return unsigned, f"0x{unsigned:04x} (bits set: {', '.join(bits) or 'none'})"
    if kind == "nibbles":
        return unsigned, "nibbles " + " ".join(f"{unsigned >> s & 0xF:x}" for s in (12, 8, 4, 0))
    if kind == "time_date":
        ms, days = int.from_bytes(raw[:4], "big"), int.from_bytes(raw[4:6], "big")
        clock = f"{ms // 3_600_000:02d}:{ms // 60_000 % 60:02d}:{ms // 1000 % 60:02d}.{ms % 1000:03d}"
        if fmt == 0x0C:
            return unsigned, f"{_EPOCH_1984 + timedelta(days=days)} {clock} (ms {ms}, days {days})"
        return unsigned, f"{days} days {ms} ms"
    if kind == "date":
        ms = int.from_bytes(raw[0:2], "big")
        minute, hour, day, month, year = raw[2] & 0x3F, raw[3] & 0x1F, raw[4] & 0x1F, raw[5] & 0x0F, raw[6] & 0x7F
        year += 2000 if year < 50 else 1900
        return raw.hex(), f"{year:04d}-{month:02d}-{day:02d} {hour:02d}:{minute:02d}:{ms / 1000:06.3f}"
    return unsigned, str(unsigned)


def description_fields(block: Block, i: int, base: int) -> list[Field]:
    """The complete description (attribute 0x20, subindex 0: 46 octets) element by element."""
    out = []
    for off, size, element, code in pt.DESCRIPTION_LAYOUT:
        raw = block.data[off:off + size]
        name = f"pd.val[{i}].desc.{element}"
        if code:
            value = struct.unpack(code, raw)[0]
            shown = pt.float_text(value, size) if isinstance(value, float) else str(value)
            if element == "identifier":
                fmt = value & 0xFF
                flags = [text for bit, text in pt.IDENTIFIER_BITS.items() if value >> bit & 1]
                shown = f"0x{value:04x} (data type {pt.FORMAT_NAME.get(fmt, hex(fmt))}" + \
                        (f"; {', '.join(flags)}" if flags else "") + ")"
            elif element in ("low_limit", "high_limit"):
                shown = f"0x{value:08x} (as Float32 {pt.float_text(struct.unpack('>f', raw)[0], 4)})"
        else:
            value = raw.decode("latin-1")
            shown = f'"{value}"' if value.isprintable() else repr(value)
        out.append(Field(name, base + block.offset + 2 + off, size, bytes(raw), value, shown))
    return out


# --- annotation for the dump ----------------------------------------------------------------
Section = tuple[str, list[Field]]  # (title, fields), one tree node of the dump


class Checks(Protocol):
    """What the view asks of the run's checker (profidrive_checks.Checker): a field's check text, and the
    names the selected profile gives parameters and errors."""

    names: pt.Names

    @property
    def ids(self) -> VendorIds | None: ...  # the selected profile's own Request and Response IDs

    def describe(self, key: str, value: object) -> str: ...



def _described(checks: Checks, key: str, value: object) -> str:
    """checks.describe(key, value), remembered: the same few values of a field recur in every record of a
    capture, and each text names every profile's limits."""
    memo = _DESCRIBED.get(id(checks))
    if memo is None or memo[0] is not checks:  # another run's checker (the id of one gone)
        if len(_DESCRIBED) >= 16:
            _DESCRIBED.clear()
        memo = _DESCRIBED[id(checks)] = (checks, {})
    texts = memo[1]
    text = texts.get((key, value))
    if text is None:
        text = checks.describe(key, value)
        if len(texts) < 4096:
            texts[(key, value)] = text
    return text


_DESCRIBED: dict[int, tuple[Checks, dict[tuple[str, object], str]]] = {}  # by checker: (checker, texts)


def annotate(p: Parsed, data: bytes, base: int, checks: Checks,
             request: Parsed | None = None) -> list[Section]:
    """The dump's tree of a parsed request/response; `checks.describe(key, value)` gives a check text. A vendor's
    own Request/Response ID (protocol.md 5.5) is shown with its name, service and error words."""
    layout = RESPONSE_HEADER if p.response else HEADER
    side = "response" if p.response else "request"
    if not p.header_ok:  # decoded as far as the bytes go (protocol.md 1.3), the finding says it is cut
        return [(f"Parameter {side} header (cut: {len(data)} of 4 bytes)",
                 _fields_present(data, 0, base, tuple(zip(layout.names, layout.sizes, strict=True))))]
    memo = _memo(checks)
    ref_key = ("ref", p.response, base, data[0])  # the reference changes every transaction: a key of its own
    key = ("header", p.response, base, bytes(data[1:4]), id(p.vendor))
    ref, rest = memo.get(ref_key), memo.get(key)
    if ref is None or rest is None:
        head = _header(p, data, base, checks, layout, side)
        ref, rest = memo[ref_key], memo[key] = head[0], tuple(head[1:])
    vendor = request.vendor if p.response and request is not None else p.vendor
    service = vendor if isinstance(vendor, VendorRequest) else None
    sections: list[Section] = [(f"Parameter {side} header", [ref, *rest])]
    for i, a in enumerate(p.addresses):
        at = a.offset
        key = ("address", i, base + at, bytes(data[at:at + 6]), id(service))
        found = memo.get(key)
        if found is None:
            found = memo[key] = _address(i, a, data, base, checks, service)
        sections.append((found[0], list(found[1])))
    if p.echo:
        sections.append(("Address echo (AKD manual layout)", [Field("pd.echo", base + 4, 6, bytes(data[4:10]),
                                                                    data[4:10].hex(), data[4:10].hex(" "))]))
    cut_address = not p.response and len(p.addresses) < p.n and p.end < len(data)
    if cut_address:  # the record ends inside this address
        i = len(p.addresses)
        sections.append((f"Parameter address [{i}] (cut: {len(data) - p.end} of 6 bytes)", _fields_present(
            data, p.end, base, tuple((f"pd.addr[{i}].{n}", size) for n, size in _ADDRESS_PARTS))))
    addresses = request.addresses if request is not None and p.response else p.addresses
    if service is not None:
        addresses = [as_value(a) for a in addresses]
    for i, block in enumerate(p.blocks):
        addr = addresses[i] if i < len(addresses) else None
        sections.append(_block_section(i, block, addr, p, data, base, side, checks, memo))
    cut = _cut_block(p, data, base, side, checks, addresses)
    if cut is not None:
        sections.append(cut)
    elif p.end < len(data) and not cut_address:
        rest = data[p.end:]
        sections.append(("Bytes after the parsed record", [Field("pd.trailing", base + p.end, len(rest), bytes(rest),
                                                                 rest.hex(), rest.hex(" "))]))
    return sections




def _header(p: Parsed, data: bytes, base: int, checks: Checks, layout: Layout, side: str) -> list[Field]:
    """The record header's four fields with their checks (a vendor's own ID with its name)."""
    head = layout.annotate(data, 0, (p.ref, p.ident, p.do, p.n), base)
    for i, key in enumerate(("ref", "resp_id" if p.response else "req_id", "do", "n_params")):
        head[i] = head[i].with_check(_described(checks, f"{side}.{key}", head[i].value))
    if p.vendor is not None:  # the vendor's own ID: the generic profile does not define it (protocol.md 5.5)
        head[1] = head[1].replaced(f"0x{p.ident:02x} ({p.vendor.name})", _vendor_check(head[1].check))
    return list(head)


def _address(i: int, a: Address, data: bytes, base: int, checks: Checks, service: VendorRequest | None
             ) -> tuple[str, tuple[Field, ...]]:
    """Parameter address `i`: its title and fields with their checks (a vendor service's own attribute and
    PNU checked against the vendor profile only)."""
    at = a.offset
    fields = []
    for n, key, off, size, v in (("attr", "attribute", 0, 1, a.attr), ("n_elems", "n_elems", 1, 1, a.n_elems),
                                 ("pnu", "pnu", 2, 2, a.pnu), ("subindex", "subindex", 4, 2, a.subindex)):
        check = _described(checks, f"request.{key}", v)
        if service is not None and key in ("attribute", "pnu"):  # the service's, not the profile's
            check = _vendor_check(check)
        raw = bytes(data[at + off:at + off + size])
        fields.append(SharedField.make(f"pd.addr[{i}].{n}", base + at + off, size, raw, v,
                                       _show_addr(n, v, service, checks.names), check))
    return f"Parameter address [{i}]: {_named(a.label(), a.pnu, checks.names)}", tuple(fields)


def _block_section(i: int, block: Block, addr: Address | None, p: Parsed, data: bytes, base: int, side: str,
                   checks: Checks, memo: dict[tuple, Any]) -> Section:
    """Value block `i` of `p` (named after `addr`): its title and fields (_block_title, _block_fields) kept in
    `memo`. A block of numbers is kept without its values (they change), each value by its bytes."""
    numbers = not block.is_error and not _is_text(block) and not _is_description(block, addr)
    key = ("block", i, base + block.offset, block.format, block.n_values, block.size, block.pad, block.unknown_size,
           None if addr is None else (addr.attr, addr.n_elems, addr.pnu, addr.subindex), p.response,
           id(p.vendor), None if numbers else block.data)  # (a vendor's Response ID names its errors, 5.5)
    found = memo.get(key)
    if found is None:
        made = tuple(SharedField.make(f.name, f.offset, f.length, f.raw, f.value, f.show, f.check)
                     for f in _block_fields(i, block, data, base, side, checks, addr, p))
        title = _block_title(i, block, addr, p, checks.names)
        if not numbers:
            memo[key] = (title, made, ())
            return title, list(made)
        found = memo[key] = (title, made[:2], made[2 + block.n_values:])
        for f in made[2:2 + block.n_values]:
            memo[("value", f.name, f.offset, block.format, f.raw)] = f
        return title, list(made)
    title, head, tail = found
    if not numbers:
        return title, list(head)
    fields = list(head)
    size, fmt, values = block.size, block.format, block.data
    at = base + block.offset + 2
    for j in range(block.n_values):  # as _block_fields shows the values of a block of numbers (values_of)
        raw = values[j * size:(j + 1) * size]
        name = f"pd.val[{i}].value[{j}]"
        f = memo.get(("value", name, at + j * size, fmt, raw))
        if f is None:
            value, shown = value_of(fmt, raw)
            f = memo[("value", name, at + j * size, fmt, raw)] = SharedField.make(name, at + j * size, size, raw,
                                                                                  value, shown)
        fields.append(f)
    fields += tail
    return title, fields


def _memo(checks: Checks) -> dict[tuple, Any]:
    """The sections made for the checker `checks` (its texts and names), by what decides them: the header,
    each address and each value block by its bytes, offset and what names it. A commissioning reads and
    writes the same few parameters over and over, so most sections are met again, with their texts kept on
    their SharedFields."""
    memo = _SECTIONS.get(id(checks))
    if memo is None or memo[0] is not checks:  # another run's checker (the id of one gone)
        if len(_SECTIONS) >= 16:
            _SECTIONS.clear()
        memo = _SECTIONS[id(checks)] = (checks, {})
    if len(memo[1]) >= _SECTIONS_KEPT:
        memo[1].clear()
    return memo[1]


_SECTIONS: dict[int, tuple[Checks, dict[tuple, Any]]] = {}  # by checker: (checker, sections)
_SECTIONS_KEPT = 16_384  # sections per checker (a section with its texts: some 2 KB)


_ADDRESS_PARTS = (("attr", 1), ("n_elems", 1), ("pnu", 2), ("subindex", 2))


def _fields_present(data: bytes, at: int, base: int, parts: tuple[tuple[str, int], ...]) -> list[Field]:
    """The fields of a structure the record ends inside, as far as the bytes go: whole ones decoded, the
    one the record ends inside shown raw as `pd.cut`, the missing ones left out."""
    out = []
    for name, size in parts:
        raw = bytes(data[at:at + size])
        if len(raw) == size:
            value = int.from_bytes(raw, "big")
            out.append(Field(name, base + at, size, raw, value, show(name, value)))
        elif raw:
            out.append(Field("pd.cut", base + at, len(raw), raw, raw.hex(),
                             f"{name} cut: {len(raw)} of {size} bytes before the record ends"))
        at += size
    return out


def _cut_block(p: Parsed, data: bytes, base: int, side: str, checks: Checks, addresses: list[Address]
               ) -> Section | None:
    """A value or error block whose values overrun the record (P6/Q12), decoded as far as the bytes go:
    Format, No. of values, every whole value, the cut one raw (`pd.cut`). None when the parse did not stop
    at such a block."""
    i, at = len(p.blocks), p.end
    if p.complete or at >= len(data) or (p.blocks and p.blocks[-1].unknown_size):
        return None
    fmt = data[at]
    spec = pt.FORMATS.get(fmt)
    m = data[at + 1] if at + 1 < len(data) else -1
    if spec is None or not spec.size or (m >= 0 and at + 2 + m * spec.size <= len(data)):
        return None  # not a sized block that overruns: the parse stopped for another reason
    addr = addresses[i] if i < len(addresses) else None
    label = _named(addr.label(), addr.pnu, checks.names) if addr is not None else f"block [{i}]"
    if m < 0:  # only its Format is left
        return (f"Parameter [{i}]: {label} {spec.name} (cut: no values before the record ends)",
                _fields_present(data, at, base, ((f"pd.val[{i}].format", 1), (f"pd.val[{i}].n_values", 1))))
    whole = (len(data) - at - 2) // spec.size
    present = bytes(data[at + 2:at + 2 + whole * spec.size])
    block = Block(at, fmt, whole, spec.size, present)
    if fmt == pt.FMT_ERROR and whole:
        block.error = int.from_bytes(present[:2], "big")
    fields = _block_fields(i, block, data, base, side, checks, addr, p)
    counted = fields[1]  # No. of values as the record declares it, not the whole values present
    counted.value, counted.show = m, str(m)
    rest = bytes(data[at + 2 + len(present):])
    if rest:
        fields.append(Field("pd.cut", base + at + 2 + len(present), len(rest), rest, rest.hex(),
                            f"value {whole + 1} cut: {len(rest)} of {spec.size} bytes before the record ends"))
    return f"Parameter [{i}]: {label} {spec.name} (cut: {whole} of {m} values before the record ends)", fields


def _vendor_check(check: str) -> str:
    """A check text without the generic profile's verdict: for fields of a vendor's own service, which the
    checks hold against the vendor profile only (Checker.request)."""
    return "; ".join(part for part in check.split("; ") if not part.startswith(f"{DEFAULT} "))


def _show_addr(name: str, value: int, vendor: VendorRequest | None, names: pt.Names) -> str:
    if name == "attr" and vendor is not None and vendor.services:
        svc = vendor.service(value)
        return f"0x{value:02x} ({svc.name if svc is not None else 'reserved service'})"
    if name == "attr":
        return f"0x{value:02x} ({pt.ATTRIBUTE.get(value, 'reserved')})"
    if name == "n_elems" and value == 0:
        return "0 (single value / non-array)"
    if name == "pnu" and names.pnu(value):
        return f"{value} ({names.pnu(value)})"
    return str(value)


def _named(label: str, pnu: int | None, names: pt.Names) -> str:
    """A parameter label with its name when it has one: 'P964[0] (drive unit identification)'."""
    name = names.pnu(pnu) if pnu is not None else ""
    return f"{label} ({name})" if name else label


def _block_title(i: int, block: Block, addr: Address | None, owner: Parsed, names: pt.Names) -> str:
    response = owner.response
    label = addr.label() if addr is not None else f"block [{i}]"  # the address (P7 reports a count differing)
    label = _named(label, addr.pnu if addr is not None else None, names)
    if block.is_error and block.n_values == 0:  # an error block without its error number (E, error_block_count)
        return f"Parameter [{i}]: {label} error block without an error number (No. of values 0)"
    if block.is_error:
        number = f"{block.error:#06x}" if block.error > 0xFF else f"{block.error:#04x}"
        return f"Parameter [{i}]: {label} error {number} ({error_meaning(block.error, owner, names)})"
    if block.format in (pt.FMT_ZERO, pt.FMT_AKD_ZERO):
        return f"Parameter [{i}]: {label} written" if response else f"Parameter [{i}]: {label} Zero"
    name = pt.FORMAT_NAME.get(block.format, f"format {block.format:#04x}")
    element = ""
    if addr is not None and addr.attr == pt.ATTR_DESCRIPTION:
        element = f", description element {addr.subindex} ({pt.DESCRIPTION_ELEMENT.get(addr.subindex, '?')})"
    elif addr is not None and addr.attr == pt.ATTR_TEXT:
        element = ", text"
    return f"Parameter [{i}]: {label} {name} x {block.n_values}{element}"


def _block_fields(i: int, block: Block, data: bytes, base: int, side: str, checks: Checks,
                  addr: Address | None, owner: Parsed) -> list[Field]:
    pos = block.offset
    fmt_show = f"0x{block.format:02x} ({pt.FORMAT_NAME.get(block.format, 'unknown format')})"
    fields = [Field(f"pd.val[{i}].format", base + pos, 1, bytes(data[pos:pos + 1]), block.format, fmt_show,
                    _described(checks, f"{side}.format", block.format)),
              Field(f"pd.val[{i}].n_values", base + pos + 1, 1, bytes(data[pos + 1:pos + 2]), block.n_values,
                    str(block.n_values),
                    _described(checks, f"{side}.n_values", block.n_values) if not block.is_error else "")]
    if block.is_error:
        words = [block.data[k:k + 2] for k in range(0, len(block.data), 2)]
        for k, word in enumerate(words):
            value = int.from_bytes(word, "big")
            if k == 0:
                fields.append(Field(f"pd.val[{i}].error", base + pos + 2, 2, bytes(word), value,
                                    f"0x{value:02x} ({error_meaning(value, owner, checks.names)})"))
            elif k == 1:
                fields.append(Field(f"pd.val[{i}].error_subindex", base + pos + 4, 2, bytes(word), value, str(value)))
            else:
                fields.append(Field(f"pd.val[{i}].value[{k}]", base + pos + 2 + 2 * k, 2, bytes(word), value,
                                    f"{value} (extra error value)"))
    elif _is_description(block, addr):
        fields += description_fields(block, i, base)
    else:
        for j, (off, size, value, shown) in enumerate(values_of(block)):
            name = f"pd.val[{i}].string" if _is_text(block) else f"pd.val[{i}].value[{j}]"
            fields.append(Field(name, base + off, size, bytes(data[off:off + size]), value, shown))
    if block.pad >= 0:
        fields.append(Field(f"pd.val[{i}].pad", base + block.pad_offset, 1, bytes([block.pad]), block.pad,
                            f"0x{block.pad:02x} (word-alignment pad)"))
    return fields


def _is_description(block: Block, addr: Address | None) -> bool:
    """The block holds a complete description (attribute 0x20, subindex 0), shown element by element."""
    return addr is not None and addr.attr == pt.ATTR_DESCRIPTION and addr.subindex == 0 \
        and len(block.data) == pt.DESCRIPTION_SIZE


def _is_text(block: Block) -> bool:
    spec = pt.FORMATS.get(block.format)
    return spec is None or block.unknown_size or spec.kind in ("string", "octets", "unicode")
