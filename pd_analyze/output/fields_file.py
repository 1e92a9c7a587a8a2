"""`dump -T fields` of a capture file (with or without -Y), read as batches: the cells of the frames the
column decode reads regularly come from the columns (output.column_fields), the filter is judged on them
(output.dump_prefilter), and only the frames the columns cannot tell are dissected (issue 24 point 1).

The lines are today's per-frame path's (frame_select.views: one dissector with its own pairing beside the
records, every frame a line), byte for byte. That dissector's state is the only thing one frame's tree takes
from another (reassembly, and the request a response is decoded as the answer to), so one dissector reads the
capture here too, in frame order: the frames the columns cannot decode (fragments, cut or odd PDUs, other link
types, control PDUs) and the rows whose line needs a tree are fed to it; every other column row is passed by
(`Dissector.pass_pdu`: its call opened or answered, its activity and parameter request remembered, what `feed`
would leave) and a frame without IPv4, UDP or DCE/RPC moves its clock on. A response is decoded in its tree as
the answer to its call's request: a row whose request has another operation (`Dissector.answered_as`) is fed.

A frame's line is written in frame order: a dissected frame's result may come out of the dissector's hold later
(a request waits for its answer), and the lines after it wait with it.

Used for a capture file whose fields and filter name no link (those are the report's pairing: the per-frame
path, frame_select). frame.time_epoch is a record's time as tshark prints it: the batches' nanoseconds, or, for
the frames whose nanoseconds do not hold it (a pcapng's Simple Packet Blocks, which have none, and units in
powers of two or finer than a nanosecond), their record's stamp (FrameBatch.stamps).
"""

from __future__ import annotations

import heapq
from collections.abc import Iterator, Mapping

import numpy as np

from pd_analyze.analysis.capture_run import Settings
from pd_analyze.analysis.engine.decode import column_rows
from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.capture import CaptureError
from pd_analyze.capture.batches import FrameBatch, batches
from pd_analyze.capture.pcapng import Block
from pd_analyze.capture.pcapng_write import BT_SPB
from pd_analyze.model.values import OP_WRITE, PTYPE_FAULT, PTYPE_REJECT, PTYPE_REQUEST, PTYPE_RESPONSE
from pd_analyze.output import dump_prefilter
from pd_analyze.output.column_fields import OtherFrames, PartFields
from pd_analyze.output.display_filter import DisplayFilter
from pd_analyze.output.dump import safe
from pd_analyze.output.dump_file import in_ranges
from pd_analyze.output.frame_notes import FrameNote, NotesUpto
from pd_analyze.output.frame_select import FieldsFormat, fields_line
from pd_analyze.output.frame_view import ANALYSIS, FRAME, FieldRef, FrameView, record_time
from pd_analyze.protocol.dissector import Dissector, Unparsed
from pd_analyze.protocol.frames import Accounting, FrameResult
from pd_analyze.protocol.pnio_batch import SKIP_REASONS
from pd_analyze.protocol.profidrive import footprint_of
from pd_analyze.protocol.profidrive_checks import Checker

_RECORD_TYPE = 0  # the Block type of a frame made from a batch whose nanoseconds hold its time (record_time)


def takes(path: str, needs_notes: bool = False) -> bool:
    """This path reads the capture (else the per-frame path does), unless the per-frame reference is forced;
    standard input only when no analysis is read first (the analysis and this read would both need it: the
    per-frame path says so)."""
    return (path != "-" or not needs_notes) and not dump_prefilter.per_frame_forced()


class FieldsFile:
    """The `-T fields` lines of one capture file (`lines`), and its accounting (the dissector's, every frame
    counted)."""

    def __init__(self, path: str, settings: Settings, checker: Checker, refs: list[FieldRef], fmt: FieldsFormat,
                 flt: DisplayFilter | None, notes: NotesUpto | None, ranges: list[tuple[int, int]]) -> None:
        self.path, self.settings, self.checker = path, settings, checker
        self.refs, self.fmt, self.flt, self.notes, self.ranges = refs, fmt, flt, notes, ranges
        self.d = Dissector(annotate=True, rpc_timeout=settings.rpc_timeout, checker=checker)
        self._judge = dump_prefilter.candidates_of(flt) if flt is not None else None
        self._notes: dict[int, FrameNote] = {}  # the notes of the frames read, not yet written
        self._fed: dict[int, tuple[float, int, int, int, int, bytes]] = {}  # frames dissected, line not written
        self._lines: list[tuple[int, str]] = []  # a heap of (frame, line) to write

    @property
    def accounting(self) -> Accounting:
        return self.d.accounting

    def lines(self) -> Iterator[str]:
        """Every line in frame order; CaptureError after the lines of the frames before the damage."""
        source = batches(self.path, self.settings.batch_frames) if self.settings.batch_frames else \
            batches(self.path)
        try:
            for batch in source:
                if not len(batch):
                    continue
                for part, view in BatchView.parts(batch, self.checker):
                    self._part(part, view)
                    held = self.d.hold.first_held() if self.d.hold is not None else 0
                    yield from self._release(held or int(part.number[-1]) + 1)
        except CaptureError:  # the frames before the damage first (not on GeneratorExit: a closed pipe)
            yield from self._end()
            raise
        yield from self._end()

    def _end(self) -> Iterator[str]:
        self._results(self.d.finish())  # (it read every frame: its own count is the capture's)
        yield from self._release(None)

    # --- one part ----------------------------------------------------------------------------------
    def _part(self, batch: FrameBatch, view: BatchView) -> None:
        if self.notes is not None:
            self._notes.update((n.frame, n) for n in self.notes.upto(int(batch.number[-1])))
        rows, odd = column_rows(view)
        kind = np.zeros(len(batch), np.int8)  # 0: the columns skip it, 1: a column row, 2: dissected
        pos = view.p.pos[rows]
        kind[pos] = 1
        kind[odd] = 2
        wanted = self._wanted(batch.number)
        tree, lines = self._rows(batch, view, rows, wanted[pos])
        self._others(batch, view, np.flatnonzero(kind == 0), wanted)
        self._events(batch, view, rows, np.flatnonzero(kind > 0), tree, lines)

    def _wanted(self, frames: np.ndarray) -> np.ndarray:
        return in_ranges(frames, self.ranges)

    def _judged(self, fields: dump_prefilter.Fields, batch: FrameBatch, at: np.ndarray,
                wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The frames `at` (positions in the batch): certainly printed, printed if their tree says so, and
        per frame whether every cell is known from `fields`."""
        rows = dump_prefilter.Rows(fields, batch.number[at], batch.ts[at], self._notes, _record(batch, at),
                                   stamped=not _unstamped(batch, at))
        if self._judge is None:
            sure, maybe = np.ones(len(at), bool), np.zeros(len(at), bool)
        else:
            sure, maybe = self._judge(rows)
        known = np.ones(len(at), bool)
        for ref in self.refs:
            if ref.kind == FRAME or ref.kind == ANALYSIS:
                continue
            occ = fields.occurrences(ref)
            if occ is None or any(len(t) != 1 for t in occ.text_lists()):
                known[:] = False
                break
            known &= occ.known
        return sure & wanted, maybe & wanted, known

    def _rows(self, batch: FrameBatch, view: BatchView, rows: np.ndarray,
              wanted: np.ndarray) -> tuple[np.ndarray, dict[int, str]]:
        """Per column row whether it must be dissected (a fault always: its call's state is the per-frame
        code's), and the lines of the others that print: pushed now, but a response's (by row), which is
        dissected after all if its request has another operation (_RowColumns.passable)."""
        ptype = view.p.ptype[rows]
        fault = (ptype == PTYPE_FAULT) | (ptype == PTYPE_REJECT)
        pos = view.p.pos[rows]
        fields = PartFields(view, rows, np.ones(len(rows), bool))
        sure, maybe, known = self._judged(fields, batch, pos, wanted)
        tree = maybe | (sure & ~known) | (fault & wanted)
        chosen = np.flatnonzero(sure & known & ~fault)
        lines = self._lines_of(fields, batch, pos, chosen)
        later = ptype[chosen] == PTYPE_RESPONSE
        for frame, line in zip(batch.number[pos[chosen[~later]]].tolist(), np.array(lines, object)[~later].tolist(),
                               strict=True):
            heapq.heappush(self._lines, (frame, line))
        return tree, dict(zip(chosen[later].tolist(), np.array(lines, object)[later].tolist(), strict=True))

    def _others(self, batch: FrameBatch, view: BatchView, at: np.ndarray, wanted: np.ndarray) -> None:
        """The frames the columns skip (not PNIO RPC): counted, their lines pushed (their headers read frame by
        frame where a cell or the filter asks for them: no dissector state is theirs)."""
        reason = view.decoded.frames.skip_reason[at]
        acc = self.d.accounting
        acc.read += len(at)
        for code, count in enumerate(np.bincount(reason.astype(np.int64), minlength=len(SKIP_REASONS)).tolist()):
            if count:
                acc.skipped[SKIP_REASONS[code]] += count
        sure, maybe, known = self._judged(OtherFrames(len(at)), batch, at, wanted[at])
        chosen = np.flatnonzero(sure & known)
        for frame, line in zip(batch.number[at[chosen]].tolist(), self._lines_of(OtherFrames(len(at)), batch, at,
                                                                                 chosen), strict=True):
            heapq.heappush(self._lines, (frame, line))
        for k in np.flatnonzero(maybe | (sure & ~known)).tolist():
            i = int(at[k])
            frame = int(batch.number[i])
            view_ = FrameView(frame, float(batch.ts[i]), None, _block(batch, i), self._notes.get(frame))
            if self.flt is None or self.flt.matches(view_):
                heapq.heappush(self._lines, (frame, fields_line(view_, self.refs, self.fmt)))

    # --- the frames in order: dissected, or passed by --------------------------------------------------
    def _events(self, batch: FrameBatch, view: BatchView, rows: np.ndarray, at: np.ndarray, tree: np.ndarray,
                lines: dict[int, str]) -> None:
        d, p = self.d, view.p
        if not len(batch):
            return
        clock = np.fmax.accumulate(batch.ts).tolist()  # the dissector's clock: the latest time read so far
        row_of = np.full(len(batch), -1, np.int64)
        row_of[p.pos[rows]] = np.arange(len(rows))
        rows_at, tree_of = row_of[at].tolist(), tree.tolist()
        cols = _RowColumns(batch, view, rows)
        passable, pass_by, results, get_line = cols.passable, cols.pass_by, self._results, lines.get
        now = float("-inf")
        for i, k in zip(at.tolist(), rows_at, strict=True):
            if i and clock[i - 1] > now:  # the frames since the last one it read moved its clock on
                now = clock[i - 1]
                d.advance(now)
            if k >= 0 and not tree_of[k] and passable(k, d):
                results(pass_by(k, d))
                line = get_line(k)
                if line is not None:
                    heapq.heappush(self._lines, (cols.frame[k], line))
                continue
            frame = batch.raw_frame(i)
            self._fed[frame.number] = (frame.ts, frame.linktype, int(batch.caplen[i]), frame.iface,
                                       int(batch.ns[i]), frame.data, _stamp(batch, frame.number))
            results(d.feed(frame))
        d.advance(clock[-1])

    def _results(self, results: list[FrameResult]) -> None:
        for res in results:  # (most calls: none)
            self._line_of(res.frame, res)

    def _line_of(self, frame: int, res: FrameResult | None) -> None:
        meta = self._fed.pop(frame, None)
        if meta is None or (self.ranges and not any(lo <= frame <= hi for lo, hi in self.ranges)):
            return
        ts, linktype, caplen, iface, ns, data, stamp = meta
        block = _record_block(data, frame, ts, linktype, caplen, iface, ns, stamp)
        view = FrameView(frame, ts, res, block, self._notes.get(frame))
        if self.flt is None or self.flt.matches(view):
            heapq.heappush(self._lines, (frame, fields_line(view, self.refs, self.fmt)))

    def _release(self, before: int | None) -> Iterator[str]:
        """The lines of the frames before `before` (all: None), in order; the dissected frames before it
        that gave no result are frames the dissector skipped (their headers' cells)."""
        for frame in sorted(f for f in self._fed if before is None or f < before):
            self._line_of(frame, None)
        lines = self._lines
        while lines and (before is None or lines[0][0] < before):
            yield heapq.heappop(lines)[1]
        for frame in [f for f in self._notes if before is None or f < before]:
            del self._notes[frame]

    # --- cells from the columns ----------------------------------------------------------------------
    def _lines_of(self, fields: dump_prefilter.Fields, batch: FrameBatch, at: np.ndarray,
                  chosen: np.ndarray) -> list[str]:
        """The lines of the frames `at[chosen]`, every cell from the columns."""
        if not len(chosen):
            return []
        frames = batch.number[at]
        cells = [_cells(ref, fields, batch, at, frames, self._notes, self.fmt)[chosen] for ref in self.refs]
        return [self.fmt.separator.join(t) for t in zip(*cells, strict=True)]


def _record(batch: FrameBatch, at: np.ndarray) -> dict[str, np.ndarray]:
    """frame.iface, frame.linktype and frame.caplen of the frames `at`, as their records hold them."""
    return {"frame.iface": batch.iface[at], "frame.linktype": batch.linktype[at], "frame.caplen": batch.caplen[at]}


def _block(batch: FrameBatch, i: int) -> Block:
    """Frame i of the batch as the record FrameView reads."""
    start, caplen, frame = int(batch.start[i]), int(batch.caplen[i]), int(batch.number[i])
    return _record_block(bytes(batch.buf[start:start + caplen]), frame, float(batch.ts[i]), int(batch.linktype[i]),
                         caplen, int(batch.iface[i]), int(batch.ns[i]), _stamp(batch, frame))


def _stamp(batch: FrameBatch, frame: int) -> tuple[int, float, int, int] | None:
    """The record's own stamp of a frame whose nanoseconds do not hold its time (FrameBatch.stamps)."""
    return batch.stamps.get(frame) if batch.stamps else None


def _record_block(data: bytes, frame: int, ts: float, linktype: int, caplen: int, iface: int, ns: int,
                  stamp: tuple[int, float, int, int] | None) -> Block:
    """A frame's record as FrameView reads it: its time exact in nanoseconds, or its record's own stamp."""
    if stamp is None:
        return Block(data, _RECORD_TYPE, True, frame, ts, linktype, 0, caplen, iface, 1e9, 0, ns)
    btype, divisor, offset, ticks = stamp
    return Block(data, btype, True, frame, ts, linktype, 0, caplen, iface, divisor, offset, ticks)


def _unstamped(batch: FrameBatch, at: np.ndarray) -> bool:
    """A frame of `at` has no time (a Simple Packet Block): frame.time_epoch is then left to the trees."""
    stamps = batch.stamps
    return bool(stamps) and any(stamps[f][0] == BT_SPB for f in batch.number[at].tolist() if f in stamps)


def _time_text(batch: FrameBatch, frame: int, ns: int) -> str:
    stamp = _stamp(batch, frame)
    return _seconds(ns) if stamp is None else record_time(_record_block(b"", frame, 0.0, 0, 0, 0, ns, stamp))


def _cells(ref: FieldRef, fields: dump_prefilter.Fields, batch: FrameBatch, at: np.ndarray, frames: np.ndarray,
           notes: Mapping[int, FrameNote], fmt: FieldsFormat) -> np.ndarray:
    """One column of cells (an object array of str, one per frame of `at`), as frame_select.fields_line makes
    them."""
    n = len(at)
    if ref.kind == FRAME:
        name = ref.names[0]
        if name == "frame.no":
            texts = [str(f) for f in frames.tolist()]
        elif name == "frame.ts":
            texts = [_time_text(batch, f, ns) for f, ns in zip(frames.tolist(), batch.ns[at].tolist(), strict=True)]
        else:
            texts = [str(v) for v in _record(batch, at)[name].tolist()]
        return np.array([_quoted(safe(t), fmt) for t in texts], object)
    if ref.kind == ANALYSIS:
        out = np.full(n, "", object)
        for k, frame in enumerate(frames.tolist()):
            note = notes.get(frame)
            if note is not None:
                out[k] = _cell(FrameView(frame, 0.0, None, None, note).shown(ref), fmt)
        return out
    occ = fields.occurrences(ref)
    assert occ is not None  # (_judged: every cell of the frames whose cells are made here is known)
    texts = [t[0] for t in occ.text_lists()]
    single = np.array([_quoted(safe(t), fmt) for t in texts] + [""], object)
    owner, code = occ.owner, occ.code
    rows = np.arange(n)
    first, end = np.searchsorted(owner, rows, "left"), np.searchsorted(owner, rows, "right")
    count = end - first
    out = np.full(n, "", object)
    one = count == 1 if fmt.occurrence == "a" else count >= 1
    pick = (end - 1) if fmt.occurrence == "l" else first
    out[one] = single[code[pick[one]]]
    if fmt.occurrence == "a":
        for k in np.flatnonzero(count > 1).tolist():
            out[k] = _cell([texts[c] for c in code[first[k]:end[k]].tolist()], fmt)
    return out


def _cell(shown: list[str], fmt: FieldsFormat) -> str:
    """frame_select.fields_line's cell of one field's texts."""
    if shown and fmt.occurrence != "a":
        shown = shown[:1] if fmt.occurrence == "f" else shown[-1:]
    return _quoted(safe(fmt.aggregator.join(shown)), fmt)


def _quoted(text: str, fmt: FieldsFormat) -> str:
    return f"{fmt.quote}{text}{fmt.quote}" if text else ""


def _seconds(ns: int) -> str:
    """Nanoseconds since the epoch as frame_view.record_time prints a classic pcap record's time."""
    sign = "-" if ns < 0 else ""
    whole, frac = divmod(abs(ns), 1_000_000_000)
    return f"{sign}{whole}.{frac:09d}"


class _RowColumns:
    """What passing a column row by takes (Dissector.pass_pdu), read from the columns as Python values."""

    def __init__(self, batch: FrameBatch, view: BatchView, rows: np.ndarray) -> None:
        p = view.p
        self.batch, self.view, self.rows = batch, view, rows
        self.frame = view.frame_no[rows].tolist()
        self.ts = view.ts[rows].tolist()
        self.ptype = p.ptype[rows].tolist()
        self.opnum = p.opnum[rows].tolist()
        self.seq = p.seq[rows].tolist()
        hi = p.act_hi[rows].astype(">u8").tobytes()
        lo = p.act_lo[rows].astype(">u8").tobytes()
        self.activity = [hi[8 * k:8 * k + 8] + lo[8 * k:8 * k + 8] for k in range(len(rows))]
        interface = np.stack([p.if_hi[rows], p.if_lo[rows]], 1).astype(">u8").tobytes()
        self.interface = [interface[16 * k:16 * k + 16] for k in range(len(rows))]
        src, dst = p.src[rows].astype(">u4").tobytes(), p.dst[rows].astype(">u4").tobytes()
        self.src = [src[4 * k:4 * k + 4] for k in range(len(rows))]
        self.dst = [dst[4 * k:4 * k + 4] for k in range(len(rows))]
        start, length = p.body_start[rows].astype(np.int64).tolist(), p.body_len[rows].astype(np.int64).tolist()
        buf = memoryview(batch.buf)  # a call keeps its body's length and digest, not its bytes
        self.body = [buf[a:a + n] for a, n in zip(start, length, strict=True)]
        self.has_block = p.has_block[rows].tolist()
        self.record_len = np.where(p.opnum[rows] == OP_WRITE, p.record_len[rows], 0).tolist()
        self.rec_of = view.rec_of[rows].tolist()

    def passable(self, k: int, d: Dissector) -> bool:
        """Row k is passed by: not a fault (its call's state is the per-frame code's), and a response's request
        (if it pairs one) has its operation, so its tree would be the columns' decode."""
        ptype = self.ptype[k]
        if ptype in (PTYPE_FAULT, PTYPE_REJECT):
            return False
        if ptype != PTYPE_RESPONSE:
            return True
        opnum = d.answered_as((self.activity[k], self.seq[k]))
        return opnum is None or opnum == self.opnum[k]

    def pass_by(self, k: int, d: Dissector) -> list[FrameResult]:
        src, dst = self.src[k], self.dst[k]
        channel: tuple = ()
        unparsed = None
        request = self.ptype[k] == PTYPE_REQUEST
        rec = self.rec_of[k]
        if request and rec >= 0:  # a parameter request: remembered for its channel's responses
            i = int(self.rows[k])
            p, r = self.view.p, self.view.records.records
            ar = int(p.ar_hi[i]).to_bytes(8, "big") + int(p.ar_lo[i]).to_bytes(8, "big")
            channel = (dst, src, ar, int(p.api[i]), int(p.slot[i]), int(p.subslot[i]), int(p.index[i]))
            at, size = int(p.rec_start[i]), int(p.rec_len[i])
            unparsed = Unparsed(bytes(self.batch.buf[at:at + size]),
                                footprint_of(size, int(r.n_addr[rec]), int(r.n_blocks[rec])))
        return d.pass_pdu(self.frame[k], self.ts[k], self.ptype[k], (self.activity[k], self.seq[k]), src, dst,
                          self.interface[k], self.opnum[k], self.body[k],
                          self.record_len[k] if request and self.has_block[k] else -1, channel, unparsed)
