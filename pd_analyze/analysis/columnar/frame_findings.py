"""The findings of flagged frames, made by the per-frame dissector itself: their text is the reference's.

The columnar decode flags a frame when one of the frame's rules may report something. Such frames are
few; those of a batch are dissected together, in frame order, by a dissector of their own that also
reads, just before, the frames they are checked against (a response's request), and learns the
channel's last parameter request before the answer to one. (In an ordinary group nothing else in
between changes what those checks see: calls are answered within rpc_timeout, a channel's calls do not
overlap.)
"""

from __future__ import annotations

from collections.abc import Iterable

from pd_analyze.capture.raw import RawFrame
from pd_analyze.model.rules import Finding
from pd_analyze.protocol.dissector import Dissector
from pd_analyze.protocol.profidrive import Parsed
from pd_analyze.protocol.profidrive_checks import Checker


def findings_of(frames: Iterable[RawFrame], wanted: set[int], checker: Checker, rpc_timeout: float,
                requests: dict[int, tuple[tuple, Parsed, int]]) -> dict[int, list[Finding]]:
    """The findings the per-frame dissector reports on each frame numbered in `wanted`, `frames` (those
    and their context, any order, a frame possibly twice) read in frame order; `requests`: by frame, the
    channel's last parameter request (channel, parse, its frame) the dissector knows when it reads it."""
    d = Dissector(annotate=False, rpc_timeout=rpc_timeout, checker=checker)
    out: dict[int, list[Finding]] = {}
    for frame in sorted({f.number: f for f in frames}.values(), key=lambda f: f.number):
        known = requests.get(frame.number)
        if known is not None:
            d.adopt_channel_request(*known)
        for res in d.feed(frame):
            if res.frame in wanted:
                out[res.frame] = res.findings
    return out
