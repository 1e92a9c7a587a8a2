"""The report: the four tables written as files, and a summary worst offenders first.

`stream` is the command line's path: each row, as the pipeline closes it, is counted into the summary
and formatted as the line its file will hold (CSV, JSON; Parquet keeps the row), then goes into a spool
(a bounded external sort) that hands the lines on in table order and in chunks, so memory does not grow
with the capture. `write_tables` and `summary` do the same from an Analysis already in memory.

`BatchReport` (and `write_batches`, all at once) is the same end for the columnar analysis: the tables
come as pyarrow batches in any order, a `TableSink` per table writes them in table order, and the
summary is counted from the batches as they come.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
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
    from pd_analyze.model.rules import Finding

__all__ = ["CHUNK_ROWS", "TABLES", "BatchReport", "Streamed", "neutralise", "stream", "stream_findings", "summary",
           "write_batches", "write_tables"]

TABLES = tuple(COLUMNS)
CHUNK_ROWS = 4096  # rows per table held for sorting, and per chunk written


def _by_capture(name: str, fmt: str) -> bool:
    """Parquet writes one partition file at a time, so its findings come grouped by capture (within a
    capture the order is the table's: a partition holds the same rows in the same order either way)."""
    return fmt == "parquet" and name == "findings"


def write_tables(analysis: Analysis, out_dir: str, fmt: str) -> list[str]:
    """transactions, parameters, findings, changes as csv / parquet / json (JSON Lines) files.

    CSV and Parquet go the columnar way (each table one batch through `write_batches`); JSON Lines, which
    a batch would only turn back into rows, and which alone can hold a string Arrow cannot (a lone
    surrogate from an undecodable file name), stays on the rows."""
    if fmt in ("csv", "parquet") or any(analysis.rows.tables.values()):
        return write_batches(out_dir, fmt, {name: _batches(analysis.rows, name) for name in TABLES},
                             count=False, digits=analysis.rows.digits).written
    os.makedirs(out_dir, exist_ok=True)
    written = []
    for name in TABLES:
        writer = open_table(out_dir, name, fmt, analysis.rows.digits)
        rows = sorted(getattr(analysis.rows, name), key=sort_key(name, _by_capture(name, fmt)))  # stable
        for i in range(0, len(rows), CHUNK_ROWS):
            writer.write(rows[i:i + CHUNK_ROWS])
        written.append(writer.close())
    return written


def summary(analysis: Analysis, top: int = TOP) -> str:
    """Verdict counts; NAKs by device, DO, PNU and error; B5 retries; latency per device."""
    acc = Summary(analysis.rows.digits)
    for name in ("transactions", "parameters", "findings"):
        acc.add(name, getattr(analysis.rows, name))
        for table in analysis.rows.tables.get(name, ()):
            acc.add_batch(name, table)
    return acc.text(analysis.captures, top)


def _batches(rows: Rows, name: str) -> list[Any]:
    """A table's rows as pyarrow batches: the rows made one by one, then the columns' tables."""
    from pd_analyze.analysis.table_batches import rows_to_batch

    return [rows_to_batch(name, getattr(rows, name)), *rows.tables.get(name, ())]


class BatchReport:
    """The report files and summary of the columnar analysis: `add(name, table)` batches of a table in any
    order (columns of table_batches.batch_schema(name)), `flush(name, watermark)` when no row of that table
    still to come sorts below the watermark, `close(captures)` at the end (or `abort()` after a failure; as
    a context manager it does that itself).

    A watermark is a value of the table's sort column (txn; frame for findings); for Parquet's findings,
    which are written by capture, a pair (capture, frame) (`by_capture(name)` says which). Rows are held
    in memory up to `max_held` per table, beyond that spilled to a hidden directory in `out_dir`; a flush
    writes once `min_write` rows are complete (see table_sink); `count=False` leaves the summary out.
    `digits`: each capture's resolution (Rows.digits; by default a dict of its own, which the run's Rows
    then shares: `_ReportRows`), read as the rows are written."""

    def __init__(self, out_dir: str, fmt: str, max_held: int | None = None, chunk_rows: int | None = None,
                 count: bool = True, min_write: int | None = None, digits: dict[str, int] | None = None) -> None:
        from pd_analyze.output import table_sink

        os.makedirs(out_dir, exist_ok=True)
        self.fmt = fmt
        self.digits = {} if digits is None else digits
        self.acc = Summary(self.digits) if count else None
        self._uncounted: dict[str, list[Any]] = {name: [] for name in TABLES}  # batches not yet in the summary
        self._count_rows = table_sink.FORMAT_ROWS  # batches counted together: a call costs, whatever its size
        self._spill = tempfile.mkdtemp(prefix=".pd-analyze-", dir=out_dir)  # beside the output: room for big files
        self._writers: dict[str, Any] = {}
        self.sinks: dict[str, table_sink.TableSink] = {}
        try:
            for name in TABLES:
                self._writers[name] = writer = open_table(out_dir, name, fmt, self.digits)
                self.sinks[name] = table_sink.TableSink(
                    name, writer, self.by_capture(name), self._spill, max_held or table_sink.MAX_HELD,
                    chunk_rows or table_sink.CHUNK_ROWS, min_write or table_sink.FORMAT_ROWS)
        except BaseException:
            self.abort()
            raise

    def by_capture(self, name: str) -> bool:
        """Whether the table is written by capture first (its watermark then a pair (capture, value))."""
        return _by_capture(name, self.fmt)

    def add(self, name: str, table: Any) -> None:
        """A batch of one table. It is counted into the summary now, in the order batches come: the summary
        is the same in any order (a row's place is its key, then its number), as the row stream's is."""
        from pd_analyze.analysis.table_batches import conform

        table = conform(name, table)
        if self.acc is not None:
            waiting = self._uncounted[name]
            waiting.append(table)
            if sum(t.num_rows for t in waiting) >= self._count_rows:
                self._count(name)
        self.sinks[name].add(table)

    def _count(self, name: str) -> None:
        import pyarrow as pa

        waiting, self._uncounted[name] = self._uncounted[name], []
        if self.acc is not None and waiting:
            self.acc.add_batch(name, pa.concat_tables(waiting))

    def flush(self, name: str, watermark: object) -> int:
        return self.sinks[name].flush(watermark)

    def close(self, captures: Sequence[CaptureResult] = ()) -> Streamed:
        """Write every row still held, close the files; the summary of `captures`."""
        try:
            written = []
            for name in TABLES:
                self._count(name)
                self.sinks[name].close()
                written.append(self._writers.pop(name).close())
            text = self.acc.text(list(captures)) if self.acc is not None else ""
            return Streamed(written, text, list(captures), {n: s.peak_held for n, s in self.sinks.items()})
        finally:
            self.abort()

    def abort(self) -> None:
        """Close what is open and remove the spill files (the files written so far stay)."""
        for sink in self.sinks.values():
            sink.discard()
        for writer in self._writers.values():
            writer.close()
        self._writers = {}
        shutil.rmtree(self._spill, ignore_errors=True)

    def __enter__(self) -> BatchReport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.abort()


def write_batches(out_dir: str, fmt: str, batches_by_table: Mapping[str, Iterable[Any]],
                  captures: Sequence[CaptureResult] = (), max_held: int | None = None,
                  chunk_rows: int | None = None, count: bool = True, min_write: int | None = None,
                  digits: dict[str, int] | None = None) -> Streamed:
    """The report files of tables given as pyarrow batches (each table's batches in any order, rows of a
    batch in the order found; tables not given are written empty), and the summary of `captures`; `digits`:
    each capture's resolution (Rows.digits)."""
    with BatchReport(out_dir, fmt, max_held, chunk_rows, count, min_write, digits) as out:
        for name, tables in batches_by_table.items():
            for table in tables:
                out.add(name, table)
        return out.close(captures)


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
           chunk_rows: int | None = None) -> Streamed:
    """The report of `files` written to `out_dir` as csv / json / parquet without holding the tables:
    the files equal `write_tables(analyze(files))`, and the summary equals `summary(analyze(files))`.
    `chunk_rows`: the rows of a table held in memory before they spill to disk (None: table_sink.MAX_HELD).
    A capture whose file name is not UTF-8 is named in the tables as schema.capture_text writes it."""
    from pd_analyze.analysis.jobs import run

    with BatchReport(out_dir, fmt, max_held=chunk_rows, chunk_rows=chunk_rows) as out:
        rows = _ReportRows(out, chunk_rows or _ReportRows.ROWS_PER_BATCH)
        captures = run(files, rows, settings, progress, jobs, chain)
        rows.batch_done()
        return out.close(captures)


class _ReportRows(Rows):
    """Rows for the streaming report: the engine's tables go straight to the report's sinks, findings made
    one by one follow as batches of ROWS_PER_BATCH rows, or when a batch of frames ends."""

    ROWS_PER_BATCH = 4096

    def __init__(self, out: BatchReport, rows_per_batch: int) -> None:
        super().__init__(digits=out.digits)  # the writers and the summary read the resolutions the run notes
        self.out = out
        self.size = min(rows_per_batch, self.ROWS_PER_BATCH)

    def add_finding(self, capture: str, f: Finding, txn: int | None = None) -> None:
        super().add_finding(capture, f, txn)
        if len(self.findings) >= self.size:
            self.batch_done()

    def add_table(self, name: str, table: object) -> None:
        n = table.num_rows  # type: ignore[attr-defined]
        for start in range(0, n, self.size) if n > self.size else (0,):  # (the sinks hold one batch whole)
            self.out.add(name, table.slice(start, self.size) if n > self.size else table)  # type: ignore[attr-defined]

    def batch_done(self) -> None:
        from pd_analyze.analysis.table_batches import rows_to_batch

        for name in TABLES:
            rows = getattr(self, name)
            if rows:
                self.out.add(name, rows_to_batch(name, rows))
                rows.clear()


class _FindingsOnly(Rows):
    """Rows that keep only findings (audit): the other tables are not even built."""

    def extend(self, other: Rows, offset: int) -> None:
        self.findings.extend(r[:2] + ((r[2] + offset if r[2] is not None else None),) + r[3:]
                             for r in other.findings)
        for table in other.tables.get("findings", ()):
            self.add_table("findings", table)
            if offset:
                self.findings[-table.num_rows:] = [  # type: ignore[attr-defined]
                    r[:2] + ((r[2] + offset if r[2] is not None else None),) + r[3:]
                    for r in self.findings[-table.num_rows:]]  # type: ignore[attr-defined]

    def add_table(self, name: str, table: object) -> None:
        """The columns' findings as rows (audit prints them); their other tables are not needed."""
        if name == "findings" and table.num_rows:  # type: ignore[attr-defined]
            self.findings.extend(zip(*(c.to_pylist() for c in table.columns), strict=True))  # type: ignore[attr-defined]


def stream_findings(files: list[str], settings: Settings, jobs: int = 1, chain: bool = False,
                    chunk_rows: int = CHUNK_ROWS, progress: Progress | None = None,
                    wrap: Callable[[Rows], Rows] | None = None) -> tuple[Iterator[tuple], list[CaptureResult]]:
    """Findings of `files` sorted by capture and frame (ties as found), streamed: for `audit`.

    The rows are read lazily; the spill files go once the iterator is exhausted or closed. `wrap` may put
    another sink in front of the findings' (one that passes every row on, e.g. param_state.StateRows)."""
    from pd_analyze.analysis.jobs import run

    spool = Spool(sort_key("findings", by_capture=True), chunk_rows)
    sink = _FindingsOnly(findings=spool)  # type: ignore[arg-type]
    try:
        captures = run(files, sink if wrap is None else wrap(sink), settings, progress, jobs, chain)
    except BaseException:
        spool.close()
        raise
    return (row for chunk in spool.chunks(chunk_rows) for row in chunk), captures
