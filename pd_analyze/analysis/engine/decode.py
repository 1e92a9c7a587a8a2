"""A batch of frames decoded into the engine's PDU rows, in frame order.

The column decode (protocol.pnio_batch, protocol.profidrive_batch) takes the ordinary frames; what it
cannot decode (IP and CL fragments to reassemble, cut or damaged frames, other link types, Write-Multiple,
an irregular record, a PDU whose interface is not PNIO's) is decoded by the per-frame dissector without
pairing, and both give `facts.Pdu` rows of one shape. Decoding decides nothing about calls or
transactions: no frame changes path because of another one.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from pd_analyze.analysis.engine.facts import Answer, Head, Pdu, Write
from pd_analyze.analysis.engine.view import KIND_READ, KIND_WRITE, BatchView
from pd_analyze.capture.batches import FrameBatch
from pd_analyze.capture.raw import RawFrame
from pd_analyze.model.capped import IP_FRAGMENT_TIMES, CappedTable
from pd_analyze.model.rules import Finding
from pd_analyze.model.values import (
    INDEX_PD_DPV1,
    INDEX_WRITE_MULTIPLE,
    OP_WRITE,
    PROFIDRIVE_INDICES,
    PTYPE_FAULT,
    PTYPE_REJECT,
    PTYPE_REQUEST,
    PTYPE_RESPONSE,
)
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol.dissector import Dissector
from pd_analyze.protocol.frames import Accounting, FrameResult
from pd_analyze.protocol.pnio import Status
from pd_analyze.protocol.pnio_batch import ROUTE_DECIDE, ROUTE_FRAMES, ROUTE_PNIO, ROUTE_SKIP, SKIP_REASONS
from pd_analyze.protocol.profidrive import Parsed
from pd_analyze.protocol.profiles import VendorRequest


def uuid_int(raw: bytes) -> tuple[int, int]:
    """A UUID's canonical 16 bytes as the two halves the columns hold."""
    return int.from_bytes(raw[:8], "big"), int.from_bytes(raw[8:16], "big")


def ip_int(raw: bytes) -> int:
    return int.from_bytes(raw, "big")


def packed(status: Status | None) -> int:
    """A PNIOStatus as the columns pack it (0: none, or OK)."""
    if status is None:
        return 0
    return status.code << 24 | status.decode << 16 | status.code1 << 8 | status.code2


def column_rows(view: BatchView) -> tuple[np.ndarray, np.ndarray]:
    """The PNIO PDUs the columns decode (indices into view.p, frame order): every ROUTE_PNIO one but for an
    irregular record (the per-frame parse's); and the positions in the batch of the frames the per-frame
    dissector decodes: those the columns route to it, the DECIDE ones, and the PNIO ones taken back."""
    p = view.p
    f = view.decoded.frames
    pnio = view.pnio.copy()
    sel = np.flatnonzero(view.rec_of >= 0)
    r = view.records.records
    odd_record = ~r.regular[view.rec_of[sel]] | ((p.index[sel] == INDEX_PD_DPV1) & ~r.plausible[view.rec_of[sel]])
    pnio[sel[odd_record]] = False
    take = (f.route == ROUTE_FRAMES) | (f.route == ROUTE_DECIDE)
    take[p.pos[view.pnio & ~pnio]] = True
    return np.flatnonzero(pnio), np.flatnonzero(take)


@dataclass(slots=True)
class Decoded:
    """One batch (or part of one) as the engine reads it."""

    batch: FrameBatch
    view: BatchView
    rows: np.ndarray  # int64: the PDUs the columns decoded (indices into view.p), in frame order
    odd: np.ndarray  # int64: positions in the batch of the frames the per-frame dissector decodes
    accounting: Accounting = field(default_factory=Accounting)  # the columns' share of the frames
    odd_rows: list[Pdu] = field(default_factory=list)  # the dissector's rows of those frames, in frame order
    # findings the dissector made at column rows: a response that found its request's fragment set
    # unfinished (rpc_fragments.drop_call), by PDU index
    dropped: dict[int, list[Finding]] = field(default_factory=dict)


class Decoder:
    """The per-frame dissector without pairing, for the frames the columns cannot decode, and what it must
    remember across batches (its reassembly state, the times of fragments)."""

    def __init__(self, dissector: Dissector) -> None:
        assert not dissector.pairing
        self.d = dissector
        self._ns: CappedTable[int, int] = CappedTable(IP_FRAGMENT_TIMES)  # frame -> time of frames it decoded

    @property
    def accounting(self) -> Accounting:
        return self.d.accounting

    def parts(self, batch: FrameBatch, views: list[tuple[FrameBatch, BatchView]] | None = None) -> Iterator[Decoded]:
        """The batch decoded, in consecutive parts when its records declare very many parameters (memory).
        `views`: the batch's `BatchView.parts` made elsewhere (the column decode needs no state across
        batches: another process may make it), or None."""
        for part, view in views if views is not None else BatchView.parts(batch, self.d.checker):
            yield self._decode(part, view)

    def decode(self, batch: FrameBatch, view: BatchView) -> Decoded:
        """One part of `BatchView.parts` (the caller reads its columns before its odd frames are dissected)."""
        return self._decode(batch, view)

    def _decode(self, batch: FrameBatch, view: BatchView) -> Decoded:
        f = view.decoded.frames
        out = Decoded(batch, view, np.empty(0, np.int64), np.empty(0, np.int64))
        acc = out.accounting
        acc.read = len(batch)
        counts = np.bincount(f.skip_reason[f.route == ROUTE_SKIP].astype(np.int64), minlength=len(SKIP_REASONS))
        for code, count in enumerate(counts.tolist()):
            if count:
                acc.skipped[SKIP_REASONS[code]] += count
        out.rows, out.odd = column_rows(view)
        acc.decoded = len(out.rows)
        acc.read -= len(out.odd)  # the dissector counts them
        self._odd_rows(out)
        return out

    def _odd_rows(self, dec: Decoded) -> None:
        """The dissector's rows of the part's odd frames, in frame order; between them, the answers the
        columns decoded tell it (in frame order too) that their calls were answered, so an unfinished
        fragment set of such a call's request is reported at the answer, as the dissector would."""
        batch, view, p = dec.batch, dec.view, dec.view.p
        answers = dec.rows[(p.ptype[dec.rows] == PTYPE_RESPONSE) | (p.ptype[dec.rows] == PTYPE_FAULT)
                           | (p.ptype[dec.rows] == PTYPE_REJECT)]
        answer_frames = view.frame_no[answers]
        frags = self.d.frags
        k = 0
        out = dec.odd_rows
        for pos in dec.odd.tolist():
            number = int(batch.number[pos])
            if frags.pending_calls():
                while k < len(answers) and answer_frames[k] < number:
                    self._drop(dec, int(answers[k]))
                    k += 1
            else:
                k = int(np.searchsorted(answer_frames, number))
            out += self.frame_rows(batch, pos)
        if frags.pending_calls():
            for i in answers[k:].tolist():
                self._drop(dec, int(i))

    def _drop(self, dec: Decoded, i: int) -> None:
        p = dec.view.p
        found: list[Finding] = []
        key = (int(p.act_hi[i]).to_bytes(8, "big") + int(p.act_lo[i]).to_bytes(8, "big"), int(p.seq[i]))
        self.d.frags.drop_call(key, int(dec.view.frame_no[i]), found)
        if found:
            dec.dropped[i] = found

    # --- frames by the dissector ---------------------------------------------------------------
    def frame_rows(self, batch: FrameBatch, pos: int) -> list[Pdu]:
        """The rows of frame `pos` of the batch, decoded by the dissector (called in frame order)."""
        frame = batch.raw_frame(pos)
        ns = int(batch.ns[pos])
        self._ns.remember(frame.number, ns)
        return [self.row(res, ns if res.frame == frame.number else self._ns.get(res.frame, ns))
                for res in self.d.feed(frame)]

    def feed_raw(self, frame: RawFrame, ns: int) -> list[Pdu]:
        """A frame given alone (not in a batch): its rows."""
        self._ns.remember(frame.number, ns)
        return [self.row(res, ns) for res in self.d.feed(frame)]

    def row(self, res: FrameResult, ns: int) -> Pdu:
        """The dissector's result of a frame as the engine's row."""
        row = Pdu(res.frame, ns, res.ptype)
        row.odd = True
        row.raw = res
        row.findings = res.findings
        row.decide = res.decide
        row.src, row.dst = ip_int(res.src_ip), ip_int(res.dst_ip)
        if res.key is not None:
            hi, lo = uuid_int(res.key[0])
            row.key = (hi, lo, res.key[1])
        pdu = res.pdu
        if pdu is None or pdu.unpaired:
            row.whole = False
            return row
        row.opnum = pdu.opnum
        row.ifc = uuid_int(pdu.interface) if pdu.interface else (0, 0)
        row.malformed = pdu.malformed
        row.digest = pdu.digest
        if pdu.fragments:
            row.frames = pdu.fragments
            row.first = pdu.fragments[0]
            times = [self._ns.get(n) for n in pdu.fragments]
            row.first_ts = min((t for t in times if t is not None), default=ns)
        if pdu.ptype == PTYPE_REQUEST:
            _request_facts(row, pdu.stub, pdu.malformed)
        elif pdu.ptype in (PTYPE_FAULT, PTYPE_REJECT):
            row.answer = Answer(pdu.fault_status or 0, 0, (), None, None, False)
        elif pdu.ptype == PTYPE_RESPONSE:
            row.answer = _answer_facts(pdu.stub, res.src_ip, res.dst_ip)
        return row

    def finish(self, last_frame: int) -> tuple[list[Pdu], list[Finding]]:
        """End of capture (`last_frame`: its last frame's number): what the dissector still held (incomplete
        fragment sets and IP datagrams), as findings (the rows of frames it releases, if any)."""
        rows = [self.row(res, self._ns.get(res.frame, 0)) for res in self.d.finish(last_frame)]
        loose = list(self.d.loose_findings)
        self.d.loose_findings.clear()
        return rows, loose

    def loose(self) -> list[Finding]:
        """The dissector's findings on frames that are not PNIO RPC (link layer, fragments), drained."""
        out = list(self.d.loose_findings)
        self.d.loose_findings.clear()
        return out

    # --- frames by the columns -------------------------------------------------------------------
    @staticmethod
    def column_pdus(batch: FrameBatch, view: BatchView, rows: np.ndarray) -> list[Pdu]:
        """The column rows `rows` (indices into view.p, frame order) as the loop's rows."""
        p = view.p
        if not len(rows):
            return []
        pos = p.pos[rows]
        frame = view.frame_no[rows].tolist()
        ns = batch.ns[pos].tolist()
        ptype = p.ptype[rows].tolist()
        act_hi, act_lo, seq = p.act_hi[rows].tolist(), p.act_lo[rows].tolist(), p.seq[rows].tolist()
        src, dst, opnum = p.src[rows].tolist(), p.dst[rows].tolist(), p.opnum[rows].tolist()
        if_hi, if_lo = p.if_hi[rows].tolist(), p.if_lo[rows].tolist()
        body = (p.body_start[rows].astype(np.int64), p.body_len[rows].astype(np.int64))
        out = []
        cols = rows.tolist()
        for k in range(len(frame)):
            row = Pdu(frame[k], ns[k], ptype[k])
            row.col = cols[k]
            row.key = (act_hi[k], act_lo[k], seq[k])
            row.src, row.dst, row.opnum = src[k], dst[k], opnum[k]
            row.ifc = (if_hi[k], if_lo[k])
            out.append(row)
        _column_requests(view, rows, out, body, batch.buf)
        _column_answers(view, rows, out)
        return out


def _channels(view: BatchView, i: np.ndarray) -> list[tuple[int, ...]]:
    """The channel each of the column rows `i` (requests) names: (device, controller, AR (an implicit read's
    target AR), API, slot, subslot, index)."""
    p = view.p
    nil = (p.ar_hi[i] == 0) & (p.ar_lo[i] == 0)
    ar_hi, ar_lo = np.where(nil, p.target_hi[i], p.ar_hi[i]), np.where(nil, p.target_lo[i], p.ar_lo[i])
    return list(zip(p.dst[i].tolist(), p.src[i].tolist(), ar_hi.tolist(), ar_lo.tolist(), p.api[i].tolist(),
                    p.slot[i].tolist(), p.subslot[i].tolist(), p.index[i].tolist(), strict=True))


def _column_requests(view: BatchView, rows: np.ndarray, out: list[Pdu], body: tuple[np.ndarray, np.ndarray],
                     buf: bytes) -> None:
    """The writes and reads the column rows' requests ask for, and their bodies' digests."""
    import zlib

    p = view.p
    request = np.flatnonzero(p.ptype[rows] == PTYPE_REQUEST)
    mv = memoryview(buf)
    starts, lengths = body[0][request].tolist(), body[1][request].tolist()
    for k, start, length in zip(request.tolist(), starts, lengths, strict=True):
        out[k].digest = (zlib.crc32(mv[start:start + length]), length)
    kind = view.kind[rows]
    rc = view.records.records
    writes = np.flatnonzero(kind == KIND_WRITE)
    if len(writes):
        record = view.rec_of[rows[writes]]
        heads = zip(rc.ref[record].tolist(), rc.ident[record].tolist(), rc.do[record].tolist(), rc.n[record].tolist(),
                    strict=True)
        for k, channel, rec_, head in zip(writes.tolist(), _channels(view, rows[writes]), record.tolist(), heads,
                                          strict=True):
            out[k].writes = [Write(channel, rec_, head, False)]
    reads = np.flatnonzero(kind == KIND_READ)
    for k, channel in zip(reads.tolist(), _channels(view, rows[reads]), strict=True):
        out[k].read = channel
    # a write request on another record: no transaction (a call all the same)
    other = (p.ptype[rows] == PTYPE_REQUEST) & (p.opnum[rows] == OP_WRITE) & (kind != KIND_WRITE)
    for k in np.flatnonzero(other).tolist():
        out[k].writes = [None] if p.has_block[rows[k]] and p.index[rows[k]] != INDEX_WRITE_MULTIPLE else []


def _column_answers(view: BatchView, rows: np.ndarray, out: list[Pdu]) -> None:
    """What the column rows' responses, faults and rejects say."""
    p = view.p
    ptype = p.ptype[rows]
    fault = np.flatnonzero((ptype == PTYPE_FAULT) | (ptype == PTYPE_REJECT))
    for k, status in zip(fault.tolist(), p.status[rows[fault]].tolist(), strict=True):
        out[k].answer = Answer(status, 0, (), None, None, False)
    res = np.flatnonzero(ptype == PTYPE_RESPONSE)
    i = rows[res]
    write = p.opnum[i] == OP_WRITE
    status = np.where(write & (p.status[i] == 0), p.block_status[i], p.status[i]).astype(np.int64)
    record = np.where(~write, view.rec_of[i], -1)
    for k, s in zip(res[record < 0].tolist(), status[record < 0].tolist(), strict=True):
        out[k].answer = Answer(-1, s, (), None, None, False)
    has = np.flatnonzero(record >= 0)
    if not len(has):
        return
    rc, bc = view.records.records, view.records.blocks
    r = record[has]
    nb = rc.n_blocks[r]
    first_error = np.zeros(len(r), bool)
    some = nb > 0
    first_error[some] = bc.error[rc.first_block[r[some]]] >= 0
    heads = zip(rc.ref[r].tolist(), rc.ident[r].tolist(), rc.do[r].tolist(), rc.n[r].tolist(), first_error.tolist(),
                nb.tolist(), strict=True)
    for k, s, rec_, head in zip(res[has].tolist(), status[has].tolist(), r.tolist(), heads, strict=True):
        out[k].answer = Answer(-1, s, (), rec_, Head(*head), True)


# --- the facts of a per-frame decoded PDU ---------------------------------------------------------------
def _request_facts(row: Pdu, stub: rec.Stub | None, malformed: bool) -> None:
    if stub is None:
        return
    if row.opnum == OP_WRITE:
        writes: list[Write | None] = []
        for block in stub.blocks:
            if block.layout is not rec.WRITE_REQ or block.index == INDEX_WRITE_MULTIPLE:
                continue
            if block.index not in PROFIDRIVE_INDICES or (block.pd is None and len(block.record) == block.record_len):
                writes.append(None)  # not PROFIdrive (or index 0x002F that is not): no transaction
                continue
            parsed = block.pd[0] if isinstance(block.pd, tuple) else None
            record = block.record
            head = (record[0], record[1], record[2], record[3]) if len(record) >= 4 else None
            vendor = parsed.vendor.answers if parsed is not None and isinstance(parsed.vendor, VendorRequest) else None
            writes.append(Write(_block_channel(block, row.dst, row.src), parsed, head,
                                malformed or parsed is None or not parsed.complete, vendor))
        row.writes = writes
        # cut before its first IOD header was complete: the answer may name the index (protocol.md 7.3 step 1)
        row.cut = malformed and not stub.blocks
    elif stub.blocks and stub.blocks[0].index in PROFIDRIVE_INDICES:
        row.read = _block_channel(stub.blocks[0], row.dst, row.src)


def _block_channel(block: rec.Block, device: int, controller: int) -> tuple[int, ...]:
    v = block.values
    ar = block.target_ar if v[rec.B_AR] == rec.NIL_UUID and block.target_ar else v[rec.B_AR]
    hi, lo = uuid_int(ar)
    return device, controller, hi, lo, v[rec.B_API], v[rec.B_SLOT], v[rec.B_SUBSLOT], v[rec.B_INDEX]


def _answer_facts(stub: rec.Stub | None, device: bytes, controller: bytes) -> Answer:
    """A response decoded frame by frame: its status(es), its PROFIdrive record, the channel it names."""
    if stub is None:
        return Answer(-1, 0, (), None, None, False)
    if len(stub.blocks) > 1:  # a Write-Multiple's: the outer status, then each inner write's
        inner = tuple(packed(b.status) for b in stub.blocks[1:])
        status = packed(stub.status)
    else:
        bad = stub.status is not None and not stub.status.ok
        status = packed(stub.status if bad or not stub.blocks else stub.blocks[0].status)
        inner = ()
    block = next((b for b in stub.blocks if b.index in PROFIDRIVE_INDICES), None)
    parsed = block.pd[0] if block is not None and isinstance(block.pd, tuple) else None
    head = None
    if isinstance(parsed, Parsed) and parsed.complete:
        first_error = bool(parsed.blocks) and parsed.blocks[0].is_error
        head = Head(parsed.ref, parsed.ident, parsed.do, parsed.n, first_error, len(parsed.blocks))
    names = None
    first = stub.blocks[0] if stub.blocks else None
    if first is not None and first.layout is rec.WRITE_RES and first.index in PROFIDRIVE_INDICES:
        names = Write(_block_channel(first, ip_int(device), ip_int(controller)), None, None, True)
    return Answer(-1, status, inner, parsed, head, head is not None, names)


def skipped_decide(acc: Accounting, res: FrameResult, reason: str) -> None:
    """A frame the dissector counted as PNIO that its call or activity says is not: counted as skipped."""
    if res.counted:
        acc.malformed[res.counted] -= 1
        if not acc.malformed[res.counted]:
            del acc.malformed[res.counted]
    else:
        acc.decoded -= 1
    acc.skipped[reason] += 1


def merge_accounting(into: Accounting, part: Accounting) -> None:
    into.read += part.read
    into.decoded += part.decoded
    into.skipped.update(part.skipped)
    into.malformed.update(part.malformed)


_ = (Counter, ROUTE_PNIO)
