"""One batch as the column decode sees it: its frames routed, its PNIO PDUs decoded down to the IOD
header, the PROFIdrive records among them decoded, what each request asks for (a write, a read)."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from pd_analyze.capture.batches import FrameBatch
from pd_analyze.model.values import (
    IP_ETHERTYPES,
    LINKTYPE_ETHERNET,
    OP_READ,
    OP_READ_IMPLICIT,
    OP_WRITE,
    PROFIDRIVE_INDICES,
)
from pd_analyze.protocol import pnio_batch, profidrive_batch
from pd_analyze.protocol.pnio_batch import ROUTE_DECIDE, ROUTE_FRAMES, ROUTE_PNIO, DecodedBatch
from pd_analyze.protocol.profidrive import Parsed
from pd_analyze.protocol.profidrive_checks import Checker

KIND_OTHER, KIND_WRITE, KIND_READ = 0, 1, 2  # a call on another record, a parameter request's write, a read
_PD_INDICES = np.array(sorted(PROFIDRIVE_INDICES))
# Parameters one batch's records may declare (No. of parameters summed) before the batch is decoded in
# parts: the parameter and block columns take some 160 bytes a parameter, so this bounds them near 20 MB,
# where 8 MiB of 39-parameter change requests would explode into 600,000 parameters.
PARAMETERS_PER_DECODE = 131_072
# Frames of one part the per-frame dissector decodes: each keeps its result (some kilobytes) until the part
# is through, so a batch of IP fragments or odd calls is taken in parts of this many.
ODD_FRAMES_PER_DECODE = 4_096
_IP_ETHERTYPES = np.array(sorted(int.from_bytes(t, "big") for t in IP_ETHERTYPES))


def fed(batch: FrameBatch) -> np.ndarray:
    """Per frame: the per-frame loop hands it to the dissector (`dissector.dissect_frames` counts an
    Ethernet frame without an IPv4 EtherType itself, and the dissector's clock does not see it)."""
    b = np.frombuffer(batch.buf, np.uint8)
    long = np.flatnonzero(batch.caplen >= 14)
    at = batch.start[long] + 12
    ip = np.zeros(len(batch), bool)
    ip[long] = np.isin((b[at].astype(np.int64) << 8) | b[at + 1], _IP_ETHERTYPES)
    return (batch.linktype != LINKTYPE_ETHERNET) | ip


def group_key(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The address pair of a frame as one uint64 (the same for both directions)."""
    a, b = a.astype(np.uint64), b.astype(np.uint64)
    return (np.minimum(a, b) << np.uint64(32)) | np.maximum(a, b)


@dataclass(slots=True)
class BatchView:
    """A decoded batch and what the columnar path derives from it (indices `i` are into `p`, the PDUs)."""

    batch: FrameBatch
    decoded: DecodedBatch
    records: profidrive_batch.DecodedRecords
    rec_of: np.ndarray  # int64 per PDU: its record in `records`, -1 when it carries none decoded here
    rec_pdu: np.ndarray  # int64 per record: its PDU
    group: np.ndarray  # uint64 per PDU
    frame_no: np.ndarray  # int64 per PDU
    ts: np.ndarray  # float64 per PDU
    pnio: np.ndarray  # bool per PDU: route PNIO (the rest are DECIDE)
    kind: np.ndarray  # int8 per PDU: KIND_* of a request
    flag: np.ndarray  # bool per PDU: the per-frame checks may report on it (more are added by `calls`)
    # bool per PDU: its only frame-local findings are limits the columns state themselves (column_findings):
    # it is not dissected for them
    stated: np.ndarray
    _texts: list[str] | None = None

    @property
    def p(self):  # noqa: ANN201 (PduColumns)
        return self.decoded.pdus

    @property
    def first_ts(self) -> float:
        return float(self.batch.ts[0])

    @property
    def last_ts(self) -> float:
        return float(self.batch.ts[-1])

    @property
    def last_pnio(self) -> float:
        """The time of the batch's last PNIO RPC frame the columns decoded (-inf: none)."""
        ts = self.ts[self.pnio]
        return float(ts[-1]) if len(ts) else float("-inf")

    @staticmethod
    def parts(batch: FrameBatch, checker: Checker) -> Iterator[tuple[FrameBatch, BatchView]]:
        """The batch decoded (pnio_batch, profidrive_batch: what needs no state across batches), in
        consecutive parts when its records declare more than PARAMETERS_PER_DECODE parameters or more than
        ODD_FRAMES_PER_DECODE of its frames go to the per-frame dissector (memory stays flat whatever the
        records hold and however few frames the columns decode)."""
        decoded = pnio_batch.decode(batch, checker)
        p = decoded.pdus
        has_record = p.has_block & (p.rec_len >= 4)
        declared = np.zeros(len(batch), np.int64)
        at = p.rec_start[has_record] + 3  # No. of parameters, in requests and responses alike
        np.add.at(declared, p.pos[has_record], np.frombuffer(batch.buf, np.uint8)[at])
        route = decoded.frames.route
        odd = (route == ROUTE_FRAMES) | (route == ROUTE_DECIDE)
        # each part's share of both budgets at most one: a frame weighs its parameters and, when odd, a frame
        weight = declared / PARAMETERS_PER_DECODE + odd / ODD_FRAMES_PER_DECODE
        total = np.cumsum(weight)
        if len(batch) == 1 or float(total[-1]) <= 1.0:
            yield batch, BatchView._of(batch, decoded, checker)
            return
        del decoded, p  # the parts decode again, each its own frames
        cuts = np.searchsorted(total, np.arange(1, int(np.ceil(total[-1]))), "right")
        edges = [0, *sorted({min(max(int(c), 1), len(batch) - 1) for c in cuts.tolist()}), len(batch)]
        for start, stop in itertools.pairwise(edges):
            yield from BatchView.parts(batch.part(start, stop), checker)

    @staticmethod
    def _of(batch: FrameBatch, decoded: DecodedBatch, checker: Checker) -> BatchView:
        p = decoded.pdus
        route = decoded.frames.route[p.pos]
        pnio = route == ROUTE_PNIO
        request = p.ptype == 0
        pd = pnio & p.has_block & np.isin(p.index, _PD_INDICES)
        kind = np.full(len(p.pos), KIND_OTHER, np.int8)
        kind[pd & request & (p.opnum == OP_WRITE)] = KIND_WRITE
        kind[pd & request & ((p.opnum == OP_READ) | (p.opnum == OP_READ_IMPLICIT))] = KIND_READ
        # the records: every parameter request written, every read response that succeeded
        carries = (kind == KIND_WRITE) | (pd & ~request & (p.opnum != OP_WRITE) & (p.status == 0))
        sel = np.flatnonzero(carries)
        records = profidrive_batch.decode(batch.buf, p.rec_start[sel], p.rec_len[sel], ~request[sel], checker)
        rec_of = np.full(len(p.pos), -1, np.int64)
        rec_of[sel] = np.arange(len(sel))
        rc = records.records
        flag = p.flag & ~p.long_write  # what only the per-frame checks can say
        flag[sel] |= rc.flag & ~rc.limits_only
        stated = p.long_write.copy()
        stated[sel] |= rc.limits_only
        stated &= ~flag
        return BatchView(batch, decoded, records, rec_of, sel, group_key(p.src, p.dst), batch.number[p.pos],
                         batch.ts[p.pos], pnio, kind, flag, stated)

    # --- records as the per-frame parse gives them -------------------------------------------------
    @property
    def block_texts(self) -> list[str]:
        """BlockColumns.text as a list (made once)."""
        if self._texts is None:
            text = self.records.blocks.text
            self._texts = text.to_pylist() if hasattr(text, "to_pylist") else list(text)
        return self._texts

    def parsed_record(self, record: int) -> Parsed:
        """Record `record` of `records`, parsed."""
        return self.parsed(int(self.rec_pdu[record]))

    def parsed(self, i: int) -> Parsed:
        """The record PDU i carries, as profidrive.parse_request / parse_response give it."""
        p = self.p
        return profidrive_batch.parsed(self.records, self.batch.buf, int(p.rec_start[i]), int(p.rec_len[i]),
                                       bool(p.ptype[i] != 0), int(self.rec_of[i]))
