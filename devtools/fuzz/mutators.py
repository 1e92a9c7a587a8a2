"""The mutations of the fuzzer: of one frame (bit flips, interesting bytes, insertions, deletions,
truncation at every layer, length and count fields set to 0, 1, max and max-1, DCE/RPC fragment and
sequence numbers and IP fragment fields scrambled, splices), of a case (a window of a seed's frames,
reordered, duplicated, thinned, flooded, with link types and timestamps changed), and of a capture
file (record and block lengths, magic, truncation, the gzip stream and its CRC).

A case is generated from the base seed and its number alone, so any case replays exactly.
"""

from __future__ import annotations

import gzip
import random
import struct
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from pd_analyze import capture
from pd_analyze.capture import RawFrame
from pd_analyze.protocol import link

from .corpus import Seed, SeedFrame

WINDOW = 40  # frames of a seed per case
LINKTYPES = (1, 113, 276, 101, 228, 0, 105, 65_535)
_INTERESTING = (0x00, 0x01, 0x7F, 0x80, 0xFE, 0xFF)


# --- frame mutations ----------------------------------------------------------------------------
def _flip(rng: random.Random, data: bytearray, sf: SeedFrame) -> None:
    for _ in range(rng.randint(1, 8)):
        if not data:
            return
        if sf.fields and rng.random() < 0.6:
            off, n = rng.choice(sf.fields)
            pos = min(off + rng.randrange(n), len(data) - 1)
        else:
            pos = rng.randrange(len(data))
        data[pos] ^= 1 << rng.randrange(8)


def _bytes(rng: random.Random, data: bytearray, sf: SeedFrame) -> None:
    del sf
    for _ in range(rng.randint(1, 4)):
        if data:
            data[rng.randrange(len(data))] = rng.choice(_INTERESTING) if rng.random() < 0.5 else rng.randrange(256)


def _insert(rng: random.Random, data: bytearray, sf: SeedFrame) -> None:
    pos = rng.choice(sf.cuts) if sf.cuts and rng.random() < 0.5 else rng.randint(0, len(data))
    n = rng.choice((1, 2, 3, 4, 7, 8, 16, 64, 300))
    fill = bytes([rng.randrange(256)]) * n if rng.random() < 0.5 else rng.randbytes(n)
    data[pos:pos] = fill


def _delete(rng: random.Random, data: bytearray, sf: SeedFrame) -> None:
    if not data:
        return
    pos = rng.choice(sf.cuts) if sf.cuts and rng.random() < 0.5 else rng.randrange(len(data))
    del data[pos:pos + rng.choice((1, 2, 3, 4, 8, 16, 80))]


def _truncate(rng: random.Random, data: bytearray, sf: SeedFrame) -> None:
    """Cut at a layer start, inside a field, or anywhere."""
    roll = rng.random()
    if roll < 0.4 and sf.cuts:
        at = rng.choice(sf.cuts) + rng.choice((-1, 0, 0, 1))
    elif roll < 0.8 and sf.fields:
        off, n = rng.choice(sf.fields)
        at = off + rng.randrange(n + 1)
    else:
        at = rng.randint(0, len(data))
    del data[max(0, at):]


def _field(rng: random.Random, data: bytearray, sf: SeedFrame) -> None:
    """A length or count field set to 0, 1, max or max-1 (either byte order), or random."""
    if not sf.fields:
        return _bytes(rng, data, sf)
    off, n = rng.choice(sf.fields)
    n = min(n, 8, len(data) - off)
    if n <= 0:
        return None
    top = (1 << (8 * n)) - 1
    value = rng.choice((0, 1, top, top - 1, top >> 1, (top >> 1) + 1, rng.randrange(top + 1)))
    data[off:off + n] = value.to_bytes(n, rng.choice(("big", "little")))
    return None


def _splice(rng: random.Random, data: bytearray, sf: SeedFrame, other: bytes) -> None:
    at = rng.choice(sf.cuts) if sf.cuts else rng.randint(0, len(data))
    data[at:] = other[rng.randint(0, len(other)):] if other else b""


_FRAME_OPS: tuple[Callable[[random.Random, bytearray, SeedFrame], None], ...] = (
    _flip, _flip, _bytes, _insert, _delete, _truncate, _field, _field, _field)


def _set(data: bytearray, at: int, size: int, value: int, little: bool = False) -> None:
    if at >= 0 and at + size <= len(data):
        data[at:at + size] = (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little" if little else "big")


def _rpc_little(data: bytearray, at: int) -> bool:
    return len(data) > at + 4 and bool(data[at + 4] & 0x10)


def _scramble_rpc(rng: random.Random, data: bytearray, at: int) -> None:
    """Fragment number, fragment flags, sequence number or activity of a DCE/RPC PDU."""
    if at < 0 or len(data) < at + 80:
        return
    little = _rpc_little(data, at)
    what = rng.randrange(5)
    if what == 0:
        _set(data, at + 76, 2, rng.choice((0, 1, 2, 3, 0xFFFF, 0xFFFE, rng.randrange(65536))), little)
    elif what == 1:
        data[at + 2] ^= rng.choice((0x02, 0x04, 0x06))
    elif what == 2:
        _set(data, at + 64, 4, rng.choice((0, 1, 0xFFFFFFFF, rng.randrange(1 << 32))), little)
    elif what == 3:
        data[at + 40:at + 56] = rng.randbytes(16)
    else:
        data[at + 1] = rng.choice((0, 2, 3, 4, 5, 6, 8, 9, 10))


def _scramble_ip(rng: random.Random, data: bytearray, linktype: int) -> None:
    l3 = link.l3_offset(linktype, bytes(data)) if len(data) >= 16 else -1
    if l3 < 0 or len(data) < l3 + 20:
        return
    flags = rng.choice((0x2000, 0x0000, 0x4000)) | rng.choice((0, 1, 2, 185, 0x1FFF, rng.randrange(0x2000)))
    _set(data, l3 + 6, 2, flags)
    if rng.random() < 0.5:
        _set(data, l3 + 4, 2, rng.randrange(65536))


def mutate_frame(rng: random.Random, sf: SeedFrame, other: bytes) -> bytes:
    data = bytearray(sf.raw.data)
    for _ in range(rng.choice((1, 1, 1, 2, 2, 3, 5))):
        roll = rng.random()
        if roll < 0.08:
            _scramble_rpc(rng, data, sf.rpc)
        elif roll < 0.12:
            _scramble_ip(rng, data, sf.raw.linktype)
        elif roll < 0.15:
            _splice(rng, data, sf, other)
        else:
            rng.choice(_FRAME_OPS)(rng, data, sf)
    return bytes(data)


def _flood(rng: random.Random, sf: SeedFrame, ts: float) -> list[tuple[float, int, bytes]]:
    """Many frames made from one: unfinished CL fragments, IP fragments, or unanswered requests."""
    data = bytearray(sf.raw.data)
    count = rng.choice((16, 50, 120, 300))
    kind = rng.randrange(3) if sf.rpc >= 0 else 1
    out = []
    fixed_key = rng.random() < 0.5  # one set / datagram with many pieces, or many sets
    activity = rng.randbytes(16)
    for k in range(count):
        frame = bytearray(data)
        if kind == 0:  # CL fragments: fragment flag, never the last one
            at = sf.rpc
            little = _rpc_little(frame, at)
            frame[at + 2] = (frame[at + 2] | 0x04) & ~0x02 & 0xFF
            frame[at + 40:at + 56] = activity if fixed_key else rng.randbytes(16)
            _set(frame, at + 76, 2, k if rng.random() < 0.7 else rng.randrange(65536), little)
        elif kind == 1:  # IP fragments with MF set
            l3 = link.l3_offset(sf.raw.linktype, bytes(frame)) if len(frame) >= 16 else -1
            if l3 < 0 or len(frame) < l3 + 20:
                return out
            _set(frame, l3 + 4, 2, 0x4242 if fixed_key else rng.randrange(65536))
            _set(frame, l3 + 6, 2, 0x2000 | (k if rng.random() < 0.7 else rng.randrange(0x2000)))
        else:  # requests never answered: new sequence numbers (and activities)
            at = sf.rpc
            little = _rpc_little(frame, at)
            frame[at + 1] = 0
            _set(frame, at + 64, 4, rng.randrange(1 << 32), little)
            if not fixed_key:
                frame[at + 40:at + 56] = rng.randbytes(16)
        out.append((ts, sf.raw.linktype, bytes(frame)))
    return out


@dataclass(slots=True)
class Case:
    number: int
    seed: str
    frames: list[RawFrame]
    mutated: int  # frames that differ from the seed's


def make_case(seeds: Sequence[Seed], number: int, base_seed: int) -> Case:
    rng = random.Random(f"pd-analyze fuzz {base_seed} {number}")
    seed = seeds[rng.randrange(len(seeds))]
    start = rng.randrange(max(1, len(seed.frames) - 4))
    window = seed.frames[start:start + rng.randint(1, WINDOW)]
    items: list[tuple[float, int, bytes, bool]] = []
    p = rng.choice((0.3, 0.7, 0.9, 1.0))
    for sf in window:
        if rng.random() < p:
            other = rng.choice(seed.frames).raw.data
            data = mutate_frame(rng, sf, other)
            linktype = rng.choice(LINKTYPES) if rng.random() < 0.02 else sf.raw.linktype
            items.append((sf.raw.ts, linktype, data, data != sf.raw.data or linktype != sf.raw.linktype))
        else:
            items.append((sf.raw.ts, sf.raw.linktype, sf.raw.data, False))
    roll = rng.random()
    if roll < 0.12:
        sf = rng.choice(window)
        items += [(ts, lt, d, True) for ts, lt, d in _flood(rng, sf, sf.raw.ts)]
    elif roll < 0.22 and len(items) > 1:
        i, j = rng.randrange(len(items)), rng.randrange(len(items))
        items[i], items[j] = items[j], items[i]
    elif roll < 0.30:
        items.append(items[rng.randrange(len(items))])
    elif roll < 0.36:
        items = [(t, lt, d, m) for t, lt, d, m in items if rng.random() < 0.7] or items[:1]
    roll = rng.random()
    if roll < 0.05:
        items = [(items[0][0], lt, d, m) for _, lt, d, m in items]  # one timestamp for all
    elif roll < 0.08:
        items = [(rng.choice((0.0, -1.0, 1e12, t - 100.0, t + 1e6)), lt, d, m) for t, lt, d, m in items]
    frames = [RawFrame(n, ts, lt, d) for n, (ts, lt, d, _m) in enumerate(items, 1)]
    return Case(number, seed.name, frames, sum(1 for *_, m in items if m))


# --- file mutations ---------------------------------------------------------------------------
def _records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, length-field offset, length) of each pcap record or pcapng block, by walking the file."""
    out: list[tuple[int, int, int]] = []
    if len(data) < 24:
        return out
    if data[:4] in (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\xc3\xd4", b"\xa1\xb2\x3c\x4d"):
        order = "<" if data[:4] in (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1") else ">"
        pos = 24
        while pos + 16 <= len(data) and len(out) < 4096:
            caplen = struct.unpack_from(order + "I", data, pos + 8)[0]
            out.append((pos, pos + 8, caplen))
            pos += 16 + caplen
        return out
    if data[:4] == b"\x0a\x0d\x0d\x0a":
        order = "<" if data[8:12] == b"\x4d\x3c\x2b\x1a" else ">"
        pos = 0
        while pos + 12 <= len(data) and len(out) < 4096:
            blen = struct.unpack_from(order + "I", data, pos + 4)[0]
            out.append((pos, pos + 4, blen))
            if blen < 12:
                break
            pos += blen
    return out


def mutate_file(rng: random.Random, data: bytes) -> bytes:
    """A damaged copy of a capture file: lengths, magic, truncation, gzip stream or CRC."""
    if data[:2] == b"\x1f\x8b":
        if rng.random() < 0.5:
            raw = bytearray(data)
            roll = rng.random()
            if roll < 0.3:
                raw[-8 + rng.randrange(8)] ^= 0xFF  # CRC32 or ISIZE
            elif roll < 0.6:
                del raw[rng.randint(10, len(raw)):]
            else:
                raw[rng.randrange(10, len(raw))] ^= 1 << rng.randrange(8)
            return bytes(raw)
        try:
            inner = gzip.decompress(data)
        except (OSError, EOFError, zlib.error):
            return data
        return gzip.compress(mutate_file(rng, inner), mtime=0)
    raw = bytearray(data)
    records = _records(data)
    if data[:4] == b"\x0a\x0d\x0d\x0a" and len(records) > 1 and rng.random() < 0.2:
        return _reshape_block(rng, data, records)
    for _ in range(rng.choice((1, 1, 2, 3))):
        roll = rng.random()
        if roll < 0.35 and records:
            _pos, at, _n = rng.choice(records)
            value = rng.choice((0, 1, 2, 11, 12, 13, 0xFFFFFFFF, 0xFFFFFFFE, capture.MAX_CAPLEN,
                                capture.MAX_CAPLEN + 1, 0x7FFFFFFF, rng.randrange(1 << 32)))
            if at + 4 <= len(raw):
                raw[at:at + 4] = struct.pack(rng.choice("<>") + "I", value)
        elif roll < 0.55:
            cut = rng.choice(records)[0] + rng.choice((0, 1, 4, 8, 15, 16, 17)) if records else 0
            del raw[max(0, min(cut, len(raw))) if rng.random() < 0.7 else rng.randint(0, len(raw)):]
        elif roll < 0.70:
            pos = rng.randrange(min(len(raw), 64)) if raw else 0
            if raw:
                raw[pos] ^= 1 << rng.randrange(8)
        elif roll < 0.85 and raw:
            pos = rng.randrange(len(raw))
            raw[pos] ^= 1 << rng.randrange(8)
        elif raw:
            pos = rng.randrange(len(raw))
            if rng.random() < 0.5:
                raw[pos:pos] = rng.randbytes(rng.choice((1, 4, 16)))
            else:
                del raw[pos:pos + rng.choice((1, 4, 16))]
    return bytes(raw)


def _reshape_block(rng: random.Random, data: bytes, records: list[tuple[int, int, int]]) -> bytes:
    """One pcapng block cut or grown to another length, both length fields consistent (so the reader gets
    past the framing checks into the block's own fields), or its type changed."""
    pos, _at, blen = rng.choice(records[1:])
    order = "<" if data[8:12] == b"\x4d\x3c\x2b\x1a" else ">"
    btype = struct.unpack_from(order + "I", data, pos)[0]
    if rng.random() < 0.3:
        btype = rng.choice((1, 2, 3, 5, 6, 0x0A0D0D0A, 0xBAD))
    size = rng.choice((12, 16, 20, 24, 28, 32, 36, blen - 4, blen + 4, blen + 64, capture.MAX_CAPLEN + 64))
    body = (data[pos + 8:pos + max(8, blen - 4)] + bytes(size))[:max(0, size - 12)]
    block = struct.pack(order + "II", btype, size) + body + struct.pack(order + "I", size)
    return data[:pos] + block + data[pos + blen:]
