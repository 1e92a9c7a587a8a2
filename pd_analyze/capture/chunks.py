"""Large reads for the batch reader that meet the end of the data and read failures where the per-frame
readers meet them, so that both tell a damaged file alike."""

from __future__ import annotations

import zlib
from typing import BinaryIO

from pd_analyze.capture import pcap
from pd_analyze.capture.gzip_stream import read_failure
from pd_analyze.capture.raw import CaptureError

PIECES = 8  # a chunk is this many of pcap_frames' reads (8 MiB): per-chunk costs vanish, memory stays small


class ChunkReads:
    """A capture's data a chunk at a time: reads of pcap._CHUNK bytes, each from where the last one ended,
    PIECES at a time, the reads pcap_frames makes, so both see the same reads succeed, come up short or
    fail. A failure is held back (`failure`) until the data before it is used up: the per-frame readers
    meet it only then.

    A seekable file is read again from the block that waits for more data, in one read that ends where
    one of pcap_frames' reads would end: no copy of the chunk to join its pieces and that block's first
    bytes (two copies cost as much as the walk). Only when such a read fails are the pieces read one by one."""

    def __init__(self, path: str, stream: BinaryIO, origin: int) -> None:
        self.path = path
        self.stream = stream
        self.short = False  # the last read returned less than asked: the data ends (or fails) after it
        self.failure: BaseException | None = None
        self.shift: int | None = None  # stream position minus data offset; None: not seekable
        try:
            if stream.seekable():
                self.shift = stream.tell() - origin
        except (OSError, ValueError):
            pass

    def chunk(self, at: int, rest: bytes) -> bytes:
        """The data from `at`, the start of the block waiting for more: `rest`, its bytes at hand, and what
        the next reads bring; nothing more at the end of the data or once a read has failed."""
        if self.failure is not None:
            return rest
        piece = pcap._CHUNK
        if self.shift is not None:
            want = len(rest) + PIECES * piece
            try:
                self.stream.seek(at + self.shift)
                data = self.stream.read(want)
            except (OSError, EOFError, zlib.error):
                self.stream.seek(at + len(rest) + self.shift)  # where the pieces go on
            else:
                self.short = len(data) < want
                return data
        parts = [rest]
        self.short = False
        for _ in range(PIECES):
            try:
                data = self.stream.read(piece)
            except (OSError, EOFError, zlib.error) as exc:
                self.failure = exc
                break
            parts.append(data)
            if len(data) < piece:
                self.short = True
                break
        return b"".join(parts)

    def failed(self, at: int) -> CaptureError:
        """The read failure, told at `at`: the start of the block that needed the read."""
        assert self.failure is not None
        return CaptureError(self.path, f"read failed ({read_failure(self.failure)})", at)
