"""One PROFIdrive transaction (protocol.md 7.3) as the engine follows it: what it holds from its write, its
reads and how it ended; its figures (7.6, computed exactly on integer nanoseconds) and its verdict (7.4)."""

from __future__ import annotations

from pd_analyze.analysis.engine.facts import Channel, Head, Record
from pd_analyze.model.rules import Finding
from pd_analyze.model.times import NS


class Txn:
    """A transaction: opened by a write of a parameter request, closed by its final answer, a failure,
    its deadline, the next write on its channel, the caps or the capture's end."""

    __slots__ = ("admitted", "b5", "calls", "capture_ended", "channel", "closed_by", "do", "ended_at", "fallback",
                 "findings", "frames", "last_b5", "malformed", "malformed_at", "mismatch", "n_params", "number",
                 "opened_at", "pnio_status", "position", "read_frames", "read_res_frame", "ref", "req_id", "request",
                 "response", "response_head", "retransmissions", "t_read_res", "t_reads", "t_start", "t_write_res",
                 "values_before", "vendor", "verdict", "write_frame", "write_res_frame")

    def __init__(self, channel: Channel, write_frame: int, t_start: int, opened_at: int, position: int) -> None:
        self.channel = channel
        self.write_frame = write_frame  # its write request's first frame (a fragmented one's first fragment)
        self.t_start = t_start  # ns: timed at the request's first frame (protocol.md 7.6)
        self.opened_at, self.position = opened_at, position  # numbered in this order (README: txn)
        self.admitted = opened_at  # the frame T1/T4 and T3 name it at (a cut write's: its request's)
        self.number = 0
        self.ref = self.req_id = self.do = self.n_params = -1  # -1: not in the frame (a cut request)
        self.request: Record = None
        self.response: Record = None
        self.response_head: Head | None = None
        self.vendor: tuple[int, ...] | None = None  # the Response IDs of a profile's own Request ID (5.5)
        self.write_res_frame = 0
        self.t_write_res: int | None = None
        self.read_frames: list[int] = []
        self.t_reads: list[int] = []
        self.read_res_frame = 0
        self.t_read_res: int | None = None
        self.b5 = 0
        self.last_b5: int | None = None
        self.calls: list = []  # its requests' RPC calls (their copies are its retransmissions)
        self.retransmissions = 0
        self.pnio_status = ""
        self.malformed = self.mismatch = self.fallback = self.capture_ended = False
        self.malformed_at = 0  # the frame of the first PDU of it that cannot be decoded (T8 names it)
        self.ended_at = 0  # the frame of the write that superseded it, or of its eviction (T8 names it)
        self.closed_by = ""  # "response", "pnio_error", "deadline", "superseded", "capture_end", "evicted"
        self.verdict = ""
        self.frames: list[int] = []
        self.findings: list[Finding] = []
        # a change: per address, the values of its elements last read back before its write request (None:
        # not read in the capture)
        self.values_before: list[str] = []  # a change's value_before cell per address ("" unknown; [] none known)

    def spoil(self, frame: int) -> None:
        """A PDU of the transaction at `frame` cannot be decoded: it is malformed (protocol.md 7.4 rule 1)."""
        if not self.malformed_at:
            self.malformed_at = frame
        self.malformed = True

    def figures(self) -> dict[str, float | None]:
        """Timing figures of protocol.md 7.6 in seconds, each the exact difference of two capture times
        (None where the capture has no such frame)."""
        res = self.t_write_res
        final_req = self.t_reads[-1] if self.t_reads else None
        done = self.t_read_res if self.closed_by == "response" else None
        start = self.t_start
        return {
            "t_write_rtt": None if res is None else (res - start) / NS,
            "t_total": None if done is None else (done - start) / NS,
            "t_final_read_rtt": None if done is None or final_req is None else (done - final_req) / NS,
            "t_first_read_gap": None if res is None or not self.t_reads else (self.t_reads[0] - res) / NS,
            "t_last_read": None if final_req is None else (final_req - start) / NS,
        }
