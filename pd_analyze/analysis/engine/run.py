"""The capture loop: batch by batch, decode (analysis.engine.decode), take the ordinary calls and
transactions whole as vector expressions (vector; what of a part it may take: take), run the compact loop
over every other row (calls, machine), settle what needs them all (finals), make the findings the columns
leave to the reference's code (findings), number the transactions opened, hand the closed ones' rows on
(tables), carry what is still open.

Every capture takes this one way, whatever its size; a capture is one stream of frames through one
pairing and one machine, so no frame, channel or batch ever changes path.
"""

from __future__ import annotations

import heapq
from collections import Counter
from collections.abc import Callable, Iterable

import numpy as np

from pd_analyze.analysis.capture_run import CaptureResult, Progress, Settings, error_text
from pd_analyze.analysis.engine.allocator import give_back
from pd_analyze.analysis.engine.calls import Pairing, part_done
from pd_analyze.analysis.engine.checks import FrameChecks
from pd_analyze.analysis.engine.collector import spaced_collections
from pd_analyze.analysis.engine.decode import Decoded, Decoder, merge_accounting, skipped_decide
from pd_analyze.analysis.engine.facts import Channel, Pdu
from pd_analyze.analysis.engine.finals import Finals
from pd_analyze.analysis.engine.findings import Findings, response_channel, response_channels, write_names
from pd_analyze.analysis.engine.late import LateCopies
from pd_analyze.analysis.engine.machine import FsmCall, Machine
from pd_analyze.analysis.engine.numbering import Numbering
from pd_analyze.analysis.engine.records import PACKED_ADDRESS, Records, unpacked
from pd_analyze.analysis.engine.tables import TableBuilder
from pd_analyze.analysis.engine.take import EMPTY, Costs, VectorTake, given_back
from pd_analyze.analysis.engine.txn import Txn
from pd_analyze.analysis.engine.txncols import TxnCols, of_episodes
from pd_analyze.analysis.engine.vector import Calls, Episodes
from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.analysis.rows import Rows
from pd_analyze.analysis.schema import capture_text
from pd_analyze.analysis.stations import names_in_batch
from pd_analyze.capture import CaptureError
from pd_analyze.capture.batches import BATCH_FRAMES, FrameBatch, frame_batches
from pd_analyze.capture.raw import RawFrame
from pd_analyze.model.capped import CHANNEL_REQUESTS, CappedTable
from pd_analyze.model.values import PTYPE_FAULT, PTYPE_REJECT, PTYPE_REQUEST, PTYPE_RESPONSE
from pd_analyze.protocol import rpc
from pd_analyze.protocol.dissector import Dissector, truncated_elsewhere
from pd_analyze.protocol.frames import Accounting

_NEVER = -(1 << 62)
_ANSWERS = (PTYPE_RESPONSE, PTYPE_FAULT, PTYPE_REJECT)  # what answers a call (the dump links it to its request)


class EngineRun:
    """One capture (or a chain of files read as one) analysed a batch at a time."""

    def __init__(self, settings: Settings, rows: Rows, capture_of: Callable[[int], str],
                 results: list[CaptureResult], progress: Progress | None = None, offset: int = 0) -> None:
        self.settings = settings
        checker = settings.checker()
        self.decoder = Decoder(Dissector(annotate=False, rpc_timeout=settings.rpc_timeout, checker=checker,
                                         pairing=False))
        self.pairing = Pairing(settings.rpc_timeout)
        self.machine = Machine(settings.txn_timeout)
        self.findings = Findings(FrameChecks(checker, settings.rpc_timeout))
        self.finals = Finals()
        self.tables = TableBuilder(checker)
        self.rows = rows
        rows.use_names(checker.names)  # the rows name parameters and errors as the run's profile does
        self.capture_of = lambda frame: capture_text(capture_of(frame))  # (a name every table format holds)
        self.results = results
        self.progress = progress
        self.offset = offset
        self.vector = settings.vector
        self.accounting = Accounting()  # the frames the columns took; the dissector counts its own
        self.numbering = Numbering()
        self.late = LateCopies(self.pairing.timeout)
        self.now_all = _NEVER  # the latest capture time of any frame (ns)
        self.now_pnio = _NEVER  # the latest capture time of a PNIO RPC frame but those whose PNIO-ness the
        # loop decides (ns); with them: machine.now
        self.part = 0
        self.last_frame = 0
        # each channel's last parameter request's addresses, as Q7 compares a read response with them (6.4)
        self.last_request: CappedTable[tuple, object] = CappedTable(CHANNEL_REQUESTS)
        self.costs = Costs.of(checker.record)
        self.take = VectorTake(self.vector, self.pairing, self.machine, self.numbering, self.costs)

    # --- the loop -----------------------------------------------------------------------------------
    def feed(self, batch: FrameBatch, views: list[tuple[FrameBatch, BatchView]] | None = None) -> None:
        """The next batch of frames; `views`: its column decode made elsewhere (`BatchView.parts` of the
        batch in another process: analysis.split), or None to make it here."""
        if not len(batch):
            return
        self.last_frame = int(batch.number[-1])
        for result in self.results:  # (a chain is one capture: its files' rows are written at its finest)
            self.rows.note_digits(capture_text(result.path), batch.digits)
        for decoded in self.decoder.parts(batch, views):
            self._part(decoded)
            del decoded  # (the next part's decode does not wait for this one's memory)
        if self.results:  # (the file being read: a chain appends each file's result before its batches)
            names_in_batch(batch, self.results[-1].stations)
        if self.progress is not None and self.results:
            self.progress(self.results[-1].path, self.read)

    @property
    def read(self) -> int:
        return self.accounting.read + self.decoder.accounting.read

    def _part(self, dec: Decoded) -> None:
        self.part += 1
        merge_accounting(self.accounting, dec.accounting)
        view, batch = dec.view, dec.batch
        p = view.p
        records = Records(view)
        self.machine.records = records
        self.machine.names_of = lambda row: write_names(view, row)
        for row in dec.odd_rows:
            row.part = self.part
        # the capture time reached at each frame: over every frame (calls expire on it), and over the
        # PNIO frames (transactions' deadlines) but the rows the loop may still find are not PNIO
        runmax_all = np.maximum.accumulate(np.maximum(batch.ns, self.now_all))
        pnio_ns = np.full(len(batch), _NEVER, np.int64)
        pnio_ns[p.pos[dec.rows]] = batch.ns[p.pos[dec.rows]]
        decide_ns = pnio_ns.copy()
        odd_pos = np.searchsorted(batch.number, np.fromiter((r.frame for r in dec.odd_rows), np.int64,
                                                            len(dec.odd_rows)))
        for row, at in zip(dec.odd_rows, odd_pos.tolist(), strict=True):
            (decide_ns if row.decide else pnio_ns)[at] = row.ts
        runmax_pnio = np.maximum.accumulate(np.maximum(pnio_ns, self.now_pnio))
        static_pnio = np.maximum.accumulate(np.maximum(np.maximum(pnio_ns, decide_ns), self.now_pnio))
        calls, ep = self.take.part(dec, runmax_all, static_pnio)
        taken = np.zeros(len(p.pos), bool)
        taken[calls.q] = True
        taken[calls.s] = True
        loop_cols = dec.rows[~taken[dec.rows]]
        stream = _merged(self.decoder.column_pdus(batch, view, loop_cols), dec.odd_rows)
        for row in stream:
            row.part = self.part
            if row.col >= 0 and row.col in dec.dropped:
                row.findings += dec.dropped[row.col]
        accepted, rejected, marked = self._loop(dec, stream, calls, ep, runmax_all, runmax_pnio)
        self.numbering.note_cuts(accepted)
        late: dict[int, int] = {}  # a copy of a call whose transaction's rows were made already: its number
        for row in accepted:
            if row.copy and row.owner is None and row.call is not None:
                number = self.late.copy(row.call.frame, row.frames or (row.frame,), row.resent)
                if number is not None:
                    late[id(row)] = number
        self.now_all = max(self.now_all, int(runmax_all[-1]))
        self.now_pnio = max(self.now_pnio, int(runmax_pnio[-1]))
        self.pairing.tick(self.now_all)
        keep = np.ones(len(ep.w), bool)
        keep[rejected] = False
        self._last_requests(view, calls, ep, keep & ~marked, records)
        done_calls, ep = given_back(calls, ep, keep)
        self._calls_paired(view, done_calls, accepted)
        cols = of_episodes(view, done_calls, ep) if len(ep.w) else None
        result = self.results[-1]
        result.vector_pdus += 2 * len(done_calls.q)
        result.column_pdus += len(dec.rows)
        result.pnio_pdus += len(dec.rows) + sum(1 for r in dec.odd_rows if not r.decide)
        self.take.remember_calls(view, done_calls)
        self.pairing.order_activities(self.take.first)
        self.take.first = {}
        loose = self.findings.vector(dec, done_calls, ep, cols, records)
        loose += self.findings.loop(dec, accepted, self.part)
        for row in accepted:
            if row.findings:
                number = late.get(id(row)) if late else None
                if number is not None:  # its findings are its transaction's, as those of a copy met before
                    for f in row.findings:
                        self.rows.add_finding(self.capture_of(f.frame), f, number)
                else:
                    (row.owner.findings if row.owner is not None else loose).extend(row.findings)
            # what a call still open keeps of its request's row: its frames and times (no findings, no
            # records: those went to the transaction), so open calls cost what the caps count
            row.findings, row.q7, row.owner, row.writes, row.read, row.answer = [], None, None, None, None, None
        loose += self.decoder.loose() + self.pairing.loose + self.machine.loose
        self.pairing.loose.clear()
        self.machine.loose.clear()
        for f in loose:
            self.rows.add_finding(self.capture_of(f.frame), f)
        self._settle(view, records, cols)
        self._close_part(view, batch, records, accepted)

    def _calls_paired(self, view: BatchView, calls: Calls, accepted: list[Pdu]) -> None:
        """The part's paired calls (the vector path's and the loop's) and the PDUs the loop took as PNIO by
        their call, to `rows.add_calls` (the dump's links)."""
        answered = [(row.call.frame, row.frame) for row in accepted
                    if row.call is not None and not row.copy and row.whole and row.ptype in _ANSWERS]
        loop = np.array(answered, np.int64).reshape(-1, 2)
        self.rows.add_calls(np.concatenate([view.frame_no[calls.q], loop[:, 0]]),
                            np.concatenate([view.frame_no[calls.s], loop[:, 1]]),
                            [row.frame for row in accepted if row.decide])

    # --- the vector path -------------------------------------------------------------------------------
    def _loop(self, dec: Decoded, stream: list[Pdu], calls: Calls, ep: Episodes, runmax_all: np.ndarray,
              runmax_pnio: np.ndarray) -> tuple[list[Pdu], list[int], np.ndarray]:
        """The loop over the part's other rows in frame order, the first frames of the episodes on a channel
        the loop has rows of among them: an episode whose channel has a transaction of the loop pending there
        is given back to the loop."""
        batch, view = dec.batch, dec.view
        pairing, machine, records = self.pairing, self.machine, self.machine.records
        last_request = self.last_request
        first = self.take.first  # activities the vector path's rows make known, at their first frames
        channels = response_channels(view, stream)  # (the stream's rows stay alive: their ids are theirs)
        marks = self._marks(view, calls, ep, stream, channels)
        marked = np.zeros(len(ep.w), bool)
        marked[marks] = True
        mark_frames = view.frame_no[calls.q[ep.w[marks]]] if len(marks) else EMPTY
        # each marked episode's channel and write request record
        marked_at = dict(zip(marks, zip([ep.channels[c] for c in ep.channel[marks].tolist()],
                                        view.rec_of[calls.q[ep.w[marks]]].tolist(), strict=True), strict=True)) \
            if len(marks) else {}
        request_cost = self.costs.request
        items: list = [*stream, *marks]
        frames = np.concatenate([np.fromiter((r.frame for r in stream), np.int64, len(stream)), mark_frames])
        # (at one frame an episode's marker before... a frame is one PDU: a marker's frame is its write's)
        order = np.argsort(frames, kind="stable")
        at = np.searchsorted(batch.number, frames)
        now_all, now_pnio_at = runmax_all[at].tolist(), runmax_pnio[at].tolist()
        heap: list[tuple[int, int, int, int, object]] = []  # rows given back: (frame, seq, now_all, now_pnio, row)
        seq = len(items)
        accepted: list[Pdu] = []
        rejected: list[int] = []
        decided = _NEVER  # the latest time of a row the loop took as PNIO though its interface is not
        pending = list(order.tolist())
        pending.reverse()
        while pending or heap:
            if heap and (not pending or heap[0][0] < frames[pending[-1]]):
                _frame, _seq, row_now_all, row_now_pnio, item = heapq.heappop(heap)
            else:
                index = pending.pop()
                item, row_now_all, row_now_pnio = items[index], now_all[index], now_pnio_at[index]
            now_pnio = max(row_now_pnio, decided)
            if isinstance(item, int):  # an episode begins on a channel the loop has rows of
                k = item
                machine.advance(now_pnio)
                channel, record = marked_at[k]
                if machine.pending.get(channel) is not None:
                    rejected.append(k)
                    for row in self._episode_rows(dec, calls, ep, k):
                        seq += 1
                        at_row = int(np.searchsorted(batch.number, row.frame))
                        heapq.heappush(heap, (row.frame, seq, int(runmax_all[at_row]), int(runmax_pnio[at_row]), row))
                else:
                    last_request.remember(channel, record, request_cost)
                continue
            row = item
            pairing.tick(row_now_all)
            if row.decide:
                if not pairing.pnio(row, first):
                    skipped_decide(self.decoder.accounting, row.raw, rpc.SKIP_NOT_PNIO)
                    if row.raw.truncated:
                        self.rows.add_finding(self.capture_of(row.frame), truncated_elsewhere(row.frame))
                    continue
                decided = max(decided, row.ts)
                now_pnio = max(now_pnio, row.ts)
            pairing.pair(row)
            if row.call is not None and row.ptype == PTYPE_RESPONSE and row.call.opnum != row.opnum and not row.frames:
                row = self.findings.redecoded(row, batch, row.call.opnum, self.decoder)
            if row.whole and row.ptype == PTYPE_REQUEST:
                for w in row.writes or ():
                    if w is not None and w.record is not None:
                        last_request.remember(w.channel, w.record, self.costs.request)
            elif row.whole and row.ptype == PTYPE_RESPONSE and row.answer is not None and row.answer.head is not None:
                request = last_request.get(channels[id(row)] if id(row) in channels else response_channel(view, row))
                row.q7 = self.findings.q7(row, view, records, None if request is None else
                                          unpacked(request) if isinstance(request, bytes)
                                          else tuple(records.addresses(request)))
            row.owner = machine.feed(row, now_pnio)
            accepted.append(row)
        self.now_pnio = max(self.now_pnio, decided)
        machine.advance(max(int(runmax_pnio[-1]), decided))  # (the rows the vector path took passed too)
        return accepted, rejected, marked

    def _last_requests(self, view: object, calls: Calls, ep: Episodes, unmarked: np.ndarray,
                       records: Records) -> None:
        """The channels' last parameter requests after the part: the episodes the loop did not meet (on
        channels it had no row of: nothing of the loop came after them), then every request of the part
        kept as its addresses (the part's records go)."""
        last = self.last_request
        for k in np.flatnonzero(unmarked).tolist():  # (per channel in frame order: a later write replaces)
            last.remember(ep.channels[int(ep.channel[k])], int(view.rec_of[calls.q[ep.w[k]]]), self.costs.request)  # type: ignore[attr-defined]
        for channel, request in list(last.items()):
            if not isinstance(request, bytes):
                packed = records.packed(request)
                last.put(channel, packed, 64 + 72 * (len(packed) // PACKED_ADDRESS))  # (charged as tuples)

    def _marks(self, view: object, calls: Calls, ep: Episodes, stream: list[Pdu],
               channels: dict[int, Channel | None]) -> list[int]:
        """The episodes on a channel the loop has rows of in the part, or a transaction pending on: the loop
        meets their first frames (a transaction of its own may still be pending there; and the channel's last
        parameter request must be known in frame order for its reads' Q7)."""
        if not len(ep.w):
            return []
        mine = {t.channel for t in self.machine.pending.values()}
        p = view.p  # type: ignore[attr-defined]
        for row in stream:
            for w in row.writes or ():
                if w is not None:
                    mine.add(w.channel)
            if row.read is not None:
                mine.add(row.read)
        for row in stream:
            if row.ptype == PTYPE_RESPONSE and row.answer is not None and (row.odd or p.has_block[row.col]):
                named = channels[id(row)]
                if named is not None:
                    mine.add(named)
        if not mine:
            return []
        ids = {channel: k for k, channel in enumerate(ep.channels)}
        wanted = np.fromiter((ids[c] for c in mine if c in ids), np.int64)
        return np.flatnonzero(np.isin(ep.channel, wanted)).tolist()

    def _episode_rows(self, dec: Decoded, calls: Calls, ep: Episodes, k: int) -> list[Pdu]:
        """An episode given back to the loop: its rows."""
        idx = [int(ep.w[k])] + ep.reads[ep.first_read[k]:ep.first_read[k] + ep.n_reads[k]].tolist()
        cols = np.sort(np.concatenate([calls.q[idx], calls.s[idx]]))
        rows = self.decoder.column_pdus(dec.batch, dec.view, cols)
        for row in rows:
            row.part = self.part
        return rows

    def _settle(self, view: object, records: Records, cols: TxnCols | None) -> None:
        """T1/T4 and the values read and replaced, over the transactions of both ways, then the numbers."""
        machine = self.machine
        self.finals.apply(machine.opened, machine.closed, cols, view, records)  # type: ignore[arg-type]
        if cols is not None:
            for k in [k for k, v in cols.findings.items() if not v]:
                del cols.findings[k]
        # numbers in the order the transactions opened, whichever way they went
        self.numbering.number(machine.opened, cols, self.numbering.barrier(self.pairing))
        machine.opened.clear()
        self._episodes = cols

    def _close_part(self, view: object, batch: FrameBatch, records: Records, accepted: list[Pdu]) -> None:
        """Hand on what closed, carry what stays open past the part."""
        machine = self.machine
        done, machine.closed = machine.closed, []
        self._emit(view, self.numbering.ready(done, records), self._episodes)
        self._episodes = None
        for txn in machine.pending.values():
            if isinstance(txn.request, int):
                txn.request = records.carried(txn.request)
        part_done(accepted, lambda row: batch.raw_frame(int(view.p.pos[row.col])))  # type: ignore[attr-defined]
        self.machine.part_done()
        self.finals.settle()
        self.rows.batch_done()

    def _emit(self, view: object, done: list[Txn], cols: TxnCols | None = None) -> None:
        if not done and cols is None:
            return
        done.sort(key=lambda t: t.number)  # (in number order, whichever way and batch they closed in)
        for t in done:
            _handed_on(t)
        slices = self.tables.tables(view, done, self.capture_of, self.offset, cols)  # type: ignore[arg-type]
        for k, (txns, part, made) in enumerate(slices):
            if k:  # the slice before's memory, as a batch's (the batch's own give_back follows the last)
                give_back()
            self.late.hold(made, txns, part, self.offset, self.now_all)
            self._hand_on(self.late.release(self.now_all))
        frames = np.fromiter((t.write_frame for t in done), np.int64, len(done))
        self._count(np.concatenate([frames, cols.write_frame]) if cols is not None else frames)

    def _hand_on(self, released: list[dict]) -> None:
        for made in released:
            for name, tables in made.items():
                for table in tables:
                    self.rows.add_table(name, table)

    def finish(self) -> None:
        """End of capture: what the dissector held, the calls never answered, every pending transaction."""
        rows, loose = self.decoder.finish(self.last_frame)
        for row in rows:  # (a dissector without a hold releases none)
            loose += row.findings
        self.pairing.finish()
        self.machine.finish(max(self.machine.now, self.now_pnio))
        loose += self.pairing.loose + self.machine.loose
        for f in loose:
            self.rows.add_finding(self.capture_of(f.frame), f)
        self.numbering.number([], None, None)  # (no call is open any more: every number is known)
        done, self.machine.closed = self.machine.closed, []
        self._emit(None, self.numbering.ready(done, Records(None)))
        self._hand_on(self.late.release(self.now_all, everything=True))
        self.rows.batch_done()

    def totals(self) -> Accounting:
        """Every frame read, counted once: the columns' and the per-frame dissector's."""
        out = Accounting()
        merge_accounting(out, self.accounting)
        merge_accounting(out, self.decoder.accounting)
        return out

    def _count(self, frames: np.ndarray) -> None:
        """Transactions more, by their write request frames, of the captures they are in."""
        if len(frames):  # (a chain's files hold consecutive frames: one capture holds all when it holds both ends)
            first, last = self.capture_of(int(frames.min())), self.capture_of(int(frames.max()))
            names = {first: len(frames)} if first == last else Counter(map(self.capture_of, frames.tolist()))
            for name, n in names.items():  # (schema.capture_text of a path)
                next(r for r in self.results if capture_text(r.path) == name).transactions += n


def _handed_on(txn: Txn) -> None:
    """A transaction whose rows are made: its retransmissions counted, its calls no longer lead to it (a later
    copy is engine.late's)."""
    txn.retransmissions = sum(c.copies for c in txn.calls if c is not None)
    for c in txn.calls:
        fsm = c.fsm if c is not None else None
        if isinstance(fsm, FsmCall) and all(t is None or t.closed_by for t in fsm.txns):
            c.fsm = None


def _merged(columns: list[Pdu], odd: list[Pdu]) -> list[Pdu]:
    if not odd:
        return columns
    if not columns:
        return list(odd)
    out = columns + odd
    out.sort(key=lambda row: row.frame)  # (stable: a frame is in one list only)
    return out


def run_batches(source: Iterable[FrameBatch] | Iterable[tuple[FrameBatch, list[tuple[FrameBatch, BatchView]]]],
                settings: Settings, rows: Rows, capture_of: Callable[[int], str], results: list[CaptureResult],
                progress: Progress | None, offset: int = 0) -> Accounting:
    """The loop over batches (or batches with their column decode made elsewhere: analysis.split); the
    frames' accounting when done (also after a CaptureError, which is recorded in the last result)."""
    with spaced_collections():
        run = EngineRun(settings, rows, capture_of, results, progress, offset)
        try:
            for item in source:
                run.feed(*(item if isinstance(item, tuple) else (item,)))
                give_back()  # (the batch's memory, freed now, back to the system: a flat peak)
        except CaptureError as exc:
            results[-1].error = error_text(exc)
        run.finish()
        return run.totals()


def analyze_frames(frames: Iterable[RawFrame], settings: Settings, rows: Rows, capture: str = "frames",
                   batch_frames: int = BATCH_FRAMES) -> CaptureResult:
    """Frames given one by one (a generator's, a fuzzer's: not a file) through the engine, as one capture."""
    result = CaptureResult(capture, Accounting())
    result.accounting = run_batches(frame_batches(frames, batch_frames), settings, rows, lambda _frame: capture,
                                    [result], None)
    return result

