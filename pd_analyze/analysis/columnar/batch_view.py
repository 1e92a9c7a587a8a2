"""One batch as the columnar path sees it: its frames routed, its PDUs grouped by address pair, the
PROFIdrive records among them decoded, and which groups must go to the per-frame path.

A group goes there (for good) when any of its frames is one the columns do not take (route FRAMES), when a
record of it is irregular or not PROFIdrive at index 0x002F, when a frame the interface does not mark
as PNIO may belong to one of its calls (same activity), and when the pairing of calls or the state
machine find something unusual (`calls`, `channels`).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from pd_analyze.analysis.columnar.state import KIND_OTHER, KIND_READ, KIND_WRITE, ColumnarState
from pd_analyze.capture.batches import FrameBatch
from pd_analyze.model.values import (
    INDEX_PD_DPV1,
    IP_ETHERTYPES,
    LINKTYPE_ETHERNET,
    OP_READ,
    OP_READ_IMPLICIT,
    OP_WRITE,
    PROFIDRIVE_INDICES,
)
from pd_analyze.protocol import pnio_batch, profidrive_batch
from pd_analyze.protocol.pnio_batch import ROUTE_DECIDE, ROUTE_FRAMES, ROUTE_PNIO, ROUTE_SKIP, DecodedBatch
from pd_analyze.protocol.profidrive import Parsed
from pd_analyze.protocol.profidrive_checks import Checker

_PD_INDICES = np.array(sorted(PROFIDRIVE_INDICES))
# Parameters one batch's records may declare (No. of parameters summed) before the batch is decoded in
# parts: the parameter and block columns take some 160 bytes a parameter, so this bounds them near 20 MB,
# where 8 MiB of 39-parameter change requests would explode into 600,000 parameters.
PARAMETERS_PER_DECODE = 131_072
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
        consecutive parts when its records declare more than PARAMETERS_PER_DECODE parameters (memory stays
        flat whatever the records hold)."""
        decoded = pnio_batch.decode(batch, checker)
        p = decoded.pdus
        has_record = p.has_block & (p.rec_len >= 4)
        declared = np.zeros(len(batch), np.int64)
        at = p.rec_start[has_record] + 3  # No. of parameters, in requests and responses alike
        np.add.at(declared, p.pos[has_record], np.frombuffer(batch.buf, np.uint8)[at])
        if len(batch) == 1 or int(declared.sum()) <= PARAMETERS_PER_DECODE:
            yield batch, BatchView._of(batch, decoded, checker)
            return
        del decoded, p  # the parts decode again, each its own frames
        total = np.cumsum(declared)
        cuts = np.searchsorted(total, np.arange(PARAMETERS_PER_DECODE, int(total[-1]), PARAMETERS_PER_DECODE),
                               "right")
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
        flag = p.flag.copy()
        flag[sel] |= records.records.flag
        return BatchView(batch, decoded, records, rec_of, sel, group_key(p.src, p.dst), batch.number[p.pos],
                         batch.ts[p.pos], pnio, kind, flag)

    # --- which groups the per-frame path takes ---------------------------------------------------
    def reference_groups(self, state: ColumnarState) -> set[int]:
        """The groups of this batch the per-frame path takes (those it had already, and the new ones)."""
        f = self.decoded.frames
        bad = set(state.reference_groups)
        frames = (f.route == ROUTE_FRAMES) & (f.group != 0)
        bad.update(np.unique(f.group[frames]).tolist())
        r = self.records.records
        sel = np.flatnonzero(self.rec_of >= 0)
        odd = ~r.regular | ((self.p.index[sel] == INDEX_PD_DPV1) & ~r.plausible)
        bad.update(np.unique(self.group[sel[odd]]).tolist())
        self._shared_activities(state, bad)
        return bad

    def _shared_activities(self, state: ColumnarState, bad: set[int]) -> None:
        """Adds to `bad` the groups with a call whose activity a frame of the per-frame path carries: a
        call's frames may cross address pairs (a response from another address is R4's), and the
        dissector decides whether a frame without a PNIO interface belongs to a PNIO call (DECIDE)."""
        f = self.decoded.frames
        p = self.p
        while True:
            frames = (f.route == ROUTE_FRAMES) | (f.route == ROUTE_DECIDE)
            if bad:
                frames[p.pos[self.pnio & ~self.good(bad)]] = True
            frames &= (f.act_hi != 0) | (f.act_lo != 0)
            if not frames.any():
                return
            acts = set(zip(f.act_hi[frames].tolist(), f.act_lo[frames].tolist(), strict=True))
            found: set[int] = set()
            mine = np.flatnonzero(self.pnio & self.good(bad))
            for i, hi, lo in zip(mine.tolist(), p.act_hi[mine].tolist(), p.act_lo[mine].tolist(), strict=True):
                if (hi, lo) in acts:
                    found.add(int(self.group[i]))
            found.update(call.request.group for key, call in state.open_calls.items() if key[:2] in acts)
            for log in state.answered:
                hit = np.zeros(len(log.group), bool)
                for hi, lo in acts:
                    hit |= (log.act_hi == hi) & (log.act_lo == lo)
                found.update(np.unique(log.group[hit]).tolist())
            if found <= bad:
                return
            bad |= found

    def candidates(self, bad: set[int]) -> np.ndarray:
        """The PDUs the columns analyse: PNIO frames of the groups not in `bad`, in frame order."""
        return np.flatnonzero(self.pnio & self.good(bad))

    def good(self, bad: set[int]) -> np.ndarray:
        """Per PDU: its group is analysed by the columns."""
        if not bad:
            return np.ones(len(self.group), bool)
        return ~np.isin(self.group, np.fromiter(bad, np.uint64, len(bad)))

    def frames_for_reference(self, bad: set[int]) -> np.ndarray:
        """Positions in the batch of the frames the per-frame dissector reads, in frame order: those the
        columns do not take, the DECIDE ones, and the PNIO frames of the groups in `bad`."""
        f = self.decoded.frames
        take = (f.route == ROUTE_FRAMES) | (f.route == ROUTE_DECIDE)
        if bad:
            pnio_bad = self.p.pos[self.pnio & ~self.good(bad)]
            take[pnio_bad] = True
        return np.flatnonzero(take)

    def skip_codes(self) -> np.ndarray:
        f = self.decoded.frames
        return f.skip_reason[f.route == ROUTE_SKIP].astype(np.int64)

    def columnar_decoded(self, bad: set[int]) -> int:
        return int(np.count_nonzero(self.pnio & self.good(bad)))

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
