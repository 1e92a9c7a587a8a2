"""The drill-down: chosen frames of a capture dissected again with every field, as the dump shows them.

The report path keeps no field objects; `Analysis.fields()` and the HTML report's drill-down ask for
the frames of a few transactions here, in one annotated pass that stops after the last of them.
"""

from __future__ import annotations

from collections.abc import Collection, Iterator

from pd_analyze.capture import CaptureError
from pd_analyze.protocol.dissector import Dissector, dissect
from pd_analyze.protocol.frames import FrameResult
from pd_analyze.protocol.profidrive_checks import Checker


def annotated_frames(capture: str, frames: Collection[int], profile: str, rpc_timeout: float) -> Iterator[FrameResult]:
    """The frames numbered `frames` of one capture, annotated and checked, in frame order.

    A damaged capture gives the wanted frames before the damage (its error is in the analysis)."""
    wanted = frozenset(frames)
    if not wanted:
        return
    last = max(wanted)
    d = Dissector(annotate=True, rpc_timeout=rpc_timeout, checker=Checker.for_profile(profile))
    try:
        for res in dissect(capture, dissector=d):
            if res.frame in wanted:
                yield res
            if res.frame >= last:
                return
    except CaptureError:
        return
