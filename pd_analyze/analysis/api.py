"""The Python API: `analyze(paths)` runs the whole pipeline and returns tidy pandas tables.

    import pd_analyze
    a = pd_analyze.analyze("trace.pcapng", profile="sinamics")
    a.transactions.verdict.value_counts()
    a.parameters.query("error != ''")
    a.fields(12)             # frames and fields of transaction 12, for drill-down
"""

from __future__ import annotations

import glob
import math
import os
from bisect import bisect_right
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from functools import cached_property
from itertools import chain
from typing import TYPE_CHECKING

from pd_analyze import capture
from pd_analyze.analysis.drilldown import annotated_frames
from pd_analyze.analysis.rows import COLUMNS, Rows, frame_of, stitch_part, stitch_values_before
from pd_analyze.analysis.transactions import DEFAULT_TXN_TIMEOUT, LastDone, Transaction, TransactionEngine, iter_closed
from pd_analyze.capture import CaptureError
from pd_analyze.protocol import profiles
from pd_analyze.protocol.dissector import DEFAULT_RPC_TIMEOUT, Dissector, dissect_frames
from pd_analyze.protocol.frames import Accounting
from pd_analyze.protocol.profidrive_checks import Checker

if TYPE_CHECKING:
    import pandas as pd

CAPTURE_SUFFIXES = (".pcap", ".pcapng", ".cap", ".pcap.gz", ".pcapng.gz", ".gz")


@dataclass(slots=True)
class CaptureResult:
    path: str
    accounting: Accounting
    error: str = ""
    transactions: int = 0


@dataclass
class Analysis:
    """The tables of one or more captures, built once from rows."""

    rows: Rows
    captures: list[CaptureResult]
    profile: str
    txn_timeout: float
    rpc_timeout: float
    _cache: dict = field(default_factory=dict, repr=False)

    @cached_property
    def transactions(self) -> pd.DataFrame:
        return frame_of("transactions", self.rows.transactions)

    @cached_property
    def parameters(self) -> pd.DataFrame:
        return frame_of("parameters", self.rows.parameters)

    @cached_property
    def findings(self) -> pd.DataFrame:
        return frame_of("findings", self.rows.findings)

    @cached_property
    def changes(self) -> pd.DataFrame:
        return frame_of("changes", self.rows.changes)

    @cached_property
    def accounting(self) -> pd.DataFrame:
        """Per capture: frames read = decoded + skipped + malformed, and why frames were skipped."""
        return accounting_frame(self.captures)

    @property
    def errors(self) -> list[str]:
        return [f"{c.path}: {c.error}" for c in self.captures if c.error]

    def fields(self, txn: int) -> pd.DataFrame:
        """Every field of every frame of one transaction (the dump, as a table): drill-down."""
        import pandas as pd

        row = self.transactions.loc[self.transactions.txn == txn]
        if row.empty:
            raise KeyError(f"no transaction {txn}")
        capture = str(row.capture.iloc[0])
        frames = {int(n) for n in str(row.frames.iloc[0]).split()}
        out = []
        for res in annotated_frames(capture, frames, self.profile, self.rpc_timeout):
            for layer in res.layers:
                out += [{"frame": res.frame, "layer": layer.title, "name": f.name, "offset": f.offset,
                         "length": f.length, "raw": f.raw.hex(" "), "value": f.value, "show": f.show,
                         "check": f.check} for f in layer.fields]
        return pd.DataFrame(out)


ACCOUNTING_COLUMNS = {  # name: dtype
    "capture": "str", "read": "int64", "decoded": "int64", "skipped": "int64", "malformed": "int64",
    "balanced": "bool", "transactions": "int64", "error": "str", "skipped_by_reason": "object",
    "malformed_by_reason": "object"}


def accounting_frame(captures: Iterable[CaptureResult]) -> pd.DataFrame:
    """Per capture: frames read = decoded + skipped + malformed, and why frames were skipped or malformed."""
    import pandas as pd

    return pd.DataFrame([(
        c.path, c.accounting.read, c.accounting.decoded, sum(c.accounting.skipped.values()),
        sum(c.accounting.malformed.values()), c.accounting.balanced(), c.transactions, c.error,
        dict(c.accounting.skipped), dict(c.accounting.malformed)) for c in captures],
        columns=list(ACCOUNTING_COLUMNS)).astype(ACCOUNTING_COLUMNS)


def expand(paths: str | Iterable[str]) -> list[str]:
    """Files, directories (their captures, sorted) and glob patterns to a list of capture paths."""
    items = [paths] if isinstance(paths, str) else list(paths)
    out: list[str] = []
    for item in items:
        if item != "-" and os.path.isdir(item):
            out += sorted(os.path.join(item, n) for n in os.listdir(item)
                          if n.endswith(CAPTURE_SUFFIXES) and os.path.isfile(os.path.join(item, n)))
        elif any(ch in item for ch in "*?[") and not os.path.exists(item):
            out += sorted(glob.glob(item, recursive=True))
        else:
            out.append(item)
    return out


def analyze(paths: str | Iterable[str], profile: str = profiles.DEFAULT, timeout: float = DEFAULT_TXN_TIMEOUT,
            rpc_timeout: float = DEFAULT_RPC_TIMEOUT, progress: Callable[[str, int], None] | None = None,
            jobs: int = 1, chain: bool = False) -> Analysis:
    """Analyse captures (files, directories or globs) and return the tables as an Analysis.

    `jobs` > 1 analyses files in parallel processes; the tables are identical to one process
    (transactions numbered in file order). `chain` treats the files as one capture continued across
    files (a ring-buffer set, as `mergecap -a` would join them): frame numbers run on across the set
    and a transaction split over two files is still paired.
    A damaged capture keeps every result before the damage; its error is in `Analysis.errors`
    and in the `error` column of `Analysis.accounting`.
    """
    profiles.load(profile)  # an unknown profile fails here, before any work
    rows = Rows()
    results = run(expand(paths), rows, (profile, timeout, rpc_timeout), progress, jobs, chain)
    return Analysis(rows, results, profile, timeout, rpc_timeout)


def run(files: list[str], rows: Rows, settings: tuple[str, float, float],
        progress: Callable[[str, int], None] | None = None, jobs: int = 1, chain: bool = False) -> list[CaptureResult]:
    """The pipeline over capture files, every row handed to `rows` (lists for `analyze()`, spools for
    the streaming report): one way through for both, so their tables cannot differ.

    Settings are (profile, timeout, rpc_timeout). One process streams frame by frame; the parallel
    paths (`jobs` > 1) get each file's or part's rows from the workers and hand them on in order."""
    if chain:
        return _analyze_chain(files, settings, progress, rows)
    if jobs > 1 and ("-" in files or _input_bytes(files) < PARALLEL_MIN_BYTES):
        jobs = 1  # standard input is one stream; for small files, process start-up and shipping the rows
        # back would cost more than the files take
    if jobs > 1 and len(files) == 1:
        split = _analyze_split(files[0], settings, jobs, rows)
        if split is not None:
            return [split]
    results: list[CaptureResult] = []
    if jobs > 1 and len(files) > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=min(jobs, len(files))) as pool:
            # merged in file order as results arrive: numbering does not depend on scheduling
            for part_rows, result in pool.map(_analyze_file, files, [settings] * len(files)):
                rows.extend(part_rows, sum(r.transactions for r in results))
                results.append(result)
        return results
    for path in files:
        rows.new_capture()
        _, result = _analyze_file(path, settings, progress, rows, sum(r.transactions for r in results))
        results.append(result)
    return results


PARALLEL_MIN_BYTES = 8 * 1024 * 1024  # captures smaller than this in all are analysed in one process


def _input_bytes(files: list[str]) -> int:
    """Capture bytes to analyse (a gzip file counted as its typical decompressed size)."""
    total = 0
    for path in files:
        try:
            total += os.path.getsize(path) * (5 if path.endswith(".gz") else 1)
        except OSError:
            total += PARALLEL_MIN_BYTES  # unreadable: its error is reported where it is read
    return total


def _analyze_file(path: str, settings: tuple[str, float, float],
                  progress: Callable[[str, int], None] | None = None, rows: Rows | None = None,
                  offset: int = 0) -> tuple[Rows, CaptureResult]:
    """One capture, numbered from transaction `offset` + 1 (a process-pool task: arguments and result pickle)."""
    profile, timeout, rpc_timeout = settings
    checker = Checker.for_profile(profile)
    rows = Rows() if rows is None else rows
    d = Dissector(annotate=False, rpc_timeout=rpc_timeout, checker=checker)
    result = CaptureResult(path, d.accounting)
    frames = capture.frames(path, ip_only=True)
    _run(frames, d, TransactionEngine(timeout), rows, lambda _frame: path, [result], progress, offset)
    return rows, result


LEAD_IN = 20.0  # seconds of capture time a split part replays before its range (> txn + rpc timeouts)
PART_LEAD_INS = 10  # a split part spans at most this many lead-ins of capture time (a tenth replayed)


def _analyze_split(path: str, settings: tuple[str, float, float], jobs: int, rows: Rows) -> CaptureResult | None:
    """One large capture in `jobs` processes: each part analyses a range of frames, replaying LEAD_IN
    seconds (at least the two timeouts) before it, so calls and channels that cross the split are
    known, and reading past its end until everything opened in its range has closed; parts are
    stitched in frame order.

    Some dependencies reach further back than any lead-in: the value read before a change
    (`changes.value_before`), for T1 a channel's last transaction, and the numbers of transactions
    messages name. A part lists what it cannot resolve and marks those numbers, and the parent fills
    them in from the parts before (`stitch_values_before`, `stitch_part`), so the tables equal one
    process. Still bounded by the lead-in: a duplicate RPC PDU arriving more than LEAD_IN seconds
    after its call closed is an orphan to the part, and an IP or CL fragment set that spans more
    than LEAD_IN seconds is missing its earlier pieces."""
    points = capture.pcap_split_points(path, jobs)
    if points is None:
        return None
    lead_in = max(LEAD_IN, settings[1] + settings[2])
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
    reads: dict[tuple, tuple[int, str]] = {}  # the values read before the part at hand, per element
    channels: dict[tuple, LastDone] = {}  # the last transaction per channel before it
    numbers: dict[int, int] = {}  # transaction numbers by write request frame, for the next lead-in
    next_leads = [task[2] for task in tasks[1:]] + [0]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        parts = pool.map(_analyze_range, tasks)
        for (part_rows, result), keep_from in zip(parts, next_leads, strict=True):  # in frame order, as they arrive
            stitch_values_before(part_rows, reads)
            stitch_part(part_rows, total.transactions, channels, numbers, keep_from)
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


def _analyze_range(task: tuple) -> tuple[Rows, CaptureResult]:
    """Frames [first, end) of a split capture (a process-pool task)."""
    path, offset, lead_frame, first, end, (profile, timeout, rpc_timeout) = task
    checker = Checker.for_profile(profile)
    d = Dissector(annotate=False, rpc_timeout=rpc_timeout, checker=checker)
    engine = TransactionEngine(timeout)
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
                marks["start"] = _snapshot(d.accounting)
            if end is not None and number == end:
                marks["end"] = _snapshot(d.accounting)
                horizon[0] = frame.ts + timeout + rpc_timeout
            if "end" in marks and (settled() or frame.ts > horizon[0]):
                return  # beyond the horizon, what is still open stays so (as at the end of a capture)
            yield frame

    rows = Rows()
    part = Rows(split_end=end)

    def in_range(frame: int) -> bool:
        return frame >= first and (end is None or frame < end)

    _run(source(), d, engine, part, lambda _frame: path, [result], None)
    closing = marks.get("end", _snapshot(d.accounting))
    result.accounting = _difference(closing, marks.get("start", Accounting()))
    write_frame = [c.name for c in COLUMNS["transactions"]].index("write_req_frame")
    rows.transactions = [r for r in part.transactions if r[0] and in_range(r[write_frame])]  # txn 0: lead-in
    numbered = {r[0] for r in rows.transactions}
    rows.parameters = [r for r in part.parameters if r[0] in numbered]
    moved: dict[int, int] = {}  # index in part.changes -> index in rows.changes
    for i, row in enumerate(part.changes):
        if row[3] in numbered:
            moved[i] = len(rows.changes)
            rows.changes.append(row)
    rows.unresolved = [(moved[i], keys, before) for i, keys, before in part.unresolved if i in moved]
    rows.reads = part.reads
    kept_before = [0]  # kept_before[i]: findings kept among part.findings[:i], to move the T1 slots
    for r in part.findings:
        if (r[2] in numbered) or (r[2] is None and in_range(r[1])):
            rows.findings.append(r)
        kept_before.append(len(rows.findings))
    rows.reuse_slots = [(kept_before[at], *rest) for at, *rest in part.reuse_slots if rest[-1] in numbered]
    rows.channel_last = part.channel_last
    result.transactions = len(rows.transactions)
    return rows, result


def _analyze_chain(files: list[str], settings: tuple[str, float, float],
                   progress: Callable[[str, int], None] | None, rows: Rows) -> list[CaptureResult]:
    profile, timeout, rpc_timeout = settings
    checker = Checker.for_profile(profile)
    d = Dissector(annotate=False, rpc_timeout=rpc_timeout, checker=checker)
    results: list[CaptureResult] = []
    starts: list[int] = []  # first global frame number of each file

    def frames() -> Iterator[capture.RawFrame]:
        offset = 0
        for path in files:
            before = _snapshot(d.accounting)
            starts.append(offset + 1)
            result = CaptureResult(path, Accounting())
            results.append(result)
            try:
                for frame in capture.frames(path, ip_only=True):
                    offset += frame.run or 1  # a run of skipped frames ends at its number
                    yield frame._replace(number=offset)
            except CaptureError as exc:
                result.error = _error_text(exc)
            result.accounting = _difference(d.accounting, before)

    def capture_of(frame: int) -> str:
        return files[max(0, bisect_right(starts, frame) - 1)] if files else ""

    _run(frames(), d, TransactionEngine(timeout), rows, capture_of, results, progress)
    return results


def _run(source: Iterable[capture.RawFrame], d: Dissector, engine: TransactionEngine, rows: Rows,
         capture_of: Callable[[int], str], results: list[CaptureResult],
         progress: Callable[[str, int], None] | None, offset: int = 0) -> None:
    """The frame loop: dissector -> transaction engine -> rows (transactions numbered after `offset`)."""
    last = [float("-inf")]

    def frames() -> Iterator:
        for res in dissect_frames(source, d):
            if progress is not None:
                progress(results[-1].path, d.accounting.read)
            yield res
            _drain(engine, d, rows, capture_of)

    def add(txn: Transaction) -> None:
        path = capture_of(txn.write_req_frame)
        rows.add(path, txn, offset)
        next(r for r in results if r.path == path).transactions += 1

    try:
        for txn in iter_closed(engine, frames(), last):
            add(txn)
    except CaptureError as exc:
        results[-1].error = _error_text(exc)
        for txn in engine.finish(last[0]):
            add(txn)
    _drain(engine, d, rows, capture_of)


def _error_text(exc: CaptureError) -> str:
    return exc.reason if exc.offset is None else f"byte {exc.offset}: {exc.reason}"


def _snapshot(acc: Accounting) -> Accounting:
    return Accounting(acc.read, acc.decoded, Counter(acc.skipped), Counter(acc.malformed))


def _difference(acc: Accounting, before: Accounting) -> Accounting:
    return Accounting(acc.read - before.read, acc.decoded - before.decoded, acc.skipped - before.skipped,
                      acc.malformed - before.malformed)


def _drain(engine: TransactionEngine, d: Dissector, rows: Rows, capture_of: Callable[[int], str]) -> None:
    for f in engine.loose:
        rows.add_finding(capture_of(f.frame), f)
    engine.loose.clear()
    for f in d.loose_findings:
        rows.add_finding(capture_of(f.frame), f)
    d.loose_findings.clear()
