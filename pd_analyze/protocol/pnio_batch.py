"""A batch of frames decoded as columns down to the IOD record: link, IPv4, UDP, CL-RPC, NDR, IOD header.

The per-frame dissector stays the reference; this is the same decode, applied to a whole batch with
numpy (the Layout declarations give every field's offset and width), for the frames whose shape is
ordinary. Each frame gets a route:

- ROUTE_SKIP: not analysed further, counted under `skip_reason` exactly as the per-frame dissector
  counts it (a frame without IPv4, a UDP datagram that is no DCE/RPC v4, a request to another DCE/RPC
  interface), and it earns no finding;
- ROUTE_FRAMES: the per-frame dissector must take it: IP fragments, malformed or truncated headers,
  other link types, CL fragments, faults and rejects, pings and other control PDUs with a PNIO
  interface, other operations, stubs or records cut short, Write-Multiple, authentication, ...;
- ROUTE_DECIDE: a plausible DCE/RPC v4 PDU other than a request whose interface is not a PNIO one: it
  is PNIO only if its call (activity + sequence number) is a PNIO call, or (pings, acks ...) its
  activity is known: the caller, who holds that state, decides (skip it, or give it to the frames path);
- ROUTE_PNIO: a PNIO RPC request (ptype 0, PNIO interface) or response (ptype 2, PNIO interface) whose
  stub decodes by the columns below without a structural problem.

`flag` marks PNIO frames on which a frame-local rule (R2, R5, R6, the serial note, R8, N1-N3, N5-N9,
H1-H5, H9, H10, H12-H14, profibus_index, P4 on the IOD fields) may report something: the caller has
those frames' findings made by the per-frame checks, so their text is the reference's. Rules that
need the paired request (R4, N4, H6-H8) are the caller's too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pd_analyze.capture.batches import FrameBatch
from pd_analyze.model.layout import Layout, be_halves
from pd_analyze.model.values import (
    API_PROFIDRIVE,
    ERROR_CODE_READ,
    ERROR_CODE_WRITE,
    ERROR_DECODE_PNIO,
    ERROR_DECODE_PNIORW,
    FLAG1_FRAG,
    INDEX_PD_DPV1,
    INDEX_WRITE_MULTIPLE,
    OP_READ_IMPLICIT,
    OP_WRITE,
    PNIORW_STATE_CONFLICT,
    PROFIDRIVE_INDICES,
    PTYPE_REQUEST,
    PTYPE_RESPONSE,
    RECORD_SERVICES,
)
from pd_analyze.protocol import link, link_batch, profidrive, rpc, rpc_batch
from pd_analyze.protocol import pnio as rec
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
BLOCK_LENGTH = rec.IOD_SIZE - 4  # H2: BlockLength counts the bytes after BlockType and itself
BLOCK_VERSION = (1, 0)  # H3


@dataclass(slots=True)
class FrameColumns:
    """One entry per frame of the batch."""

    route: np.ndarray  # int8, ROUTE_*
    skip_reason: np.ndarray  # int8 index into SKIP_REASONS (ROUTE_SKIP), -1 otherwise
    # The frame's IPv4 address pair as one key, min << 32 | max of the two addresses as big-endian
    # integers, for every frame with a readable IPv4 header (fragments included); 0 otherwise
    group: np.ndarray  # uint64


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
    status: np.ndarray  # uint32, responses: PNIOStatus as ErrorCode << 24 | ErrorDecode << 16 | Code1 << 8 | Code2
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
    frames: FrameColumns
    pdus: PduColumns


def decode(batch: FrameBatch, checker: Checker) -> DecodedBatch:
    """Every frame of the batch routed; the PNIO ones decoded as columns."""
    data = np.frombuffer(batch.buf, np.uint8)
    n = len(batch)
    route = np.full(n, ROUTE_FRAMES, np.int8)
    reason = np.full(n, -1, np.int8)
    dg = link_batch.datagrams(data, batch.linktype, batch.start, batch.caplen)
    skipped = dg.skip >= 0
    route[skipped], reason[skipped] = ROUTE_SKIP, _LINK_REASONS[dg.skip[skipped]]
    d = np.flatnonzero(dg.ordinary)
    plausible, hdr = rpc_batch.decode(data, dg.start[d], dg.length[d])
    route[d[~plausible]], reason[d[~plausible]] = ROUTE_SKIP, _NOT_RPC
    r = d[plausible]  # frames of a plausible CL-RPC header; hdr is theirs
    pnio = hdr.pnio
    request, response = hdr.ptype == PTYPE_REQUEST, hdr.ptype == PTYPE_RESPONSE
    route[r[~pnio & request]], reason[r[~pnio & request]] = ROUTE_SKIP, _NOT_PNIO
    route[r[~pnio & ~request]] = ROUTE_DECIDE  # PNIO only by its call or activity: the caller knows
    body_start = dg.start[r] + rpc.HEADER_SIZE
    present = dg.length[r] - rpc.HEADER_SIZE
    body_len = hdr.frag_len.astype(np.int64)
    record_service = np.isin(hdr.opnum, _RECORD_SERVICES)
    # R1, CL fragments, authentication, faults, rejects and control PDUs, other operations: per frame
    c = np.flatnonzero(pnio & (request | response) & (body_len <= present) & (hdr.flags1 & FLAG1_FRAG == 0)
                       & (hdr.auth == 0) & record_service)
    stubs = _stubs(data, body_start[c], body_len[c], response[c], hdr.little[c], hdr.opnum[c], checker)
    ok = stubs.pop("ok")
    route[r[c[ok]]] = ROUTE_PNIO
    frames = FrameColumns(route, reason, dg.group)
    # the PDU entries: PNIO and DECIDE frames, in frame order (r ascends)
    mine = np.flatnonzero(route[r] >= ROUTE_DECIDE)
    flag = (stubs.pop("flag") | rpc_batch.flags(_rows(hdr, c), present[c], record_service[c])) & ok
    stub_cols = {}
    for name, col in (*stubs.items(), ("flag", flag)):
        full = np.zeros(len(r), col.dtype)
        full[c] = col
        stub_cols[name] = full[mine]
    pos = r[mine]
    h = _rows(hdr, mine)
    pdus = PduColumns(
        pos=pos.astype(np.int64), src=dg.src[pos], dst=dg.dst[pos], sport=dg.sport[pos], dport=dg.dport[pos],
        ptype=h.ptype, flags1=h.flags1, little=h.little, act_hi=h.act_hi, act_lo=h.act_lo, if_hi=h.if_hi,
        if_lo=h.if_lo, seq=h.seq, opnum=h.opnum, body_start=body_start[mine],
        body_len=body_len[mine].astype(np.int32), **stub_cols)
    return DecodedBatch(frames, pdus)


def _rows(h: rpc_batch.Headers, rows: np.ndarray) -> rpc_batch.Headers:
    """The headers of some rows."""
    return rpc_batch.Headers(*(getattr(h, name)[rows] for name in rpc_batch.Headers.__slots__))


# The stub columns of PduColumns, with their dtypes
_STUB_COLUMNS = (("args_max", np.uint32), ("status", np.uint32), ("args_len", np.uint32), ("max_count", np.uint32),
                 ("has_block", np.bool_), ("block_type", np.uint16), ("iod_seq", np.uint16), ("ar_hi", np.uint64),
                 ("ar_lo", np.uint64), ("target_hi", np.uint64), ("target_lo", np.uint64), ("api", np.uint32),
                 ("slot", np.uint16), ("subslot", np.uint16), ("index", np.uint16), ("record_len", np.uint32),
                 ("block_status", np.uint32), ("rec_start", np.int64), ("rec_len", np.int32))


def _stubs(data: np.ndarray, at: np.ndarray, length: np.ndarray, response: np.ndarray, little: np.ndarray,
           opnum: np.ndarray, checker: Checker) -> dict[str, np.ndarray]:
    """pnio.parse_stub for stubs data[at[i] : at[i] + length[i]] of Read, Write and ReadImplicit PDUs.

    The PduColumns stub columns, `ok` (the stub decodes as an ordinary one) and `flag` (a rule of
    pnio_checks.ndr, pnio_checks.blocks or Checker.iod may report on it)."""
    f = _fields(data, at, length, response, little, opnum)
    write = opnum == OP_WRITE
    status = (f["ndr.status.code"].astype(np.uint32) << 24 | f["ndr.status.decode"].astype(np.uint32) << 16
              | f["ndr.status.code1"].astype(np.uint32) << 8 | f["ndr.status.code2"])
    block = length >= rec.NDR_SIZE + rec.IOD_SIZE
    # a read response without blocks is ordinary when it reports an error (ArgsLength 0, protocol.md 2.7)
    ok = block | ((length == rec.NDR_SIZE) & response & ~write & (status != 0))
    index = f["iod.index"]
    record_len = f["iod.record_len"].astype(np.int64)
    ok &= ~(block & write & (index == INDEX_WRITE_MULTIPLE))  # Write-Multiple: the per-frame path's
    carries = block & (write != response)  # write requests and read responses carry a record
    after = length - rec.NDR_SIZE - rec.IOD_SIZE  # bytes after the IOD header
    ok &= ~(carries & (record_len > after))  # a record cut short (record_truncated)
    trailing = block & (np.where(carries, after - record_len, after) > 0)
    with_record = carries & (~response | (status == 0))
    block_status = (f["iod.status.code"].astype(np.uint32) << 24 | f["iod.status.decode"].astype(np.uint32) << 16
                    | f["iod.status.code1"].astype(np.uint32) << 8 | f["iod.status.code2"])
    out = {"ok": ok, "flag": _flag(f, status, block_status, block, trailing, length, response, opnum, checker),
           "args_max": f["ndr.args_max"], "status": status, "args_len": f["ndr.args_len"],
           "max_count": f["ndr.max_count"], "has_block": block, "block_type": f["iod.block_type"],
           "iod_seq": f["iod.seq"], "ar_hi": f["iod.ar_uuid.hi"], "ar_lo": f["iod.ar_uuid.lo"],
           "target_hi": f["iod.target_ar_uuid.hi"], "target_lo": f["iod.target_ar_uuid.lo"], "api": f["iod.api"],
           "slot": f["iod.slot"], "subslot": f["iod.subslot"], "index": index, "record_len": f["iod.record_len"],
           "block_status": block_status,
           "rec_start": np.where(with_record, at + rec.NDR_SIZE + rec.IOD_SIZE, 0),
           "rec_len": np.where(with_record, record_len, 0)}
    return {name: out[name].astype(dtype, copy=False) for name, dtype in (("ok", np.bool_), ("flag", np.bool_),
                                                                          *_STUB_COLUMNS)}


def _flag(f: dict[str, np.ndarray], status: np.ndarray, block_status: np.ndarray, block: np.ndarray,
          trailing: np.ndarray, length: np.ndarray, response: np.ndarray, opnum: np.ndarray,
          checker: Checker) -> np.ndarray:
    """Stubs on which pnio_checks.ndr or pnio_checks.blocks (without the request) or Checker.iod may report."""
    request = ~response
    write = opnum == OP_WRITE
    read = ~write
    args_len = f["ndr.args_len"].astype(np.int64)
    record_len = f["iod.record_len"].astype(np.int64)
    code = f["ndr.status.code"]
    failed = status != 0
    flag = ((args_len != length - rec.NDR_SIZE)  # N1
            | (f["ndr.actual_count"] != f["ndr.args_len"]) | (f["ndr.offset"] != 0)  # N2
            | (request & (f["ndr.max_count"] != f["ndr.args_max"]))  # N3
            | (request & read & block & (f["ndr.args_max"] < rec.IOD_SIZE + record_len))  # N5
            # N6 (the form), N7 (the service's ErrorCode) as pnio_checks.pnio_status (ErrorCode 0 is not the
            # service's either, so N6's "ErrorCode 0 with other bytes set" is in the N7 term)
            | (response & failed & ((code != np.where(write, ERROR_CODE_WRITE, ERROR_CODE_READ))
                                    | ~np.isin(f["ndr.status.decode"], (ERROR_DECODE_PNIORW, ERROR_DECODE_PNIO))))
            | (response & read & failed & block & (f["ndr.status.code1"] != PNIORW_STATE_CONFLICT))  # N9
            | (response & write & block & (block_status != status)))  # N8
    expected = np.zeros(len(opnum), np.int64)
    for (op, is_response), block_type in rec.EXPECTED_BLOCK.items():
        expected[(opnum == op) & (response == is_response)] = block_type
    nil = (f["iod.ar_uuid.hi"] == 0) & (f["iod.ar_uuid.lo"] == 0)
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


def _fields(data: np.ndarray, at: np.ndarray, length: np.ndarray, response: np.ndarray, little: np.ndarray,
            opnum: np.ndarray) -> dict[str, np.ndarray]:
    """Every field of the NDR args and of the first IOD header, by registry name, with the layout
    pnio.parse_stub reads each stub with; 0 where a stub has no such field. 16-byte UUIDs come as `name.hi`
    and `name.lo`; the RWPadding as `iod.rw_pad` True where any of its bytes is set."""
    k = len(at)
    f: dict[str, np.ndarray] = {}
    ndr = length >= rec.NDR_SIZE
    for is_response, layouts in ((False, rec.NDR_REQ), (True, rec.NDR_RES)):
        for is_little, layout in layouts.items():
            _scatter(f, layout, data, at, np.flatnonzero(ndr & (response == is_response) & (little == is_little)), k)
    block = length >= rec.NDR_SIZE + rec.IOD_SIZE
    write = opnum == OP_WRITE
    iod_at = at + rec.NDR_SIZE
    read_request = np.flatnonzero(block & ~response & ~write)
    ar = rec.READ_REQ.columns(data, iod_at[read_request], ("iod.ar_uuid",))["iod.ar_uuid"]
    implicit = np.zeros(k, bool)
    implicit[read_request[~ar.any(axis=1)]] = True  # pnio.iod_layout: a NIL ARUUID reads implicitly
    for layout, rows in ((rec.WRITE_REQ, block & ~response & write), (rec.WRITE_RES, block & response & write),
                         (rec.READ_RES, block & response & ~write), (rec.READ_REQ_IMPLICIT, implicit),
                         (rec.READ_REQ, block & ~response & ~write & ~implicit)):
        _scatter(f, layout, data, iod_at, np.flatnonzero(rows), k)
    return f


def _scatter(f: dict[str, np.ndarray], layout: Layout, data: np.ndarray, at: np.ndarray, rows: np.ndarray,
             k: int) -> None:
    """The layout's fields at at[rows] into f's k-long columns (made on first sight)."""
    for name, col in layout.columns(data, at[rows]).items():
        if col.ndim == 1:
            parts: tuple[tuple[str, np.ndarray], ...] = ((name, col),)
        elif name == "iod.rw_pad":
            parts = ((name, col.any(axis=1)),)
        else:
            hi, lo = be_halves(col)
            parts = ((f"{name}.hi", hi), (f"{name}.lo", lo))
        for key, values in parts:
            if key not in f:
                f[key] = np.zeros(k, values.dtype)
            f[key][rows] = values
