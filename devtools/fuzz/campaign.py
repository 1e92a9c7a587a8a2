"""A fuzzing campaign: chunks of cases run in worker processes until enough mutated frames were fed,
one case replayed without a guard (its traceback shows the bug), and the text report.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence

from devtools.hostile import peak_rss_mb

from .corpus import load_seeds, seed_paths
from .harness import FILE_CASE_EVERY, Runner, Stats
from .mutators import make_case

CHUNK = 64  # cases per worker task


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
