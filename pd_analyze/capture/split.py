"""One classic pcap cut into pieces at record boundaries, each read on its own (by another process, or a
Dask worker) with the frames, numbers and errors `batches` gives for the same records.

The cut points come from a sequential walk of the record headers (`pieces`: one unpack a record, about
0.1 us, no frame decoded), so every cut is a record boundary by construction, never a guess from bytes
that look like a header. The walk stops cutting at the first record that is cut short or claims more
than MAX_CAPLEN bytes: the last piece runs to the end of the file, and its reader meets that damage and
raises the error one reader of the whole file raises there (same text, same file offset).

pcapng and gzip-compressed captures are not cut here (a gzip stream cannot be entered in its middle; a
pcapng piece would need the section and interface blocks before it): `pieces` returns None for them, and
the caller reads them in one process (analysis.split decodes their batches in parallel all the same).
"""

from __future__ import annotations

import io
import struct
from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

from pd_analyze.capture.batches import BATCH_FRAMES, FrameBatch, _pcap_batches, _record_starts
from pd_analyze.capture.pcap import pcap_header
from pd_analyze.capture.raw import MAX_CAPLEN, CaptureError, CaptureInfo
from pd_analyze.capture.reader import opened

PIECE_BYTES = 8 << 20  # a piece is about one chunk of the batch reader: one worker's task, decoded at once
_WALK = 8 << 20  # bytes of record headers walked at a time


class Piece(NamedTuple):
    """Records `start`..`end` (file offsets; `end` None: to the end of the file), the first numbered `first`."""

    start: int
    end: int | None
    first: int


def pieces(path: str, piece_bytes: int = PIECE_BYTES, piece_frames: int = 0) -> list[Piece] | None:
    """The pieces of a plain (uncompressed) pcap, each about `piece_bytes` (or `piece_frames` records when
    given, for tests that cut everywhere); None for any other capture, or one that cannot be opened."""
    info = CaptureInfo(path)
    try:
        with opened(path, info) as (stream, fmt):
            if fmt != "pcap" or info.compressed:
                return None
            head = stream.read(24)
            little = pcap_header(path, head)[0]
            return _walk(stream, struct.Struct("<8xI" if little else ">8xI").unpack_from, piece_bytes, piece_frames)
    except (CaptureError, OSError):
        return None  # (its error is reported where it is read: in one process)


def _walk(stream: io.BufferedIOBase, caplen_at: object, piece_bytes: int, piece_frames: int) -> list[Piece]:
    out = [Piece(24, None, 1)]
    base, number, buf = 24, 1, b""  # base: file offset of buf[0], a record's start; number: its frame
    while True:
        data = stream.read(_WALK)
        buf = buf + data if buf else data
        starts = _record_starts(buf, caplen_at)  # type: ignore[arg-type]
        ends = starts[1:]
        too_long = np.flatnonzero(ends - starts[:-1] - 16 > MAX_CAPLEN)
        good = int(too_long[0]) if too_long.size else len(ends)
        complete = min(good, int(np.searchsorted(ends, len(buf), "right")))  # records wholly in buf, undamaged
        _cut(out, base + ends[:complete], number + 1, piece_bytes, piece_frames)
        if too_long.size and complete == good:
            return out  # a record claims more than MAX_CAPLEN: no cut after it (nor is the rest read)
        at = int(starts[complete])
        base, number, buf = base + at, number + complete, buf[at:]
        if not data:
            if not buf and len(out) > 1 and out[-1].start == base:  # (a cut at the end of the file: no piece)
                out.pop()
                out[-1] = out[-1]._replace(end=None)
            return out


def _cut(out: list[Piece], ends: np.ndarray, first: int, piece_bytes: int, piece_frames: int) -> None:
    """Cuts at the ends of records (file offsets `ends`, the first record's end being frame `first`'s
    start) wherever the piece begun last has reached its size."""
    while len(ends):
        start, frame = out[-1].start, out[-1].first
        k = frame + piece_frames - first if piece_frames else int(np.searchsorted(ends, start + piece_bytes))
        if k >= len(ends) or k < 0:
            return
        at = int(ends[k])
        out[-1] = out[-1]._replace(end=at)
        out.append(Piece(at, None, first + k))


def piece_batches(path: str, piece: Piece, size: int = BATCH_FRAMES) -> Iterator[FrameBatch]:
    """The frames of `piece` in batches of at most `size` frames (the last piece: then its CaptureError,
    if the file is damaged there, as `batches` raises it)."""
    info = CaptureInfo(path)
    with opened(path, info) as (stream, _fmt):
        head = stream.read(24)
        stream.seek(piece.start)
        bounded = stream if piece.end is None else _Bounded(stream, piece.end)
        for _base, batch in _pcap_batches(path, bounded, info, size, head, piece.start, piece.first):  # type: ignore[arg-type]
            yield batch


class _Bounded(io.RawIOBase):
    """A seekable stream that ends at file offset `end` (a piece's last record ends there)."""

    def __init__(self, stream: io.BufferedIOBase, end: int) -> None:
        super().__init__()
        self.stream = stream
        self.end = end

    def seekable(self) -> bool:
        return True

    def readable(self) -> bool:
        return True

    def tell(self) -> int:
        return self.stream.tell()

    def seek(self, offset: int, whence: int = 0) -> int:
        return self.stream.seek(offset, whence)

    def read(self, size: int = -1) -> bytes:
        left = max(0, self.end - self.stream.tell())
        return self.stream.read(left if size is None or size < 0 else min(size, left))
