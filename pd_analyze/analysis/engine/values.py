"""The values a change replaced (protocol.md 7.6's change trail): per element of each change, the value last
read back before its write request, whichever way (loop or vector) the read and the change went.

The reads and changes of a batch are expanded to one entry per parameter element as columns, matched by
element and frame with one sort; only the values a change needs, and the last value of each element read
in the batch (kept for the batches to come, capped), are made into text.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from pd_analyze.analysis.engine.records import Element
from pd_analyze.analysis.engine.vector import pair_ids
from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.model import pd_values as pt
from pd_analyze.model.capped import READ_VALUES, CappedTable

_KINDS: dict[int, int] = {}  # format code -> 0 number, 1 one value per block (strings), 2 text cells split
for _code, _spec in pt.FORMATS.items():
    _KINDS[_code] = 0 if _spec.kind in ("hex", "bits", "nibbles") else 1 if _spec.kind in (
        "string", "octets", "unicode") else 2
_KIND = np.full(256, 2, np.int8)
for _code, _k in _KINDS.items():
    _KIND[_code] = _k
_SIZE = np.zeros(256, np.int64)
for _code, _spec in pt.FORMATS.items():
    _SIZE[_code] = _spec.size


@dataclass(slots=True)
class Elements:
    """One entry per parameter element: its key (device << 8 | DO, PNU << 17 | subindex), its frame, and
    how to get its value (`value(i)`)."""

    k1: np.ndarray  # uint64
    k2: np.ndarray  # uint64
    frame: np.ndarray  # int64
    owner: np.ndarray  # int64: the read or change it comes from (its index in the caller's list)
    value: Callable[[int], str]

    def __len__(self) -> int:
        return len(self.k1)


def _empty() -> Elements:
    e = np.empty(0, np.int64)
    return Elements(e.astype(np.uint64), e.astype(np.uint64), e, e, lambda i: "")


def column_reads(view: BatchView, req: np.ndarray, res: np.ndarray, device: np.ndarray, do: np.ndarray,
                 frame: np.ndarray) -> Elements:
    """The elements reads answered in the batch brought back (request and response column records): per
    Value address answered with values, all its elements, or the first when the drive gave one value
    (as Records.read_back)."""
    rc, a, b = view.records.records, view.records.addresses, view.records.blocks
    n = np.minimum(rc.n_addr[req], rc.n_blocks[res]).astype(np.int64)
    owner = np.repeat(np.arange(len(req)), n)
    first = np.cumsum(n) - n
    j = np.arange(int(n.sum())) - np.repeat(first, n)
    ai = rc.first_addr[req][owner] + j
    bi = rc.first_block[res][owner] + j
    fmt = b.format[bi]
    values = b.n_values[bi].astype(np.int64)
    kind = _KIND[fmt]
    count = np.maximum(a.n_elems[ai].astype(np.int64), 1)
    got = np.where(kind == 1, 1, values)  # a string is one value
    m = np.where(got == count, count, np.where(got == 1, 1, 0))
    m[(a.attr[ai] != pt.ATTR_VALUE) | (fmt == pt.FMT_ERROR)] = 0
    pair = np.repeat(np.arange(len(m)), m)
    i = np.arange(int(m.sum())) - np.repeat(np.cumsum(m) - m, m)
    sub = a.subindex[ai][pair].astype(np.uint64) + i.astype(np.uint64)
    k1 = device[owner[pair]].astype(np.uint64) << np.uint64(8) | do[owner[pair]].astype(np.uint64)
    k2 = a.pnu[ai][pair].astype(np.uint64) << np.uint64(17) | sub
    buf = view.batch.buf
    texts: list[str] | None = None
    # (lists: value() is asked of one element at a time)
    kinds, starts, sizes = kind[pair].tolist(), b.data_start[bi][pair].tolist(), _SIZE[fmt][pair].tolist()
    blocks, items = bi[pair].tolist(), i.tolist()

    def value(e: int) -> str:
        nonlocal texts
        if kinds[e] == 0:
            size = sizes[e]
            at = starts[e] + items[e] * size
            return str(int.from_bytes(buf[at:at + size], "big"))
        if texts is None:
            texts = view.block_texts
        cell = texts[blocks[e]]
        return cell if kinds[e] == 1 else cell.split(" ")[items[e]] if " " in cell else cell

    return Elements(k1, k2, frame[owner[pair]], owner[pair], value)


def change_elements(view: BatchView, req: np.ndarray, device: np.ndarray, do: np.ndarray,
                    frame: np.ndarray) -> tuple[Elements, np.ndarray, np.ndarray]:
    """The elements changes of the batch write (their request column records), with per element its
    address (position among the change's addresses) and its place among the address's elements."""
    rc, a = view.records.records, view.records.addresses
    n = rc.n_addr[req].astype(np.int64)
    owner = np.repeat(np.arange(len(req)), n)
    position = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
    ai = rc.first_addr[req][owner] + position
    m = np.maximum(a.n_elems[ai].astype(np.int64), 1)
    pair = np.repeat(np.arange(len(m)), m)
    i = np.arange(int(m.sum())) - np.repeat(np.cumsum(m) - m, m)
    k1 = device[owner[pair]].astype(np.uint64) << np.uint64(8) | do[owner[pair]].astype(np.uint64)
    sub = a.subindex[ai][pair].astype(np.uint64) + i.astype(np.uint64)
    k2 = a.pnu[ai][pair].astype(np.uint64) << np.uint64(17) | sub
    return Elements(k1, k2, frame[owner[pair]], owner[pair], lambda e: ""), position[pair], i


def listed_reads(pairs: list[tuple[Element, str]], frames: list[int], owners: list[int]) -> Elements:
    """Reads the loop closed (their elements and values, as Records.read_back gives them)."""
    if not pairs:
        return _empty()
    k1 = np.array([(e[0] << 8) | e[1] for e, _ in pairs], np.uint64)
    k2 = np.array([(e[2] << 17) | e[3] for e, _ in pairs], np.uint64)
    values = [v for _, v in pairs]
    return Elements(k1, k2, np.array(frames, np.int64), np.array(owners, np.int64), values.__getitem__)


class ReadValues:
    """The value last read back of each element, from batch to batch (capped: the oldest forgotten)."""

    def __init__(self) -> None:
        # by element as two integers (device << 8 | DO, PNU << 17 | subindex: Elements.k1, k2)
        self.table: CappedTable[tuple[int, int], str] = CappedTable(READ_VALUES)

    def before(self, reads: list[Elements], changes: Elements) -> np.ndarray:
        """Per change element, the value last read back before its frame (this batch's reads first, then
        what earlier batches read; None: none), as an object array; then this batch's reads become the last
        read of their elements."""
        reads = [r for r in reads if len(r)]
        k1 = np.concatenate([r.k1 for r in reads]) if reads else np.empty(0, np.uint64)
        k2 = np.concatenate([r.k2 for r in reads]) if reads else np.empty(0, np.uint64)
        frame = np.concatenate([r.frame for r in reads]) if reads else np.empty(0, np.int64)
        source = np.concatenate([np.full(len(r), s) for s, r in enumerate(reads)]) if reads else np.empty(0, np.int64)
        index = np.concatenate([np.arange(len(r)) for r in reads]) if reads else np.empty(0, np.int64)
        out = np.full(len(changes), None, object)
        if not len(k1):  # no read in the batch: what earlier batches read, if anything
            self._earlier(changes, np.arange(len(changes)), out)
            return out
        # elements numbered over reads and changes together
        all1, all2 = np.concatenate([k1, changes.k1]), np.concatenate([k2, changes.k2])
        ids, _first = pair_ids(all1, all2)
        rid, cid = ids[:len(k1)], ids[len(k1):]
        order = np.lexsort((frame, rid))  # reads by element, then frame
        combined = (rid[order] << np.int64(40)) | frame[order]
        query = (cid << np.int64(40)) | changes.frame
        at = np.searchsorted(combined, query, "left") - 1  # the last read of the element before the frame
        hit = (at >= 0) & (rid[order][np.maximum(at, 0)] == cid)
        found = order[at[hit]]
        for e, s, i in zip(np.flatnonzero(hit).tolist(), source[found].tolist(), index[found].tolist(), strict=True):
            out[e] = reads[s].value(i)
        self._earlier(changes, np.flatnonzero(~hit), out)
        # the last read of each element in the batch
        last = np.r_[rid[order][1:] != rid[order][:-1], True]
        table = self.table
        lasts = order[last]
        for key, s, i in zip(zip(k1[lasts].tolist(), k2[lasts].tolist(), strict=True), source[lasts].tolist(),
                             index[lasts].tolist(), strict=True):
            table.remember(key, reads[s].value(i))
        return out

    def _earlier(self, changes: Elements, rows: np.ndarray, out: np.ndarray) -> None:
        """out[rows]: the value earlier batches last read of each of those change elements."""
        if not len(self.table) or not len(rows):
            return
        get = self.table.get
        out[rows] = [get(key) for key in zip(changes.k1[rows].tolist(), changes.k2[rows].tolist(), strict=True)]
