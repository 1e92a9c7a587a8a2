"""What `annotate` and `extract` share: the output file, and the capture's records seen as frames (each
with its dissected fields, when a display filter needs them, and what the analysis says of it).

Everything is read in frame order and joined by frame number, each stream read no further ahead than the
dissector's own bounded hold: memory stays flat in the capture size. The capture is read more than once
(analysis, dissection, records), so it must be a file, not standard input.
"""

from __future__ import annotations

import gzip
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import BinaryIO

from pd_analyze.analysis.capture_run import Settings
from pd_analyze.capture.pcapng import Block
from pd_analyze.capture.records import CaptureCopy
from pd_analyze.output.display_filter import DisplayFilter
from pd_analyze.output.frame_notes import Notes
from pd_analyze.output.frame_view import LAYERS, Cursor, FrameView
from pd_analyze.protocol.dissector import Dissector, dissect


class UsageError(ValueError):
    """Arguments that cannot work (standard input, the output is the input): a one-line message."""


@dataclass
class Copied:
    """What a copy wrote: frames and how many carry a comment (annotate) or transactions (extract)."""

    path: str
    frames: int = 0
    comments: int = 0
    transactions: int = 0
    errors: list[str] = field(default_factory=list)


def check_paths(capture: str, out: str) -> None:
    """The capture is read several times (not stdin) and is not the file written."""
    if capture == "-":
        raise UsageError("the capture is read more than once: give a file, not - (standard input)")
    if out != "-" and os.path.exists(out) and os.path.exists(capture) and os.path.samefile(capture, out):
        raise UsageError(f"-w {out} is the capture itself: write to another file")


@contextmanager
def output(path: str) -> Iterator[BinaryIO]:
    """The file written: `-` is standard output, a name ending in .gz is gzip-compressed."""
    if path == "-":
        yield sys.stdout.buffer
        sys.stdout.buffer.flush()
        return
    try:
        raw = open(path, "wb")  # noqa: SIM115 - closed below
    except OSError as exc:
        raise UsageError(f"-w {path}: cannot write there ({exc.strerror or exc})") from None
    try:
        if path.endswith(".gz"):
            with gzip.GzipFile(fileobj=raw, mode="wb") as zipped:
                yield zipped  # type: ignore[misc]
        else:
            yield raw
    finally:
        raw.close()


def frames(copy: CaptureCopy, dissector: Dissector | None,
           notes: Notes | None) -> Iterator[tuple[Block, FrameView | None]]:
    """Every block of the capture; a packet's with its frame view (None for other blocks). `dissector`,
    when given, reads the capture beside the records and gives each PNIO RPC frame its fields."""
    results = Cursor(dissect(copy.path, dissector=dissector)) if dissector is not None else None
    for block in copy.blocks():
        if not block.number:
            yield block, None
            continue
        number = block.number
        yield block, FrameView(number, block.ts, results.at(number) if results is not None else None, block,
                               notes.at(number) if notes is not None else None)


def dissector_for(settings: Settings, flt: DisplayFilter | None, always: bool = False) -> Dissector | None:
    """The dissector to read the capture with when the filter names dissected fields (or `always`)."""
    if not always and (flt is None or not any(r.kind == LAYERS for r in flt.refs)):
        return None
    return Dissector(annotate=True, rpc_timeout=settings.rpc_timeout, checker=settings.checker())
