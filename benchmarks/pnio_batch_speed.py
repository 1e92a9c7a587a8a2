"""Speed of the columnar decode, `pd_analyze.protocol.pnio_batch.decode`: link, IPv4, UDP, CL-RPC, NDR and the
IOD header with the routes and the flag, per frame.

    python benchmarks/pnio_batch_speed.py                        # 1,000,000 frames, batches of 65,536
    python benchmarks/pnio_batch_speed.py --frames 200000 --batch 16384 --rounds 3 --profile sinamics
    python benchmarks/pnio_batch_speed.py --capture /tmp/pnio.pcap  # made there once, then reused

Generates a parameter-access-only capture (devtools.synth.mixed_capture.make_capture with pnio_share=1.0:
every frame a PNIO RPC request or response, a few other UDP datagrams), cuts it into FrameBatch objects
over the file's bytes (pcap record headers stay between the frames, as a batch reader may leave them), and
times decode() over all batches: the best of --rounds, in microseconds per frame. Reading the file is not
timed. Not a test: its number goes into the report.
"""

from __future__ import annotations

import argparse
import struct
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(1, str(Path(__file__).resolve().parent.parent))  # the repository root: devtools/ is not installed
from devtools.synth.mixed_capture import make_capture
from pd_analyze.capture.batches import FrameBatch
from pd_analyze.protocol import pnio_batch
from pd_analyze.protocol.profidrive_checks import Checker

PCAP_HEADER, RECORD_HEADER = 24, 16


def read_batches(path: Path, size: int) -> list[FrameBatch]:
    """The frames of a classic little-endian pcap (as make_capture writes it) as batches over the file's bytes."""
    buf = path.read_bytes()
    linktype = struct.unpack_from("<I", buf, 20)[0]
    starts, lengths, times = [], [], []
    pos = PCAP_HEADER
    while pos + RECORD_HEADER <= len(buf):
        sec, usec, caplen, _ = struct.unpack_from("<IIII", buf, pos)
        starts.append(pos + RECORD_HEADER)
        lengths.append(caplen)
        times.append(sec + usec / 1e6)
        pos += RECORD_HEADER + caplen
    start, caplen, ts = np.array(starts, np.int64), np.array(lengths, np.int64), np.array(times)
    out = []
    for lo in range(0, len(start), size):
        hi = min(lo + size, len(start))
        out.append(FrameBatch(buf, np.arange(lo + 1, hi + 1, dtype=np.int64), ts[lo:hi],
                              np.full(hi - lo, linktype, np.int32), start[lo:hi], caplen[lo:hi],
                              np.zeros(hi - lo, np.int32), np.round(ts[lo:hi] * 1e6).astype(np.int64) * 1000))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=1_000_000)
    parser.add_argument("--batch", type=int, default=65_536, help="frames per batch")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--profile", default="generic")
    parser.add_argument("--capture", type=Path, help="capture file to use, made there first if missing "
                                                    "(default: a temporary one)")
    args = parser.parse_args()
    checker = Checker.for_profile(args.profile)
    with tempfile.TemporaryDirectory() as tmp:
        path = args.capture or Path(tmp) / "pnio.pcap"
        if not path.exists():
            t0 = time.perf_counter()
            make_capture(path, args.frames, pnio_share=1.0)
            print(f"capture made in {time.perf_counter() - t0:.1f} s")
        batches = read_batches(path, args.batch)
        print(f"capture: {sum(len(b) for b in batches):,} frames, {path.stat().st_size / 1e6:.1f} MB")
    n = sum(len(b) for b in batches)
    best = float("inf")
    for _ in range(args.rounds):
        t0 = time.perf_counter()
        outs = [pnio_batch.decode(b, checker) for b in batches]
        best = min(best, time.perf_counter() - t0)
    routes = np.bincount(np.concatenate([o.frames.route for o in outs]), minlength=4)
    flagged = sum(int(o.pdus.flag.sum()) for o in outs)
    print(f"routes: skip {routes[0]:,}, frames {routes[1]:,}, decide {routes[2]:,}, pnio {routes[3]:,}; "
          f"flagged {flagged:,}")
    print(f"decode: {best:.3f} s for {n:,} frames in {len(batches)} batches of up to {args.batch:,} "
          f"(best of {args.rounds}): {best / n * 1e6:.3f} us per frame")


if __name__ == "__main__":
    main()
