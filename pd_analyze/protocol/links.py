"""The pairing a dissector is told instead of finding it itself: the dump of a capture file shows the report's
pairing (analysis.engine, read in a first pass by output.dump_facts), so its links (rpc.request_frame,
rpc.response_frame, pd.request_frame) and the request a response's blocks are named after are the report's.

A dissector given `Links` pairs nothing: it decodes each frame alone (as without pairing) and asks these for
what another frame decides. Its own findings are replaced by the report's at each frame (the dump does
that), so a frame reads the same whichever frames were dissected before it.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol.frames import FrameResult
from pd_analyze.protocol.profidrive import Parsed

# the fields a dissector adds from its pairing (the Call and Parameter access layers)
LINK_FIELDS = frozenset({"rpc.request_frame", "rpc.response_frame", "rpc.rtt", "pd.request_frame"})


class Request(NamedTuple):
    """The request a response, fault or reject answers: its frame, time (the frame's own, as a float) and
    operation (a response is decoded as the answer to it, protocol.md 2.4)."""

    frame: int
    ts: float
    opnum: int


class Links(Protocol):
    def request(self, frame: int) -> Request | None:
        """The request the answer in `frame` answers (None: none, as the report pairs it)."""

    def answer(self, frame: int) -> int:
        """The frame of the first answer to the request in `frame` (0: none)."""

    def open_call(self, activity: bytes, seq: int, frame: int, ts: float) -> int:
        """The request frame of the call (activity, seq) still open at `frame` (a control PDU of it: ping,
        working, ack ...), 0 when none is."""

    def request_seen(self, res: FrameResult) -> None:
        """A request dissected (in frame order, by the dissector told these links): what its answer will ask."""

    def parameter_request(self, frame: int, block: rec.Block) -> tuple[int, Parsed | None] | None:
        """The parameter request the response record `block` of `frame` answers, as the report's transaction
        pairs it: its frame and its parse (None when it was cut short), None when the record belongs to no
        transaction."""
