"""Requests paired with their responses over a whole batch (protocol.md 2.4), as columns.

A call is its activity UUID and sequence number. In an ordinary group every call is one request, then
at most one response from the request's destination, with the same operation and interface, within
rpc_timeout. Anything else (a copy of a request, a response without its request, a second response, a
reused key, a late answer, a call left unanswered past rpc_timeout, addresses not swapped) marks the
group for the per-frame path, which reports it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pd_analyze.analysis.columnar.state import Answered, CallKey, OpenCall
from pd_analyze.protocol.pnio_batch import PduColumns

_MIX = np.uint64(0x9E3779B97F4A7C15)


def key_hash(hi: np.ndarray, lo: np.ndarray, seq: np.ndarray) -> np.ndarray:
    """One uint64 per call key (equal keys, equal hashes; a hit is checked against the key itself)."""
    with np.errstate(over="ignore"):
        return (hi * _MIX) ^ lo ^ (seq.astype(np.uint64) << np.uint64(17))


@dataclass(slots=True)
class Calls:
    """The calls of a batch's ordinary groups, by request frame: a request of this batch or one carried
    over (`carried`), its response of this batch (-1: none yet)."""

    req: np.ndarray  # int64 index into PduColumns, -1 when the request was carried over
    res: np.ndarray  # int64 index into PduColumns, -1 when unanswered so far
    carried: list[OpenCall | None]  # the carried-over call where req is -1
    frame: np.ndarray  # int64 request frame
    ts: np.ndarray  # float64 request time
    expired: np.ndarray  # bool: unanswered longer than rpc_timeout by `now` (rpc_unanswered; the call is dropped)


def pair(p: PduColumns, cand: np.ndarray, frame_no: np.ndarray, ts: np.ndarray, open_calls: dict[CallKey, OpenCall],
         answered: list[Answered], rpc_timeout: float, now: float, bad: set[int]) -> Calls:
    """Pair the candidate PDUs (`cand`, indices into `p`, in frame order) with each other and with the calls
    carried over; add to `bad` every group whose calls are not ordinary. `frame_no`/`ts` give each PDU's
    frame number and time (indexed like `p`); `now` is the per-frame dissector's clock at the end of the
    batch (its last frame read): a call unanswered that long expires as it would there."""
    open_calls = {key: call for key, call in open_calls.items() if call.request.group not in bad}
    group = _groups_of(p, cand)
    hi, lo, sq = p.act_hi[cand], p.act_lo[cand], p.seq[cand]
    is_req = p.ptype[cand] == 0
    order = np.lexsort((p.pos[cand], sq, lo, hi))
    h, l_, s = hi[order], lo[order], sq[order]
    new_key = np.ones(len(order), bool)
    new_key[1:] = (h[1:] != h[:-1]) | (l_[1:] != l_[:-1]) | (s[1:] != s[:-1])
    starts = np.flatnonzero(new_key)
    sizes = np.diff(np.append(starts, len(order)))
    first = order[starts]
    second = np.where(sizes >= 2, order[np.minimum(starts + 1, len(order) - 1)], -1)
    bad_key = (sizes > 2) | ((sizes == 2) & ~(is_req[first] & ~is_req[np.maximum(second, 0)]))
    # a request whose key is open (carried over) or answered lately: a copy or a reused key
    hashes = key_hash(h[starts], l_[starts], s[starts])
    known_hashes = [key_hash(np.fromiter((k[0] for k in open_calls), np.uint64, len(open_calls)),
                             np.fromiter((k[1] for k in open_calls), np.uint64, len(open_calls)),
                             np.fromiter((k[2] for k in open_calls), np.uint32, len(open_calls)))]
    t0 = float(ts[cand].min()) if len(cand) else now
    known_hashes += [key_hash(a.act_hi, a.act_lo, a.seq) for a in answered if a.last + rpc_timeout >= t0]
    known = np.concatenate(known_hashes) if known_hashes else np.empty(0, np.uint64)
    hit = np.isin(hashes, known) & is_req[first]
    bad_key |= hit  # (a hash collision only sends a group to the per-frame path: never wrong, rarely slower)
    # a response alone: the answer to a carried-over call, else an orphan or a duplicate
    lone_res = (sizes == 1) & ~is_req[first]
    carried: list[tuple[int, OpenCall]] = []
    for j in np.flatnonzero(lone_res):
        i = int(first[j])
        call = open_calls.get((int(hi[i]), int(lo[i]), int(sq[i])))
        if call is None:
            bad_key[j] = True
        else:
            carried.append((i, call))
    for j in np.flatnonzero(bad_key):
        bad.add(int(group[first[j]]))
        if second[j] >= 0:
            bad.add(int(group[second[j]]))
    ok = ~bad_key & ~lone_res
    req = first[ok]
    res = np.where(sizes[ok] == 2, second[ok], -1)
    req_i, res_i = cand[req], np.where(res >= 0, cand[np.maximum(res, 0)], -1)
    _check_answers(p, req_i, res_i, frame_no, ts, rpc_timeout, bad)
    # calls carried over: their answer in this batch, or still none
    c_res = np.array([cand[i] for i, _ in carried], np.int64)
    c_calls = [c for _, c in carried]
    answered_keys = {(int(p.act_hi[i]), int(p.act_lo[i]), int(p.seq[i])) for i in c_res}
    for key, call in open_calls.items():
        if key not in answered_keys:
            c_res = np.append(c_res, -1)
            c_calls.append(call)
    for k, call in enumerate(c_calls):
        i = int(c_res[k])
        if i >= 0 and (ts[i] - call.ts > rpc_timeout or not _answers(p, i, call)):
            bad.add(call.request.group)
            bad.add(int(_groups_of(p, np.array([i]))[0]))
    req_all = np.concatenate([req_i, np.full(len(c_calls), -1, np.int64)])
    res_all = np.concatenate([res_i, c_res]).astype(np.int64)
    frames = np.concatenate([frame_no[req_i], np.array([c.request.frame.number for c in c_calls], np.int64)])
    times = np.concatenate([ts[req_i], np.array([c.ts for c in c_calls], np.float64)])
    by_frame = np.argsort(frames, kind="stable")
    carried_all: list[OpenCall | None] = [None] * len(req_i) + c_calls
    expired = (res_all < 0) & (now - times > rpc_timeout)
    return Calls(req_all[by_frame], res_all[by_frame], [carried_all[k] for k in by_frame], frames[by_frame],
                 times[by_frame], expired[by_frame])


def _groups_of(p: PduColumns, idx: np.ndarray) -> np.ndarray:
    a, b = p.src[idx].astype(np.uint64), p.dst[idx].astype(np.uint64)
    return (np.minimum(a, b) << np.uint64(32)) | np.maximum(a, b)


def _check_answers(p: PduColumns, req: np.ndarray, res: np.ndarray, frame_no: np.ndarray, ts: np.ndarray,
                   rpc_timeout: float, bad: set[int]) -> None:
    """R4 and rpc_timeout on the calls paired in this batch: operation, interface, addresses, lateness
    (both the request's group and the response's go to the per-frame path)."""
    has = res >= 0
    r = np.maximum(res, 0)
    wrong = has & ((p.opnum[r] != p.opnum[req]) | (p.if_hi[r] != p.if_hi[req]) | (p.if_lo[r] != p.if_lo[req])
                   | (p.src[r] != p.dst[req]) | (p.dst[r] != p.src[req]) | (frame_no[r] < frame_no[req]))
    late = has & (ts[r] - ts[req] > rpc_timeout)
    odd = wrong | late
    bad.update(np.unique(_groups_of(p, req[odd])).tolist())
    bad.update(np.unique(_groups_of(p, r[odd & has])).tolist())


def _answers(p: PduColumns, i: int, call: OpenCall) -> bool:
    """Whether PDU i is an ordinary answer to a carried-over call."""
    q = call.request
    return (int(p.opnum[i]) == q.opnum and int(p.if_hi[i]) == q.if_hi and int(p.if_lo[i]) == q.if_lo
            and int(p.src[i]) == q.dst and int(p.dst[i]) == q.src)
