"""`dump --findings-only`: each frame's own findings and those the transaction engine finds at it.

A frame's decode finds what the frame alone shows; pairing a response with its request (Q2-Q5) and the
channel rules (T1-T7, protocol.md 6.5) are found by the transaction engine, often frames later. To show
them at their frames, as `audit` does, the frames are held (without their layers) from the first frame
of the oldest open transaction on, and written once no open transaction can add to them.
"""

from __future__ import annotations

import dataclasses
import heapq
from collections.abc import Iterable, Iterator

from pd_analyze.analysis.transaction import Transaction
from pd_analyze.analysis.transactions import TransactionEngine
from pd_analyze.model.rules import TRANSACTION_RULES, Finding
from pd_analyze.protocol.frames import FrameResult


def with_transaction_findings(results: Iterable[FrameResult], engine: TransactionEngine) -> Iterator[FrameResult]:
    """The frame results in frame order, layers dropped, each with the engine's findings at its frame added
    after its own; frames with no finding at all are left out."""
    held: list[tuple[int, int, FrameResult]] = []  # (frame, arrival, result), a heap
    extra: dict[int, list[Finding]] = {}
    last_ts = float("-inf")
    for arrival, res in enumerate(results):
        last_ts = max(last_ts, res.ts)
        _collect(engine.feed(res), engine, extra)
        heapq.heappush(held, (res.frame, arrival, dataclasses.replace(res, layers=[], pdu=None)))
        bound = min(engine.open_frames(), default=res.frame + 1)
        while held and held[0][0] < bound:
            out = _with(heapq.heappop(held)[2], extra)
            if out is not None:
                yield out
    _collect(engine.finish(last_ts), engine, extra)
    while held:
        out = _with(heapq.heappop(held)[2], extra)
        if out is not None:
            yield out
    for frame in sorted(extra):  # a frame written before the engine spoke of it (rare: a late adoption)
        yield FrameResult(frame, float("nan"), bytes(4), bytes(4), "transaction findings (frame shown earlier)", -1,
                          findings=extra[frame])


def _collect(closed: list[Transaction], engine: TransactionEngine, extra: dict[int, list[Finding]]) -> None:
    found = [f for txn in closed for f in txn.findings if f.name in TRANSACTION_RULES]
    found += [f for f in engine.loose if f.name in TRANSACTION_RULES]
    engine.loose.clear()
    for f in found:
        extra.setdefault(f.frame, []).append(f)


def _with(res: FrameResult, extra: dict[int, list[Finding]]) -> FrameResult | None:
    more = extra.pop(res.frame, None)
    if more:
        res.findings = [*res.findings, *more]
    return res if res.findings else None
