"""PROFIdrive transactions (protocol.md 7): write a parameter request, poll with reads, get the response.

`TransactionEngine.feed` takes the dissector's frame results in frame order and returns the
transactions that closed, each with its verdict, figures, per-parameter results and findings.
State is kept only for open channels and open RPC calls; a closed transaction is handed on at once.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from pd_analyze.analysis.transaction import (
    UNANSWERED_ENDS,
    Channel,
    Element,
    LastDone,
    Transaction,
    b5_finding,
    elements,
    elements_read,
    mirroring_findings,
    reuse_finding,
    superseded_finding,
    vendor_answers,
    verdict_of,
)
from pd_analyze.model.capped import (
    CHANNEL_HISTORY,
    PENDING_TRANSACTIONS,
    READ_VALUES,
    TXN_CALLS,
    TXN_FRAMES,
    CappedTable,
)
from pd_analyze.model.rules import Finding, finding
from pd_analyze.model.values import (
    INDEX_WRITE_MULTIPLE,
    OP_WRITE,
    PNIORW_STATE_CONFLICT,
    PROFIDRIVE_INDICES,
    PTYPE_FAULT,
    PTYPE_REJECT,
    PTYPE_REQUEST,
    PTYPE_RESPONSE,
    RECORD_SERVICES,
)
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol.frames import FrameResult, Pdu
from pd_analyze.protocol.pnio import Status
from pd_analyze.protocol.profidrive import footprint, writes_values

DEFAULT_TXN_TIMEOUT = 10.0
DEFAULT_B5_THRESHOLD = 50
FRAME_COST = 1024  # bytes a transaction keeps per frame (frame lists, its RPC calls)

def _cost(txn: Transaction) -> int:
    """Bytes a pending transaction keeps alive beyond its frames: the parsed request, findings."""
    return 1024 + (footprint(txn.request) if txn.request is not None else 0)


@dataclass(slots=True)
class _Call:
    """What an open write/read call is about, by its request frame."""

    kind: str  # "write", "read", or "cut": a write cut before its first IOD block (its response may name it)
    txns: list[Transaction | None]  # per PROFIdrive block (write), or the one read target
    channel: Channel | None = None
    request: Pdu | None = None  # a cut write's request PDU


class TransactionEngine:
    """Channel state machines over dissected frames (protocol.md 7.3)."""

    def __init__(self, txn_timeout: float = DEFAULT_TXN_TIMEOUT, b5_threshold: int = DEFAULT_B5_THRESHOLD) -> None:
        self.txn_timeout = txn_timeout
        self.b5_threshold = b5_threshold
        self.loose: list[Finding] = []  # findings of frames that belong to no transaction, drained by callers
        self._next = 1
        # open transactions by channel, in opening order; the oldest ends as a timeout when the table is full
        self._pending: CappedTable[Channel, Transaction] = CappedTable(PENDING_TRANSACTIONS)
        # the same by device, controller, AR and index: the fallback pairing's key (protocol.md 7.2)
        self._by_ar: dict[tuple, OrderedDict[Channel, Transaction]] = {}
        self._last_done: CappedTable[Channel, LastDone] = CappedTable(CHANNEL_HISTORY)  # for T1, T4
        self._calls: CappedTable[int, _Call] = CappedTable(TXN_CALLS)  # by request frame number
        self.read_values: CappedTable[Element, str] = CappedTable(READ_VALUES)  # the last read back, per element
        self._now = float("-inf")
        # The number of the transaction a write request opens, by (frame, position among the records of
        # the request): the columnar path numbers transactions across both of its engines; None: 1, 2, ...
        self.number_of: Callable[[int, int], int] | None = None

    # --- the frame loop ---------------------------------------------------------------------
    def feed(self, res: FrameResult) -> list[Transaction]:
        self._now = max(self._now, res.ts)
        closed = self._expire()
        owner = self._frame(res, closed)
        if owner is not None:
            owner.findings += res.findings
            if not owner.frames or (owner.frames[-1] < res.frame or res.frame not in owner.frames):
                owner.frames.append(res.frame)  # results come in frame order: one comparison, as a rule
                if not owner.closed_by:
                    self._pending.charge(owner.channel, FRAME_COST)
                    if len(owner.frames) > TXN_FRAMES:
                        closed.append(self._evict(owner, res.frame, f"more than {TXN_FRAMES} frames"))
        else:
            self.loose += res.findings
        return closed

    def advance(self, now: float) -> list[Transaction]:
        """Capture time reached `now` on frames this engine did not see: the transactions due close."""
        if now <= self._now:
            return []
        self._now = now
        return self._expire()

    def adopt(self, txn: Transaction, waiting: list[tuple[int, str]]) -> None:
        """Take over a pending transaction followed elsewhere (the columnar path), with the calls it waits
        on: (request frame, "write" or "read"). `reorder` puts the pending ones back in time order after."""
        self._pending.put(txn.channel, txn, _cost(txn) + FRAME_COST * len(txn.frames))
        self._by_ar.setdefault(_fallback_key(txn.channel), OrderedDict())[txn.channel] = txn
        for frame, kind in waiting:
            self._remember(frame, _Call(kind, [txn], txn.channel if kind == "read" else None))

    def adopt_last(self, channel: Channel, last: LastDone) -> None:
        """The channel's last closed transaction, learnt elsewhere (for T1, T4)."""
        self._last_done.remember(channel, last)

    def busy_pairs(self) -> set[tuple[bytes, bytes]]:
        """(device, controller) of every pending transaction."""
        return {(channel[0], channel[1]) for channel in self._pending}

    def last_done(self) -> Iterator[tuple[Channel, LastDone]]:
        """Each channel's last closed transaction."""
        return iter(self._last_done.items())

    def reorder(self) -> None:
        """Pending transactions back in the order they opened (adopted ones came in late): expiry walks
        them oldest first."""
        for table in (self._pending, *self._by_ar.values()):
            ordered = sorted(table.items(), key=lambda item: (item[1].t_start, item[1].write_req_frame))
            for channel, _txn in ordered:
                table.move_to_end(channel)

    def open_frames(self) -> Iterator[int]:
        """Write request frame of every pending transaction."""
        return (txn.write_req_frame for txn in self._pending.values())

    def finish(self, last_ts: float) -> list[Transaction]:
        """Capture end: every open transaction is a timeout, marked capture_ended if its deadline lies beyond."""
        out = []
        for txn in list(self._pending.values()):
            txn.capture_ended = txn.t_start + self.txn_timeout > last_ts
            out.append(self._close(txn, "capture_end"))
        self._calls.clear()
        return out

    def _expire(self) -> list[Transaction]:
        due = []
        for txn in self._pending.values():  # in opening order: stop at the first not yet due
            if txn.t_start + self.txn_timeout >= self._now:
                break
            due.append(txn)
        return [self._close(txn, "deadline") for txn in due]

    def _frame(self, res: FrameResult, closed: list[Transaction]) -> Transaction | None:
        pdu = res.pdu
        if pdu is None or pdu.opnum not in RECORD_SERVICES:
            return None
        if pdu.ptype == PTYPE_REQUEST:
            if pdu.retransmission:
                return self._retransmitted(pdu)
            return self._write_request(pdu, res, closed) if pdu.opnum == OP_WRITE else self._read_request(pdu, res)
        if pdu.ptype in (PTYPE_RESPONSE, PTYPE_FAULT, PTYPE_REJECT) and pdu.request is not None \
                and not pdu.retransmission:
            call = self._calls.pop(pdu.request.frame, None)
            if call is None:
                return None
            if call.kind == "cut":
                return self._cut_write_response(pdu, call, res, closed)
            if call.kind == "write":
                return self._write_response(pdu, call, res, closed)
            return self._read_response(pdu, call, res, closed)
        return None

    # --- writes -----------------------------------------------------------------------------
    def _write_request(self, pdu: Pdu, res: FrameResult, closed: list[Transaction]) -> Transaction | None:
        stub = pdu.stub
        if stub is None:
            return None
        opened: list[Transaction | None] = []
        for block in stub.blocks:
            if block.layout is not rec.WRITE_REQ or block.index == INDEX_WRITE_MULTIPLE:
                continue
            if block.index not in PROFIDRIVE_INDICES or (block.pd is None and len(block.record) == block.record_len):
                opened.append(None)  # not PROFIdrive (or index 0x002F that is not): no transaction
                continue
            opened.append(self._open(pdu, block, res, closed, len(opened)))
        if not any(opened):
            if pdu.malformed and not stub.blocks and not pdu.retransmission:
                # cut before its IOD header was complete (snaplen, damage): the index is unknown until the
                # response, paired by activity and sequence number, names it (protocol.md 7.3 step 1)
                self._remember(pdu.frame, _Call("cut", [], None, pdu))
            return None
        self._remember(pdu.frame, _Call("write", opened))
        return next(t for t in opened if t is not None)

    def _open(self, pdu: Pdu, block: rec.Block, res: FrameResult, closed: list[Transaction],
              position: int = 0) -> Transaction:
        v = block.values
        channel = (pdu.dst, pdu.src, v[rec.B_AR], v[rec.B_API], v[rec.B_SLOT], v[rec.B_SUBSLOT], v[rec.B_INDEX])
        parsed = block.pd[0] if isinstance(block.pd, tuple) else None
        txn = self._new(pdu, channel, parsed, pdu.frame, position)
        record = block.record
        if len(record) >= 4:
            txn.ref, txn.req_id, txn.do, txn.n_params = record[0], record[1], record[2], record[3]
        txn.malformed = pdu.malformed or parsed is None or not parsed.complete
        if writes_values(parsed):  # what the change replaces, known before it
            txn.values_before = [[self.read_values.get(k) for k in elements(txn, addr)] for addr in parsed.addresses]
        self._admit(txn, pdu.frame, closed)
        return txn

    def _new(self, pdu: Pdu, channel: Channel, parsed: object, opened_at: int, position: int) -> Transaction:
        """A transaction of the write request `pdu`, numbered at the frame that opens it (`opened_at`: the
        request's, or a cut request's response)."""
        first = pdu.fragments[0] if pdu.fragments else pdu.frame  # timed at its first frame (7.6)
        start = pdu.first_ts if pdu.first_ts is not None else pdu.ts
        if self.number_of is not None:
            number = self.number_of(opened_at, position)
        else:
            number = self._next
            self._next += 1
        txn = Transaction(number, channel, parsed, first, start)  # type: ignore[arg-type]
        txn.frames.extend(pdu.fragments)
        txn.rpc_calls.append(pdu.request)
        return txn

    def _admit(self, txn: Transaction, frame: int, closed: list[Transaction]) -> None:
        """A new transaction becomes its channel's pending one: T3 on a pending one, T1/T4, the caps."""
        channel = txn.channel
        old = self._pending.get(channel)
        if old is not None:
            txn.findings.append(superseded_finding(txn.ref, old.write_req_frame, old.ref, frame))
            closed.append(self._close(old, "superseded"))
        last = self._last_done.get(channel)
        if last is not None:
            reuse = reuse_finding(last, txn.ref, frame)
            if reuse is not None:
                txn.findings.append(reuse)
        self._pending.put(channel, txn, _cost(txn))
        self._by_ar.setdefault(_fallback_key(channel), OrderedDict())[channel] = txn
        while len(self._pending) > 1 and self._pending.full():
            oldest = self._pending.oldest()
            closed.append(self._evict(oldest, frame, "transaction table full"))

    def _cut_write_response(self, pdu: Pdu, call: _Call, res: FrameResult,
                            closed: list[Transaction]) -> Transaction | None:
        """The answer to a write cut before its IOD header was complete: when it names a PROFIdrive index
        (a single write, not 0xE040), the transaction opens at the request's frame with what could be read
        of it (nothing of its record): malformed, and its reads pair with it as usual (protocol.md 7.3
        step 1). Numbered here, at the answer (the frame that opens it)."""
        req = call.request
        stub = pdu.stub
        block = stub.blocks[0] if stub is not None and stub.blocks else None
        if req is None or pdu.ptype != PTYPE_RESPONSE or block is None or block.layout is not rec.WRITE_RES \
                or block.index not in PROFIDRIVE_INDICES:
            return None
        v = block.values
        channel = (pdu.src, pdu.dst, v[rec.B_AR], v[rec.B_API], v[rec.B_SLOT], v[rec.B_SUBSLOT], v[rec.B_INDEX])
        txn = self._new(req, channel, None, pdu.frame, 0)
        txn.malformed = True  # the record is cut (H5/R1 on the request's frame)
        if req.frame not in txn.frames:
            txn.frames.append(req.frame)
        self._admit(txn, req.frame, closed)
        return self._write_response(pdu, _Call("write", [txn]), res, closed)

    def _write_response(self, pdu: Pdu, call: _Call, res: FrameResult,
                        closed: list[Transaction]) -> Transaction | None:
        statuses = _write_statuses(pdu, len(call.txns))
        first = None
        for txn, status in zip(call.txns, statuses, strict=False):
            if txn is None or txn.closed_by:
                continue
            first = first or txn
            txn.write_res_frame = pdu.frame
            txn.t_write_res = pdu.ts
            txn.malformed |= pdu.malformed
            if pdu.ptype in (PTYPE_FAULT, PTYPE_REJECT):
                txn.pnio_status = f"{pdu.fault_status or 0:08X}"
                closed.append(self._close(txn, "pnio_error"))
            elif status is not None and not status.ok:
                txn.pnio_status = status.text()
                closed.append(self._close(txn, "pnio_error"))
        return first

    # --- reads ------------------------------------------------------------------------------
    def _read_request(self, pdu: Pdu, res: FrameResult) -> Transaction | None:
        stub = pdu.stub
        if stub is None or not stub.blocks or stub.blocks[0].index not in PROFIDRIVE_INDICES:
            return None
        block = stub.blocks[0]
        v = block.values
        ar = block.target_ar if v[rec.B_AR] == rec.NIL_UUID and block.target_ar else v[rec.B_AR]
        channel = (pdu.dst, pdu.src, ar, v[rec.B_API], v[rec.B_SLOT], v[rec.B_SUBSLOT], v[rec.B_INDEX])
        txn = self._pending.get(channel)
        if txn is None:
            # the oldest pending on the same index: a read never fetches another index's response (7.2)
            txn = next(iter(self._by_ar.get(_fallback_key(channel), {}).values()), None)
            if txn is not None and not txn.fallback:
                txn.fallback = True
                txn.findings.append(finding(
                    "fallback_pairing", pdu.frame, "iod.index", f"{v[rec.B_SLOT]}/{v[rec.B_SUBSLOT]}/"
                    f"{v[rec.B_INDEX]:#06x}", f"{txn.channel[4]}/{txn.channel[5]}/{txn.channel[6]:#06x}",
                    f"read addressed differently from the write of frame {txn.write_req_frame} (paired by device, "
                    "controller, AR and index)"))
        if txn is None:
            self.loose.append(finding("read_without_request", pdu.frame, "iod.index", f"{v[rec.B_INDEX]:#06x}",
                                      "a pending parameter request", "read on a PROFIdrive index with no "
                                                                     "pending write on the channel"))
            self._remember(pdu.frame, _Call("read", [None], channel))
            return None
        txn.read_req_frames.append(pdu.fragments[0] if pdu.fragments else pdu.frame)
        txn.t_read_reqs.append(pdu.first_ts if pdu.first_ts is not None else pdu.ts)
        txn.frames.extend(pdu.fragments)
        txn.rpc_calls.append(pdu.request)
        self._remember(pdu.frame, _Call("read", [txn], channel))
        return txn

    def _read_response(self, pdu: Pdu, call: _Call, res: FrameResult,
                       closed: list[Transaction]) -> Transaction | None:
        txn = call.txns[0]
        if txn is None or txn.closed_by:
            return None
        txn.malformed |= pdu.malformed
        if pdu.ptype in (PTYPE_FAULT, PTYPE_REJECT):
            txn.pnio_status = f"{pdu.fault_status or 0:08X}"
            txn.read_res_frame, txn.t_read_res = pdu.frame, pdu.ts
            closed.append(self._close(txn, "pnio_error"))
            return txn
        status = pdu.stub.status if pdu.stub is not None else None
        if status is not None and not status.ok:
            if status.code1 == PNIORW_STATE_CONFLICT and status.decode == 0x80:
                txn.b5_retries += 1
                txn.last_b5_res = pdu.ts
                if txn.b5_retries == self.b5_threshold + 1:
                    txn.findings.append(b5_finding(txn.b5_retries, self.b5_threshold, pdu.frame))
                return txn
            txn.pnio_status = status.text()
            txn.read_res_frame, txn.t_read_res = pdu.frame, pdu.ts
            closed.append(self._close(txn, "pnio_error"))
            return txn
        txn.read_res_frame, txn.t_read_res = pdu.frame, pdu.ts
        block = next((b for b in (pdu.stub.blocks if pdu.stub else []) if b.index in PROFIDRIVE_INDICES), None)
        parsed = block.pd[0] if block is not None and isinstance(block.pd, tuple) else None
        txn.response = parsed
        if parsed is None or not parsed.complete:
            txn.malformed = True
        else:
            found, mismatch = mirroring_findings(txn.ref, txn.req_id, txn.do, txn.n_params, parsed, pdu.frame,
                                                 vendor_answers(txn.request))
            txn.findings += found
            txn.mismatch |= mismatch
        closed.append(self._close(txn, "response"))
        return txn

    def _retransmitted(self, pdu: Pdu) -> Transaction | None:
        call = self._calls.get(pdu.request.frame) if pdu.request is not None else None
        if call is None:
            return None
        return next((t for t in call.txns if t is not None), None)

    # --- closing ----------------------------------------------------------------------------
    def _evict(self, txn: Transaction, frame: int, why: str) -> Transaction:
        """Close a pending transaction the caps cannot hold any longer: a timeout, closed_by "evicted"."""
        self._pending.evict(txn.channel, frame)  # counted; each evicted transaction is a row with its finding
        txn.findings.append(finding(PENDING_TRANSACTIONS.rule, frame, "pd.ref", txn.ref,
                                    f"{PENDING_TRANSACTIONS.text()}, {TXN_FRAMES} frames each",
                                    f"{why}: the transaction of frame {txn.write_req_frame} ends as a timeout"))
        return self._close(txn, "evicted")

    def _close(self, txn: Transaction, why: str) -> Transaction:
        channel = txn.channel
        if self._pending.get(channel) is txn:
            self._pending.pop(channel)
        same_ar = self._by_ar.get(_fallback_key(channel))
        if same_ar is not None and same_ar.get(channel) is txn:  # it was pending (and maybe evicted just now)
            del same_ar[channel]
            if not same_ar:
                del self._by_ar[_fallback_key(channel)]
            self._forget_calls(txn)
        txn.closed_by = why
        txn.verdict = verdict_of(txn)
        # copies seen so far, of answered and unanswered calls alike (protocol.md 7.6)
        txn.rpc_retransmissions = sum(c.copies for c in txn.rpc_calls if c is not None)
        if why in UNANSWERED_ENDS and not txn.pnio_status and txn.b5_retries:
            txn.pnio_status = f"DE80{PNIORW_STATE_CONFLICT:02X}00"  # last answer was B5 (txn.last_status)
        # not the transaction itself: it is handed on
        self._last_done.remember(channel, LastDone(txn.write_req_frame, txn.ref, txn.verdict))
        for key, value in elements_read(txn):
            self.read_values.remember(key, value)
        return txn

    def _forget_calls(self, txn: Transaction) -> None:
        """A closed transaction's calls need no state: a late answer to them belongs to no transaction."""
        for frame in txn.frames:  # its requests' frames among them (a reassembled one: the completing frame)
            call = self._calls.get(frame)
            if call is not None and all(t is None or t is txn or t.closed_by for t in call.txns):
                self._calls.pop(frame)

    def _remember(self, frame: int, call: _Call) -> None:
        self._calls.remember(frame, call)  # the oldest are forgotten


def _fallback_key(channel: Channel) -> tuple:
    """Device, controller, AR and index: what a read must share with a write addressed differently
    (protocol.md 7.2; slot and subslot may differ, the index may not)."""
    return channel[0], channel[1], channel[2], channel[6]


def _write_statuses(pdu: Pdu, count: int) -> list[Status | None]:
    """The status per PROFIdrive write of the call: the inner block status in a Write-Multiple."""
    stub = pdu.stub
    if stub is None:
        return [None] * count
    if len(stub.blocks) > 1:
        inner = [b.status for b in stub.blocks[1:]]
        if stub.status is not None and not stub.status.ok and not any(s and not s.ok for s in inner):
            return [stub.status] * count  # the whole Write-Multiple failed
        return inner
    status = stub.status if stub.status is not None and not stub.status.ok else (
        stub.blocks[0].status if stub.blocks else stub.status)
    return [status] * count


def iter_closed(engine: TransactionEngine, results: Iterator[FrameResult], last: list[float]) -> Iterator[Transaction]:
    """Feed frame results through the engine; yields transactions as they close (then at the end)."""
    for res in results:
        last[0] = max(last[0], res.ts)
        yield from engine.feed(res)
    yield from engine.finish(last[0])
