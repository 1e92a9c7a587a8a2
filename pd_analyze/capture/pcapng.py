"""pcapng files, walked block by block: several interfaces with their own link types and timestamp
resolutions, Enhanced and Simple Packet Blocks (dpkt's reader handles one interface and no Simple Packet
Blocks; its block classes still parse the interface descriptions), unknown blocks skipped."""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from typing import BinaryIO, NamedTuple

import dpkt
import dpkt.pcapng

from pd_analyze.capture.gzip_stream import read_failure
from pd_analyze.capture.raw import MAX_CAPLEN, PCAPNG_SHB, CaptureError, CaptureInfo, RawFrame, peek
from pd_analyze.model.times import resol_digits

_PCAPNG_BOM = 0x1A2B3C4D
_PCAPNG_MAX_BLOCK = MAX_CAPLEN + 65_536  # a packet block plus generous room for options


class _Interface(NamedTuple):
    linktype: int
    divisor: float
    offset: int
    snaplen: int
    resol: int = 6  # if_tsresol: 10^-resol s per unit, or 2^-(resol & 0x7F) with the 0x80 bit

    def ns(self, ticks: int) -> int:
        """A timestamp in nanoseconds since the epoch, exact for decimal units down to the nanosecond."""
        return clamp_ns(self.offset * 1_000_000_000 + ticks_ns(ticks, self.resol))


NS_LIMIT = (1 << 63) - 1  # a time beyond what an int64 of nanoseconds holds (after 2262) is kept at its edge


def clamp_ns(ns: int) -> int:
    return max(-NS_LIMIT, min(NS_LIMIT, ns))


def ticks_ns(ticks: int, resol: int) -> int:
    """Timestamp units of resolution `resol` (if_tsresol) in whole nanoseconds (finer units rounded down)."""
    if resol & 0x80:
        return ticks * 1_000_000_000 >> (resol & 0x7F)
    if resol <= 9:
        return ticks * 10 ** (9 - resol)
    return ticks // 10 ** (resol - 9)

class Section:
    """What a pcapng reader knows at a block: the section's byte order and interfaces, the frames so far."""

    __slots__ = ("ifaces", "last_ns", "last_ts", "little", "number")

    def __init__(self) -> None:
        self.little = True
        self.ifaces: list[_Interface] = []
        self.number = 0
        self.last_ts = 0.0
        self.last_ns = 0


def pcapng_frames(path: str, stream: BinaryIO, info: CaptureInfo) -> Iterator[RawFrame]:
    for section, block, packet in _walk(path, stream, info):
        if packet is not None:
            ts, linktype, start, caplen, iface_id, ns = packet
            yield RawFrame(section.number, ts, linktype, block[start:start + caplen], iface_id, 0, ns)


def _walk(path: str, stream: BinaryIO, info: CaptureInfo
          ) -> Iterator[tuple[Section, bytes, tuple[float, int, int, int, int, int] | None]]:
    """Every block of a pcapng file, read whole and checked, with its section and, for a packet,
    read_block's tuple (the section then counts it)."""
    pos = 0
    section = Section()
    while True:
        head = _read_exact(path, stream, 8, pos, allow_eof=True)
        if not head:
            return
        if struct.unpack("<I", head[:4])[0] == PCAPNG_SHB:
            section.little = _shb_little(path, stream, pos)
            section.ifaces = []
        blen = block_length(path, head, 0, section.little, pos)
        block = head + _read_exact(path, stream, blen - 8, pos)
        yield section, block, read_block(path, section, info, block, 0, pos)
        pos += blen


def block_length(path: str, buf: bytes, at: int, little: bool, pos: int) -> int:
    """The length of the block whose first 8 bytes are at buf[at:], checked (the block is at file offset pos)."""
    btype, blen = struct.unpack_from("<II" if little else ">II", buf, at)
    if blen < 12 or blen % 4 or blen > _PCAPNG_MAX_BLOCK:
        raise CaptureError(path, f"pcapng block of type {btype:#x} has invalid length {blen}", pos)
    return blen


def read_block(path: str, section: Section, info: CaptureInfo, buf: bytes, at: int,
               pos: int) -> tuple[float, int, int, int, int, int] | None:
    """The whole block at buf[at:] (its length checked), at file offset pos: a packet's (time, link type,
    offset of its data in buf, caplen, interface id, time in nanoseconds), counted in `section`; None for
    any other block (an interface description is learnt)."""
    order = "<" if section.little else ">"
    btype, blen = struct.unpack_from(order + "II", buf, at)
    if struct.unpack_from(order + "I", buf, at + blen - 4)[0] != blen:
        raise CaptureError(path, f"pcapng block of type {btype:#x}: trailing length differs "
                                 f"from {blen}", pos)
    if btype == dpkt.pcapng.PCAPNG_BT_SHB:
        pass
    elif btype == dpkt.pcapng.PCAPNG_BT_IDB:
        section.ifaces.append(_interface(path, buf[at:at + blen], section.little, pos))
        info.linktypes.append(section.ifaces[-1].linktype)
        info.digits = max(info.digits, resol_digits(section.ifaces[-1].resol))
    elif btype in (dpkt.pcapng.PCAPNG_BT_EPB, dpkt.pcapng.PCAPNG_BT_PB):
        if blen < 32:
            raise CaptureError(path, f"packet block of {blen} bytes, shorter than its 32-byte header", pos)
        iface_id, ts_high, ts_low, caplen = _packet_header(order, btype, buf, at)
        if iface_id >= len(section.ifaces):
            raise CaptureError(path, f"packet block names interface {iface_id}, "
                                     f"only {len(section.ifaces)} described", pos)
        if caplen > blen - 28 - 4:
            raise CaptureError(path, f"packet block caplen {caplen} exceeds its block", pos)
        if caplen > MAX_CAPLEN:
            raise CaptureError(path, f"packet block caplen {caplen} exceeds {MAX_CAPLEN} bytes", pos)
        iface = section.ifaces[iface_id]
        section.number += 1
        section.last_ts = iface.offset + ((ts_high << 32) | ts_low) / iface.divisor
        section.last_ns = iface.ns((ts_high << 32) | ts_low)
        return section.last_ts, iface.linktype, at + 28, caplen, iface_id, section.last_ns
    elif btype == dpkt.pcapng.PCAPNG_BT_SPB:
        if not section.ifaces:
            raise CaptureError(path, "simple packet block before any interface", pos)
        if blen < 16:
            raise CaptureError(path, f"simple packet block of {blen} bytes, shorter than its 16-byte header",
                               pos)
        orig_len = struct.unpack_from(order + "I", buf, at + 8)[0]
        iface = section.ifaces[0]
        caplen = min(orig_len, blen - 16, iface.snaplen or MAX_CAPLEN)
        if caplen > MAX_CAPLEN:
            raise CaptureError(path, f"simple packet block of {caplen} bytes exceeds {MAX_CAPLEN} bytes", pos)
        section.number += 1
        # An SPB carries no timestamp: Wireshark shows none; we keep the previous one so
        # capture-time timeouts stay monotonic.
        return section.last_ts, iface.linktype, at + 12, caplen, 0, section.last_ns
    # every other block type (name resolution, statistics, custom, ...) is skipped
    return None


def _read_exact(path: str, stream: BinaryIO, size: int, pos: int, allow_eof: bool = False) -> bytes:
    try:
        data = stream.read(size)
    except (OSError, EOFError, zlib.error) as exc:
        raise CaptureError(path, f"read failed ({read_failure(exc)})", pos) from None
    if allow_eof and not data:
        return b""
    if len(data) != size:
        raise CaptureError(path, f"block truncated ({len(data)} of {size} bytes present)", pos)
    return data


def _shb_little(path: str, stream: BinaryIO, pos: int) -> bool:
    try:
        bom = peek(stream, 4)
    except (OSError, EOFError, zlib.error) as exc:
        raise CaptureError(path, f"read failed ({read_failure(exc)})", pos) from None
    return shb_little(path, bom, pos)


def shb_little(path: str, bom: bytes, pos: int) -> bool:
    """The byte order of a section, from the byte-order magic after its header block's first 8 bytes."""
    if len(bom) < 4:
        raise CaptureError(path, "section header block truncated", pos)
    if struct.unpack("<I", bom)[0] == _PCAPNG_BOM:
        return True
    if struct.unpack(">I", bom)[0] == _PCAPNG_BOM:
        return False
    raise CaptureError(path, "section header block has no valid byte-order magic", pos)


def _interface(path: str, block: bytes, little: bool, pos: int) -> _Interface:
    try:
        idb = (dpkt.pcapng.InterfaceDescriptionBlockLE if little
               else dpkt.pcapng.InterfaceDescriptionBlock)(block)
    except (dpkt.NeedData, dpkt.UnpackError, struct.error) as exc:
        raise CaptureError(path, f"interface description block invalid ({exc})", pos) from None
    divisor, offset, resol = 1e6, 0, 6
    for opt in idb.opts:
        if opt.code == dpkt.pcapng.PCAPNG_OPT_IF_TSRESOL and opt.data:
            resol = opt.data[0]
            divisor = float(2 ** (resol & 0x7F) if resol & 0x80 else 10 ** (resol & 0x7F))
        elif opt.code == dpkt.pcapng.PCAPNG_OPT_IF_TSOFFSET and len(opt.data) == 8:
            offset = struct.unpack("<q" if little else ">q", opt.data)[0]
    return _Interface(idb.linktype, divisor, offset, idb.snaplen, resol)


def _packet_header(order: str, btype: int, buf: bytes, at: int) -> tuple[int, int, int, int]:
    if btype == dpkt.pcapng.PCAPNG_BT_EPB:
        return struct.unpack_from(order + "IIII", buf, at + 8)
    # obsolete Packet Block: interface id and drops count are 16-bit each
    iface_id, _drops, ts_high, ts_low, caplen = struct.unpack_from(order + "HHIII", buf, at + 8)
    return iface_id, ts_high, ts_low, caplen


class Block(NamedTuple):
    """One pcapng block as it is in the file, for writing a copy (annotate, extract). `number` is the frame
    number of a packet block (as `pcapng_frames` counts them), 0 for any other block."""

    raw: bytes
    btype: int
    little: bool
    number: int = 0
    ts: float = 0.0
    linktype: int = 0
    data_at: int = 0  # where the frame's bytes start in raw
    caplen: int = 0
    iface: int = 0
    divisor: float = 1e6  # the interface's timestamp units per second
    ts_offset: int = 0  # and its if_tsoffset, seconds
    stamp: int = -1  # a classic pcap record's time in those units (records.py); -1 for pcapng blocks
    orig_len: int = 0  # a classic pcap record's original length (records.py)


def pcapng_blocks(path: str, stream: BinaryIO, info: CaptureInfo) -> Iterator[Block]:
    """Every block of a pcapng file, checked and counted as `pcapng_frames` reads them."""
    for section, block, packet in _walk(path, stream, info):
        btype = struct.unpack_from("<I" if section.little else ">I", block)[0]
        if packet is None:
            yield Block(block, btype, section.little)
        else:
            ts, linktype, start, caplen, iface_id, _ns = packet
            iface = section.ifaces[iface_id]
            yield Block(block, btype, section.little, section.number, ts, linktype, start, caplen, iface_id,
                        iface.divisor, iface.offset)

