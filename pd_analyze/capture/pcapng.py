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
from pd_analyze.capture.raw import MAX_CAPLEN, CaptureError, CaptureInfo, RawFrame, peek

PCAPNG_SHB = 0x0A0D0D0A
_PCAPNG_BOM = 0x1A2B3C4D
_PCAPNG_MAX_BLOCK = MAX_CAPLEN + 65_536  # a packet block plus generous room for options


class _Interface(NamedTuple):
    linktype: int
    divisor: float
    offset: int
    snaplen: int


def pcapng_frames(path: str, stream: BinaryIO, info: CaptureInfo) -> Iterator[RawFrame]:
    pos = 0
    little = True
    ifaces: list[_Interface] = []
    number = 0
    last_ts = 0.0
    while True:
        head = _read_exact(path, stream, 8, pos, allow_eof=True)
        if not head:
            return
        if struct.unpack("<I", head[:4])[0] == PCAPNG_SHB:
            little = _shb_little(path, stream, pos)
            ifaces = []
        order = "<" if little else ">"
        btype, blen = struct.unpack(order + "II", head)
        if blen < 12 or blen % 4 or blen > _PCAPNG_MAX_BLOCK:
            raise CaptureError(path, f"pcapng block of type {btype:#x} has invalid length {blen}", pos)
        body = _read_exact(path, stream, blen - 8, pos)
        if struct.unpack(order + "I", body[-4:])[0] != blen:
            raise CaptureError(path, f"pcapng block of type {btype:#x}: trailing length differs "
                                     f"from {blen}", pos)
        block = head + body
        if btype == dpkt.pcapng.PCAPNG_BT_SHB:
            pass
        elif btype == dpkt.pcapng.PCAPNG_BT_IDB:
            ifaces.append(_interface(path, block, little, pos))
            info.linktypes.append(ifaces[-1].linktype)
        elif btype in (dpkt.pcapng.PCAPNG_BT_EPB, dpkt.pcapng.PCAPNG_BT_PB):
            if blen < 32:
                raise CaptureError(path, f"packet block of {blen} bytes, shorter than its 32-byte header", pos)
            iface_id, ts_high, ts_low, caplen = _packet_header(order, btype, block)
            if iface_id >= len(ifaces):
                raise CaptureError(path, f"packet block names interface {iface_id}, "
                                         f"only {len(ifaces)} described", pos)
            if caplen > blen - 28 - 4:
                raise CaptureError(path, f"packet block caplen {caplen} exceeds its block", pos)
            if caplen > MAX_CAPLEN:
                raise CaptureError(path, f"packet block caplen {caplen} exceeds {MAX_CAPLEN} bytes", pos)
            iface = ifaces[iface_id]
            number += 1
            last_ts = iface.offset + ((ts_high << 32) | ts_low) / iface.divisor
            yield RawFrame(number, last_ts, iface.linktype, block[28:28 + caplen], iface_id)
        elif btype == dpkt.pcapng.PCAPNG_BT_SPB:
            if not ifaces:
                raise CaptureError(path, "simple packet block before any interface", pos)
            if blen < 16:
                raise CaptureError(path, f"simple packet block of {blen} bytes, shorter than its 16-byte header",
                                   pos)
            orig_len = struct.unpack(order + "I", block[8:12])[0]
            iface = ifaces[0]
            caplen = min(orig_len, blen - 16, iface.snaplen or MAX_CAPLEN)
            if caplen > MAX_CAPLEN:
                raise CaptureError(path, f"simple packet block of {caplen} bytes exceeds {MAX_CAPLEN} bytes", pos)
            number += 1
            # An SPB carries no timestamp: Wireshark shows none; we keep the previous one so
            # capture-time timeouts stay monotonic.
            yield RawFrame(number, last_ts, iface.linktype, block[12:12 + caplen], 0)
        # every other block type (name resolution, statistics, custom, ...) is skipped
        pos += blen


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
    divisor, offset = 1e6, 0
    for opt in idb.opts:
        if opt.code == dpkt.pcapng.PCAPNG_OPT_IF_TSRESOL and opt.data:
            resol = opt.data[0]
            divisor = float(2 ** (resol & 0x7F) if resol & 0x80 else 10 ** (resol & 0x7F))
        elif opt.code == dpkt.pcapng.PCAPNG_OPT_IF_TSOFFSET and len(opt.data) == 8:
            offset = struct.unpack("<q" if little else ">q", opt.data)[0]
    return _Interface(idb.linktype, divisor, offset, idb.snaplen)


def _packet_header(order: str, btype: int, block: bytes) -> tuple[int, int, int, int]:
    if btype == dpkt.pcapng.PCAPNG_BT_EPB:
        return struct.unpack_from(order + "IIII", block, 8)
    # obsolete Packet Block: interface id and drops count are 16-bit each
    iface_id, _drops, ts_high, ts_low, caplen = struct.unpack_from(order + "HHIII", block, 8)
    return iface_id, ts_high, ts_low, caplen
