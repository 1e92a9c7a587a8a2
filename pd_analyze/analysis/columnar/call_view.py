"""The calls of a batch's ordinary groups as the state machine reads them, and the rules that compare a
response with its request (protocol.md 2.5-2.7, 6.4): N4, H6-H8 and Q7.

H6 (a response block that does not mirror its request's AR, slot, subslot, index or sequence number)
sends the group to the per-frame path: the response would not name the request's channel. N4, H7, H8
and Q7 flag the response, whose findings the per-frame checks then make.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from pd_analyze.analysis.columnar.batch_view import BatchView
from pd_analyze.analysis.columnar.calls import Calls
from pd_analyze.analysis.columnar.channels import FAULT, CallView
from pd_analyze.analysis.columnar.state import KIND_OTHER, KIND_READ, KIND_WRITE, ChannelKey, ColumnarState, Request
from pd_analyze.model import pd_values as pt
from pd_analyze.model.values import OP_WRITE, PTYPE_FAULT, PTYPE_REJECT
from pd_analyze.protocol.profidrive import Parsed

_ERROR_BLOCK = SimpleNamespace(is_error=True)
_VALUE_BLOCK = SimpleNamespace(is_error=False)


def request_of(view: BatchView, i: int) -> Request:
    """PDU i (a request of this batch) as a call carried to the next batch keeps it."""
    p = view.p
    ar = (int(p.ar_hi[i]), int(p.ar_lo[i]))
    target = (int(p.target_hi[i]), int(p.target_lo[i]))
    kind = int(view.kind[i])
    channel = None
    if kind != KIND_OTHER:
        hi, lo = target if ar == (0, 0) else ar
        channel = (int(p.dst[i]), int(p.src[i]), hi, lo, int(p.api[i]), int(p.slot[i]), int(p.subslot[i]),
                   int(p.index[i]))
    pos = int(p.pos[i])
    return Request(view.batch.raw_frame(pos), int(view.group[i]), int(p.src[i]), int(p.dst[i]),
                   int(p.opnum[i]), int(p.if_hi[i]), int(p.if_lo[i]), int(p.args_max[i]), bool(p.has_block[i]),
                   int(p.iod_seq[i]), ar, target, int(p.api[i]), int(p.slot[i]), int(p.subslot[i]),
                   int(p.index[i]), int(p.record_len[i]), channel, kind,
                   int(p.body_start[i]) - int(view.batch.start[pos]), int(p.body_len[i]))


def build(view: BatchView, calls: Calls, bad: set[int], state: ColumnarState) -> tuple[CallView, dict[int, object]]:
    """The CallView of `calls`; flags the responses N4, H7, H8 and Q7 may report on (view.flag) and adds
    to `bad` the groups of H6. Also: per read call answered with a record, the channel's last parameter
    request as of that call (a record index of this batch, or a carried (Parsed, frame)))."""
    p = view.p
    req, res = calls.req, calls.res
    if not len(view.group):  # no PDU in this batch: only calls carried over, none answered yet
        return _carried_only(calls), {}
    inb = req >= 0
    r = np.where(inb, req, 0)
    has = res >= 0
    s = np.where(has, res, 0)
    n = len(req)
    # the request side, from this batch's columns (carried calls are patched below)
    kind = np.where(inb, view.kind[r], KIND_OTHER).astype(np.int8)
    group = view.group[r].astype(np.uint64)
    ar_hi = np.where((p.ar_hi[r] == 0) & (p.ar_lo[r] == 0), p.target_hi[r], p.ar_hi[r])
    ar_lo = np.where((p.ar_hi[r] == 0) & (p.ar_lo[r] == 0), p.target_lo[r], p.ar_lo[r])
    carried = [k for k in range(n) if not inb[k]]
    kinds = kind.tolist()
    groups = group.tolist()
    for k in carried:
        q = calls.carried[k].request
        kinds[k], groups[k] = q.kind, q.group
    channels: list[ChannelKey | None] = [None] * n
    pd = np.flatnonzero(inb & (kind != KIND_OTHER))
    for k, ch in zip(pd.tolist(), zip(p.dst[r[pd]].tolist(), p.src[r[pd]].tolist(), ar_hi[pd].tolist(),
                                      ar_lo[pd].tolist(), p.api[r[pd]].tolist(), p.slot[r[pd]].tolist(),
                                      p.subslot[r[pd]].tolist(), p.index[r[pd]].tolist(), strict=True), strict=True):
        channels[k] = ch
    for k in carried:
        channels[k] = calls.carried[k].request.channel
    _paired_checks(view, calls, bad, groups)
    # the write's record and header
    record = np.where(inb & (kind == KIND_WRITE), view.rec_of[r], -1)
    rc = view.records.records
    w = np.flatnonzero(record >= 0)
    heads: list[tuple[int, int, int, int] | None] = [None] * n
    for k, head in zip(w.tolist(), zip(rc.ref[record[w]].tolist(), rc.ident[record[w]].tolist(),
                                       rc.do[record[w]].tolist(), rc.n[record[w]].tolist(), strict=True),
                       strict=True):
        heads[k] = head
    # the answer
    write = p.opnum[s] == OP_WRITE
    fault = (p.ptype[s] == PTYPE_FAULT) | (p.ptype[s] == PTYPE_REJECT)
    status = np.where(has, np.where(write & (p.status[s] == 0), p.block_status[s], p.status[s]), 0).astype(np.int64)
    status = np.where(has & fault, p.status[s].astype(np.int64) | FAULT, status)
    res_record = np.where(has & ~write, view.rec_of[s], -1)
    res_heads: list[SimpleNamespace | None] = [None] * n
    a = np.flatnonzero(res_record >= 0)
    a = a[view.records.records.regular[res_record[a]]]
    ra = res_record[a]
    first_error = np.zeros(len(a), bool)
    nb = rc.n_blocks[ra]
    first_error[nb > 0] = view.records.blocks.error[rc.first_block[ra][nb > 0]] >= 0
    for k, ref, ident, do, count, blocks, err in zip(a.tolist(), rc.ref[ra].tolist(), rc.ident[ra].tolist(),
                                                     rc.do[ra].tolist(), rc.n[ra].tolist(), nb.tolist(),
                                                     first_error.tolist(), strict=True):
        first = _ERROR_BLOCK if err else _VALUE_BLOCK
        res_heads[k] = SimpleNamespace(ref=ref, ident=ident, do=do, n=count, blocks=[first] * blocks)
    cv = CallView(calls.frame.tolist(), calls.ts.tolist(), groups, kinds, channels, record.tolist(), heads,
                  [c.txn if c is not None else None for c in calls.carried],
                  np.where(has, view.frame_no[s], -1).tolist(), np.where(has, view.ts[s], 0.0).tolist(),
                  status.astype(np.int64).tolist(), np.where(res_record >= 0, res_record, -1).tolist(), res_heads)
    requests = _q7(view, cv, calls, state)
    return cv, requests


def _carried_only(calls: Calls) -> CallView:
    n = len(calls.req)
    q = [c.request for c in calls.carried]
    return CallView(calls.frame.tolist(), calls.ts.tolist(), [r.group for r in q], [r.kind for r in q],
                    [r.channel for r in q], [-1] * n, [None] * n, [c.txn for c in calls.carried], [-1] * n,
                    [0.0] * n, [0] * n, [-1] * n, [None] * n)


def _paired_checks(view: BatchView, calls: Calls, bad: set[int], groups: list[int]) -> None:
    """N4, H6, H7, H8 over the answered calls."""
    p = view.p
    k = np.flatnonzero((calls.res >= 0) & (calls.req >= 0))
    q, s = calls.req[k], calls.res[k]
    block = p.has_block[s] & p.has_block[q]
    n4 = (p.max_count[s] != p.args_max[q]) | (p.args_len[s] > p.args_max[q])
    want_hi = np.where((p.target_hi[q] | p.target_lo[q]).astype(bool) & ((p.ar_hi[s] | p.ar_lo[s]) != 0),
                       p.target_hi[q], p.ar_hi[q])
    want_lo = np.where((p.target_hi[q] | p.target_lo[q]).astype(bool) & ((p.ar_hi[s] | p.ar_lo[s]) != 0),
                       p.target_lo[q], p.ar_lo[q])
    ar_ok = (((p.ar_hi[s] == want_hi) & (p.ar_lo[s] == want_lo))
             | ((p.ar_hi[s] == p.ar_hi[q]) & (p.ar_lo[s] == p.ar_lo[q])))
    h6 = block & ((p.iod_seq[s] != p.iod_seq[q]) | (p.api[s] != p.api[q]) | (p.slot[s] != p.slot[q])
                  | (p.subslot[s] != p.subslot[q]) | (p.index[s] != p.index[q]) | ~ar_ok)
    write = p.opnum[q] == OP_WRITE
    h7 = block & write & (p.record_len[s] != p.record_len[q])
    h8 = block & ~write & (p.record_len[s] > p.record_len[q])
    view.flag[s[n4 | h7 | h8]] = True
    for j in np.flatnonzero(h6):
        bad.add(groups[int(k[j])])
    for j in np.flatnonzero((calls.res >= 0) & (calls.req < 0)):
        _carried_checks(view, calls.carried[int(j)].request, int(calls.res[j]), bad)


def _carried_checks(view: BatchView, q: Request, s: int, bad: set[int]) -> None:
    """N4, H6, H7, H8 of the answer to a call carried over."""
    p = view.p
    if int(p.max_count[s]) != q.args_max or int(p.args_len[s]) > q.args_max:
        view.flag[s] = True
    if not (p.has_block[s] and q.has_block):
        return
    res_ar = (int(p.ar_hi[s]), int(p.ar_lo[s]))
    want = q.target if q.target != (0, 0) and res_ar != (0, 0) else q.ar
    if ((int(p.iod_seq[s]), int(p.api[s]), int(p.slot[s]), int(p.subslot[s]), int(p.index[s]))
            != (q.iod_seq, q.api, q.slot, q.subslot, q.index) or res_ar not in (want, q.ar)):
        bad.add(q.group)
    record_len = int(p.record_len[s])
    if (q.opnum == OP_WRITE and record_len != q.record_len) or (q.opnum != OP_WRITE and record_len > q.record_len):
        view.flag[s] = True


def _q7(view: BatchView, cv: CallView, calls: Calls, state: ColumnarState) -> dict[int, object]:
    """Q7 (n_values_read): a positive read response's No. of values against the channel's last parameter
    request's elements; flags the responses that differ. Returns, per read call answered with a record,
    that request (a record index of this batch, or the carried (Parsed, frame))."""
    last: dict[ChannelKey, object] = {}
    out: dict[int, object] = {}
    pairs_res: list[int] = []
    pairs_req: list[int] = []
    for k, kind in enumerate(cv.kind):
        if kind == KIND_WRITE and cv.record[k] >= 0:  # (a write carried over is state.last_request's already)
            last[cv.channel[k]] = cv.record[k]
        elif kind == KIND_READ and cv.res_record[k] >= 0:
            ch = cv.channel[k]
            source = last.get(ch)
            if source is None:
                source = state.last_request.get(ch)
            if source is None:
                continue
            out[k] = source
            res = cv.res_record[k]
            if isinstance(source, int):
                pairs_res.append(res)
                pairs_req.append(source)
            elif _q7_differs(view, res, source[0]):
                view.flag[int(calls.res[k])] = True
    if pairs_res:
        flagged = _q7_columns(view, np.array(pairs_res, np.int64), np.array(pairs_req, np.int64))
        res_pdu = view.rec_pdu[np.array(pairs_res, np.int64)[flagged]]
        view.flag[res_pdu] = True
    return out


def _q7_columns(view: BatchView, res: np.ndarray, req: np.ndarray) -> np.ndarray:
    """Per (response record, request record) pair: a value block's No. of values differs from its Value
    address's elements (the response a positive read response)."""
    rc, a, b = view.records.records, view.records.addresses, view.records.blocks
    read = rc.ident[res] == pt.RES_READ
    m = np.where(read, np.minimum(rc.n_blocks[res], rc.n_addr[req]), 0).astype(np.int64)
    owner = np.repeat(np.arange(len(res)), m)
    starts = np.zeros(len(m), np.int64)
    np.cumsum(m[:-1], out=starts[1:])
    pos = np.arange(int(m.sum())) - np.repeat(starts, m)
    bi = rc.first_block[res][owner] + pos
    ai = rc.first_addr[req][owner] + pos
    differs = (a.attr[ai] == pt.ATTR_VALUE) & (b.error[bi] < 0) & (b.n_values[bi] != np.maximum(a.n_elems[ai], 1))
    out = np.zeros(len(res), bool)
    out[owner[differs]] = True
    return out


def _q7_differs(view: BatchView, res: int, request: Parsed) -> bool:
    rc, b = view.records.records, view.records.blocks
    if int(rc.ident[res]) != pt.RES_READ:
        return False
    first = int(rc.first_block[res])
    for j, addr in enumerate(request.addresses[:int(rc.n_blocks[res])]):
        row = first + j
        if addr.attr == pt.ATTR_VALUE and b.error[row] < 0 and int(b.n_values[row]) != max(addr.n_elems, 1):
            return True
    return False
