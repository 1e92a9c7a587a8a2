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
        n = len(cols) if cols is not None else 0
        shared = np.empty(0, np.int64)
        if cols is not None and n:
            ids = {c: i for i, c in enumerate(cols.channel)}
            shared_ids = np.fromiter((ids[c] for c in mixed if c in ids), np.int64)
            alone = ~np.isin(cols.ch, shared_ids)
            shared = np.flatnonzero(~alone)
            self._reuse_columns(cols, alone)
        self._reuse_mixed(opened, cols, shared)

    def _reuse_mixed(self, opened: list[Txn], cols: TxnCols | None, shared: np.ndarray) -> None:
        """T1/T4 of the machine's transactions and the vector path's `shared` entries on their channels, in
        opening order, each against the one before it on its channel (the first against the channel's last of
        earlier batches): as one pass over them in that order would, the passes' lookups made as columns."""
        m = len(opened)
        if not m and not len(shared):
            return
        ks = shared.tolist()
        channels: dict[Channel, int] = {}
        ch = [channels.setdefault(t.channel, len(channels)) for t in opened]
        if len(shared):
            col_ch = np.fromiter((channels.setdefault(c, len(channels)) for c in cols.channel), np.int64,  # type: ignore[union-attr]
                                 len(cols.channel))  # type: ignore[union-attr]
            ch += col_ch[cols.ch[shared]].tolist()  # type: ignore[union-attr]
        col_ref: list[int] = []
        at = [t.opened_at for t in opened]
        if len(shared):
            at += cols.write_frame[shared].tolist()  # type: ignore[union-attr]
            col_ref = cols.ref[shared].tolist()  # type: ignore[union-attr]
        position = [t.position for t in opened] + [0] * len(ks)
        order = np.lexsort((np.array(position, np.int64), np.array(at, np.int64)))  # (stable, as list.sort)
        last = self.last
        names = list(channels)
        if len(last) + len(names) > last.cap.count:  # (the table may forget one of them within the pass)
            self._reuse_one_by_one(opened, cols, ks, order.tolist(), names, ch)
            return
        # each item's own (ref, frame T1/T4 name) and what it leaves as the channel's last (LastDone)
        ref = [t.ref for t in opened] + col_ref
        frame = [t.admitted for t in opened] + at[m:]

        def done(i: int) -> LastDone:  # what item i leaves as the channel's last
            return _done(opened[i]) if i < m else LastDone(at[i], ref[i], cols.verdict[ks[i - m]])  # type: ignore[union-attr]

        chs = np.array(ch, np.int64)[order]
        refs = np.array(ref, np.int64)[order]
        by_channel = np.lexsort((np.arange(len(order)), chs))  # each channel's items in opening order
        c_sorted = chs[by_channel]
        first = np.r_[True, c_sorted[1:] != c_sorted[:-1]]
        prev_same = np.zeros(len(order), bool)  # (item in `order` whose channel's previous item has its ref)
        prev_same[by_channel[1:]] = ~first[1:] & (refs[by_channel[1:]] == refs[by_channel[:-1]])
        prev_of = np.full(len(order), -1, np.int64)
        prev_of[by_channel[1:]] = np.where(first[1:], -1, by_channel[:-1])
        order_l = order.tolist()
        # the first item of each channel against what the table held of it
        candidates = set(np.flatnonzero(prev_same).tolist())
        before: dict[int, LastDone] = {}
        for j in by_channel[first].tolist():
            prev = last.get(names[int(chs[j])])
            if prev is not None:
                before[j] = _done(prev)
                if before[j].ref == int(refs[j]):
                    candidates.add(j)
        for j in sorted(candidates):
            i = order_l[j]
            prev_done = before[j] if j in before else done(order_l[int(prev_of[j])])
            found = reuse_finding(prev_done, ref[i], frame[i])
            if found is not None:
                if i < m:
                    opened[i].findings.append(found)
                else:
                    cols.findings.setdefault(ks[i - m], []).append(found)  # type: ignore[union-attr]
        # the table as the pass leaves it: each channel's last item, the channels in the order of those
        ends = np.r_[c_sorted[1:] != c_sorted[:-1], True]
        final = np.sort(by_channel[ends])
        for j in final.tolist():
            i = order_l[j]
            last.remember(names[int(chs[j])], opened[i] if i < m else done(i))
        self._txns += [opened[i].channel for i in order_l if i < m]

    def _reuse_one_by_one(self, opened: list[Txn], cols: TxnCols | None, ks: list[int], order: list[int],
                          names: list[Channel], ch: list[int]) -> None:
        """`_reuse_mixed` item after item (the table may forget a channel within the pass)."""
        m, last = len(opened), self.last
        for i in order:
            channel = names[ch[i]]
            prev = last.get(channel)
            if i < m:
                item = opened[i]
                ref, frame, findings, now = item.ref, item.admitted, item.findings, item
            else:
                k = ks[i - m]
                ref, frame = int(cols.ref[k]), int(cols.write_frame[k])  # type: ignore[union-attr]
                findings = cols.findings.setdefault(k, [])  # type: ignore[union-attr]
                now = LastDone(frame, ref, cols.verdict[k])  # type: ignore[union-attr]
            if prev is not None:
                found = reuse_finding(_done(prev), ref, frame)
                if found is not None:
                    findings.append(found)
            last.remember(channel, now)
            if i < m:
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
