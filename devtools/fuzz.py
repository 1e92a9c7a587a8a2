"""Mutation fuzzing of the whole pipeline, seeded from every capture of sample_pcaps/ and ../shared/captures/.

    python -m devtools.fuzz --frames 1000000 --seed 1 --jobs 2     # the long run (README, Robustness)
    python -m devtools.fuzz --frames 20000 --seed 7                  # a short one
    python -m devtools.fuzz --seed 1 --replay 4711                   # one case again, with its traceback

A *case* is a window of up to 40 consecutive frames of one seed capture, each frame mutated with high
probability (bit flips, byte insertions and deletions, truncation at every layer, length and count
fields set to 0, 1, max and max-1, fragment and sequence numbers scrambled, link types and timestamps
changed), sometimes followed by a fragment or request flood. Every frame of a case goes through the
dump path (`Dissector(annotate=True)`, the check marks, the text and JSON renderers) and the report path
(`Dissector(annotate=False)`, `TransactionEngine`, table rows); every few cases the seed *file* itself is
mutated (record and block lengths, magic, gzip stream, truncation at every record) and read with
`capture.frames`, and one in 32 of those files goes through `analyze()`, the summary, the CSV files and
the HTML report. What counts as a failure:

- crash: any exception (for a mutated file: any exception but `CaptureError`);
- hang: one frame (or one file) taking longer than `--frame-limit` seconds (a SIGALRM interrupts it);
- invariant: frames read != decoded + skipped + malformed, or frames read != frames fed;
- bounds: a field of a frame whose offset and length do not lie inside the frame, or whose raw bytes
  are not the frame's bytes there;
- inert output: a control character in the text dump, or a JSON line that is not ASCII JSON.

Cases are numbered and generated from `--seed` and their number alone, so any case replays exactly.
"""

from __future__ import annotations

import argparse
import contextlib
import gzip
import json
import os
import random
import signal
import struct
import sys
import tempfile
import time
import traceback
import zlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from pd_analyze import capture
from pd_analyze.analysis.rows import Rows
from pd_analyze.analysis.transactions import TransactionEngine
from pd_analyze.capture import CaptureError, RawFrame
from pd_analyze.output import dump
from pd_analyze.protocol import link, rpc
from pd_analyze.protocol.dissector import Dissector
from pd_analyze.protocol.frames import FrameResult
from pd_analyze.protocol.profidrive_checks import Checker

ROOT = Path(__file__).resolve().parent.parent
SEED_DIRS = (ROOT / "sample_pcaps", ROOT.parent / "shared" / "captures")
CAPTURE_GLOBS = ("*.pcap", "*.pcapng", "*.gz", "*.cap")
WINDOW = 40  # frames of a seed per case
FILE_CASE_EVERY = 8  # every 8th case also mutates a seed file
REPORT_CASE_EVERY = 32  # every 32nd mutated file also goes through analyze(), the CSV files and the HTML page
CHUNK = 64  # cases per worker task
LINKTYPES = (1, 113, 276, 101, 228, 0, 105, 65_535)
_INTERESTING = (0x00, 0x01, 0x7F, 0x80, 0xFE, 0xFF)
_SKIP_FIELDS_AFTER = ("Reassembled body", "User Datagram Protocol (reassembled)")


class HangError(Exception):
    """Raised by the alarm when one frame or file takes longer than the limit."""


# --- seeds --------------------------------------------------------------------------------------
@dataclass(slots=True)
class SeedFrame:
    raw: RawFrame
    fields: tuple[tuple[int, int], ...]  # (offset, length) of decoded fields inside the frame
    cuts: tuple[int, ...]  # layer starts: truncation points
    rpc: int  # offset of the DCE/RPC header in the frame, -1 when none


@dataclass(slots=True)
class Seed:
    name: str
    path: str
    frames: list[SeedFrame]
    data: bytes  # the file as stored


def seed_paths(dirs: Sequence[Path | str] = SEED_DIRS) -> list[str]:
    out: list[str] = []
    for d in dirs:
        path = Path(d)
        if path.is_file():
            out.append(str(path))
            continue
        if not path.is_dir():
            continue
        found = {p for pattern in CAPTURE_GLOBS for p in path.glob(pattern) if p.is_file()}
        out += sorted(str(p) for p in found)
    return out


def load_seeds(paths: Sequence[str]) -> list[Seed]:
    """Each capture's frames with the offsets of their decoded fields (from the dump path)."""
    seeds = []
    for path in paths:
        try:
            raws = list(capture.frames(path))
        except CaptureError:
            continue
        if not raws:
            continue
        known: dict[int, list[tuple[int, int]]] = {}
        d = Dissector(annotate=True)
        for res in [r for raw in raws for r in d.feed(raw)] + d.finish():
            data = raws[res.frame - 1].data
            known[res.frame] = [(f.offset, f.length) for f in _frame_fields(res)
                                if f.length and f.offset >= 0 and f.offset + f.length <= len(data)]
        frames = []
        for raw in raws:
            extra, cuts, at = _landmarks(raw.linktype, raw.data)
            fields = tuple(sorted(set(known.get(raw.number, [])) | set(extra)))
            frames.append(SeedFrame(raw, fields, cuts, at))
        seeds.append(Seed(Path(path).name, path, frames, Path(path).read_bytes()))
    return seeds


def _frame_fields(res: FrameResult) -> Iterator:
    """Fields whose offsets are in the frame: those before a reassembled body or datagram."""
    for layer in res.layers:
        if layer.title.startswith(_SKIP_FIELDS_AFTER):
            return
        yield from layer.fields


def _landmarks(linktype: int, data: bytes) -> tuple[list[tuple[int, int]], tuple[int, ...], int]:
    """IPv4, UDP and DCE/RPC header fields found by position, for frames the dump does not show."""
    fields: list[tuple[int, int]] = []
    cuts = {0, 6, 12, 14}
    l3 = link.l3_offset(linktype, data) if len(data) >= 16 else -1
    if l3 < 0 or len(data) < l3 + 20:
        return fields, tuple(sorted(c for c in cuts if c < len(data))), -1
    cuts.add(l3)
    fields += [(l3, 1), (l3 + 2, 2), (l3 + 4, 2), (l3 + 6, 2), (l3 + 9, 1)]
    udp = l3 + (data[l3] & 0x0F) * 4
    cuts.update({udp, udp + 4, udp + 8})
    fields += [(udp, 2), (udp + 2, 2), (udp + 4, 2)]
    at = udp + 8
    if not rpc.plausible(data[at:]):
        return fields, tuple(sorted(c for c in cuts if c < len(data))), -1
    fields += [(at + o, n) for o, n in ((1, 1), (2, 1), (4, 1), (7, 1), (56, 4), (60, 4), (64, 4), (68, 2),
                                        (74, 2), (76, 2), (78, 1), (79, 1))]
    cuts.update(at + o for o in (0, 40, 80, 84, 100, 104, 120, 164, 165, 168, 174, 180))
    return fields, tuple(sorted(c for c in cuts if c < len(data))), at


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


# --- running cases --------------------------------------------------------------------------------
@dataclass(slots=True)
class Stats:
    cases: int = 0
    frames: int = 0  # frames fed, mutated or not
    mutated: int = 0  # mutated frames fed
    files: int = 0
    file_frames: int = 0
    transactions: int = 0
    crashes: list[str] = field(default_factory=list)
    hangs: list[str] = field(default_factory=list)
    violations: list[str] = field(default_factory=list)
    slowest: float = 0.0  # seconds, one frame
    peak_rss_mb: float = 0.0
    seconds: float = 0.0

    def add(self, other: Stats) -> None:
        self.cases += other.cases
        self.frames += other.frames
        self.mutated += other.mutated
        self.files += other.files
        self.file_frames += other.file_frames
        self.transactions += other.transactions
        self.crashes += other.crashes
        self.hangs += other.hangs
        self.violations += other.violations
        self.slowest = max(self.slowest, other.slowest)
        self.peak_rss_mb = max(self.peak_rss_mb, other.peak_rss_mb)

    @property
    def ok(self) -> bool:
        return not (self.crashes or self.hangs or self.violations)


def _on_alarm(signum: int, frame: object) -> None:
    del signum, frame
    raise HangError("time limit exceeded")


@contextlib.contextmanager
def _limit(seconds: float) -> Iterator[None]:
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)


class Runner:
    """Runs cases against the dump and report paths, collecting failures."""

    def __init__(self, seeds: Sequence[Seed], base_seed: int, frame_limit: float = 2.0,
                 workdir: str | None = None) -> None:
        self.seeds = list(seeds)
        self.base_seed = base_seed
        self.frame_limit = frame_limit
        self.workdir = workdir or tempfile.mkdtemp(prefix="pd-fuzz-", dir=_tmp_root())
        self.checker = Checker.for_profile("sinamics")
        self.rows = Rows()
        signal.signal(signal.SIGALRM, _on_alarm)

    def run(self, first: int, count: int) -> Stats:
        stats = Stats()
        started = time.perf_counter()
        for number in range(first, first + count):
            case = make_case(self.seeds, number, self.base_seed)
            stats.cases += 1
            stats.frames += len(case.frames)
            stats.mutated += case.mutated
            self._guarded(stats, f"case {number} ({case.seed})", lambda c=case: self.frame_case(c, stats))
            if number % FILE_CASE_EVERY == 0:
                self._guarded(stats, f"file case {number}", lambda n=number: self.file_case(n, stats))
        self._guarded(stats, f"tables after case {first + count - 1}", self.tables)
        stats.seconds = time.perf_counter() - started
        stats.peak_rss_mb = peak_rss_mb()
        return stats

    def _guarded(self, stats: Stats, what: str, func: Callable[[], None]) -> None:
        try:
            func()
        except HangError:
            stats.hangs.append(f"{what}: more than {self.frame_limit:g} s")
        except InvariantError as exc:
            stats.violations.append(f"{what}: {exc}")
        except Exception as exc:
            tb = traceback.extract_tb(exc.__traceback__)[-1]
            stats.crashes.append(f"{what}: {exc.__class__.__name__}: {str(exc)[:200]} "
                                 f"at {Path(tb.filename).name}:{tb.lineno}")

    # --- frame cases -------------------------------------------------------------------------
    def frame_case(self, case: Case, stats: Stats) -> None:
        data = {f.number: f.data for f in case.frames}
        annotated = Dissector(annotate=True, checker=self.checker)
        plain = Dissector(annotate=False, checker=self.checker)
        engine = TransactionEngine()
        last = float("-inf")
        for raw in case.frames:
            t0 = time.perf_counter()
            with _limit(self.frame_limit):
                for res in annotated.feed(raw):
                    check_result(res, data[res.frame])
                for res in plain.feed(raw):
                    last = max(last, res.ts)
                    for txn in engine.feed(res):
                        self.rows.add(case.seed, txn)
                        stats.transactions += 1
            stats.slowest = max(stats.slowest, time.perf_counter() - t0)
        with _limit(self.frame_limit * 4):
            for res in annotated.finish():
                check_result(res, data[res.frame])
            for res in plain.finish():
                last = max(last, res.ts)
                for txn in engine.feed(res):
                    self.rows.add(case.seed, txn)
            for txn in engine.finish(last):
                self.rows.add(case.seed, txn)
                stats.transactions += 1
        for d in (annotated, plain):
            acc = d.accounting
            if acc.read != len(case.frames) or not acc.balanced():
                raise InvariantError(f"accounting {acc.line()} for {len(case.frames)} frames fed")
        if len(self.rows.transactions) > 5000:
            self.tables()

    # --- file cases --------------------------------------------------------------------------
    def file_case(self, number: int, stats: Stats) -> None:
        rng = random.Random(f"pd-analyze fuzz file {self.base_seed} {number}")
        seed = self.seeds[rng.randrange(len(self.seeds))]
        mutated = mutate_file(rng, seed.data)
        path = os.path.join(self.workdir, f"case{number}.pcap")
        with open(path, "wb") as out:
            out.write(mutated)
        d = Dissector(annotate=False, checker=self.checker)
        engine = TransactionEngine()
        read = 0
        t0 = time.perf_counter()
        try:
            with _limit(self.frame_limit * 10):
                try:
                    for raw in capture.frames(path):
                        read += 1
                        if len(raw.data) > capture.MAX_CAPLEN:
                            raise InvariantError(f"frame {raw.number} of {len(raw.data)} bytes above MAX_CAPLEN")
                        for res in d.feed(raw):
                            engine.feed(res)
                except CaptureError as exc:
                    size = len(mutated) if mutated[:2] != b"\x1f\x8b" else float("inf")  # gzip: decompressed
                    if exc.offset is not None and not 0 <= exc.offset <= size:
                        raise InvariantError(f"CaptureError offset {exc.offset} outside the file "
                                             f"({len(mutated)} bytes)") from None
                for res in d.finish():
                    engine.feed(res)
                engine.finish(0.0)
                stats.slowest = max(stats.slowest, (time.perf_counter() - t0) / max(1, read))
                if number % (FILE_CASE_EVERY * REPORT_CASE_EVERY) == 0:
                    self.report_case(path)  # whole tables and pages: not a frame's time
        finally:
            os.unlink(path)
        stats.files += 1
        stats.file_frames += read
        if d.accounting.read != read or not d.accounting.balanced():
            raise InvariantError(f"accounting {d.accounting.line()} for {read} frames read")

    def report_case(self, path: str) -> None:
        """The whole report path on a damaged file: analyze(), the summary, the CSV files, the HTML page."""
        import pd_analyze
        from pd_analyze.output import report

        analysis = pd_analyze.analyze(path, profile="sinamics")
        if not analysis.accounting.balanced.all():
            raise InvariantError(f"analyze() accounting not balanced: {analysis.accounting.to_dict('records')}")
        report.summary(analysis)
        report.write_tables(analysis, os.path.join(self.workdir, "report"), "csv")
        try:
            from pd_analyze.output import html_report
        except ImportError:
            return
        html_report.render(analysis)

    def tables(self) -> None:
        """The report path beyond rows: typed tables, CSV cells, the summary."""
        from pd_analyze.analysis.api import Analysis
        from pd_analyze.analysis.pipeline import CaptureResult
        from pd_analyze.output import report
        from pd_analyze.protocol.frames import Accounting

        analysis = Analysis(self.rows, [CaptureResult("fuzz", Accounting())], "sinamics", 10.0, 5.0)
        report.summary(analysis)
        report.write_tables(analysis, os.path.join(self.workdir, "tables"), "csv")
        self.rows = Rows()


class InvariantError(Exception):
    """A property the analyser promises does not hold."""


def check_result(res: FrameResult, data: bytes) -> None:
    """Fields inside the frame with the frame's bytes; renderers emit inert text and ASCII JSON."""
    for f in _frame_fields(res):
        if f.offset < 0:
            continue
        if f.offset + f.length > len(data) or f.length < 0:
            raise InvariantError(f"frame {res.frame}: field {f.name} at {f.offset}+{f.length} outside "
                            f"{len(data)} bytes")
        if f.raw != data[f.offset:f.offset + f.length]:
            raise InvariantError(f"frame {res.frame}: field {f.name} raw bytes differ from the frame at {f.offset}")
    text = dump.frame_text(res)
    for line in text.split("\n"):
        if not line.isprintable():
            bad = next(ch for ch in line if not ch.isprintable())
            raise InvariantError(f"frame {res.frame}: text dump emits {bad!r} raw")
    line = dump.frame_json(res)
    if not line.isascii():
        raise InvariantError(f"frame {res.frame}: JSON line not ASCII")
    json.loads(line)


def peak_rss_mb() -> float:
    """Peak resident set size of this process in MB (hostile.peak_rss_mb: VmHWM where Linux has it)."""
    from devtools.hostile import peak_rss_mb as peak

    return peak()


def _tmp_root() -> str | None:
    return "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None


# --- processes ------------------------------------------------------------------------------------
_WORKER: Runner | None = None


def _init_worker(paths: list[str], base_seed: int, frame_limit: float) -> None:
    global _WORKER
    _WORKER = Runner(load_seeds(paths), base_seed, frame_limit)


def _work(first: int) -> Stats:
    assert _WORKER is not None
    return _WORKER.run(first, CHUNK)


def fuzz(frames: int, base_seed: int = 1, jobs: int = 1, frame_limit: float = 2.0,
         paths: Sequence[str] | None = None, progress: Callable[[Stats], None] | None = None) -> Stats:
    """Run chunks of cases until at least `frames` mutated frames were fed; the merged statistics."""
    paths = list(paths) if paths is not None else seed_paths()
    total = Stats()
    started = time.perf_counter()
    if jobs <= 1:
        runner = Runner(load_seeds(paths), base_seed, frame_limit)
        first = 0
        while total.mutated < frames:
            total.add(runner.run(first, CHUNK))
            first += CHUNK
            if progress:
                progress(total)
    else:
        import multiprocessing

        ctx = multiprocessing.get_context("fork" if sys.platform.startswith("linux") else "spawn")
        with ctx.Pool(jobs, _init_worker, (paths, base_seed, frame_limit), maxtasksperchild=200) as pool:
            first = 0
            pending = []
            while total.mutated < frames or pending:
                while total.mutated < frames and len(pending) < 2 * jobs:
                    pending.append(pool.apply_async(_work, (first,)))
                    first += CHUNK
                done = pending.pop(0).get()
                total.add(done)
                if progress:
                    progress(total)
    total.seconds = time.perf_counter() - started
    total.peak_rss_mb = max(total.peak_rss_mb, peak_rss_mb())  # the workers report their own
    return total


def replay(number: int, base_seed: int, paths: Sequence[str] | None = None) -> None:
    """One case (and its file case) again, without catching anything: the traceback shows the bug."""
    runner = Runner(load_seeds(list(paths) if paths is not None else seed_paths()), base_seed, 3600.0)
    case = make_case(runner.seeds, number, base_seed)
    print(f"case {number}: seed {case.seed}, {len(case.frames)} frames, {case.mutated} mutated")
    for f in case.frames:
        print(f"  frame {f.number} ts {f.ts!r} linktype {f.linktype} {len(f.data)} bytes: {f.data.hex()}")
    stats = Stats()
    runner.frame_case(case, stats)
    if number % FILE_CASE_EVERY == 0:
        runner.file_case(number, stats)
    runner.tables()
    print("no failure")


def report_text(stats: Stats, frames: int, seed: int, jobs: int) -> str:
    lines = [
        f"pd-analyze fuzz: seed {seed}, {jobs} process(es), target {frames:,} mutated frames",
        f"  cases                 {stats.cases:,}",
        f"  mutated frames fed    {stats.mutated:,} (of {stats.frames:,} frames fed)",
        f"  mutated files read    {stats.files:,} ({stats.file_frames:,} frames)",
        f"  transactions closed   {stats.transactions:,}",
        f"  crashes               {len(stats.crashes)}",
        f"  hangs                 {len(stats.hangs)} (slowest frame {stats.slowest * 1000:.1f} ms)",
        f"  invariant violations  {len(stats.violations)} (accounting read = decoded + skipped + malformed, "
        "fields inside the frame, inert output)",
        f"  peak RSS              {stats.peak_rss_mb:.0f} MB (largest process)",
        f"  time                  {stats.seconds:.0f} s",
    ]
    for kind, items in (("crash", stats.crashes), ("hang", stats.hangs), ("violation", stats.violations)):
        lines += [f"  {kind}: {item}" for item in items[:20]]
        if len(items) > 20:
            lines.append(f"  ... {len(items) - 20} more {kind}es")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m devtools.fuzz", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=100_000, help="mutated frames to feed (default 100000)")
    parser.add_argument("--seed", type=int, default=1, help="base seed; cases are derived from it and their number")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes")
    parser.add_argument("--frame-limit", type=float, default=2.0, help="seconds one frame may take (a hang)")
    parser.add_argument("--replay", type=int, metavar="CASE", help="run one case and show its traceback")
    parser.add_argument("seeds", nargs="*", help="seed captures or directories (default: sample_pcaps, "
                                                 "../shared/captures)")
    args = parser.parse_args(argv)
    paths = seed_paths(args.seeds) if args.seeds else seed_paths()
    if not paths:
        parser.error("no seed captures found")
    if args.replay is not None:
        replay(args.replay, args.seed, paths)
        return 0
    last = [0.0]

    def progress(s: Stats) -> None:
        now = time.perf_counter()
        if now - last[0] > 10:
            last[0] = now
            print(f"  ... {s.mutated:,} mutated frames, {len(s.crashes)} crashes, {len(s.hangs)} hangs, "
                  f"{len(s.violations)} violations", file=sys.stderr, flush=True)

    stats = fuzz(args.frames, args.seed, args.jobs, args.frame_limit, paths, progress)
    print(report_text(stats, args.frames, args.seed, args.jobs))
    return 0 if stats.ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
