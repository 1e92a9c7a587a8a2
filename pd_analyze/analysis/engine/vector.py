"""The ordinary sequences of a batch, found and followed as vector expressions over its columns.

Most calls are a request and its response in the same batch, and most transactions an ordinary sequence
on one channel: a write, its answer, reads answered B5, the final read's answer (protocol.md 7.1). Those
are taken here, whole, without a Python object per frame; every other row goes through the compact loop
(`calls.Pairing`, `machine.Machine`), which stays the one implementation of protocol.md 2.4 and 7. The
choice never changes a result: a call is taken only when no other row of the batch or the carried state
shares its key or activity; a transaction only when its channel's calls are consecutive and answered in
turn, its deadline is not reached, no loop row of its group (device, controller, AR, index) falls within
its span (a read there could be paired to it by the fallback, 7.2), no other channel of the group is busy
at the same time, and (checked by the loop at its first frame, `Episode` markers) no transaction of the
loop is pending on its channel.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from pd_analyze.analysis.engine.checks import paired_flags
from pd_analyze.analysis.engine.view import KIND_READ, KIND_WRITE, BatchView
from pd_analyze.model.capped import TXN_FRAMES
from pd_analyze.model.values import PNIORW_STATE_CONFLICT, PTYPE_REQUEST, PTYPE_RESPONSE

_MIX = np.uint64(0x9E3779B97F4A7C15)
_B5 = 0x80 << 16 | PNIORW_STATE_CONFLICT << 8  # ErrorDecode PNIORW, ErrorCode1 state conflict (packed status)


def act_hash(hi: np.ndarray, lo: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        return (hi.astype(np.uint64) * _MIX) ^ lo.astype(np.uint64)


def key_hash(hi: np.ndarray, lo: np.ndarray, seq: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        return act_hash(hi, lo) ^ (seq.astype(np.uint64) << np.uint64(17)) ^ (seq.astype(np.uint64) * _MIX)


class KnownKeys(Protocol):
    """Keys carried over (engine.take.Known: the pairing's open calls and calls answered lately)."""

    def __bool__(self) -> bool: ...

    def unknown(self, keys: list[tuple[int, int, int]]) -> np.ndarray: ...


def pair_ids(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows (a[i], b[i]) numbered by their distinct values in lexicographic order: (id per row, the first row
    of each id), what np.unique(np.stack([a, b], 1), axis=0, return_index=True, return_inverse=True) gives,
    at a fraction of its cost (it sorts the rows as records)."""
    order = np.lexsort((b, a))  # (stable: a group's first row is its earliest)
    sa, sb = a[order], b[order]
    new = np.ones(len(a), bool)
    new[1:] = (sa[1:] != sa[:-1]) | (sb[1:] != sb[:-1])
    ids = np.empty(len(a), np.int64)
    ids[order] = np.cumsum(new) - 1
    return ids, order[new]


@dataclass(slots=True)
class Calls:
    """The calls taken whole: request and response rows (indices into the view's PDUs)."""

    q: np.ndarray  # int64 request PDU
    s: np.ndarray  # int64 response PDU
    pd: np.ndarray  # bool: a write or read on a PROFIdrive index (its transaction is the machine's or an episode's)


@dataclass(slots=True)
class Episodes:
    """Transactions taken whole: per episode its write call, its read calls (offsets into `reads`)."""

    w: np.ndarray  # int64 index into Calls
    reads: np.ndarray  # int64 indices into Calls, episode after episode, in order
    first_read: np.ndarray  # int64 offset into `reads`
    n_reads: np.ndarray  # int64
    channel: np.ndarray  # int64 channel id (into `channels`)
    group: np.ndarray  # int64 group id
    start: np.ndarray  # int64 write request frame
    end: np.ndarray  # int64 frame of the answer that closes it
    channels: list[tuple]  # channel id -> the channel (protocol.md 7.2, as facts.Channel)


def pair(view: BatchView, rows: np.ndarray, runmax_all: np.ndarray, timeout: int, excluded: np.ndarray,
         known: KnownKeys) -> Calls:
    """The calls among the column `rows` (indices into view.p, frame order) taken whole: a request and its
    response, both in `rows` and nothing else with their key; the response from the request's destination
    with its operation and interface, before rpc_timeout passed (`runmax_all`: the capture time reached at
    each PDU); the key not `known` (carried over: open or answered lately); `excluded` rows (a key or
    activity the loop has rows of) left out."""
    p = view.p
    ptype = p.ptype[rows]
    cand = rows[((ptype == PTYPE_REQUEST) | (ptype == PTYPE_RESPONSE)) & ~excluded]
    empty = np.empty(0, np.int64)
    if not len(cand):
        return Calls(empty, empty, np.empty(0, bool))
    hi, lo, seq = p.act_hi[cand], p.act_lo[cand], p.seq[cand]
    order = np.lexsort((cand, seq, lo, hi))
    c = cand[order]
    h, lw, sq = hi[order], lo[order], seq[order]
    new = np.ones(len(c), bool)
    new[1:] = (h[1:] != h[:-1]) | (lw[1:] != lw[:-1]) | (sq[1:] != sq[:-1])
    starts = np.flatnonzero(new)
    sizes = np.diff(np.append(starts, len(c)))
    two = starts[sizes == 2]
    q, s = c[two], c[two + 1]
    ok = (p.ptype[q] == PTYPE_REQUEST) & (p.ptype[s] == PTYPE_RESPONSE)
    ok &= (p.src[s] == p.dst[q]) & (p.dst[s] == p.src[q]) & (p.opnum[s] == p.opnum[q])
    ok &= (p.if_hi[s] == p.if_hi[q]) & (p.if_lo[s] == p.if_lo[q])
    ts = view.batch.ns[p.pos[q]]
    ok &= runmax_all[s] - ts <= timeout  # (runmax_all is indexed by PDU)
    q, s = q[ok], s[ok]
    plain = ~paired_flags(view, q, s)  # N4, H6-H8 may report: the loop's, with the reference's checks
    q, s = q[plain], s[plain]
    if known and len(q):
        fresh = known.unknown(list(zip(p.act_hi[q].tolist(), p.act_lo[q].tolist(), p.seq[q].tolist(), strict=True)))
        q, s = q[fresh], s[fresh]
    by_frame = np.argsort(q, kind="stable")
    q, s = q[by_frame], s[by_frame]
    kind = view.kind[q]
    return Calls(q, s, (kind == KIND_WRITE) | (kind == KIND_READ))


def channel_ids(view: BatchView, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[tuple]]:
    """Per request PDU its channel and group (ids), and the channels (tuples) by id."""
    p = view.p
    nil = (p.ar_hi[q] == 0) & (p.ar_lo[q] == 0)
    ar_hi = np.where(nil, p.target_hi[q], p.ar_hi[q])
    ar_lo = np.where(nil, p.target_lo[q], p.ar_lo[q])
    cols = np.stack([p.dst[q].astype(np.uint64), p.src[q].astype(np.uint64), ar_hi.astype(np.uint64),
                     ar_lo.astype(np.uint64), p.api[q].astype(np.uint64), p.slot[q].astype(np.uint64),
                     p.subslot[q].astype(np.uint64), p.index[q].astype(np.uint64)], axis=1)
    if not len(q):
        return np.empty(0, np.int64), np.empty(0, np.int64), []
    channel, first = _ids(cols)
    group, _ = _ids(cols[:, [0, 1, 2, 3, 7]])
    channels = [tuple(int(x) for x in u) for u in cols[first].tolist()]
    return channel, group, channels


def _ids(cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of uint64 columns numbered by their distinct values: (id per row, first row of each id). A hash
    of the row sorts them (rows equal in every column, checked, make one id; a hash shared by rows that
    differ, never seen in practice, falls back to comparing the rows themselves)."""
    h = np.zeros(len(cols), np.uint64)
    with np.errstate(over="ignore"):
        for j in range(cols.shape[1]):
            h = (h ^ cols[:, j]) * _MIX + np.uint64(j + 1)
    uniq, first, ids = np.unique(h, return_index=True, return_inverse=True)
    if not np.array_equal(cols, cols[first][ids.ravel()]):  # a collision: the rows themselves
        _u, first, ids = np.unique(cols, axis=0, return_index=True, return_inverse=True)
    del uniq
    return ids.astype(np.int64).ravel(), first


def episodes(view: BatchView, calls: Calls, loop_events: dict[int, np.ndarray], runmax_pnio: np.ndarray,
             txn_timeout: int, b5_threshold: int) -> Episodes:
    """The ordinary transactions among the calls (see the module docstring). `loop_events`: per address pair
    (pair_key of device and controller) the sorted frames of the loop's rows between them; `runmax_pnio`:
    the capture time reached at each PDU over the PNIO frames."""
    p, batch = view.p, view.batch
    pd = np.flatnonzero(calls.pd)
    empty = np.empty(0, np.int64)
    none = Episodes(empty, empty, empty, empty, empty, empty, empty, empty, [])
    if not len(pd):
        return none
    q, s = calls.q[pd], calls.s[pd]
    channel, group, channels = channel_ids(view, q)
    write = view.kind[q] == KIND_WRITE
    qf, sf = view.frame_no[q], view.frame_no[s]
    # each call's answer: a write's status (its block's when the NDR one is OK), a read's
    status = np.where(write & (p.status[s] == 0), p.block_status[s], p.status[s]).astype(np.int64)
    b5 = ~write & (status != 0) & ((status & 0xFFFF00) == _B5)
    rec = view.rec_of[s]
    final_ok = ~write & (status == 0) & (rec >= 0)  # a read answered with a parameter response
    closes = (write & (status != 0)) | (~write & ~b5)  # the answer that closes the transaction
    # the channel's calls in request order
    order = np.lexsort((qf, channel))
    n = len(order)
    ch = channel[order]
    same_next = np.zeros(n, bool)
    same_next[:-1] = ch[1:] == ch[:-1]
    next_q = np.where(same_next, np.r_[qf[order][1:], 0], np.iinfo(np.int64).max)
    in_turn = sf[order] < next_q  # answered before the channel's next request
    wr, cl = write[order], closes[order]
    start_pos = np.flatnonzero(wr)
    if not len(start_pos):
        return none
    # the first closing call at or after each write, and the next write (or change of channel) after it
    cl_pos = np.flatnonzero(cl)
    if not len(cl_pos):
        return none
    at = np.searchsorted(cl_pos, start_pos)
    close_at = np.where(at < len(cl_pos), cl_pos[np.minimum(at, len(cl_pos) - 1)], n)
    boundary = np.flatnonzero(wr | np.r_[True, ch[1:] != ch[:-1]])  # where a channel or a write starts
    after = np.searchsorted(boundary, start_pos, "right")
    limit = np.where(after < len(boundary), boundary[np.minimum(after, len(boundary) - 1)], n)
    valid = close_at < limit  # closed before the next write or channel
    count = np.where(valid, close_at - start_pos + 1, 0)
    # every call from the write to the close answered in turn; the reads between answered B5
    total = int(count.sum())
    offsets = np.cumsum(count) - count
    idx = np.repeat(start_pos, count) + (np.arange(total) - np.repeat(offsets, count))
    ep = np.repeat(np.arange(len(start_pos)), count)
    middle = (idx != np.repeat(start_pos, count)) & (idx != np.repeat(close_at, count))
    good = in_turn[idx] & (~middle | b5[order][idx])
    bad = np.zeros(len(start_pos), bool)
    np.logical_or.at(bad, ep, ~good)
    valid &= ~bad
    last = order[np.minimum(close_at, n - 1)]
    w = order[start_pos]
    # the close: a refused write (alone), a refused read, or a read with its parameter response
    valid &= np.where(count == 1, write[last] & (status[last] != 0), ~write[last] & (final_ok[last] | ~b5[last]))
    valid &= (count == 1) | (status[w] == 0)
    valid &= ~(~write[last] & (status[last] == 0) & (rec[last] < 0))  # answered without a record: the loop's
    # deadline, B5 threshold, the frame cap
    t_start = batch.ns[p.pos[q[w]]]
    valid &= runmax_pnio[s[last]] <= t_start + txn_timeout
    valid &= (np.maximum(count - 2, 0) <= b5_threshold) & (2 * count <= TXN_FRAMES)
    # a parameter response that mirrors its request (Q2-Q5 differences are the loop's)
    rc = view.records.records
    w_rec = np.maximum(view.rec_of[q[w]], 0)
    l_rec = np.where(final_ok[last], rec[last], 0)
    ident_w, ident_l = rc.ident[w_rec], rc.ident[l_rec]
    mirrored = (rc.ref[l_rec] == rc.ref[w_rec]) & (rc.do[l_rec] == rc.do[w_rec]) & (rc.n[l_rec] == rc.n[w_rec])
    answers = (((ident_w == 1) & ((ident_l == 1) | (ident_l == 0x81)))
               | ((ident_w == 2) & ((ident_l == 2) | (ident_l == 0x82))))
    valid &= (view.rec_of[q[w]] >= 0) & (~final_ok[last] | (mirrored & answers))
    span_lo, span_hi = qf[w], sf[last]
    # no loop row between the drive and the controller within the span
    pairs = pair_key(p.dst[q[w]], p.src[q[w]])
    for key, frames in loop_events.items():
        mine = np.flatnonzero(valid & (pairs == key))
        if len(mine):
            lo_i = np.searchsorted(frames, span_lo[mine], "left")
            hi_i = np.searchsorted(frames, span_hi[mine], "right")
            valid[mine[hi_i > lo_i]] = False
    keep = np.flatnonzero(valid)
    counts = count[keep]
    n_reads = counts - 1
    first_read = np.cumsum(n_reads) - n_reads
    reads = np.repeat(start_pos[keep] + 1, n_reads) + (np.arange(int(n_reads.sum())) - np.repeat(first_read, n_reads))
    return Episodes(pd[w[keep]], pd[order[reads]], first_read, n_reads, channel[w[keep]], group[w[keep]],
                    span_lo[keep], span_hi[keep], channels)


def pair_key(device: np.ndarray, controller: np.ndarray) -> np.ndarray:
    """A drive and its controller (IPv4 as integers) as one key."""
    return device.astype(np.uint64) << np.uint64(32) | controller.astype(np.uint64)
