"""The capture loop: frames -> dissector -> transaction engine -> rows, for one file or a chain of files.

`analysis.jobs.run` decides which way a set of captures goes; every way ends in `run_frames`.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Callable, Iterable, Iterator

from pd_analyze import capture
from pd_analyze.analysis.capture_run import CaptureResult, Progress, Settings, difference, error_text, snapshot
from pd_analyze.analysis.rows import Rows
from pd_analyze.analysis.stations import names_in_file
from pd_analyze.analysis.transaction import Transaction
from pd_analyze.analysis.transactions import TransactionEngine, iter_closed
from pd_analyze.capture import CaptureError
from pd_analyze.protocol.dissector import Dissector, dissect_frames
from pd_analyze.protocol.frames import Accounting


def analyze_file(path: str, settings: Settings, progress: Progress | None = None, rows: Rows | None = None,
                 offset: int = 0) -> tuple[Rows, CaptureResult]:
    """One capture, numbered from transaction `offset` + 1 (a process-pool task: arguments and result pickle)."""
    rows = Rows() if rows is None else rows
    d = settings.dissector()
    result = CaptureResult(path, d.accounting)
    frames = capture.frames(path, ip_only=True)
    run_frames(frames, d, settings.engine(), rows, lambda _frame: path, [result], progress, offset)
    result.stations = names_in_file(path)
    return rows, result


def analyze_chain(files: list[str], settings: Settings, progress: Progress | None, rows: Rows) -> list[CaptureResult]:
    d = settings.dissector()
    results: list[CaptureResult] = []
    starts: list[int] = []  # first global frame number of each file

    def frames() -> Iterator[capture.RawFrame]:
        offset = 0
        for path in files:
            before = snapshot(d.accounting)
            starts.append(offset + 1)
            result = CaptureResult(path, Accounting())
            results.append(result)
            try:
                for frame in chain_numbered(path, offset):
                    offset = frame.number
                    yield frame
            except CaptureError as exc:
                result.error = error_text(exc)
            result.accounting = difference(d.accounting, before)

    def capture_of(frame: int) -> str:
        return files[max(0, bisect_right(starts, frame) - 1)] if files else ""

    run_frames(frames(), d, settings.engine(), rows, capture_of, results, progress)
    for result in results:
        result.stations = names_in_file(result.path)
    return results


def chain_numbered(path: str, offset: int) -> Iterator[capture.RawFrame]:
    """One file of a chain, its frames numbered on after `offset` (the files numbered as one capture)."""
    for frame in capture.frames(path, ip_only=True):
        offset += frame.run or 1  # a run of skipped frames ends at its number
        yield frame._replace(number=offset)


def run_frames(source: Iterable[capture.RawFrame], d: Dissector, engine: TransactionEngine, rows: Rows,
               capture_of: Callable[[int], str], results: list[CaptureResult], progress: Progress | None,
               offset: int = 0) -> None:
    """The frame loop: dissector -> transaction engine -> rows (transactions numbered after `offset`)."""
    rows.use_names(d.checker.names)  # the rows name parameters and errors as the run's profile does
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
        results[-1].error = error_text(exc)
        for txn in engine.finish(last[0]):
            add(txn)
    _drain(engine, d, rows, capture_of)


def _drain(engine: TransactionEngine, d: Dissector, rows: Rows, capture_of: Callable[[int], str]) -> None:
    for f in engine.loose:
        rows.add_finding(capture_of(f.frame), f)
    engine.loose.clear()
    for f in d.loose_findings:
        rows.add_finding(capture_of(f.frame), f)
    d.loose_findings.clear()
