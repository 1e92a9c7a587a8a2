"""A display filter judged on the column decode of a batch, without a tree (issue 24 point 1): `dump -Y`,
`dump -T fields -Y`, and for `annotate -Y` and `extract -Y`.

    judge = candidates_of(flt)                                    # once per filter
    # per part (engine.decode.Decoded: `part.view`, `part.rows`) and the notes of its frames by frame:
    known = stub_known_by_links(part.view, part.rows, links)      # the report's pairing (FileLinks) ...
    fields = PartFields(part.view, part.rows, known)              # ... or np.ones: no response asks a request
    sure, maybe = judge(Rows(fields, part.view.frame_no[part.rows], part.view.ts[part.rows], notes))

`sure` (bool per row): the filter matches the frame, certainly; `maybe`: the columns cannot tell, the frame
must be dissected and judged on its tree (`flt.matches(FrameView(...))`); every other row certainly does
not match. The rows are the PNIO RPC frames the columns decoded regularly (`Decoded.rows`); a frame the
columns do not decode is dissected and judged frame by frame, as before. `known` says per row whether its
tree decodes its stub as the columns do: a response is decoded as the answer to its request's operation, as
the dissector finds it (`stub_known_by_links` for a dissector told the report's pairing; a dissector with its
own pairing: Dissector.answered_as, output.fields_file); where it is False the row's stub fields are unknown.

Each test of the filter's tree (filter_tree.Test) is three-valued per row: true, false, or unknown when the
row's tree may hold occurrences of the field the columns do not read (output.column_fields: a value block's
values where a description may show instead, the links a pairing adds, a response decoded in its tree as the
answer to another operation than its own). `not`, `and`, `or` combine by Kleene's logic (false and unknown is
false, true or unknown is true), so a filter is decided wherever its decided parts decide it. A test's
operator is applied by the filter's own closure, once per distinct value of the field in the part, on the
same values the tree holds (FrameView.values): the semantics of every operator, repeated fields and tshark's
names are the per-frame path's by construction.

The analysis fields (txn.*, finding.*) are judged from the report's notes of the frames (frame_notes): known
for every row. frame.number and frame.time_epoch are the row's; frame.iface, frame.linktype and frame.caplen
are the record's (`Rows.record`), absent where no record is read (the dump's frames).

The environment variable PD_ANALYZE_PER_FRAME=1 turns the column path off (`per_frame_forced`): the tests'
reference, never a user's setting.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from pd_analyze.analysis.engine.view import BatchView
from pd_analyze.model.values import PTYPE_RESPONSE
from pd_analyze.output.column_read import Occurrences
from pd_analyze.output.display_filter import DisplayFilter
from pd_analyze.output.dump_facts import FileLinks
from pd_analyze.output.filter_tree import All, Any, Node, Not, Test
from pd_analyze.output.frame_notes import FrameNote
from pd_analyze.output.frame_view import ANALYSIS, FRAME, FieldRef, FrameView

Tri = tuple[np.ndarray, np.ndarray]  # (true, unknown) per row; false elsewhere
PER_FRAME_ENV = "PD_ANALYZE_PER_FRAME"  # "1": every frame dissected and judged on its tree (the tests' reference)


def per_frame_forced() -> bool:
    """The tests' switch to the per-frame path (`PER_FRAME_ENV`): the column judging and cells are then left
    out, every frame judged and shown from its tree, so the two paths' outputs can be compared."""
    return os.environ.get(PER_FRAME_ENV, "") == "1"


class Fields(Protocol):
    """Where a part's rows' fields come from: output.column_fields.PartFields (the column rows) or OtherFrames."""

    def occurrences(self, ref: FieldRef) -> Occurrences | None: ...


@dataclass(slots=True)
class Rows:
    """A part's column rows as a filter judges them: their fields (`fields.rows` index the part's PDUs), frame
    numbers and times, the report's notes by frame (None: no analysis read; a filter naming txn.* or finding.*
    then needs one), and the records' frame.iface / frame.linktype / frame.caplen per row when the records are
    read (`record`; None: the frames have none, as the dump's). `stamped`: every row's record has a time (False:
    a pcapng file, whose Simple Packet Blocks have none: frame.time_epoch is unknown)."""

    fields: Fields
    frames: np.ndarray
    ts: np.ndarray
    notes: Mapping[int, FrameNote] | None = None
    record: Mapping[str, np.ndarray] | None = None
    stamped: bool = True


Judge = Callable[[Rows], tuple[np.ndarray, np.ndarray]]


def candidates_of(flt: DisplayFilter) -> Judge:
    """The column judge of a filter: rows -> (sure, maybe) masks (module docstring)."""

    def judge(rows: Rows) -> tuple[np.ndarray, np.ndarray]:
        true, unknown = _tri(flt.node, rows)
        return true & ~unknown, unknown
    return judge


def stub_known_by_links(view: BatchView, rows: np.ndarray, links: FileLinks) -> np.ndarray:
    """Per row (indices into view.p): its stub is decoded in its tree as the columns decode it. With the report's
    pairing (a dissector told `links`), a response is decoded as the answer to its request's operation as the
    report pairs it (FileLinks.request; its own when it pairs none): the columns decode it with its own."""
    p = view.p
    out = np.ones(len(rows), bool)
    responses = np.flatnonzero(p.ptype[rows] == PTYPE_RESPONSE)
    if not len(responses) or not len(links.answer_at):
        return out
    frames = view.frame_no[rows[responses]]
    at = np.minimum(np.searchsorted(links.answer_at, frames), len(links.answer_at) - 1)
    paired = links.answer_at[at] == frames
    seen = links.seen
    opnum = [seen.get(m, (0.0, -1))[1] for m in links.request_of[at[paired]].tolist()]
    out[responses[paired]] = np.array(opnum, np.int64) == p.opnum[rows[responses[paired]]]
    return out


# --- three-valued judging ------------------------------------------------------------------------------
def _tri(node: Node, rows: Rows) -> Tri:
    if isinstance(node, Test):
        return _test(node, rows)
    if isinstance(node, Not):
        true, unknown = _tri(node.item, rows)
        return ~true & ~unknown, unknown
    parts = [_tri(item, rows) for item in node.items]
    n = len(rows.frames)
    if isinstance(node, All):
        true, false = np.ones(n, bool), np.zeros(n, bool)
        for t, u in parts:
            true &= t & ~u
            false |= ~t & ~u
    else:
        assert isinstance(node, Any)
        true, false = np.zeros(n, bool), np.ones(n, bool)
        for t, u in parts:
            true |= t & ~u
            false &= ~t & ~u
    return true, ~true & ~false


def _test(test: Test, rows: Rows) -> Tri:
    ref, n = test.ref, len(rows.frames)
    if ref.kind == FRAME:
        return _per_row(test, _frame_values(ref.names[0], rows), n)
    if ref.kind == ANALYSIS:
        return _analysis(test, rows)
    occ = rows.fields.occurrences(ref)
    if occ is None:
        return np.zeros(n, bool), np.ones(n, bool)
    each = np.array([bool(test.each(v)) for v in occ.values()], bool)
    ok = each[occ.code] if len(occ.code) else np.zeros(0, bool)
    count = np.bincount(occ.owner, minlength=n)
    passed = np.bincount(occ.owner, weights=ok, minlength=n)
    true = (count > 0) & (passed == count) if test.every else passed > 0
    return true & occ.known, ~occ.known


def _per_row(test: Test, values: list[list[object]] | None, n: int) -> Tri:
    if values is None:
        return np.zeros(n, bool), np.ones(n, bool)
    judge = test.judge
    return np.fromiter((judge(v) for v in values), bool, n), np.zeros(n, bool)


def _frame_values(name: str, rows: Rows) -> list[list[object]] | None:
    if name == "frame.no":
        return [[f] for f in rows.frames.tolist()]
    if name == "frame.ts":
        return [[t] for t in rows.ts.tolist()] if rows.stamped else None
    if rows.record is None:
        return [[] for _ in range(len(rows.frames))]
    return [[v] for v in rows.record[name].tolist()]


def _analysis(test: Test, rows: Rows) -> Tri:
    """txn.* and finding.*: a frame without a note has none of them."""
    n = len(rows.frames)
    notes = rows.notes
    if notes is None:
        return np.zeros(n, bool), np.ones(n, bool)
    true = np.full(n, test.judge([]), bool)
    if notes:
        frames = rows.frames
        noted = np.flatnonzero(np.isin(frames, np.fromiter(notes, np.int64, len(notes))))
        ref, judge = test.ref, test.judge
        for k in noted.tolist():
            frame = int(frames[k])
            true[k] = judge(FrameView(frame, 0.0, None, None, notes[frame]).values(ref))
    return true, np.zeros(n, bool)
