"""Classic pcap files: the 24-byte file header and the records are read by an own loop (records cut from
large chunks). dpkt is not imported for them: its package loads every protocol module it has (about 70 ms of
a start-up that should take 0.3 s), and all a pcap header gives us is its magic and link type.

dpkt's record loop costs about 1.7 us a frame (a header object each) and reads whatever length a record
claims; this loop bounds every length by MAX_CAPLEN and counts a run of frames without IPv4 with one
unpack each. Split points let `--jobs` cut one file into parts at record boundaries.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable, Iterator
from typing import BinaryIO

from pd_analyze.capture.gzip_stream import read_failure
from pd_analyze.capture.raw import MAX_CAPLEN, CaptureError, CaptureInfo, RawFrame
from pd_analyze.model.times import NS
from pd_analyze.model.values import IP_ETHERTYPES, LINKTYPE_ETHERNET

PCAP_MAGICS = {
    b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\xc3\xd4",  # microseconds, LE / BE
    b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\x3c\x4d",  # nanoseconds, LE / BE
}
_LITTLE_MAGICS = (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1")
_NANO_MAGICS = (b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\x3c\x4d")
_HEADER_SIZE = 24  # magic, version (2 x 2), thiszone, sigfigs, snaplen, link type (4 each)


def pcap_header(path: str, head: bytes) -> tuple[bool, float, int]:
    """(little-endian, the divisor of a record's fraction of a second, link type) of a file header: the
    link type is its last field, in the byte order its magic shows (big-endian for any other magic)."""
    if len(head) < _HEADER_SIZE:
        raise CaptureError(path, "pcap file header truncated", 0)
    little = head[:4] in _LITTLE_MAGICS
    divisor = 1e9 if head[:4] in _NANO_MAGICS else 1e6
    return little, divisor, struct.unpack_from("<I" if little else ">I", head, 20)[0]


def divisor_digits(divisor: float) -> int:
    """The decimals of a second a pcap's records carry: 6 (microsecond magic) or 9 (nanosecond magic)."""
    return 9 if divisor == 1e9 else 6


def pcap_frames(path: str, stream: BinaryIO, info: CaptureInfo, ip_only: bool = False) -> Iterator[RawFrame]:
    """Classic pcap: the file header read by pcap_header; records are cut from large chunks.

    dpkt's record loop builds a header object per frame (about 1.7 us) and reads whatever length a
    record claims; this loop costs a fraction of that, and bounds every length before reading.
    """
    little, divisor, linktype = pcap_header(path, stream.read(24))
    info.linktypes = [linktype]
    info.digits = divisor_digits(divisor)
    unit = NS // int(divisor)  # nanoseconds a unit of a record's fraction of a second
    unpack = struct.Struct("<IIII" if little else ">IIII").unpack_from
    skip_non_ip = ip_only and linktype == LINKTYPE_ETHERNET
    buf = b""
    base = 24  # the file offset of buf[0]
    pos = 0  # in buf
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
        yield RawFrame(number, sec + frac / divisor, linktype, buf[pos + 16:end], 0, 0, sec * NS + frac * unit)
        pos = end


_CHUNK = 1 << 20


def _run_record(number: int, buf: bytes, pos: int, unpack: Callable, divisor: float, linktype: int,
                run: int) -> RawFrame:
    """The record standing for `run` skipped frames up to `number`, timed as the last (its header at pos)."""
    sec, frac = unpack(buf, pos)[:2]
    return RawFrame(number, sec + frac / divisor, linktype, b"", 0, run, sec * NS + frac * (NS // int(divisor)))


def _read(path: str, stream: BinaryIO, size: int, offset: int) -> bytes:
    try:
        return stream.read(size)
    except (OSError, EOFError, zlib.error) as exc:
        raise CaptureError(path, f"read failed ({read_failure(exc)})", offset) from None


def pcap_records(path: str, stream: BinaryIO, head: bytes) -> Iterator[tuple[bytes, int, int, int, int]]:
    """Every record of a classic pcap whose 24-byte file header `head` was read, as it is in the file:
    (record bytes with their 16-byte header, seconds, fraction, caplen, original length). For writing a
    copy (annotate, extract): frame numbers are the records' order, as `pcap_frames` counts them."""
    little = pcap_header(path, head)[0]
    unpack = struct.Struct("<IIII" if little else ">IIII").unpack
    pos = 24
    while True:
        hdr = _read(path, stream, 16, pos)
        if not hdr:
            return
        if len(hdr) < 16:
            raise CaptureError(path, f"record header truncated ({len(hdr)} of 16 bytes present)", pos)
        sec, frac, caplen, orig = unpack(hdr)
        if caplen > MAX_CAPLEN:
            raise CaptureError(path, f"record length {caplen} exceeds {MAX_CAPLEN} bytes (corrupt record header)",
                               pos)
        data = _read(path, stream, caplen, pos + 16)
        if len(data) < caplen:
            raise CaptureError(path, f"record data truncated ({len(data)} of {caplen} bytes present)", pos)
        yield hdr + data, sec, frac, caplen, orig
        pos += 16 + caplen
