"""What the vector path takes of a part: the ordinary calls and transactions (engine.vector) whose keys,
activities and channels no row of the loop shares, and which the loop's caps leave room for; the rest is
the loop's (engine.run). Also what the loop must know of the calls taken: their keys and bodies, remembered
for late copies.

Split from engine.run, which calls it once a part: run imports this module, never the other way.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from pd_analyze.analysis.engine.calls import Pairing
from pd_analyze.analysis.engine.decode import Decoded
from pd_analyze.analysis.engine.facts import Pdu
from pd_analyze.analysis.engine.machine import Machine
from pd_analyze.analysis.engine.numbering import Numbering
from pd_analyze.analysis.engine.vector import Calls, Episodes, episodes, key_hash, pair, pair_ids, pair_key
from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.model.capped import KNOWN_ACTIVITIES, OPEN_CALLS, PENDING_TRANSACTIONS, TXN_CALLS
from pd_analyze.model.values import PTYPE_FAULT, PTYPE_REJECT, PTYPE_REQUEST, PTYPE_RESPONSE
from pd_analyze.protocol.profiles import RecordLimit
from pd_analyze.protocol.rpc_calls import CALL_OVERHEAD

_ANSWERS = (PTYPE_RESPONSE, PTYPE_FAULT, PTYPE_REJECT)  # what answers a call


@dataclass(frozen=True, slots=True)
class Costs:
    """The most one item of the loop's capped tables counts (bytes, as model.capped charges them) under the
    profile's record limit (protocol.md 3.6): a channel's last parameter request (its addresses), a pending
    transaction (engine.machine), an open call (engine.calls.Pairing)."""

    request: int
    pending: int
    call: int

    @staticmethod
    def of(record: RecordLimit) -> Costs:
        n = record.max_params
        return Costs(64 + 72 * n, 1024 + 256 + 2 * record.max_length + (128 + 192) * n, CALL_OVERHEAD + 65_536)


class VectorTake:
    """The vector path's share of each part, decided against the loop's state (its pairing, machine and
    numbering); `first`: the activities the part's column rows make known, at their first frames."""

    def __init__(self, enabled: bool, pairing: Pairing, machine: Machine, numbering: Numbering,
                 costs: Costs) -> None:
        self.enabled = enabled
        self.pairing, self.machine, self.numbering, self.costs = pairing, machine, numbering, costs
        self.first: dict[tuple[int, int], int] = {}

    def part(self, dec: Decoded, runmax_all: np.ndarray, runmax_pnio: np.ndarray) -> tuple[Calls, Episodes]:
        """The calls and transactions of the part the vector path takes whole (none when it is off, or when
        the caps come near: then the loop's order of evictions decides, and it takes everything)."""
        view = dec.view
        p = view.p
        empty = np.empty(0, np.int64)
        none = Calls(empty, empty, np.empty(0, bool)), Episodes(empty, empty, empty, empty, empty, empty, empty,
                                                              empty, [])
        if not self.enabled or not len(dec.rows) or self.numbering.barrier(self.pairing) is not None:
            return none  # (a cut write request of an earlier part awaits its answer: numbers wait)
        # rows the loop has, or might have, a share in: their keys stay the loop's (an activity does not:
        # what the loop decides by activity, a PDU of another interface, it decides by the activities first
        # seen before it in frame order, `first_seen`)
        excluded = np.zeros(len(dec.rows), bool)
        keys = {row.key for row in dec.odd_rows if row.key[0] or row.key[1]}
        rows = dec.rows
        if keys:
            hashes = key_hash(np.array([k[0] for k in keys], np.uint64), np.array([k[1] for k in keys], np.uint64),
                              np.array([k[2] for k in keys], np.uint32))
            excluded |= np.isin(key_hash(p.act_hi[rows], p.act_lo[rows], p.seq[rows]), hashes)
        if dec.dropped:
            excluded |= np.isin(rows, np.fromiter(dec.dropped, np.int64, len(dec.dropped)))
        horizon = cut_horizon(view, rows, dec.odd_rows)
        if horizon is not None:
            excluded |= view.frame_no[rows] >= horizon
        if excluded.any():  # a key the loop meets stays whole the loop's: it must know every call under it
            # (a call taken here is known to the pairing only after the loop ran over the part)
            hashed = key_hash(p.act_hi[rows], p.act_lo[rows], p.seq[rows])
            excluded |= np.isin(hashed, hashed[excluded])
        pairing = self.pairing
        self.first = self.first_seen(view, rows)
        if len(pairing.activities) + len(self.first) >= KNOWN_ACTIVITIES.count:
            self.first = {}
            return none  # (the loop's order of evictions decides)
        known = Known(pairing)
        runmax_pdu = runmax_all[p.pos]
        calls = pair(view, rows, runmax_pdu, pairing.timeout, excluded, known)
        if not len(calls.q):
            return none
        # the loop's rows between each drive and controller (odd rows, and the column rows not taken)
        taken = np.zeros(len(p.pos), bool)
        taken[calls.q] = True
        taken[calls.s] = True
        loop_cols = rows[~taken[rows]]
        static = runmax_pnio[p.pos]
        ep = empty_episodes()
        frames_by_pair = loop_frames(view, loop_cols, dec.odd_rows, None, calls)
        for _ in range(8):  # episodes refused add their rows to the loop's; until nothing changes
            ep = episodes(view, calls, frames_by_pair, static, self.machine.timeout, self.machine.b5_threshold)
            more = loop_frames(view, loop_cols, dec.odd_rows, ep, calls)
            if all(np.array_equal(more.get(k, EMPTY), v) for k, v in frames_by_pair.items()) and \
                    more.keys() == frames_by_pair.keys():
                break
            frames_by_pair = more
        else:  # (not settled: the loop takes every transaction of the part)
            ep = empty_episodes()
        # PROFIdrive calls outside an episode are the loop's
        in_ep = np.zeros(len(calls.q), bool)
        in_ep[ep.w] = True
        in_ep[ep.reads] = True
        keep = ~calls.pd | in_ep
        out = Calls(calls.q[keep], calls.s[keep], calls.pd[keep])
        if self.near_caps(most_at_once(view.frame_no[out.q], view.frame_no[out.s]),
                          most_at_once(ep.start, ep.end)):
            return none
        index = np.full(len(calls.q), -1, np.int64)
        index[np.flatnonzero(keep)] = np.arange(int(keep.sum()))
        return out, Episodes(index[ep.w], index[ep.reads], ep.first_read, ep.n_reads, ep.channel, ep.group, ep.start,
                             ep.end, ep.channels)

    def first_seen(self, view: BatchView, rows: np.ndarray) -> dict[tuple[int, int], int]:
        """The activities of the column `rows` (frame order) not known when the part begins: activity -> the
        frame of its first row."""
        p = view.p
        if not len(rows):
            return {}
        hi, lo = p.act_hi[rows], p.act_lo[rows]
        _ids, first = pair_ids(hi, lo)
        known = self.pairing.activities
        frames = view.frame_no[rows[first]].tolist()
        return {act: frame for act, frame in zip(zip(hi[first].tolist(), lo[first].tolist(), strict=True), frames,
                                                  strict=True) if act not in known}

    def near_caps(self, calls: int, transactions: int) -> bool:
        """Whether the loop's tables could reach a cap with the calls and transactions the vector path takes
        (at most `calls` and `transactions` of them open at once), where the order the loop meets rows in
        decides what is evicted: the loop then takes the part whole."""
        machine, pairing = self.machine, self.pairing
        return (len(machine.pending) + transactions >= PENDING_TRANSACTIONS.count
                or machine.pending.bytes + transactions * self.costs.pending >= PENDING_TRANSACTIONS.bytes
                or len(pairing.open) + calls >= OPEN_CALLS.count
                or pairing.open.bytes + calls * self.costs.call >= OPEN_CALLS.bytes
                or len(machine.calls_table()) + calls >= TXN_CALLS.count)

    def remember_calls(self, view: object, calls: Calls) -> None:
        """The calls the vector path took, answered: remembered rpc_timeout after the answer (a late copy is
        recognised by its key and body digest), their activities known."""
        if not len(calls.q):
            return
        p, ns, buf = view.p, view.batch.ns, memoryview(view.batch.buf)  # type: ignore[attr-defined]
        q, s = calls.q, calls.s
        start, length = p.body_start[q].astype(np.int64).tolist(), p.body_len[q].astype(np.int64).tolist()
        hi, lo = p.act_hi[q].tolist(), p.act_lo[q].tolist()
        keys = list(zip(hi, lo, p.seq[q].tolist(), strict=True))
        columns = {"frame": view.frame_no[q].tolist(), "ts": ns[p.pos[q]].tolist(),  # type: ignore[attr-defined]
                   "answered": ns[p.pos[s]].tolist(), "src": p.src[q].tolist(), "dst": p.dst[q].tolist(),
                   "if_hi": p.if_hi[q].tolist(), "if_lo": p.if_lo[q].tolist(), "opnum": p.opnum[q].tolist(),
                   "digest": [zlib.crc32(buf[a:a + n]) for a, n in zip(start, length, strict=True)], "size": length,
                   "response_frame": view.frame_no[s].tolist()}  # type: ignore[attr-defined]
        self.pairing.remember_log(keys, columns)


def most_at_once(begin: np.ndarray, end: np.ndarray) -> int:
    """The most of the intervals [begin, end] (frames) open at one time."""
    if not len(begin):
        return 0
    events = np.concatenate([begin, end])
    step = np.concatenate([np.ones(len(begin), np.int64), -np.ones(len(end), np.int64)])
    order = np.lexsort((-step, events))  # (at one frame an opening before a closing: counted together)
    return int(np.cumsum(step[order]).max())


class Known:
    """Keys the loop holds (open calls, calls answered lately)."""

    def __init__(self, pairing: Pairing) -> None:
        self.pairing = pairing

    def unknown(self, keys: list[tuple[int, int, int]]) -> np.ndarray:
        """Per key, whether it is not `in` this (a pass over each table the pairing holds keys in)."""
        pairing = self.pairing
        out = np.ones(len(keys), bool)
        for table in (pairing.open, pairing.closed, *(log.index for log in pairing.logs)):
            if table:
                out &= np.fromiter((k not in table for k in keys), bool, len(keys))
        return out

    def __bool__(self) -> bool:
        pairing = self.pairing
        return bool(pairing.open or pairing.closed or pairing.logs)


EMPTY = np.empty(0, np.int64)


def empty_episodes() -> Episodes:
    return Episodes(EMPTY, EMPTY, EMPTY, EMPTY, EMPTY, EMPTY, EMPTY, EMPTY, [])


def given_back(calls: Calls, ep: Episodes, keep: np.ndarray) -> tuple[Calls, Episodes]:
    """The calls and episodes the vector path took, but those of the episodes given back to the loop (the
    episodes' call indices renumbered)."""
    if keep.all():
        return calls, ep
    back = np.zeros(len(calls.q), bool)
    for k in np.flatnonzero(~keep).tolist():
        back[int(ep.w[k])] = True
        back[ep.reads[ep.first_read[k]:ep.first_read[k] + ep.n_reads[k]]] = True
    index = np.cumsum(~back) - 1
    sub = _subset(ep, keep)
    return Calls(calls.q[~back], calls.s[~back], calls.pd[~back]), Episodes(
        index[sub.w], index[sub.reads], sub.first_read, sub.n_reads, sub.channel, sub.group, sub.start, sub.end,
        sub.channels)


def _subset(ep: Episodes, keep: np.ndarray) -> Episodes:
    if keep.all():
        return ep
    first = np.zeros(int(keep.sum()), np.int64)
    n = ep.n_reads[keep]
    np.cumsum(n[:-1], out=first[1:])
    reads = np.concatenate([ep.reads[a:a + b] for a, b in zip(ep.first_read[keep].tolist(), n.tolist(), strict=True)]) \
        if len(n) else EMPTY
    return Episodes(ep.w[keep], reads.astype(np.int64), first, n, ep.channel[keep], ep.group[keep], ep.start[keep],
                    ep.end[keep], ep.channels)


def loop_frames(view: object, loop_cols: np.ndarray, odd_rows: list[Pdu], ep: Episodes | None,
                 calls: Calls) -> dict[int, np.ndarray]:
    """The frames of the loop's rows by drive and controller (pair_key): the column rows not taken, the odd
    rows, and (with `ep`) the rows of PROFIdrive calls taken but in no episode."""
    p = view.p  # type: ignore[attr-defined]
    cols = loop_cols
    if ep is not None:
        in_ep = np.zeros(len(calls.q), bool)
        in_ep[ep.w] = True
        in_ep[ep.reads] = True
        out_ep = calls.pd & ~in_ep
        cols = np.concatenate([cols, calls.q[out_ep], calls.s[out_ep]])
    request = p.ptype[cols] == PTYPE_REQUEST
    keys = np.where(request, pair_key(p.dst[cols], p.src[cols]), pair_key(p.src[cols], p.dst[cols]))
    frames = view.frame_no[cols]  # type: ignore[attr-defined]
    if odd_rows:
        odd_keys = np.array([(r.dst << 32 | r.src) if r.ptype == PTYPE_REQUEST else (r.src << 32 | r.dst)
                             for r in odd_rows], np.uint64)
        keys = np.concatenate([keys, odd_keys])
        frames = np.concatenate([frames, np.array([r.frame for r in odd_rows], np.int64)])
    order = np.lexsort((frames, keys))
    keys, frames = keys[order], frames[order]
    out: dict[int, np.ndarray] = {}
    if len(keys):
        bounds = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
        for a, b in zip(bounds.tolist(), [*bounds[1:].tolist(), len(keys)], strict=True):
            out[int(keys[a])] = frames[a:b]
    return out


def cut_horizon(view: BatchView, rows: np.ndarray, odd_rows: list[Pdu]) -> int | None:
    """The frame of the part's first write request cut before its IOD header that has no answer later in the
    part (None: none). The transactions opened from it on wait for their numbers (engine.numbering); the
    vector path numbers its transactions in their part, so it takes none from there on. (A cut request that
    is answered in the part is the loop's, and so is its answer: its key is an odd row's.)"""
    cut = [row for row in odd_rows if row.cut and row.ptype == PTYPE_REQUEST]
    if not cut:
        return None
    p = view.p
    answers = rows[np.isin(p.ptype[rows], _ANSWERS)]
    last: dict[int, int] = {}  # key hash -> the last frame of an answer with that key
    hashes, frames = key_hash(p.act_hi[answers], p.act_lo[answers], p.seq[answers]), view.frame_no[answers]
    if len(hashes):
        order = np.lexsort((frames, hashes))
        ends = np.r_[hashes[order][1:] != hashes[order][:-1], True]
        last = dict(zip(hashes[order][ends].tolist(), frames[order][ends].tolist(), strict=True))
    odd = [row for row in odd_rows if row.ptype in _ANSWERS]
    for row, h in zip(odd, _hashes([row.key for row in odd]).tolist(), strict=True):
        last[h] = max(last.get(h, 0), row.frame)
    pending = [row.frame for row, h in zip(cut, _hashes([row.key for row in cut]).tolist(), strict=True)
               if last.get(h, 0) <= row.frame]
    return min(pending) if pending else None


def _hashes(keys: list[tuple[int, int, int]]) -> np.ndarray:
    return key_hash(np.array([k[0] for k in keys], np.uint64), np.array([k[1] for k in keys], np.uint64),
                    np.array([k[2] for k in keys], np.uint32))
