"""A group handed from the columnar path to the per-frame one: what the columns had learnt of it becomes
the per-frame dissector's and engine's state, as if they had seen the group's frames themselves.

Open calls are opened by the dissector from their request frames; calls answered lately, pending
transactions, each channel's last transaction and last parameter request are made from what the
columns kept. The tables whose order decides expiry (open calls, answered calls, pending transactions)
are put back in time order afterwards, as they would be had the frames come in order.
"""

from __future__ import annotations

import numpy as np

from pd_analyze.analysis.columnar.state import Answered, ChannelKey, ColumnarState, Txn
from pd_analyze.analysis.transaction import Transaction
from pd_analyze.analysis.transactions import TransactionEngine
from pd_analyze.protocol import rpc_calls
from pd_analyze.protocol.dissector import Dissector
from pd_analyze.protocol.profidrive import Parsed


def uuid_bytes(hi: int, lo: int) -> bytes:
    return hi.to_bytes(8, "big") + lo.to_bytes(8, "big")


def channel_bytes(ch: ChannelKey) -> tuple:
    """A columnar channel key as the per-frame engine writes it."""
    device, controller, ar_hi, ar_lo, api, slot, subslot, index = ch
    return (device.to_bytes(4, "big"), controller.to_bytes(4, "big"), uuid_bytes(ar_hi, ar_lo), api, slot, subslot,
            index)


def group_of(ch: ChannelKey) -> int:
    """The IP address pair of a channel, as the columns key groups."""
    a, b = ch[0], ch[1]
    return min(a, b) << 32 | max(a, b)


def hand_over(groups: set[int], state: ColumnarState, d: Dissector, engine: TransactionEngine, now: float,
              rpc_timeout: float) -> None:
    """Move the columnar state of `groups` to the per-frame dissector `d` and `engine`; `now` is the
    capture time reached (calls answered longer than rpc_timeout before it are forgotten)."""
    if not groups:
        return
    calls: dict[int, rpc_calls.Call] = {}  # request frame -> its call, for the transactions' rpc_calls
    for key, open_call in [(k, c) for k, c in state.open_calls.items() if c.request.group in groups]:
        del state.open_calls[key]
        call = d.adopt_request(open_call.request.frame)
        if call is not None:
            calls[call.frame] = call
    for log in state.answered:
        calls.update(_answered(d, log, groups, now, rpc_timeout))
    for ch, txn in [(c, t) for c, t in state.pending.items() if t.group in groups]:
        del state.pending[ch]
        _pending(engine, txn, channel_bytes(ch), calls)
    for ch in [c for c in state.last_done if group_of(c) in groups]:
        engine.adopt_last(channel_bytes(ch), state.last_done.pop(ch))
    for ch in [c for c in state.last_request if group_of(c) in groups]:
        parsed, frame = state.last_request.pop(ch)
        d.adopt_channel_request(channel_bytes(ch), parsed, frame)
    d.reorder()
    engine.reorder()


def _answered(d: Dissector, log: Answered, groups: set[int], now: float,
              rpc_timeout: float) -> dict[int, rpc_calls.Call]:
    """The calls of `groups` answered lately, as the dissector remembers them (by the digest of their body)."""
    out: dict[int, rpc_calls.Call] = {}
    if log.keys_only:
        return out
    keep = np.isin(log.group, np.fromiter(groups, np.uint64, len(groups))) & (log.answered + rpc_timeout >= now)
    for i in np.flatnonzero(keep):
        start = int(log.body_start[i])
        body = log.bufs[int(log.buf_of[i])][start:start + int(log.body_len[i])]
        call = rpc_calls.Call(int(log.frame[i]), float(log.req_ts[i]), b"", b"", b"", 0, body)
        call.answered = float(log.answered[i])
        d.adopt_answered((uuid_bytes(int(log.act_hi[i]), int(log.act_lo[i])), int(log.seq[i])), call)
        out[call.frame] = call
    return out


def hand_back(state: ColumnarState, d: Dissector, engine: TransactionEngine, now: float, rpc_timeout: float) -> None:
    """The groups of the per-frame path with nothing open there (no call, fragment set, IP datagram or
    transaction) come back to the columns: what the columns need to go on as the per-frame path would
    (each channel's last transaction and last parameter request, the keys of the calls answered lately)
    is copied from it. What stays behind there is still true should the group come back to it."""
    if not state.reference_groups or state.all_reference:
        return
    busy = {_group(a, b) for a, b in d.busy_pairs() | engine.busy_pairs()}
    quiet = state.reference_groups - busy
    if not quiet:
        return
    for channel, last in engine.last_done():
        if _group(channel[0], channel[1]) in quiet:
            state.last_done[_channel_key(channel)] = last
    for channel, known in d.channel_requests():
        if _group(channel[0], channel[1]) in quiet:
            state.last_request[_channel_key(channel)] = known
    calls = [(key, call) for key, call in d.calls.closed.items()
             if call.answered + rpc_timeout >= now and _group(call.src, call.dst) in quiet]
    if calls:
        n = len(calls)
        acts = [key[0] for key, _ in calls]
        state.answered.append(Answered(
            np.array([int.from_bytes(a[:8], "big") for a in acts], np.uint64),
            np.array([int.from_bytes(a[8:], "big") for a in acts], np.uint64),
            np.array([key[1] for key, _ in calls], np.uint32),
            np.array([_group(c.src, c.dst) for _, c in calls], np.uint64),
            np.array([c.frame for _, c in calls], np.int64), np.array([c.ts for _, c in calls], np.float64),
            np.array([c.answered for _, c in calls], np.float64), np.zeros(n, np.int32), np.zeros(n, np.int64),
            np.zeros(n, np.int64), [b""], max(c.answered for _, c in calls), keys_only=True))
    state.reference_groups -= quiet


def _group(a: bytes, b: bytes) -> int:
    x, y = int.from_bytes(a, "big"), int.from_bytes(b, "big")
    return min(x, y) << 32 | max(x, y)


def _channel_key(channel: tuple) -> ChannelKey:
    """A per-frame engine's channel as the columns key it (channel_bytes reversed)."""
    device, controller, ar, api, slot, subslot, index = channel
    return (int.from_bytes(device, "big"), int.from_bytes(controller, "big"), int.from_bytes(ar[:8], "big"),
            int.from_bytes(ar[8:], "big"), api, slot, subslot, index)


def _pending(engine: TransactionEngine, t: Txn, channel: tuple, calls: dict[int, rpc_calls.Call]) -> None:
    """A pending columnar transaction as the engine's Transaction, with the calls it waits on."""
    request = t.request if isinstance(t.request, Parsed) else None
    txn = Transaction(t.number, channel, request, t.write_frame, t.t_start, t.ref, t.req_id, t.do, t.n_params)
    txn.write_res_frame, txn.t_write_res = t.write_res_frame, t.t_write_res
    txn.read_req_frames, txn.t_read_reqs = list(t.read_frames), list(t.t_reads)
    txn.b5_retries, txn.last_b5_res = t.b5, t.last_b5
    txn.frames = list(t.frames)
    txn.findings = list(t.findings)
    txn.values_before = t.values_before
    own = [t.write_frame, *t.read_frames]
    txn.rpc_calls = [calls[f] for f in own if f in calls]
    waiting = [(f, "write" if f == t.write_frame else "read") for f in own
               if f in calls and calls[f].answered == float("-inf")]
    engine.adopt(txn, waiting)
