"""Columnar transactions as the per-frame engine's Transaction, so the one row builder (`analysis.rows`)
makes their rows; and the values they read and replaced, kept in the engine's memory in frame order
with the per-frame path's own (protocol.md 7.5: a change's value_before is the value last read before
its write request, whichever path read it)."""

from __future__ import annotations

from pd_analyze.analysis.columnar.batch_view import BatchView
from pd_analyze.analysis.columnar.handover import channel_bytes
from pd_analyze.analysis.columnar.state import ChannelKey, Txn
from pd_analyze.analysis.transaction import Transaction, elements_read
from pd_analyze.model import pd_values as pt
from pd_analyze.model.capped import CappedTable
from pd_analyze.protocol.profidrive import Parsed

READ, CHANGE, ACTIVITY = 0, 1, 2  # value events, by kind (in one frame: a read closes before a change opens)


class Converter:
    """Makes Transactions of one capture's columnar transactions (channel texts made once per channel)."""

    def __init__(self) -> None:
        self._channels: dict[ChannelKey, tuple] = {}

    def channel(self, ch: ChannelKey) -> tuple:
        out = self._channels.get(ch)
        if out is None:
            if len(self._channels) > 65536:
                self._channels.clear()
            out = self._channels[ch] = channel_bytes(ch)
        return out

    def transaction(self, t: Txn, view: BatchView) -> Transaction:
        """A closed transaction (its response, if any, is a record of `view`; its number set later)."""
        request = t.request if isinstance(t.request, Parsed) else view.parsed_record(t.request)
        txn = Transaction(t.number, self.channel(t.channel), request, t.write_frame, t.t_start, t.ref, t.req_id,
                          t.do, t.n_params)
        if isinstance(t.response, int):
            txn.response = view.parsed_record(t.response)
        txn.write_res_frame, txn.t_write_res = t.write_res_frame, t.t_write_res
        txn.read_req_frames, txn.t_read_reqs = t.read_frames, t.t_reads
        txn.read_res_frame, txn.t_read_res = t.read_res_frame, t.t_read_res
        txn.b5_retries, txn.last_b5_res = t.b5, t.last_b5
        txn.pnio_status, txn.mismatch, txn.closed_by, txn.verdict = t.pnio_status, t.mismatch, t.closed_by, t.verdict
        txn.frames, txn.findings = t.frames, t.findings
        txn.values_before = t.values_before  # the same list: a change's snapshot may still be taken
        return txn


def snapshot(t: Txn, request: Parsed, device: bytes, read_values: CappedTable) -> None:
    """A change opening: the values last read of the elements it writes (in place: its Transaction may
    exist already)."""
    if t.req_id != pt.REQ_CHANGE:
        return
    for addr in request.addresses:
        keys = [(device, t.do, addr.pnu, addr.subindex + j) for j in range(max(addr.n_elems, 1))]
        t.values_before.append([read_values.get(k) for k in keys])


def remember_read(txn: Transaction, read_values: CappedTable) -> None:
    """A read closing: the values it read become the last read of their elements."""
    txn.values_read = elements_read(txn)
    for key, value in txn.values_read:
        read_values.remember(key, value)


