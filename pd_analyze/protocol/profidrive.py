"""PROFIdrive parameter request and response records (protocol.md 3 and 4), field by field.

`parse_request` / `parse_response` decode a record into small structures with offsets and report
the structural findings that bound the decode (too short, a block overrunning the record, a format
of unknown size, pad bytes). `annotate_*` turns a parsed record into registry Fields for the dump;
the report path never calls them. Range and consistency checks against the profiles live in
`pd_checks`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from pd_analyze.model import pd_values as pt
from pd_analyze.model.layout import Layout
from pd_analyze.model.rules import Finding, finding
from pd_analyze.protocol.profiles import VendorIds, VendorRequest, VendorResponse, generic_record

HEADER = Layout("PROFIdrive header", ">", (("pd.ref", "B"), ("pd.req_id", "B"), ("pd.do", "B"),
                                           ("pd.n_params", "B")))
RESPONSE_HEADER = Layout("PROFIdrive header", ">", (("pd.ref", "B"), ("pd.resp_id", "B"), ("pd.do", "B"),
                                                    ("pd.n_params", "B")))
_ADDRESS = struct.Struct(">BBHH")


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


def as_value(a: Address) -> Address:
    """A vendor service's address read as a value access: its Attribute names the vendor's service (e.g.
    MOVILINK WRITE volatile 0x30, protocol.md 5.5), not the PROFIdrive Description or Text."""
    return Address(a.offset, pt.ATTR_VALUE, a.n_elems, a.pnu, a.subindex)


def service_name(p: Parsed | None, attribute: int) -> str | None:
    """The vendor service a request's Attribute names (protocol.md 5.5), None for a PROFIdrive request."""
    service = p.vendor.service(attribute) if p is not None and isinstance(p.vendor, VendorRequest) else None
    return service.name if service is not None else None


def writes_values(p: Parsed | None) -> bool:
    """A request that writes values: a change parameter, or a vendor service laid out as one (5.5)."""
    if p is None or p.response:
        return False
    if isinstance(p.vendor, VendorRequest):
        return p.vendor.layout_of(p.addresses[0].attr if p.addresses else 0) == "change"
    return p.ident == pt.REQ_CHANGE


def error_meaning(value: int, response: Parsed | None = None, names: pt.Names = pt.PROFIDRIVE_NAMES) -> str:
    """An error value as the response's profile names it: a vendor error word (5.5), or a PROFIdrive number
    with the profile's manufacturer-specific text where it has one (`names`: the run's, Checker.names)."""
    vendor = response.vendor if response is not None and isinstance(response.vendor, VendorResponse) else None
    text = vendor.error_text(value) if vendor is not None else None
    return text if text is not None else names.error(max(value, 0))


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
    vendor: VendorRequest | VendorResponse | None = None  # a profile's own Request/Response ID (5.5)

    @property
    def header_ok(self) -> bool:
        return self.length >= 4


def footprint(p: Parsed) -> int:
    """Bytes a parsed record keeps alive, objects included (roughly): what the caps of the tables that
    keep parsed requests count. A record of n parameters costs some 300 bytes per parameter."""
    return footprint_of(p.length, len(p.addresses), len(p.blocks))


def footprint_of(length: int, addresses: int, blocks: int) -> int:
    """`footprint` of a record of `length` bytes parsed into so many addresses and blocks."""
    return 256 + 2 * length + 128 * addresses + 192 * blocks  # block data <= length


# --- parsing ----------------------------------------------------------------------------------
def parse_request(data: bytes, frame: int, findings: list[Finding], ids: VendorIds | None = None) -> Parsed:
    """A parameter request (Write to a PROFIdrive index): header, addresses, value blocks. `ids`: the
    selected profile's own Request IDs, laid out as it declares (protocol.md 5.5); others stay reserved."""
    p = Parsed(False, len(data))
    if len(data) < 4:
        findings.append(finding("pd_too_short", frame, "iod.record_len", len(data), ">= 4",
                                f"parameter request of {len(data)} bytes has no complete header"))
        return p
    p.ref, p.ident, p.do, p.n = HEADER.unpack(data)
    pos = 4
    for i in range(p.n):
        if pos + 6 > len(data):
            findings.append(finding("pd_too_short", frame, "iod.record_len", len(data), f">= {4 + 6 * p.n}",
                                    f"request ends after {i} of {p.n} parameter addresses"))
            p.end = pos
            return p
        p.addresses.append(Address(pos, *_ADDRESS.unpack_from(data, pos)))
        pos += 6
    p.end = pos
    change = p.ident == pt.REQ_CHANGE
    if ids is not None and p.ident in ids.requests:
        p.vendor = vendor = ids.requests[p.ident]
        change = vendor.layout_of(p.addresses[0].attr if p.addresses else 0) == "change"
    if not change:
        p.complete = True
        return p
    p.blocks, p.end, p.complete = _blocks(data, pos, p.n, frame, findings, False)
    if len(p.blocks) < p.n and p.end >= len(data) and not any(b.unknown_size for b in p.blocks):
        findings.append(finding("change_blocks", frame, "pd.n_params", len(p.blocks), p.n,
                                f"change request ends after {len(p.blocks)} of {p.n} value blocks"))
        p.complete = False
    return p


def parse_response(data: bytes, frame: int, findings: list[Finding], ids: VendorIds | None = None) -> Parsed:
    """A parameter response (Read response from a PROFIdrive index); `ids` as for parse_request: a vendor's
    positive Response ID carries value blocks or nothing (a write service), a negative one error blocks."""
    p = Parsed(True, len(data))
    if len(data) < 4:
        findings.append(finding("pd_response_too_short", frame, "iod.record_len", len(data), ">= 4",
                                f"parameter response of {len(data)} bytes has no complete header"))
        return p
    p.ref, p.ident, p.do, p.n = RESPONSE_HEADER.unpack(data)
    p.end = 4
    if ids is not None and p.ident in ids.responses:
        p.vendor = ids.responses[p.ident]
        if len(data) == 4 and not p.vendor.negative:  # the answer to a write service: header only
            p.complete = True
            return p
    elif p.ident == pt.RES_CHANGE:
        p.complete = True
        return p
    elif p.ident not in (pt.RES_READ, pt.RES_READ_NAK, pt.RES_CHANGE_NAK, pt.RES_NOT_SUPPORTED):
        # Unknown Response ID: Q1 reports it and the body is not guessed at. A header-only record is
        # still completely decoded (its verdict comes from Q3, protocol.md 7.4); a body is not.
        p.complete = len(data) == 4
        return p
    # No. of parameters 0 mirrors a request of no parameter: a negative answer refuses it with one error
    # block for the whole request (3.3), as a 0x80 does
    count = 1 if p.n == 0 and (p.ident == pt.RES_NOT_SUPPORTED or (p.ident & 0x80 and len(data) > 4)) else p.n
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


def plausible(data: bytes, response: bool | None = None, max_params: int | None = None,
              ids: VendorIds | None = None) -> bool:
    """Index 0x002F carries PROFIdrive only if the header is plausible (protocol.md 1.4): Request or
    Response ID valid, 1 <= n <= `max_params` (default: the generic profile's record limit), reference
    != 0, lengths consistent.

    `response` names the direction (False: parameter request of a write, True: parameter response
    of a read); None accepts either reading, for callers that do not pass it. Request and Response
    IDs 0x01/0x02 coincide, so the direction decides which length rule applies. `ids`: the selected
    profile's own IDs count as valid, with their declared layouts.
    """
    if len(data) < 4:
        return False
    ref, ident, _do, n = data[0], data[1], data[2], data[3]
    if max_params is None:
        max_params = generic_record().max_params
    if ref == 0 or not 1 <= n <= max_params:
        return False
    if response is None:
        return plausible(data, False, max_params, ids) or plausible(data, True, max_params, ids)
    if ids is not None and ident in (ids.responses if response else ids.requests):
        vendor = (parse_response if response else parse_request)(data, 0, [], ids)
        return vendor.complete and vendor.end == len(data)
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
