"""The report: the four tables written as files, and a summary worst offenders first.

`stream` is the command line's path: each row, as the pipeline closes it, is counted into the summary
and formatted as the line its file will hold (CSV, JSON; Parquet keeps the row), then goes into a spool
(a bounded external sort) that hands the lines on in table order and in chunks, so memory does not grow
with the capture. `write_tables` and `summary` do the same from an Analysis already in memory.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from pd_analyze.analysis.rows import Rows
from pd_analyze.analysis.schema import COLUMNS, sort_key
from pd_analyze.output.spool import Spool
from pd_analyze.output.summary import TOP, Summary
from pd_analyze.output.writers import neutralise, open_table

if TYPE_CHECKING:
    from pd_analyze.analysis.api import Analysis
    from pd_analyze.analysis.capture_run import CaptureResult, Progress, Settings
    from pd_analyze.analysis.transaction import Transaction

__all__ = ["CHUNK_ROWS", "TABLES", "Streamed", "neutralise", "stream", "stream_findings", "summary", "write_tables"]

TABLES = tuple(COLUMNS)
CHUNK_ROWS = 4096  # rows per table held for sorting, and per chunk written


def _by_capture(name: str, fmt: str) -> bool:
    """Parquet writes one partition file at a time, so its findings come grouped by capture (within a
    capture the order is the table's: a partition holds the same rows in the same order either way)."""
    return fmt == "parquet" and name == "findings"


def write_tables(analysis: Analysis, out_dir: str, fmt: str) -> list[str]:
    """transactions, parameters, findings, changes as csv / parquet / json (JSON Lines) files."""
    os.makedirs(out_dir, exist_ok=True)
    written = []
    for name in TABLES:
        writer = open_table(out_dir, name, fmt)
        rows = sorted(getattr(analysis.rows, name), key=sort_key(name, _by_capture(name, fmt)))  # stable
        for i in range(0, len(rows), CHUNK_ROWS):
            writer.write(rows[i:i + CHUNK_ROWS])
        written.append(writer.close())
    return written


def summary(analysis: Analysis, top: int = TOP) -> str:
    """Verdict counts; NAKs by device, DO, PNU and error; B5 retries; latency per device."""
    acc = Summary()
    for name in ("transactions", "parameters", "findings"):
        acc.add(name, getattr(analysis.rows, name))
    return acc.text(analysis.captures, top)


class _Table:
    """Where `Rows` puts one table's rows in the streaming report: into the summary, and, as the line the
    file will hold (CSV, JSON) or as the row (Parquet), into the spool that orders them."""

    BATCH = 256  # rows gathered before they go on: one summary call per batch, not per row

    def __init__(self, name: str, writer: Any, spool: Spool, acc: Summary) -> None:
        self.name, self.spool, self.acc = name, spool, acc
        self.line = getattr(writer, "line", None)
        self._batch: list[tuple] = []

    def append(self, row: tuple) -> None:
        self._batch.append(row)
        if len(self._batch) >= self.BATCH:
            self.flush()

    def extend(self, rows: Iterable[tuple]) -> None:
        for row in rows:
            self.append(row)

    def flush(self) -> None:
        batch, self._batch = self._batch, []
        self.acc.add(self.name, batch)
        line, append = self.line, self.spool.append
        for row in batch:
            append(row, None if line is None else line(row))


@dataclass
class Streamed:
    """What `stream` wrote and found."""

    written: list[str]
    summary: str
    captures: list[CaptureResult]
    peak_held: dict[str, int] = field(default_factory=dict)  # most rows of each table in memory at once

    @property
    def errors(self) -> list[str]:
        return [f"{c.path}: {c.error}" for c in self.captures if c.error]


def stream(files: list[str], out_dir: str, fmt: str, settings: Settings,
           progress: Progress | None = None, jobs: int = 1, chain: bool = False,
           chunk_rows: int = CHUNK_ROWS) -> Streamed:
    """The report of `files` written to `out_dir` as csv / json / parquet without holding the tables:
    the files equal `write_tables(analyze(files))`, and the summary equals `summary(analyze(files))`."""
    from pd_analyze.analysis.jobs import run

    os.makedirs(out_dir, exist_ok=True)
    spill = tempfile.mkdtemp(prefix=".pd-analyze-", dir=out_dir)  # beside the output: room for big files
    writers = {name: open_table(out_dir, name, fmt) for name in TABLES}
    try:
        acc = Summary()
        spools = {name: Spool(sort_key(name, _by_capture(name, fmt)), chunk_rows, spill) for name in TABLES}
        tables = {name: _Table(name, writers[name], spools[name], acc) for name in TABLES}
        captures = run(files, Rows(**tables), settings, progress, jobs, chain)  # type: ignore[arg-type]
        written = []
        for name in TABLES:
            tables[name].flush()
            writer = writers.pop(name)
            for chunk in spools[name].chunks(chunk_rows):  # lines of text, or rows for Parquet
                if tables[name].line is None:
                    writer.write(chunk)
                else:
                    writer.write_lines(chunk)
            written.append(writer.close())
        return Streamed(written, acc.text(captures), captures, {n: s.peak_held for n, s in spools.items()})
    finally:
        for writer in writers.values():  # only after a failure: close what is open
            writer.close()
        shutil.rmtree(spill, ignore_errors=True)


class _FindingsOnly(Rows):
    """Rows that keep only findings (audit): the other tables are not even built."""

    def add(self, capture: str, txn: Transaction, offset: int = 0) -> None:
        for f in txn.findings:
            self.add_finding(capture, f, txn.txn + offset)

    def extend(self, other: Rows, offset: int) -> None:
        self.findings.extend(r[:2] + ((r[2] + offset if r[2] is not None else None),) + r[3:]
                             for r in other.findings)


def stream_findings(files: list[str], settings: Settings, jobs: int = 1, chain: bool = False,
                    chunk_rows: int = CHUNK_ROWS, progress: Progress | None = None,
                    ) -> tuple[Iterator[tuple], list[CaptureResult]]:
    """Findings of `files` sorted by capture and frame (ties as found), streamed: for `audit`.

    The rows are read lazily; the spill files go once the iterator is exhausted or closed."""
    from pd_analyze.analysis.jobs import run

    spool = Spool(sort_key("findings", by_capture=True), chunk_rows)
    sink = _FindingsOnly(findings=spool)  # type: ignore[arg-type]
    try:
        captures = run(files, sink, settings, progress, jobs, chain)
    except BaseException:
        spool.close()
        raise
    return (row for chunk in spool.chunks(chunk_rows) for row in chunk), captures
