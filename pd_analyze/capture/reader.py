"""Capture files, streamed one frame at a time: the format found by magic, never by file name.

pcap (microsecond and nanosecond magic, both byte orders) is read by `pcap`, pcapng by `pcapng`;
either may be gzip-compressed (`gzip_stream`).

A damaged file raises CaptureError naming the byte offset, after every frame before the damage has
been yielded. No length field read from a file is trusted for an allocation: every record is
bounded by MAX_CAPLEN before it is read.
"""

from __future__ import annotations

import os
import struct
import sys
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from typing import BinaryIO

from pd_analyze.capture.gzip_stream import GZIP_MAGIC, _Gunzip
from pd_analyze.capture.pcap import PCAP_MAGICS, pcap_frames
from pd_analyze.capture.raw import PCAPNG_SHB, CaptureError, CaptureInfo, RawFrame, peek


def frames(path: str, info: CaptureInfo | None = None, ip_only: bool = False) -> Iterator[RawFrame]:
    """Every frame of a capture file (`-` = standard input), numbered from 1.

    `ip_only`: consecutive Ethernet frames whose EtherType is neither IPv4 nor a VLAN tag (cyclic PN-RT,
    LLDP, ARP: most of a PROFINET capture) may come as one `run` record instead of a frame each, so
    the analysis skips them without an object per frame (classic pcap; other formats ignore it)."""
    info = info or CaptureInfo(path)
    with opened(path, info) as (stream, fmt):
        if fmt == "pcap":
            yield from pcap_frames(path, stream, info, ip_only=ip_only)
            return
        from pd_analyze.capture.pcapng import pcapng_frames  # here: it loads dpkt, which a pcap does not need

        yield from pcapng_frames(path, stream, info)


@contextmanager
def opened(path: str, info: CaptureInfo) -> Iterator[tuple[BinaryIO, str]]:
    """The capture open (open_capture), closed at the end; damage inside a gzip file is told at its
    offset in the decompressed data (in_decompressed)."""
    stream, fmt = open_capture(path, info)
    try:
        yield stream, fmt
    except CaptureError as exc:
        if not info.compressed or exc.offset is None:
            raise
        raise in_decompressed(exc) from None
    finally:
        stream.close()


def open_capture(path: str, info: CaptureInfo) -> tuple[BinaryIO, str]:
    """The capture's stream, inflated when gzip-compressed, and its format ("pcap" or "pcapng") found by
    magic; `info` learns both. Nothing is consumed but what a gzip header takes; the caller closes the
    stream (closed here when the capture cannot be read at all)."""
    stream = _open(path)
    try:
        try:
            head = peek(stream, 4)
        except OSError as exc:  # e.g. EIO from a failing disk or a special file
            raise CaptureError(path, f"read failed ({exc.strerror or exc})", 0) from None
        if head[:2] == GZIP_MAGIC:
            info.compressed = True
            stream = _Gunzip(stream)  # type: ignore[assignment]
            try:
                head = peek(stream, 4)
            except (OSError, EOFError, zlib.error) as exc:
                raise CaptureError(path, f"gzip data unreadable ({exc})", 0) from None
        return stream, _format(path, head, info)
    except BaseException:
        stream.close()
        raise


def unreadable_reason(path: str) -> str:
    """Why a capture cannot be read at all (missing, a directory, not a capture, ...), '' when its header
    reads; stdin is not probed (its bytes can be read only once)."""
    if path == "-":
        return ""
    try:
        stream, _ = open_capture(path, CaptureInfo(path))
    except CaptureError as exc:
        return str(exc)
    stream.close()
    return ""


def in_decompressed(exc: CaptureError) -> CaptureError:
    """The error of a gzip-compressed capture: its offset counts decompressed bytes, and says so."""
    return CaptureError(exc.path, f"{exc.reason} (offset in the decompressed data)", exc.offset)


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


def _format(path: str, head: bytes, info: CaptureInfo) -> str:
    if len(head) == 0:
        raise CaptureError(path, "empty file: no capture header", 0)
    if len(head) >= 4 and head in PCAP_MAGICS:
        info.format = "pcap"
        return "pcap"
    if len(head) >= 4 and struct.unpack("<I", head)[0] == PCAPNG_SHB:
        info.format = "pcapng"
        return "pcapng"
    raise CaptureError(path, f"not a pcap or pcapng file (magic {head.hex()}; "
                             "convert other formats with editcap first)", 0)


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
