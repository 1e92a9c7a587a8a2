"""Capture files, streamed one frame at a time.

pcap (microsecond and nanosecond magic, both byte orders): dpkt parses the file header and the records
are cut from large chunks (see _pcap_frames for why); pcapng is walked block by block here because it
carries several interfaces with their own link types and timestamp resolutions, and Simple Packet
Blocks, which dpkt's pcapng reader does not handle (dpkt's block classes parse the interface blocks).
Either may be gzip-compressed; the format is found by magic, never by file name.

A damaged file raises CaptureError naming the byte offset, after every frame before the damage has
been yielded. No length field read from a file is trusted for an allocation: every record is
bounded by MAX_CAPLEN before it is read.
"""

from __future__ import annotations

import io
import os
import struct
import sys
import zlib
from collections.abc import Callable, Iterator
from typing import BinaryIO, NamedTuple

import dpkt
import dpkt.pcap
import dpkt.pcapng

from pd_analyze.model.values import IP_ETHERTYPES, LINKTYPE_ETHERNET

MAX_CAPLEN = 262_144  # the largest snaplen tools write (tcpdump, Wireshark)
_PCAPNG_MAX_BLOCK = MAX_CAPLEN + 65_536  # a packet block plus generous room for options
_GZIP_MAGIC = b"\x1f\x8b"
_PCAPNG_SHB = 0x0A0D0D0A
_PCAPNG_BOM = 0x1A2B3C4D
_PCAP_MAGICS = {
    b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\xc3\xd4",  # microseconds, LE / BE
    b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\x3c\x4d",  # nanoseconds, LE / BE
}


class CaptureError(Exception):
    """A capture cannot be read (further); `offset` is the byte offset of the damage, if known."""

    def __init__(self, path: str, message: str, offset: int | None = None) -> None:
        self.path = path
        self.offset = offset
        self.reason = message
        where = f"byte {offset}: " if offset is not None else ""
        super().__init__(f"{path}: {where}{message}")


class RawFrame(NamedTuple):
    """A frame; or, from an `ip_only` reader, a run of `run` skipped frames ending at `number`."""

    number: int
    ts: float
    linktype: int
    data: bytes
    iface: int = 0
    run: int = 0  # > 0: this record stands for that many Ethernet frames without IPv4 (data is empty)




class CaptureInfo:
    """What the reader learnt about the file: format, compression, interfaces."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.format = ""
        self.compressed = False
        self.linktypes: list[int] = []


def frames(path: str, info: CaptureInfo | None = None, ip_only: bool = False) -> Iterator[RawFrame]:
    """Every frame of a capture file (`-` = standard input), numbered from 1.

    `ip_only`: consecutive Ethernet frames whose EtherType is neither IPv4 nor a VLAN tag (cyclic PN-RT,
    LLDP, ARP: most of a PROFINET capture) may come as one `run` record instead of a frame each, so
    the analysis skips them without an object per frame (classic pcap; other formats ignore it)."""
    info = info or CaptureInfo(path)
    stream = _open(path)
    try:
        try:
            head = _peek(stream, 4)
        except OSError as exc:  # e.g. EIO from a failing disk or a special file
            raise CaptureError(path, f"read failed ({exc.strerror or exc})", 0) from None
        if head[:2] == _GZIP_MAGIC:
            info.compressed = True
            stream = _Gunzip(stream)  # type: ignore[assignment]
            try:
                head = _peek(stream, 4)
            except (OSError, EOFError, zlib.error) as exc:
                raise CaptureError(path, f"gzip data unreadable ({exc})", 0) from None
        reader = _reader_for(path, head, info)
        try:
            yield from reader(path, stream, info, ip_only=ip_only) if reader is _pcap_frames else \
                reader(path, stream, info)
        except CaptureError as exc:
            if not info.compressed or exc.offset is None:
                raise
            raise CaptureError(path, f"{exc.reason} (offset in the decompressed data)", exc.offset) from None
    finally:
        stream.close()


def _open(path: str) -> BinaryIO:
    if path == "-":
        return sys.stdin.buffer
    if os.path.isdir(path):
        raise CaptureError(path, "is a directory, not a capture file")
    try:
        return open(path, "rb")
    except FileNotFoundError:
        raise CaptureError(path, "no such file") from None
    except PermissionError:
        raise CaptureError(path, "permission denied (check the file's read rights)") from None
    except OSError as exc:
        raise CaptureError(path, f"cannot open ({exc.strerror})") from None


def _peek(stream: BinaryIO, size: int) -> bytes:
    peek = getattr(stream, "peek", None)
    data = peek(size)[:size] if peek else b""
    return data


def _reader_for(path: str, head: bytes, info: CaptureInfo):  # noqa: ANN202
    if len(head) == 0:
        raise CaptureError(path, "empty file: no capture header", 0)
    if len(head) >= 4 and head in _PCAP_MAGICS:
        info.format = "pcap"
        return _pcap_frames
    if len(head) >= 4 and struct.unpack("<I", head)[0] == _PCAPNG_SHB:
        info.format = "pcapng"
        return _pcapng_frames
    raise CaptureError(path, f"not a pcap or pcapng file (magic {head.hex()}; "
                             "convert other formats with editcap first)", 0)


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
            if self.backlog[:2] != _GZIP_MAGIC[:len(self.backlog[:2])]:
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


def _gzip_reason(exc: BaseException) -> str:
    text = str(exc) or exc.__class__.__name__
    if isinstance(exc, EOFError):
        return f"compressed data ends early: {text}"
    if "data check" in text or "CRC" in text:
        return f"gzip CRC mismatch, the file is corrupt: {text}"
    return f"corrupt compressed data: {text}" if isinstance(exc, zlib.error) else text


def cut_runs(frames: Iterator[RawFrame], cuts: tuple[int, ...]) -> Iterator[RawFrame]:
    """The frames, with every run of skipped frames that spans a cut (a frame number that must start
    a record, e.g. the first frame of a split part) cut in two there."""
    for frame in frames:
        if frame.run > 1:
            first = frame.number - frame.run + 1
            for cut in sorted(c for c in cuts if first < c <= frame.number):
                yield frame._replace(number=cut - 1, run=cut - first)  # time of the run's last frame
                first = cut
            frame = frame._replace(run=frame.number - first + 1)
        yield frame


def pcap_split_points(path: str, parts: int) -> list[tuple[int, int, float]] | None:
    """(frame number, byte offset, time) of every 512th record of an uncompressed classic pcap, to
    split it among processes; None for any other file (those are analysed in one process)."""
    with open(path, "rb") as f:
        head = f.read(24)
        if head[:4] not in _PCAP_MAGICS or len(head) < 24:
            return None
        f.seek(0)
        info = CaptureInfo(path)
        points = []
        try:
            for frame in _pcap_frames(path, f, info, with_offsets=True):  # every 512th record
                points.append((frame.number, frame.iface, frame.ts))  # iface carries the offset here
        except CaptureError:
            return None
    return points if len(points) >= 2 * parts else None


def pcap_frames_from(path: str, offset: int, first_number: int, ip_only: bool = False) -> Iterator[RawFrame]:
    """The frames of a classic pcap from a record at `offset`, numbered from `first_number`."""
    with open(path, "rb") as f:
        head = f.read(24)
        f.seek(offset)
        for frame in _pcap_frames(path, f, CaptureInfo(path), head=head, base=offset, ip_only=ip_only):
            yield frame._replace(number=frame.number + first_number - 1)


def _pcap_frames(path: str, stream: BinaryIO, info: CaptureInfo, with_offsets: bool = False,
                 head: bytes | None = None, base: int = 24, ip_only: bool = False) -> Iterator[RawFrame]:
    """Classic pcap: dpkt parses the file header; records are cut from large chunks.

    dpkt's record loop builds a header object per frame (about 1.7 us) and reads whatever length a
    record claims; this loop costs a fraction of that, and bounds every length before reading.
    """
    head = head if head is not None else stream.read(24)
    try:
        fh = dpkt.pcap.FileHdr(head)
        if fh.magic in (dpkt.pcap.PMUDPCT_MAGIC, dpkt.pcap.PMUDPCT_MAGIC_NANO):
            fh = dpkt.pcap.LEFileHdr(head)
    except (dpkt.NeedData, dpkt.UnpackError):
        raise CaptureError(path, "pcap file header truncated", 0) from None
    little = head[:4] in (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1")
    divisor = 1e9 if head[:4] in (b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\x3c\x4d") else 1e6
    linktype = fh.linktype
    info.linktypes = [linktype]
    unpack = struct.Struct("<IIII" if little else ">IIII").unpack_from
    skip_non_ip = ip_only and linktype == LINKTYPE_ETHERNET and not with_offsets
    buf = b""
    pos = 0  # in buf; base is the file offset of buf[0]
    number = 0
    run = 0  # frames skipped since the last one yielded (ip_only)
    run_buf, run_pos = b"", 0  # where the last of them is, for its time
    # the skip loop reads caplen and the EtherType (taken in the file's byte order, so compared with
    # the IP EtherTypes read the same way) in one unpack, without cutting the frame out
    skip_unpack = struct.Struct("<8xI16xH" if little else ">8xI16xH").unpack_from
    ip_types = frozenset(struct.unpack("<H" if little else ">H", t)[0] for t in IP_ETHERTYPES)
    while True:
        if skip_non_ip:  # most records of a PROFINET capture: counted here, a few operations each
            limit = len(buf) - 30
            while pos <= limit:
                caplen, etype = skip_unpack(buf, pos)
                end = pos + 16 + caplen
                if caplen < 14 or etype in ip_types or caplen > MAX_CAPLEN or end > len(buf):
                    break  # the general path below takes it (or reports the damage)
                number += 1
                run += 1
                run_buf, run_pos, pos = buf, pos, end
        if len(buf) - pos < 16:
            buf = buf[pos:] + _read(path, stream, _CHUNK, base + pos)
            base += pos
            pos = 0
            if run and (len(buf) < 16):  # the run ends here: account for it before the end or the damage
                yield _run_record(number, run_buf, run_pos, unpack, divisor, linktype, run)
                run = 0
            if not buf:
                return
            if len(buf) < 16:
                raise CaptureError(path, f"record header truncated ({len(buf)} of 16 bytes present)", base)
        sec, frac, caplen, _orig = unpack(buf, pos)
        if caplen > MAX_CAPLEN:
            if run:
                yield _run_record(number, run_buf, run_pos, unpack, divisor, linktype, run)
            raise CaptureError(path, f"record length {caplen} exceeds {MAX_CAPLEN} bytes (corrupt record "
                                     "header)", base + pos)
        end = pos + 16 + caplen
        if end > len(buf):
            buf = buf[pos:] + _read(path, stream, max(_CHUNK, caplen + 16), base + pos)
            base += pos
            pos, end = 0, 16 + caplen
            if end > len(buf):
                if run:
                    yield _run_record(number, run_buf, run_pos, unpack, divisor, linktype, run)
                raise CaptureError(path, f"record data truncated ({len(buf) - 16} of {caplen} bytes present)",
                                   base)
        number += 1
        if skip_non_ip and caplen >= 14 and buf[pos + 28:pos + 30] not in IP_ETHERTYPES:
            run += 1
            run_buf, run_pos = buf, pos
            pos = end
            continue
        if run:
            yield _run_record(number - 1, run_buf, run_pos, unpack, divisor, linktype, run)
            run = 0
        if with_offsets:  # split points: the offset of every 512th record, no frame data
            if number % 512 == 1:
                yield RawFrame(number, sec + frac / divisor, linktype, b"", base + pos)
        else:
            yield RawFrame(number, sec + frac / divisor, linktype, buf[pos + 16:end])
        pos = end


_CHUNK = 1 << 20


def _run_record(number: int, buf: bytes, pos: int, unpack: Callable, divisor: float, linktype: int,
                run: int) -> RawFrame:
    """The record standing for `run` skipped frames up to `number`, timed as the last (its header at pos)."""
    sec, frac = unpack(buf, pos)[:2]
    return RawFrame(number, sec + frac / divisor, linktype, b"", 0, run)


def _read(path: str, stream: BinaryIO, size: int, offset: int) -> bytes:
    try:
        return stream.read(size)
    except (OSError, EOFError, zlib.error) as exc:
        raise CaptureError(path, f"read failed ({_gzip_reason(exc)})", offset) from None


class _Interface(NamedTuple):
    linktype: int
    divisor: float
    offset: int
    snaplen: int


def _pcapng_frames(path: str, stream: BinaryIO, info: CaptureInfo) -> Iterator[RawFrame]:
    pos = 0
    little = True
    ifaces: list[_Interface] = []
    number = 0
    last_ts = 0.0
    while True:
        head = _read_exact(path, stream, 8, pos, allow_eof=True)
        if not head:
            return
        if struct.unpack("<I", head[:4])[0] == _PCAPNG_SHB:
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
        raise CaptureError(path, f"read failed ({_gzip_reason(exc)})", pos) from None
    if allow_eof and not data:
        return b""
    if len(data) != size:
        raise CaptureError(path, f"block truncated ({len(data)} of {size} bytes present)", pos)
    return data


def _shb_little(path: str, stream: BinaryIO, pos: int) -> bool:
    try:
        bom = _peek(stream, 4)
    except (OSError, EOFError, zlib.error) as exc:
        raise CaptureError(path, f"read failed ({_gzip_reason(exc)})", pos) from None
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
