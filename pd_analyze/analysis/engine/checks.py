"""Findings the columns leave to the reference's own code, so their text is the reference's.

A column row that a frame-local rule may report on (`BatchView.flag`) is dissected alone by the
per-frame dissector without pairing: its local findings. A response is checked against its request
and its channel's last parameter request (N4, H6-H8, Q7, protocol.md 6.1-6.4) from the two stubs,
when the columns' comparison flags the pair or when either side was not decoded by the columns.
"""

from __future__ import annotations

import numpy as np

from pd_analyze.analysis.engine.facts import Pdu
from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.capture.raw import RawFrame
from pd_analyze.model import pd_values as pt
from pd_analyze.model.rules import Finding
from pd_analyze.model.values import OP_WRITE, PTYPE_REQUEST
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol import pnio_checks
from pd_analyze.protocol.dissector import Dissector
from pd_analyze.protocol.frames import FrameResult
from pd_analyze.protocol.profidrive import Parsed
from pd_analyze.protocol.profidrive_checks import Checker, n_values_read


class FrameChecks:
    """The reference's checks on single frames and on request/response pairs."""

    def __init__(self, checker: Checker, rpc_timeout: float) -> None:
        self.checker = checker
        self.rpc_timeout = rpc_timeout

    def alone(self, frame: RawFrame, opnum: int | None = None, records: bool = True) -> FrameResult | None:
        """A frame dissected alone, without pairing: its PDU, stub and local findings (`opnum`: a response
        decoded as the answer to that operation, its request's; `records` False: its PROFIdrive record not
        parsed, when the columns say no record rule can report on it)."""
        d = Dissector(annotate=False, rpc_timeout=self.rpc_timeout, checker=self.checker, pairing=False)
        d.force_opnum = opnum
        d.records = records
        results = d.feed(frame)
        return results[0] if results else None

    def stated(self, view: BatchView, i: int) -> list[Finding]:
        """The frame-local findings of column row i (BatchView.stated) as the per-frame checks give them, from
        the columns: H13 of a parameter request above the record limit, then the limits its record's header
        and addresses break (a regular record, never a vendor service's)."""
        p, frame = view.p, int(view.frame_no[i])
        out: list[Finding] = []
        if p.long_write[i]:
            out.append(pnio_checks.request_length(int(p.record_len[i]), frame, self.checker.record.max_length))
        record = int(view.rec_of[i])
        rc = view.records.records
        if record < 0 or not rc.limits_only[record]:
            return out
        head = int(rc.ref[record]), int(rc.ident[record]), int(rc.do[record]), int(rc.n[record])
        if p.ptype[i] != PTYPE_REQUEST:
            self.checker.response_limits(int(p.rec_len[i]), *head, frame, out)
            return out
        a, first = view.records.addresses, int(rc.first_addr[record])
        at = slice(first, first + int(rc.n_addr[record]))
        self.checker.request_limits(*head, list(zip(a.attr[at].tolist(), a.n_elems[at].tolist(), a.pnu[at].tolist(),
                                                    a.subindex[at].tolist(), strict=True)), frame, out)
        return out

    def paired(self, res_stub: rec.Stub | None, req_stub: rec.Stub | None, opnum: int, frame: int) -> list[Finding]:
        """N4 and H6-H8: a response's NDR args and IOD blocks against its request's."""
        if res_stub is None or req_stub is None:
            return []
        out = pnio_checks.ndr_paired(res_stub, req_stub, frame)
        if rec.EXPECTED_BLOCK.get((opnum, True)) is not None:
            out += pnio_checks.mirroring(res_stub, req_stub, opnum, frame)
        return out

    @staticmethod
    def q7(response: Parsed | None, request: Parsed | None, frame: int) -> list[Finding]:
        """Q7: a positive read response's No. of values against its channel's last parameter request."""
        if response is None or request is None or not response.header_ok:
            return []
        return n_values_read(response, frame, request)


def paired_flags(view: BatchView, req: np.ndarray, res: np.ndarray) -> np.ndarray:
    """Per pair of column rows (request i, response j of the same batch): whether N4, H6, H7 or H8 may
    report on the response (the reference then checks it)."""
    p = view.p
    q, s = req, res
    block = p.has_block[s] & p.has_block[q]
    n4 = (p.max_count[s] != p.args_max[q]) | (p.args_len[s] > p.args_max[q])
    target = (p.target_hi[q] | p.target_lo[q]).astype(bool) & ((p.ar_hi[s] | p.ar_lo[s]) != 0)
    want_hi = np.where(target, p.target_hi[q], p.ar_hi[q])
    want_lo = np.where(target, p.target_lo[q], p.ar_lo[q])
    ar_ok = (((p.ar_hi[s] == want_hi) & (p.ar_lo[s] == want_lo))
             | ((p.ar_hi[s] == p.ar_hi[q]) & (p.ar_lo[s] == p.ar_lo[q])))
    h6 = block & ((p.iod_seq[s] != p.iod_seq[q]) | (p.api[s] != p.api[q]) | (p.slot[s] != p.slot[q])
                  | (p.subslot[s] != p.subslot[q]) | (p.index[s] != p.index[q]) | ~ar_ok)
    write = p.opnum[q] == OP_WRITE
    h7 = block & write & (p.record_len[s] != p.record_len[q])
    h8 = block & ~write & (p.record_len[s] > p.record_len[q])
    return n4 | h6 | h7 | h8


def q7_differs(view: BatchView, res_record: int, request_addresses: list[tuple[int, int, int, int]]) -> bool:
    """Whether a column read response's value blocks differ in No. of values from the request's elements."""
    rc, b = view.records.records, view.records.blocks
    if int(rc.ident[res_record]) != pt.RES_READ:
        return False
    first = int(rc.first_block[res_record])
    for j, (attr, n_elems, _pnu, _sub) in enumerate(request_addresses[:int(rc.n_blocks[res_record])]):
        row = first + j
        if attr == pt.ATTR_VALUE and b.error[row] < 0 and int(b.n_values[row]) != max(n_elems, 1):
            return True
    return False


def q7_differ(view: BatchView, res_record: np.ndarray, req_record: np.ndarray) -> np.ndarray:
    """`q7_differs` of column read responses against column requests, pair by pair, as one expression."""
    rc, a, b = view.records.records, view.records.addresses, view.records.blocks
    if not len(res_record):
        return np.zeros(0, bool)
    n = np.where(rc.ident[res_record] == pt.RES_READ,
                 np.minimum(rc.n_addr[req_record], rc.n_blocks[res_record]), 0).astype(np.int64)
    owner = np.repeat(np.arange(len(n)), n)
    j = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
    ai = rc.first_addr[req_record][owner].astype(np.int64) + j
    bi = rc.first_block[res_record][owner].astype(np.int64) + j
    wrong = (a.attr[ai] == pt.ATTR_VALUE) & (b.error[bi] < 0) & \
        (b.n_values[bi].astype(np.int64) != np.maximum(a.n_elems[ai].astype(np.int64), 1))
    return np.bincount(owner[wrong], minlength=len(n)) > 0


def stub_of(row: Pdu) -> rec.Stub | None:
    """The stub of a row the dissector decoded."""
    res = row.raw
    return res.pdu.stub if res is not None and res.pdu is not None else None
