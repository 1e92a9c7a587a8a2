"""Mutation fuzzing of the whole pipeline, seeded from every capture of sample_pcaps/ and ../shared/captures/.

    python -m devtools.fuzz --frames 1000000 --seed 1 --jobs 2     # the long run (README, Robustness)
    python -m devtools.fuzz --frames 20000 --seed 7                  # a short one
    python -m devtools.fuzz --seed 1 --replay 4711                   # one case again, with its traceback

What a case is and what counts as a failure: the package docstring (devtools/fuzz/__init__.py).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from .campaign import fuzz, replay, report_text
from .corpus import seed_paths
from .harness import Stats


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
