"""A large mutated capture for `--jobs` and the benchmarks: the fuzz corpus's Ethernet seed frames one
seed after another, over and over, `share` of them mutated (mutators.mutate_frame), written as one
nanosecond pcap. Each seed's clock starts where the seed's does, so time goes backwards wherever one seed
follows another."""

from __future__ import annotations

import random
import struct
from pathlib import Path

from .corpus import load_seeds, seed_paths
from .mutators import mutate_frame


def mutated_capture(path: str | Path, frames: int, share: float = 0.3, seed: int = 1) -> int:
    """Write `frames` frames to `path`; returns the frames written."""
    rng = random.Random(f"pd-analyze mutated capture {seed}")
    pool = [sf for s in load_seeds(seed_paths()) for sf in s.frames if sf.raw.linktype == 1 and 0 <= sf.raw.ts < 2**32]
    written = 0
    with open(path, "wb") as f:
        f.write(struct.pack("<IHHiIII", 0xA1B23C4D, 2, 4, 0, 0, 262144, 1))
        while written < frames:
            for sf in pool[:frames - written]:
                data = mutate_frame(rng, sf, rng.choice(pool).raw.data) if rng.random() < share else sf.raw.data
                ns = round(sf.raw.ts * 1e9)
                f.write(struct.pack("<IIII", ns // 1_000_000_000, ns % 1_000_000_000, len(data), len(data)) + data)
            written += min(len(pool), frames - written)
    return written
