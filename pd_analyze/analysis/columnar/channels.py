"""Transactions of the ordinary groups (protocol.md 7.3): a small state machine over their calls.

Calls come in request order with their answers. A write of a parameter request opens a transaction on
its channel (superseding a pending one: T3; reusing the last one's reference: T1/T4); its answer closes
it when refused; reads answered B5 count; the final read's answer closes it (Q2-Q5 on the mirroring);
a deadline passed closes it as a timeout. What the per-frame engine would treat differently (a read with
no pending write, a read paired by fallback, calls overlapping on one channel, an answer that cannot be
decoded here) marks the group for the per-frame path instead.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache
from types import SimpleNamespace

from pd_analyze.analysis.columnar.state import KIND_WRITE, ChannelKey, Txn
from pd_analyze.analysis.transaction import (
    ANSWERS,
    UNANSWERED_ENDS,
    LastDone,
    b5_finding,
    mirroring_findings,
    refused_busy,
    reuse_finding,
    superseded_finding,
)
from pd_analyze.model.capped import TXN_FRAMES
from pd_analyze.model.values import PNIORW_STATE_CONFLICT
from pd_analyze.model.verdicts import ANSWERED, PRECEDENCE


@dataclass(slots=True)
class CallView:
    """The calls of a batch's ordinary groups, in request order, as Python lists (one entry per call)."""

    frame: list[int]  # request frame
    ts: list[float]
    group: list[int]
    kind: list[int]  # KIND_*
    channel: list[ChannelKey | None]
    record: list[int]  # the write's request record (index into the batch's records), -1 otherwise
    head: list[tuple[int, int, int, int] | None]  # the write's request header: ref, Request ID, DO, n
    carried_txn: list[Txn | None]  # the transaction of a call carried over from the last batch
    # the answer in this batch (res_frame -1: none yet)
    res_frame: list[int]
    res_ts: list[float]
    res_status: list[int]  # PNIOStatus (a write's: its block's when the NDR one is OK), or FAULT | NCA status
    res_record: list[int]  # a read's response record, -1 when none (status not OK, or no record)
    res_head: list[SimpleNamespace | None]  # its ref, ident, do, n, blocks ([error] when header-level)


@dataclass(slots=True)
class Outcome:
    """What the calls of a batch did to the transactions."""

    opened: list[Txn] = field(default_factory=list)  # in frame order, opened by a write of this batch
    closed: list[Txn] = field(default_factory=list)
    owner: dict[int, Txn] = field(default_factory=dict)  # frame -> the transaction it belongs to
    unanswered: dict[int, Txn | None] = field(default_factory=dict)  # call index -> its transaction
    reads: list[tuple[int, Txn]] = field(default_factory=list)  # (final response frame, read answered ok/nak)
    pending: dict[ChannelKey, Txn] = field(default_factory=dict)
    done: dict[ChannelKey, LastDone] = field(default_factory=dict)  # each channel's last transaction closed


@cache
def _verdict(why: str, mismatch: bool, nak: bool, busy: bool) -> str:
    """protocol.md 7.4 for a columnar transaction (never malformed: such records go to the per-frame path);
    `busy`: every read answered B5 until the controller gave up (7.3 step 5)."""
    holds = {"malformed": False, "pnio_error": why == "pnio_error" or busy, "timeout": why in UNANSWERED_ENDS,
             "reference_mismatch": mismatch, "nak": nak, "ok": True}
    return next(verdict for verdict in PRECEDENCE if holds[verdict])


_B5 = 0x80 << 16 | PNIORW_STATE_CONFLICT << 8  # ErrorDecode PNIORW, ErrorCode1 state conflict (in a PNIOStatus)
FAULT = 1 << 32  # in CallView.res_status: the answer is an RPC fault or reject, with this NCA status below
_B5_MASK = FAULT | 0xFFFF00


class ChannelMachine:
    """The state machine of one batch over the calls of its ordinary groups."""

    def __init__(self, pending: dict[ChannelKey, Txn], last_done: dict[ChannelKey, LastDone], txn_timeout: float,
                 b5_threshold: int, bad: set[int]) -> None:
        self.timeout = txn_timeout
        self.threshold = b5_threshold
        self.bad = bad
        self.last_done = last_done
        self.out = Outcome(pending=dict(pending))
        self.pending = self.out.pending
        # Transactions carried over are copied before this batch changes them: should their group go to the
        # per-frame path after all, it takes them as they were before the batch (columnar.handover)
        self._carried = {id(t): t for t in pending.values()}
        self.copies: dict[int, Txn] = {}  # id of a carried transaction -> its copy

    def run(self, v: CallView) -> Outcome:
        """Every call in order (`close_due` then closes what the rest of the batch's time let pass). The
        common case, a read of the pending transaction answered in time, is written out here; the rest
        goes through the methods below."""
        bad, pending, owner, unanswered = self.bad, self.pending, self.out.owner, self.out.unanswered
        carried_ids, timeout, threshold = self._carried, self.timeout, self.threshold
        answered_in: dict[ChannelKey, int] = {}  # the frame that answered the channel's last call (-1: none yet)
        frames, groups, channels, kinds, res_frames = v.frame, v.group, v.channel, v.kind, v.res_frame
        res_times, statuses, carried_txns = v.res_ts, v.res_status, v.carried_txn
        for k, ch in enumerate(channels):
            group = groups[k]
            if group in bad:
                continue
            res_frame = res_frames[k]
            if ch is None:  # a call on another record
                if res_frame < 0:
                    unanswered[k] = None
                continue
            if answered_in.get(ch, 0) > frames[k]:  # the channel's last call is answered after this one's request
                bad.add(group)  # (one left unanswered is not: an answer in a later batch finds its txn closed)
                continue
            answered_in[ch] = res_frame
            t = v.ts[k]
            if kinds[k] == KIND_WRITE:
                txn = self._write(v, k, t)
            elif carried_txns[k] is not None:
                txn = self._own(carried_txns[k])
                if res_frame >= 0:
                    self._read_answer(v, k, txn)
            else:
                txn = pending.get(ch)
                if txn is not None and id(txn) in carried_ids:
                    txn = self._own(txn)
                if txn is not None and txn.t_start + timeout < t:
                    self._close(txn, "deadline")
                    txn = None
                if txn is None:  # no pending write on the channel: T2, or a fallback pairing: the per-frame path's
                    bad.add(group)
                    continue
                frame = frames[k]
                txn.read_frames.append(frame)
                txn.t_reads.append(t)
                txn.frames.append(frame)
                owner[frame] = txn
                if res_frame >= 0:
                    status = statuses[k]
                    res_ts = res_times[k]
                    if status & _B5_MASK == _B5 and txn.t_start + timeout >= res_ts:
                        txn.frames.append(res_frame)  # the common answer while the drive is busy
                        owner[res_frame] = txn
                        txn.b5 += 1
                        txn.last_b5 = res_ts
                        if txn.b5 == threshold + 1:
                            txn.findings.append(b5_finding(txn.b5, threshold, res_frame))
                        if len(txn.frames) > TXN_FRAMES:
                            bad.add(group)
                    else:
                        self._read_answer(v, k, txn)
            if res_frame < 0:
                unanswered[k] = txn
        return self.out

    def close_due(self, now: float) -> None:
        """The deadlines that passed by `now`, the last PNIO frame's time in the batch (on any path)."""
        for txn in list(self.pending.values()):
            if txn.group not in self.bad and txn.t_start + self.timeout < now:
                self._close(self._own(txn), "deadline")

    def _own(self, txn: Txn | None) -> Txn | None:
        """The transaction this batch may change: a carried one's copy (made on first use)."""
        if txn is None or id(txn) not in self._carried:
            return txn
        copy = self.copies.get(id(txn))
        if copy is None:
            copy = self.copies[id(txn)] = txn.copy()
            if self.pending.get(txn.channel) is txn:
                self.pending[txn.channel] = copy
        return copy

    # --- one call -------------------------------------------------------------------------------
    def _due(self, ch: ChannelKey, t: float) -> Txn | None:
        """The channel's pending transaction, after closing it if its deadline passed before time t."""
        txn = self._own(self.pending.get(ch))
        if txn is not None and txn.t_start + self.timeout < t:
            self._close(txn, "deadline")
            return None
        return txn

    def _write(self, v: CallView, k: int, t: float) -> Txn:
        ch, frame = v.channel[k], v.frame[k]
        assert ch is not None
        carried = self._own(v.carried_txn[k])
        if carried is not None:  # opened in the last batch; its answer comes in this one
            txn = carried
            if txn.closed_by:  # superseded or due meanwhile: the answer belongs to no transaction
                return txn
        else:
            old = self._due(ch, t)
            txn = Txn(ch, v.group[k], frame, t)
            txn.request = v.record[k]
            head = v.head[k]
            assert head is not None
            txn.ref, txn.req_id, txn.do, txn.n_params = head
            if old is not None:
                txn.findings.append(superseded_finding(txn.ref, old.write_frame, old.ref, frame))
                self._close(old, "superseded")
            last = self.out.done.get(ch) or self.last_done.get(ch)
            if last is not None:
                reuse = reuse_finding(last, txn.ref, frame)
                if reuse is not None:
                    txn.findings.append(reuse)
            self.pending[ch] = txn
            self.out.opened.append(txn)
            self.out.owner[frame] = txn
        if v.res_frame[k] >= 0:
            res_frame, res_ts = v.res_frame[k], v.res_ts[k]
            if self._due(ch, res_ts) is None:  # the deadline passed before the answer: it belongs to none
                return txn
            txn.write_res_frame, txn.t_write_res = res_frame, res_ts
            self._owns(txn, res_frame)
            if v.res_status[k]:
                txn.pnio_status = f"{v.res_status[k] & 0xFFFFFFFF:08X}"
                self._close(txn, "pnio_error")
        return txn

    def _read(self, v: CallView, k: int, t: float) -> Txn | None:
        ch = v.channel[k]
        assert ch is not None
        txn = self._due(ch, t)
        if txn is None:  # no pending write on the channel: T2, or a fallback pairing: the per-frame path's
            self.bad.add(v.group[k])
            return None
        frame = v.frame[k]
        txn.read_frames.append(frame)
        txn.t_reads.append(t)
        self._owns(txn, frame)
        if v.res_frame[k] >= 0:
            self._read_answer(v, k, txn)
        return txn

    def _read_answer(self, v: CallView, k: int, txn: Txn) -> None:
        res_frame, res_ts = v.res_frame[k], v.res_ts[k]
        if txn.closed_by or self._due(txn.channel, res_ts) is None:
            return
        self._owns(txn, res_frame)
        status = v.res_status[k]
        if status:
            if status & _B5_MASK == _B5:
                txn.b5 += 1
                txn.last_b5 = res_ts
                if txn.b5 == self.threshold + 1:
                    txn.findings.append(b5_finding(txn.b5, self.threshold, res_frame))
                return
            txn.pnio_status = f"{status & 0xFFFFFFFF:08X}"
            txn.read_res_frame, txn.t_read_res = res_frame, res_ts
            self._close(txn, "pnio_error")
            return
        head = v.res_head[k]
        if head is None:  # an answer without a PROFIdrive record: decoded by the per-frame path
            self.bad.add(v.group[k])
            return
        txn.read_res_frame, txn.t_read_res = res_frame, res_ts
        txn.response = v.res_record[k]
        if not (head.ref == txn.ref and head.do == txn.do and head.n == txn.n_params
                and head.ident in ANSWERS.get(txn.req_id, ())):  # Q2-Q5 hold, as a rule
            found, txn.mismatch = mirroring_findings(txn.ref, txn.req_id, txn.do, txn.n_params, head, res_frame)
            txn.findings += found
        self._close(txn, "response", head.ident)
        if txn.req_id == 0x01 and txn.verdict in ANSWERED:
            self.out.reads.append((res_frame, txn))

    def _owns(self, txn: Txn, frame: int) -> None:
        """A frame of the transaction (more than TXN_FRAMES: the per-frame engine evicts it)."""
        txn.frames.append(frame)
        self.out.owner[frame] = txn
        if len(txn.frames) > TXN_FRAMES:
            self.bad.add(txn.group)

    def _close(self, txn: Txn, why: str, ident: int = -1) -> None:
        if self.pending.get(txn.channel) is txn:
            del self.pending[txn.channel]
        txn.closed_by = why
        busy = refused_busy(why, txn.capture_ended, txn.b5, len(txn.read_frames))
        txn.verdict = _verdict(why, txn.mismatch, ident >= 0 and bool(ident & 0x80), busy)
        if why in UNANSWERED_ENDS and not txn.pnio_status and txn.b5:
            txn.pnio_status = f"DE80{PNIORW_STATE_CONFLICT:02X}00"  # the last answer was B5
        self.out.done[txn.channel] = LastDone(txn.write_frame, txn.ref, txn.verdict)
        self.out.closed.append(txn)
