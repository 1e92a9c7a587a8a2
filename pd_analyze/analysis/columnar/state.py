"""What the columnar path keeps from batch to batch: calls still open, transactions still pending, each
channel's last transaction and last parameter request, the calls answered lately, the groups it has
handed to the per-frame path for good."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pd_analyze.analysis.transaction import LastDone
from pd_analyze.capture.raw import RawFrame
from pd_analyze.model.rules import Finding
from pd_analyze.protocol.profidrive import Parsed

CallKey = tuple[int, int, int]  # activity (two halves) and sequence number
# A channel (protocol.md 7.2): device, controller (IPv4 as integers), AR (two halves), API, slot, subslot, index
ChannelKey = tuple[int, int, int, int, int, int, int, int]


@dataclass(slots=True)
class Request:
    """What a call's response is checked and paired against: the request's fields and its frame."""

    frame: RawFrame
    group: int
    src: int
    dst: int
    opnum: int
    if_hi: int
    if_lo: int
    args_max: int
    has_block: bool
    iod_seq: int
    ar: tuple[int, int]
    target: tuple[int, int]
    api: int
    slot: int
    subslot: int
    index: int
    record_len: int
    channel: ChannelKey | None  # for a call on a PROFIdrive index
    kind: int  # KIND_*
    body_at: int  # where its RPC body starts in frame.data
    body_len: int


KIND_OTHER, KIND_WRITE, KIND_READ = 0, 1, 2  # a call on another record, a parameter request's write, a read


class Txn:
    """A transaction the columnar path is following (the fields of analysis.transaction.Transaction it
    needs; it becomes one only when its rows are made by the per-frame builder or it is handed over)."""

    __slots__ = ("b5", "capture_ended", "channel", "closed_by", "do", "findings", "frames", "group", "last_b5",
                 "mismatch", "n_params", "number", "pnio_status", "position", "read_frames", "read_res_frame",
                 "ref", "req_id", "request", "response", "t_read_res", "t_reads", "t_start", "t_write_res",
                 "values_before", "verdict", "write_frame", "write_res_frame")

    def __init__(self, channel: ChannelKey, group: int, write_frame: int, t_start: float) -> None:
        self.channel, self.group, self.write_frame, self.t_start = channel, group, write_frame, t_start
        self.position = 0  # among the PROFIdrive records of its write request (always 0: no Write-Multiple here)
        self.number = 0
        self.ref = self.req_id = self.do = self.n_params = -1
        self.request: Parsed | int | None = None  # the batch's record index, or the parse once carried over
        self.response: Parsed | int | None = None
        self.write_res_frame = 0
        self.t_write_res: float | None = None
        self.read_frames: list[int] = []
        self.t_reads: list[float] = []
        self.read_res_frame = 0
        self.t_read_res: float | None = None
        self.b5 = 0
        self.last_b5: float | None = None
        self.pnio_status = ""
        self.closed_by = ""
        self.verdict = ""
        self.mismatch = False
        self.capture_ended = False
        self.findings: list[Finding] = []
        self.frames: list[int] = [write_frame]
        self.values_before: list[list[str | None]] = []

    def copy(self) -> Txn:
        """A copy whose lists are its own."""
        new = Txn.__new__(Txn)
        for name in Txn.__slots__:
            value = getattr(self, name)
            setattr(new, name, list(value) if isinstance(value, list) else value)
        return new


@dataclass(slots=True)
class OpenCall:
    """A call whose response has not come yet: its request, and the transaction it belongs to."""

    request: Request
    ts: float
    txn: Txn | None
    key: CallKey


@dataclass(slots=True)
class Answered:
    """Calls the columnar path saw answered in one batch (remembered rpc_timeout after their answer): the
    keys to recognise a late copy, and where their request bodies are (the digest is made when a group
    is handed over)."""

    act_hi: np.ndarray  # uint64
    act_lo: np.ndarray  # uint64
    seq: np.ndarray  # uint32
    group: np.ndarray  # uint64
    frame: np.ndarray  # int64 request frame
    req_ts: np.ndarray  # float64
    answered: np.ndarray  # float64
    buf_of: np.ndarray  # int32: call i's body is bufs[buf_of[i]][body_start[i] : body_start[i] + body_len[i]]
    body_start: np.ndarray  # int64
    body_len: np.ndarray  # int64
    bufs: list[bytes]
    last: float = float("-inf")  # the latest answer among them
    keys_only: bool = False  # calls the per-frame dissector answered and still remembers (no bodies here)


@dataclass(slots=True)
class ColumnarState:
    """The columnar path's memory across batches (for its groups only)."""

    reference_groups: set[int] = field(default_factory=set)  # groups on the per-frame path for good
    all_reference: bool = False  # every group there (time went backwards, or the caps came near)
    open_calls: dict[CallKey, OpenCall] = field(default_factory=dict)
    pending: dict[ChannelKey, Txn] = field(default_factory=dict)
    last_done: dict[ChannelKey, LastDone] = field(default_factory=dict)
    # each channel's last parameter request and its frame, as the dissector keeps them (Q7 checks against it)
    last_request: dict[ChannelKey, tuple[Parsed, int]] = field(default_factory=dict)
    answered: list[Answered] = field(default_factory=list)
