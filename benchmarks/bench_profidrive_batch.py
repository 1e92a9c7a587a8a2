"""Time the columnar PROFIdrive decode (pd_analyze.protocol.profidrive_batch) on the records of a large capture.

    python benchmarks/bench_profidrive_batch.py                  # 1,000,000 frames, 5 rounds
    python benchmarks/bench_profidrive_batch.py --frames 200000 --rounds 3 --profile sinamics

Generates a capture with the project's generator (every frame PNIO RPC: reads, changes,
multi-parameter requests, NAKs, B5 polling of 8 drives), collects its PROFIdrive records once with the
per-frame dissector (one buffer, their offsets and directions), then times `decode` alone on all of
them at once and in batches of the size the report path reads (65,536 frames' worth). Prints the
records, the share decoded regular / unflagged, and the time per record and per frame (median of the
rounds). The per-frame parse and checks of the same records are timed once for comparison.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(1, str(Path(__file__).resolve().parent.parent))  # the repository root: devtools/ is not installed
from devtools.synth.mixed_capture import make_capture
from pd_analyze.model.values import PROFIDRIVE_INDICES
from pd_analyze.protocol import pnio, profidrive, profidrive_batch
from pd_analyze.protocol.dissector import dissect
from pd_analyze.protocol.profidrive_checks import Checker

BATCH_FRAMES = 65_536


def records_of(path: Path) -> tuple[bytes, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The PROFIdrive records of a capture in one buffer: starts, lengths, directions, frame numbers."""
    parts, start, length, response, frames, at = [], [], [], [], [], 0
    for res in dissect(str(path)):
        stub = res.pdu.stub if res.pdu is not None else None
        for block in stub.blocks if stub is not None else ():
            if block.index in PROFIDRIVE_INDICES and block.layout in (pnio.WRITE_REQ, pnio.READ_RES):
                parts.append(block.record)
                start.append(at)
                length.append(len(block.record))
                response.append(stub.response)
                frames.append(res.frame)
                at += len(block.record)
    return (b"".join(parts), np.array(start, np.int64), np.array(length, np.int64), np.array(response, bool),
            np.array(frames, np.int64))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--profile", default="generic")
    args = ap.parse_args()
    checker = Checker.for_profile(args.profile)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "mixed.pcap"
        t0 = time.perf_counter()
        frames = make_capture(path, args.frames, pnio_share=1.0)
        print(f"capture: {frames:,} frames ({time.perf_counter() - t0:.1f} s to make)")
        t0 = time.perf_counter()
        buf, start, length, response, numbers = records_of(path)
        print(f"records: {len(start):,} ({response.sum():,} responses), collected per frame in "
              f"{time.perf_counter() - t0:.1f} s")
    d = profidrive_batch.decode(buf, start, length, response, checker)
    r = d.records
    print(f"regular {r.regular.mean():.1%}, unflagged {(~r.flag).mean():.1%}, addresses {len(d.addresses.record):,}, "
          f"blocks {len(d.blocks.record):,}")
    whole = []
    for _ in range(args.rounds):
        t0 = time.perf_counter()
        profidrive_batch.decode(buf, start, length, response, checker)
        whole.append(time.perf_counter() - t0)
    # batches as the report path cuts them: by frame number
    cuts = np.searchsorted(numbers, np.arange(BATCH_FRAMES, frames + BATCH_FRAMES, BATCH_FRAMES), side="right")
    bounds = list(zip(np.concatenate([[0], cuts[:-1]]), cuts, strict=True))
    batched = []
    for _ in range(args.rounds):
        t0 = time.perf_counter()
        for lo, hi in bounds:
            profidrive_batch.decode(buf, start[lo:hi], length[lo:hi], response[lo:hi], checker)
        batched.append(time.perf_counter() - t0)
    per_frame = _per_frame(buf, start, length, response, checker)
    n = len(start)
    for name, times in (("one batch", whole), (f"batches of {BATCH_FRAMES:,} frames", batched)):
        t = statistics.median(times)
        print(f"decode, {name}: {t:.3f} s = {t / n * 1e6:.3f} us per record, {t / frames * 1e6:.3f} us per frame")
    print(f"per-frame parse_* + Checker of the same records: {per_frame / n * 1e6:.2f} us per record")


def _per_frame(buf: bytes, start: np.ndarray, length: np.ndarray, response: np.ndarray, checker: Checker) -> float:
    t0 = time.perf_counter()
    for s, n, resp in zip(start.tolist(), length.tolist(), response.tolist(), strict=True):
        found: list = []
        data = buf[s:s + n]
        if resp:
            checker.response(profidrive.parse_response(data, 1, found), 1, None)
        else:
            checker.request(profidrive.parse_request(data, 1, found), 1)
    return time.perf_counter() - t0


if __name__ == "__main__":
    main()
