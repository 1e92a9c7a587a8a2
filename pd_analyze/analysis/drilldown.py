"""The drill-down: chosen frames of a capture dissected again with every field, as the dump shows them.

The report path keeps no field objects; `Analysis.fields()` and the HTML report's drill-down ask for
the frames of a few transactions here, in one annotated pass that stops after the last of them.

A frame's decode alone finds only its own findings; the transaction engine finds the others (Q2-Q9,
T1-T9) frames later, and the RPC layer's `rpc_unanswered` once the timeout has passed, after the pass
stopped. `with_findings` gives each frame every finding the analysis' findings table holds for it,
whatever rule found it, and marks the field each names, as the dissector marks its own.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Iterator, Mapping, Sequence

from pd_analyze import capture
from pd_analyze.analysis.schema import RULE_RANK
from pd_analyze.capture import CaptureError, RawFrame
from pd_analyze.model.rules import Finding
from pd_analyze.protocol.dissector import Dissector, dissect, dissect_frames
from pd_analyze.protocol.frames import FrameResult, mark_field
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


def with_findings(results: Iterable[FrameResult], found: Mapping[int, Sequence[Finding]]) -> Iterator[FrameResult]:
    """Each result with the findings `found` holds for its frame (the findings table's, by frame) added to its
    own, a finding both hold listed once, in the table's order (by rule), and every field a finding names
    marked with it."""
    for res in results:
        extra = found.get(res.frame)
        if extra:
            add_findings(res, extra)
        yield res


def add_findings(res: FrameResult, extra: Sequence[Finding]) -> None:
    """`extra` added to the findings of `res` (those it has already once), its fields marked again."""
    seen = {_key(f) for f in res.findings}
    added = []
    for f in extra:  # (one finding listed once, however often a table repeats it)
        if _key(f) not in seen:
            seen.add(_key(f))
            added.append(f)
    if not added:
        return
    res.findings = sorted([*res.findings, *added], key=lambda f: RULE_RANK.get(f.name, -1))
    by_field: dict[str, list[Finding]] = {}
    for f in res.findings:
        by_field.setdefault(f.field, []).append(f)
    named = {f.field for f in added}
    for layer in res.layers:
        fields = layer.fields  # a Layout's fields are shared between frames: each marked one is put back
        for i, fld in enumerate(fields):
            if fld.name in named:
                fields[i] = mark_field(fld, by_field, frozenset())


def _key(f: Finding) -> tuple[str, str, str, str]:
    return (f.name, f.field, f.value, f.message)


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
