"""The drill-down: chosen frames of a capture dissected again with every field, as the dump shows them.

The report path keeps no field objects; `Analysis.fields()` and the HTML report's drill-down ask for
the frames of a few transactions here, in one annotated pass that stops after the last of them.
"""

from __future__ import annotations

from collections.abc import Collection, Iterator, Sequence

from pd_analyze import capture
from pd_analyze.capture import CaptureError, RawFrame
from pd_analyze.protocol.dissector import Dissector, dissect, dissect_frames
from pd_analyze.protocol.frames import FrameResult
from pd_analyze.protocol.profidrive_checks import Checker


def annotated_frames(capture: str, frames: Collection[int], profile: str, rpc_timeout: float,
                     chain: Sequence[str] = ()) -> Iterator[FrameResult]:
    """The frames numbered `frames` of one capture, annotated and checked, in frame order; with `chain`
    (the files of a --chain analysis) the frames of those files numbered as one capture, as the report
    numbers them, whichever file `capture` is.

    A damaged capture gives the wanted frames before the damage (its error is in the analysis)."""
    wanted = frozenset(frames)
    if not wanted:
        return
    last = max(wanted)
    d = Dissector(annotate=True, rpc_timeout=rpc_timeout, checker=Checker.for_profile(profile))
    try:
        for res in dissect_frames(_chained(chain), d) if chain else dissect(capture, dissector=d):
            if res.frame in wanted:
                yield res
            if res.frame >= last:
                return
    except CaptureError:
        return


def _chained(files: Sequence[str]) -> Iterator[RawFrame]:
    offset = 0
    for path in files:
        for frame in chain_numbered(path, offset):
            offset = frame.number
            yield frame


def chain_numbered(path: str, offset: int) -> Iterator[RawFrame]:
    """One file of a chain, its frames numbered on after `offset` (the files numbered as one capture)."""
    for frame in capture.frames(path, ip_only=True):
        offset += frame.run or 1  # a run of skipped frames ends at its number
        yield frame._replace(number=offset)
