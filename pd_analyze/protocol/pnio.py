"""NDR args header, IOD Read/Write header blocks, Write-Multiple, records bounded by RecordDataLength.

Parsing here is structural: it finds the blocks and the record bytes at their true offsets, and
reports only what stops or bounds the decode (truncation, nesting). Value and consistency rules
live in `checks`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import pairwise
from typing import NamedTuple

from pd_analyze.model import rules
from pd_analyze.model.layout import Layout
from pd_analyze.model.rules import Finding
from pd_analyze.model.values import (
    BT_READ_REQ,
    BT_READ_RES,
    BT_WRITE_REQ,
    BT_WRITE_RES,
    INDEX_WRITE_MULTIPLE,
    OP_READ,
    OP_READ_IMPLICIT,
    OP_WRITE,
    PNIO_OPNUM,
)

NDR_SIZE = 20
IOD_SIZE = 64
_NDR_REQ = (("ndr.args_max", "I"), ("ndr.args_len", "I"), ("ndr.max_count", "I"), ("ndr.offset", "I"),
            ("ndr.actual_count", "I"))
_NDR_TAIL = (("ndr.args_len", "I"), ("ndr.max_count", "I"), ("ndr.offset", "I"), ("ndr.actual_count", "I"))
# PNIOStatus is one NDR uint32 (ErrorCode most significant), so little-endian DREP reverses it.
_STATUS_BE = (("ndr.status.code", "B"), ("ndr.status.decode", "B"), ("ndr.status.code1", "B"),
              ("ndr.status.code2", "B"))
NDR_REQ = {True: Layout("NDR args (request)", "<", _NDR_REQ), False: Layout("NDR args (request)", ">", _NDR_REQ)}
NDR_RES = {True: Layout("NDR args (response)", "<", _STATUS_BE[::-1] + _NDR_TAIL),
           False: Layout("NDR args (response)", ">", _STATUS_BE + _NDR_TAIL)}

_COMMON = (("iod.block_type", "H"), ("iod.block_length", "H"), ("iod.version_high", "B"),
           ("iod.version_low", "B"), ("iod.seq", "H"), ("iod.ar_uuid", "16s"), ("iod.api", "I"),
           ("iod.slot", "H"), ("iod.subslot", "H"), ("iod.pad", "H"), ("iod.index", "H"),
           ("iod.record_len", "I"))
_STATUS = (("iod.status.code", "B"), ("iod.status.decode", "B"), ("iod.status.code1", "B"),
           ("iod.status.code2", "B"))
WRITE_REQ = Layout("IODWriteReqHeader", ">", _COMMON + (("iod.rw_pad", "24s"),))
READ_REQ = Layout("IODReadReqHeader", ">", _COMMON + (("iod.rw_pad", "24s"),))
READ_REQ_IMPLICIT = Layout("IODReadReqHeader (implicit)", ">", _COMMON + (
    ("iod.target_ar_uuid", "16s"), ("iod.rw_pad", "8s")))
WRITE_RES = Layout("IODWriteResHeader", ">", _COMMON + (
    ("iod.add_val1", "H"), ("iod.add_val2", "H")) + _STATUS + (("iod.rw_pad", "16s"),))
READ_RES = Layout("IODReadResHeader", ">", _COMMON + (
    ("iod.add_val1", "H"), ("iod.add_val2", "H"), ("iod.rw_pad", "20s")))
(B_TYPE, B_LENGTH, B_VHIGH, B_VLOW, B_SEQ, B_AR, B_API, B_SLOT, B_SUBSLOT, B_PAD, B_INDEX,
 B_RECLEN) = range(12)
B_ADD_VAL1, B_ADD_VAL2 = 12, 13  # in both response layouts, right after the common fields
assert all(layout.index("iod.add_val1") == B_ADD_VAL1 and layout.index("iod.add_val2") == B_ADD_VAL2
           for layout in (WRITE_RES, READ_RES))
assert all(layout.names[-1] == "iod.rw_pad" for layout in (WRITE_REQ, READ_REQ, READ_REQ_IMPLICIT, WRITE_RES,
                                                           READ_RES))  # checks reads the padding as values[-1]
_WRITE_RES_STATUS = WRITE_RES.index("iod.status.code")
_TARGET_AR = READ_REQ_IMPLICIT.index("iod.target_ar_uuid")
NIL_UUID = bytes(16)

EXPECTED_BLOCK = {(OP_WRITE, False): BT_WRITE_REQ, (OP_WRITE, True): BT_WRITE_RES,
                  (OP_READ, False): BT_READ_REQ, (OP_READ, True): BT_READ_RES,
                  (OP_READ_IMPLICIT, False): BT_READ_REQ, (OP_READ_IMPLICIT, True): BT_READ_RES}


def iod_layout(opnum: int, response: bool, ar_uuid_nil: bool) -> Layout:
    """The fixed layout for the service and direction (not for the BlockType seen: H1 checks that)."""
    if opnum == OP_WRITE:
        return WRITE_RES if response else WRITE_REQ
    if response:
        return READ_RES
    return READ_REQ_IMPLICIT if ar_uuid_nil else READ_REQ


class Status(NamedTuple):
    code: int
    decode: int
    code1: int
    code2: int

    @property
    def ok(self) -> bool:
        return not (self.code or self.decode or self.code1 or self.code2)

    def text(self) -> str:
        return f"{self.code:02X}{self.decode:02X}{self.code1:02X}{self.code2:02X}"


OK_STATUS = Status(0, 0, 0, 0)


@dataclass(slots=True)
class Block:
    """One IOD header block and the record it frames."""

    layout: Layout
    values: tuple
    offset: int  # of the header in the stub
    record: bytes  # bounded by RecordDataLength and by the bytes present
    record_offset: int
    depth: int = 0  # 1 for the inner blocks of a Write-Multiple
    status: Status | None = None  # write response block status
    target_ar: bytes = b""
    pd: object = None  # the parsed PROFIdrive request/response of this record, if any

    @property
    def index(self) -> int:
        return self.values[B_INDEX]

    @property
    def record_len(self) -> int:
        return self.values[B_RECLEN]

    def get(self, name: str) -> object:
        return self.values[self.layout.index(name)]


@dataclass(slots=True)
class Stub:
    """A decoded NDR stub: args header, then the IOD blocks."""

    little: bool
    response: bool
    ndr: tuple = ()
    status: Status | None = None  # response PNIOStatus from the NDR header
    blocks: list[Block] = field(default_factory=list)
    trailing: int = 0  # bytes after the last block/record
    truncated: bool = False
    # Write-Multiple: the bytes the outer RecordDataLength counts after the last inner record, up to the
    # next multiple of 4 (1-3 pad bytes, protocol.md 2.8: optional, both forms valid); empty when none
    last_pad: bytes = b""
    args_max: int = -1  # requests only
    args_len: int = -1
    max_count: int = -1
    offset: int = -1
    actual_count: int = -1

    @property
    def ndr_layout(self) -> Layout:
        return (NDR_RES if self.response else NDR_REQ)[self.little]


def parse_stub(stub: bytes, little: bool, response: bool, opnum: int, frame: int,
               findings: list[Finding]) -> Stub:
    """NDR header and, for Read/Write/ReadImplicit, the IOD blocks with their records.

    Only the PNIO CM operations (opnums 0-5, protocol.md 1.4) have NDR args; the stub of any other
    opnum is left undecoded (no `ndr`), as tshark does, rather than read as an args header.
    """
    out = Stub(little, response)
    if opnum not in PNIO_OPNUM:
        return out
    layout = (NDR_RES if response else NDR_REQ)[little]
    if len(stub) < NDR_SIZE:
        out.truncated = True
        findings.append(rules.finding("ndr_truncated", frame, "ndr.args_len", len(stub), f">= {NDR_SIZE}",
                                      f"stub of {len(stub)} bytes has no complete NDR header"))
        return out
    out.ndr = v = layout.struct.unpack_from(stub)
    if response:
        out.status = Status(v[3], v[2], v[1], v[0]) if little else Status(v[0], v[1], v[2], v[3])
        out.args_len, out.max_count, out.offset, out.actual_count = v[4:]
    else:
        out.args_max, out.args_len, out.max_count, out.offset, out.actual_count = v
    if (opnum, response) not in EXPECTED_BLOCK or len(stub) == NDR_SIZE:
        out.trailing = 0
        return out
    _parse_blocks(stub, out, opnum, response, frame, findings)
    return out


def _header(stub: bytes, pos: int, layout: Layout, frame: int, findings: list[Finding]) -> tuple | None:
    if len(stub) < pos + IOD_SIZE:
        findings.append(rules.finding("iod_truncated", frame, "iod.block_length", len(stub) - pos,
                                      IOD_SIZE, f"{layout.title} cut short: {len(stub) - pos} of "
                                                f"{IOD_SIZE} bytes present"))
        return None
    return layout.struct.unpack_from(stub, pos)


def _parse_blocks(stub: bytes, out: Stub, opnum: int, response: bool, frame: int,
                  findings: list[Finding]) -> None:
    nil = stub[NDR_SIZE + 8:NDR_SIZE + 24] == NIL_UUID
    layout = iod_layout(opnum, response, nil and opnum != OP_WRITE)
    values = _header(stub, NDR_SIZE, layout, frame, findings)
    if values is None:
        out.truncated = True
        return
    block = _block(stub, layout, values, NDR_SIZE, len(stub), 0, response, frame, findings)
    out.blocks.append(block)
    if layout in (WRITE_REQ, READ_RES) and len(block.record) < block.record_len:
        out.truncated = True
    if opnum == OP_WRITE and block.index == INDEX_WRITE_MULTIPLE:
        end = _multi(stub, out, block, response, frame, findings)
    elif (response and opnum == OP_WRITE) or (not response and opnum != OP_WRITE):
        end = NDR_SIZE + IOD_SIZE  # write responses and read requests carry no record
    else:
        end = block.record_offset + len(block.record)
    out.trailing = max(0, len(stub) - end)


def _block(stub: bytes, layout: Layout, values: tuple, pos: int, limit: int, depth: int,
           response: bool, frame: int, findings: list[Finding]) -> Block:
    start = pos + IOD_SIZE
    carries_record = layout in (WRITE_REQ, READ_RES)
    want = values[B_RECLEN] if carries_record else 0
    record = stub[start:min(start + want, limit)]
    if carries_record and len(record) < want:
        findings.append(rules.finding(
            "record_truncated", frame, "iod.record_len", len(record), want,
            f"record at index {values[B_INDEX]:#06x} truncated: RecordDataLength {want}, "
            f"{len(record)} bytes present"))
    block = Block(layout, values, pos, record, start, depth)
    if layout is WRITE_RES:
        block.status = Status._make(values[_WRITE_RES_STATUS:_WRITE_RES_STATUS + 4])
    elif layout is READ_REQ_IMPLICIT:
        block.target_ar = values[_TARGET_AR]
    return block


def _multi(stub: bytes, out: Stub, outer: Block, response: bool, frame: int,
           findings: list[Finding]) -> int:
    """Inner blocks of a Write-Multiple request or response (protocol.md 2.8); returns the end."""
    if response:
        pos = NDR_SIZE + IOD_SIZE
        while pos + IOD_SIZE <= len(stub):
            values = WRITE_RES.unpack(stub, pos)
            out.blocks.append(_block(stub, WRITE_RES, values, pos, len(stub), 1, True, frame, findings))
            pos += IOD_SIZE
        return pos
    end = min(outer.record_offset + outer.record_len, len(stub))
    pos = outer.record_offset
    while pos < end:
        aligned = (pos + 3) & ~3
        if aligned > pos:
            pad = stub[pos:min(aligned, end)]
            if aligned >= end:  # the last record's pad bytes, counted by the outer RecordDataLength
                out.last_pad = pad
                break
            if any(pad):
                findings.append(rules.finding(
                    "multi_write_padding", frame, "iod.multi_pad", pad.hex(), "00",
                    "Write-Multiple alignment padding not zero"))
            pos = aligned
        values = _header(stub, pos, WRITE_REQ, frame, findings)
        if values is None:
            out.truncated = True
            return len(stub)
        inner = _block(stub, WRITE_REQ, values, pos, end, 1, False, frame, findings)
        out.blocks.append(inner)
        if values[B_TYPE] != BT_WRITE_REQ:
            findings.append(rules.finding(
                "multi_write_structure", frame, "iod.block_type", f"{values[B_TYPE]:#06x}", "0x0008",
                "inner block of a Write-Multiple is not an IODWriteReqHeader"))
        if values[B_INDEX] == INDEX_WRITE_MULTIPLE:
            findings.append(rules.finding(
                "multi_write_structure", frame, "iod.index", "0xe040", "not 0xe040",
                "Write-Multiple nested inside a Write-Multiple (not decoded further)"))
        pos = inner.record_offset + len(inner.record)
        if len(inner.record) < inner.record_len:
            out.truncated = True
            break
    return max(pos, end)


def multi_pads(stub: Stub) -> list[tuple[int, int]]:
    """(offset, length) of the alignment padding between the inner blocks of a Write-Multiple."""
    pads = []
    inner = [b for b in stub.blocks if b.depth == 1]
    for prev, nxt in pairwise(inner):
        end = prev.record_offset + len(prev.record)
        if nxt.offset > end:
            pads.append((end, nxt.offset - end))
    if inner and stub.last_pad:  # after the last record (protocol.md 2.8)
        pads.append((inner[-1].record_offset + len(inner[-1].record), len(stub.last_pad)))
    return pads
