"""Closed transactions as columns: what the tables are made of, whether the machine followed them one by
one (`of_txns`) or the vector path took them whole (`of_episodes`)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np

from pd_analyze.analysis.engine.rules import LastDone, answered_with, failed_at
from pd_analyze.analysis.engine.txn import Txn
from pd_analyze.analysis.engine.vector import Calls, Episodes
from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.model.rules import Finding
from pd_analyze.model.values import PNIORW_STATE_CONFLICT

MISSING = -(1 << 62)  # an int64 time or number the capture does not have
# parameter rows whose tables are made at once: the transactions a batch closes are made and handed on in
# slices of about this many, so a batch of long requests (a flood of 39-parameter writes never answered:
# 1.5 million rows in one batch) costs the memory of a slice, not of the batch. An ordinary capture's batch is
# one slice; the floods of long requests pay about a quarter more time (README, Performance, run D), and
# 16,384 took the 40-parameter flood over 300 MiB
SLICE_ROWS = 8_192


@dataclass(slots=True)
class TxnCols:
    """One entry per closed transaction; times in nanoseconds (MISSING where there is none)."""

    channel: list[tuple]  # the channels (facts.Channel), by `ch`
    ch: np.ndarray  # int64 channel id
    ref: np.ndarray  # int64 (-1: not in the frame)
    req_id: np.ndarray
    do: np.ndarray
    n_params: np.ndarray
    req: np.ndarray  # int64 request record in the records the tables are made from
    res: np.ndarray  # int64 response record, -1 when none
    verdict: list[str]
    pnio_status: list[str]
    b5: np.ndarray
    reads: np.ndarray
    retrans: np.ndarray
    write_frame: np.ndarray
    write_res_frame: np.ndarray  # 0: none
    read_res_frame: np.ndarray  # 0: none
    read_frames: np.ndarray  # int64, transaction after transaction
    read_offsets: np.ndarray  # int64, len n + 1
    frames: np.ndarray  # int64, each transaction's frames sorted
    frame_offsets: np.ndarray
    t_start: np.ndarray
    t_write_res: np.ndarray
    t_first_read: np.ndarray
    t_last_read: np.ndarray
    t_done: np.ndarray  # the final answer's time when it closed the transaction (closed_by "response")
    capture_ended: np.ndarray  # bool
    closed_by: list[str]
    number: np.ndarray  # int64
    findings: dict[int, list[Finding]] = field(default_factory=dict)  # by entry, only those with findings
    # by entry, only changes with some value known: per address, its value_before cell (Txn.values_before)
    values_before: dict[int, list[str]] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.ch)

    def take(self, idx: np.ndarray) -> TxnCols:
        """The entries at `idx` (int64, ascending), in that order."""
        def nested(values: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            lengths = np.diff(offsets)[idx]
            out = np.zeros(len(idx) + 1, np.int64)
            np.cumsum(lengths, out=out[1:])
            at = np.repeat(offsets[:-1][idx] - out[:-1], lengths) + np.arange(out[-1])
            return values[at], out

        read_frames, read_offsets = nested(self.read_frames, self.read_offsets)
        frames, frame_offsets = nested(self.frames, self.frame_offsets)
        keep = idx.tolist()
        return TxnCols(
            self.channel, self.ch[idx], self.ref[idx], self.req_id[idx], self.do[idx], self.n_params[idx],
            self.req[idx], self.res[idx], [self.verdict[k] for k in keep], [self.pnio_status[k] for k in keep],
            self.b5[idx], self.reads[idx], self.retrans[idx], self.write_frame[idx], self.write_res_frame[idx],
            self.read_res_frame[idx], read_frames, read_offsets, frames, frame_offsets, self.t_start[idx],
            self.t_write_res[idx], self.t_first_read[idx], self.t_last_read[idx], self.t_done[idx],
            self.capture_ended[idx], [self.closed_by[k] for k in keep], self.number[idx],
            {i: self.findings[k] for i, k in enumerate(keep) if k in self.findings},
            {i: self.values_before[k] for i, k in enumerate(keep) if k in self.values_before})


def in_slices(txns: list[Txn], cols: TxnCols | None,
              rows: int | None = None) -> Iterator[tuple[list[Txn], TxnCols | None]]:
    """`txns` (the loop's, in number order) and `cols` (the vector path's) cut by transaction number into
    slices of about `rows` (SLICE_ROWS) parameter rows (a transaction is never cut), in number order."""
    rows = SLICE_ROWS if rows is None else rows
    numbers = np.fromiter((t.number for t in txns), np.int64, len(txns))
    weights = np.fromiter((t.n_params for t in txns), np.int64, len(txns))
    if cols is not None:
        numbers, weights = np.concatenate([numbers, cols.number]), np.concatenate([weights, cols.n_params])
    weights = np.maximum(weights, 1)  # (a cut request has none in the frame: still a row)
    if int(weights.sum()) <= rows:
        yield txns, cols
        return
    order = np.argsort(numbers, kind="stable")
    before = np.cumsum(weights[order]) - weights[order]
    cut = np.flatnonzero(np.diff(before // rows)) + 1
    bounds = numbers[order][np.concatenate([[0], cut])].tolist() + [int(numbers.max()) + 1]
    mine = numbers[:len(txns)]
    for lo, hi in pairwise(bounds):
        a, b = np.searchsorted(mine, [lo, hi]).tolist()
        part = None
        if cols is not None:
            idx = np.flatnonzero((cols.number >= lo) & (cols.number < hi))
            part = cols.take(idx) if len(idx) else None
        yield txns[a:b], part


def _flat(lists: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    lengths = np.fromiter((len(x) for x in lists), np.int64, len(lists))
    offsets = np.zeros(len(lists) + 1, np.int64)
    np.cumsum(lengths, out=offsets[1:])
    flat = np.fromiter((v for x in lists for v in x), np.int64, int(offsets[-1]))
    return flat, offsets


def _ints(values: list[int]) -> np.ndarray:
    return np.array(values, np.int64)


def _opt(values: list[int | None]) -> np.ndarray:
    return np.fromiter((MISSING if v is None else v for v in values), np.int64, len(values))


def of_txns(txns: list[Txn], req: list[int]) -> TxnCols:
    """Transactions the machine followed (their request records `req` in the tables' records)."""
    channels: dict[tuple, int] = {}
    ch = np.fromiter((channels.setdefault(t.channel, len(channels)) for t in txns), np.int64, len(txns))
    read_frames, read_offsets = _flat([t.read_frames for t in txns])
    frames, frame_offsets = _flat([sorted(t.frames) for t in txns])
    out = TxnCols(
        list(channels), ch,
        _ints([t.ref for t in txns]), _ints([t.req_id for t in txns]), _ints([t.do for t in txns]),
        _ints([t.n_params for t in txns]),
        np.array(req, np.int64),
        np.fromiter((t.response if isinstance(t.response, int) else -1 for t in txns), np.int64, len(txns)),
        [t.verdict for t in txns], [t.pnio_status for t in txns],
        np.fromiter((t.b5 for t in txns), np.int64, len(txns)),
        np.fromiter((len(t.read_frames) for t in txns), np.int64, len(txns)),
        np.fromiter((t.retransmissions for t in txns), np.int64, len(txns)),
        np.fromiter((t.write_frame for t in txns), np.int64, len(txns)),
        np.fromiter((t.write_res_frame for t in txns), np.int64, len(txns)),
        np.fromiter((t.read_res_frame for t in txns), np.int64, len(txns)),
        read_frames, read_offsets, frames, frame_offsets,
        np.fromiter((t.t_start for t in txns), np.int64, len(txns)), _opt([t.t_write_res for t in txns]),
        _opt([t.t_reads[0] if t.t_reads else None for t in txns]),
        _opt([t.t_reads[-1] if t.t_reads else None for t in txns]),
        _opt([t.t_read_res if t.closed_by == "response" else None for t in txns]),
        np.fromiter((t.capture_ended for t in txns), bool, len(txns)), [t.closed_by for t in txns],
        np.fromiter((t.number for t in txns), np.int64, len(txns)))
    for k, t in enumerate(txns):
        if t.findings:
            out.findings[k] = t.findings
        if t.values_before:
            out.values_before[k] = t.values_before
    return out


_B5_TEXT = f"DE80{PNIORW_STATE_CONFLICT:02X}00"


def of_episodes(view: BatchView, calls: Calls, ep: Episodes) -> TxnCols:
    """Transactions the vector path took whole: a write, its reads, the answer that closed it."""
    p, ns = view.p, view.batch.ns
    n = len(ep.w)
    wq, ws = calls.q[ep.w], calls.s[ep.w]
    rq, rs = calls.q[ep.reads], calls.s[ep.reads]
    rc = view.records.records
    w_rec = view.rec_of[wq]
    last_read = np.where(ep.n_reads > 0, ep.first_read + ep.n_reads - 1, -1)
    has_read = ep.n_reads > 0
    lq = np.where(has_read, rq[np.maximum(last_read, 0)] if len(rq) else 0, wq)
    ls = np.where(has_read, rs[np.maximum(last_read, 0)] if len(rs) else 0, ws)
    # the closing answer's status; a write answered OK and a read with its parameter response close "response"
    w_status = np.where(p.status[ws] == 0, p.block_status[ws], p.status[ws]).astype(np.int64)
    l_status = np.where(has_read, p.status[ls].astype(np.int64), w_status)
    failed = l_status != 0
    res = np.where(has_read & ~failed, view.rec_of[ls], -1)
    ident = np.where(res >= 0, rc.ident[np.maximum(res, 0)], 0)
    verdict = np.where(failed, "pnio_error", np.where(ident & 0x80, "nak", "ok"))
    pnio_status = [f"{s & 0xFFFFFFFF:08X}" if f else "" for s, f in zip(l_status.tolist(), failed.tolist(),
                                                                         strict=True)]
    b5 = np.maximum(ep.n_reads - 1, 0)  # every read but the one whose answer closed it was answered B5
    frame = view.frame_no
    t = ns[p.pos]
    read_frames = frame[rq]
    read_offsets = np.zeros(n + 1, np.int64)
    np.cumsum(ep.n_reads, out=read_offsets[1:])
    # frames: write request and answer, then each read's request and answer (already in order)
    per = 2 + 2 * ep.n_reads
    frame_offsets = np.zeros(n + 1, np.int64)
    np.cumsum(per, out=frame_offsets[1:])
    frames = np.empty(int(frame_offsets[-1]), np.int64)
    frames[frame_offsets[:-1]] = frame[wq]
    frames[frame_offsets[:-1] + 1] = frame[ws]
    owner = np.repeat(np.arange(n), ep.n_reads)
    k = np.arange(len(rq)) - read_offsets[owner]
    frames[frame_offsets[owner] + 2 + 2 * k] = frame[rq]
    frames[frame_offsets[owner] + 3 + 2 * k] = frame[rs]
    first_read = np.full(n, MISSING, np.int64)
    if len(rq):
        first_read[has_read] = t[rq[read_offsets[:-1][has_read]]]
    last_read_t = np.where(has_read, t[lq], MISSING)
    done = np.where(has_read & ~failed, t[ls], MISSING)
    chosen = ["response"] * n
    findings: dict[int, list[Finding]] = {}
    closing = np.where(has_read, frame[ls], frame[ws])
    for i in np.flatnonzero(failed).tolist():
        chosen[i] = "pnio_error"  # T8 at the answer that refused it, as the machine's (rules.failed_finding)
        service = "read" if has_read[i] else "write"
        findings[i] = [failed_at("pnio_error", int(closing[i]), int(frame[wq[i]]),
                                 answered_with(pnio_status[i], service))]
    head = (rc.ref[w_rec].astype(np.int64), rc.ident[w_rec].astype(np.int64), rc.do[w_rec].astype(np.int64),
            rc.n[w_rec].astype(np.int64))
    return TxnCols(
        ep.channels, ep.channel, *head, w_rec.astype(np.int64), res.astype(np.int64), verdict.tolist(), pnio_status,
        b5.astype(np.int64), ep.n_reads.astype(np.int64), np.zeros(n, np.int64), frame[wq], frame[ws],
        np.where(has_read, frame[ls], 0), read_frames, read_offsets, frames, frame_offsets, t[wq], t[ws],
        first_read, last_read_t, done, np.zeros(n, bool), chosen, np.zeros(n, np.int64), findings)


def last_done_of(cols: TxnCols, k: int) -> LastDone:
    return LastDone(int(cols.write_frame[k]), int(cols.ref[k]), cols.verdict[k])
