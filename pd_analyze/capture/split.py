"""One classic pcap cut into pieces, each read on its own (by another process, or a Dask worker) into
exactly the batches one reader of the whole file (`batches`) makes of the same frames.

The cut points are batch boundaries of that reader, found by a walk of the file that reads it chunk for
chunk as `batches` does (the same 8 MiB reads from the same offsets, the record headers chained by their
lengths, no frame decoded): every cut is a record boundary by construction, never a guess from bytes that
look like a header, and a piece's reader starts with the chunk `batches` reads there, holding the same
bytes of the record that chunk begins with, so its chunks, batches, frame numbers and times are those of
`batches`, batch for batch. What follows the pieces (the engine) therefore sees the very batches of one
process. The walk stops cutting at the first damaged record (cut short, or longer than MAX_CAPLEN): the
last piece runs to the end of the file, and its reader meets that damage and raises the error `batches`
raises there (same text, same file offset).

pcapng and gzip-compressed captures are not cut here (a gzip stream cannot be entered in its middle; a
pcapng piece would need the section and interface blocks before it): `pieces` returns None for them, and
the caller reads them in one process (analysis.split has their batches decoded in parallel all the same).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from typing import BinaryIO, NamedTuple

import numpy as np

from pd_analyze.capture import pcap
from pd_analyze.capture.batches import BATCH_FRAMES, FrameBatch, _pcap_batches, _record_starts
from pd_analyze.capture.chunks import PIECES
from pd_analyze.capture.pcap import pcap_header
from pd_analyze.capture.raw import MAX_CAPLEN, CaptureError, CaptureInfo
from pd_analyze.capture.reader import opened

PIECE_BYTES = 8 << 20  # a piece is about one chunk of the batch reader: one worker's task, decoded at once


class Piece(NamedTuple):
    """Frames `first` .. `stop` - 1 (`stop` None: to the end of the file), which begin in the chunk `batches`
    reads at file offset `at` holding `lead` bytes of the record there, frame `number`."""

    first: int
    stop: int | None
    at: int
    lead: int
    number: int


class _Chunk(NamedTuple):
    at: int  # where `batches` reads it
    lead: int  # bytes of its first record it held before the read
    number: int  # its first frame
    starts: np.ndarray  # file offsets of the starts of its batches


def pieces(path: str, piece_bytes: int = PIECE_BYTES, piece_frames: int = 0,
           size: int = BATCH_FRAMES) -> list[Piece] | None:
    """The pieces of a plain (uncompressed) pcap read in batches of `size` frames, each about `piece_bytes`
    (or, when given, `piece_frames` frames or the next batch boundary after them: tests cut everywhere);
    None for any other capture, or one that cannot be opened."""
    info = CaptureInfo(path)
    try:
        with opened(path, info) as (stream, fmt):
            if fmt != "pcap" or info.compressed:
                return None
            little = pcap_header(path, stream.read(24))[0]
            chunks = _chunks(stream, struct.Struct("<8xI" if little else ">8xI").unpack_from, size)
    except (CaptureError, OSError):
        return None  # (its error is reported where it is read: in one process)
    return _cut(chunks, piece_bytes, piece_frames, size)


def _chunks(stream: BinaryIO, caplen_at: Callable, size: int) -> list[_Chunk]:
    """The chunks `batches` reads (batches._pcap_batches with chunks.ChunkReads on a seekable file), as far
    as no record is damaged; in each, where its batches begin."""
    out: list[_Chunk] = []
    want = PIECES * pcap._CHUNK
    at, rest, number = 24, 0, 1
    while True:
        stream.seek(at)
        buf = stream.read(rest + want)
        starts = _record_starts(buf, caplen_at)
        complete = int(np.searchsorted(starts, len(buf), "right")) - 1
        too_long = np.flatnonzero(np.diff(starts[:complete + 1]) - 16 > MAX_CAPLEN)
        good = int(too_long[0]) if too_long.size else complete
        if good:
            out.append(_Chunk(at, rest, number, at + starts[:good:size]))
        pos = int(starts[complete])
        if too_long.size or len(buf) < rest + want or not complete:
            return out  # damage, or the end of the data: the last piece reads on from here as `batches` does
        if len(buf) - pos >= 16 and caplen_at(buf, pos)[0] > MAX_CAPLEN:
            return out
        at, rest, number = at + pos, len(buf) - pos, number + complete


def _cut(chunks: list[_Chunk], piece_bytes: int, piece_frames: int, size: int) -> list[Piece]:
    """Pieces of whole batches: a cut at the first batch start past the size of the piece begun last."""
    out = [Piece(1, None, 24, 0, 1)]
    begun = 24  # the file offset of the piece begun last
    for chunk in chunks:
        for k, offset in enumerate(chunk.starts.tolist()):
            frame = chunk.number + k * size
            if frame > 1 and ((frame - out[-1].first >= piece_frames) if piece_frames else
                              (offset - begun >= piece_bytes // 2)):
                out[-1] = out[-1]._replace(stop=frame)
                out.append(Piece(frame, None, chunk.at, chunk.lead, chunk.number))
                begun = offset
    return out


def piece_batches(path: str, piece: Piece, size: int = BATCH_FRAMES) -> Iterator[FrameBatch]:
    """The batches of `piece`, those `batches(path, size)` makes of its frames (the last piece: then its
    CaptureError, if the file is damaged there, as `batches` raises it)."""
    info = CaptureInfo(path)
    with opened(path, info) as (stream, _fmt):
        head = stream.read(24)
        stream.seek(piece.at)
        for _base, batch in _pcap_batches(path, stream, info, size, head, 24, piece.number, piece.at, piece.lead):
            first = int(batch.number[0])
            if piece.stop is not None and first >= piece.stop:
                return
            if first >= piece.first:
                yield batch
