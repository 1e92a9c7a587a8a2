"""The dump of a capture file, second pass: the frames it prints, dissected with the report's pairing and shown
with the report's findings (output.dump_facts read them first).

The capture is read batch by batch as the engine reads it (analysis.engine.decode): the column decode routes
every frame; the frames it cannot decode (fragments, cut or damaged frames, other link types, ...) go to one
per-frame dissector in frame order, as the engine's do, so reassembly is the same; a frame the columns decode
is dissected alone, and only when it is printed (or a selection needs its fields). A dissector told the
pairing (protocol.links) keeps nothing of one frame for the next, so a frame's tree is the same whichever
frames are printed: `dump -Y` prints the frames the full dump prints, byte for byte. Each printed frame's
findings are those the report has at it, in the findings table's order, and mark its fields.

Which frames are printed is a `Selection`'s choice: every PNIO RPC frame, those with a finding, those a
display filter matches (judged on the columns, and frame by frame where the columns cannot tell).
"""

from __future__ import annotations

import heapq
from collections.abc import Iterator

import numpy as np

from pd_analyze.analysis.capture_run import Settings
from pd_analyze.analysis.engine.decode import Decoded, Decoder, column_rows
from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.capture import CaptureError
from pd_analyze.capture.batches import FrameBatch, batches
from pd_analyze.model.rules import Finding
from pd_analyze.model.values import PTYPE_REQUEST
from pd_analyze.output import dump_prefilter
from pd_analyze.output.column_fields import PartFields
from pd_analyze.output.display_filter import DisplayFilter
from pd_analyze.output.dump import Clock, FrameSpool, Spooled
from pd_analyze.output.dump_facts import DumpFacts, FileLinks
from pd_analyze.output.frame_notes import FrameNote
from pd_analyze.output.frame_view import ANALYSIS, FrameView
from pd_analyze.protocol.dissector import MAX_LOOSE_FINDINGS, Dissector
from pd_analyze.protocol.frames import FrameResult, mark_checks
from pd_analyze.protocol.pnio_checks import CHECKED_FIELDS
from pd_analyze.protocol.profidrive_checks import Checker


def in_ranges(frames: np.ndarray, ranges: list[tuple[int, int]]) -> np.ndarray:
    """Per frame number: within one of the --frames ranges (every frame when none is given)?"""
    if not ranges:
        return np.ones(len(frames), bool)
    out = np.zeros(len(frames), bool)
    for lo, hi in ranges:
        out |= (frames >= lo) & (frames <= hi)
    return out


class Selection:
    """Which frames the dump prints (every PNIO RPC frame in `ranges`, all when empty)."""

    per_frame = False  # the column rows must be dissected to be judged (a field the columns do not hold)
    needs_txns = False  # it reads txn.* (the transactions noted at their frames)

    def __init__(self, ranges: list[tuple[int, int]] | None = None) -> None:
        self.ranges = ranges or []

    def wanted(self, frames: np.ndarray) -> np.ndarray:
        return in_ranges(frames, self.ranges)

    def columns(self, part: Decoded, rows: np.ndarray, notes: dict[int, FrameNote], links: FileLinks) -> np.ndarray:
        """Per column row `rows` (indices into the part's PDU columns, frame order): printed? (per_frame: may
        it be printed: the rows to dissect and judge by `frame`)"""
        return self.wanted(part.view.frame_no[rows])

    def frame(self, res: FrameResult, note: FrameNote | None) -> bool:
        """A dissected frame (and its note): printed?"""
        return bool(self.wanted(np.array([res.frame]))[0])


class WithFindings(Selection):
    """The frames the report has a finding at (`dump --findings-only`)."""

    def columns(self, part: Decoded, rows: np.ndarray, notes: dict[int, FrameNote], links: FileLinks) -> np.ndarray:
        frames = part.view.frame_no[rows]
        noted = np.fromiter((f for f, n in notes.items() if n.findings), np.int64)
        return self.wanted(frames) & np.isin(frames, noted)

    def frame(self, res: FrameResult, note: FrameNote | None) -> bool:
        return note is not None and bool(note.findings) and super().frame(res, note)


class Filtered(Selection):
    """The frames a display filter matches (`dump -Y`), those with a finding among them (`findings_only`).
    The filter is judged on the columns first (output.dump_prefilter): a row it certainly matches is printed
    without being judged again, one it certainly does not match is not dissected, and only the rows the
    columns cannot decide (and the frames they do not decode) are judged on their trees."""

    per_frame = True

    def __init__(self, flt: DisplayFilter, ranges: list[tuple[int, int]] | None = None,
                 findings_only: bool = False) -> None:
        super().__init__(ranges)
        self.flt, self.findings_only = flt, findings_only
        self.needs_txns = any(r.kind == ANALYSIS and r.names[0].startswith("txn.") for r in flt.refs)
        self._judge = dump_prefilter.candidates_of(flt)
        self._sure: set[int] = set()  # frames of the part the columns judged matched

    def columns(self, part: Decoded, rows: np.ndarray, notes: dict[int, FrameNote], links: FileLinks) -> np.ndarray:
        view = part.view
        frames = view.frame_no[rows]
        out = self.wanted(frames)
        if self.findings_only:
            out &= np.isin(frames, np.fromiter((f for f, n in notes.items() if n.findings), np.int64))
        if dump_prefilter.per_frame_forced():
            self._sure = set()
            return out
        fields = PartFields(view, rows, dump_prefilter.stub_known_by_links(view, rows, links))
        sure, maybe = self._judge(dump_prefilter.Rows(fields, frames, view.ts[rows], notes))
        self._sure = set(frames[out & sure].tolist())
        return out & (sure | maybe)

    def frame(self, res: FrameResult, note: FrameNote | None) -> bool:
        if self.findings_only and (note is None or not note.findings):
            return False
        if res.frame in self._sure:
            return True
        return super().frame(res, note) and self.flt.matches(FrameView(res.frame, res.ts, res, None, note))


CHUNK_FRAMES = 256  # frames of a part walked at once (DumpFrames)
HELD_RESULTS = 512  # results held at once at most (DumpFrames with a FrameSpool): the others wait on disk


class DumpFrames:
    """The frame results of one capture file as the dump prints them, in frame order (`results`), and the
    report's findings at frames that are not PNIO RPC (`loose`, with `loose_dropped` beyond the first
    MAX_LOOSE_FINDINGS).

    A part of a batch (up to a batch of frames) is walked CHUNK_FRAMES frames at a time: the chunk's odd
    frames go to the per-frame dissector, its printed column rows are dissected, and every result before
    the next chunk leaves at once, unless the per-frame dissector holds a frame back (a fragment waiting
    for the frame that reassembles its PDU): the results after it wait for it, beyond HELD_RESULTS written
    ahead to a `dump.FrameSpool` (when `results` is given one). So the results held at once (`held_most`) are
    a chunk's, at most HELD_RESULTS, whatever the part's size; the report's notes of the part's frames are
    kept as before (the selection judges the part's rows at once)."""

    def __init__(self, path: str, settings: Settings, checker: Checker, facts: DumpFacts) -> None:
        self.path, self.settings, self.facts = path, settings, facts
        self.checker = checker
        self.links = links = facts.links
        self.odd = Decoder(Dissector(annotate=True, rpc_timeout=settings.rpc_timeout, checker=checker, links=links))
        self.alone = Dissector(annotate=True, rpc_timeout=settings.rpc_timeout, checker=checker, links=links)
        quiet = Dissector(annotate=False, rpc_timeout=settings.rpc_timeout, checker=checker, links=links)
        links.dissect = lambda raw: next(iter(quiet.feed(raw)), None)
        self.loose: list[Finding] = []
        self.loose_dropped = 0
        self.first_ts: float | None = None  # the first PNIO RPC frame's time (dump -t r counts from it)
        self.held_most = 0  # the most results held at once, waiting to be printed in frame order
        self._ready: list[tuple[int, int, FrameResult | Spooled]] = []  # a heap of (frame, tie, result) to print
        self._live = 0  # results in it (not Spooled)
        self._spool: FrameSpool | None = None
        self._tie = 0
        self._notes: dict[int, FrameNote] = {}  # the notes of the frames read, not yet passed
        self._pnio: list[np.ndarray] = []  # PNIO RPC frames read, not yet passed (their findings are not loose)

    def timed(self, results: Iterator[FrameResult | Spooled], clock: Clock) -> Iterator[FrameResult | Spooled]:
        """The results, `clock` counting relative times from the capture's first PNIO RPC frame."""
        for res in results:
            if clock.first is None:
                clock.first = self.first_ts
            yield res

    # --- the loop --------------------------------------------------------------------------------------
    def results(self, selection: Selection, spool: FrameSpool | None = None) -> Iterator[FrameResult | Spooled]:
        """The printed frames; CaptureError after those before the damage. With a `spool`, the frames that
        must wait beyond HELD_RESULTS are written to it ahead of their turn (dump.render takes them back)."""
        self._spool = spool
        source = batches(self.path, self.settings.batch_frames) if self.settings.batch_frames else \
            batches(self.path)
        last = 0
        try:
            for batch in source:
                if not len(batch):
                    continue
                last = int(batch.number[-1])
                for part_batch, view in BatchView.parts(batch, self.checker):
                    self._learn(part_batch, view)
                    yield from self._part(part_batch, view, selection)
        except CaptureError:  # the frames before the damage first (not on GeneratorExit: a closed pipe)
            yield from self._end(last, selection)
            raise
        yield from self._end(last, selection)

    def _end(self, last: int, selection: Selection) -> Iterator[FrameResult | Spooled]:
        """The frames the per-frame dissector still held, and every result not yet released."""
        rows, _loose = self.odd.finish(last)
        self._odd_results([row.raw for row in rows], selection)
        self._notes.update((n.frame, n) for n in self.facts.notes.upto(1 << 62))
        yield from self._release(None)
        self._settle(None)

    def _part(self, batch: FrameBatch, view: BatchView, selection: Selection) -> Iterator[FrameResult | Spooled]:
        """One part, chunk by chunk (the class's docstring). Its rows are chosen at once, before its odd
        frames are dissected: a response whose request is one of those frames is then not known to be
        decoded as the columns decode it (dump_prefilter.stub_known_by_links) and is judged on its tree."""
        self._notes.update((n.frame, n) for n in self.facts.notes.upto(int(batch.number[-1])))
        rows, odd = column_rows(view)
        self._pnio.append(view.frame_no[rows])
        whole = Decoded(batch, view, rows, odd)
        chosen = rows[selection.columns(whole, rows, self._notes, self.links)]
        # the first PNIO RPC frame's time: the least of the part's first column row's and its odd PNIO
        # frames' (min() in that order), known once no odd frame left in the part can be earlier
        first = self.first_ts is None
        least = float(view.ts[rows[0]]) if first and len(rows) else None
        odd_ts = batch.ts[odd]
        later = np.minimum.accumulate(np.where(np.isnan(odd_ts), np.inf, odd_ts)[::-1])[::-1] if first else odd_ts
        bounds = np.append(np.arange(0, len(batch), CHUNK_FRAMES), len(batch))  # the chunks' batch positions
        pos = view.p.pos
        at_rows, at_chosen = np.searchsorted(pos[rows], bounds), np.searchsorted(pos[chosen], bounds)
        at_odd = np.searchsorted(odd, bounds)
        alone, notes = self.alone, self._notes
        for k in range(len(bounds) - 1):
            stop, o1 = int(bounds[k + 1]), int(at_odd[k + 1])
            chunk = Decoded(batch, view, rows[at_rows[k]:at_rows[k + 1]], odd[at_odd[k]:o1])
            self.odd._odd_rows(chunk)  # (Decoder.decode's walk of a part's odd frames, a chunk at a time)
            mine = chosen[at_chosen[k]:at_chosen[k + 1]]
            for i in mine.tolist():
                found = alone.feed(batch.raw_frame(int(pos[i])))
                res = found[0] if found else None
                if res is not None and (not selection.per_frame or selection.frame(res, notes.get(res.frame))):
                    self._push(res)
            odd_results = [row.raw for row in chunk.odd_rows]
            self._odd_results(odd_results, selection)
            if first:
                for res in odd_results:
                    if res is not None and self._is_pnio(res) and (least is None or res.ts < least):
                        least = res.ts
                if least is not None and (least != least  # (NaN: nothing is less)
                                          or (not self._held() and (o1 == len(odd) or later[o1] >= least))):
                    self.first_ts, first = least, False
            if not first:
                yield from self._release(self._held() or int(batch.number[stop - 1]) + 1)
        if first:
            self.first_ts = least
            yield from self._release(self._held() or int(batch.number[-1]) + 1)
        self._settle(self._held() or int(batch.number[-1]) + 1)

    def _held(self) -> int:
        """The first frame the per-frame dissector holds back (0: none)."""
        hold = self.odd.d.hold
        return hold.first_held() if hold is not None else 0

    def _push(self, res: FrameResult) -> None:
        self._tie += 1
        if self._spool is not None and self._live >= HELD_RESULTS:
            self._finish(res)  # (nothing changes a result once it is pushed: its text can be written now)
            heapq.heappush(self._ready, (res.frame, self._tie, self._spool.put(res)))
            return
        heapq.heappush(self._ready, (res.frame, self._tie, res))
        self._live += 1
        if self._live > self.held_most:
            self.held_most = self._live

    def _odd_results(self, results: list, selection: Selection) -> None:
        pnio = []
        for res in results:
            if res is None or not self._is_pnio(res):
                continue
            pnio.append(res.frame)
            if selection.frame(res, self._notes.get(res.frame)):
                self._push(res)
        if pnio:
            self._pnio.append(np.array(pnio, np.int64))

    def _is_pnio(self, res: FrameResult) -> bool:
        return not res.decide or res.frame in self.links.decided

    def _release(self, before: int | None) -> Iterator[FrameResult | Spooled]:
        """The results of the frames before `before` (all: None), in frame order, with their findings."""
        ready = self._ready
        while ready and (before is None or ready[0][0] < before):
            res = heapq.heappop(ready)[2]
            if res.__class__ is not Spooled:
                self._live -= 1
                self._finish(res)  # type: ignore[arg-type]
            yield res

    def _finish(self, res: FrameResult) -> None:
        """A result as printed: the report's findings at its frame, and the fields they mark."""
        note = self._notes.get(res.frame)
        res.findings = [f.finding(res.frame) for f in note.findings] if note is not None else []
        mark_checks(res, CHECKED_FIELDS)

    def _settle(self, before: int | None) -> None:
        """The notes of the frames before `before` (all: None) are done with: the findings of those that are
        not PNIO RPC go to `loose`."""
        notes = self._notes
        passed = [f for f in notes if before is None or f < before]
        pnio = np.concatenate(self._pnio) if self._pnio else np.empty(0, np.int64)
        noted = np.array([f for f in passed if notes[f].findings], np.int64)
        for frame in noted[~np.isin(noted, pnio)].tolist():
            self._lose([f.finding(frame) for f in notes[frame].findings])
        for frame in passed:
            del notes[frame]
        self._pnio = [pnio[pnio >= before]] if before is not None else []

    def _lose(self, findings: list[Finding]) -> None:
        room = max(MAX_LOOSE_FINDINGS - len(self.loose), 0)
        self.loose += findings[:room]
        self.loose_dropped += max(len(findings) - room, 0)

    # --- what later frames ask -------------------------------------------------------------------------
    def _learn(self, batch: FrameBatch, view: BatchView) -> None:
        """What later frames ask of the requests the columns decode in this part (before its odd frames are
        dissected): their time and operation, their records (kept as raw frames, dissected when a printed
        response asks), their keys (control PDUs ask). The dissectors tell the links of the requests they
        decode themselves (Links.request_seen)."""
        links, p = self.links, view.p
        rows = np.flatnonzero(view.pnio & (p.ptype == PTYPE_REQUEST))
        if not len(rows):
            return
        frames, ts = view.frame_no[rows], view.ts[rows]
        links.forget_before(int(frames[0]), float(ts[0]))
        wanted = links.is_request(frames)
        for frame, t, op in zip(frames[wanted].tolist(), ts[wanted].tolist(), p.opnum[rows[wanted]].tolist(),
                                strict=True):
            links.seen[frame] = (t, op)
        keep = links.is_parameter_request(frames)
        for i, frame in zip(rows[keep].tolist(), frames[keep].tolist(), strict=True):
            links.kept[frame] = batch.raw_frame(int(p.pos[i]))
        hi = p.act_hi[rows].astype(">u8").tobytes()
        lo = p.act_lo[rows].astype(">u8").tobytes()
        links.recent += [(hi[8 * k:8 * k + 8] + lo[8 * k:8 * k + 8], seq, frame, t) for k, (frame, seq, t) in
                         enumerate(zip(frames.tolist(), p.seq[rows].tolist(), ts.tolist(), strict=True))]
