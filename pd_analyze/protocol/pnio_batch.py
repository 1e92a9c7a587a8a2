"""A batch of frames decoded as columns down to the IOD record: link, IPv4, UDP, CL-RPC, NDR, IOD header.

The per-frame dissector stays the reference; this is the same decode, applied to a whole batch with
numpy (the Layout declarations give every field's offset and width), for the frames whose shape is
ordinary. Each frame gets a route:

- ROUTE_SKIP: not analysed further, counted under `skip_reason` exactly as the per-frame dissector
  counts it (a frame without IPv4, a UDP datagram that is no DCE/RPC v4, a request to another DCE/RPC
  interface), and it earns no finding;
- ROUTE_FRAMES: the per-frame dissector must take it: IP fragments, malformed or truncated headers,
  other link types, CL fragments, faults and rejects without their status, pings and other control PDUs
  with a PNIO interface, other operations, stubs or records cut short, Write-Multiple, authentication, ...;
- ROUTE_DECIDE: a plausible DCE/RPC v4 PDU other than a request whose interface is not a PNIO one: it
  is PNIO only if its call (activity + sequence number) is a PNIO call, or (pings, acks ...) its
  activity is known: the caller, who holds that state, decides (skip it, or give it to the frames path);
- ROUTE_PNIO: a PNIO RPC request (ptype 0, PNIO interface) or response (ptype 2, PNIO interface) whose
  stub decodes by the columns below without a structural problem; or a fault or reject (ptype 3, 6) with
  a PNIO interface and its status (always flagged: the per-frame dissector reports every fault).

`flag` marks PNIO frames on which a frame-local rule (R2, R5, R6, the serial note, R8, N1-N3, N5-N9,
H1-H5, H9, H10, H12-H14, profibus_index, P4 on the IOD fields) may report something: the caller has
those frames' findings made by the per-frame checks, so their text is the reference's. Rules that
need the paired request (R4, N4, H6-H8) are the caller's too.

Each layer's columnar decode lives beside its parser: link_batch (link, IPv4, UDP), rpc_batch (CL-RPC
header, rpc.check_header), this module the NDR args and the IOD header (pnio.parse_stub, pnio_checks);
all of them read fields with Layout.columns / Layout.records and the parsers' declarations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pd_analyze.capture.batches import FrameBatch
from pd_analyze.model.layout import Layout, be_halves, fields_by_order
from pd_analyze.model.values import (
    API_PROFIDRIVE,
    ERROR_CODE_READ,
    ERROR_CODE_WRITE,
    ERROR_DECODE_PNIO,
    ERROR_DECODE_PNIORW,
    FLAG1_FRAG,
    INDEX_PD_DPV1,
    INDEX_WRITE_MULTIPLE,
    LINKTYPE_ETHERNET,
    OP_READ_IMPLICIT,
    OP_WRITE,
    PNIORW_STATE_CONFLICT,
    PROFIDRIVE_INDICES,
    PTYPE_FAULT,
    PTYPE_REJECT,
    PTYPE_REQUEST,
    PTYPE_RESPONSE,
    RECORD_SERVICES,
)
from pd_analyze.protocol import link, link_batch, profidrive, rpc, rpc_batch
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol.pnio_checks import BLOCK_LENGTH
from pd_analyze.protocol.profidrive_checks import Checker

ROUTE_SKIP, ROUTE_FRAMES, ROUTE_DECIDE, ROUTE_PNIO = 0, 1, 2, 3
# The skip reasons of the per-frame dissector, by code: FrameColumns.skip_reason indexes this tuple
SKIP_REASONS = (link.SKIP_NOT_IPV4, link.SKIP_LINKTYPE, link.SKIP_SHORT, link.SKIP_NOT_UDP, rpc.SKIP_NOT_RPC,
                rpc.SKIP_NOT_PNIO)
_LINK_REASONS = np.array([SKIP_REASONS.index(reason) for reason in link_batch.SKIPS], np.int8)
_NOT_RPC, _NOT_PNIO = SKIP_REASONS.index(rpc.SKIP_NOT_RPC), SKIP_REASONS.index(rpc.SKIP_NOT_PNIO)
_RECORD_SERVICES = np.array(sorted(RECORD_SERVICES))
_PD_INDICES = np.array(sorted(PROFIDRIVE_INDICES))
_IOD_LIMITS = ("iod.api", "iod.slot", "iod.subslot", "iod.index")  # Checker.iod's keys, also the field names
PD_HEADER = profidrive.HEADER.size  # H13's least PROFIdrive record length
BLOCK_VERSION = (1, 0)  # H3


@dataclass(slots=True)
class FrameColumns:
    """One entry per frame of the batch."""

    route: np.ndarray  # int8, ROUTE_*
    skip_reason: np.ndarray  # int8 index into SKIP_REASONS (ROUTE_SKIP), -1 otherwise
    # The frame's IPv4 address pair as one key, min << 32 | max of the two addresses as big-endian
    # integers, for every frame with a readable IPv4 header (fragments included); 0 otherwise
    group: np.ndarray  # uint64
    # The activity UUID (canonical halves) of a frame with a plausible DCE/RPC v4 header where its UDP
    # payload would start, whatever its route; 0 otherwise (a call's frames may cross address pairs)
    act_hi: np.ndarray  # uint64
    act_lo: np.ndarray  # uint64


@dataclass(slots=True)
class PduColumns:
    """One entry per ROUTE_PNIO or ROUTE_DECIDE frame, in frame order (`pos`: its index in the batch).

    Integers are as the per-frame decode reads them (DREP order for the RPC header and NDR args,
    big-endian in the IOD header). UUIDs are two uint64 of their canonical (big-endian) 16 bytes.
    ROUTE_DECIDE entries fill only the RPC header columns; the rest is 0.
    """

    pos: np.ndarray  # int64
    src: np.ndarray  # uint32 IPv4 source, big-endian integer
    dst: np.ndarray  # uint32
    sport: np.ndarray  # uint16
    dport: np.ndarray  # uint16
    # CL-RPC header (protocol.md 2.1)
    ptype: np.ndarray  # uint8
    flags1: np.ndarray  # uint8
    little: np.ndarray  # bool: DREP integer order little-endian
    act_hi: np.ndarray  # uint64, activity UUID (canonical) bytes 0-7
    act_lo: np.ndarray  # uint64, bytes 8-15
    if_hi: np.ndarray  # uint64, interface UUID (canonical)
    if_lo: np.ndarray  # uint64
    seq: np.ndarray  # uint32
    opnum: np.ndarray  # uint16 (its own: a response is decoded with it; the caller checks the request's)
    body_start: np.ndarray  # int64: offset of the RPC body (after the 80-byte header) in buf
    body_len: np.ndarray  # int32: rpc.frag_len (the body; bytes beyond it are R2's, and flagged)
    # NDR args header (protocol.md 2.5)
    args_max: np.ndarray  # uint32, requests (0 for responses)
    status: np.ndarray  # uint32, responses: PNIOStatus as ErrorCode << 24 | ErrorDecode << 16 | Code1 << 8 | Code2;
    # faults and rejects (ptype 3, 6): their NCA status
    args_len: np.ndarray  # uint32
    max_count: np.ndarray  # uint32
    # First IOD header block (protocol.md 2.6); has_block False: a response of the NDR header only
    has_block: np.ndarray  # bool
    block_type: np.ndarray  # uint16
    iod_seq: np.ndarray  # uint16
    ar_hi: np.ndarray  # uint64, ARUUID
    ar_lo: np.ndarray  # uint64
    target_hi: np.ndarray  # uint64, TargetARUUID of an implicit read request (0 otherwise)
    target_lo: np.ndarray  # uint64
    api: np.ndarray  # uint32
    slot: np.ndarray  # uint16
    subslot: np.ndarray  # uint16
    index: np.ndarray  # uint16
    record_len: np.ndarray  # uint32, RecordDataLength
    block_status: np.ndarray  # uint32, write response: its PNIOStatus (as `status`); 0 otherwise
    # The record a write request or read response carries, complete: buf[rec_start : rec_start + rec_len]
    rec_start: np.ndarray  # int64 (0 when none)
    rec_len: np.ndarray  # int32 (0 when none)
    flag: np.ndarray  # bool: a frame-local rule may report something (module docstring)


@dataclass(slots=True)
class DecodedBatch:
    """What `decode` makes of a batch."""

    frames: FrameColumns
    pdus: PduColumns


def decode(batch: FrameBatch, checker: Checker) -> DecodedBatch:
    """Every frame of the batch routed; the PNIO ones decoded as columns."""
    data = np.frombuffer(batch.buf, np.uint8)
    route = np.full(len(batch), ROUTE_FRAMES, np.int8)
    reason = np.full(len(batch), -1, np.int8)
    dg = link_batch.datagrams(data, batch.linktype, batch.start, batch.caplen)
    skipped = dg.skip >= 0
    route[skipped], reason[skipped] = ROUTE_SKIP, _LINK_REASONS[dg.skip[skipped]]
    # From here on one row per whole UDP datagram, every layer over all rows with masks (cheaper than subsets)
    d = np.flatnonzero(dg.ordinary)
    at, length = dg.start[d], dg.length[d]
    hdr = rpc_batch.decode(data, at, length)
    request, response = hdr.ptype == PTYPE_REQUEST, hdr.ptype == PTYPE_RESPONSE
    pnio = hdr.plausible & hdr.pnio
    other = hdr.plausible & ~hdr.pnio  # a request: not PNIO; anything else: PNIO only by its call or activity
    body_len = hdr.frag_len.astype(np.int64)
    present = length - rpc.HEADER_SIZE
    record_service = np.isin(hdr.opnum, _RECORD_SERVICES)
    # R1, CL fragments, authentication, faults, rejects and control PDUs, other operations: per frame
    candidate = (pnio & (request | response) & (body_len <= present) & (hdr.flags1 & FLAG1_FRAG == 0)
                 & (hdr.auth == 0) & record_service)
    stubs = _stubs(data, at + rpc.HEADER_SIZE, body_len, candidate, response, hdr.little, hdr.opnum, checker)
    # a fault or reject answering a call with its status (dissector._fault): always reported (rpc_fault)
    fault = (pnio & ((hdr.ptype == PTYPE_FAULT) | (hdr.ptype == PTYPE_REJECT)) & (body_len >= 4)
             & (body_len <= present) & (hdr.flags1 & FLAG1_FRAG == 0) & (hdr.auth == 0))
    raw = rpc.FAULT_LE.records(data, at + rpc.HEADER_SIZE, fault)
    status = fields_by_order(rpc.FAULT_LE, rpc.FAULT_BE, raw, hdr.little, ("rpc.fault_status",))["rpc.fault_status"]
    stubs["status"] = np.where(fault, status, stubs["status"]).astype(np.uint32)
    ordinary = stubs.pop("ok") | fault
    stubs["flag"] = ordinary & (stubs["flag"] | fault | rpc_batch.flags(hdr, present, record_service))
    rows = np.select([~hdr.plausible, other & request, other, ordinary], [ROUTE_SKIP, ROUTE_SKIP, ROUTE_DECIDE,
                                                                          ROUTE_PNIO], ROUTE_FRAMES)
    route[d] = rows
    reason[d] = np.select([~hdr.plausible, other & request], [_NOT_RPC, _NOT_PNIO], -1)
    # the PDU entries: PNIO and DECIDE frames, in frame order (d ascends); a DECIDE row was no candidate, so
    # its stub columns are 0
    mine = rows >= ROUTE_DECIDE
    every = bool(mine.all())

    def take(column: np.ndarray) -> np.ndarray:
        return column if every else column[mine]

    pdus = PduColumns(
        pos=take(d), src=take(dg.src[d]), dst=take(dg.dst[d]), sport=take(dg.sport[d]), dport=take(dg.dport[d]),
        ptype=take(hdr.ptype), flags1=take(hdr.flags1), little=take(hdr.little), act_hi=take(hdr.act_hi),
        act_lo=take(hdr.act_lo), if_hi=take(hdr.if_hi), if_lo=take(hdr.if_lo), seq=take(hdr.seq),
        opnum=take(hdr.opnum), body_start=take(at) + rpc.HEADER_SIZE, body_len=take(body_len).astype(np.int32),
        **{name: take(column) for name, column in stubs.items()})
    act_hi, act_lo = np.zeros(len(batch), np.uint64), np.zeros(len(batch), np.uint64)
    act_hi[d] = np.where(hdr.plausible, hdr.act_hi, 0)
    act_lo[d] = np.where(hdr.plausible, hdr.act_lo, 0)
    # frames for the per-frame path (cut, fragmented...) whose RPC header is there all the same
    end = batch.start.astype(np.int64) + batch.caplen
    peek = np.flatnonzero(dg.frames & (dg.group != 0) & (batch.linktype == LINKTYPE_ETHERNET)
                          & (dg.start + rpc.HEADER_SIZE <= end))
    if len(peek):
        seen = rpc_batch.decode(data, dg.start[peek], end[peek] - dg.start[peek])
        act_hi[peek] = np.where(seen.plausible, seen.act_hi, 0)
        act_lo[peek] = np.where(seen.plausible, seen.act_lo, 0)
    return DecodedBatch(FrameColumns(route, reason, dg.group, act_hi, act_lo), pdus)


# The stub columns of PduColumns, with their dtypes
_STUB_COLUMNS = (("args_max", np.uint32), ("status", np.uint32), ("args_len", np.uint32), ("max_count", np.uint32),
                 ("has_block", np.bool_), ("block_type", np.uint16), ("iod_seq", np.uint16), ("ar_hi", np.uint64),
                 ("ar_lo", np.uint64), ("target_hi", np.uint64), ("target_lo", np.uint64), ("api", np.uint32),
                 ("slot", np.uint16), ("subslot", np.uint16), ("index", np.uint16), ("record_len", np.uint32),
                 ("block_status", np.uint32), ("rec_start", np.int64), ("rec_len", np.int32))
# Fields declared alike (name, offset, code) in the layouts they are read from together, read with the first
_NDR_TAIL = ("ndr.args_len", "ndr.max_count", "ndr.offset", "ndr.actual_count")
_IOD_COMMON = rec.WRITE_REQ.names[:rec.B_RECLEN + 1]
_IOD_LAYOUTS = (rec.WRITE_REQ, rec.WRITE_RES, rec.READ_RES, rec.READ_REQ_IMPLICIT, rec.READ_REQ)
_ADD_VALS = ("iod.add_val1", "iod.add_val2")
_IOD_STATUS = ("iod.status.code", "iod.status.decode", "iod.status.code1", "iod.status.code2")
_NDR_STATUS = ("ndr.status.code", "ndr.status.decode", "ndr.status.code1", "ndr.status.code2")


def _declared_alike(layouts: tuple[Layout, ...], names: tuple[str, ...]) -> bool:
    """The named fields sit at the same offsets with the same codes and byte order in every layout."""
    return all(len({(lay.offsets[lay.index(name)], lay.codes[lay.index(name)], lay.order) for lay in layouts}) == 1
               for name in names)


assert _declared_alike((rec.NDR_REQ[True], rec.NDR_RES[True]), _NDR_TAIL)
assert _declared_alike((rec.NDR_REQ[False], rec.NDR_RES[False]), _NDR_TAIL)
assert _declared_alike(_IOD_LAYOUTS, _IOD_COMMON)
assert _declared_alike((rec.WRITE_RES, rec.READ_RES), _ADD_VALS)
assert len({layout.size for layout in _IOD_LAYOUTS}) == 1


def _padding_words() -> tuple[np.dtype, tuple[tuple[int, ...], ...]]:
    """H4's RWPadding of the five IOD headers as bit masks over the big-endian 8-byte words from the first byte
    any of them pads (they all pad up to the end): testing words is several times faster than testing bytes.
    The numpy record type of those words in a raw header, and each layout's masks (in _IOD_LAYOUTS order)."""
    spans = [(lay.offsets[lay.index("iod.rw_pad")], lay.sizes[lay.index("iod.rw_pad")]) for lay in _IOD_LAYOUTS]
    lo = min(off for off, _ in spans)
    words = (rec.IOD_SIZE - lo) // 8
    assert lo + 8 * words == rec.IOD_SIZE == max(off + size for off, size in spans)
    rtype = np.dtype({"names": [f"w{w}" for w in range(words)], "formats": [">u8"] * words,
                      "offsets": [lo + 8 * w for w in range(words)], "itemsize": rec.IOD_SIZE})
    masks = tuple(tuple(sum(0xFF << 8 * (7 - b) for b in range(8) if off <= lo + 8 * w + b < off + size)
                        for w in range(words)) for off, size in spans)
    return rtype, masks


_PAD_WORDS, _PAD_MASKS = _padding_words()


def _stubs(data: np.ndarray, at: np.ndarray, length: np.ndarray, candidate: np.ndarray, response: np.ndarray,
           little: np.ndarray, opnum: np.ndarray, checker: Checker) -> dict[str, np.ndarray]:
    """pnio.parse_stub for the stubs data[at[i] : at[i] + length[i]] of the `candidate` rows (Read, Write and
    ReadImplicit PDUs whose body is present); other rows are not read.

    The PduColumns stub columns (0 outside the candidates), `ok` (the stub decodes as an ordinary one) and
    `flag` (a rule of pnio_checks.ndr, pnio_checks.blocks or Checker.iod may report on it)."""
    request = ~response
    write = opnum == OP_WRITE
    ndr = candidate & (length >= rec.NDR_SIZE)
    block = candidate & (length >= rec.NDR_SIZE + rec.IOD_SIZE)
    # the NDR args (the request's or the response's, in DREP order)
    raw = rec.NDR_REQ[False].records(data, at, ndr)
    f = fields_by_order(rec.NDR_REQ[True], rec.NDR_REQ[False], raw, little, ("ndr.args_max", *_NDR_TAIL))
    f.update(fields_by_order(rec.NDR_RES[True], rec.NDR_RES[False], raw, little, _NDR_STATUS))
    status = np.where(response, _packed(f, _NDR_STATUS), 0).astype(np.uint32)
    args_max = np.where(request, f["ndr.args_max"], 0)
    # the first IOD header: the fields all five declare alike, then each one's own
    raw = rec.WRITE_REQ.records(data, at + rec.NDR_SIZE, block)
    f.update(rec.WRITE_REQ.fields(raw, _IOD_COMMON))
    ar_hi, ar_lo = be_halves(f["iod.ar_uuid"])
    nil = (ar_hi == 0) & (ar_lo == 0)
    read_request = block & request & ~write
    kinds = (block & request & write, block & response & write, block & response & ~write, read_request & nil,
             read_request & ~nil)  # as pnio.iod_layout chooses, in _IOD_LAYOUTS order
    words = raw.view(_PAD_WORDS)
    words = [words[name].astype(np.uint64) for name in _PAD_WORDS.names]
    rw_pad = np.zeros(len(at), bool)
    for rows, masks in zip(kinds, _PAD_MASKS, strict=True):
        set_bits = np.zeros(len(at), np.uint64)
        for word, mask in zip(words, masks, strict=True):
            if mask:
                set_bits |= word if mask == (1 << 64) - 1 else word & np.uint64(mask)
        rw_pad |= rows & (set_bits != 0)
    f["iod.rw_pad"] = rw_pad
    f.update(rec.WRITE_RES.fields(raw, _ADD_VALS))  # 0 where not read; H12 asks them of responses only
    wres, implicit = kinds[1], kinds[3]
    block_status = np.where(wres, _packed(rec.WRITE_RES.fields(raw, _IOD_STATUS), _IOD_STATUS), 0).astype(np.uint32)
    target_hi, target_lo = be_halves(rec.READ_REQ_IMPLICIT.fields(raw, ("iod.target_ar_uuid",))["iod.target_ar_uuid"])
    index = f["iod.index"]
    record_len = f["iod.record_len"].astype(np.int64)
    # a read response without blocks is ordinary when it reports an error (ArgsLength 0, protocol.md 2.7)
    ok = block | (ndr & (length == rec.NDR_SIZE) & response & ~write & (status != 0))
    ok &= ~(block & write & (index == INDEX_WRITE_MULTIPLE))  # Write-Multiple: the per-frame path's
    carries = kinds[0] | kinds[2]  # write requests and read responses carry a record
    after = length - rec.NDR_SIZE - rec.IOD_SIZE  # bytes after the IOD header
    ok &= ~(carries & (record_len > after))  # a record cut short (record_truncated)
    # a wrong BlockType (H1) or BlockLength (H2) makes the transaction malformed (protocol.md 7.4 rule 1): the
    # per-frame path's, which marks the PDU so (pnio_checks.header_undecodable)
    expected = _expected_block(opnum, response)
    ok &= ~(block & ((f["iod.block_type"] != expected) | (f["iod.block_length"] != BLOCK_LENGTH)))
    trailing = block & (np.where(carries, after - record_len, after) > 0)
    with_record = carries & (request | (status == 0))
    flag = _flag(f, status, block_status, ndr, block, nil, trailing, length, response, opnum, checker)
    out = {"ok": ok, "flag": flag, "args_max": args_max, "status": status, "args_len": f["ndr.args_len"],
           "max_count": f["ndr.max_count"], "has_block": block, "block_type": f["iod.block_type"],
           "iod_seq": f["iod.seq"], "ar_hi": ar_hi, "ar_lo": ar_lo, "target_hi": np.where(implicit, target_hi, 0),
           "target_lo": np.where(implicit, target_lo, 0), "api": f["iod.api"], "slot": f["iod.slot"],
           "subslot": f["iod.subslot"], "index": index, "record_len": f["iod.record_len"],
           "block_status": block_status, "rec_start": np.where(with_record, at + rec.NDR_SIZE + rec.IOD_SIZE, 0),
           "rec_len": np.where(with_record, record_len, 0)}
    return {name: out[name].astype(dtype, copy=False) for name, dtype in (("ok", np.bool_), ("flag", np.bool_),
                                                                          *_STUB_COLUMNS)}


def _expected_block(opnum: np.ndarray, response: np.ndarray) -> np.ndarray:
    """The BlockType each PDU's service and direction asks for (H1; 0 where none)."""
    expected = np.zeros(len(opnum), np.int64)
    for (op, is_response), block_type in rec.EXPECTED_BLOCK.items():
        expected[(opnum == op) & (response == is_response)] = block_type
    return expected


def _packed(f: dict[str, np.ndarray], names: tuple[str, ...]) -> np.ndarray:
    """A PNIOStatus from its four byte fields: ErrorCode << 24 | ErrorDecode << 16 | ErrorCode1 << 8 | ErrorCode2."""
    code, decode, code1, code2 = (f[name].astype(np.uint32) for name in names)
    return code << np.uint32(24) | decode << np.uint32(16) | code1 << np.uint32(8) | code2


def _flag(f: dict[str, np.ndarray], status: np.ndarray, block_status: np.ndarray, ndr: np.ndarray,
          block: np.ndarray, nil: np.ndarray, trailing: np.ndarray, length: np.ndarray, response: np.ndarray,
          opnum: np.ndarray, checker: Checker) -> np.ndarray:
    """Stubs on which pnio_checks.ndr or pnio_checks.blocks (without the request) or Checker.iod may report."""
    request = ~response
    write = opnum == OP_WRITE
    read = ~write
    record_len = f["iod.record_len"].astype(np.int64)
    code = f["ndr.status.code"]
    failed = status != 0
    flag = ndr & ((f["ndr.args_len"] != length - rec.NDR_SIZE)  # N1
                  | (f["ndr.actual_count"] != f["ndr.args_len"]) | (f["ndr.offset"] != 0)  # N2
                  | (request & (f["ndr.max_count"] != f["ndr.args_max"])))  # N3
    flag |= block & request & read & (f["ndr.args_max"] < rec.IOD_SIZE + record_len)  # N5
    # N6 (the form), N7 (the service's ErrorCode) as pnio_checks.pnio_status (ErrorCode 0 is not the service's
    # either, so N6's "ErrorCode 0 with other bytes set" is in the N7 term)
    flag |= failed & ((code != np.where(write, ERROR_CODE_WRITE, ERROR_CODE_READ))
                      | ~np.isin(f["ndr.status.decode"], (ERROR_DECODE_PNIORW, ERROR_DECODE_PNIO)))
    flag |= block & response & read & failed & (f["ndr.status.code1"] != PNIORW_STATE_CONFLICT)  # N9
    flag |= block & response & write & (block_status != status)  # N8
    expected = _expected_block(opnum, response)
    flag |= block & ((f["iod.block_type"] != expected) | (f["iod.block_length"] != BLOCK_LENGTH)  # H1, H2
                     | (f["iod.version_high"] != BLOCK_VERSION[0]) | (f["iod.version_low"] != BLOCK_VERSION[1])  # H3
                     | (f["iod.pad"] != 0) | f["iod.rw_pad"]  # H4
                     | (response & ((f["iod.add_val1"] != 0) | (f["iod.add_val2"] != 0)))  # H12
                     | (request & (nil != (opnum == OP_READ_IMPLICIT))))  # H9: NIL for ReadImplicit only
    flag |= trailing  # H5's trailing_stub_bytes
    index = f["iod.index"]
    pd = block & np.isin(index, _PD_INDICES)
    max_record = checker.record.max_length
    flag |= pd & request & ((index == INDEX_PD_DPV1) | (f["iod.api"] != API_PROFIDRIVE)  # profibus_index, H10
                            | (write & ((record_len < PD_HEADER) | (record_len > max_record)))  # H13
                            | (read & (record_len < max_record)))  # H14
    flag |= pd & response & read & (record_len < PD_HEADER)  # H13 of a read response
    flag |= pd & request & _outside_limits(f, checker)  # P4 on the IOD fields
    return flag


def _outside_limits(f: dict[str, np.ndarray], checker: Checker) -> np.ndarray:
    """Checker.iod: a value of API, slot, subslot or index outside a limit of the generic or vendor profile."""
    out = np.zeros(len(f["iod.index"]), bool)
    for key in _IOD_LIMITS:
        values = f[key].astype(np.int64)
        for lim in checker.limits(key):
            inside = np.zeros(len(values), bool)
            for lo, hi in lim.ranges:
                inside |= (values >= lo) & (values <= hi)
            out |= ~inside
    return out
