"""What the report says of a capture file's frames, read first for its dump: the findings at every frame (all of
them, as `audit` lists them: the frame's own, the pairing's and the transactions' Q2-Q5, T1-T9, R7), the
transactions (for txn.* in a filter), and the pairing (protocol.links): each call's request and first answer,
each transaction's parameter request and final read response, the PDUs taken as PNIO by their call.

The findings and transactions go through `frame_notes` (sorted by frame on disk); the pairing is two int64
arrays per call and per transaction (some 16 bytes a call), held in memory. What `Links` answers about another
frame's time, operation or record it learns from `DumpFrames` as the second pass reads the frames
(output.dump_file): a request always comes before its answer.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pd_analyze.analysis.capture_run import CaptureResult, Settings
from pd_analyze.capture.raw import RawFrame
from pd_analyze.output import frame_notes
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol.frames import Accounting, FrameResult
from pd_analyze.protocol.links import Request
from pd_analyze.protocol.profidrive import Parsed

_E = np.empty(0, np.int64)


def _sorted_pairs(keys: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    order = np.argsort(keys, kind="stable")
    return keys[order], values[order]


def _has(keys: np.ndarray, frame: int) -> bool:
    at = int(np.searchsorted(keys, frame))
    return at < len(keys) and int(keys[at]) == frame


def _lookup(keys: np.ndarray, values: np.ndarray, frame: int) -> int:
    at = int(np.searchsorted(keys, frame))
    return int(values[at]) if at < len(keys) and keys[at] == frame else 0


@dataclass
class FileLinks:
    """The report's pairing of one capture (protocol.links.Links), and what the second pass tells it of the
    frames it passes (`seen`, `stubs`, `recent`)."""

    answer_at: np.ndarray = field(default_factory=lambda: _E)  # sorted answer frames ...
    request_of: np.ndarray = field(default_factory=lambda: _E)  # ... and the request frame of each
    request_at: np.ndarray = field(default_factory=lambda: _E)  # sorted request frames ...
    answer_of: np.ndarray = field(default_factory=lambda: _E)  # ... and the answer frame of each
    pd_response_at: np.ndarray = field(default_factory=lambda: _E)  # sorted final read responses ...
    pd_request_of: np.ndarray = field(default_factory=lambda: _E)  # ... and their parameter request's frame
    decided: frozenset[int] = frozenset()  # PDUs of an interface not PNIO's, taken as PNIO by their call
    rpc_timeout: float = 5.0
    # filled by the second pass: each request's time and operation (by frame), each parameter request whose
    # final response is still to come (its raw frame, dissected by `dissect` when a response asks, or its
    # stub), the requests of the last rpc_timeout (activity, seq, frame, ts) for control PDUs
    seen: dict[int, tuple[float, int]] = field(default_factory=dict)
    kept: dict[int, RawFrame | rec.Stub | None] = field(default_factory=dict)
    dissect: Callable[[RawFrame], FrameResult | None] = lambda _frame: None
    recent: list[tuple[bytes, int, int, float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.pd_requests = np.unique(self.pd_request_of)

    def request(self, frame: int) -> Request | None:
        m = _lookup(self.answer_at, self.request_of, frame)
        if not m:
            return None
        ts, opnum = self.seen.get(m, (float("nan"), -1))
        return Request(m, ts, opnum)

    def answer(self, frame: int) -> int:
        return _lookup(self.request_at, self.answer_of, frame)

    def open_call(self, activity: bytes, seq: int, frame: int, ts: float) -> int:
        for act, s, m, m_ts in self.recent:
            if act == activity and s == seq and m < frame and m_ts + self.rpc_timeout >= ts:
                answer = self.answer(m)
                return m if not answer or answer > frame else 0
        return 0

    def request_seen(self, res: FrameResult) -> None:
        frame, pdu = res.frame, res.pdu
        if _has(self.request_at, frame):
            self.seen[frame] = (res.ts, pdu.opnum)  # type: ignore[union-attr]
        if _has(self.pd_requests, frame):  # its stub alone: the result is printed and let go (output.dump_file)
            self.kept[frame] = pdu.stub if pdu is not None else None
        if res.key is not None:
            self.recent.append((res.key[0], res.key[1], frame, res.ts))

    def stub_of(self, frame: int) -> rec.Stub | None:
        """The stub of parameter request `frame` (its records parsed), dissected when first asked."""
        kept = self.kept.get(frame)
        if isinstance(kept, RawFrame):
            res = self.dissect(kept)
            kept = self.kept[frame] = res.pdu.stub if res is not None and res.pdu is not None else None
        return kept  # type: ignore[return-value]

    def parameter_request(self, frame: int, block: rec.Block) -> tuple[int, Parsed | None] | None:
        m = _lookup(self.pd_response_at, self.pd_request_of, frame)
        stub = self.stub_of(m) if m else None
        if stub is None:
            return None
        v = block.values
        pd = [b for b in stub.blocks if isinstance(b.pd, tuple) and b.layout is rec.WRITE_REQ]
        same = [b for b in pd if (b.values[rec.B_API], b.values[rec.B_SLOT], b.values[rec.B_SUBSLOT], b.index)
                == (v[rec.B_API], v[rec.B_SLOT], v[rec.B_SUBSLOT], block.index)]
        chosen = (same or pd)[:1]
        return (m, chosen[0].pd[0] if chosen else None)  # type: ignore[index]  (a record cut short: not parsed)

    def is_request(self, frames: np.ndarray) -> np.ndarray:
        """Which of `frames` are requests some later frame answers (their time and operation are wanted)."""
        return np.isin(frames, self.request_at)

    def is_parameter_request(self, frames: np.ndarray) -> np.ndarray:
        return np.isin(frames, self.pd_requests)

    def forget_before(self, frame: int, ts: float) -> None:
        """What no frame from `frame` on asks for any more (answers passed, requests past rpc_timeout)."""
        if self.seen:
            at = np.searchsorted(self.request_at, np.fromiter(self.seen, np.int64, len(self.seen)))
            for m, k in zip(list(self.seen), at.tolist(), strict=True):
                if k >= len(self.request_at) or self.answer_of[k] < frame:
                    del self.seen[m]
        if self.kept:
            still = set(self.pd_request_of[self.pd_response_at >= frame].tolist())
            for m in [m for m in self.kept if m not in still]:
                del self.kept[m]
        if self.recent and self.recent[0][3] + self.rpc_timeout < ts:
            self.recent = [r for r in self.recent if r[3] + self.rpc_timeout >= ts]


@dataclass
class DumpFacts:
    notes: frame_notes.Notes
    links: FileLinks
    captures: list[CaptureResult]

    @property
    def accounting(self) -> Accounting:
        return self.captures[0].accounting if self.captures else Accounting()

    def close(self) -> None:
        self.notes.close()


class _Calls:
    def __init__(self) -> None:
        self.requests: list[np.ndarray] = []
        self.answers: list[np.ndarray] = []
        self.decided: set[int] = set()
        # (final read response, write response, write request): blocks, and the rows given one by one since
        self.final: list[np.ndarray] = []
        self.rows: list[tuple[int, int, int]] = []

    def add(self, requests: np.ndarray, answers: np.ndarray, decided: list[int]) -> None:
        self.requests.append(np.asarray(requests, np.int64))
        self.answers.append(np.asarray(answers, np.int64))
        self.decided.update(decided)

    def transaction(self, row: Any) -> None:
        if row.read_res_frame is not None and row.closed_by in frame_notes.FINAL_ANSWER:
            self.rows.append((int(row.read_res_frame), int(row.write_res_frame or 0), int(row.write_req_frame or 0)))

    def table(self, name: str, table: Any) -> None:
        """An engine's table whole (frame_notes.collect's `on_table`): a transactions table's final answers, as
        `transaction` takes them, in its order. (Its rows and the parameters' are then not made one by one.)"""
        if name != "transactions" or not table.num_rows:
            return
        import pyarrow as pa
        import pyarrow.compute as pc

        closed_by = table.column("closed_by")
        final = pc.is_in(closed_by, value_set=pa.array(sorted(frame_notes.FINAL_ANSWER), closed_by.type))
        final = pc.and_(final.fill_null(False), pc.is_valid(table.column("read_res_frame")))
        rows = table.filter(final)
        self._flush()
        self.final.append(np.stack([rows.column(name).fill_null(0).to_numpy().astype(np.int64)
                                    for name in ("read_res_frame", "write_res_frame", "write_req_frame")], axis=1))

    def _flush(self) -> None:
        if self.rows:
            self.final.append(np.array(self.rows, np.int64).reshape(-1, 3))
            self.rows = []

    def links(self, rpc_timeout: float) -> FileLinks:
        req = np.concatenate(self.requests) if self.requests else _E
        ans = np.concatenate(self.answers) if self.answers else _E
        answer_at, request_of = _sorted_pairs(ans, req)
        request_at, answer_of = _sorted_pairs(req, ans)
        self._flush()
        final = np.concatenate(self.final) if self.final else np.empty((0, 3), np.int64)
        # the parameter request: the frame its PDU is decoded in (the write response's call: a fragmented
        # request's last fragment), else the write request's frame
        via_call = np.zeros(len(final), np.int64)
        if len(answer_at) and len(final):
            at = np.minimum(np.searchsorted(answer_at, final[:, 1]), len(answer_at) - 1)
            found = answer_at[at] == final[:, 1]
            via_call[found] = request_of[at[found]]
        pd_request = np.where(via_call > 0, via_call, final[:, 2]) if len(final) else _E
        pd_response_at, pd_request_of = _sorted_pairs(final[:, 0], pd_request)
        return FileLinks(answer_at, request_of, request_at, answer_of, pd_response_at, pd_request_of,
                         frozenset(self.decided), rpc_timeout)


def collect(path: str, settings: Settings, txns: bool = True) -> DumpFacts:
    """The report's facts of one capture file (`txns` False: the transactions are not noted per frame, only
    the findings and the pairing)."""
    calls = _Calls()
    notes = frame_notes.collect(path, settings, calls.transaction, on_calls=calls.add, txns=txns,
                                on_table=calls.table)
    return DumpFacts(notes, calls.links(settings.rpc_timeout), notes.captures)
