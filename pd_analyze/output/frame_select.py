"""`dump -Y FILTER` and `dump -T fields -e FIELD ...`: the frames a display filter selects, and one line per
frame of chosen fields as `tshark -T fields` prints them (its -E options: header, separator, quote,
occurrence, aggregator), so a script moves over with its field names unchanged.

A capture file is read record by record beside the dissector, so `-T fields` has a line for every frame (for a
frame that is not PNIO RPC, the cells of its link, IPv4, UDP and DCE/RPC headers as tshark fills them, by
output.frame_layers, and empty cells for the rest, as tshark's for a frame without the protocol); standard
input is read by the dissector alone: only PNIO RPC frames, and no analysis fields (they need the
capture read twice).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from pd_analyze.analysis.capture_run import Settings
from pd_analyze.capture.records import CaptureCopy
from pd_analyze.output import dump_facts, frame_notes
from pd_analyze.output.capture_copy import UsageError, frames
from pd_analyze.output.display_filter import DisplayFilter, FilterError
from pd_analyze.output.dump import safe
from pd_analyze.output.dump_facts import DumpFacts
from pd_analyze.output.frame_view import ANALYSIS, FieldRef, FrameView, resolve
from pd_analyze.protocol.dissector import Dissector, dissect
from pd_analyze.protocol.links import LINK_FIELDS

_FORGET_EVERY = 4_096  # frames between two clean-ups of the links' memory of requests
_SEPARATORS = {"/t": "\t", "/s": " "}
_QUOTES = {"d": '"', "s": "'", "n": ""}


@dataclass(frozen=True)
class FieldsFormat:
    """tshark's -E options for -T fields."""

    header: bool = False
    separator: str = "\t"
    quote: str = ""
    occurrence: str = "a"  # f first, l last, a all
    aggregator: str = ","

    @classmethod
    def parse(cls, options: tuple[str, ...]) -> FieldsFormat:
        """-E header=y -E separator=, ... (tshark's names and values); UsageError for anything else."""
        values: dict[str, object] = {}
        for option in options:
            name, eq, value = option.partition("=")
            if not eq:
                raise UsageError(f"-E {option}: use name=value, e.g. -E header=y or -E separator=,")
            if name == "header" and value in ("y", "n"):
                values["header"] = value == "y"
            elif name in ("separator", "aggregator") and value:
                values[name] = _SEPARATORS.get(value, value)
            elif name == "quote" and value in _QUOTES:
                values["quote"] = _QUOTES[value]
            elif name == "occurrence" and value in ("f", "l", "a"):
                values["occurrence"] = value
            else:
                raise UsageError(f"-E {option}: pd-analyze knows header=y|n, separator=/t|/s|<char>, "
                                 "quote=d|s|n, occurrence=f|l|a, aggregator=,|/s|<char>")
        return cls(**values)  # type: ignore[arg-type]


def field_refs(names: tuple[str, ...]) -> list[FieldRef]:
    """The -e fields; FilterError (column 1) naming the first unknown one."""
    refs = []
    for name in names:
        ref = resolve(name)
        if ref is None:
            raise FilterError(f"-e {name}: neither a field of the registry nor a tshark name it maps "
                              "(see `pd-analyze fields`)", 1)
        refs.append(ref)
    return refs


def header_line(names: tuple[str, ...], fmt: FieldsFormat) -> str:
    return fmt.separator.join(f"{fmt.quote}{name}{fmt.quote}" for name in names)


def fields_line(view: FrameView, refs: list[FieldRef], fmt: FieldsFormat) -> str:
    cells = []
    for ref in refs:
        shown = view.shown(ref)
        if shown and fmt.occurrence != "a":
            shown = shown[:1] if fmt.occurrence == "f" else shown[-1:]
        text = safe(fmt.aggregator.join(shown))  # control characters escaped, never raw to a terminal
        cells.append(f"{fmt.quote}{text}{fmt.quote}" if text else "")
    return fmt.separator.join(cells)


def reads_analysis(refs: list[FieldRef], flt: DisplayFilter | None) -> bool:
    """The fields or the filter name txn.* or finding.*: the analysis is read before the frames."""
    return any(r.kind == ANALYSIS for r in refs) or (flt is not None and flt.needs_analysis)


def report_facts(path: str, settings: Settings, flt: DisplayFilter | None,
                 refs: list[FieldRef]) -> DumpFacts | None:
    """The report's facts of a capture file when the fields or the filter name a link (rpc.request_frame,
    pd.request_frame ...): the dissector is then told the report's pairing (protocol.links), as the dump's
    tree is. None for standard input or when no link is named (the dissector's own pairing gives the same
    links but for odd cases, and reading the capture twice costs a report's time)."""
    named = {n for r in [*refs, *(flt.refs if flt is not None else ())] for n in r.names}
    if path == "-" or not named & LINK_FIELDS:
        return None
    return dump_facts.collect(path, settings, txns=True)


def views(path: str, settings: Settings, dissector: Dissector, flt: DisplayFilter | None,
          refs: list[FieldRef], every_frame: bool, facts: DumpFacts | None = None) -> Iterator[FrameView]:
    """The frames of one capture the filter keeps, in frame order: every frame (`every_frame`) or only
    PNIO RPC frames. The analysis is read first when the filter or the fields name analysis fields (or
    given: `facts`, whose links `dissector` was told)."""
    needs_notes = reads_analysis(refs, flt)
    if path == "-":
        if needs_notes:
            raise UsageError("txn.* and finding.* need the capture read twice: give a file, not - (standard "
                             "input)")
        for result in dissect(path, dissector=dissector):
            view = FrameView(result.frame, result.ts, result)
            if flt is None or flt.matches(view):
                yield view
        return
    notes = facts.notes if facts is not None else frame_notes.collect(path, settings) if needs_notes else None
    try:
        with CaptureCopy(path) as copy:
            for _block, view in frames(copy, dissector, notes):
                if view is None or (view.result is None and not every_frame):
                    continue
                if facts is not None and view.number % _FORGET_EVERY == 0:  # what no later frame asks any more
                    facts.links.forget_before(view.number, view.ts)
                if flt is None or flt.matches(view):
                    yield view
    finally:
        if notes is not None:
            notes.close()
