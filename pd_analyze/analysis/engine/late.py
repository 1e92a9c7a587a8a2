"""Copies that come after their transaction's rows were made: a duplicate answer, a retransmitted request or a
mirror-port copy of a call whose transaction closed in an earlier batch. The call's copy belongs to the
transaction (its `frames`, protocol.md 7.6; a request's copy is one more of its `rpc_retransmissions`), so a
batch's rows are held as long as a copy can still be recognised: the pairing knows an answered call for
rpc_timeout of capture time after its answer (engine.calls). Held rows go on when that time has passed, when
the held transactions or their tables' bytes reach their cap (the oldest go first; a later copy is then not
listed), or at the capture's end, with the copies met meanwhile added to their transactions' rows.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
import pyarrow as pa

from pd_analyze.analysis.engine.txn import Txn
from pd_analyze.analysis.engine.txncols import TxnCols
from pd_analyze.model.capped import LATE_COPIES


@dataclass(slots=True)
class _Held:
    until: int  # capture time (ns) after which no copy of its calls is recognised
    tables: dict[str, list[pa.Table]]
    calls: dict[int, list[int]]  # the loop's transactions' calls: request frame -> transaction numbers
    frames: np.ndarray  # the vector path's calls: request frames, sorted (int64)
    numbers: np.ndarray  # their transaction numbers, in that order
    count: int  # its transactions
    size: int  # its tables' bytes

    def numbers_of(self, frame: int) -> list[int]:
        """The held transactions with a call whose request is at `frame` (the loop's first, as they were held)."""
        out = self.calls.get(frame, [])
        a, b = np.searchsorted(self.frames, [frame, frame + 1]).tolist()
        return out + self.numbers[a:b].tolist() if b > a else out


@dataclass(slots=True)
class _Extra:
    frames: list[int] = field(default_factory=list)
    copies: int = 0  # request copies: retransmissions


class LateCopies:
    """Rows held for the copies still to come, by batch."""

    def __init__(self, rpc_timeout_ns: int) -> None:
        self.timeout = rpc_timeout_ns
        self._held: deque[_Held] = deque()
        self._extra: dict[int, _Extra] = {}  # transaction number -> what copies added to it
        self._count = 0
        self._bytes = 0

    def hold(self, tables: dict[str, list[pa.Table]], txns: list[Txn], cols: TxnCols | None, offset: int,
             now: int) -> None:
        """A batch's rows of `txns` (the loop's) and `cols` (the vector path's, numbered `offset` on)."""
        calls: dict[int, list[int]] = {}
        for t in txns:
            for c in t.calls:
                if c is not None:
                    calls.setdefault(c.frame, []).append(t.number + offset)
        frames = numbers = np.empty(0, np.int64)
        if cols is not None and len(cols):  # each transaction's write, then its reads (never fragmented)
            n = len(cols)
            owner = np.repeat(np.arange(n), np.diff(cols.read_offsets))
            at = np.arange(n) + cols.read_offsets[:-1]  # the write's place; its reads after it
            frames = np.empty(n + len(owner), np.int64)
            frames[at] = cols.write_frame
            frames[np.arange(len(owner)) + owner + 1] = cols.read_frames[:len(owner)]
            numbers = np.empty(len(frames), np.int64)
            numbers[at] = cols.number + offset
            numbers[np.arange(len(owner)) + owner + 1] = cols.number[owner] + offset
            order = np.argsort(frames, kind="stable")
            frames, numbers = frames[order], numbers[order]
        count = len(txns) + (len(cols) if cols is not None else 0)
        size = sum(table.nbytes for parts in tables.values() for table in parts)
        self._held.append(_Held(now + self.timeout, tables, calls, frames, numbers, count, size))
        self._count += count
        self._bytes += size

    def copy(self, call_frame: int, frames: tuple[int, ...], resent: bool) -> int | None:
        """A copy (its `frames`) of the call whose request is at `call_frame`: the number of the held transaction
        it belongs to (the first, for a Write-Multiple's), None when none is held; `resent`: a retransmission of its
        request (a request with another body under the same key is a frame of it, not a retransmission)."""
        numbers = [n for held in self._held for n in held.numbers_of(call_frame)]
        if not numbers:
            return None
        for n in numbers:
            extra = self._extra.setdefault(n, _Extra())
            extra.frames += frames
            extra.copies += resent
        return numbers[0]

    def release(self, now: int, everything: bool = False) -> list[dict[str, list[pa.Table]]]:
        """The held rows that may go at capture time `now` (all of them with `everything`), copies added."""
        out = []
        while self._held and (everything or self._held[0].until < now or self._count > LATE_COPIES.count
                              or self._bytes > LATE_COPIES.bytes):
            held = self._held.popleft()
            self._count -= held.count
            self._bytes -= held.size
            if self._extra:
                held.tables["transactions"] = [self._patched(t) for t in held.tables.get("transactions", [])]
            out.append(held.tables)
        return out

    def _patched(self, table: pa.Table) -> pa.Table:
        """A transactions table with the copies met added to its rows' frames and retransmissions."""
        numbers = table.column("txn").to_pylist()
        if not any(n in self._extra for n in numbers):
            return table
        frames = table.column("frames").to_pylist()
        copies = table.column("rpc_retransmissions").to_pylist()
        for i, n in enumerate(numbers):
            extra = self._extra.pop(n, None)
            if extra is None:
                continue
            have = [int(f) for f in frames[i].split()] if frames[i] else []
            frames[i] = " ".join(map(str, sorted(set(have) | set(extra.frames))))
            copies[i] = int(copies[i] or 0) + extra.copies
        i = table.schema.get_field_index("frames")
        table = table.set_column(i, table.schema.field(i), pa.array(frames, table.schema.field(i).type))
        i = table.schema.get_field_index("rpc_retransmissions")
        return table.set_column(i, table.schema.field(i), pa.array(np.array(copies, np.int64), pa.int64()))
