"""A bounded external sort for table rows: rows in any order, out in key order, stable.

Rows close out of order (a transaction is numbered by its write request but closes at its last
response), yet mostly only within a window. The spool keeps at most `memory_rows` rows: when full it
sorts them (Timsort is near-linear on such input), writes the lower half to the current sorted run on
disk and keeps the upper half to meet the next rows. A row below what that run already holds cannot go
there: such rows form a run of their own. So input out of order only within half the buffer makes one
run, however long the capture; anything else makes more runs. At the end the runs and the rows still in
memory are merged, at most `FAN_IN` runs at a time. Rows held in memory stay below `memory_rows` plus one
block per run being merged, whatever the input size.

Spill files are JSON, a block of entries a line: table rows hold only str, int, float, bool and None,
which JSON gives back exactly (and no file is ever read as code).
"""

from __future__ import annotations

import heapq
import json
import os
import shutil
import tempfile
from bisect import bisect_left
from collections.abc import Callable, Iterable, Iterator
from typing import IO

FAN_IN = 16  # runs merged at once: the merge holds one block of each


class Spool:
    """Rows in, sorted rows out (`chunks`), ties in the order they came in."""

    def __init__(self, key: Callable[[tuple], object], memory_rows: int = 4096, tmp_dir: str | None = None) -> None:
        self.key = key
        self.memory_rows = max(2, memory_rows)
        self.block = max(1, self.memory_rows // FAN_IN)  # entries per line of a spill file: what an open run costs
        self.tmp_dir = tmp_dir
        self.rows = 0  # rows added
        self.peak_held = 0  # most rows held in memory at once (buffer, merge blocks)
        self._buffer: list[tuple] = []  # (key, seq, row)
        self._run: IO[str] | None = None  # the run the lower halves go to
        self._last: tuple | None = None  # (key, seq) last written to it
        self._runs: list[str] = []  # spill files, one sorted run each
        self._dir: str | None = None
        self._files = 0  # spill files made so far (their names)

    def append(self, row: tuple, payload: object = None) -> None:
        """Add a row; `payload` (JSON-able), when given, is what comes out in its place, in the row's order."""
        self._buffer.append((self.key(row), self.rows, row if payload is None else payload))
        self.rows += 1
        if len(self._buffer) >= self.memory_rows:
            self._spill_half()

    def extend(self, rows: Iterable[tuple]) -> None:
        for row in rows:
            self.append(row)

    def chunks(self, size: int) -> Iterator[list[tuple]]:
        """The rows in order, `size` at a time; the spool is empty afterwards."""
        chunk: list[tuple] = []
        for row in self._sorted():
            chunk.append(row)
            if len(chunk) >= size:
                yield chunk
                chunk = []
        if chunk:
            yield chunk

    def close(self) -> None:
        """Forget every row and remove the spill files."""
        if self._run is not None:
            self._run.close()
            self._run = None
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None
        self._buffer, self._runs = [], []

    def _spill_half(self) -> None:
        buffer = self._buffer
        self.peak_held = max(self.peak_held, len(buffer))
        buffer.sort()  # (key, seq) never ties: rows are never compared
        half = len(buffer) // 2
        out, self._buffer = buffer[:half], buffer[half:]
        below = 0 if self._last is None else bisect_left(out, self._last)
        if below:  # lower than the current run's end: a run of their own
            with open(self._new_path(), "w", encoding="ascii") as f:
                _dump(out[:below], f, self.block)
        if below < len(out):
            if self._run is None:
                self._run = open(self._new_path(), "w", encoding="ascii")  # noqa: SIM115 - closed in _sorted
            _dump(out[below:], self._run, self.block)
            self._last = out[-1][:2]

    def _new_path(self) -> str:
        if self._dir is None:
            self._dir = tempfile.mkdtemp(prefix=".pd-analyze-spool-", dir=self.tmp_dir)
        self._files += 1
        path = os.path.join(self._dir, f"run-{self._files}")
        self._runs.append(path)
        return path

    def _sorted(self) -> Iterator[tuple]:
        try:
            rest, self._buffer = self._buffer, []
            self.peak_held = max(self.peak_held, len(rest))
            rest.sort()
            if self._run is not None:
                self._run.close()
                self._run = None
            runs = self._runs
            while len(runs) + 1 > FAN_IN:  # merge the oldest runs until one merge can take them all
                first, runs = runs[:FAN_IN], runs[FAN_IN:]
                merged = self._new_path()
                self._runs.pop()
                with open(merged, "w", encoding="ascii") as out:
                    block = []
                    for entry in self._merge(first, len(rest)):
                        block.append(entry)
                        if len(block) >= self.block:
                            _dump(block, out, self.block)
                            block = []
                    _dump(block, out, self.block)
                runs.append(merged)
            if not runs:
                for entry in rest:
                    yield entry[2]
                return
            for entry in heapq.merge(self._merge(runs, len(rest)), rest):
                yield tuple(entry[2]) if type(entry[2]) is list else entry[2]  # a row comes back from JSON as a list
        finally:
            self.close()

    def _merge(self, paths: list[str], resident: int) -> Iterator[tuple]:
        """Entries of sorted runs merged: (key, seq) never ties, so the rows are never compared."""
        held = [0] * len(paths)

        def read(i: int, path: str) -> Iterator[tuple]:
            with open(path, encoding="ascii") as f:
                for line in f:
                    block = json.loads(line)
                    held[i] = len(block)
                    self.peak_held = max(self.peak_held, resident + sum(held))
                    for key, seq, row in block:
                        yield _key(key), seq, row
            held[i] = 0
            os.unlink(path)

        return heapq.merge(*(read(i, p) for i, p in enumerate(paths)))


def _key(key: object) -> object:
    # JSON gives a tuple key back as a list: a tuple again, to compare with the keys held in memory
    return tuple(key) if isinstance(key, list) else key


def _dump(entries: list, file: IO[str], block: int) -> None:
    # ASCII escapes keep any string (even a lone surrogate from an undecodable file name) intact
    for i in range(0, len(entries), block):
        file.write(json.dumps(entries[i:i + block], ensure_ascii=True, separators=(",", ":")) + "\n")
