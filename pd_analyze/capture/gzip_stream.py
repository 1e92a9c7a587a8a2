"""gzip-compressed captures, inflated in bounded steps so every frame before damage is delivered."""

from __future__ import annotations

import io
import zlib
from typing import BinaryIO

GZIP_MAGIC = b"\x1f\x8b"


class _Gunzip(io.RawIOBase):
    """gzip decompression that delivers every byte before the trailer is checked.

    gzip.GzipFile raises on a CRC error in the same read that returns the file's last bytes, so
    the frames in them would be lost; here the 8-byte trailer is held back and checked on its own.
    Any error is raised only once every byte before it has been read. Each step inflates at most
    _GZIP_STEP bytes (a small, highly compressed file cannot blow up one read), and reads advance
    an offset instead of copying what is left, so reading is linear in the decompressed size.
    """

    def __init__(self, raw: BinaryIO) -> None:
        super().__init__()
        self.raw = raw
        self.zobj = zlib.decompressobj(16 + zlib.MAX_WBITS)
        self.pending = b""  # decompressed; pending[pos:] not yet returned
        self.pos = 0
        self.backlog = b""  # compressed input read but not yet inflated
        self.tail = b""  # compressed input held back: the last 8 bytes may be a trailer
        self.eof = False  # the raw stream is exhausted (tail moved to the backlog)
        self.done = False  # nothing more will be inflated
        self.error: BaseException | None = None

    def readable(self) -> bool:
        return True

    def _fill(self, want: int) -> None:
        while len(self.pending) - self.pos < want and not self.done:
            if self.backlog:
                self._inflate()
            elif not self.eof:
                chunk = self.raw.read(1 << 16)
                data = self.tail + chunk
                if chunk:
                    self.tail, self.backlog = data[-8:], data[:-8]
                else:
                    self.eof, self.tail, self.backlog = True, b"", data
            else:
                self.done = True
                if not self.zobj.eof and self.error is None:
                    self.error = EOFError("compressed file ended before the end-of-stream marker")
        if self.pos >= len(self.pending) and self.error is not None:
            error, self.error = self.error, None
            raise error

    def _inflate(self) -> None:
        if self.zobj.eof:  # after a member: a further member, or trailing garbage (ignored, as gzip does)
            if self.backlog[:2] != GZIP_MAGIC[:len(self.backlog[:2])]:
                self.done, self.backlog = True, b""
                return
            self.zobj = zlib.decompressobj(16 + zlib.MAX_WBITS)
        try:
            out = self.zobj.decompress(self.backlog, _GZIP_STEP)
        except zlib.error as exc:
            self.error, self.done, self.backlog = exc, True, b""  # raised once every byte before it is read
            return
        self.backlog = self.zobj.unused_data if self.zobj.eof else self.zobj.unconsumed_tail
        if out:
            self.pending = self.pending[self.pos:] + out
            self.pos = 0

    def read(self, size: int = -1) -> bytes:  # type: ignore[override]
        self._fill(size if size >= 0 else 1 << 62)
        end = len(self.pending) if size < 0 else min(len(self.pending), self.pos + size)
        out = self.pending[self.pos:end]
        self.pos = end
        return out

    def peek(self, size: int = 1) -> bytes:
        self._fill(size)
        return self.pending[self.pos:self.pos + size]


_GZIP_STEP = 1 << 20


def read_failure(exc: BaseException) -> str:
    """Why reading failed, in words (for the one-line error naming the byte offset)."""
    text = str(exc) or exc.__class__.__name__
    if isinstance(exc, EOFError):
        return f"compressed data ends early: {text}"
    if "data check" in text or "CRC" in text:
        return f"gzip CRC mismatch, the file is corrupt: {text}"
    return f"corrupt compressed data: {text}" if isinstance(exc, zlib.error) else text
