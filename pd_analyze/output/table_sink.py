"""An ordered sink for one table: Arrow batches in, in any order; the table's rows out, sorted, in bounded memory.

The columnar analysis hands a table on in batches as its parts finish: rows of a batch in the order
they were found, batches in no particular order. `TableSink` holds them until the analysis says how far
the table is complete (`flush(watermark)`: no row still to come sorts below it), then hands every held
row below the watermark to its writer (`write_batch`), in table order: by the table's sort column
(`schema.SORT_COLUMN`; findings then by rule rank), missing keys last, ties in the order the rows came
(`add` numbers them). `close()` writes the rest.

A writer that can format rows ahead (`format_batch(table) -> pa.Array` of text, one element a row, and
`write_formatted(text)`: CSV and JSON Lines) gets them formatted as they arrive, a few thousand at a time,
and the sink sorts that one column of text instead of every column (a gather of thirty string columns
costs more than formatting them). Other writers (Parquet) get `write_batch(table)` of the columns.

Memory: rows waiting are held as Arrow tables. Past `max_held` rows the sink does what `spool.Spool`
does with its rows: it sorts them, writes all but the highest `max_held // 2` to a sorted run on disk
(Arrow IPC files in `spill_dir`; rows below what the current run holds start a run of their own) and
keeps the rest (output/table_runs.py). A flush then merges the runs with the rows in memory, a block of
each run at a time; more than FAN_IN runs are first merged, FAN_IN into one. Without runs (no flood so
far) a flush sorts only the keys and copies only the rows it writes. So the rows in memory stay below
`max_held` plus the batch being added, plus one block of `max_held // (2 * FAN_IN)` rows for each run being merged
(at most FAN_IN + 1: about `max_held // 2`), whatever arrives and however long the watermark stalls:
about 1.5 x `max_held` rows and one batch. `peak_held` records the most. (The writer's own chunk is made
of those rows: slices, not copies, where they lie in order.)
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from typing import Any, Protocol

import numpy as np
import pyarrow as pa

from pd_analyze.analysis.table_batches import SEQ, arrival_numbers, batch_schema, conform, order_keys
from pd_analyze.output.table_runs import Block, Key, Run, below, number, sort_order, sorted_rows, taken

MAX_HELD = 16_384  # rows held in memory before the sink spills (about 5 MB of transaction rows: four
# tables of them, 1.5 x each, stay well inside the flood budget of 200 MiB)
CHUNK_ROWS = 65_536  # rows per write_batch call at most
FORMAT_ROWS = 16_384  # rows gathered before they are formatted (a column at a time costs per call, too)
TEXT = "__text"  # the column of formatted rows
FAN_IN = 16  # runs merged at once


class BatchWriter(Protocol):
    """What a sink writes to: tables of batch_schema(name), in table order. A writer may also offer
    `format_batch(table) -> pa.ChunkedArray` (a row's text each) and `write_formatted(text)`."""

    def write_batch(self, table: pa.Table) -> None: ...


class TableSink:
    """One table's rows, batches in any order, written through `writer.write_batch` in table order.

    `name` is a table of schema.COLUMNS; `by_capture` orders by capture first (Parquet's findings,
    one partition file at a time). A watermark is a value of the sort column (txn, or frame for findings)
    or, with `by_capture`, a pair (capture, value); float("inf") stands for every value. Spill files go
    to a hidden directory in `spill_dir` (the system's temporary directory when None), made when first
    needed and removed by close() or discard(). `chunk_rows` bounds the rows of one writer call;
    `min_write` is the fewest complete rows a flush writes (1: every flush writes what it can)."""

    def __init__(self, name: str, writer: BatchWriter, by_capture: bool = False, spill_dir: str | None = None,
                 max_held: int = MAX_HELD, chunk_rows: int = CHUNK_ROWS, min_write: int = FORMAT_ROWS) -> None:
        self.name, self.writer, self.by_capture = name, writer, by_capture
        self.min_write = max(1, min_write)
        self.max_held = max(2, max_held)
        self.block = max(1, self.max_held // (2 * FAN_IN))
        self.chunk_rows = max(1, chunk_rows)
        self.spill_dir = spill_dir
        self._format = getattr(writer, "format_batch", None)  # formats rows ahead (CSV, JSON Lines)
        self.names = [TEXT] if self._format is not None else batch_schema(name).names  # the columns held
        self.rows_in = self.rows_out = 0
        self.peak_held = 0  # most rows held in memory at once (waiting rows, merge blocks)
        self.runs_made = 0
        self._width = len(order_keys(name, batch_schema(name).empty_table(), by_capture)) + 1  # key parts + SEQ
        self._held: list[pa.Table] = []  # waiting rows: the data columns, the key parts, SEQ
        self._held_rows = 0
        self._held_sorted = False  # the held rows are one table, sorted
        self._raw: list[pa.Table] = []  # rows still to be formatted (formatting writers only), as added
        self._raw_rows = 0
        self._runs: list[Run] = []
        self._current: Run | None = None  # the run spilled rows go on to
        self._floor: Key | None = None  # the highest watermark flushed: nothing may come below it
        self._dir: str | None = None

    def add(self, table: pa.Table) -> None:
        """A batch of rows (columns of batch_schema(name); see table_batches.conform), in the order found."""
        table = conform(self.name, table)
        n = table.num_rows
        if not n:
            return
        parts = order_keys(self.name, table, self.by_capture)
        if self._floor is not None and below([p for _, p in parts], self._floor).any():
            raise ValueError(f"{self.name}: a row below the watermark {self._floor[-1]!r} already flushed")
        for part_name, values in parts:
            table = table.append_column(part_name, values)
        table = table.append_column(SEQ, arrival_numbers(self.rows_in, n))
        self.rows_in += n
        self._held_rows += n
        self._peak(self._held_rows)
        if self._format is not None:
            self._raw.append(table)
            self._raw_rows += n
            if self._raw_rows >= FORMAT_ROWS:
                self._formatted()
        else:
            self._held.append(table)
            self._held_sorted = False
        if self._held_rows > self.max_held:
            self._spill()

    def _formatted(self) -> None:
        """The rows waiting to be formatted, formatted (in the order they came) and held."""
        if not self._raw:
            return
        table = pa.concat_tables(self._raw) if len(self._raw) > 1 else self._raw[0]
        self._raw, self._raw_rows = [], 0
        text = self._format(table.select(batch_schema(self.name).names))  # type: ignore[misc]
        keys = table.columns[table.num_columns - self._width:]
        names = table.column_names[table.num_columns - self._width:]
        self._held.append(pa.Table.from_arrays([text, *keys], names=[TEXT, *names]))
        self._held_sorted = False

    def flush(self, watermark: object) -> int:
        """The rows below the watermark are complete: the caller promises none will come below it any more.
        They are written, in table order, once `min_write` of them wait (or runs lie on disk); fewer wait
        for a later flush or close(), since a few hundred rows cost more to write a column at a time than
        their formatting. Returns the rows written now."""
        prefix = self._prefix(watermark)
        self._floor = prefix if self._floor is None or prefix > self._floor else self._floor
        if not self._runs and self.min_write > 1 and self._waiting(self._floor) < self.min_write:
            return 0
        return self._emit(self._floor)

    def _waiting(self, limit: Key) -> int:
        """Rows in memory below `limit`, counted until min_write of them are found."""
        count = 0
        for t in self._held + self._raw:
            count += int(np.count_nonzero(below(t.columns[t.num_columns - self._width:], limit)))
            if count >= self.min_write:
                break
        return count

    def close(self) -> int:
        """Write every row still held and remove the spill files; returns the rows written by it.
        The writer stays open: closing it is the caller's."""
        try:
            return self._emit(None)
        finally:
            self.discard()

    def discard(self) -> None:
        """Forget every held row and remove the spill files (after a failure)."""
        for run in self._runs:
            run.remove()
        self._runs, self._current, self._held, self._held_rows, self._raw, self._raw_rows = [], None, [], 0, [], 0
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None

    def _prefix(self, watermark: object) -> Key:
        """The watermark as a prefix of the key parts: present (0), then the value (inf: every value)."""
        if self.by_capture:
            if not (isinstance(watermark, tuple) and len(watermark) == 2):
                raise TypeError("a sink by capture takes a watermark (capture, value)")
            return (0, str(watermark[0]), 0, number(watermark[1]))
        return (0, number(watermark))

    def _peak(self, held: int) -> None:
        self.peak_held = max(self.peak_held, held)

    def _sorted_held(self) -> pa.Table | None:
        """The rows in memory as one sorted table (also kept as the only held table)."""
        self._formatted()
        if not self._held:
            return None
        table = pa.concat_tables(self._held) if len(self._held) > 1 else self._held[0]
        if not self._held_sorted:
            table = sorted_rows(table, self._width)
        self._held, self._held_sorted = [table], True
        return table

    def _emit(self, limit: Key | None) -> int:
        """Write every row below `limit` (None: every row), merging memory and runs."""
        out = _Output(self)
        if not self._runs:  # all in memory (no flood so far): the rows below the limit, the rest left as is
            self._formatted()
            table = pa.concat_tables(self._held) if len(self._held) > 1 else self._held[0] if self._held else None
            if table is None:
                return 0
            parts = table.columns[table.num_columns - self._width:]
            low = np.ones(table.num_rows, bool) if limit is None else below(parts, limit)
            n = int(np.count_nonzero(low))
            if n:  # the rows below sort first: the head of the order
                out.add(taken(table, sort_order(table, self._width)[:n]))
                table = table.filter(pa.array(~low)) if n < table.num_rows else None
            self._held = [table] if table is not None else []
            self._held_rows = table.num_rows if table is not None else 0
            self._held_sorted = self._held_sorted and len(self._held) == 1  # a filter keeps a sorted table sorted
            out.close()
            return out.rows
        held = self._sorted_held()
        for piece in self._merge(([held] if held is not None else []) + self._runs, limit):
            out.add(piece)
        out.close()
        return out.rows

    def _merge(self, sources: list[Any], limit: Key | None) -> Iterator[pa.Table]:
        """Sorted pieces of every row below `limit` of the sources (a sorted table, or runs), in order.

        Each round takes, from every source's head block, the rows at or below the smallest last key
        of the runs' blocks: nothing still unread can sort below them."""
        memory = rest = None
        if sources and isinstance(sources[0], pa.Table):
            block = Block(sources[0], self._width)
            head = len(block) if limit is None else block.count(limit)
            memory, rest = Block(block.table.slice(0, head), self._width), block.table.slice(head)
        runs = [s for s in sources if isinstance(s, Run)]
        try:
            while True:
                heads: list[tuple[Run | None, Block]] = []
                if memory is not None and len(memory):
                    heads.append((None, memory))
                for run in runs:
                    head = run.next_block(self._width)
                    if head is not None and (limit is None or head.count(limit) > 0):
                        heads.append((run, head))
                if not heads:
                    return
                self._peak(sum(len(b) for _, b in heads) + (rest.num_rows if rest is not None else self._held_rows))
                lasts = [b.key(len(b) - 1) for s, b in heads if s is not None]
                bound = min(lasts) if lasts else None
                pieces = []
                for source, head in heads:
                    n = len(head) if bound is None else head.count(bound, or_equal=True)
                    if limit is not None and source is not None:
                        n = min(n, head.count(limit))
                    if not n:
                        continue
                    taken, left = head.split(n)
                    pieces.append(taken)
                    if source is None:
                        memory = Block(left, self._width)
                    else:
                        source.used(n)
                piece = pa.concat_tables(pieces) if len(pieces) > 1 else pieces[0]
                if len(pieces) > 1:
                    piece = sorted_rows(piece, self._width)
                yield piece
        finally:
            if memory is not None:  # what is left in memory: the rows not taken, then those at or above limit
                left = pa.concat_tables([memory.table, rest]) if rest is not None else memory.table
                self._held, self._held_rows, self._held_sorted = ([left] if left.num_rows else []), left.num_rows, True
            for run in runs:
                if not run.rows:
                    run.remove()
            self._runs = [r for r in self._runs if r.rows]
            if self._current is not None and not self._current.rows:
                self._current = None

    def _spill(self) -> None:
        """Write the held rows but the highest max_held // 2 to runs on disk."""
        table = self._sorted_held()
        assert table is not None
        keep = self.max_held // 2
        out = Block(table.slice(0, table.num_rows - keep), self._width)
        self._held, self._held_rows = [table.slice(table.num_rows - keep)], keep
        lower = out.count(self._current.last) if self._current is not None and self._current.last else 0
        if lower:  # lower than the current run's end: a run of their own
            run = Run()
            self._runs.append(run)
            run.append(self._path(), out.table.slice(0, lower), self.block, out.key(lower - 1))
        if lower < len(out):
            if self._current is None:
                self._current = Run()
                self._runs.append(self._current)
            self._current.append(self._path(), out.table.slice(lower), self.block, out.key(len(out) - 1))
        if len(self._runs) > FAN_IN:
            self._compact()

    def _compact(self) -> None:
        """Merge the FAN_IN smallest runs but the current one into one run."""
        others = sorted((r for r in self._runs if r is not self._current), key=lambda r: r.rows)[:FAN_IN]
        merged = Run()
        pending: list[pa.Table] = []
        for piece in self._merge(others, None):
            pending.append(piece)
            if sum(p.num_rows for p in pending) >= self.block:
                self._append(merged, pending)
                pending = []
        if pending:
            self._append(merged, pending)
        self._runs = [r for r in self._runs if r.rows and all(r is not o for o in others)] + [merged]

    def _append(self, run: Run, pieces: list[pa.Table]) -> None:
        table = pa.concat_tables(pieces)
        block = Block(table, self._width)
        run.append(self._path(), table, self.block, block.key(len(block) - 1))

    def _path(self) -> str:
        if self._dir is None:
            self._dir = tempfile.mkdtemp(prefix=".pd-analyze-sink-", dir=self.spill_dir)
        self.runs_made += 1
        return os.path.join(self._dir, f"{self.name}-{self.runs_made}.arrow")


class _Output:
    """Sorted pieces gathered into chunks of chunk_rows for the writer, without the key columns."""

    def __init__(self, sink: TableSink) -> None:
        self.sink, self.rows = sink, 0
        self._pending: list[pa.Table] = []
        self._pending_rows = 0

    def add(self, piece: pa.Table) -> None:
        self._pending.append(piece.select(self.sink.names))
        self._pending_rows += piece.num_rows
        if self._pending_rows >= self.sink.chunk_rows:
            self._write()

    def _write(self) -> None:
        if not self._pending_rows:
            return
        table = pa.concat_tables(self._pending)
        self._pending, self._pending_rows = [], 0
        writer = self.sink.writer
        for start in range(0, table.num_rows, self.sink.chunk_rows):
            chunk = table.slice(start, self.sink.chunk_rows)
            if self.sink.names == [TEXT]:
                writer.write_formatted(chunk.column(TEXT))  # type: ignore[attr-defined]
            else:
                writer.write_batch(chunk)
            self.rows += chunk.num_rows
            self.sink.rows_out += chunk.num_rows

    def close(self) -> None:
        self._write()
