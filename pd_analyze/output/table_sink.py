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
keeps the rest. A flush then merges the runs with the rows in memory, a block of each run at a time;
more than FAN_IN runs are first merged, FAN_IN into one. So the rows in memory stay below `max_held`
plus the batch being added, plus one block of `max_held // (2 * FAN_IN)` rows for each run being merged
(at most FAN_IN + 1: about `max_held // 2`), whatever arrives and however long the watermark stalls:
about 1.5 x `max_held` rows and one batch. `peak_held` records the most. (The writer's own chunk is made
of those rows: slices, not copies, where they lie in order.)
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from itertools import pairwise
from typing import Any, Protocol

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pd_analyze.analysis.table_batches import SEQ, arrival_numbers, batch_schema, conform, order_keys, sort_indices

MAX_HELD = 250_000  # rows held in memory before the sink spills (about 100 MB of transaction rows)
CHUNK_ROWS = 65_536  # rows per write_batch call at most
FORMAT_ROWS = 16_384  # rows gathered before they are formatted (a column at a time costs per call, too)
TEXT = "__text"  # the column of formatted rows
FAN_IN = 16  # runs merged at once
RUN_ROWS = 4_096  # rows in order, on average, worth keeping as slices rather than gathered


class BatchWriter(Protocol):
    """What a sink writes to: tables of batch_schema(name), in table order. A writer may also offer
    `format_batch(table) -> pa.ChunkedArray` (a row's text each) and `write_formatted(text)`."""

    def write_batch(self, table: pa.Table) -> None: ...


Key = tuple  # a row's key parts (order_keys), then its SEQ; a prefix of them for a watermark


def _below(parts: list[Any], key: Key) -> np.ndarray:
    """Which rows sort below `key`, comparing the first len(key) parts (one vectorised pass)."""
    result = np.zeros(len(parts[0]), dtype=bool)  # equal in every part compared: not below
    for values, bound in reversed(list(zip(parts, key, strict=False))):
        if isinstance(bound, str):
            less = pc.less(values, bound).to_numpy(zero_copy_only=False)
            equal = pc.equal(values, bound).to_numpy(zero_copy_only=False)
        else:
            array = values.to_numpy()
            less, equal = array < bound, array == bound
        result = less | (equal & result)
    return result


def _number(value: object) -> int | float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer) or value != value:
        raise TypeError(f"a watermark is a number, not {value!r}")
    return value if isinstance(value, int | float) else int(value)


def _sorted(table: pa.Table, width: int) -> pa.Table:
    """A table sorted by its last `width` columns (the key parts, then SEQ). Rows mostly come in order,
    a batch at a time, so the order is usually a few runs of consecutive rows: those are sliced (no copy);
    a gather of every column is left for rows in disorder."""
    order = sort_indices(table.select(table.column_names[-width:])).to_numpy()
    starts = np.flatnonzero(np.diff(order) != 1) + 1
    if len(starts) + 1 > max(1, len(order) // RUN_ROWS):
        return table.take(pa.array(order))
    bounds = [0, *starts.tolist(), len(order)]
    return pa.concat_tables([table.slice(int(order[a]), b - a) for a, b in pairwise(bounds)])


class _Block:
    """Sorted rows of one source (memory or a run), the head of what is left of it."""

    def __init__(self, table: pa.Table, width: int) -> None:
        self.table = table
        self.parts = table.columns[table.num_columns - width:]

    def __len__(self) -> int:
        return self.table.num_rows

    def key(self, i: int) -> Key:
        return tuple(p[i].as_py() for p in self.parts)

    def count(self, key: Key, or_equal: bool = False) -> int:
        """Rows at the head that sort below `key` (at or below: `or_equal`), comparing len(key) parts:
        the block is sorted, so they are a prefix, found by bisection."""
        m = len(key)
        lo, hi = 0, len(self)
        while lo < hi:
            mid = (lo + hi) // 2
            k = self.key(mid)[:m]
            if k < key or (or_equal and k == key):
                lo = mid + 1
            else:
                hi = mid
        return lo

    def split(self, n: int) -> tuple[pa.Table, pa.Table]:
        return self.table.slice(0, n), self.table.slice(n)


class _Run:
    """A sorted run on disk: IPC files, each sorted and starting at or above where the one before ends."""

    def __init__(self) -> None:
        self.files: list[str] = []
        self.rows = 0
        self.last: Key | None = None  # the key of the last row appended
        self._reader: Any = None
        self._file: Any = None
        self._batch = 0  # next record batch of the first file
        self.head: _Block | None = None  # rows read and not yet used

    def append(self, path: str, table: pa.Table, block: int, last: Key) -> None:
        with pa.OSFile(path, "wb") as sink, pa.ipc.new_file(sink, table.schema) as writer:
            writer.write_table(table, max_chunksize=block)
        self.files.append(path)
        self.rows += table.num_rows
        self.last = last

    def next_block(self, width: int) -> _Block | None:
        """The head, reading the next record batch when it is used up; None at the end of the run."""
        while self.head is None or not len(self.head):
            if not self.files:
                return None
            if self._reader is None:
                self._file = pa.OSFile(self.files[0], "rb")
                self._reader = pa.ipc.open_file(self._file)
                self._batch = 0
            if self._batch < self._reader.num_record_batches:
                batch = self._reader.get_batch(self._batch)
                self._batch += 1
                self.head = _Block(pa.Table.from_batches([batch]), width)
                continue
            self._close()
            os.unlink(self.files.pop(0))
        return self.head

    def used(self, n: int) -> None:
        assert self.head is not None
        self.rows -= n
        self.head = _Block(self.head.table.slice(n), len(self.head.parts))

    def _close(self) -> None:
        if self._reader is not None:
            self._file.close()
            self._reader = self._file = None

    def remove(self) -> None:
        self._close()
        self.head = None
        for path in self.files:
            os.unlink(path)
        self.files = []


class TableSink:
    """One table's rows, batches in any order, written through `writer.write_batch` in table order.

    `name` is a table of schema.COLUMNS; `by_capture` orders by capture first (Parquet's findings,
    one partition file at a time). A watermark is a value of the sort column (txn, or frame for findings)
    or, with `by_capture`, a pair (capture, value); float("inf") stands for every value. Spill files go
    to a hidden directory in `spill_dir` (the system's temporary directory when None), made when first
    needed and removed by close() or discard(). `chunk_rows` bounds the rows of one writer call."""

    def __init__(self, name: str, writer: BatchWriter, by_capture: bool = False, spill_dir: str | None = None,
                 max_held: int = MAX_HELD, chunk_rows: int = CHUNK_ROWS) -> None:
        self.name, self.writer, self.by_capture = name, writer, by_capture
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
        self._runs: list[_Run] = []
        self._current: _Run | None = None  # the run spilled rows go on to
        self._floor: Key | None = None  # the highest watermark flushed: nothing may come below it
        self._dir: str | None = None

    def add(self, table: pa.Table) -> None:
        """A batch of rows (columns of batch_schema(name); see table_batches.conform), in the order found."""
        table = conform(self.name, table)
        n = table.num_rows
        if not n:
            return
        parts = order_keys(self.name, table, self.by_capture)
        if self._floor is not None and _below([p for _, p in parts], self._floor).any():
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
        """Write every held row whose key is below the watermark; the caller promises none will come
        below it any more. Returns the rows written."""
        prefix = self._prefix(watermark)
        written = self._emit(prefix)
        self._floor = prefix if self._floor is None or prefix > self._floor else self._floor
        return written

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
            return (0, str(watermark[0]), 0, _number(watermark[1]))
        return (0, _number(watermark))

    def _peak(self, held: int) -> None:
        self.peak_held = max(self.peak_held, held)

    def _sorted_held(self) -> pa.Table | None:
        """The rows in memory as one sorted table (also kept as the only held table)."""
        self._formatted()
        if not self._held:
            return None
        table = pa.concat_tables(self._held) if len(self._held) > 1 else self._held[0]
        if not self._held_sorted:
            table = _sorted(table, self._width)
        self._held, self._held_sorted = [table], True
        return table

    def _emit(self, limit: Key | None) -> int:
        """Write every row below `limit` (None: every row), merging memory and runs."""
        held = self._sorted_held()
        sources: list[Any] = []
        if held is not None:
            sources.append(held)
        sources += self._runs
        out = _Output(self)
        for piece in self._merge(sources, limit):
            out.add(piece)
        out.close()
        return out.rows

    def _merge(self, sources: list[Any], limit: Key | None) -> Iterator[pa.Table]:
        """Sorted pieces of every row below `limit` of the sources (a sorted table, or runs), in order.

        Each round takes, from every source's head block, the rows at or below the smallest last key
        of the runs' blocks: nothing still unread can sort below them."""
        memory = rest = None
        if sources and isinstance(sources[0], pa.Table):
            block = _Block(sources[0], self._width)
            below = len(block) if limit is None else block.count(limit)
            memory, rest = _Block(block.table.slice(0, below), self._width), block.table.slice(below)
        runs = [s for s in sources if isinstance(s, _Run)]
        try:
            while True:
                heads: list[tuple[_Run | None, _Block]] = []
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
                        memory = _Block(left, self._width)
                    else:
                        source.used(n)
                piece = pa.concat_tables(pieces) if len(pieces) > 1 else pieces[0]
                if len(pieces) > 1:
                    piece = _sorted(piece, self._width)
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
        out = _Block(table.slice(0, table.num_rows - keep), self._width)
        self._held, self._held_rows = [table.slice(table.num_rows - keep)], keep
        below = out.count(self._current.last) if self._current is not None and self._current.last else 0
        if below:  # lower than the current run's end: a run of their own
            run = _Run()
            self._runs.append(run)
            run.append(self._path(), out.table.slice(0, below), self.block, out.key(below - 1))
        if below < len(out):
            if self._current is None:
                self._current = _Run()
                self._runs.append(self._current)
            self._current.append(self._path(), out.table.slice(below), self.block, out.key(len(out) - 1))
        if len(self._runs) > FAN_IN:
            self._compact()

    def _compact(self) -> None:
        """Merge the FAN_IN smallest runs but the current one into one run."""
        others = sorted((r for r in self._runs if r is not self._current), key=lambda r: r.rows)[:FAN_IN]
        merged = _Run()
        pending: list[pa.Table] = []
        for piece in self._merge(others, None):
            pending.append(piece)
            if sum(p.num_rows for p in pending) >= self.block:
                self._append(merged, pending)
                pending = []
        if pending:
            self._append(merged, pending)
        self._runs = [r for r in self._runs if r.rows and all(r is not o for o in others)] + [merged]

    def _append(self, run: _Run, pieces: list[pa.Table]) -> None:
        table = pa.concat_tables(pieces)
        block = _Block(table, self._width)
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
