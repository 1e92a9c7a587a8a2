"""What the columnar path carries from one batch to the next, for the groups it keeps: calls still
open (with a copy of their request frame), calls answered lately (their keys and request bodies),
pending transactions (their parameter request parsed: the batch's buffer goes), each channel's last
transaction and last parameter request."""

from __future__ import annotations

import numpy as np

from pd_analyze.analysis.columnar.batch_view import BatchView
from pd_analyze.analysis.columnar.call_view import request_of
from pd_analyze.analysis.columnar.calls import Calls
from pd_analyze.analysis.columnar.channels import CallView, ChannelMachine, Outcome
from pd_analyze.analysis.columnar.handover import group_of
from pd_analyze.analysis.columnar.state import KIND_WRITE, Answered, ColumnarState, OpenCall
from pd_analyze.model.capped import ANSWERED_CALLS, CHANNEL_HISTORY, CHANNEL_REQUESTS, OPEN_CALLS, PENDING_TRANSACTIONS


def carry_over(view: BatchView, cv: CallView, calls: Calls, out: Outcome, machine: ChannelMachine, bad: set[int],
               state: ColumnarState, rpc_timeout: float) -> None:
    p = view.p
    good = [g not in bad for g in cv.group]
    # open calls: the carried ones answered now are done; new unanswered ones are kept
    for k, carried in enumerate(calls.carried):
        if carried is None or not good[k]:
            continue
        if cv.res_frame[k] >= 0 or calls.expired[k]:
            state.open_calls.pop(carried.key, None)
        elif carried.txn is not None:
            carried.txn = machine.copies.get(id(carried.txn), carried.txn)
    for k in np.flatnonzero((calls.req >= 0) & (calls.res < 0) & ~calls.expired).tolist():
        if not good[k]:
            continue
        i = int(calls.req[k])
        key = (int(p.act_hi[i]), int(p.act_lo[i]), int(p.seq[i]))
        state.open_calls[key] = OpenCall(request_of(view, i), float(view.ts[i]), out.unanswered.get(k), key)
    _answered_log(view, calls, good, state, rpc_timeout)
    # pending transactions (their request parsed), the channels' last transactions and requests
    state.pending = {ch: t for ch, t in out.pending.items() if t.group not in bad}
    for t in state.pending.values():
        if isinstance(t.request, int):
            t.request = view.parsed_record(t.request)
    state.last_done.update((ch, last) for ch, last in out.done.items() if group_of(ch) not in bad)
    last: dict = {}
    for k in range(len(cv.kind)):
        if cv.kind[k] == KIND_WRITE and good[k] and cv.record[k] >= 0:
            last[cv.channel[k]] = k
    for ch, k in last.items():
        state.last_request[ch] = (view.parsed_record(cv.record[k]), cv.frame[k])


def _answered_log(view: BatchView, calls: Calls, good: list[bool], state: ColumnarState, rpc_timeout: float) -> None:
    """The calls answered in this batch, as a log kept rpc_timeout after its last answer, all logs
    together no longer than the dissector's ANSWERED_CALLS cap."""
    p = view.p
    k = np.flatnonzero((calls.res >= 0) & np.array(good, bool)) if len(good) else np.empty(0, np.int64)
    if len(k):
        req, res = calls.req[k], calls.res[k]
        inb = req >= 0
        r = np.where(inb, req, 0)
        act_hi, act_lo, seq = p.act_hi[r].copy(), p.act_lo[r].copy(), p.seq[r].copy()
        group = view.group[r].copy()
        starts, lengths = p.body_start[r].astype(np.int64), p.body_len[r].astype(np.int64)
        bufs = [view.batch.buf]  # kept, not copied: the logs hold a few batches' buffers at most
        buf_of = np.zeros(len(k), np.int32)
        for j in np.flatnonzero(~inb).tolist():
            carried = calls.carried[int(k[j])]
            q = carried.request
            act_hi[j], act_lo[j], seq[j] = carried.key
            group[j] = q.group
            buf_of[j], starts[j], lengths[j] = len(bufs), q.body_at, q.body_len
            bufs.append(q.frame.data)
        answered = view.ts[res]
        state.answered.append(Answered(act_hi, act_lo, seq, group, calls.frame[k], calls.ts[k], answered, buf_of,
                                       starts, lengths, bufs, float(answered.max())))
    now = view.last_ts
    logs = [log for log in state.answered if log.last + rpc_timeout >= now]
    while len(logs) > 1 and sum(len(log.seq) for log in logs[1:]) >= ANSWERED_CALLS.count:
        logs.pop(0)
    state.answered = logs


def calls_overflow(view: BatchView, calls: Calls, bad: set[int], state: ColumnarState) -> bool:
    """Carrying this batch's open calls would take the columnar memory past half the per-frame path's
    cap (a flood of calls never answered): the batch then goes to the per-frame path, whose caps and
    evictions are the reference's. Asked before the channel machine, which would hold a transaction
    per call."""
    p = view.p
    new = np.flatnonzero((calls.req >= 0) & (calls.res < 0) & ~calls.expired)
    new = new[~view.good(bad)[calls.req[new]]] if bad else new
    if len(new) + len(state.open_calls) > OPEN_CALLS.count // 2:
        return True
    held = int(view.batch.caplen[p.pos[calls.req[new]]].sum()) + sum(
        len(c.request.frame.data) for c in state.open_calls.values())
    return held > OPEN_CALLS.bytes // 4


def pending_overflow(out: Outcome, bad: set[int]) -> bool:
    """Carrying the pending transactions would pass half the per-frame path's cap (channels never closed)."""
    return sum(1 for t in out.pending.values() if t.group not in bad) > PENDING_TRANSACTIONS.count // 2


def near_caps(state: ColumnarState) -> bool:
    """The columnar memory has grown to half a cap of the per-frame path: from here on everything goes
    there, whose caps and evictions are the reference's."""
    return (len(state.open_calls) > OPEN_CALLS.count // 2
            or len(state.pending) > PENDING_TRANSACTIONS.count // 2
            or len(state.last_request) > CHANNEL_REQUESTS.count // 2
            or len(state.last_done) > CHANNEL_HISTORY.count // 2)
