"""Connectionless DCE/RPC v4: the header, PNIO recognition and the header's checks (R2, R4-R6).

Fragment reassembly is in rpc_fragments, call pairing in rpc_calls. Calls are keyed by activity UUID +
sequence number only, never by UDP ports (devices answer from other ports). Activity UUIDs are kept in
canonical big-endian form, because a request and its response may use different DREP byte orders.
"""

from __future__ import annotations

from typing import NamedTuple

from pd_analyze.model.layout import Layout
from pd_analyze.model.rules import Finding, finding
from pd_analyze.model.values import (
    FLAG1_BROADCAST,
    FLAG1_MAYBE,
    PNIO_UUID_PREFIX,
    PNIO_UUID_SUFFIX,
    PTYPE_ACK,
    PTYPE_CANCEL,
    PTYPE_CANCEL_ACK,
    PTYPE_FACK,
    PTYPE_PING,
    PTYPE_REQUEST,
    PTYPE_RESPONSE,
)
from pd_analyze.protocol.rpc_calls import Call

HEADER_SIZE = 80
_FIELDS = (
    ("rpc.ver", "B"), ("rpc.ptype", "B"), ("rpc.flags1", "B"), ("rpc.flags2", "B"), ("rpc.drep", "3s"),
    ("rpc.serial_hi", "B"), ("rpc.object", "16s"), ("rpc.interface", "16s"), ("rpc.activity", "16s"),
    ("rpc.boot_time", "I"), ("rpc.if_version", "I"), ("rpc.seq", "I"), ("rpc.opnum", "H"),
    ("rpc.ihint", "H"), ("rpc.ahint", "H"), ("rpc.frag_len", "H"), ("rpc.frag_num", "H"),
    ("rpc.auth_proto", "B"), ("rpc.serial_lo", "B"))
HEADER_LE = Layout("DCE/RPC connectionless header", "<", _FIELDS)
HEADER_BE = Layout("DCE/RPC connectionless header", ">", _FIELDS)
(I_VER, I_PTYPE, I_FLAGS1, I_FLAGS2, I_DREP, I_SERIAL_HI, I_OBJECT, I_INTERFACE, I_ACTIVITY, I_BOOT,
 I_IFVER, I_SEQ, I_OPNUM, I_IHINT, I_AHINT, I_FRAG_LEN, I_FRAG_NUM, I_AUTH, I_SERIAL_LO) = range(19)
FAULT_LE = Layout("Fault status", "<", (("rpc.fault_status", "I"),))
FAULT_BE = Layout("Fault status", ">", (("rpc.fault_status", "I"),))
_CONTROL_PTYPES = frozenset({PTYPE_PING, PTYPE_ACK, PTYPE_CANCEL, PTYPE_FACK, PTYPE_CANCEL_ACK})

SKIP_NOT_RPC = "UDP, not DCE/RPC v4"
SKIP_NOT_PNIO = "DCE/RPC, not PNIO (e.g. endpoint mapper)"
# What `plausible` asks of the first header bytes (protocol.md 1.4 items 1-3)
RPC_VERSION = 4
PTYPE_LAST = 10  # cancel_ack, the highest packet type
FLAGS2_RESERVED = 0xFC  # flags2 bits other than implementation (0x01) and cancel pending (0x02)
DREP_RESERVED = 0xEE  # drep[0] bits other than the integer order (0x10) and the character set (0x01)
DREP_FLOAT_LAST = 3  # IBM, the highest float representation
DREP_LITTLE = 0x10  # drep[0]: integers little-endian


def canonical_uuid(raw: bytes, little: bool) -> bytes:
    """A DREP-ordered UUID as big-endian bytes, so both byte orders give one key."""
    if not little:
        return raw
    return raw[3::-1] + raw[5:3:-1] + raw[7:5:-1] + raw[8:]


def is_pnio_uuid(canonical: bytes) -> bool:
    return canonical[:3] == PNIO_UUID_PREFIX and canonical[4:] == PNIO_UUID_SUFFIX


def plausible(payload: bytes) -> bool:
    """protocol.md 1.4 items 1-3: a CL-RPC v4 header, by a few byte comparisons."""
    return (len(payload) >= HEADER_SIZE and payload[0] == RPC_VERSION and payload[1] <= PTYPE_LAST
            and not payload[3] & FLAGS2_RESERVED and not payload[4] & DREP_RESERVED
            and payload[5] <= DREP_FLOAT_LAST)


class Header(NamedTuple):
    """The header fields the analysis needs, decoded from one unpack of the 80 bytes."""

    values: tuple
    little: bool
    ptype: int
    flags1: int
    activity: bytes  # canonical
    interface: bytes  # canonical
    seq: int
    opnum: int
    frag_len: int
    frag_num: int


def header(payload: bytes) -> Header:
    little = bool(payload[4] & DREP_LITTLE)
    v = (HEADER_LE if little else HEADER_BE).unpack(payload)
    return Header(v, little, v[I_PTYPE], v[I_FLAGS1], canonical_uuid(v[I_ACTIVITY], little),
                  canonical_uuid(v[I_INTERFACE], little), v[I_SEQ], v[I_OPNUM], v[I_FRAG_LEN],
                  v[I_FRAG_NUM])


def is_control(ptype: int) -> bool:
    """Ping, ack, cancel, fack, cancel_ack: no body to decode as data."""
    return ptype in _CONTROL_PTYPES


# --- checks: R2, R4-R6 and the serial-number note (protocol.md 6.1) -----------------------------------
def check_header(hdr: Header, frame: int, body_present: int, record_service: bool) -> list[Finding]:
    """R2, R5, R6 and the serial-number note on one PDU header."""
    out: list[Finding] = []
    v = hdr.values
    if body_present > hdr.frag_len:
        out.append(finding("rpc_extra_bytes", frame, "rpc.frag_len", hdr.frag_len, body_present,
                           f"{body_present - hdr.frag_len} bytes after the fragment body"))
    if v[I_IFVER] != 1:
        out.append(finding("rpc_header_values", frame, "rpc.if_version", v[I_IFVER], 1,
                           "interface version is not 1"))
    if v[I_AUTH] != 0:
        out.append(finding("auth_present", frame, "rpc.auth_proto", v[I_AUTH], 0,
                           "authentication protocol set: body not decoded"))
    if record_service and hdr.ptype == PTYPE_REQUEST and hdr.flags1 & (FLAG1_MAYBE | FLAG1_BROADCAST):
        out.append(finding("rpc_header_values", frame, "rpc.flags1", f"{hdr.flags1:#04x}",
                           "maybe and broadcast clear", "Read/Write request flagged maybe/broadcast: "
                                                        "no response expected"))
    drep = v[I_DREP]
    if drep[1] != 0:
        out.append(finding("rpc_float_repr", frame, "rpc.drep", drep.hex(), "float representation 0 (IEEE)",
                           f"DREP float representation {drep[1]} is not IEEE"))
    serial = v[I_SERIAL_HI] << 8 | v[I_SERIAL_LO]
    if serial != hdr.frag_num and hdr.ptype in (PTYPE_REQUEST, PTYPE_RESPONSE):
        out.append(finding("rpc_serial", frame, "rpc.serial_lo", serial, hdr.frag_num,
                           "serial number differs from the fragment number (a retransmission?)"))
    return out


def check_response(req: Call, hdr: Header, src: bytes, dst: bytes, frame: int) -> list[Finding]:
    """R4: the response names the request's interface and opnum, and swaps its addresses."""
    return response_findings(req.frame, hdr.interface == req.interface and hdr.opnum == req.opnum, hdr.opnum,
                             req.opnum, _ip(src), _ip(req.dst), (src, dst) == (req.dst, req.src), frame)


def response_findings(request_frame: int, same_call: bool, opnum: int, request_opnum: int, src: str,
                      request_dst: str, swapped: bool, frame: int) -> list[Finding]:
    """R4 from what was compared: interface and opnum the request's (`same_call`), addresses swapped."""
    out = []
    if not same_call:
        out.append(finding("rpc_response_mismatch", frame, "rpc.opnum", opnum, request_opnum,
                           f"response interface/opnum differ from the request in frame {request_frame}"))
    if not swapped:
        out.append(finding("rpc_addresses_not_swapped", frame, "ip.src", src, request_dst,
                           f"response addresses do not swap those of the request in frame {request_frame}"))
    return out


def _ip(addr: bytes) -> str:
    return ".".join(str(b) for b in addr)
