"""PROFIdrive transactions (protocol.md 7): write a parameter request, poll with reads, get the response.

`Machine.feed` takes the paired PDU rows in frame order and closes transactions as the model says:
a write of a parameter request opens one on its channel (superseding a pending one: T3; reusing the
last one's reference: T1/T4), its answer closes it when refused; reads answered B5 count; the final
read's answer closes it (Q2-Q5 on the mirroring); a read with no pending write on its channel is
paired by device, controller, AR and index (T6) or reported (T2); a deadline passed, the caps or the
capture's end close it as a timeout, or as a busy drive given up (7.3 step 5). State is kept only for
open channels and open calls, each table capped with its evictions stated (model.capped).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from typing import NamedTuple

from pd_analyze.analysis.capture_run import DEFAULT_B5_THRESHOLD, DEFAULT_TXN_TIMEOUT
from pd_analyze.analysis.engine.calls import Call
from pd_analyze.analysis.engine.facts import Channel, Pdu, Write
from pd_analyze.analysis.engine.records import Records
from pd_analyze.analysis.engine.rules import (
    UNANSWERED_ENDS,
    b5_finding,
    ends,
    failed_finding,
    mirroring,
    superseded_finding,
    verdict_of,
)
from pd_analyze.analysis.engine.txn import Txn
from pd_analyze.model.capped import (
    PENDING_TRANSACTIONS,
    TXN_CALLS,
    TXN_FRAMES,
    CappedTable,
)
from pd_analyze.model.rules import Finding, finding
from pd_analyze.model.values import (
    OP_WRITE,
    PNIORW_STATE_CONFLICT,
    PTYPE_FAULT,
    PTYPE_REJECT,
    PTYPE_REQUEST,
    PTYPE_RESPONSE,
    RECORD_SERVICES,
)

FRAME_COST = 1024  # bytes a transaction keeps per frame (frame lists, its RPC calls)
_B5 = 0x80 << 16 | PNIORW_STATE_CONFLICT << 8  # ErrorDecode PNIORW, ErrorCode1 state conflict (packed status)
B5_STATUS = f"DE80{PNIORW_STATE_CONFLICT:02X}00"


class FsmCall(NamedTuple):
    """What an open write/read call is about, by its request frame."""

    kind: str  # "write", "read", or "cut": a write cut before its first IOD block (its answer may name it)
    txns: list[Txn | None]  # per record written (a Write-Multiple's), or the one read target
    channel: Channel | None = None
    request: Pdu | None = None  # a cut write's request row


def _names_none(_row: Pdu) -> Write | None:
    return None  # (no part's columns: between parts)


def fallback_key(channel: Channel) -> tuple:
    """Device, controller, AR and index: what a read must share with a write addressed differently
    (protocol.md 7.2; slot and subslot may differ, the index may not)."""
    return channel[0], channel[1], channel[2], channel[3], channel[7]


class Machine:
    """The channel state machines over paired PDU rows (protocol.md 7.3); times in nanoseconds."""

    def __init__(self, txn_timeout: float = DEFAULT_TXN_TIMEOUT, b5_threshold: int = DEFAULT_B5_THRESHOLD) -> None:
        self.timeout = round(txn_timeout * 1e9)
        self.b5_threshold = b5_threshold
        self.records = Records(None)  # the current batch's (set by the run)
        self.names_of: Callable[[Pdu], Write | None] = _names_none  # the channel a column answer names
        self.loose: list[Finding] = []  # findings of frames that belong to no transaction
        self.opened: list[Txn] = []  # opened since the run last took them (it numbers them)
        self.closed: list[Txn] = []  # closed since the run last took them
        # open transactions by channel, in opening order; the oldest ends as a timeout when the table is full
        self.pending: CappedTable[Channel, Txn] = CappedTable(PENDING_TRANSACTIONS)
        self._by_ar: dict[tuple, OrderedDict[Channel, Txn]] = {}  # the fallback pairing's key (7.2)
        self._calls: CappedTable[int, FsmCall] = CappedTable(TXN_CALLS)  # by request frame
        self.now = -(1 << 62)

    # --- the row loop -------------------------------------------------------------------------
    def feed(self, row: Pdu, now: int) -> Txn | None:
        """One PNIO RPC frame's row (in frame order; `now`: the capture time reached at its frame over every
        PNIO frame, those the vector path takes included); the transaction it belongs to, if any."""
        if now > self.now:
            self.now = now
        self._expire()  # (also when time stood still or went back: a transaction opened past its deadline)
        owner = self._row(row)
        if owner is None:
            return None
        # every frame of the row (a reassembled PDU's fragments) is each of its transactions' (a Write-Multiple
        # opens several; a copy of a call's request or answer belongs to the call's)
        owners = self._owners(row.call) or (owner,)
        for txn in owners:
            frames = txn.frames
            for frame in row.frames or (row.frame,):
                if not frames or frames[-1] < frame or frame not in frames:
                    frames.append(frame)  # rows come in frame order: one comparison, as a rule
            if not txn.closed_by:
                self.pending.charge(txn.channel, FRAME_COST)
                if len(frames) > TXN_FRAMES:
                    self._evict(txn, row.frame, f"more than {TXN_FRAMES} frames")
        return owner

    def part_done(self) -> None:
        """The part's view and records go now, not when the next part replaces them: two batches' columns
        are never alive at once."""
        self.records = Records(None)
        self.names_of = _names_none

    def calls_table(self) -> CappedTable:
        """The calls the machine awaits answers to (their count bounds what the vector path may leave out)."""
        return self._calls

    def advance(self, now: int) -> None:
        """Capture time reached `now`: the transactions due close."""
        if now > self.now:
            self.now = now
            self._expire()

    def finish(self, last: int) -> None:
        """Capture end (`last`: its latest PNIO time): every open transaction is a timeout, marked
        capture_ended if its deadline lies beyond."""
        for txn in list(self.pending.values()):
            txn.capture_ended = txn.t_start + self.timeout > last
            self._close(txn, "capture_end")
        self._calls.clear()

    def _expire(self) -> None:
        for txn in self.pending.values():  # the common case, on every row: the oldest is not due
            if txn.t_start + self.timeout >= self.now:
                return
            break
        due = []
        for txn in self.pending.values():  # in opening order: stop at the first not yet due
            if txn.t_start + self.timeout >= self.now:
                break
            due.append(txn)
        for txn in due:
            self._close(txn, "deadline")

    def _row(self, row: Pdu) -> Txn | None:
        if not row.whole:  # a fragment: a retransmitted one belongs to its call's transactions
            return next(iter(self._owners(row.call)), None) if row.copy else None
        call: Call | None = row.call
        ptype = row.ptype
        if ptype == PTYPE_REQUEST:
            if row.opnum not in RECORD_SERVICES:
                return None
            if row.copy:
                return next(iter(self._owners(call)), None)
            return self._write_request(row) if row.opnum == OP_WRITE else self._read_request(row)
        if ptype in (PTYPE_RESPONSE, PTYPE_FAULT, PTYPE_REJECT) and call is not None:
            if call.opnum not in RECORD_SERVICES:
                return None
            if row.copy:  # a second answer to the call: its transactions' frame
                return next(iter(self._owners(call)), None)
            fsm = self._calls.pop(call.frame, None)
            if fsm is None:
                return None
            if fsm.kind == "cut":
                return self._cut_write_response(row, fsm)
            if fsm.kind == "write":
                return self._write_response(row, fsm)
            return self._read_response(row, fsm)
        return None

    # --- writes -----------------------------------------------------------------------------
    def _write_request(self, row: Pdu) -> Txn | None:
        writes = row.writes
        if writes is None:
            return None
        opened: list[Txn | None] = []
        for w in writes:
            opened.append(None if w is None else self._open(row, w, len(opened)))
        if not any(opened):
            if row.cut:
                # cut before its IOD header was complete (snaplen, damage): the index is unknown until the
                # answer, paired by activity and sequence number, names it (protocol.md 7.3 step 1)
                self._remember(row, FsmCall("cut", [], None, row))
            return None
        self._remember(row, FsmCall("write", opened))
        return next(t for t in opened if t is not None)

    def _open(self, row: Pdu, w: Write, position: int) -> Txn:
        txn = self._new(row, w.channel, row.frame, position)
        txn.request = w.record
        if w.head is not None:
            txn.ref, txn.req_id, txn.do, txn.n_params = w.head
        if w.malformed:
            txn.spoil(row.frame)
        txn.vendor = w.vendor
        self._admit(txn, row.frame)
        return txn

    def _new(self, row: Pdu, channel: Channel, opened_at: int, position: int) -> Txn:
        """A transaction of the write request `row`, numbered by the frame that opens it (`opened_at`: the
        request's, or a cut request's answer) and its position among the request's records."""
        txn = Txn(channel, row.first, row.first_ts, opened_at, position)
        txn.frames.extend(row.frames)
        txn.calls.append(row.call)
        self.opened.append(txn)
        return txn

    def _admit(self, txn: Txn, frame: int) -> None:
        """A new transaction becomes its channel's pending one: T3 on a pending one, the caps (T1/T4, which
        compare it with the channel's last transaction, are the run's: finals.reuse)."""
        channel = txn.channel
        txn.admitted = frame
        old = self.pending.get(channel)
        if old is not None:
            old.ended_at = frame
            self._close(old, "superseded")
            txn.findings.append(superseded_finding(txn.ref, old, frame))
        self.pending.put(channel, txn, 1024 + self.records.cost(txn.request))
        self._by_ar.setdefault(fallback_key(channel), OrderedDict())[channel] = txn
        while len(self.pending) > 1 and self.pending.full():
            self._evict(self.pending.oldest(), frame, "transaction table full")  # type: ignore[arg-type]

    def _cut_write_response(self, row: Pdu, fsm: FsmCall) -> Txn | None:
        """The answer to a write cut before its IOD header was complete: when it names a PROFIdrive index
        (a single write, not 0xE040), the transaction opens at the request's frame with what could be read
        of it (nothing of its record): malformed, and its reads pair with it as usual (protocol.md 7.3
        step 1). Numbered at the request's frame (engine.numbering)."""
        req = fsm.request
        answer = row.answer
        names = None
        if answer is not None and answer.fault < 0:
            names = answer.names if row.odd else self.names_of(row)
        if req is None or row.ptype != PTYPE_RESPONSE or names is None:
            return None
        txn = self._new(req, names.channel, req.frame, 0)
        txn.spoil(req.frame)  # the record is cut (H5/R1 on the request's frame)
        if req.frame not in txn.frames:
            txn.frames.append(req.frame)
        if req.call is not None:
            req.call.fsm = FsmCall("write", [txn])
        self._admit(txn, req.frame)
        return self._write_response(row, FsmCall("write", [txn]))

    def _write_response(self, row: Pdu, fsm: FsmCall) -> Txn | None:
        answer = row.answer
        count = len(fsm.txns)
        if answer is None:
            statuses = [0] * count
        elif answer.statuses:  # a Write-Multiple's inner statuses are authoritative (protocol.md 2.8)
            inner = list(answer.statuses)
            statuses = [answer.status] * count if answer.status and not any(inner) else inner
        else:
            statuses = [answer.status] * count
        first = None
        for txn, status in zip(fsm.txns, statuses, strict=False):
            if txn is None or txn.closed_by:
                continue
            first = first or txn
            txn.write_res_frame = row.frame
            txn.t_write_res = row.ts
            if row.malformed:
                txn.spoil(row.frame)
            if answer is not None and answer.fault >= 0:
                txn.pnio_status = f"{answer.fault:08X}"
                self._close(txn, "pnio_error")
            elif status:
                txn.pnio_status = f"{status:08X}"
                self._close(txn, "pnio_error")
        return first

    # --- reads ------------------------------------------------------------------------------
    def _read_request(self, row: Pdu) -> Txn | None:
        channel = row.read
        if channel is None:
            return None
        txn = self.pending.get(channel)
        if txn is None:
            # the oldest pending on the same index: a read never fetches another index's response (7.2)
            txn = next(iter(self._by_ar.get(fallback_key(channel), {}).values()), None)
            if txn is not None and not txn.fallback:
                txn.fallback = True
                txn.findings.append(finding(
                    "fallback_pairing", row.frame, "iod.index", f"{channel[5]}/{channel[6]}/{channel[7]:#06x}",
                    f"{txn.channel[5]}/{txn.channel[6]}/{txn.channel[7]:#06x}",
                    f"read addressed differently from the write of frame {txn.write_frame} (paired by device, "
                    "controller, AR and index)"))
        if txn is None:
            self.loose.append(finding("read_without_request", row.frame, "iod.index", f"{channel[7]:#06x}",
                                      "a pending parameter request", "read on a PROFIdrive index with no "
                                                                     "pending write on the channel"))
            self._remember(row, FsmCall("read", [None], channel))
            return None
        txn.read_frames.append(row.first)
        txn.t_reads.append(row.first_ts)
        txn.frames.extend(row.frames)
        txn.calls.append(row.call)
        self._remember(row, FsmCall("read", [txn], channel))
        return txn

    def _read_response(self, row: Pdu, fsm: FsmCall) -> Txn | None:
        txn = fsm.txns[0]
        if txn is None or txn.closed_by:
            return None
        if row.malformed:
            txn.spoil(row.frame)
        answer = row.answer
        if answer is not None and answer.fault >= 0:
            txn.pnio_status = f"{answer.fault:08X}"
            txn.read_res_frame, txn.t_read_res = row.frame, row.ts
            self._close(txn, "pnio_error")
            return txn
        status = answer.status if answer is not None else 0
        if status:
            if status & 0xFFFF00 == _B5:
                txn.b5 += 1
                txn.last_b5 = row.ts
                if txn.b5 == self.b5_threshold + 1:
                    txn.findings.append(b5_finding(txn.b5, self.b5_threshold, row.frame))
                return txn
            txn.pnio_status = f"{status:08X}"
            txn.read_res_frame, txn.t_read_res = row.frame, row.ts
            self._close(txn, "pnio_error")
            return txn
        txn.read_res_frame, txn.t_read_res = row.frame, row.ts
        head = answer.head if answer is not None else None
        txn.response = answer.record if answer is not None else None
        if head is None or not answer.complete:  # type: ignore[union-attr]
            txn.spoil(row.frame)
        else:
            txn.response_head = head
            found, mismatch = mirroring(txn, head, row.frame)
            txn.findings += found
            txn.mismatch |= mismatch
        self._close(txn, "response")
        return txn

    @staticmethod
    def _owners(call: Call | None) -> list[Txn]:
        """The transactions a call's request opened or read for (a copy of the request or of its answer is
        theirs too), until the run hands them on (it forgets them then: `forget`)."""
        fsm = call.fsm if call is not None else None
        return [t for t in fsm.txns if t is not None] if isinstance(fsm, FsmCall) else []

    # --- closing ----------------------------------------------------------------------------
    def _evict(self, txn: Txn, frame: int, why: str) -> None:
        """Close a pending transaction the caps cannot hold any longer: a timeout, closed_by "evicted"."""
        self.pending.evict(txn.channel, frame)  # counted; each evicted transaction is a row with its finding
        txn.ended_at = frame
        self._close(txn, "evicted")
        txn.findings.append(finding(PENDING_TRANSACTIONS.rule, frame, "pd.ref", txn.ref,
                                    f"{PENDING_TRANSACTIONS.text()}, {TXN_FRAMES} frames each",
                                    f"{why}: the transaction of frame {txn.write_frame} ends {ends(txn)}"))

    def _close(self, txn: Txn, why: str) -> None:
        channel = txn.channel
        if self.pending.get(channel) is txn:
            self.pending.pop(channel)
        same_ar = self._by_ar.get(fallback_key(channel))
        if same_ar is not None and same_ar.get(channel) is txn:  # it was pending (and maybe evicted just now)
            del same_ar[channel]
            if not same_ar:
                del self._by_ar[fallback_key(channel)]
            self._forget_calls(txn)
        txn.closed_by = why
        txn.verdict = verdict_of(txn)
        # copies seen so far, of answered and unanswered calls alike (protocol.md 7.6)
        txn.retransmissions = sum(c.copies for c in txn.calls if c is not None)
        if why in UNANSWERED_ENDS and not txn.pnio_status and txn.b5:
            txn.pnio_status = B5_STATUS  # the last answer was B5 (txn.last_status)
        txn.findings += failed_finding(txn, self.timeout / 1e9)  # T8
        self.closed.append(txn)

    def _forget_calls(self, txn: Txn) -> None:
        """A closed transaction's calls need no state: a late answer to them belongs to no transaction."""
        for frame in txn.frames:  # its requests' frames among them (a reassembled one: the completing frame)
            fsm = self._calls.get(frame)
            if fsm is not None and all(t is None or t is txn or t.closed_by for t in fsm.txns):
                self._calls.pop(frame)

    def _remember(self, row: Pdu, fsm: FsmCall) -> None:
        if row.call is not None and any(t is not None for t in fsm.txns):  # (`_owners` reads none of the others)
            row.call.fsm = fsm
        self._calls.remember(row.frame, fsm)  # the oldest are forgotten
