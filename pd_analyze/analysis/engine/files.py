"""Capture files through the engine: one file, or a chain of files read as one capture (frame numbers
running on across the files, as `mergecap -a` would join them)."""

from __future__ import annotations

import dataclasses
from bisect import bisect_right
from collections.abc import Iterator

from pd_analyze.analysis.capture_run import CaptureResult, Progress, Settings, difference, error_text, snapshot
from pd_analyze.analysis.engine.collector import spaced_collections
from pd_analyze.analysis.engine.run import EngineRun, run_batches
from pd_analyze.analysis.rows import Rows
from pd_analyze.capture import CaptureError
from pd_analyze.capture.batches import FrameBatch, batches
from pd_analyze.protocol.frames import Accounting


def _batches(path: str, settings: Settings) -> Iterator[FrameBatch]:
    return batches(path, settings.batch_frames) if settings.batch_frames else batches(path)


def analyze_file(path: str, settings: Settings, progress: Progress | None = None, rows: Rows | None = None,
                 offset: int = 0) -> tuple[Rows, CaptureResult]:
    """One capture, numbered from transaction `offset` + 1 (a process-pool task: arguments and result pickle)."""
    rows = Rows() if rows is None else rows
    result = CaptureResult(path, Accounting())
    result.accounting = run_batches(_batches(path, settings), settings, rows, lambda _frame: path, [result], progress,
                                    offset)
    return rows, result


def analyze_chain(files: list[str], settings: Settings, progress: Progress | None, rows: Rows) -> list[CaptureResult]:
    """The files as one capture continued across them."""
    results: list[CaptureResult] = []
    starts: list[int] = []  # first frame number of each file in the chain

    def capture_of(frame: int) -> str:
        return files[max(0, bisect_right(starts, frame) - 1)] if files else ""

    with spaced_collections():
        run = EngineRun(settings, rows, capture_of, results, progress)
        offset = 0
        for path in files:
            before = snapshot(run.totals())
            starts.append(offset + 1)
            result = CaptureResult(path, Accounting())
            results.append(result)
            try:
                for batch in _batches(path, settings):
                    if len(batch):
                        run.feed(dataclasses.replace(batch, number=batch.number + offset))
                        offset = int(batch.number[-1]) + offset
            except CaptureError as exc:
                result.error = error_text(exc)
            result.accounting = difference(run.totals(), before)
        run.finish()
    return results
