"""The frames a display filter keeps for `annotate -Y` and `extract -Y`, judged on the column decode (issue 24
point 1): `FieldsFile` reads the capture as batches with one dissector of its own pairing, as the copies' own
per-frame read does (capture_copy.dissector_for), judges the filter on the columns and dissects only the frames
the columns cannot tell; asked for one cell, frame.number, its lines are the numbers of the matching frames,
in frame order. The frames are the same as the per-frame judgement's, frame for frame
(tests/test_copy_filter.py holds both against each other).

Where FieldsFile does not read the capture (standard input, the per-frame reference forced) `matching` is None
and the caller judges frame by frame, as before.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator

from pd_analyze.analysis.capture_run import Settings
from pd_analyze.capture import CaptureError
from pd_analyze.output.display_filter import DisplayFilter
from pd_analyze.output.fields_file import FieldsFile, takes
from pd_analyze.output.frame_notes import FrameNote, Notes
from pd_analyze.output.frame_select import FieldsFormat, field_refs

_NUMBER = field_refs(("frame.number",))


class NotesAhead:
    """The notes of a capture read by two readers in frame order: the filter's pass (`upto`, as FieldsFile asks),
    which runs at most a batch ahead, and the copy (`at`, for the frames it writes). The notes the filter's pass
    read and the copy has not passed yet are held: a batch's worth at most."""

    def __init__(self, notes: Notes) -> None:
        self.notes = notes
        self._held: deque[FrameNote] = deque()  # in frame order
        self._read_to = 0  # the filter's pass read every note up to this frame

    def upto(self, last: int) -> list[FrameNote]:
        out = self.notes.upto(last)
        self._held.extend(out)
        self._read_to = max(self._read_to, last)
        return out

    def at(self, frame: int) -> FrameNote | None:
        """The note of `frame` (frames asked in increasing order); the held notes before it are let go."""
        if frame > self._read_to:
            return self.notes.at(frame)
        held = self._held
        while held and held[0].frame < frame:
            held.popleft()
        return held.popleft() if held and held[0].frame == frame else None


def matching(capture: str, settings: Settings, flt: DisplayFilter,
             notes: Notes | NotesAhead | None) -> Iterator[int] | None:
    """The numbers of the frames `flt` matches, in increasing order, or None when only the per-frame judgement
    can read this capture. `notes` (the analysis's, when the filter names txn.* or finding.*) is read through
    `upto`. The iterator stops at a damaged record (the copy meets and reports the same damage)."""
    if not takes(capture):
        return None
    fields = FieldsFile(capture, settings, settings.checker(), _NUMBER, FieldsFormat(), flt,
                        notes if flt.needs_analysis else None, [])
    return _numbers(fields)


def _numbers(fields: FieldsFile) -> Iterator[int]:
    try:
        for line in fields.lines():
            yield int(line)
    except CaptureError:
        return
