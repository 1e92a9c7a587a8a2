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
from pd_analyze.analysis.engine.decode import Decoded, Decoder
from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.capture import CaptureError
from pd_analyze.capture.batches import FrameBatch, batches
from pd_analyze.model.rules import Finding
from pd_analyze.model.values import PTYPE_REQUEST
from pd_analyze.output import dump_prefilter
from pd_analyze.output.column_fields import PartFields
from pd_analyze.output.display_filter import DisplayFilter
from pd_analyze.output.dump import Clock
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


class DumpFrames:
    """The frame results of one capture file as the dump prints them, in frame order (`results`), and the
    report's findings at frames that are not PNIO RPC (`loose`, with `loose_dropped` beyond the first
    MAX_LOOSE_FINDINGS)."""

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
        self._ready: list[tuple[int, int, FrameResult]] = []  # a heap of (frame, tie, result) to print
        self._tie = 0
        self._notes: dict[int, FrameNote] = {}  # the notes of the frames read, not yet passed
        self._pnio: list[np.ndarray] = []  # PNIO RPC frames read, not yet passed (their findings are not loose)

    def timed(self, results: Iterator[FrameResult], clock: Clock) -> Iterator[FrameResult]:
        """The results, `clock` counting relative times from the capture's first PNIO RPC frame."""
        for res in results:
            if clock.first is None:
                clock.first = self.first_ts
            yield res

    # --- the loop --------------------------------------------------------------------------------------
    def results(self, selection: Selection) -> Iterator[FrameResult]:
        """The printed frames; CaptureError after those before the damage."""
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
                    yield from self._part(self.odd.decode(part_batch, view), selection)
        except CaptureError:  # the frames before the damage first (not on GeneratorExit: a closed pipe)
            yield from self._end(last, selection)
            raise
        yield from self._end(last, selection)

    def _end(self, last: int, selection: Selection) -> Iterator[FrameResult]:
        """The frames the per-frame dissector still held, and every result not yet released."""
        rows, _loose = self.odd.finish(last)
        self._odd_results([row.raw for row in rows], selection)
        self._notes.update((n.frame, n) for n in self.facts.notes.upto(1 << 62))
        yield from self._release(None)

    def _part(self, part: Decoded, selection: Selection) -> Iterator[FrameResult]:
        batch, view = part.batch, part.view
        self._notes.update((n.frame, n) for n in self.facts.notes.upto(int(batch.number[-1])))
        rows = part.rows
        frames = view.frame_no[rows]
        self._pnio.append(frames)
        if self.first_ts is None:
            times = [float(view.ts[rows[0]])] if len(rows) else []
            times += [row.raw.ts for row in part.odd_rows if row.raw is not None and self._is_pnio(row.raw)]
            self.first_ts = min(times) if times else None
        chosen = selection.columns(part, rows, self._notes, self.links)
        alone = self.alone
        for i in rows[chosen].tolist():
            found = alone.feed(batch.raw_frame(int(view.p.pos[i])))
            res = found[0] if found else None
            if res is not None and (not selection.per_frame or selection.frame(res, self._notes.get(res.frame))):
                self._push(res)
        self._odd_results([row.raw for row in part.odd_rows], selection)
        held = self.odd.d.hold.first_held() if self.odd.d.hold is not None else 0
        yield from self._release(held or int(batch.number[-1]) + 1)

    def _push(self, res: FrameResult) -> None:
        self._tie += 1
        heapq.heappush(self._ready, (res.frame, self._tie, res))

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

    def _release(self, before: int | None) -> Iterator[FrameResult]:
        """The results of the frames before `before` (all: None), in frame order, with their findings; the
        findings of the frames before it that are not PNIO RPC go to `loose`."""
        ready, notes = self._ready, self._notes
        while ready and (before is None or ready[0][0] < before):
            frame, _tie, res = heapq.heappop(ready)
            note = notes.get(frame)
            res.findings = [f.finding(frame) for f in note.findings] if note is not None else []
            mark_checks(res, CHECKED_FIELDS)
            yield res
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
