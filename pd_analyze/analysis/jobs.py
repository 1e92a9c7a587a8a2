"""Which way a set of captures goes: one process, files in parallel processes, one file's decode in parallel
processes (analysis.split), or a chain of files read as one capture. Every capture goes through the one
engine (analysis.engine), batch by batch.

`run` is the one way in for `analyze()` and the streamed report alike (lists or spools as `Rows`), so
their tables cannot differ.
"""

from __future__ import annotations

import os

from pd_analyze.analysis.capture_run import CaptureResult, Progress, Settings
from pd_analyze.analysis.engine import files as engine
from pd_analyze.analysis.rows import Rows

PARALLEL_MIN_BYTES = 8 * 1024 * 1024  # captures smaller than this in all are analysed in one process


def run(files: list[str], rows: Rows, settings: Settings, progress: Progress | None = None, jobs: int = 1,
        chain: bool = False) -> list[CaptureResult]:
    """The pipeline over capture files, every row handed to `rows` (lists for `analyze()`, spools for
    the streaming report).

    One process streams frame by frame; with `jobs` > 1 several files are analysed in parallel (each
    file's rows come back from its worker and are handed on in order), and one file has its batches
    decoded by `jobs` - 1 workers while this process runs the engine over them in frame order."""
    if chain:
        return engine.analyze_chain(files, settings, progress, rows)
    if jobs > 1 and ("-" in files or _input_bytes(files) < PARALLEL_MIN_BYTES):
        jobs = 1  # standard input is one stream; for small files, process start-up and shipping the rows
        # back would cost more than the files take
    results: list[CaptureResult] = []
    if jobs > 1 and len(files) > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=min(jobs, len(files))) as pool:
            # merged in file order as results arrive: numbering does not depend on scheduling
            for part_rows, result in pool.map(analyze_file, files, [settings] * len(files)):
                rows.extend(part_rows, sum(r.transactions for r in results))
                results.append(result)
        return results
    if jobs > 1:  # one file
        from pd_analyze.analysis import split

        _, result = split.analyze_file(files[0], settings, jobs, progress, rows)
        return [result]
    for path in files:
        _, result = analyze_file(path, settings, progress, rows, sum(r.transactions for r in results))
        results.append(result)
    return results


def analyze_file(path: str, settings: Settings, progress: Progress | None = None, rows: Rows | None = None,
                 offset: int = 0) -> tuple[Rows, CaptureResult]:
    """One capture, numbered from transaction `offset` + 1 (a process-pool task: arguments and result pickle)."""
    return engine.analyze_file(path, settings, progress, rows, offset)


def _input_bytes(files: list[str]) -> int:
    """Capture bytes to analyse (a gzip file counted as its typical decompressed size)."""
    total = 0
    for path in files:
        try:
            total += os.path.getsize(path) * (5 if path.endswith(".gz") else 1)
        except OSError:
            total += PARALLEL_MIN_BYTES  # unreadable: its error is reported where it is read
    return total


