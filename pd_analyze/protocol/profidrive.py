"""PROFIdrive parameter request and response records (protocol.md 3 and 4), field by field.

`parse_request` / `parse_response` decode a record into small structures with offsets and report
the structural findings that bound the decode (too short, a block overrunning the record, a format
of unknown size, pad bytes). `annotate_*` turns a parsed record into registry Fields for the dump;
the report path never calls them. Range and consistency checks against the profiles live in
`pd_checks`.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import date, timedelta

from pd_analyze.model import pd_values as pt
from pd_analyze.model.layout import Field, Layout
from pd_analyze.model.rules import Finding, finding
from pd_analyze.protocol.profiles import generic_record

HEADER = Layout("PROFIdrive header", ">", (("pd.ref", "B"), ("pd.req_id", "B"), ("pd.do", "B"),
                                           ("pd.n_params", "B")))
RESPONSE_HEADER = Layout("PROFIdrive header", ">", (("pd.ref", "B"), ("pd.resp_id", "B"), ("pd.do", "B"),
                                                    ("pd.n_params", "B")))
_ADDRESS = struct.Struct(">BBHH")
_EPOCH_1984 = date(1984, 1, 1)


@dataclass(slots=True)
class Address:
    offset: int
    attr: int
    n_elems: int
    pnu: int
    subindex: int

    def label(self, n_values: int | None = None) -> str:
        """P<pnu>[<sub>] or P<pnu>[<sub>..<last>] (protocol.md 3.3)."""
        count = n_values if n_values is not None else max(self.n_elems, 1)
        if self.attr == pt.ATTR_VALUE and count > 1:
            return f"P{self.pnu}[{self.subindex}..{self.subindex + count - 1}]"
        return f"P{self.pnu}[{self.subindex}]"


@dataclass(slots=True)
class Block:
    """A value block, an error block (Format 0x44) or a Zero entry, at its offset in the record."""

    offset: int
    format: int
    n_values: int
    size: int  # bytes per value (0 for Zero / unknown)
    data: bytes  # the value bytes (error words for an error block)
    pad_offset: int = -1
    pad: int = -1  # value of the consumed pad byte, -1 when none
    error: int = -1
    error_subindex: int = -1
    unknown_size: bool = False

    @property
    def end(self) -> int:
        return self.offset + 2 + len(self.data) + (1 if self.pad >= 0 else 0)

    @property
    def is_error(self) -> bool:
        return self.format == pt.FMT_ERROR


@dataclass(slots=True)
class Parsed:
    """A parameter request (response=False) or response."""

    response: bool
    length: int
    ref: int = 0
    ident: int = 0  # Request ID or Response ID
    do: int = 0
    n: int = 0
    addresses: list[Address] = field(default_factory=list)
    blocks: list[Block] = field(default_factory=list)
    end: int = 0  # bytes consumed by the parse
    complete: bool = False  # every expected part decoded (False: malformed)
    echo: int = 0  # AKD address echo bytes skipped (protocol.md 5.3)

    @property
    def header_ok(self) -> bool:
        return self.length >= 4


def footprint(p: Parsed) -> int:
    """Bytes a parsed record keeps alive, objects included (roughly): what the caps of the tables that
    keep parsed requests count. A record of n parameters costs some 300 bytes per parameter."""
    return 256 + 2 * p.length + 128 * len(p.addresses) + 192 * len(p.blocks)  # block data <= p.length


# --- parsing ----------------------------------------------------------------------------------
def parse_request(data: bytes, frame: int, findings: list[Finding]) -> Parsed:
    """A parameter request (Write to a PROFIdrive index): header, addresses, value blocks."""
    p = Parsed(False, len(data))
    if len(data) < 4:
        findings.append(finding("pd_too_short", frame, "pd.n_params", len(data), ">= 4",
                                f"parameter request of {len(data)} bytes has no complete header"))
        return p
    p.ref, p.ident, p.do, p.n = HEADER.unpack(data)
    pos = 4
    for i in range(p.n):
        if pos + 6 > len(data):
            findings.append(finding("pd_too_short", frame, f"pd.addr[{i}].attr", len(data), f">= {4 + 6 * p.n}",
                                    f"request ends after {i} of {p.n} parameter addresses"))
            p.end = pos
            return p
        p.addresses.append(Address(pos, *_ADDRESS.unpack_from(data, pos)))
        pos += 6
    p.end = pos
    if p.ident != pt.REQ_CHANGE:
        p.complete = True
        return p
    p.blocks, p.end, p.complete = _blocks(data, pos, p.n, frame, findings, False)
    if len(p.blocks) < p.n and p.end >= len(data) and not any(b.unknown_size for b in p.blocks):
        findings.append(finding("change_blocks", frame, "pd.n_params", len(p.blocks), p.n,
                                f"change request ends after {len(p.blocks)} of {p.n} value blocks"))
        p.complete = False
    return p


def parse_response(data: bytes, frame: int, findings: list[Finding]) -> Parsed:
    """A parameter response (Read response from a PROFIdrive index)."""
    p = Parsed(True, len(data))
    if len(data) < 4:
        findings.append(finding("pd_response_too_short", frame, "pd.n_params", len(data), ">= 4",
                                f"parameter response of {len(data)} bytes has no complete header"))
        return p
    p.ref, p.ident, p.do, p.n = RESPONSE_HEADER.unpack(data)
    p.end = 4
    if p.ident == pt.RES_CHANGE:
        p.complete = True
        return p
    if p.ident not in (pt.RES_READ, pt.RES_READ_NAK, pt.RES_CHANGE_NAK, pt.RES_NOT_SUPPORTED):
        # Unknown Response ID: Q1 reports it and the body is not guessed at. A header-only record is
        # still completely decoded (its verdict comes from Q3, protocol.md 7.4); a body is not.
        p.complete = len(data) == 4
        return p
    count = 1 if p.ident == pt.RES_NOT_SUPPORTED and p.n == 0 else p.n
    trial: list[Finding] = []
    blocks, end, ok = _blocks(data, 4, count, frame, trial, True)
    if (trial or not ok) and len(data) > 10 and count == 1:
        echo_trial: list[Finding] = []
        eblocks, eend, eok = _blocks(data, 10, count, frame, echo_trial, True)
        if eok and eend == len(data):
            findings.append(finding("akd_address_echo", frame, "pd.val[0].format", f"{data[4]:#04x}",
                                    "Format at byte 4", "response repeats the 6-byte parameter address "
                                    "before Format (AKD manual layout); decoded after the echo"))
            p.blocks, p.end, p.complete, p.echo = eblocks, eend, True, 6
            findings += echo_trial
            return p
    findings += trial
    p.blocks, p.end, p.complete = blocks, end, ok
    if not ok and len(blocks) < count and end == len(data) and blocks and blocks[-1].is_error \
            and p.ident & 0x80 and blocks[-1].error in pt.HEADER_LEVEL_ERRORS:
        findings.append(finding("header_level_error", frame, "pd.n_params", len(blocks), p.n,
                                f"whole request refused with one error block "
                                f"({pt.error_text(blocks[-1].error)})"))
        p.complete = True
    elif not ok and len(blocks) < count and end >= len(data) and not any(b.unknown_size for b in blocks):
        findings.append(finding("pd_response_truncated", frame, "pd.n_params", len(blocks), p.n,
                                f"response ends after {len(blocks)} of {p.n} parameter blocks"))
    return p


def _blocks(data: bytes, pos: int, count: int, frame: int, findings: list[Finding],
            response: bool) -> tuple[list[Block], int, bool]:
    """`count` value/error blocks from `pos` with the pad rule of protocol.md 3.2."""
    blocks: list[Block] = []
    for i in range(count):
        if pos >= len(data):
            return blocks, pos, False
        block, problem = _block(data, pos, i, count, frame, response)
        if problem is not None:
            findings.append(problem)
            if block is not None:
                blocks.append(block)
                return blocks, block.end, problem.severity != "error" and block.unknown_size
            return blocks, pos, False
        assert block is not None
        blocks.append(block)
        pos = block.end
        if block.is_error or len(block.data) % 2 == 0:
            continue
        more = i < count - 1
        left = len(data) - pos
        if left == 0:  # with more blocks expected, the next round reports the record as cut short
            if not more:
                findings.append(finding("pad_missing_final", frame, f"pd.val[{i}].pad", "absent", "0x00",
                                        "odd value list at the end of the record without its pad byte"))
        elif left == 1 or (more and data[pos] == 0):
            _take_pad(block, data, pos, i, frame, findings)
            pos += 1
        elif more:
            if _greedy_ok(data, pos + 1, count - i - 1, response) or \
                    not _greedy_ok(data, pos, count - i - 1, response):
                _take_pad(block, data, pos, i, frame, findings)
                pos += 1
            else:
                findings.append(finding("pad_missing", frame, f"pd.val[{i}].pad", "absent", "0x00",
                                        "pad byte after an odd value list missing (decoded without it)"))
    return blocks, pos, True


def _take_pad(block: Block, data: bytes, pos: int, i: int, frame: int, findings: list[Finding]) -> None:
    block.pad_offset, block.pad = pos, data[pos]
    if block.pad:
        findings.append(finding("pad_nonzero", frame, f"pd.val[{i}].pad", f"{block.pad:#04x}", "0x00",
                                "word-alignment pad byte is not zero"))


def _greedy_ok(data: bytes, pos: int, count: int, response: bool) -> bool:
    """Whether `count` blocks parse from `pos` to exactly the end, always taking pad bytes."""
    for i in range(count):
        block, problem = _block(data, pos, i, count, 0, response, trial=True)
        if block is None or problem is not None:
            return False
        pos = block.end
        if not block.is_error and len(block.data) % 2 and (i < count - 1 or pos < len(data)):
            pos += 1
    return pos == len(data)


def _block(data: bytes, pos: int, i: int, count: int, frame: int, response: bool, trial: bool = False
           ) -> tuple[Block | None, Finding | None]:
    if pos + 2 > len(data):
        return None, finding("response_block_overrun" if response else "block_overrun", frame,
                             f"pd.val[{i}].format", len(data) - pos, ">= 2",
                             f"block {i} starts {len(data) - pos} byte(s) before the record ends")
    fmt, m = data[pos], data[pos + 1]
    spec = pt.FORMATS.get(fmt)
    if spec is None:
        last = i == count - 1
        rest = data[pos + 2:]
        block = Block(pos, fmt, m, 0, bytes(rest), unknown_size=True)
        if last:
            return block, finding("format_unsupported", frame, f"pd.val[{i}].format", f"{fmt:#04x}",
                                  "a format of known size (protocol.md 4.3)",
                                  f"format {fmt:#04x} has no known size: remaining {len(rest)} bytes shown raw")
        return block, finding("format_unsupported_stop", frame, f"pd.val[{i}].format", f"{fmt:#04x}",
                              "a format of known size (protocol.md 4.3)",
                              f"format {fmt:#04x} has no known size before the last block: decode stopped")
    size = spec.size
    if fmt == pt.FMT_DATE:
        size = 7 if trial else _date_size(data, pos, m, count - i - 1, response)
    need = m * size
    if pos + 2 + need > len(data):
        return None, finding("response_block_overrun" if response else "block_overrun", frame,
                             f"pd.val[{i}].n_values", m,
                             f"<= {(len(data) - pos - 2) // size if size else 0}",
                             f"block {i}: {m} values of {size} bytes overrun the record "
                             f"({len(data) - pos - 2} bytes left)")
    block = Block(pos, fmt, m, size, bytes(data[pos + 2:pos + 2 + need]))
    if fmt == pt.FMT_ERROR and m >= 1:
        block.error = int.from_bytes(block.data[:2], "big")
        if m >= 2:
            block.error_subindex = int.from_bytes(block.data[2:4], "big")
    return block, None


def _date_size(data: bytes, pos: int, m: int, rest: int, response: bool) -> int:
    """Date values are 7 bytes; one implementation pads them to 8 (protocol.md 4.3): take 8 only when
    the record does not add up with 7 (plus the 3.2 pad byte after an odd count) and does with 8.

    `rest` blocks follow this one. The look-ahead parses them with 7-byte Dates (no nested
    look-ahead, so the cost stays linear per Date block); when neither size adds up, the parity of
    the bytes left decides as a last guess.
    """
    left = len(data) - pos - 2
    if not m or left < 8 * m:
        return 7
    end7 = pos + 2 + 7 * m
    if m % 2 and (rest or len(data) - end7 == 1):
        end7 += 1  # pad byte after an odd value list
    if _greedy_ok(data, end7, rest, response):
        return 7
    if _greedy_ok(data, pos + 2 + 8 * m, rest, response):
        return 8
    return 8 if (left - 7 * m) % 2 and not (left - 8 * m) % 2 else 7


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
        return value, f"{value:.7g}" if len(raw) == 4 else repr(value)
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
            shown = f"{value:.7g}" if isinstance(value, float) else str(value)
            if element == "identifier":
                fmt = value & 0xFF
                flags = [text for bit, text in pt.IDENTIFIER_BITS.items() if value >> bit & 1]
                shown = f"0x{value:04x} (data type {pt.FORMAT_NAME.get(fmt, hex(fmt))}" + \
                        (f"; {', '.join(flags)}" if flags else "") + ")"
            elif element in ("low_limit", "high_limit"):
                shown = f"0x{value:08x} (as Float32 {struct.unpack('>f', raw)[0]:.7g})"
        else:
            value = raw.decode("latin-1")
            shown = f'"{value}"' if value.isprintable() else repr(value)
        out.append(Field(name, base + block.offset + 2 + off, size, bytes(raw), value, shown))
    return out


# --- annotation for the dump ----------------------------------------------------------------
Section = tuple[str, list[Field]]  # (title, fields), one tree node of the dump
Describe = Callable[[str, object], str]  # (limit key, value) -> check text, e.g. Checker.describe


def annotate(p: Parsed, data: bytes, base: int, describe: Describe,
             request: Parsed | None = None) -> list[Section]:
    """The dump's tree of a parsed request/response; `describe(key, value)` gives a check text."""
    if not p.header_ok:
        return [("PROFIdrive record (shorter than its header)",
                 [Field("pd.trailing", base, len(data), bytes(data), data.hex(), data.hex(" ") or "(empty)")])]
    layout = RESPONSE_HEADER if p.response else HEADER
    side = "response" if p.response else "request"
    head = layout.annotate(data, 0, (p.ref, p.ident, p.do, p.n), base)
    for fld, key in zip(head, ("ref", "resp_id" if p.response else "req_id", "do", "n_params"), strict=True):
        fld.check = describe(f"{side}.{key}", fld.value)
    sections: list[Section] = [(f"Parameter {side} header", head)]
    for i, a in enumerate(p.addresses):
        at = a.offset
        fields = [Field(f"pd.addr[{i}].{n}", base + at + off, size, bytes(data[at + off:at + off + size]),
                        v, _show_addr(n, v)) for n, off, size, v in
                  (("attr", 0, 1, a.attr), ("n_elems", 1, 1, a.n_elems), ("pnu", 2, 2, a.pnu),
                   ("subindex", 4, 2, a.subindex))]
        for fld, key in zip(fields, ("attribute", "n_elems", "pnu", "subindex"), strict=True):
            fld.check = describe(f"request.{key}", fld.value)
        sections.append((f"Parameter address {i + 1}: {a.label()}", fields))
    if p.echo:
        sections.append(("Address echo (AKD manual layout)", [Field("pd.echo", base + 4, 6, bytes(data[4:10]),
                                                                    data[4:10].hex(), data[4:10].hex(" "))]))
    addresses = request.addresses if request is not None and p.response else p.addresses
    for i, block in enumerate(p.blocks):
        addr = addresses[i] if i < len(addresses) else None
        sections.append((_block_title(i, block, addr, p.response), _block_fields(i, block, data, base, side,
                                                                                describe, addr)))
    if p.end < len(data):
        rest = data[p.end:]
        sections.append(("Bytes after the parsed record", [Field("pd.trailing", base + p.end, len(rest), bytes(rest),
                                                                 rest.hex(), rest.hex(" "))]))
    return sections




def _show_addr(name: str, value: int) -> str:
    if name == "attr":
        return f"0x{value:02x} ({pt.ATTRIBUTE.get(value, 'reserved')})"
    if name == "n_elems" and value == 0:
        return "0 (single value / non-array)"
    return str(value)


def _block_title(i: int, block: Block, addr: Address | None, response: bool) -> str:
    label = addr.label(block.n_values if addr is not None and addr.attr == pt.ATTR_VALUE
                       and not block.is_error else None) if addr is not None else f"block {i + 1}"
    if block.is_error:
        return f"Parameter {i + 1}: {label} error {block.error:#04x} ({pt.error_text(max(block.error, 0))})"
    if block.format in (pt.FMT_ZERO, pt.FMT_AKD_ZERO):
        return f"Parameter {i + 1}: {label} written" if response else f"Parameter {i + 1}: {label} Zero"
    name = pt.FORMAT_NAME.get(block.format, f"format {block.format:#04x}")
    element = ""
    if addr is not None and addr.attr == pt.ATTR_DESCRIPTION:
        element = f", description element {addr.subindex} ({pt.DESCRIPTION_ELEMENT.get(addr.subindex, '?')})"
    elif addr is not None and addr.attr == pt.ATTR_TEXT:
        element = ", text"
    return f"Parameter {i + 1}: {label} {name} x {block.n_values}{element}"


def _block_fields(i: int, block: Block, data: bytes, base: int, side: str, describe: Describe,
                  addr: Address | None) -> list[Field]:
    pos = block.offset
    fmt_show = f"0x{block.format:02x} ({pt.FORMAT_NAME.get(block.format, 'unknown format')})"
    fields = [Field(f"pd.val[{i}].format", base + pos, 1, bytes(data[pos:pos + 1]), block.format, fmt_show,
                    describe(f"{side}.format", block.format)),
              Field(f"pd.val[{i}].n_values", base + pos + 1, 1, bytes(data[pos + 1:pos + 2]), block.n_values,
                    str(block.n_values), describe(f"{side}.n_values", block.n_values) if not block.is_error else "")]
    if block.is_error:
        words = [block.data[k:k + 2] for k in range(0, len(block.data), 2)]
        for k, word in enumerate(words):
            value = int.from_bytes(word, "big")
            if k == 0:
                fields.append(Field(f"pd.val[{i}].error", base + pos + 2, 2, bytes(word), value,
                                    f"0x{value:02x} ({pt.error_text(value)})"))
            elif k == 1:
                fields.append(Field(f"pd.val[{i}].error_subindex", base + pos + 4, 2, bytes(word), value, str(value)))
            else:
                fields.append(Field(f"pd.val[{i}].value[{k}]", base + pos + 2 + 2 * k, 2, bytes(word), value,
                                    f"{value} (extra error value)"))
    elif addr is not None and addr.attr == pt.ATTR_DESCRIPTION and addr.subindex == 0 \
            and len(block.data) == pt.DESCRIPTION_SIZE:
        fields += description_fields(block, i, base)
    else:
        for j, (off, size, value, shown) in enumerate(values_of(block)):
            name = f"pd.val[{i}].value" if _is_text(block) else f"pd.val[{i}].value[{j}]"
            fields.append(Field(name, base + off, size, bytes(data[off:off + size]), value, shown))
    if block.pad >= 0:
        fields.append(Field(f"pd.val[{i}].pad", base + block.pad_offset, 1, bytes([block.pad]), block.pad,
                            f"0x{block.pad:02x} (word-alignment pad)"))
    return fields


def _is_text(block: Block) -> bool:
    spec = pt.FORMATS.get(block.format)
    return spec is None or block.unknown_size or spec.kind in ("string", "octets", "unicode")


def plausible(data: bytes, response: bool | None = None, max_params: int | None = None) -> bool:
    """Index 0x002F carries PROFIdrive only if the header is plausible (protocol.md 1.4): Request or
    Response ID valid, 1 <= n <= `max_params` (default: the generic profile's record limit), reference
    != 0, lengths consistent.

    `response` names the direction (False: parameter request of a write, True: parameter response
    of a read); None accepts either reading, for callers that do not pass it. Request and Response
    IDs 0x01/0x02 coincide, so the direction decides which length rule applies.
    """
    if len(data) < 4:
        return False
    ref, ident, _do, n = data[0], data[1], data[2], data[3]
    if max_params is None:
        max_params = generic_record().max_params
    if ref == 0 or not 1 <= n <= max_params:
        return False
    if response is None:
        return plausible(data, False, max_params) or plausible(data, True, max_params)
    if not response:
        if ident == pt.REQ_READ:
            return len(data) == 4 + 6 * n
        return ident == pt.REQ_CHANGE and len(data) > 4 + 6 * n
    if ident == pt.RES_CHANGE:
        return len(data) == 4
    if ident not in (pt.RES_READ, pt.RES_READ_NAK, pt.RES_CHANGE_NAK, pt.RES_NOT_SUPPORTED):
        return False
    found: list[Finding] = []
    p = parse_response(data, 0, found)
    return p.complete and p.end == len(data) and not p.echo
