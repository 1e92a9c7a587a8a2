"""The capture loop: batch by batch, decode (analysis.engine.decode), pair the calls (calls), follow the
transactions (machine), make the findings the columns leave to the reference's code (checks), number
the transactions opened, hand the closed ones' rows on (tables), and carry what is still open.

Every capture takes this one way, whatever its size; a capture is one stream of frames through one
pairing and one machine, so no frame, channel or batch ever changes path.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator

import numpy as np

from pd_analyze.analysis.capture_run import CaptureResult, Progress, Settings, error_text
from pd_analyze.analysis.engine.calls import Pairing
from pd_analyze.analysis.engine.checks import FrameChecks, paired_flags, q7_differs, stub_of
from pd_analyze.analysis.engine.decode import Decoded, Decoder, merge_accounting, skipped_decide
from pd_analyze.analysis.engine.facts import Channel, Pdu, Write
from pd_analyze.analysis.engine.machine import Machine
from pd_analyze.analysis.engine.records import Records
from pd_analyze.analysis.engine.tables import TableBuilder
from pd_analyze.analysis.engine.txn import Txn
from pd_analyze.analysis.rows import Rows
from pd_analyze.analysis.stations import names_in_batch
from pd_analyze.capture import CaptureError
from pd_analyze.capture.batches import BATCH_FRAMES, FrameBatch, frame_batches
from pd_analyze.capture.raw import RawFrame
from pd_analyze.model import pd_values as pt
from pd_analyze.model.capped import CHANNEL_REQUESTS, CappedTable
from pd_analyze.model.rules import Finding
from pd_analyze.model.values import OP_WRITE, PTYPE_FAULT, PTYPE_REJECT, PTYPE_REQUEST, PTYPE_RESPONSE
from pd_analyze.protocol import rpc
from pd_analyze.protocol.dissector import Dissector, truncated_elsewhere
from pd_analyze.protocol.frames import Accounting
from pd_analyze.protocol.profidrive import Address, Parsed

# The pairing's own findings (calls.Pairing makes them): the reference's text for them is its own
PAIRING_RULES = frozenset({"rpc_retransmission", "rpc_key_reused", "rpc_call_evicted", "orphan_response",
                           "rpc_response_mismatch", "rpc_addresses_not_swapped", "rpc_unanswered"})


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
        self.checks = FrameChecks(checker, settings.rpc_timeout)
        self.tables = TableBuilder(checker)
        self.rows = rows
        rows.use_names(checker.names)  # the rows name parameters and errors as the run's profile does
        self.capture_of = capture_of
        self.results = results
        self.progress = progress
        self.offset = offset
        self.accounting = Accounting()  # the frames the columns took; the dissector counts its own
        self.next_number = 1
        self.now_all = -(1 << 62)  # the latest capture time of any frame (ns)
        self.last_pnio = -(1 << 62)  # the latest capture time of a PNIO RPC frame (ns)
        self.part = 0
        self.last_frame = 0
        # each channel's last parameter request's addresses, as Q7 compares a read response with them (6.4)
        self.last_request: CappedTable[Channel, tuple] = CappedTable(CHANNEL_REQUESTS)

    # --- the loop -----------------------------------------------------------------------------------
    def feed(self, batch: FrameBatch) -> None:
        """The next batch of frames."""
        if not len(batch):
            return
        self.last_frame = int(batch.number[-1])
        for decoded in self.decoder.parts(batch):
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
        records = Records(view)
        self.machine.records = records
        self.machine.names_of = lambda row: _names(view, row)
        runmax = np.maximum.accumulate(np.maximum(batch.ns, self.now_all))
        accepted: list[Pdu] = []
        new_calls = []
        pairing, machine, last_request = self.pairing, self.machine, self.last_request
        for row, now in self._rows(dec, runmax):
            row.part = self.part
            pairing.tick(now)
            if row.decide and not pairing.pnio(row):
                skipped_decide(self.decoder.accounting, row.raw, rpc.SKIP_NOT_PNIO)
                if row.raw.truncated:
                    self.rows.add_finding(self.capture_of(row.frame), truncated_elsewhere(row.frame))
                continue
            if not row.odd and row.ptype == PTYPE_RESPONSE:
                self.decoder.answered(row)
            pairing.pair(row)
            if row.call is not None and row.ptype in (PTYPE_FAULT, PTYPE_REJECT):
                self.decoder.answered(row)
            if row.call is not None and row.ptype == PTYPE_RESPONSE and row.call.opnum != row.opnum and not row.frames:
                row = self._redecoded(row, batch, row.call.opnum)
            if row.whole and row.ptype == PTYPE_REQUEST:
                if not row.copy and row.call is not None:
                    new_calls.append(row.call)
                for w in row.writes or ():
                    if w is not None and w.record is not None:
                        addresses = tuple(records.addresses(w.record))
                        last_request.remember(w.channel, addresses, 64 + 72 * len(addresses))
            elif row.whole and row.ptype == PTYPE_RESPONSE and row.answer is not None and row.answer.head is not None:
                row.q7 = self._q7(row, view, records)
            row.owner = machine.feed(row)
            self.last_pnio = max(self.last_pnio, row.ts)
            accepted.append(row)
        self.now_all = max(self.now_all, int(runmax[-1]))
        pairing.tick(self.now_all)
        self._findings(dec, accepted, records)
        loose: list[Finding] = []
        for row in accepted:
            if row.findings:
                (row.owner.findings if row.owner is not None else loose).extend(row.findings)
            # what a call still open keeps of its request's row: its frames and times (no findings, no
            # records: those went to the transaction), so open calls cost what the caps count
            row.findings, row.q7, row.owner, row.writes, row.read, row.answer = [], None, None, None, None, None
        loose += self.decoder.loose() + pairing.loose + machine.loose
        pairing.loose.clear()
        machine.loose.clear()
        for f in loose:
            self.rows.add_finding(self.capture_of(f.frame), f)
        self._close_part(view, batch, records, new_calls)

    def _rows(self, dec: Decoded, runmax: np.ndarray) -> Iterator[tuple[Pdu, int]]:
        """The part's rows in frame order, each with the capture time reached at its frame: the columns'
        rows and, decoded only when their turn comes (the dissector's state follows the frame order), the
        rows of the frames the dissector decodes."""
        batch = dec.batch
        columns, odd = dec.columns, dec.odd.tolist()
        at = np.searchsorted(batch.number, np.fromiter((r.frame for r in columns), np.int64, len(columns)))
        now_of = runmax[at].tolist() if len(columns) else []
        k = 0
        frame_rows = self.decoder.frame_rows
        for pos in odd:
            number = int(batch.number[pos])
            while k < len(columns) and columns[k].frame < number:
                yield columns[k], now_of[k]
                k += 1
            now = int(runmax[pos])
            for row in frame_rows(batch, pos):
                yield row, now
        while k < len(columns):
            yield columns[k], now_of[k]
            k += 1

    def _redecoded(self, row: Pdu, batch: FrameBatch, opnum: int) -> Pdu:
        """A response whose operation differs from its request's (R4), decoded again as the answer to the
        request's operation, as the reference decodes it (its pairing kept)."""
        pos = int(np.searchsorted(batch.number, row.frame))
        res = self.checks.alone(batch.raw_frame(pos), opnum)
        if res is None or res.pdu is None:
            return row
        new = self.decoder.row(res, row.ts)
        pairing_found = [f for f in row.findings if f.name in PAIRING_RULES]
        new.findings = pairing_found + [f for f in new.findings if f.name not in PAIRING_RULES]
        new.call, new.copy, new.part, new.decide = row.call, row.copy, row.part, row.decide
        new.opnum = row.opnum
        return new

    def _close_part(self, view: object, batch: FrameBatch, records: Records, new_calls: list) -> None:
        """Number what opened, hand on what closed, carry what stays open past the part."""
        machine = self.machine
        for txn in machine.opened:  # opened in frame order: their numbers are their order
            txn.number = self.next_number
            self.next_number += 1
        machine.opened.clear()
        done, machine.closed = machine.closed, []
        self._emit(view, done)
        for txn in machine.pending.values():
            if isinstance(txn.request, int):
                txn.request = records.carried(txn.request)
        for call in new_calls:
            row = call.request
            if call.answered < 0 and not row.odd and row.part == self.part:
                call.raw = batch.raw_frame(int(view.p.pos[row.col]))  # type: ignore[attr-defined]
        self.rows.batch_done()

    def _emit(self, view: object, done: list[Txn]) -> None:
        if not done:
            return
        for name, tables in self.tables.tables(view, done, self.capture_of, self.offset).items():  # type: ignore[arg-type]
            for table in tables:
                self.rows.add_table(name, table)
        for t in done:
            self._count(self.capture_of(t.write_frame))

    def finish(self) -> None:
        """End of capture: what the dissector held, the calls never answered, every pending transaction."""
        rows, loose = self.decoder.finish(self.last_frame)
        for row in rows:  # (a dissector without a hold releases none)
            loose += row.findings
        self.pairing.finish()
        self.machine.finish(self.last_pnio)
        loose += self.pairing.loose + self.machine.loose
        for f in loose:
            self.rows.add_finding(self.capture_of(f.frame), f)
        done, self.machine.closed = self.machine.closed, []
        self._emit(None, done)
        self.rows.batch_done()

    def totals(self) -> Accounting:
        """Every frame read, counted once: the columns' and the per-frame dissector's."""
        out = Accounting()
        merge_accounting(out, self.accounting)
        merge_accounting(out, self.decoder.accounting)
        return out

    def _count(self, path: str) -> None:
        next(r for r in self.results if r.path == path).transactions += 1

    # --- findings the reference's code makes ----------------------------------------------------------
    def _q7(self, row: Pdu, view: object, records: Records) -> list[Finding]:
        """Q7 of a read response against its channel's last parameter request (as of its frame)."""
        answer = row.answer
        if answer is None or answer.head is None or answer.head.ident != pt.RES_READ:
            return []
        addresses = self.last_request.get(_response_channel(view, row))
        if addresses is None:
            return []
        if isinstance(answer.record, int) and not q7_differs(view, answer.record, addresses):  # type: ignore[arg-type]
            return []
        request = Parsed(False, 4 + 6 * len(addresses), addresses=[
            Address(4 + 6 * i, attr, n, pnu, sub) for i, (attr, n, pnu, sub) in enumerate(addresses)])
        return self.checks.q7(records.parsed(answer.record), request, row.frame)

    def _findings(self, dec: Decoded, rows: list[Pdu], records: Records) -> None:
        """The findings the columns leave to the reference's code: local ones of flagged column rows, the
        response/request comparisons (N4, H6-H8) and Q7."""
        view, batch = dec.view, dec.batch
        alone: dict[tuple[int, bool], object] = {}

        def dissected(row: Pdu, with_records: bool = False) -> object:
            """The row's frame dissected alone (its record parsed too only when a record rule may report)."""
            if row.odd:
                return row.raw
            res = alone.get((id(row), with_records)) or alone.get((id(row), True))
            if res is None:
                if row.part == self.part:
                    res = self.checks.alone(batch.raw_frame(int(view.p.pos[row.col])), records=with_records)
                else:
                    raw = getattr(row.call, "raw", None) if row.call is not None else None
                    res = self.checks.alone(raw, records=with_records) if raw is not None else None
                alone[(id(row), with_records)] = res
            return res

        flag, rec_of, rec_flag = view.flag, view.rec_of, view.records.records.flag
        for row in rows:
            if not row.odd and flag[row.col]:
                record = int(rec_of[row.col])
                res = dissected(row, record >= 0 and bool(rec_flag[record]))
                if res is not None:
                    row.findings += [f for f in res.findings if f.name not in PAIRING_RULES]
        # responses against their requests
        pairs_q, pairs_s, pair_rows = [], [], []
        for row in rows:
            call = row.call
            if not row.whole or row.copy or call is None or row.ptype != PTYPE_RESPONSE:
                q7 = getattr(row, "q7", None)
                if q7:
                    row.findings += q7
                continue
            req = call.request
            if not row.odd and not req.odd and req.part == self.part:
                pairs_q.append(req.col)
                pairs_s.append(row.col)
                pair_rows.append(row)
            else:
                self._paired(row, req, call, dissected)
            q7 = getattr(row, "q7", None)
            if q7:
                row.findings += q7
        if pair_rows:
            flagged = paired_flags(view, np.array(pairs_q, np.int64), np.array(pairs_s, np.int64))
            for k in np.flatnonzero(flagged).tolist():
                row = pair_rows[k]
                self._paired(row, row.call.request, row.call, dissected)

    def _paired(self, row: Pdu, req: Pdu, call: object, dissected: Callable[[Pdu], object]) -> None:
        res_result, req_result = dissected(row), dissected(req) if req.part == self.part or req.odd else None
        if req_result is None and not req.odd:
            raw = getattr(call, "raw", None)
            req_result = self.checks.alone(raw) if raw is not None else None
        res_stub = res_result.pdu.stub if res_result is not None and res_result.pdu is not None else None
        req_stub = stub_of(req) if req.odd else (
            req_result.pdu.stub if req_result is not None and req_result.pdu is not None else None)
        row.findings += self.checks.paired(res_stub, req_stub, req.opnum, row.frame)


def _response_channel(view: object, row: Pdu) -> Channel | None:
    """The channel a read response names (device, controller, its block's AR, API, slot, subslot, index)."""
    if row.odd:
        res = row.raw
        stub = res.pdu.stub if res is not None and res.pdu is not None else None
        if stub is None:
            return None
        from pd_analyze.analysis.engine.decode import uuid_int
        from pd_analyze.model.values import PROFIDRIVE_INDICES
        from pd_analyze.protocol import pnio as rec

        block = next((b for b in stub.blocks if b.index in PROFIDRIVE_INDICES), None)
        if block is None:
            return None
        v = block.values
        hi, lo = uuid_int(v[rec.B_AR])
        return row.src, row.dst, hi, lo, v[rec.B_API], v[rec.B_SLOT], v[rec.B_SUBSLOT], v[rec.B_INDEX]
    p = view.p  # type: ignore[attr-defined]
    i = row.col
    return (row.src, row.dst, int(p.ar_hi[i]), int(p.ar_lo[i]), int(p.api[i]), int(p.slot[i]), int(p.subslot[i]),
            int(p.index[i]))


def _names(view: object, row: Pdu) -> Write | None:
    """The PROFIdrive channel a column write response names (for a write cut before its header)."""
    from pd_analyze.model.values import PROFIDRIVE_INDICES

    p = view.p  # type: ignore[attr-defined]
    i = row.col
    if row.odd or i < 0 or not p.has_block[i] or int(p.index[i]) not in PROFIDRIVE_INDICES \
            or int(p.opnum[i]) != OP_WRITE:
        return None
    return Write((row.src, row.dst, int(p.ar_hi[i]), int(p.ar_lo[i]), int(p.api[i]), int(p.slot[i]),
                  int(p.subslot[i]), int(p.index[i])), None, None, True)


def run_batches(source: Iterable[FrameBatch], settings: Settings, rows: Rows, capture_of: Callable[[int], str],
                results: list[CaptureResult], progress: Progress | None, offset: int = 0) -> Accounting:
    """The loop over batches; the frames' accounting when done (also after a CaptureError, which is
    recorded in the last result)."""
    run = EngineRun(settings, rows, capture_of, results, progress, offset)
    try:
        for batch in source:
            run.feed(batch)
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
