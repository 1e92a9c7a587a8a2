"""Sorted rows for the table sink: key comparisons, ordering a table, sorted blocks and runs on disk.

A table here carries its data columns, then its key parts (table_batches.order_keys) and SEQ, the last
`width` columns: those order it. A `Key` is a row's key parts and SEQ as Python values (a tuple compares as
the table sorts), or a prefix of them (a watermark).
"""

from __future__ import annotations

import os
from itertools import pairwise
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pd_analyze.analysis.table_batches import sort_indices

RUN_ROWS = 4_096  # rows in order, on average, worth keeping as slices rather than gathered

Key = tuple  # a row's key parts (order_keys), then its SEQ; a prefix of them for a watermark


def below(parts: list[Any], key: Key) -> np.ndarray:
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


def number(value: object) -> int | float:
    """A watermark's value as a Python number (float("inf") allowed, NaN not)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer) or value != value:
        raise TypeError(f"a watermark is a number, not {value!r}")
    return value if isinstance(value, int | float) else int(value)


def sort_order(table: pa.Table, width: int) -> np.ndarray:
    """The positions of a table's rows in the order of its last `width` columns (key parts, then SEQ)."""
    return sort_indices(table.select(table.column_names[-width:])).to_numpy()


def taken(table: pa.Table, order: np.ndarray) -> pa.Table:
    """The rows at these positions. Rows mostly come in order, a batch at a time, so the positions are
    usually a few runs of consecutive rows: those are sliced (no copy); rows in disorder are gathered."""
    starts = np.flatnonzero(np.diff(order) != 1) + 1
    if len(starts) + 1 > max(1, len(order) // RUN_ROWS):
        return table.take(pa.array(order))
    bounds = [0, *starts.tolist(), len(order)]
    return pa.concat_tables([table.slice(int(order[a]), b - a) for a, b in pairwise(bounds)])


def sorted_rows(table: pa.Table, width: int) -> pa.Table:
    """The table in the order of its last `width` columns."""
    return taken(table, sort_order(table, width))


class Block:
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


class Run:
    """A sorted run on disk: IPC files, each sorted and starting at or above where the one before ends."""

    def __init__(self) -> None:
        self.files: list[str] = []
        self.rows = 0
        self.last: Key | None = None  # the key of the last row appended
        self._reader: Any = None
        self._file: Any = None
        self._batch = 0  # next record batch of the first file
        self.head: Block | None = None  # rows read and not yet used

    def append(self, path: str, table: pa.Table, block: int, last: Key) -> None:
        with pa.OSFile(path, "wb") as sink, pa.ipc.new_file(sink, table.schema) as writer:
            writer.write_table(table, max_chunksize=block)
        self.files.append(path)
        self.rows += table.num_rows
        self.last = last

    def next_block(self, width: int) -> Block | None:
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
                self.head = Block(pa.Table.from_batches([batch]), width)
                continue
            self._close()
            os.unlink(self.files.pop(0))
        return self.head

    def used(self, n: int) -> None:
        assert self.head is not None
        self.rows -= n
        self.head = Block(self.head.table.slice(n), len(self.head.parts))

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


