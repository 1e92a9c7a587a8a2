"""Time reading a capture frame by frame (`capture.frames`) against batch by batch (`capture.batches`).

    python benchmarks/read_batches.py                          # generates 1,000,000 frames (a minute or so)
    python benchmarks/read_batches.py --capture big.pcap       # an existing capture instead
    python benchmarks/read_batches.py --keep /tmp/m1.pcap      # generate it there and keep it for next time
    python benchmarks/read_batches.py --formats pcap,pcapng,gzip

Both readers go through every frame and touch nothing of it: the numbers are the cost of reading alone
(the report path's budget is about 4 us a frame, all of it). pcapng and gzip copies of the capture are
derived from it when asked (--formats). Each reader runs --rounds times, in this process, after one
untimed round that brings the file into the page cache; the best round counts (wall time and CPU time:
on a busy machine the CPU time is the steadier). Batches are checked to hold as many frames as
capture.frames yields.
"""

from __future__ import annotations

import argparse
import gzip
import shutil
import struct
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(1, str(Path(__file__).resolve().parent.parent))  # the repository root: devtools/ is not installed
from devtools.synth.mixed_capture import make_capture
from pd_analyze import capture
from pd_analyze.capture.batches import BATCH_FRAMES, batches


def _pcapng_copy(pcap: Path, out: Path) -> None:
    """The records of a little-endian microsecond pcap (as make_capture writes) as pcapng blocks."""

    def block(btype: int, body: bytes) -> bytes:
        body += b"\x00" * (-len(body) % 4)
        return struct.pack("<II", btype, len(body) + 12) + body + struct.pack("<I", len(body) + 12)

    with pcap.open("rb") as f, out.open("wb") as w:
        head = f.read(24)
        w.write(block(0x0A0D0D0A, struct.pack("<IHHq", 0x1A2B3C4D, 1, 0, -1)))
        w.write(block(1, struct.pack("<HHI", struct.unpack_from("<I", head, 20)[0], 0, 0)))
        while rec := f.read(16):
            sec, usec, caplen, orig = struct.unpack("<IIII", rec)
            ticks = sec * 1_000_000 + usec
            w.write(block(6, struct.pack("<IIIII", 0, ticks >> 32, ticks & 0xFFFFFFFF, caplen, orig) + f.read(caplen)))


def _gzip_copy(path: Path, out: Path) -> None:
    with path.open("rb") as f, gzip.open(out, "wb", compresslevel=6) as w:
        shutil.copyfileobj(f, w, 1 << 20)


def _per_frame(path: str) -> int:
    return sum(1 for _ in capture.frames(path))


def _per_batch(path: str) -> int:
    return sum(len(batch) for batch in batches(path, BATCH_FRAMES))


def _best(read: Callable[[str], int], path: str, rounds: int) -> tuple[int, float, float]:
    """(frames, best wall seconds, best CPU seconds) of `rounds` runs after an untimed one."""
    frames = read(path)
    wall, cpu = float("inf"), float("inf")
    for _ in range(rounds):
        w, c = time.perf_counter(), time.process_time()
        read(path)
        wall, cpu = min(wall, time.perf_counter() - w), min(cpu, time.process_time() - c)
    return frames, wall, cpu


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1_000_000, help="frames to generate (without --capture)")
    ap.add_argument("--capture", metavar="FILE", help="time this classic pcap instead of generating one")
    ap.add_argument("--keep", metavar="FILE", help="write the generated capture here and keep it")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--formats", default="pcap", help="comma-separated: pcap, pcapng, gzip (of the pcap)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="read-batches-") as tmp:
        if args.capture:
            source = Path(args.capture)
        else:
            source = Path(args.keep) if args.keep else Path(tmp) / "capture.pcap"
            started = time.perf_counter()
            count = make_capture(source, args.frames, pnio_share=1.0)
            print(f"generated {count:,} frames (all PNIO RPC) in {time.perf_counter() - started:.0f} s: {source}")
        files = {"pcap": source}
        formats = [f.strip() for f in args.formats.split(",") if f.strip()]
        if "pcapng" in formats:
            files["pcapng"] = Path(tmp) / "capture.pcapng"
            _pcapng_copy(source, files["pcapng"])
        if "gzip" in formats:
            files["gzip"] = Path(tmp) / "capture.pcap.gz"
            _gzip_copy(source, files["gzip"])
        print(f"{'file':<8} {'reader':<16} {'frames':>10} {'wall s':>8} {'us/frame':>9} {'cpu us/frame':>13}")
        for name in formats:
            path = str(files[name])
            results = {}
            for label, read in (("capture.frames", _per_frame), ("capture.batches", _per_batch)):
                frames, wall, cpu = results[label] = _best(read, path, args.rounds)
                print(f"{name:<8} {label:<16} {frames:>10,} {wall:8.2f} {wall / frames * 1e6:9.3f} "
                      f"{cpu / frames * 1e6:13.3f}", flush=True)
            (n1, w1, c1), (n2, w2, c2) = results.values()
            if n1 != n2:
                raise SystemExit(f"{name}: capture.frames read {n1} frames, batches {n2}")
            print(f"{name:<8} batches are {w1 / w2:.1f}x faster (wall), {c1 / c2:.1f}x (cpu)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
