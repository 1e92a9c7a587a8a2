"""PNIO record layer encoders: PNIOStatus, the NDR args header, the four
64-byte IOD header blocks and Write-Multiple (protocol.md 2.5-2.8).

NDR integers follow the DREP (`little`); everything inside blocks is
big-endian whatever the DREP says.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

from .rpc_encode import UuidLike, as_uuid, u32

# Block types (2.6)
WRITE_REQ: Final = 0x0008
WRITE_RES: Final = 0x8008
READ_REQ: Final = 0x0009
READ_RES: Final = 0x8009

INDEX_WRITE_MULTIPLE: Final = 0xE040
API_PROFIDRIVE: Final = 0x3A00

STATUS_OK: Final = b"\x00\x00\x00\x00"
STATUS_B5: Final = bytes.fromhex("de80b500")  # read: state conflict, response not ready


def pnio_status(code: int, decode: int, code1: int, code2: int) -> bytes:
    """PNIOStatus in natural order (ErrorCode, ErrorDecode, ErrorCode1, ErrorCode2)."""
    return bytes([code, decode, code1, code2])


def ndr_status(status: bytes, little: bool) -> bytes:
    """PNIOStatus as the NDR marshals it: one uint32, ErrorCode most
    significant, in DREP order (reversed on the wire for little-endian)."""
    return u32(int.from_bytes(status, "big"), little)


def ndr_request(
    payload: bytes,
    *,
    args_max: int,
    little: bool,
    args_len: int | None = None,
    max_count: int | None = None,
    offset: int = 0,
    actual_count: int | None = None,
) -> bytes:
    """Request stub: NDR args header (ArgsMaximum, ArgsLength, MaxCount,
    Offset, ActualCount) + payload."""
    alen = len(payload) if args_len is None else args_len
    mc = args_max if max_count is None else max_count
    ac = alen if actual_count is None else actual_count
    return b"".join(u32(v, little) for v in (args_max, alen, mc, offset, ac)) + payload


def ndr_response(
    payload: bytes,
    *,
    status: bytes,
    max_count: int,
    little: bool,
    args_len: int | None = None,
    offset: int = 0,
    actual_count: int | None = None,
    status_raw: bytes | None = None,
) -> bytes:
    """Response stub: PNIOStatus (DREP-ordered uint32; `status_raw` writes 4
    bytes verbatim instead), ArgsLength, MaxCount (= request ArgsMaximum),
    Offset, ActualCount + payload."""
    alen = len(payload) if args_len is None else args_len
    ac = alen if actual_count is None else actual_count
    st = ndr_status(status, little) if status_raw is None else status_raw
    return st + b"".join(u32(v, little) for v in (alen, max_count, offset, ac)) + payload


def iod_header(
    block_type: int,
    *,
    seq: int,
    ar_uuid: UuidLike,
    api: int,
    slot: int,
    subslot: int,
    index: int,
    record_len: int,
    tail: bytes,
    block_length: int = 60,
    version_high: int = 1,
    version_low: int = 0,
    pad: int = 0,
) -> bytes:
    """Common 36 bytes + RecordDataLength + the 24 type-specific bytes."""
    if len(tail) != 24:
        raise ValueError("IOD header tail must be 24 bytes (use a *_padding override to change content)")
    head = struct.pack(">HHBBH", block_type, block_length, version_high, version_low, seq)
    head += as_uuid(ar_uuid).bytes
    head += struct.pack(">IHHHHI", api, slot, subslot, pad, index, record_len)
    return head + tail


def iod_write_req(*, rw_padding: bytes = bytes(24), block_type: int = WRITE_REQ, **common: Any) -> bytes:
    """IODWriteReqHeader 0x0008; RecordDataLength = bytes that follow."""
    return iod_header(block_type, tail=rw_padding, **common)


def iod_write_res(
    *,
    status: bytes = STATUS_OK,
    add_val1: int = 0,
    add_val2: int = 0,
    rw_padding: bytes = bytes(16),
    block_type: int = WRITE_RES,
    **common: Any,
) -> bytes:
    """IODWriteResHeader 0x8008: AddVal1/2, block PNIOStatus (natural order)."""
    tail = struct.pack(">HH", add_val1, add_val2) + status + rw_padding
    return iod_header(block_type, tail=tail, **common)


def iod_read_req(
    *,
    target_ar_uuid: UuidLike | None = None,
    rw_padding: bytes | None = None,
    block_type: int = READ_REQ,
    **common: Any,
) -> bytes:
    """IODReadReqHeader 0x0009; with a TargetARUUID (implicit read) the
    padding shrinks to 8 bytes."""
    if target_ar_uuid is None:
        tail = bytes(24) if rw_padding is None else rw_padding
    else:
        tail = as_uuid(target_ar_uuid).bytes + (bytes(8) if rw_padding is None else rw_padding)
    return iod_header(block_type, tail=tail, **common)


def iod_read_res(
    *,
    add_val1: int = 0,
    add_val2: int = 0,
    rw_padding: bytes = bytes(20),
    block_type: int = READ_RES,
    **common: Any,
) -> bytes:
    """IODReadResHeader 0x8009: AddVal1/2 then 20 bytes RWPadding."""
    tail = struct.pack(">HH", add_val1, add_val2) + rw_padding
    return iod_header(block_type, tail=tail, **common)


@dataclass(frozen=True)
class InnerWrite:
    """One write inside a Write-Multiple: its own header fields + record.
    `header` overrides any iod_write_req keyword (e.g. block_type)."""

    index: int
    data: bytes
    seq: int
    ar_uuid: UuidLike
    api: int = 0
    slot: int = 0
    subslot: int = 1
    header: Mapping[str, Any] = field(default_factory=dict)

    def encode(self) -> bytes:
        fields: dict[str, Any] = dict(
            seq=self.seq,
            ar_uuid=self.ar_uuid,
            api=self.api,
            slot=self.slot,
            subslot=self.subslot,
            index=self.index,
            record_len=len(self.data),
        )
        fields.update(self.header)
        return iod_write_req(**fields) + self.data


def align4_pad(position: int, fill: int = 0) -> bytes:
    return bytes([fill]) * (-position % 4)


def write_multiple_records(
    inner: Sequence[bytes],
    *,
    pad_fill: int = 0,
    pad_after_last: bool = False,
) -> bytes:
    """Concatenate encoded inner header+record pieces with 0-3 pad bytes so
    each next header starts 4-aligned. Positions are counted after the
    64-byte outer header, which does not change the alignment."""
    out = b""
    for i, piece in enumerate(inner):
        out += piece
        if i + 1 < len(inner) or pad_after_last:
            out += align4_pad(len(out), pad_fill)
    return out


def write_multiple_req(
    inner: Sequence[InnerWrite | bytes],
    *,
    seq: int,
    ar_uuid: UuidLike,
    api: int = 0xFFFFFFFF,
    slot: int = 0xFFFF,
    subslot: int = 0xFFFF,
    pad_fill: int = 0,
    pad_after_last: bool = False,
    **outer: Any,
) -> bytes:
    """Outer IODWriteReqHeader (Index 0xE040) + inner writes. Items may be
    pre-encoded bytes to inject malformed inner blocks."""
    pieces = [w.encode() if isinstance(w, InnerWrite) else w for w in inner]
    body = write_multiple_records(pieces, pad_fill=pad_fill, pad_after_last=pad_after_last)
    fields: dict[str, Any] = dict(
        seq=seq, ar_uuid=ar_uuid, api=api, slot=slot, subslot=subslot, index=INDEX_WRITE_MULTIPLE, record_len=len(body)
    )
    fields.update(outer)
    return iod_write_req(**fields) + body


def write_multiple_res(
    inner: Sequence[bytes],
    *,
    seq: int,
    ar_uuid: UuidLike,
    api: int = 0xFFFFFFFF,
    slot: int = 0xFFFF,
    subslot: int = 0xFFFF,
    status: bytes = STATUS_OK,
    **outer: Any,
) -> bytes:
    """Outer IODWriteResHeader (RecordDataLength = bytes of the inner
    response headers) + the inner IODWriteResHeaders in order."""
    body = b"".join(inner)
    fields: dict[str, Any] = dict(
        seq=seq,
        ar_uuid=ar_uuid,
        api=api,
        slot=slot,
        subslot=subslot,
        index=INDEX_WRITE_MULTIPLE,
        record_len=len(body),
        status=status,
    )
    fields.update(outer)
    return iod_write_res(**fields) + body


# ---- Connect / Release / Control blocks -------------------------------------
# The analyser shows these calls' blocks raw; they are encoded properly only
# so that tshark decodes the samples without malformed-packet noise.

AR_BLOCK_REQ: Final = 0x0101
AR_BLOCK_RES: Final = 0x8101
IOD_CONTROL_REQ: Final = 0x0110  # PrmEnd
IOD_CONTROL_RES: Final = 0x8110
IOD_RELEASE_REQ: Final = 0x0114
IOD_RELEASE_RES: Final = 0x8114
CMD_PRM_END: Final = 0x0001
CMD_RELEASE: Final = 0x0004
CMD_DONE: Final = 0x0008


def block(block_type: int, body: bytes, *, version: tuple[int, int] = (1, 0), block_length: int | None = None) -> bytes:
    """Generic PNIO block: BlockType, BlockLength (= body + 2 version
    bytes), version, body."""
    ln = len(body) + 2 if block_length is None else block_length
    return struct.pack(">HHBB", block_type, ln, *version) + body


def ar_block_req(
    *,
    ar_uuid: UuidLike,
    session_key: int,
    initiator_mac: bytes,
    initiator_object: UuidLike,
    station_name: str,
    ar_type: int = 0x0001,
    ar_properties: int = 0x00000011,
    timeout_factor: int = 100,
    rt_port: int = 0x8892,
) -> bytes:
    name = station_name.encode()
    body = struct.pack(">H", ar_type) + as_uuid(ar_uuid).bytes + struct.pack(">H", session_key) + initiator_mac
    body += as_uuid(initiator_object).bytes + struct.pack(">IHHH", ar_properties, timeout_factor, rt_port, len(name))
    return block(AR_BLOCK_REQ, body + name)


def ar_block_res(
    *, ar_uuid: UuidLike, session_key: int, responder_mac: bytes, ar_type: int = 0x0001, rt_port: int = 0x8892
) -> bytes:
    body = struct.pack(">H", ar_type) + as_uuid(ar_uuid).bytes + struct.pack(">H", session_key) + responder_mac
    return block(AR_BLOCK_RES, body + struct.pack(">H", rt_port))


def control_block(block_type: int, *, ar_uuid: UuidLike, session_key: int, command: int, properties: int = 0) -> bytes:
    """IODControlReq/Res and IODReleaseReq/Res share one layout."""
    body = b"\x00\x00" + as_uuid(ar_uuid).bytes + struct.pack(">HHHH", session_key, 0, command, properties)
    return block(block_type, body)
