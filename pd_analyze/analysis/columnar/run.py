"""The columnar capture loop: each batch decoded by columns, its ordinary groups analysed here, the others
by the per-frame dissector and engine, both handing closed transactions and findings to the same rows.

Per batch: decode; route (skipped frames counted, unusual frames and their groups to the per-frame
path); pair calls and run the transactions of the ordinary groups; hand the groups found unusual over;
run the per-frame path over its frames in frame order while the columnar reads, changes and activities
take their turn in the same order (the values a change replaced are the ones read before it, whoever
read them); have the flagged frames' findings made by the per-frame checks; number the transactions
opened, in frame order across both paths; close what the batch's time let expire; make the rows; carry
what is still open to the next batch.
"""

from __future__ import annotations

from bisect import bisect_left
from collections import Counter
from collections.abc import Callable, Iterable

import numpy as np

from pd_analyze.analysis.capture_run import CaptureResult, Progress, Settings, error_text
from pd_analyze.analysis.columnar import call_view
from pd_analyze.analysis.columnar.batch_view import BatchView, fed
from pd_analyze.analysis.columnar.calls import Calls, pair
from pd_analyze.analysis.columnar.carry import calls_overflow, carry_over, near_caps, pending_overflow
from pd_analyze.analysis.columnar.channels import CallView, ChannelMachine, Outcome
from pd_analyze.analysis.columnar.frame_findings import findings_of
from pd_analyze.analysis.columnar.handover import group_of, hand_back, hand_over, uuid_bytes
from pd_analyze.analysis.columnar.state import ColumnarState, Txn
from pd_analyze.analysis.columnar.txn_rows import (
    ACTIVITY,
    CHANGE,
    READ,
    Converter,
    read_elements,
    remember_read,
    snapshot,
)
from pd_analyze.analysis.columnar.txn_tables import TableBuilder
from pd_analyze.analysis.rows import Rows
from pd_analyze.analysis.stations import names_in_batch
from pd_analyze.analysis.transaction import Transaction
from pd_analyze.capture import CaptureError
from pd_analyze.capture.batches import FrameBatch
from pd_analyze.model import pd_values as pt
from pd_analyze.protocol.frames import Accounting
from pd_analyze.protocol.link import SKIP_NOT_IPV4
from pd_analyze.protocol.pnio_batch import SKIP_REASONS
from pd_analyze.protocol.profidrive import Parsed
from pd_analyze.protocol.rpc_calls import unanswered_finding

Event = tuple[int, int, object]  # (frame, READ/CHANGE/ACTIVITY, what)


class ColumnarRun:
    """One capture (or a chain of files read as one) analysed a batch at a time."""

    def __init__(self, settings: Settings, rows: Rows, capture_of: Callable[[int], str],
                 results: list[CaptureResult], progress: Progress | None = None, offset: int = 0) -> None:
        self.settings = settings
        self.checker = settings.checker()
        self.d = settings.dissector()
        self.engine = settings.engine()
        self.engine.number_of = self._number_of
        self.rows = rows
        rows.use_names(self.checker.names)  # the rows name parameters and errors as the run's profile does
        self.capture_of = capture_of
        self.results = results
        self.progress = progress
        self.offset = offset
        self.state = ColumnarState()
        self.convert = Converter()
        self.tables = TableBuilder(self.convert, self.checker.names)
        self.accounting = Accounting()  # the frames the columns took; the dissector counts its own
        self.next_number = 1
        self.last_ts = float("-inf")  # the latest capture time seen
        self.last_pnio = float("-inf")  # the latest time of a PNIO RPC frame (the engines' "now")
        self._ref_opens: list[int] = []  # frames of the transactions the per-frame engine opened in this batch
        self._col_opens: list[int] = []  # the same, columnar
        self._base = 1

    # --- the loop -----------------------------------------------------------------------------------
    def feed(self, batch: FrameBatch) -> None:
        """The next batch of frames."""
        if not len(batch):
            return
        ts = batch.ts
        if not self.state.all_reference and (bool(np.any(ts[1:] < ts[:-1])) or float(ts[0]) < self.last_ts):
            self._all_to_frames()  # time went backwards: expiry depends on the order of everything
        if self.state.all_reference:
            self._frames_only(batch)
        else:
            for part, view in BatchView.parts(batch, self.checker):
                if self.state.all_reference:
                    self._frames_only(part)
                else:
                    self._columns(part, view)
                del view  # (the next part's decode does not wait for this one's memory)
        self.last_ts = max(self.last_ts, float(ts.max()))
        if self.results:  # (the file being read: a chain appends each file's result before its batches)
            names_in_batch(batch, self.results[-1].stations)
        if self.progress is not None and self.results:
            self.progress(self.results[-1].path, self.read)

    def _columns(self, batch: FrameBatch, view: BatchView) -> None:
        settings, state = self.settings, self.state
        self.accounting.read += len(batch)
        self._count_skipped(view)
        bad = view.reference_groups(state)
        calls = pair(view.p, view.candidates(bad), view.frame_no, view.ts, state.open_calls, state.answered,
                     settings.rpc_timeout, max(view.last_ts, self.d._now), bad)
        if calls_overflow(view, calls, bad, state):  # (nothing of the batch is kept yet)
            del view, calls  # the per-frame path takes the batch: its columns are not needed any more
            self._all_to_frames()
            self._frames_only(batch)
            return
        cv, q7_requests = call_view.build(view, calls, bad, state)
        machine = ChannelMachine(state.pending, state.last_done, settings.txn_timeout, self.engine.b5_threshold, bad)
        out = machine.run(cv)
        if pending_overflow(out, bad):
            del view, calls, cv, q7_requests, machine, out
            self._all_to_frames()
            self._frames_only(batch)
            return
        # bad is final from here on
        newly = bad - state.reference_groups
        hand_over(newly, state, self.d, self.engine, view.first_ts, settings.rpc_timeout)
        state.reference_groups |= newly
        kept = [t for t in out.opened if t.group not in bad]
        self._base, self._col_opens, self._ref_opens = self.next_number, [t.write_frame for t in kept], []
        self._per_frame(view, bad, self._events(view, bad, kept, out))
        now = max(view.last_pnio, self.engine._now, self.last_pnio)
        machine.close_due(now)
        for txn in self.engine.advance(now):
            self._add_reference(txn)
        self.d.advance(view.last_ts)
        self._drain()
        for t in kept:
            t.number = self._base + bisect_left(self._col_opens, t.write_frame) + bisect_left(self._ref_opens,
                                                                                                t.write_frame)
        self.next_number = self._base + len(self._col_opens) + len(self._ref_opens)
        self._flagged(view, cv, calls, out, bad, q7_requests)
        self._expired(view, calls, bad)
        done = [t for t in out.closed if t.group not in bad]
        for name, tables in self.tables.tables(view, done, self.capture_of, self.offset).items():
            for table in tables:
                self.rows.add_table(name, table)
        for t in done:
            self._count(self.capture_of(t.write_frame))
        self.rows.batch_done()
        carry_over(view, cv, calls, out, machine, bad, state, settings.rpc_timeout)
        hand_back(state, self.d, self.engine, view.last_ts, settings.rpc_timeout)
        self.last_pnio = now
        self.accounting.decoded += view.columnar_decoded(bad)
        if near_caps(state):
            self._all_to_frames()

    @property
    def read(self) -> int:
        return self.accounting.read + self.d.accounting.read

    def finish(self) -> None:
        """End of capture: everything still open goes to the per-frame path, which ends it as it would."""
        self._all_to_frames()
        self.d.advance(self.last_ts)
        for txn in self.engine.advance(self.last_pnio):
            self._add_reference(txn)
        for res in self.d.finish(self.read):
            for txn in self.engine.feed(res):
                self._add_reference(txn)
        for txn in self.engine.finish(max(self.last_pnio, self.engine._now)):
            self._add_reference(txn)
        self._drain()

    def totals(self) -> Accounting:
        """Every frame read, counted once: the columns' and the per-frame dissector's."""
        d, own = self.d.accounting, self.accounting
        return Accounting(own.read + d.read, own.decoded + d.decoded, own.skipped + d.skipped, Counter(d.malformed))

    # --- the per-frame part --------------------------------------------------------------------------
    @staticmethod
    def _events(view: BatchView, bad: set[int], kept: list[Txn], out: Outcome) -> list[Event]:
        """The columnar reads (values read), changes (values replaced) and activities of the batch, by frame."""
        events: list[Event] = [(t.write_frame, CHANGE, t) for t in kept if t.req_id == pt.REQ_CHANGE]
        events += [(frame, READ, t) for frame, t in out.reads if t.group not in bad]
        p, idx = view.p, view.candidates(bad)
        if len(idx):
            hi, lo = p.act_hi[idx], p.act_lo[idx]
            order = np.lexsort((idx, lo, hi))
            first = np.ones(len(order), bool)
            first[1:] = (hi[order][1:] != hi[order][:-1]) | (lo[order][1:] != lo[order][:-1])
            for j in order[first].tolist():
                events.append((int(view.frame_no[idx[j]]), ACTIVITY, uuid_bytes(int(hi[j]), int(lo[j]))))
        events.sort(key=lambda e: (e[0], e[1]))
        return events

    def _apply(self, view: BatchView, event: Event) -> None:
        _frame, kind, what = event
        if kind == READ:
            remember_read(read_elements(what, view, self.convert.channel(what.channel)[0], self.convert),
                          self.engine.read_values)
        elif kind == CHANGE:
            snapshot(what, view, self.convert.channel(what.channel)[0], self.engine.read_values)
        else:
            self.d.remember_activity(what)

    def _per_frame(self, view: BatchView, bad: set[int], events: list[Event]) -> None:
        """The per-frame path over its frames of the batch, in frame order, the columnar events taking their
        turn between them."""
        k = 0
        batch = view.batch
        acc = self.accounting
        for pos in view.frames_for_reference(bad).tolist():
            number = int(batch.number[pos])
            while k < len(events) and events[k][0] < number:
                self._apply(view, events[k])
                k += 1
            acc.read -= 1  # the dissector counts it
            for res in self.d.feed(batch.raw_frame(pos)):
                for txn in self.engine.feed(res):
                    self._add(txn)
            if self.d.loose_findings or self.engine.loose:
                self._drain()
        for event in events[k:]:
            self._apply(view, event)

    def _frames_only(self, batch: FrameBatch) -> None:
        """A batch read by the per-frame path alone."""
        self._base, self._col_opens, self._ref_opens = self.next_number, [], []
        acc = self.d.accounting
        for pos, take in enumerate(fed(batch).tolist()):
            if not take:  # as dissect_frames counts it, its time passing too
                acc.read += 1
                acc.skipped[SKIP_NOT_IPV4] += 1
                self.d.advance(float(batch.ts[pos]))
                continue
            for res in self.d.feed(batch.raw_frame(pos)):
                for txn in self.engine.feed(res):
                    self._add_reference(txn)
            self._drain()
        self.next_number = self._base + len(self._ref_opens)
        self.last_pnio = max(self.last_pnio, self.engine._now)

    def _flagged(self, view: BatchView, cv: CallView, calls, out: Outcome, bad: set[int],  # noqa: ANN001
                 q7_requests: dict[int, object]) -> None:
        """Findings of the flagged frames of the columnar groups: on their transaction, or loose."""
        flagged = np.flatnonzero(view.flag & view.pnio & view.good(bad))
        if not len(flagged):
            return
        batch, p = view.batch, view.p
        frames = [batch.raw_frame(int(p.pos[i])) for i in flagged]
        answer_of = {int(s): k for k, s in enumerate(calls.res.tolist()) if s >= 0}
        requests: dict[int, tuple[tuple, Parsed, int]] = {}
        for i in flagged.tolist():
            k = answer_of.get(i)
            if k is None:
                continue
            q = int(calls.req[k])
            frames.append(batch.raw_frame(int(p.pos[q])) if q >= 0 else calls.carried[k].request.frame)
            source = q7_requests.get(k)
            if source is not None:
                parsed, frame = ((view.parsed_record(source), int(view.frame_no[view.rec_pdu[source]]))
                                 if isinstance(source, int) else source)
                requests[int(view.frame_no[i])] = (self.convert.channel(cv.channel[k]), parsed, frame)
        wanted = {int(n) for n in view.frame_no[flagged]}
        for frame, found in findings_of(frames, wanted, self.checker, self.settings.rpc_timeout, requests).items():
            owner = out.owner.get(frame)
            if owner is not None:
                owner.findings.extend(found)
            else:
                for f in found:
                    self.rows.add_finding(self.capture_of(f.frame), f)

    def _expired(self, view: BatchView, calls: Calls, bad: set[int]) -> None:
        """rpc_unanswered for the calls of the columnar groups that expired unanswered."""
        for k in np.flatnonzero(calls.expired).tolist():
            i = int(calls.req[k])
            carried = calls.carried[k]
            group, seq = (int(view.group[i]), int(view.p.seq[i])) if i >= 0 else (carried.request.group, carried.key[2])
            if group not in bad:
                f = unanswered_finding(int(calls.frame[k]), seq, self.settings.rpc_timeout)
                self.rows.add_finding(self.capture_of(f.frame), f)

    def _number_of(self, frame: int, position: int) -> int:
        """A transaction the per-frame engine opens: numbered in frame order among both paths' opens."""
        del position  # a Write-Multiple's records come in order on one frame: counted as they come
        number = self._base + bisect_left(self._col_opens, frame) + len(self._ref_opens)
        self._ref_opens.append(frame)
        return number

    def _add(self, txn: Transaction) -> None:
        path = self.capture_of(txn.write_req_frame)
        self.rows.add(path, txn, self.offset)
        self._count(path)

    def _count(self, path: str) -> None:
        next(r for r in self.results if r.path == path).transactions += 1

    def _add_reference(self, txn: Transaction) -> None:
        self._add(txn)
        self._drain()

    def _drain(self) -> None:
        for source in (self.engine.loose, self.d.loose_findings):
            for f in source:
                self.rows.add_finding(self.capture_of(f.frame), f)
            source.clear()

    def _count_skipped(self, view: BatchView) -> None:
        counts = np.bincount(view.skip_codes(), minlength=len(SKIP_REASONS))
        for code, count in enumerate(counts.tolist()):
            if count:
                self.accounting.skipped[SKIP_REASONS[code]] += count

    def _all_to_frames(self) -> None:
        """Every group to the per-frame path from here on (and what the columns hold of them)."""
        state = self.state
        if state.all_reference:
            return
        state.all_reference = True
        groups = {t.group for t in state.pending.values()} | {c.request.group for c in state.open_calls.values()}
        groups |= {int(g) for log in state.answered for g in np.unique(log.group).tolist()}
        groups |= {group_of(ch) for ch in state.last_done} | {group_of(ch) for ch in state.last_request}
        hand_over(groups - state.reference_groups, state, self.d, self.engine, self.last_ts,
                  self.settings.rpc_timeout)


def run_batches(source: Iterable[FrameBatch], settings: Settings, rows: Rows, capture_of: Callable[[int], str],
                results: list[CaptureResult], progress: Progress | None, offset: int = 0) -> Accounting:
    """The columnar loop over batches; the frames' accounting when done (also after a CaptureError, which
    is recorded in the last result)."""
    run = ColumnarRun(settings, rows, capture_of, results, progress, offset)
    try:
        for batch in source:
            run.feed(batch)
    except CaptureError as exc:
        results[-1].error = error_text(exc)
    run.finish()
    return run.totals()
