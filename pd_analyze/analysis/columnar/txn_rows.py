"""Columnar transactions as the per-frame engine's Transaction, so the one row builder (`analysis.rows`)
makes their rows; and the values they read and replaced, kept in the engine's memory in frame order
with the per-frame path's own (protocol.md 7.5: a change's value_before is the value last read before
its write request, whichever path read it)."""

from __future__ import annotations

from pd_analyze.analysis.columnar.batch_view import BatchView
from pd_analyze.analysis.columnar.handover import channel_bytes
from pd_analyze.analysis.columnar.state import ChannelKey, Txn
from pd_analyze.analysis.transaction import Element, Transaction, elements_read
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


def snapshot(t: Txn, view: BatchView, device: bytes, read_values: CappedTable) -> None:
    """A change opening (its request a record of `view`): the values last read of the elements it writes,
    per address (in place: its Transaction may exist already)."""
    rc, a = view.records.records, view.records.addresses
    first = int(rc.first_addr[t.request])
    for row in range(first, first + int(rc.n_addr[t.request])):
        pnu, sub = int(a.pnu[row]), int(a.subindex[row])
        keys = [(device, t.do, pnu, sub + j) for j in range(max(int(a.n_elems[row]), 1))]
        t.values_before.append([read_values.get(k) for k in keys])


def remember_read(pairs: list[tuple[Element, str]], read_values: CappedTable) -> None:
    """A read closing: the values it read become the last read of their elements."""
    for key, value in pairs:
        read_values.remember(key, value)


_WHOLE = frozenset({"string", "octets", "unicode"})  # one value per block, whatever No. of values says
_NUMBERS = frozenset({"hex", "bits", "nibbles"})  # the cell shows 0x..., an element's value is the number


def read_elements(t: Txn, view: BatchView, device: bytes, convert: Converter) -> list[tuple[Element, str]]:
    """transaction.elements_read of a closed columnar read, from the batch's columns: per element of each
    Value address answered with values, the value as a table cell shows it."""
    if not isinstance(t.request, int):  # parsed in an earlier batch
        return elements_read(convert.transaction(t, view))
    rc, a, b = view.records.records, view.records.addresses, view.records.blocks
    req, res = t.request, t.response
    first_addr, first_block = int(rc.first_addr[req]), int(rc.first_block[res])
    text = None
    out: list[tuple[Element, str]] = []
    for j in range(min(int(rc.n_addr[req]), int(rc.n_blocks[res]))):
        ai, bi = first_addr + j, first_block + j
        fmt = int(b.format[bi])
        if int(a.attr[ai]) != pt.ATTR_VALUE or fmt == pt.FMT_ERROR:
            continue
        spec = pt.FORMATS[fmt]
        n = int(b.n_values[bi])
        if spec.kind in _NUMBERS:
            at, size = int(b.data_start[bi]), spec.size
            buf = view.batch.buf
            values = [str(int.from_bytes(buf[at + i * size:at + (i + 1) * size], "big")) for i in range(n)]
        else:
            text = view.block_texts if text is None else text
            cell = text[bi]
            values = [cell] if spec.kind in _WHOLE else cell.split(" ") if n > 1 else [cell] if n else []
        pnu, sub, count = int(a.pnu[ai]), int(a.subindex[ai]), max(int(a.n_elems[ai]), 1)
        if len(values) == count:
            out += [((device, t.do, pnu, sub + i), value) for i, value in enumerate(values)]
        elif len(values) == 1:
            out.append(((device, t.do, pnu, sub), values[0]))
    return out


