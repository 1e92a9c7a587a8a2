"""The capture loop: batch by batch, decode (analysis.engine.decode), take the ordinary calls and
transactions whole as vector expressions (vector), run the compact loop over every other row (calls,
machine), settle what needs them all (finals), make the findings the columns leave to the reference's
code (findings), number the transactions opened, hand the closed ones' rows on (tables), carry what is
still open.

Every capture takes this one way, whatever its size; a capture is one stream of frames through one
pairing and one machine, so no frame, channel or batch ever changes path.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Iterable

import numpy as np

from pd_analyze.analysis.capture_run import CaptureResult, Progress, Settings, error_text
from pd_analyze.analysis.engine.calls import Pairing
from pd_analyze.analysis.engine.checks import FrameChecks
from pd_analyze.analysis.engine.decode import Decoded, Decoder, merge_accounting, skipped_decide
from pd_analyze.analysis.engine.facts import Pdu
from pd_analyze.analysis.engine.finals import Finals
from pd_analyze.analysis.engine.findings import Findings, response_channel, write_names
from pd_analyze.analysis.engine.late import LateCopies
from pd_analyze.analysis.engine.machine import FsmCall, Machine
from pd_analyze.analysis.engine.numbering import Numbering
from pd_analyze.analysis.engine.records import Records
from pd_analyze.analysis.engine.tables import TableBuilder
from pd_analyze.analysis.engine.txn import Txn
from pd_analyze.analysis.engine.txncols import TxnCols, of_episodes
from pd_analyze.analysis.engine.vector import Calls, Episodes, episodes, key_hash, pair, pair_key
from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.analysis.rows import Rows
from pd_analyze.analysis.schema import arrow_text
from pd_analyze.analysis.stations import names_in_batch
from pd_analyze.capture import CaptureError
from pd_analyze.capture.batches import BATCH_FRAMES, FrameBatch, frame_batches
from pd_analyze.capture.raw import RawFrame
from pd_analyze.model.capped import (
    CHANNEL_REQUESTS,
    KNOWN_ACTIVITIES,
    OPEN_CALLS,
    PENDING_TRANSACTIONS,
    TXN_CALLS,
    CappedTable,
)
from pd_analyze.model.values import PTYPE_REQUEST, PTYPE_RESPONSE
from pd_analyze.protocol import rpc
from pd_analyze.protocol.dissector import Dissector, truncated_elsewhere
from pd_analyze.protocol.frames import Accounting
from pd_analyze.protocol.rpc_calls import CALL_OVERHEAD

_NEVER = -(1 << 62)
_MARK = object()  # a marker in the loop's stream: the first frame of an episode the vector path took


class EngineRun:
    """One capture (or a chain of files read as one) analysed a batch at a time."""

    def __init__(self, settings: Settings, rows: Rows, capture_of: Callable[[int], str],
                 results: list[CaptureResult], progress: Progress | None = None, offset: int = 0,
                 as_rows: bool = False) -> None:
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
        self.capture_of = capture_of
        self.results = results
        self.progress = progress
        self.offset = offset
        # as_rows: a capture name Arrow cannot hold (schema.arrow_text): the loop alone, its transactions as
        # rows (Rows.add) rather than Arrow tables
        self.as_rows = as_rows
        self.vector = settings.vector and not as_rows
        self.accounting = Accounting()  # the frames the columns took; the dissector counts its own
        self.numbering = Numbering()
        self.late = LateCopies(self.pairing.timeout)
        self.now_all = _NEVER  # the latest capture time of any frame (ns)
        self.now_pnio = _NEVER  # the latest capture time of a PNIO RPC frame but those whose PNIO-ness the
        # loop decides (ns); with them: machine.now
        self.part = 0
        self.last_frame = 0
        # each channel's last parameter request's addresses, as Q7 compares a read response with them (6.4)
        self.last_request: CappedTable[tuple, tuple] = CappedTable(CHANNEL_REQUESTS)
        self._first: dict[tuple[int, int], int] = {}  # the part's activities first seen in column rows (_first_seen)
        self.taken = 0  # PNIO rows the vector path took whole
        self.pnio_rows = 0  # PNIO rows in all

    # --- the loop -----------------------------------------------------------------------------------
    def feed(self, batch: FrameBatch, views: list[tuple[FrameBatch, BatchView]] | None = None) -> None:
        """The next batch of frames; `views`: its column decode made elsewhere (`BatchView.parts` of the
        batch in another process: analysis.split), or None to make it here."""
        if not len(batch):
            return
        self.last_frame = int(batch.number[-1])
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
        calls, ep = self._vector(dec, runmax_all, static_pnio)
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
        for row in accepted:  # a copy of a call whose transaction's rows were made already
            if row.copy and row.owner is None and row.call is not None:
                number = self.late.copy(row.call.frame, row.frames or (row.frame,), row.ptype == PTYPE_REQUEST)
                if number is not None:  # its findings are its transaction's, as those of a copy met before
                    for f in row.findings:
                        self.rows.add_finding(self.capture_of(f.frame), f, number)
                    row.findings = []
        self.now_all = max(self.now_all, int(runmax_all[-1]))
        self.now_pnio = max(self.now_pnio, int(runmax_pnio[-1]))
        self.pairing.tick(self.now_all)
        keep = np.ones(len(ep.w), bool)
        keep[rejected] = False
        self._last_requests(view, calls, ep, keep & ~marked, records)
        done_calls, ep = _given_back(calls, ep, keep)
        cols = of_episodes(view, done_calls, ep) if len(ep.w) else None
        self.taken += 2 * len(done_calls.q)
        self.pnio_rows += len(dec.rows) + sum(1 for r in dec.odd_rows if not r.decide)
        self._remember_calls(view, done_calls)
        self.pairing.order_activities(self._first)
        self._first = {}
        loose = self.findings.vector(dec, done_calls, ep, cols, records)
        loose += self.findings.loop(dec, accepted, self.part)
        for row in accepted:
            if row.findings:
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

    # --- the vector path -------------------------------------------------------------------------------
    def _vector(self, dec: Decoded, runmax_all: np.ndarray, runmax_pnio: np.ndarray) -> tuple[Calls, Episodes]:
        """The calls and transactions of the part the vector path takes whole (none when it is off, or when
        the caps come near: then the loop's order of evictions decides, and it takes everything)."""
        view = dec.view
        p = view.p
        empty = np.empty(0, np.int64)
        none = Calls(empty, empty, np.empty(0, bool)), Episodes(empty, empty, empty, empty, empty, empty, empty,
                                                              empty, [])
        if not self.vector or not len(dec.rows) or self.numbering.waits(self.pairing, dec.odd_rows):
            return none
        # rows the loop has, or might have, a share in: their keys stay the loop's (an activity does not:
        # what the loop decides by activity, a PDU of another interface, it decides by the activities first
        # seen before it in frame order, `_first_seen`)
        excluded = np.zeros(len(dec.rows), bool)
        keys = {row.key for row in dec.odd_rows if row.key[0] or row.key[1]}
        rows = dec.rows
        if keys:
            hashes = key_hash(np.array([k[0] for k in keys], np.uint64), np.array([k[1] for k in keys], np.uint64),
                              np.array([k[2] for k in keys], np.uint32))
            excluded |= np.isin(key_hash(p.act_hi[rows], p.act_lo[rows], p.seq[rows]), hashes)
        if dec.dropped:
            excluded |= np.isin(rows, np.fromiter(dec.dropped, np.int64, len(dec.dropped)))
        pairing = self.pairing
        self._first = self._first_seen(view, rows)
        if len(pairing.activities) + len(self._first) >= KNOWN_ACTIVITIES.count:
            self._first = {}
            return none  # (the loop's order of evictions decides)
        known = _Known(pairing)
        runmax_pdu = runmax_all[p.pos]
        calls = pair(view, rows, runmax_pdu, pairing.timeout, excluded, known)
        if not len(calls.q):
            return none
        # the loop's rows between each drive and controller (odd rows, and the column rows not taken)
        taken = np.zeros(len(p.pos), bool)
        taken[calls.q] = True
        taken[calls.s] = True
        loop_cols = rows[~taken[rows]]
        static = runmax_pnio[p.pos]
        ep = _empty_episodes()
        frames_by_pair = _loop_frames(view, loop_cols, dec.odd_rows, None, calls)
        for _ in range(8):  # episodes refused add their rows to the loop's; until nothing changes
            ep = episodes(view, calls, frames_by_pair, static, self.machine.timeout, self.machine.b5_threshold)
            more = _loop_frames(view, loop_cols, dec.odd_rows, ep, calls)
            if all(np.array_equal(more.get(k, _E), v) for k, v in frames_by_pair.items()) and \
                    more.keys() == frames_by_pair.keys():
                break
            frames_by_pair = more
        else:  # (not settled: the loop takes every transaction of the part)
            ep = _empty_episodes()
        # PROFIdrive calls outside an episode are the loop's
        in_ep = np.zeros(len(calls.q), bool)
        in_ep[ep.w] = True
        in_ep[ep.reads] = True
        keep = ~calls.pd | in_ep
        out = Calls(calls.q[keep], calls.s[keep], calls.pd[keep])
        if self._near_caps(_most_at_once(view.frame_no[out.q], view.frame_no[out.s]),
                           _most_at_once(ep.start, ep.end)):
            return none
        index = np.full(len(calls.q), -1, np.int64)
        index[np.flatnonzero(keep)] = np.arange(int(keep.sum()))
        return out, Episodes(index[ep.w], index[ep.reads], ep.first_read, ep.n_reads, ep.channel, ep.group, ep.start,
                             ep.end, ep.channels)

    def _first_seen(self, view: BatchView, rows: np.ndarray) -> dict[tuple[int, int], int]:
        """The activities of the column `rows` (frame order) not known when the part begins: activity -> the
        frame of its first row."""
        p = view.p
        acts = np.stack([p.act_hi[rows], p.act_lo[rows]], axis=1)
        if not len(acts):
            return {}
        distinct, first = np.unique(acts, axis=0, return_index=True)
        known = self.pairing.activities
        frames = view.frame_no[rows[first]].tolist()
        return {act: frame for act, frame in zip(map(tuple, distinct.tolist()), frames, strict=True)
                if act not in known}

    def _near_caps(self, calls: int, transactions: int) -> bool:
        """Whether the loop's tables could reach a cap with the calls and transactions the vector path takes
        (at most `calls` and `transactions` of them open at once), where the order the loop meets rows in
        decides what is evicted: the loop then takes the part whole."""
        machine, pairing = self.machine, self.pairing
        return (len(machine.pending) + transactions >= PENDING_TRANSACTIONS.count
                or machine.pending.bytes + transactions * _PENDING_COST >= PENDING_TRANSACTIONS.bytes
                or len(pairing.open) + calls >= OPEN_CALLS.count
                or pairing.open.bytes + calls * _CALL_COST >= OPEN_CALLS.bytes
                or len(machine.calls_table()) + calls >= TXN_CALLS.count)

    def _loop(self, dec: Decoded, stream: list[Pdu], calls: Calls, ep: Episodes, runmax_all: np.ndarray,
              runmax_pnio: np.ndarray) -> tuple[list[Pdu], list[int], np.ndarray]:
        """The loop over the part's other rows in frame order, the first frames of the episodes on a channel
        the loop has rows of among them: an episode whose channel has a transaction of the loop pending there
        is given back to the loop."""
        batch, view = dec.batch, dec.view
        pairing, machine, records = self.pairing, self.machine, self.machine.records
        last_request = self.last_request
        first = self._first  # activities the vector path's rows make known, at their first frames
        marks = self._marks(view, calls, ep, stream)
        marked = np.zeros(len(ep.w), bool)
        marked[marks] = True
        mark_frames = view.frame_no[calls.q[ep.w[marks]]] if len(marks) else _E
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
                channel = ep.channels[int(ep.channel[k])]
                if machine.pending.get(channel) is not None:
                    rejected.append(k)
                    for row in self._episode_rows(dec, calls, ep, k):
                        seq += 1
                        at_row = int(np.searchsorted(batch.number, row.frame))
                        heapq.heappush(heap, (row.frame, seq, int(runmax_all[at_row]), int(runmax_pnio[at_row]), row))
                else:
                    last_request.remember(channel, int(view.rec_of[calls.q[ep.w[k]]]), _REQUEST_COST)
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
                        last_request.remember(w.channel, w.record, _REQUEST_COST)
            elif row.whole and row.ptype == PTYPE_RESPONSE and row.answer is not None and row.answer.head is not None:
                request = last_request.get(response_channel(view, row))
                row.q7 = self.findings.q7(row, view, records, None if request is None else
                                          tuple(records.addresses(request)) if not isinstance(request, tuple)
                                          else request)
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
            last.remember(ep.channels[int(ep.channel[k])], int(view.rec_of[calls.q[ep.w[k]]]), _REQUEST_COST)  # type: ignore[attr-defined]
        for channel, request in list(last.items()):
            if not isinstance(request, tuple):
                addresses = tuple(records.addresses(request))
                last.put(channel, addresses, 64 + 72 * len(addresses))

    def _marks(self, view: object, calls: Calls, ep: Episodes, stream: list[Pdu]) -> list[int]:
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
            if row.ptype == PTYPE_RESPONSE:
                named = response_channel(view, row) if row.answer is not None and (
                    row.odd or p.has_block[row.col]) else None  # type: ignore[arg-type]
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

    def _remember_calls(self, view: object, calls: Calls) -> None:
        """The calls the vector path took, answered: remembered rpc_timeout after the answer (a late copy is
        recognised by its key and body digest), their activities known."""
        if not len(calls.q):
            return
        import zlib

        p, ns, buf = view.p, view.batch.ns, memoryview(view.batch.buf)  # type: ignore[attr-defined]
        q, s = calls.q, calls.s
        start, length = p.body_start[q].astype(np.int64).tolist(), p.body_len[q].astype(np.int64).tolist()
        hi, lo = p.act_hi[q].tolist(), p.act_lo[q].tolist()
        keys = list(zip(hi, lo, p.seq[q].tolist(), strict=True))
        columns = {"frame": view.frame_no[q].tolist(), "ts": ns[p.pos[q]].tolist(),  # type: ignore[attr-defined]
                   "answered": ns[p.pos[s]].tolist(), "src": p.src[q].tolist(), "dst": p.dst[q].tolist(),
                   "if_hi": p.if_hi[q].tolist(), "if_lo": p.if_lo[q].tolist(), "opnum": p.opnum[q].tolist(),
                   "digest": [zlib.crc32(buf[a:a + n]) for a, n in zip(start, length, strict=True)], "size": length,
                   "response_frame": view.frame_no[s].tolist()}  # type: ignore[attr-defined]
        self.pairing.remember_log(keys, columns)

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
        for row in accepted:
            call = row.call
            if row.whole and row.ptype == PTYPE_REQUEST and not row.copy and call is not None and call.answered < 0 \
                    and not row.odd and call.raw is None:
                call.raw = batch.raw_frame(int(view.p.pos[row.col]))  # type: ignore[attr-defined]
        self.finals.settle()
        self.rows.batch_done()

    def _emit(self, view: object, done: list[Txn], cols: TxnCols | None = None) -> None:
        if not done and cols is None:
            return
        done.sort(key=lambda t: t.number)  # (in number order, whichever way and batch they closed in)
        for t in done:
            _handed_on(t)
        if self.as_rows:  # (rows made one by one: a copy after them is not added to them)
            records = Records(view)  # type: ignore[arg-type]
            for t in done:
                self.rows.add(self.capture_of(t.write_frame), t, records, self.offset)
                self._count(self.capture_of(t.write_frame))
            return
        made = self.tables.tables(view, done, self.capture_of, self.offset, cols)  # type: ignore[arg-type]
        self.late.hold(made, done, cols, self.offset, self.now_all)
        self._hand_on(self.late.release(self.now_all))
        for t in done:
            self._count(self.capture_of(t.write_frame))
        if cols is not None:
            for frame in cols.write_frame.tolist():
                self._count(self.capture_of(int(frame)))

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

    def _count(self, path: str) -> None:
        next(r for r in self.results if r.path == path).transactions += 1


def _handed_on(txn: Txn) -> None:
    """A transaction whose rows are made: its retransmissions counted, its calls no longer lead to it (a later
    copy is engine.late's)."""
    txn.retransmissions = sum(c.copies for c in txn.calls if c is not None)
    for c in txn.calls:
        fsm = c.fsm if c is not None else None
        if isinstance(fsm, FsmCall) and all(t is None or t.closed_by for t in fsm.txns):
            c.fsm = None


def _most_at_once(begin: np.ndarray, end: np.ndarray) -> int:
    """The most of the intervals [begin, end] (frames) open at one time."""
    if not len(begin):
        return 0
    events = np.concatenate([begin, end])
    step = np.concatenate([np.ones(len(begin), np.int64), -np.ones(len(end), np.int64)])
    order = np.lexsort((-step, events))  # (at one frame an opening before a closing: counted together)
    return int(np.cumsum(step[order]).max())


_REQUEST_COST = 64 + 72 * 39  # the most a channel's last parameter request counts (its addresses)
_PENDING_COST = 1024 + 256 + 2 * 240 + 128 * 39 + 192 * 39  # the most a pending transaction counts (machine)
_CALL_COST = CALL_OVERHEAD + 65_536  # the most an open call counts (calls.Pairing)


class _Known:
    """Keys the loop holds (open calls, calls answered lately)."""

    def __init__(self, pairing: Pairing) -> None:
        self.pairing = pairing

    def __contains__(self, key: object) -> bool:
        return self.pairing.known(key)  # type: ignore[arg-type]

    def __bool__(self) -> bool:
        pairing = self.pairing
        return bool(pairing.open or pairing.closed or pairing.logs)


_E = np.empty(0, np.int64)


def _empty_episodes() -> Episodes:
    return Episodes(_E, _E, _E, _E, _E, _E, _E, _E, [])


def _given_back(calls: Calls, ep: Episodes, keep: np.ndarray) -> tuple[Calls, Episodes]:
    """The calls and episodes the vector path took, but those of the episodes given back to the loop (the
    episodes' call indices renumbered)."""
    if keep.all():
        return calls, ep
    back = np.zeros(len(calls.q), bool)
    for k in np.flatnonzero(~keep).tolist():
        back[int(ep.w[k])] = True
        back[ep.reads[ep.first_read[k]:ep.first_read[k] + ep.n_reads[k]]] = True
    index = np.cumsum(~back) - 1
    sub = _subset(ep, keep)
    return Calls(calls.q[~back], calls.s[~back], calls.pd[~back]), Episodes(
        index[sub.w], index[sub.reads], sub.first_read, sub.n_reads, sub.channel, sub.group, sub.start, sub.end,
        sub.channels)


def _subset(ep: Episodes, keep: np.ndarray) -> Episodes:
    if keep.all():
        return ep
    first = np.zeros(int(keep.sum()), np.int64)
    n = ep.n_reads[keep]
    np.cumsum(n[:-1], out=first[1:])
    reads = np.concatenate([ep.reads[a:a + b] for a, b in zip(ep.first_read[keep].tolist(), n.tolist(), strict=True)]) \
        if len(n) else _E
    return Episodes(ep.w[keep], reads.astype(np.int64), first, n, ep.channel[keep], ep.group[keep], ep.start[keep],
                    ep.end[keep], ep.channels)


def _merged(columns: list[Pdu], odd: list[Pdu]) -> list[Pdu]:
    if not odd:
        return columns
    if not columns:
        return list(odd)
    out = columns + odd
    out.sort(key=lambda row: row.frame)  # (stable: a frame is in one list only)
    return out


def _loop_frames(view: object, loop_cols: np.ndarray, odd_rows: list[Pdu], ep: Episodes | None,
                 calls: Calls) -> dict[int, np.ndarray]:
    """The frames of the loop's rows by drive and controller (pair_key): the column rows not taken, the odd
    rows, and (with `ep`) the rows of PROFIdrive calls taken but in no episode."""
    p = view.p  # type: ignore[attr-defined]
    cols = loop_cols
    if ep is not None:
        in_ep = np.zeros(len(calls.q), bool)
        in_ep[ep.w] = True
        in_ep[ep.reads] = True
        out_ep = calls.pd & ~in_ep
        cols = np.concatenate([cols, calls.q[out_ep], calls.s[out_ep]])
    request = p.ptype[cols] == PTYPE_REQUEST
    keys = np.where(request, pair_key(p.dst[cols], p.src[cols]), pair_key(p.src[cols], p.dst[cols]))
    frames = view.frame_no[cols]  # type: ignore[attr-defined]
    if odd_rows:
        odd_keys = np.array([(r.dst << 32 | r.src) if r.ptype == PTYPE_REQUEST else (r.src << 32 | r.dst)
                             for r in odd_rows], np.uint64)
        keys = np.concatenate([keys, odd_keys])
        frames = np.concatenate([frames, np.array([r.frame for r in odd_rows], np.int64)])
    order = np.lexsort((frames, keys))
    keys, frames = keys[order], frames[order]
    out: dict[int, np.ndarray] = {}
    if len(keys):
        bounds = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
        for a, b in zip(bounds.tolist(), [*bounds[1:].tolist(), len(keys)], strict=True):
            out[int(keys[a])] = frames[a:b]
    return out


def run_batches(source: Iterable[FrameBatch] | Iterable[tuple[FrameBatch, list[tuple[FrameBatch, BatchView]]]],
                settings: Settings, rows: Rows, capture_of: Callable[[int], str], results: list[CaptureResult],
                progress: Progress | None, offset: int = 0) -> Accounting:
    """The loop over batches (or batches with their column decode made elsewhere: analysis.split); the
    frames' accounting when done (also after a CaptureError, which is recorded in the last result)."""
    as_rows = not all(arrow_text(r.path) for r in results)
    run = EngineRun(settings, rows, capture_of, results, progress, offset, as_rows)
    try:
        for item in source:
            if isinstance(item, tuple):
                run.feed(*item)
            else:
                run.feed(item)
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

