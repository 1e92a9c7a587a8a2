"""What a batch's transactions learn from the channel's history once all of them are known, whichever way
(loop or vector) they went: T1/T4 (the channel's last transaction, protocol.md 6.5) and the values a change
replaced (the values last read back before its write request, 7.6's change trail), both in frame order."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from pd_analyze.analysis.engine.facts import Channel
from pd_analyze.analysis.engine.records import Records
from pd_analyze.analysis.engine.rules import LastDone, reuse_finding
from pd_analyze.analysis.engine.txn import Txn
from pd_analyze.analysis.engine.txncols import TxnCols
from pd_analyze.analysis.engine.values import Elements, ReadValues, change_elements, column_reads, listed_reads
from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.model import pd_values as pt
from pd_analyze.model.capped import CHANNEL_HISTORY, CappedTable
from pd_analyze.model.verdicts import ANSWERED


class Finals:
    """The channels' last transactions and the values last read back, from batch to batch (capped)."""

    def __init__(self) -> None:
        self.last: CappedTable[Channel, LastDone | Txn] = CappedTable(CHANNEL_HISTORY)
        self._txns: list[Channel] = []  # the channels whose last is a Txn (settle looks at those only)
        self.values = ReadValues()

    def apply(self, opened: list[Txn], closed: list[Txn], cols: TxnCols | None, view: BatchView | None,
              records: Records) -> None:
        """T1/T4 on each transaction opened in the batch (`opened` by the machine, `cols` by the vector
        path), then the values read (`closed`, `cols`) and replaced, in frame order."""
        self._reuse(opened, cols)
        self._values(opened, closed, cols, view, records)

    def settle(self) -> None:
        """The end of a batch: a closed transaction is remembered by what T1/T4 need of it only."""
        still = []
        for channel in self._txns:
            prev = self.last.get(channel)
            if not isinstance(prev, Txn):
                continue  # (forgotten, or followed by a closed one since)
            if prev.closed_by:
                self.last[channel] = LastDone(prev.write_frame, prev.ref, prev.verdict)
            else:
                still.append(channel)
        self._txns = still

    # --- T1/T4 --------------------------------------------------------------------------------------------
    def _reuse(self, opened: list[Txn], cols: TxnCols | None) -> None:
        """Each transaction against the channel's last (the one before it in opening order, closed by then:
        a channel has one pending transaction at most)."""
        mixed = {t.channel for t in opened}  # channels with transactions of the machine: one by one
        items: list[tuple[int, int, Channel, object]] = [(t.opened_at, t.position, t.channel, t) for t in opened]
        n = len(cols) if cols is not None else 0
        alone = np.ones(n, bool)
        if cols is not None and n:
            ids = {c: i for i, c in enumerate(cols.channel)}
            shared = np.fromiter((ids[c] for c in mixed if c in ids), np.int64)
            alone = ~np.isin(cols.ch, shared)
            for k in np.flatnonzero(~alone).tolist():
                items.append((int(cols.write_frame[k]), 0, cols.channel[int(cols.ch[k])], k))
            self._reuse_columns(cols, alone)
        items.sort(key=lambda item: item[:2])
        last = self.last
        for _at, _pos, channel, item in items:
            prev = last.get(channel)
            if isinstance(item, Txn):
                ref, frame, findings, now = item.ref, item.admitted, item.findings, item
            else:
                k = int(item)  # type: ignore[call-overload]
                ref, frame = int(cols.ref[k]), int(cols.write_frame[k])  # type: ignore[union-attr]
                findings = cols.findings.setdefault(k, [])  # type: ignore[union-attr]
                now = LastDone(frame, ref, cols.verdict[k])  # type: ignore[union-attr]
            if prev is not None:
                found = reuse_finding(_done(prev), ref, frame)
                if found is not None:
                    findings.append(found)
            last.remember(channel, now)
            if now is item:
                self._txns.append(channel)

    def _reuse_columns(self, cols: TxnCols, alone: np.ndarray) -> None:
        """T1/T4 of the vector path's transactions on channels the machine had none on: each against the one
        before it on its channel (the first against the channel's last of earlier batches)."""
        k = np.flatnonzero(alone)
        if not len(k):
            return
        order = k[np.lexsort((cols.write_frame[k], cols.ch[k]))]
        ch = cols.ch[order]
        first = np.r_[True, ch[1:] != ch[:-1]]
        prev_ref = np.r_[-2, cols.ref[order][:-1]]
        same = ~first & (cols.ref[order] == prev_ref)
        for j in np.flatnonzero(same | first).tolist():
            e = int(order[j])
            if first[j]:
                prev = self.last.get(cols.channel[int(ch[j])])
                if prev is None:
                    continue
                before = _done(prev)
            else:
                p = int(order[j - 1])
                before = LastDone(int(cols.write_frame[p]), int(cols.ref[p]), cols.verdict[p])
            found = reuse_finding(before, int(cols.ref[e]), int(cols.write_frame[e]))
            if found is not None:
                cols.findings.setdefault(e, []).append(found)
        ends = np.r_[ch[1:] != ch[:-1], True]
        for j in np.flatnonzero(ends).tolist():
            e = int(order[j])
            self.last.remember(cols.channel[int(ch[j])], LastDone(int(cols.write_frame[e]), int(cols.ref[e]),
                                                                  cols.verdict[e]))

    # --- values read and replaced -----------------------------------------------------------------------
    def _values(self, opened: list[Txn], closed: list[Txn], cols: TxnCols | None, view: BatchView | None,
                records: Records) -> None:
        reads: list[Elements] = []
        pairs, frames, owners = [], [], []
        for k, t in enumerate(closed):
            if t.req_id == pt.REQ_READ and t.verdict in ANSWERED and t.request is not None and t.response is not None:
                got = records.read_back(t.request, t.response, t.channel[0], t.do)
                pairs += got
                frames += [t.read_res_frame] * len(got)
                owners += [k] * len(got)
        reads.append(listed_reads(pairs, frames, owners))
        if cols is not None and view is not None and len(cols):
            read = np.flatnonzero((cols.req_id == pt.REQ_READ) & (cols.res >= 0))
            device = np.array([c[0] for c in cols.channel], np.int64)[cols.ch] if cols.channel else cols.ch
            reads.append(column_reads(view, cols.req[read], cols.res[read], device[read], cols.do[read],
                                      cols.read_res_frame[read]))
        # the changes: the machine's and the vector path's, element by element as columns
        machine = [t for t in opened if records.writes_values(t.request, t.req_id)]
        listed, listed_position = _listed_changes(machine, records)
        column = None
        if cols is not None and view is not None and len(cols):
            change = np.flatnonzero((cols.req_id == pt.REQ_CHANGE) & (cols.req >= 0))
            if len(change):
                device = np.array([c[0] for c in cols.channel], np.int64)[cols.ch]
                column = (change, *change_elements(view, cols.req[change], device[change], cols.do[change],
                                                   cols.write_frame[change]))
        changes = listed if column is None else _concat(listed, column[1])
        if not len(changes) and not any(len(r) for r in reads):
            return
        values = self.values.before(reads, changes)
        for e, pos, text in _known(listed.owner, listed_position, values[:len(listed)]):
            before = machine[e].values_before
            before += [""] * (pos + 1 - len(before))
            before[pos] = text
        if column is not None:
            change, elements, position, _i = column
            for e, pos, text in _known(change[elements.owner], position, values[len(listed):]):
                before = cols.values_before.setdefault(e, [])  # type: ignore[union-attr]
                before += [""] * (pos + 1 - len(before))
                before[pos] = text


def _listed_changes(machine: list[Txn], records: Records) -> tuple[Elements, np.ndarray]:
    """The elements the machine's changes write (owner: the change's place in `machine`), with per element
    its address's position among the change's addresses."""
    addresses = [records.address_array(t.request) for t in machine]
    counts = np.fromiter((len(a) for a in addresses), np.int64, len(addresses))
    table = np.concatenate(addresses) if addresses else np.empty((0, 4), np.int64)
    entry = np.repeat(np.arange(len(machine)), counts)
    position = np.arange(len(table)) - np.repeat(np.cumsum(counts) - counts, counts)
    m = np.maximum(table[:, 1], 1)
    pair = np.repeat(np.arange(len(table)), m)
    i = np.arange(int(m.sum())) - np.repeat(np.cumsum(m) - m, m)
    device = np.fromiter((t.channel[0] for t in machine), np.int64, len(machine))
    do = np.fromiter((t.do & 0xFF for t in machine), np.int64, len(machine))
    opened = np.fromiter((t.opened_at for t in machine), np.int64, len(machine))
    owner = entry[pair]
    k1 = (device[owner] << 8 | do[owner]).astype(np.uint64)
    k2 = (table[pair, 2] << 17 | (table[pair, 3] + i)).astype(np.uint64)
    return Elements(k1, k2, opened[owner], owner, lambda e: ""), position[pair]


def _known(entry: np.ndarray, position: np.ndarray, values: np.ndarray) -> Iterator[tuple[int, int, str]]:
    """The value_before cells of changes from their elements (entry, address position: address after
    address) and the values last read of them (None: none): (entry, position, text) of each address every
    element of which has a value (the others' cell is "")."""
    known = (values != None) & (values != "")  # noqa: E711 (element-wise on an object array)
    if not known.any():
        return
    starts = np.flatnonzero(np.r_[True, (entry[1:] != entry[:-1]) | (position[1:] != position[:-1])])
    ends = np.r_[starts[1:], len(values)]
    for g in np.flatnonzero(np.logical_and.reduceat(known, starts)).tolist():
        first = int(starts[g])
        yield int(entry[first]), int(position[first]), " ".join(values[first:int(ends[g])].tolist())


def _done(prev: LastDone | Txn) -> LastDone:
    return LastDone(prev.write_frame, prev.ref, prev.verdict) if isinstance(prev, Txn) else prev


def _concat(a: Elements, b: Elements) -> Elements:
    return Elements(np.concatenate([a.k1, b.k1]), np.concatenate([a.k2, b.k2]), np.concatenate([a.frame, b.frame]),
                    np.concatenate([a.owner, b.owner]), lambda e: "")
