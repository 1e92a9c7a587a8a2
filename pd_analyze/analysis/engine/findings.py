"""The findings the columns leave to the reference's own code (engine.checks), for the loop's rows and for
the calls and transactions the vector path took: local findings of flagged column rows, a response against
its request (N4, H6-H8) and against its channel's last parameter request (Q7)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pd_analyze.analysis.engine.checks import FrameChecks, paired_flags, q7_differ, q7_differs, stub_of
from pd_analyze.analysis.engine.decode import Decoded, Decoder, uuid_int
from pd_analyze.analysis.engine.facts import Channel, Pdu, Write
from pd_analyze.analysis.engine.records import Records
from pd_analyze.analysis.engine.txncols import TxnCols
from pd_analyze.analysis.engine.vector import Calls, Episodes
from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.capture.batches import FrameBatch
from pd_analyze.model import pd_values as pt
from pd_analyze.model.rules import Finding
from pd_analyze.model.values import OP_WRITE, PROFIDRIVE_INDICES, PTYPE_RESPONSE
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol.profidrive import Address, Parsed

# The pairing's own findings (calls.Pairing makes them): the reference's text for them is its own
PAIRING_RULES = frozenset({"rpc_retransmission", "rpc_key_reused", "rpc_call_evicted", "orphan_response",
                           "rpc_response_mismatch", "rpc_addresses_not_swapped", "rpc_unanswered"})


class Findings:
    def __init__(self, checks: FrameChecks) -> None:
        self.checks = checks

    # --- the loop's rows ------------------------------------------------------------------------------
    def loop(self, dec: Decoded, rows: list[Pdu], part: int) -> list[Finding]:
        """The findings of the loop's rows (on the rows: each goes to the transaction its row belongs to)."""
        view, batch = dec.view, dec.batch
        alone: dict[tuple[int, bool], object] = {}

        def dissected(row: Pdu, with_records: bool = False) -> object:
            """The row's frame dissected alone (its record parsed too only when a record rule may report)."""
            if row.odd:
                return row.raw
            res = alone.get((id(row), with_records)) or alone.get((id(row), True))
            if res is None:
                if row.part == part:
                    res = self.checks.alone(batch.raw_frame(int(view.p.pos[row.col])), records=with_records)
                else:
                    raw = row.call.raw if row.call is not None else None
                    res = self.checks.alone(raw, records=with_records) if raw is not None else None
                alone[(id(row), with_records)] = res
            return res

        flag, stated, rec_of, rec_flag = view.flag, view.stated, view.rec_of, view.records.records.flag
        for row in rows:
            if row.odd:
                continue
            if flag[row.col]:
                record = int(rec_of[row.col])
                res = dissected(row, record >= 0 and bool(rec_flag[record]))
                if res is not None:
                    row.findings += [f for f in res.findings if f.name not in PAIRING_RULES]
            elif stated[row.col]:
                row.findings += self.checks.stated(view, row.col)
        pairs_q, pairs_s, pair_rows = [], [], []
        for row in rows:
            call = row.call
            if row.q7:
                row.findings += row.q7
            if not row.whole or row.copy or call is None or row.ptype != PTYPE_RESPONSE:
                continue
            req = call.request
            if not row.odd and not req.odd and req.part == part:
                pairs_q.append(req.col)
                pairs_s.append(row.col)
                pair_rows.append(row)
            else:
                self._paired(row, req, call, dissected, part)
        if pair_rows:
            flagged = paired_flags(view, np.array(pairs_q, np.int64), np.array(pairs_s, np.int64))
            for k in np.flatnonzero(flagged).tolist():
                row = pair_rows[k]
                self._paired(row, row.call.request, row.call, dissected, part)
        return []

    def _paired(self, row: Pdu, req: Pdu, call: object, dissected: Callable, part: int) -> None:
        res_result = dissected(row)
        req_result = dissected(req) if req.part == part or req.odd else None
        if req_result is None and not req.odd:
            raw = call.raw  # type: ignore[attr-defined]
            req_result = self.checks.alone(raw) if raw is not None else None
        res_stub = res_result.pdu.stub if res_result is not None and res_result.pdu is not None else None
        req_stub = stub_of(req) if req.odd else (
            req_result.pdu.stub if req_result is not None and req_result.pdu is not None else None)
        row.findings += self.checks.paired(res_stub, req_stub, req.opnum, row.frame)

    def q7(self, row: Pdu, view: BatchView, records: Records, addresses: tuple | None) -> list[Finding]:
        """Q7 of a read response against its channel's last parameter request (its addresses, as of its frame)."""
        answer = row.answer
        if answer is None or answer.head is None or answer.head.ident != pt.RES_READ or addresses is None:
            return []
        if isinstance(answer.record, int) and not q7_differs(view, answer.record, addresses):
            return []
        return self.checks.q7(records.parsed(answer.record), _request(addresses), row.frame)

    def redecoded(self, row: Pdu, batch: FrameBatch, opnum: int, decoder: Decoder) -> Pdu:
        """A response whose operation differs from its request's (R4), decoded again as the answer to the
        request's operation, as the reference decodes it (its pairing kept)."""
        pos = int(np.searchsorted(batch.number, row.frame))
        res = self.checks.alone(batch.raw_frame(pos), opnum)
        if res is None or res.pdu is None:
            return row
        new = decoder.row(res, row.ts)
        pairing_found = [f for f in row.findings if f.name in PAIRING_RULES]
        new.findings = pairing_found + [f for f in new.findings if f.name not in PAIRING_RULES]
        new.call, new.copy, new.part, new.decide = row.call, row.copy, row.part, row.decide
        new.opnum = row.opnum
        return new

    # --- what the vector path took ----------------------------------------------------------------------
    def vector(self, dec: Decoded, calls: Calls, ep: Episodes, cols: TxnCols | None,
               records: Records) -> list[Finding]:
        """The findings of the calls taken whole: at their episode's transaction, else (a call on another
        record) returned as findings of no transaction."""
        view, batch = dec.view, dec.batch
        if not len(calls.q):
            return []
        owner = np.full(len(calls.q), -1, np.int64)  # call -> its episode
        owner[ep.w] = np.arange(len(ep.w))
        owner[ep.reads] = np.repeat(np.arange(len(ep.w)), ep.n_reads)
        loose: list[Finding] = []

        def put(k: int, found: list[Finding]) -> None:
            if not found:
                return
            e = int(owner[k])
            if e >= 0 and cols is not None:
                cols.findings.setdefault(e, []).extend(found)
            else:
                loose.extend(found)

        flag, rec_of, rec_flag, p = view.flag, view.rec_of, view.records.records.flag, view.p
        alone: dict[tuple[int, bool], object] = {}

        def dissected(i: int, with_records: bool) -> object:
            res = alone.get((i, with_records)) or alone.get((i, True))
            if res is None:
                res = alone[(i, with_records)] = self.checks.alone(batch.raw_frame(int(p.pos[i])),
                                                                   records=with_records)
            return res

        for side in (calls.q, calls.s):
            for k in np.flatnonzero(flag[side]).tolist():
                i = int(side[k])
                record = int(rec_of[i])
                res = dissected(i, record >= 0 and bool(rec_flag[record]))
                if res is not None:
                    put(k, [f for f in res.findings if f.name not in PAIRING_RULES])
            for k in np.flatnonzero(view.stated[side]).tolist():
                put(k, self.checks.stated(view, int(side[k])))
        for k in np.flatnonzero(paired_flags(view, calls.q, calls.s)).tolist():
            q, s = int(calls.q[k]), int(calls.s[k])
            res, req = dissected(s, False), dissected(q, False)
            res_stub = res.pdu.stub if res is not None and res.pdu is not None else None
            req_stub = req.pdu.stub if req is not None and req.pdu is not None else None
            put(k, self.checks.paired(res_stub, req_stub, int(p.opnum[q]), int(view.frame_no[s])))
        # Q7: an episode's final read against its own write (the channel's last parameter request)
        read = np.flatnonzero(ep.n_reads > 0)
        last = ep.reads[ep.first_read[read] + ep.n_reads[read] - 1]
        res_rec, w_rec = rec_of[calls.s[last]], rec_of[calls.q[ep.w[read]]]
        both = (res_rec >= 0) & (w_rec >= 0)
        last, res_rec, w_rec = last[both], res_rec[both], w_rec[both]
        for j in np.flatnonzero(q7_differ(view, res_rec, w_rec)).tolist():
            addresses = records.addresses(int(w_rec[j]))
            put(int(last[j]), self.checks.q7(records.parsed(int(res_rec[j])), _request(tuple(addresses)),
                                             int(view.frame_no[calls.s[last[j]]])))
        return loose


def _request(addresses: tuple) -> Parsed:
    """A parameter request of these addresses (what Q7 compares a response with)."""
    return Parsed(False, 4 + 6 * len(addresses), addresses=[
        Address(4 + 6 * i, attr, n, pnu, sub) for i, (attr, n, pnu, sub) in enumerate(addresses)])


def response_channel(view: BatchView, row: Pdu) -> Channel | None:
    """The channel a read response names (device, controller, its block's AR, API, slot, subslot, index)."""
    if row.odd:
        res = row.raw
        stub = res.pdu.stub if res is not None and res.pdu is not None else None
        if stub is None:
            return None
        block = next((b for b in stub.blocks if b.index in PROFIDRIVE_INDICES), None)
        if block is None:
            return None
        v = block.values
        hi, lo = uuid_int(v[rec.B_AR])
        return row.src, row.dst, hi, lo, v[rec.B_API], v[rec.B_SLOT], v[rec.B_SUBSLOT], v[rec.B_INDEX]
    p = view.p
    i = row.col
    return (row.src, row.dst, int(p.ar_hi[i]), int(p.ar_lo[i]), int(p.api[i]), int(p.slot[i]), int(p.subslot[i]),
            int(p.index[i]))


def response_channels(view: BatchView, stream: list[Pdu]) -> dict[int, Channel | None]:
    """`response_channel` of each response with an answer among `stream`, by the row's id (the rows stay
    alive while it is used): the column rows' read as columns."""
    out: dict[int, Channel | None] = {}
    column = []
    for row in stream:
        if row.ptype == PTYPE_RESPONSE and row.answer is not None:
            if row.odd:
                out[id(row)] = response_channel(view, row)
            else:
                column.append(row)
    if column:
        p = view.p
        i = np.fromiter((row.col for row in column), np.int64, len(column))
        for row, *named in zip(column, p.ar_hi[i].tolist(), p.ar_lo[i].tolist(), p.api[i].tolist(),
                               p.slot[i].tolist(), p.subslot[i].tolist(), p.index[i].tolist(), strict=True):
            out[id(row)] = (row.src, row.dst, *named)
    return out


def write_names(view: BatchView, row: Pdu) -> Write | None:
    """The PROFIdrive channel a column write response names (for a write cut before its header)."""
    p = view.p
    i = row.col
    if row.odd or i < 0 or not p.has_block[i] or int(p.index[i]) not in PROFIDRIVE_INDICES \
            or int(p.opnum[i]) != OP_WRITE:
        return None
    return Write((row.src, row.dst, int(p.ar_hi[i]), int(p.ar_lo[i]), int(p.api[i]), int(p.slot[i]),
                  int(p.subslot[i]), int(p.index[i])), None, None, True)
