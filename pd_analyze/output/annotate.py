"""`pd-analyze annotate`: a pcapng copy of a capture whose frames carry the analysis as packet comments.

Every frame is kept with its bytes, captured and original length and timestamp in its interface's units;
a pcapng input keeps its sections, interfaces and other blocks as they are, and its own comments (ours is
added after them); a pcap input becomes one pcapng section with one interface of its link type, snap length
and timestamp resolution. A frame that has a finding, or that opens or closes a transaction, carries one
comment (`frame_notes.FrameNote.comment`), which Wireshark shows and tshark 4.0 filters as frame.comment.
With a display filter only the matching frames are written, as `tshark -Y ... -w` does; the filter is judged
on the column decode where it can be (output.copy_filter), frame by frame on the records and trees otherwise.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import BinaryIO

from pd_analyze import __version__
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.capture import CaptureError
from pd_analyze.capture.pcapng import Block
from pd_analyze.capture.pcapng_write import (
    comment_option,
    enhanced_packet,
    interface_description,
    section_header,
    with_comment,
)
from pd_analyze.capture.records import PCAP_RECORD, CaptureCopy
from pd_analyze.output import frame_notes
from pd_analyze.output.capture_copy import Copied, check_paths, dissector_for, frames, output
from pd_analyze.output.copy_filter import NotesAhead, matching
from pd_analyze.output.display_filter import DisplayFilter
from pd_analyze.output.frame_notes import Notes


def annotate(capture: str, out: str, settings: Settings, flt: DisplayFilter | None = None) -> Copied:
    """Write the annotated copy of `capture` to `out`; a damaged capture is copied up to the damage and
    its error listed (the same error the analysis met is listed once)."""
    check_paths(capture, out)
    result = Copied(out)
    notes = frame_notes.collect(capture, settings)
    try:
        with CaptureCopy(capture) as copy, output(out) as stream:
            if copy.format == "pcap":
                stream.write(section_header(f"pd-analyze {__version__}")
                             + interface_description(copy.linktype, copy.snaplen, copy.resolution))
            try:
                ahead = NotesAhead(notes)
                matched = matching(capture, settings, flt, ahead) if flt is not None else None
                if matched is not None:
                    _matched(stream, copy, matched, ahead, result)
                else:
                    _judged(stream, copy, settings, flt, notes, result)
            except CaptureError as exc:
                result.errors.append(str(exc))
    finally:
        notes.close()
    result.errors += notes.errors_besides(result.errors)
    return result


def _matched(stream: BinaryIO, copy: CaptureCopy, matched: Iterator[int], notes: NotesAhead,
             result: Copied) -> None:
    """The frames a filter judged on the columns matches (copy_filter.matching), with their comments."""
    next_match = next(matched, None)
    for block in copy.blocks():
        number = block.number
        if not number:  # a pcapng's section, interface and other blocks
            stream.write(block.raw)
            continue
        while next_match is not None and next_match < number:
            next_match = next(matched, None)
        if next_match == number:
            note = notes.at(number)
            _counted(stream, block, note.comment() if note is not None else "", result)


def _judged(stream: BinaryIO, copy: CaptureCopy, settings: Settings, flt: DisplayFilter | None, notes: Notes,
            result: Copied) -> None:
    """Every frame, or those a filter matches judged frame by frame on the record and its tree."""
    for block, view in frames(copy, dissector_for(settings, flt), notes):
        if view is None:
            stream.write(block.raw)
        elif flt is None or flt.matches(view):
            _counted(stream, block, view.note.comment() if view.note is not None else "", result)


def _counted(stream: BinaryIO, block: Block, comment: str, result: Copied) -> None:
    _write(stream, block, comment)
    result.frames += 1
    result.comments += bool(comment)


def _write(stream: BinaryIO, block: Block, comment: str) -> None:
    if block.btype == PCAP_RECORD:
        options = comment_option(comment) if comment else b""
        data = block.raw[block.data_at:block.data_at + block.caplen]
        stream.write(enhanced_packet(0, block.stamp, data, block.orig_len, options))
    else:
        stream.write(with_comment(block, comment) if comment else block.raw)
