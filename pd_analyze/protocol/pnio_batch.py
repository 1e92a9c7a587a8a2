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
from pd_analyze.protocol import link, rpc
from pd_analyze.protocol.profidrive_checks import Checker

ROUTE_SKIP, ROUTE_FRAMES, ROUTE_DECIDE, ROUTE_PNIO = 0, 1, 2, 3
# The skip reasons of the per-frame dissector, by code: FrameColumns.skip_reason indexes this tuple
SKIP_REASONS = (link.SKIP_NOT_IPV4, link.SKIP_LINKTYPE, link.SKIP_SHORT, link.SKIP_NOT_UDP, rpc.SKIP_NOT_RPC,
                rpc.SKIP_NOT_PNIO)


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
    raise NotImplementedError
