"""One large capture analysed in several processes (`--jobs N` on one classic pcap file).

Each part analyses a range of frames, replaying LEAD_IN seconds (at least the two timeouts) before it,
so calls and channels that cross the split are known, and reading past its end until everything it
opened in its range has closed; the parent stitches the parts in frame order.

Some dependencies reach further back than any lead-in: the value read before a change
(`changes.value_before`) and, for T1, a channel's last transaction. A part lists what it cannot
resolve (`PartRows`) and the parent fills it in from the parts before (`stitch_part`), so the tables
equal one process. Still bounded by the lead-in: a duplicate RPC PDU arriving more than LEAD_IN seconds
after its call closed is an orphan to the part, and an IP or CL fragment set that spans more than
LEAD_IN seconds is missing its earlier pieces.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from itertools import chain

from pd_analyze import capture
from pd_analyze.analysis.capture_run import CaptureResult, Settings, difference, snapshot
from pd_analyze.analysis.pipeline import run_frames
from pd_analyze.analysis.rows import Rows, finding_row
from pd_analyze.analysis.transaction import Element, LastDone, Transaction, reuse_finding
from pd_analyze.analysis.transactions import TransactionEngine
from pd_analyze.protocol.frames import Accounting

LEAD_IN = 20.0  # seconds of capture time a split part replays before its range (> txn + rpc timeouts)
PART_LEAD_INS = 10  # a split part spans at most this many lead-ins of capture time (a tenth replayed)


@dataclass(slots=True)
class PartRows(Rows):
    """The rows of one part, and what the parent needs to stitch them to the parts before.

    The part's range ends before frame `split_end` (None: at the end of the capture). It lists the
    changes whose value_before it does not know and the last value read per element (with the frame
    that closed the read), and the T1 checks its engine could not decide (the channel's last
    transaction lies before the lead-in) with each channel's last transaction in the range."""

    split_end: int | None = None
    engine: TransactionEngine | None = None
    unresolved: list[tuple[int, list[Element], list[str | None]]] = field(default_factory=list)
    reads: dict[Element, tuple[int, str]] = field(default_factory=dict)
    # (index in findings, capture, channel, ref, frame, txn) of each T1 check left to the parent
    reuse_slots: list[tuple[int, str, tuple, int, int, int]] = field(default_factory=list)
    channel_last: dict[tuple, LastDone] = field(default_factory=dict)

    def _in_range(self, frame: int) -> bool:
        return self.split_end is None or frame < self.split_end

    def _added(self, capture_path: str, txn: Transaction, number: int) -> None:
        slot = self.engine.history_unknown.pop(id(txn), None) if self.engine is not None else None
        if slot is not None:
            _txn, at, frame = slot
            self.reuse_slots.append((len(self.findings) + at, capture_path, txn.channel, txn.ref, frame, number))
        if txn.txn and self._in_range(txn.write_req_frame):
            self.channel_last[txn.channel] = LastDone(txn.write_req_frame, txn.ref, txn.verdict)

    def _read(self, txn: Transaction, pairs: list[tuple[Element, str]]) -> None:
        if self._in_range(txn.read_res_frame):
            self.reads.update((k, (txn.read_res_frame, v)) for k, v in pairs)

    def _before(self, keys: list[Element], before: list[str | None]) -> None:
        if not all(before):
            self.unresolved.append((len(self.changes), keys, before))


def stitch_part(part: PartRows, channels: dict[tuple, LastDone]) -> None:
    """T1 for the transactions whose channel's last transaction the part did not know: `channels` holds
    each channel's last transaction in the parts before; the part's own go there afterwards."""
    for at, capture_path, channel, ref, frame, number in reversed(part.reuse_slots):
        last = channels.get(channel)
        found = reuse_finding(last, ref, frame) if last is not None else None
        if found is not None:
            part.findings.insert(at, finding_row(capture_path, found, number))
    channels.update(part.channel_last)


def stitch_values_before(part: PartRows, known: dict[Element, tuple[int, str]]) -> None:
    """Fill in a split part's unknown `value_before` from `known` (the reads of the parts before it,
    each closed before this part's range began), then add the part's own reads to `known`."""
    for index, keys, before in part.unresolved:
        values = [b if b is not None else known.get(k, (0, None))[1] for k, b in zip(keys, before, strict=True)]
        if all(values):
            part.changes[index] = part.changes[index]._replace(value_before=" ".join(values))
    for key, (frame, value) in part.reads.items():
        if frame > known.get(key, (0, ""))[0]:
            known[key] = (frame, value)


def analyze_split(path: str, settings: Settings, jobs: int, rows: Rows) -> CaptureResult | None:
    """One large capture in `jobs` processes (None: not a file that can be split, analyse it whole)."""
    points = capture.pcap_split_points(path, jobs)
    if points is None:
        return None
    lead_in = max(LEAD_IN, settings.txn_timeout + settings.rpc_timeout)
    leads = _lead_points(points, lead_in)
    # A worker returns its part's rows whole: on a long capture, parts of at most PART_LEAD_INS lead-ins
    # (more parts than workers) keep that bounded whatever the length, at a lead-in's replay per part.
    duration = max(0.0, points[-1][2] - points[0][2])
    parts = max(jobs, min(len(points) // 2, math.ceil(duration / (PART_LEAD_INS * lead_in))))
    starts = _balanced_starts(leads, len(points), parts)
    tasks = []
    for k, start in enumerate(starts):
        lead = points[leads[start]]
        end = points[starts[k + 1]][0] if k + 1 < len(starts) else None
        tasks.append((path, lead[1], lead[0], points[start][0], end, settings))
    from concurrent.futures import ProcessPoolExecutor

    total = CaptureResult(path, Accounting())
    reads: dict[Element, tuple[int, str]] = {}  # the values read before the part at hand, per element
    channels: dict[tuple, LastDone] = {}  # the last transaction per channel before it
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for part_rows, result in pool.map(_analyze_range, tasks):  # in frame order, as they arrive
            stitch_values_before(part_rows, reads)
            stitch_part(part_rows, channels)
            rows.extend(part_rows, total.transactions)
            _add_part(total, result)
    return total


def _lead_points(points: list[tuple[int, int, float]], lead_in: float) -> list[int]:
    """For each split point, the latest point at least `lead_in` seconds of capture time before it
    (the first point when there is none): where a part starting there begins to replay."""
    out = []
    j = 0  # moves forward only while the times do (linear in the points)
    for i, (_number, _offset, ts) in enumerate(points):
        while j < i and points[j + 1][2] <= ts - lead_in:
            j += 1
        k = j
        while k > 0 and points[k][2] > ts - lead_in:  # the time went backwards: look further back
            k -= 1
        out.append(k)
    return out


def _balanced_starts(leads: list[int], count: int, jobs: int) -> list[int]:
    """The split points (indices) where the parts start, so that each reads about as many records,
    its lead-in included: the later parts get shorter ranges, as they replay more before them."""
    for work in range(-(-count // jobs), count + 1):
        starts = [0]
        for _ in range(jobs - 1):
            nxt = (leads[starts[-1]] if len(starts) > 1 else 0) + work
            if nxt <= starts[-1] or nxt >= count:
                break
            starts.append(nxt)
        if len(starts) == jobs and count - leads[starts[-1]] <= work:
            return starts
    step = count // jobs  # too few points to balance (lead-ins longer than the parts): equal ranges
    return [i * step for i in range(jobs)]


def _add_part(total: CaptureResult, result: CaptureResult) -> None:
    total.transactions += result.transactions
    acc = total.accounting
    acc.read += result.accounting.read
    acc.decoded += result.accounting.decoded
    acc.skipped += result.accounting.skipped
    acc.malformed += result.accounting.malformed
    total.error = total.error or result.error


def _analyze_range(task: tuple) -> tuple[PartRows, CaptureResult]:
    """Frames [first, end) of a split capture (a process-pool task)."""
    path, offset, lead_frame, first, end, settings = task
    d = settings.dissector()
    engine = settings.engine()
    engine.number_from = first
    result = CaptureResult(path, Accounting())
    marks: dict[str, Accounting] = {}
    horizon = [float("inf")]

    def settled() -> bool:
        """Nothing opened in the range is still open: no later frame can change its rows."""
        return not any(first <= n < end for n in chain(d.open_frames(), engine.open_frames()))

    def source() -> Iterator[capture.RawFrame]:
        frames = capture.pcap_frames_from(path, offset, lead_frame, ip_only=True)
        for frame in capture.cut_runs(frames, (first, end or first)):
            number = frame.number - frame.run + 1 if frame.run else frame.number  # the record's first frame
            if number == first:
                marks["start"] = snapshot(d.accounting)
            if end is not None and number == end:
                marks["end"] = snapshot(d.accounting)
                horizon[0] = frame.ts + settings.txn_timeout + settings.rpc_timeout
            if "end" in marks and (settled() or frame.ts > horizon[0]):
                return  # beyond the horizon, what is still open stays so (as at the end of a capture)
            yield frame

    part = PartRows(split_end=end, engine=engine)

    def in_range(frame: int) -> bool:
        return frame >= first and (end is None or frame < end)

    run_frames(source(), d, engine, part, lambda _frame: path, [result], None)
    closing = marks.get("end", snapshot(d.accounting))
    result.accounting = difference(closing, marks.get("start", Accounting()))
    rows = PartRows(split_end=end)
    rows.transactions = [r for r in part.transactions if r.txn and in_range(r.write_req_frame)]  # txn 0: lead-in
    numbered = {r.txn for r in rows.transactions}
    rows.parameters = [r for r in part.parameters if r.txn in numbered]
    moved: dict[int, int] = {}  # index in part.changes -> index in rows.changes
    for i, row in enumerate(part.changes):
        if row.txn in numbered:
            moved[i] = len(rows.changes)
            rows.changes.append(row)
    rows.unresolved = [(moved[i], keys, before) for i, keys, before in part.unresolved if i in moved]
    rows.reads = part.reads
    kept_before = [0]  # kept_before[i]: findings kept among part.findings[:i], to move the T1 slots
    for r in part.findings:
        if (r.txn in numbered) or (r.txn is None and in_range(r.frame)):
            rows.findings.append(r)
        kept_before.append(len(rows.findings))
    rows.reuse_slots = [(kept_before[at], *rest) for at, *rest in part.reuse_slots if rest[-1] in numbered]
    rows.channel_last = part.channel_last
    result.transactions = len(rows.transactions)
    return rows, result
