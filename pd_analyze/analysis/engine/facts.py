"""What the engine's loops read of one PNIO RPC PDU, whichever decoder made it.

A batch's PDUs come from the column decode (most of them) and from the per-frame dissector without
pairing (fragments to reassemble, cut or damaged frames, other link types, Write-Multiple, irregular
records): both become `Pdu` rows of the same shape, in frame order, so the pairing of calls and the
transactions see one stream. A request names what it asks for (`writes`: one `Write` per IOD write
block, None where the block is no PROFIdrive record; `read`: the channel a read asks on); an answer
what it says (`Answer`). Records are referred to, not copied: a column record by its index in the
batch's decoded records, a per-frame one by its parse.
"""

from __future__ import annotations

from typing import NamedTuple

from pd_analyze.model.rules import Finding
from pd_analyze.protocol.profidrive import Parsed

Key = tuple[int, int, int]  # a call: activity (two halves of its canonical bytes) and sequence number
# A channel (protocol.md 7.2): device, controller (IPv4 as integers), AR (two halves), API, slot, subslot, index
Channel = tuple[int, int, int, int, int, int, int, int]


class Carried(NamedTuple):
    """A column record that outlives its batch (its transaction still pending): its bytes, decoded again by
    the columns with the batch its transaction closes in."""

    data: bytes


Record = int | Carried | Parsed | None  # a column record of the batch (its index), its bytes, a parse, or none


class Head(NamedTuple):
    """A parameter request's or response's header, as the mirroring checks (Q2-Q5) read it."""

    ref: int
    ident: int
    do: int
    n: int
    first_error: bool  # the first block is an error block (a header-level error, protocol.md 3.3)
    blocks: int


class Write(NamedTuple):
    """One PROFIdrive record a write request carries (one per record of a Write-Multiple)."""

    channel: Channel
    record: Record
    head: tuple[int, int, int, int] | None  # ref, Request ID, DO, No. of parameters (None: cut before)
    malformed: bool  # the record or its PDU cannot be decoded whole (verdict malformed)
    vendor: tuple[int, ...] | None = None  # Response IDs answering a profile's own Request ID (5.5)


class Answer(NamedTuple):
    """What a response, fault or reject says."""

    fault: int  # the NCA status of a fault or reject, -1 for a response
    status: int  # PNIOStatus packed (ErrorCode << 24 ...); the write's: its block's when the NDR one is OK
    statuses: tuple[int, ...]  # per inner write of a Write-Multiple (empty otherwise)
    record: Record  # the PROFIdrive record of a read response
    head: Head | None
    complete: bool  # the record parsed whole
    # the Write of a PROFIdrive index this answer to a write names (a write cut before its header: the
    # transaction opens when its answer names the index, protocol.md 7.3 step 1)
    names: Write | None = None


class Pdu:
    """One PNIO RPC PDU, or a frame of one (a fragment: no `call` side), in frame order."""

    __slots__ = ("answer", "call", "col", "copy", "cut", "decide", "digest", "dst", "findings", "first", "first_ts",
                 "frame", "frames", "ifc", "key", "malformed", "odd", "opnum", "owner", "part", "ptype", "q7", "raw",
                 "read", "resent", "src", "ts", "whole", "writes")

    def __init__(self, frame: int, ts: int, ptype: int) -> None:
        self.frame, self.ts, self.ptype = frame, ts, ptype
        self.first, self.first_ts = frame, ts  # a request is timed at its first frame (protocol.md 7.6)
        self.frames: tuple[int, ...] = ()  # the fragments (IP, CL) it was reassembled from
        self.whole = True  # False: a frame that carries no complete PDU (a fragment, a dropped copy)
        self.key: Key = (0, 0, 0)
        self.src = self.dst = 0
        self.opnum = 0
        self.ifc: tuple[int, int] = (0, 0)
        self.decide = False  # PNIO only if its call or activity is (an interface that is not PNIO's)
        self.malformed = False
        self.odd = False  # decoded by the per-frame dissector
        self.findings: list[Finding] = []  # the frame's own (the dissector's, or made for a flagged frame)
        self.writes: list[Write | None] | None = None  # a write request's records (None: not a write)
        self.read: Channel | None = None  # a read request on a PROFIdrive index: its channel
        self.answer: Answer | None = None
        self.call = None  # set by the pairing: the call it opens, repeats or answers (calls.Call)
        self.copy = False  # a copy of a call's request, or a second answer (pairing)
        self.resent = False  # a copy of the request's own body: one of its call's copies (a retransmission)
        self.digest: tuple[int, int] = (0, 0)  # a request's body: CRC-32 and size
        self.raw = None  # per-frame rows: the dissector's FrameResult
        self.cut = False  # a write request cut before its first IOD header (protocol.md 7.3 step 1)
        self.col = -1  # column rows: the PDU's index in its batch's decoded columns
        self.part = 0  # the batch (part) it was decoded in
        self.owner = None  # the transaction it belongs to (machine)
        self.q7: list[Finding] | None = None  # Q7 of a read response, made when its channel's request is known
