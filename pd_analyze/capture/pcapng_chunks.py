"""pcapng read a chunk at a time for the batch reader: the runs of ordinary Enhanced Packet Blocks become
numpy columns at once; every other block, and every block a check refuses, is read by pcapng.read_block,
as pcapng_frames reads it, so that both readers yield the same frames and tell the same damage.

A chunk's blocks are found by a loop of one unpack and one append each (the block lengths chain them);
numpy then reads their headers and picks the ordinary ones: type EPB, a valid length repeated in the
trailer, caplen within the block and the limit. Their interface ids are checked against the section's
interfaces run by run (an interface description between two runs adds one).

A frame whose time its nanoseconds do not give as tshark prints frame.time_epoch (a Simple Packet Block, which
has none; units in powers of two or finer than a nanosecond, rounded down in `ns`; a time clamped to int64)
is listed with its record's stamp (`Stamps`), so the batches' frame.time_epoch is the record's exactly.
"""

from __future__ import annotations

import struct
from array import array
from collections.abc import Callable, Iterator
from typing import BinaryIO

import numpy as np

from pd_analyze.capture.chunks import ChunkReads
from pd_analyze.capture.pcapng import (
    _PCAPNG_MAX_BLOCK,
    NS_LIMIT,
    PCAPNG_SHB,
    Section,
    block_length,
    clamp_ns,
    read_block,
    shb_little,
    ticks_ns,
)
from pd_analyze.capture.pcapng_write import BT_SPB
from pd_analyze.capture.raw import MAX_CAPLEN, CaptureError, CaptureInfo

# buf, number, ts, linktype, start, caplen, iface, ns: the columns of FrameBatch, over one chunk
Columns = tuple[bytes, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
# frame number: (block type, units per second, offset in seconds, stamp in those units), as output.frame_view's
# record_time reads a record; only the frames whose `ns` is not that time exactly
Stamps = dict[int, tuple[int, float, int, int]]
Packet = tuple[float, int, int, int, int, int]  # as read_block returns it

_EPB = 6
_REWALKS = 16  # byte-order changes in a chunk walked again; beyond, the chunk is read block by block
_LENGTH = {True: struct.Struct("<4xI").unpack_from, False: struct.Struct(">4xI").unpack_from}
_SHB_AT = struct.Struct("<I").unpack_from


def pcapng_columns(path: str, stream: BinaryIO, info: CaptureInfo) -> Iterator[tuple[Columns, Stamps]]:
    """The frames of a pcapng stream (standing at its first byte) as columns, a chunk at a time, with the
    stamps of its frames whose `ns` is not their record's time (module docstring); a damaged file: the
    frames before the damage, then the CaptureError pcapng_frames raises."""
    section = Section()
    reads = ChunkReads(path, stream, 0)
    buf, base = b"", 0  # base: the file offset of buf[0], always a block's start
    while True:
        chunk = _Chunk(path, section, info, buf, base)
        try:
            pos = chunk.read()
        except CaptureError:
            if chunk.count():
                yield chunk.columns(), chunk.stamps
            raise
        if chunk.count():
            yield chunk.columns(), chunk.stamps
        rest, at = len(buf) - pos, base + pos
        buf, base = reads.chunk(at, buf[pos:]), at
        if len(buf) == rest:  # nothing more came
            _at_end(path, section, buf, at, reads, info.compressed)
            return


class _Chunk:
    """The blocks complete in one buffer, read into columns (fast runs) and packets (one by one)."""

    def __init__(self, path: str, section: Section, info: CaptureInfo, buf: bytes, base: int) -> None:
        self.path = path
        self.section = section
        self.info = info
        self.buf = buf
        self.base = base
        self.first = section.number + 1  # the chunk's first frame
        self.segments: list[tuple[np.ndarray, ...]] = []  # (ts, linktype, start, caplen, iface) in frame order
        self.packets: list[Packet] = []  # read one by one since the last segment
        self.stamps: Stamps = {}

    def count(self) -> int:
        return self.section.number + 1 - self.first

    def read(self) -> int:
        """Reads every block complete in buf; returns the offset of the first one that is not."""
        pos, walks = 0, 0
        while walks <= _REWALKS:
            pos, again = self._walk(pos)
            if not again:
                return pos
            walks += 1
        while (after := self._block(pos)) is not None:  # many byte-order changes (a hostile file)
            pos = after
        return pos

    def _walk(self, pos: int) -> tuple[int, bool]:
        """The blocks from pos in the section's byte order, up to the first incomplete one (its offset,
        False) or to a section header that changes the byte order (the offset after it, True)."""
        buf, section = self.buf, self.section
        little = section.little
        starts = _block_starts(buf, pos, _LENGTH[little])
        complete = int(np.searchsorted(starts, len(buf), "right")) - 1  # blocks whose end is in buf
        st = starts[:complete]
        blen = np.diff(starts[:complete + 1])
        # Blocks start at multiples of 4 in buf as long as lengths are valid (a multiple of 4): the header
        # words are read through one uint32 view. Past an invalid length the words are garbage, but that
        # block is read by read_block first, which refuses it.
        words = np.frombuffer(buf, "<u4" if little else ">u4", len(buf) // 4)
        index = st >> 2

        def word(k: int) -> np.ndarray:
            return np.take(words, index + k, mode="clip")  # clip: a short block's header is not read

        btype, iface, high, low, caplen = word(0), word(2), word(3), word(4), word(5)
        trailer = np.take(words, (st + blen - 4) >> 2, mode="clip")
        ordinary = ((btype == _EPB) & (blen >= 32) & (blen % 4 == 0) & (blen <= _PCAPNG_MAX_BLOCK)
                    & (trailer == blen) & (caplen <= blen - 32) & (caplen <= MAX_CAPLEN))
        done = 0
        # every other block in order, then the first incomplete one (complete after all if it is a section
        # header in the other byte order, whose length the walk misread)
        for event in [*np.flatnonzero(~ordinary).tolist(), complete]:
            if event > done:
                run = slice(done, event)
                self._run(st[run], iface[run], high[run], low[run], caplen[run])
            at = int(starts[event])
            after = self._block(at)
            if after is None:
                return at, False
            if section.little != little or event == complete:
                return after, True  # a section in the other byte order: walk again from there
            done = event + 1
        return pos, True  # not reached: the last event returns

    def _run(self, st: np.ndarray, iface: np.ndarray, high: np.ndarray, low: np.ndarray,
             caplen: np.ndarray) -> None:
        """Ordinary EPBs: their columns, up to one naming an interface not described (refused as
        read_block refuses it)."""
        ifaces = self.section.ifaces
        unknown = np.flatnonzero(iface >= len(ifaces))
        stop = int(unknown[0]) if unknown.size else len(st)
        if stop:
            ids = iface[:stop]
            linktype = np.array([i.linktype for i in ifaces], np.int32)[ids]
            divisor = np.array([i.divisor for i in ifaces], np.float64)[ids]
            offset = np.array([float(i.offset) for i in ifaces], np.float64)[ids]
            ticks = (high[:stop].astype(np.uint64) << np.uint64(32)) | low[:stop]
            # as read_block: offset + ticks / divisor, each int made a float (rounded alike) before the division
            ts = offset + ticks.astype(np.float64) / divisor
            ns = _ns(ifaces, ids, ticks)
            inexact = np.array([not _exact(i.resol) for i in ifaces], bool)[ids] | (np.abs(ns) == NS_LIMIT)
            for k in np.flatnonzero(inexact).tolist():
                i = ifaces[int(ids[k])]
                self.stamps[self.section.number + 1 + k] = (_EPB, i.divisor, i.offset, int(ticks[k]))
            self._flush()
            self.segments.append((ts, linktype, st[:stop] + 28, caplen[:stop].astype(np.int64), ids.astype(np.int32),
                                  ns))
            self.section.number += stop
            self.section.last_ts = float(ts[-1])
            self.section.last_ns = int(ns[-1])
        if unknown.size:
            self._block(int(st[stop]))
            raise AssertionError("read_block accepted an EPB naming an unknown interface")

    def _block(self, at: int) -> int | None:
        """The block at buf[at:] read as pcapng_frames reads it; the offset after it, None if it is not
        complete in buf (nothing of it is kept then)."""
        buf, section, pos = self.buf, self.section, self.base + at
        if len(buf) - at < 8:
            return None
        if _SHB_AT(buf, at)[0] == PCAPNG_SHB:
            if len(buf) - at < 12:
                return None
            section.little = shb_little(self.path, buf[at + 8:at + 12], pos)
            section.ifaces = []
        blen = block_length(self.path, buf, at, section.little, pos)
        if len(buf) - at < blen:
            return None
        packet = read_block(self.path, section, self.info, buf, at, pos)
        if packet is not None:
            self.packets.append(packet)
            btype = struct.unpack_from("<I" if section.little else ">I", buf, at)[0]
            iface = section.ifaces[packet[4]]
            if btype == BT_SPB:
                self.stamps[section.number] = (BT_SPB, iface.divisor, iface.offset, 0)
            elif not _exact(iface.resol) or abs(packet[5]) == NS_LIMIT:
                high, low = struct.unpack_from("<II" if section.little else ">II", buf, at + 12)
                self.stamps[section.number] = (btype, iface.divisor, iface.offset, (high << 32) | low)
        return at + blen

    def _flush(self) -> None:
        if self.packets:
            ts, linktype, start, caplen, iface, ns = zip(*self.packets, strict=True)
            self.segments.append((np.array(ts, np.float64), np.array(linktype, np.int32), np.array(start, np.int64),
                                  np.array(caplen, np.int64), np.array(iface, np.int32), np.array(ns, np.int64)))
            self.packets = []

    def columns(self) -> Columns:
        self._flush()
        ts, linktype, start, caplen, iface, ns = (np.concatenate(c) for c in zip(*self.segments, strict=True))
        number = np.arange(self.first, self.first + len(ts), dtype=np.int64)
        return self.buf, number, ts, linktype, start, caplen, iface, ns


def _exact(resol: int) -> bool:
    """Units of 10^-resol s down to the nanosecond: `ns` holds a stamp exactly."""
    return not resol & 0x80 and resol <= 9


def _ns(ifaces: list, ids: np.ndarray, ticks: np.ndarray) -> np.ndarray:
    """Packet times in nanoseconds, exactly as _Interface.ns gives them (vectorised for decimal units of a
    nanosecond or coarser when the products fit 62 bits; Python integers otherwise, which cannot overflow)."""
    resol = np.array([i.resol for i in ifaces], np.int64)[ids]
    offset = np.array([i.offset for i in ifaces], np.int64)[ids]
    if not len(ticks):
        return np.zeros(0, np.int64)
    if bool(np.all(resol <= 9)):
        scale = np.array([10 ** (9 - r) for r in range(10)], np.int64)[resol]
        if int(ticks.max()) * int(scale.max()) < 1 << 62 and bool(np.all(np.abs(offset) < 1 << 30)):
            return offset * 1_000_000_000 + ticks.astype(np.int64) * scale
    return np.array([clamp_ns(o * 1_000_000_000 + ticks_ns(t, r)) for o, t, r in
                     zip(offset.tolist(), ticks.tolist(), resol.tolist(), strict=True)], np.int64)


def _block_starts(buf: bytes, pos: int, length_at: Callable[[bytes, int], tuple[int, ...]]) -> np.ndarray:
    """Offsets of the blocks that follow each other from buf[pos], as far as their lengths can be read;
    the last is where the walk ended (fewer than 8 bytes there, or beyond buf). A length of 0 steps 4
    bytes, so the walk always ends (that block is refused before anything after it is read)."""
    starts = array("q")
    append = starts.append
    try:
        while True:
            append(pos)
            pos += length_at(buf, pos)[0] or 4
    except struct.error:
        pass
    return np.frombuffer(starts, np.int64)


def _at_end(path: str, section: Section, rest: bytes, at: int, reads: ChunkReads, compressed: bool) -> None:
    """The data ends in the block at `at` (`rest`: its bytes): what pcapng_frames says there, whose reads
    of 8 bytes and then of the block's rest come up short (block truncated), or, finding no byte at
    all, meet the failure of a gzip stream. A failing disk is told where the data stopped."""
    failure = reads.failure is not None
    if failure and (not compressed or not rest):
        raise reads.failed(at)
    if not rest:
        return
    if len(rest) < 8:
        raise CaptureError(path, f"block truncated ({len(rest)} of 8 bytes present)", at)
    if _SHB_AT(rest, 0)[0] == PCAPNG_SHB:
        if len(rest) == 8 and failure:
            raise reads.failed(at)
        section.little = shb_little(path, rest[8:12], at)
    blen = block_length(path, rest, 0, section.little, at)
    if len(rest) == 8 and failure:
        raise reads.failed(at)
    raise CaptureError(path, f"block truncated ({len(rest) - 8} of {blen - 8} bytes present)", at)
