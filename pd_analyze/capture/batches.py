"""Captures read as batches of frames: one buffer and numpy columns per batch, for the columnar report path.

`batches(path)` yields the same frames as `capture.frames(path)` (same numbers, times, link types, bytes,
the same CaptureError after every good frame), a batch at a time: frame i of a batch is
`batch.buf[batch.start[i] : batch.start[i] + batch.caplen[i]]`.

Both formats, gzip-compressed or not, are read in chunks of 8 MiB, each the `buf` of its batches (frames
located by `start`, no copy of a frame): a tight loop chains the record (pcap) or block (pcapng) headers
by their lengths, numpy reads the rest of the headers and checks them; pcapng's other blocks, and any
block a check refuses, go through the per-frame reader's own code (pcapng_chunks). Damage is told as
capture.frames tells it: the chunks follow its reads (chunks.ChunkReads). Memory: a chunk, its columns
and what the caller keeps of the batches.
"""

from __future__ import annotations

import struct
from array import array
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import BinaryIO

import numpy as np

from pd_analyze.capture import pcap
from pd_analyze.capture.chunks import ChunkReads
from pd_analyze.capture.pcap import divisor_digits, pcap_header
from pd_analyze.capture.raw import MAX_CAPLEN, CaptureError, CaptureInfo, RawFrame
from pd_analyze.capture.reader import opened
from pd_analyze.model.times import DEFAULT_DIGITS, NS

BATCH_FRAMES = 16_384  # frames per batch by default: a batch of full-size frames about 25 MB; 65,536 cost as much CPU
# and held ~35 MB more at the peak of a part (200,000 fault-rich frames: 224 -> 188 MB for the engine alone)
# Bytes of frames given one by one gathered into one batch: the frames and the batch's copy of them are held
# at once, so a flood of full-size frames is batched by this rather than by the count.
FRAME_BATCH_BYTES = 4 << 20


@dataclass(slots=True)
class FrameBatch:
    """Consecutive frames of one capture as columns over one buffer."""

    buf: bytes  # the bytes of every frame of the batch (and possibly more, e.g. pcap record headers)
    number: np.ndarray  # int64: frame numbers, as capture.frames numbers them (1-based)
    ts: np.ndarray  # float64: seconds since the epoch, the same float as RawFrame.ts
    linktype: np.ndarray  # int32: link type of each frame's interface
    start: np.ndarray  # int64: offset of each frame's first byte in buf
    caplen: np.ndarray  # int64: bytes captured of each frame
    iface: np.ndarray  # int32: pcapng interface id (0 for pcap)
    # int64: the same times exactly, in nanoseconds since the epoch (as the file's integer units give them;
    # a float of seconds resolves only about 0.24 us today): every duration and deadline is computed on these
    ns: np.ndarray
    # decimals of a second the capture's times carry (CaptureInfo.digits as far as the file was read): the
    # tables' files write its times and durations with as many (model.times)
    digits: int = DEFAULT_DIGITS
    # the frames whose time `ns` does not give as their record holds it (a pcapng's Simple Packet Blocks, units
    # in powers of two or finer than a nanosecond): frame -> their record's stamp (pcapng_chunks.Stamps)
    stamps: dict[int, tuple[int, float, int, int]] | None = None

    def __len__(self) -> int:
        return len(self.number)

    def part(self, start: int, stop: int) -> FrameBatch:
        """Frames start..stop-1, over the same buffer."""
        if start == 0 and stop >= len(self):
            return self
        return FrameBatch(self.buf, self.number[start:stop], self.ts[start:stop], self.linktype[start:stop],
                          self.start[start:stop], self.caplen[start:stop], self.iface[start:stop], self.ns[start:stop],
                          self.digits, self.stamps)

    def raw_frame(self, i: int) -> RawFrame:
        """Frame i as the per-frame dissector takes it."""
        start = int(self.start[i])
        return RawFrame(int(self.number[i]), float(self.ts[i]), int(self.linktype[i]),
                        bytes(self.buf[start:start + int(self.caplen[i])]), int(self.iface[i]))


def frame_batches(frames: Iterable[RawFrame], size: int = BATCH_FRAMES) -> Iterator[FrameBatch]:
    """Frames given one by one (a generator's, a fuzzer's) as batches of at most `size` frames and about
    FRAME_BATCH_BYTES. A frame's time is its `ns` where the reader gave it, else its float time taken to the
    microsecond (what a float of seconds since the epoch holds exactly); the batch's resolution is 6 decimals
    of a second, or 9 where a frame's nanoseconds need them (frames declare none)."""
    part: list[RawFrame] = []
    held = 0
    for frame in frames:
        if frame.run:  # a run of skipped frames: its frames as empty Ethernet frames would count the same
            raise ValueError("frame_batches takes frames, not runs of skipped frames (capture.frames ip_only)")
        part.append(frame)
        held += len(frame.data)
        if len(part) >= size or held >= FRAME_BATCH_BYTES:
            batch = _of_frames(part)
            part, held = [], 0
            yield batch
            del batch  # not held while the next batch gathers
    if part:
        yield _of_frames(part)


def _of_frames(frames: list[RawFrame]) -> FrameBatch:
    lengths = np.array([len(f.data) for f in frames], np.int64)
    start = np.zeros(len(frames), np.int64)
    np.cumsum(lengths[:-1], out=start[1:])
    ns = np.array([_frame_ns(f) for f in frames], np.int64)
    return FrameBatch(b"".join(f.data for f in frames), np.array([f.number for f in frames], np.int64),
                      np.array([f.ts for f in frames], np.float64), np.array([f.linktype for f in frames], np.int32),
                      start, lengths, np.array([f.iface for f in frames], np.int32), ns,
                      9 if np.any(ns % 1000) else 6)


_NS_EDGE = (1 << 62)  # a time beyond this (hostile input) is kept at the edge


def _frame_ns(frame: RawFrame) -> int:
    if frame.ns is not None:
        ns = frame.ns
    elif frame.ts == frame.ts:
        ns = round(max(-1e13, min(1e13, frame.ts)) * 1e6) * 1000  # (an infinite time kept at the edge too)
    else:
        return 0
    return max(-_NS_EDGE, min(_NS_EDGE, ns))


def batches(path: str, size: int = BATCH_FRAMES, info: CaptureInfo | None = None) -> Iterator[FrameBatch]:
    """The frames of a capture (`-`: standard input) in batches of at most `size` frames.

    A damaged file: every good frame is yielded (the last batch may be short), then CaptureError."""
    if size < 1:
        raise ValueError(f"batch size {size}: must be at least 1")
    info = info or CaptureInfo(path)
    with opened(path, info) as (stream, fmt):
        if fmt == "pcap":
            for _base, batch in _pcap_batches(path, stream, info, size, stream.read(24), 24, 1):
                yield batch
        else:
            from pd_analyze.capture.pcapng_chunks import pcapng_columns  # here: it loads dpkt, a pcap does not

            for columns, stamps in pcapng_columns(path, stream, info):
                chunk = FrameBatch(*columns, info.digits, stamps or None)
                for i in range(0, len(chunk), size):
                    yield chunk.part(i, i + size)


def _pcap_batches(path: str, stream: BinaryIO, info: CaptureInfo, size: int, head: bytes, origin: int,
                  number: int, begin: int | None = None, lead: int = 0) -> Iterator[tuple[int, FrameBatch]]:
    """Batches of a classic pcap whose records begin at byte `origin` (where `stream` stands), each with
    the file offset of its buf. `begin` (where `stream` then stands), `number` and `lead`: begin with the
    chunk a reader from `origin` reads at `begin`, where it holds `lead` bytes of the record there (capture.split:
    a piece read as the whole file's reader reads it, chunk for chunk).

    A chunk's records are found by a loop of one unpack and one append each, its complete records
    yielded, the incomplete rest carried into the next chunk. Damage is told exactly as pcap_frames tells
    it: chunks are whole numbers of its reads (`ChunkReads`), and at the end of the data `_ends_unread`
    knows which of its reads would have come next."""
    little, divisor, linktype = pcap_header(path, head)
    info.linktypes = [linktype]
    info.digits = divisor_digits(divisor)
    caplen_at = struct.Struct("<8xI" if little else ">8xI").unpack_from
    word = np.dtype("<u4" if little else ">u4")
    start = origin if begin is None else begin
    reads = ChunkReads(path, stream, start)
    buf, base = stream.read(lead) if lead else b"", start  # base: the file offset of buf[0], always a record's start
    while True:
        starts = _record_starts(buf, caplen_at)
        complete = int(np.searchsorted(starts, len(buf), "right")) - 1  # records whose end is in buf
        caplen = np.diff(starts[:complete + 1]) - 16
        too_long = np.flatnonzero(caplen > MAX_CAPLEN)
        good = int(too_long[0]) if too_long.size else complete
        if good:
            chunk = _columns(buf, starts[:good], caplen[:good], word, divisor, linktype, number)
            number += good
            for i in range(0, good, size):
                yield base, chunk.part(i, i + size)
        if too_long.size:
            raise _too_long(path, int(caplen[good]), base + int(starts[good]))
        pos = int(starts[complete])  # the first record not complete in buf, or its end
        rest, at = len(buf) - pos, base + pos
        claimed = 0
        if rest >= 16:  # pcap_frames refuses a record longer than the limit before reading its data
            claimed = caplen_at(buf, pos)[0]
            if claimed > MAX_CAPLEN:
                raise _too_long(path, claimed, at)
        if rest and reads.short and _ends_unread(origin, at, base + len(buf), rest):
            raise _truncated(path, rest, claimed, at)
        buf, base = reads.chunk(at, buf[pos:]), at
        if len(buf) == rest:  # nothing more came
            if reads.failure is not None:
                raise reads.failed(at)
            if rest:
                raise _truncated(path, rest, claimed, at)
            return


def _ends_unread(origin: int, at: int, end: int, rest: int) -> bool:
    """Whether pcap_frames stops at the record at `at`, cut by the end of the data at `end`, without
    reading again (its error is then the cut record, not a failure of that read; on a gzip stream the two
    differ). Its reads start at origin + k * pcap._CHUNK; `first` is the first of those at or after `at`.
    Before `first` it holds the record's first bytes; if those are not a header it reads at `first` for
    one (when `first` is before the end, that read brings all that is left); with a header it reads the
    record's data, once (pcap._CHUNK exceeds any record) and gives up if that is not enough."""
    piece = pcap._CHUNK
    first = origin + -(-(at - origin) // piece) * piece
    return first < end and (rest < 16 or first - at >= 16)


def _record_starts(buf: bytes, caplen_at: Callable[[bytes, int], tuple[int, ...]]) -> np.ndarray:
    """Offsets of the records that follow each other from buf[0], as far as their lengths can be read;
    the last is where the walk ended: fewer than 12 bytes (or none) there, or beyond the end of buf.

    About 0.1 us a record: per record one unpack and one append, no check (an exception ends the loop);
    the caller finds the records that are complete and bounds their lengths, with numpy."""
    starts = array("q")
    append = starts.append
    unpack = caplen_at  # local: the loop looks it up once per record
    pos = 0
    try:
        while True:
            append(pos)
            pos += 16 + unpack(buf, pos)[0]
    except struct.error:
        pass
    return np.frombuffer(starts, np.int64)


def _columns(buf: bytes, starts: np.ndarray, caplen: np.ndarray, word: np.dtype, divisor: float,
             linktype: int, number: int) -> FrameBatch:
    """The columns of complete records at `starts` of buf."""
    count = len(starts)
    # records start at any byte: their times are gathered byte by byte (8 of each header), then read as
    # two words; per record this costs less than a uint32 view per alignment and boolean masks
    stamps = np.take(np.frombuffer(buf, np.uint8), np.add.outer(starts, _STAMP_BYTES)).view(word)
    sec, frac = stamps[:, 0], stamps[:, 1]
    ts = sec.astype(np.float64) + frac.astype(np.float64) / divisor  # as pcap_frames: sec + frac / divisor
    ns = sec.astype(np.int64) * NS + frac.astype(np.int64) * (NS // int(divisor))
    # A pcap link type is 32 bits, FCS flags on top: above 2^31 (hostile files) it is kept as its bit pattern
    lt = np.full(count, linktype - (1 << 32) if linktype >= 1 << 31 else linktype, np.int32)
    return FrameBatch(buf, np.arange(number, number + count, dtype=np.int64), ts, lt, starts + 16,
                      caplen, np.zeros(count, np.int32), ns, divisor_digits(divisor))


_STAMP_BYTES = np.arange(8, dtype=np.int64)  # a record header's seconds and fraction of a second


def _too_long(path: str, caplen: int, at: int) -> CaptureError:
    return CaptureError(path, f"record length {caplen} exceeds {MAX_CAPLEN} bytes (corrupt record header)", at)


def _truncated(path: str, rest: int, caplen: int, at: int) -> CaptureError:
    if rest < 16:
        return CaptureError(path, f"record header truncated ({rest} of 16 bytes present)", at)
    return CaptureError(path, f"record data truncated ({rest - 16} of {caplen} bytes present)", at)
