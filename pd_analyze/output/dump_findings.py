"""`dump --findings-only`: each frame's own findings and those the analysis finds at it.

A frame's decode finds what the frame alone shows; pairing a response with its request (Q2-Q5) and the
channel rules (T1-T9, protocol.md 6.5) are the analysis engine's, which reads the capture first
(`frame_notes`): its findings are shown at their frames, as `audit` shows them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator

from pd_analyze.model.rules import TRANSACTION_RULES
from pd_analyze.output.frame_notes import Notes
from pd_analyze.protocol.frames import FrameResult


def with_transaction_findings(results: Iterable[FrameResult], notes: Notes) -> Iterator[FrameResult]:
    """The frame results in frame order, layers dropped, each with the analysis' transaction findings at
    its frame added after its own; frames with no finding at all are left out."""
    for res in results:
        note = notes.at(res.frame)
        more = [f.finding(res.frame) for f in note.findings if f.name in TRANSACTION_RULES] if note else []
        res = dataclasses.replace(res, layers=[], pdu=None)
        if more:
            res.findings = [*res.findings, *more]
        if res.findings:
            yield res
