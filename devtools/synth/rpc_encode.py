"""Connectionless DCE/RPC (v4) encoders: the 80-byte header, CL
fragmentation, and the bodies of the non-data PDUs (fault, reject, fack,
cancel, cancel_ack). protocol.md section 2.1-2.3.

The DREP integer-order nibble decides the byte order of every 2/4-byte
integer and of the first three UUID fields; `little` may be forced to
produce a PDU whose DREP lies about its own byte order.
"""

from __future__ import annotations

import functools
import struct
import uuid
from collections.abc import Sequence
from typing import Any, Final

DREP_LE: Final = b"\x10\x00\x00"  # little-endian, ASCII, IEEE
DREP_BE: Final = b"\x00\x00\x00"  # big-endian, ASCII, IEEE

# Packet types (protocol.md 2.2)
REQUEST: Final = 0
PING: Final = 1
RESPONSE: Final = 2
FAULT: Final = 3
WORKING: Final = 4
NOCALL: Final = 5
REJECT: Final = 6
ACK: Final = 7
CL_CANCEL: Final = 8
FACK: Final = 9
CANCEL_ACK: Final = 10

# Flags1 bits
F1_LAST_FRAG: Final = 0x02
F1_FRAG: Final = 0x04
F1_NOFACK: Final = 0x08
F1_MAYBE: Final = 0x10
F1_IDEMPOTENT: Final = 0x20
F1_BROADCAST: Final = 0x40
# Flags2 bits
F2_CANCEL_PENDING: Final = 0x02

# Unfragmented PNIO defaults seen on real equipment (and in protocol.md 9).
REQ_FLAGS1: Final = F1_IDEMPOTENT
RES_FLAGS1: Final = F1_NOFACK | F1_LAST_FRAG

MAX_FRAG_BODY: Final = 1384  # 1464-byte UDP payload = 80 header + 1384 body

NIL_UUID: Final = uuid.UUID(int=0)
PNIO_DEVICE_IF: Final = uuid.UUID("dea00001-6c97-11d1-8271-00a02442df7d")
PNIO_CONTROLLER_IF: Final = uuid.UUID("dea00002-6c97-11d1-8271-00a02442df7d")
PNIO_SUPERVISOR_IF: Final = uuid.UUID("dea00003-6c97-11d1-8271-00a02442df7d")
PNIO_PARAMSERVER_IF: Final = uuid.UUID("dea00004-6c97-11d1-8271-00a02442df7d")
EPM_IF: Final = uuid.UUID("e1af8308-5d1f-11c9-91a4-08002b14a0fa")

UuidLike = uuid.UUID | str


def as_uuid(u: UuidLike) -> uuid.UUID:
    return u if isinstance(u, uuid.UUID) else uuid.UUID(u)


def pnio_object_uuid(instance: int, device_id: int, vendor_id: int) -> uuid.UUID:
    """dea00000-6c97-11d1-8271-IIIIDDDDVVVV (protocol.md 1.4)."""
    tail = (instance << 32) | (device_id << 16) | vendor_id
    return uuid.UUID(int=(0xDEA000006C9711D18271 << 48) | tail)


def drep_little(drep: bytes) -> bool:
    """Integer order announced by DREP byte 0 (high nibble 1 = little)."""
    return bool(drep[0] & 0x10)


@functools.cache  # a session repeats its three UUIDs in every PDU
def uuid_wire(u: UuidLike, little: bool) -> bytes:
    """DREP-ordered UUID: first three fields in the integer order, last 8
    bytes as-is (little-endian is Python's bytes_le form)."""
    v = as_uuid(u)
    return v.bytes_le if little else v.bytes


def u16(value: int, little: bool) -> bytes:
    return struct.pack("<H" if little else ">H", value & 0xFFFF)


def u32(value: int, little: bool) -> bytes:
    return struct.pack("<I" if little else ">I", value & 0xFFFFFFFF)


def rpc_header(
    *,
    ptype: int,
    activity: UuidLike,
    seq: int = 0,
    opnum: int = 0,
    object_uuid: UuidLike = NIL_UUID,
    interface: UuidLike = PNIO_DEVICE_IF,
    flags1: int = 0,
    flags2: int = 0,
    drep: bytes = DREP_LE,
    serial: int = 0,
    serial_hi: int | None = None,
    serial_lo: int | None = None,
    boot_time: int = 0,
    if_version: int = 1,
    ihint: int = 0xFFFF,
    ahint: int = 0xFFFF,
    frag_len: int = 0,
    frag_num: int = 0,
    auth_proto: int = 0,
    version: int = 4,
    little: bool | None = None,
) -> bytes:
    """The 80-byte CL header (protocol.md 2.1). `serial` is split into
    hi/lo unless those are given; `little` defaults to what DREP says."""
    le = drep_little(drep) if little is None else little
    hi = (serial >> 8) & 0xFF if serial_hi is None else serial_hi
    lo = serial & 0xFF if serial_lo is None else serial_lo
    out = (
        bytes([version, ptype, flags1, flags2])
        + drep[:3]
        + bytes([hi])
        + uuid_wire(object_uuid, le)
        + uuid_wire(interface, le)
        + uuid_wire(activity, le)
        + u32(boot_time, le)
        + u32(if_version, le)
        + u32(seq, le)
        + u16(opnum, le)
        + u16(ihint, le)
        + u16(ahint, le)
        + u16(frag_len, le)
        + u16(frag_num, le)
        + bytes([auth_proto, lo])
    )
    assert len(out) == 80
    return out


def rpc_pdu(body: bytes = b"", *, frag_len: int | None = None, **header: Any) -> bytes:
    """Header + body; frag_len defaults to the body length."""
    ln = len(body) if frag_len is None else frag_len
    return rpc_header(frag_len=ln, **header) + body


def split_body(body: bytes, max_body: int = MAX_FRAG_BODY, sizes: Sequence[int] | None = None) -> list[bytes]:
    """Cut an RPC body into fragment bodies: fixed `max_body` pieces, or the
    explicit `sizes` (the last piece takes whatever remains)."""
    if sizes is None:
        return [body[i : i + max_body] for i in range(0, len(body), max_body)] or [b""]
    pieces, pos = [], 0
    for size in sizes:
        pieces.append(body[pos : pos + size])
        pos += size
    if pos < len(body):
        pieces.append(body[pos:])
    return pieces


def cl_fragments(
    body: bytes,
    *,
    max_body: int = MAX_FRAG_BODY,
    sizes: Sequence[int] | None = None,
    flags1: int = 0,
    last_extra: int = F1_NOFACK,
    **header: Any,
) -> list[bytes]:
    """Split a body into CL fragment PDUs in fragment-number order.

    Every piece gets Flags1 0x04, the last also 0x02; frag_num counts from 0
    and the serial number equals frag_num (first transmission, 2.3).
    `flags1` holds the other bits (idempotent, ...); `last_extra` is added on
    the last piece only (real stacks set "no fack" there: the reply acks it).
    """
    pieces = split_body(body, max_body, sizes)
    pdus = []
    for num, piece in enumerate(pieces):
        last = num == len(pieces) - 1
        f1 = flags1 | F1_FRAG | ((F1_LAST_FRAG | last_extra) if last else 0)
        pdus.append(rpc_pdu(piece, flags1=f1, frag_num=num, serial=num, **header))
    return pdus


def status_body(status: int, little: bool) -> bytes:
    """Fault / reject body: the NCA status as one uint32 in DREP order."""
    return u32(status, little)


def fack_body(
    *,
    little: bool,
    version: int = 1,
    window_size: int = 1,
    max_tsdu: int = 1464,
    max_frag_size: int = 1464,
    serial_num: int = 0,
    selack: Sequence[int] = (),
    selack_len: int | None = None,
) -> bytes:
    """FACK body (DCE CL): vers, pad, window size, max TSDU, max fragment
    size, serial number of the acknowledged fragment, selective-ack masks."""
    n = len(selack) if selack_len is None else selack_len
    out = bytes([version, 0]) + u16(window_size, little) + u32(max_tsdu, little) + u32(max_frag_size, little)
    out += u16(serial_num, little) + u16(n, little)
    return out + b"".join(u32(mask, little) for mask in selack)


def cancel_body(cancel_id: int, little: bool, version: int = 0) -> bytes:
    return u32(version, little) + u32(cancel_id, little)


def cancel_ack_body(cancel_id: int, little: bool, accepting: bool = True, version: int = 0) -> bytes:
    # server_is_accepting is an NDR boolean: one byte.
    return u32(version, little) + u32(cancel_id, little) + bytes([1 if accepting else 0])
