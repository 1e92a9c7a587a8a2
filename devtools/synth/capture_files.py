"""Capture file writers: classic pcap, pcapng, deterministic gzip.

All writers return bytes; nothing here reads a clock or the environment, so
the same frames always give the same file.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from .net_encode import LINKTYPE_ETHERNET

PCAP_MAGIC_US = 0xA1B2C3D4
PCAP_MAGIC_NS = 0xA1B23C4D


@dataclass(frozen=True)
class Frame:
    """One captured frame. ts_ns is absolute Unix time in nanoseconds (None
    for a pcapng SPB, which has no timestamp). orig_len > len(data) marks a
    frame already cut by the capture."""

    ts_ns: int | None
    data: bytes
    linktype: int = LINKTYPE_ETHERNET
    orig_len: int | None = None
    iface: int = 0

    @property
    def wire_len(self) -> int:
        return len(self.data) if self.orig_len is None else self.orig_len


def pcap_bytes(
    frames: Iterable[Frame],
    *,
    linktype: int = LINKTYPE_ETHERNET,
    nanosecond: bool = False,
    big_endian: bool = False,
    snaplen: int = 262144,
) -> bytes:
    """Classic pcap (v2.4). Frames longer than snaplen are cut, keeping
    orig_len, exactly as libpcap does with -s."""
    e = ">" if big_endian else "<"
    magic = PCAP_MAGIC_NS if nanosecond else PCAP_MAGIC_US
    out = [struct.pack(e + "IHHiIII", magic, 2, 4, 0, 0, snaplen, linktype)]
    for f in frames:
        ts = f.ts_ns or 0
        sec, frac = divmod(ts, 1_000_000_000)
        if not nanosecond:
            frac //= 1000
        data = f.data[:snaplen]
        out.append(struct.pack(e + "IIII", sec, frac, len(data), f.wire_len) + data)
    return b"".join(out)


def _pad4(data: bytes) -> bytes:
    return data + b"\x00" * (-len(data) % 4)


@dataclass
class Pcapng:
    """Incremental pcapng builder (one section, little- or big-endian).

    Blocks are appended in call order, so an unknown block can be placed
    between packets to prove readers skip it by its length.
    """

    big_endian: bool = False
    # the generator's name in the files it writes, as when the samples were first made: the samples
    # regenerate byte for byte
    userappl: str = "pd_analyze.synth"
    _blocks: list[bytes] = field(default_factory=list)
    _ifaces: list[tuple[int, int, int]] = field(default_factory=list)  # linktype, tsresol, snaplen

    @property
    def _e(self) -> str:
        return ">" if self.big_endian else "<"

    def _options(self, opts: Sequence[tuple[int, bytes]]) -> bytes:
        if not opts:
            return b""
        body = b"".join(struct.pack(self._e + "HH", code, len(v)) + _pad4(v) for code, v in opts)
        return body + struct.pack(self._e + "HH", 0, 0)  # opt_endofopt

    def block(self, block_type: int, body: bytes) -> None:
        """Append any block: type, total length, body (padded), total length."""
        body = _pad4(body)
        total = 12 + len(body)
        self._blocks.append(struct.pack(self._e + "II", block_type, total) + body + struct.pack(self._e + "I", total))

    def custom_block(self, pen: int, data: bytes, *, copyable: bool = True) -> None:
        """Custom Block (0x00000BAD / 0x40000BAD): Private Enterprise Number
        + opaque data; readers that do not know the PEN skip it."""
        self.block(0x00000BAD if copyable else 0x40000BAD, struct.pack(self._e + "I", pen) + data)

    def section_header(self) -> None:
        opts = self._options([(4, self.userappl.encode())])  # shb_userappl
        # section length -1: unknown, readers must walk the blocks
        self.block(0x0A0D0D0A, struct.pack(self._e + "IHHq", 0x1A2B3C4D, 1, 0, -1) + opts)

    def interface(self, linktype: int, *, tsresol: int | None = None, snaplen: int = 0, name: str | None = None) -> int:
        """Add an IDB; tsresol is the if_tsresol byte (6 = µs default, 9 = ns).
        Returns the interface id."""
        opts: list[tuple[int, bytes]] = []
        if name is not None:
            opts.append((2, name.encode()))  # if_name
        if tsresol is not None:
            opts.append((9, bytes([tsresol])))  # if_tsresol
        self.block(1, struct.pack(self._e + "HHI", linktype, 0, snaplen) + self._options(opts))
        self._ifaces.append((linktype, 6 if tsresol is None else tsresol, snaplen))
        return len(self._ifaces) - 1

    def _ticks(self, iface: int, ts_ns: int) -> int:
        res = self._ifaces[iface][1]
        if res & 0x80:
            return ts_ns * (1 << (res & 0x7F)) // 1_000_000_000
        return ts_ns * 10**res // 1_000_000_000

    def epb(self, frame: Frame, iface: int | None = None, *, comment: str | None = None) -> None:
        """Enhanced Packet Block on the frame's (or the given) interface."""
        idx = frame.iface if iface is None else iface
        snap = self._ifaces[idx][2]
        data = frame.data[:snap] if snap else frame.data
        ticks = self._ticks(idx, frame.ts_ns or 0)
        opts = self._options([(1, comment.encode())] if comment else [])
        body = struct.pack(self._e + "IIIII", idx, ticks >> 32, ticks & 0xFFFFFFFF, len(data), frame.wire_len)
        self.block(6, body + _pad4(data) + opts)

    def spb(self, frame: Frame) -> None:
        """Simple Packet Block: always interface 0, no timestamp, captured
        length implied by the block length (min(orig_len, IDB0 snaplen))."""
        snap = self._ifaces[0][2]
        data = frame.data[:snap] if snap else frame.data
        self.block(3, struct.pack(self._e + "I", frame.wire_len) + data)

    def tobytes(self) -> bytes:
        return b"".join(self._blocks)


def gzip_bytes(data: bytes) -> bytes:
    """gzip member with mtime 0, no file name, OS 255 and *stored* deflate
    blocks: stored blocks make the file independent of the zlib build (zlib
    and zlib-ng compress differently), so regenerated files stay identical."""
    out = bytearray(b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\xff")
    chunks = [data[i : i + 0xFFFF] for i in range(0, len(data), 0xFFFF)] or [b""]
    for i, chunk in enumerate(chunks):
        final = 1 if i == len(chunks) - 1 else 0
        out += struct.pack("<BHH", final, len(chunk), len(chunk) ^ 0xFFFF) + chunk
    out += struct.pack("<II", zlib.crc32(data) & 0xFFFFFFFF, len(data) & 0xFFFFFFFF)
    return bytes(out)
