"""Benchmark pd-analyze against tshark on one generated mixed PROFIdrive capture.

    python benchmarks/bench.py                      # 1,000,000 frames, 3 rounds
    python benchmarks/bench.py --frames 200000 --rounds 1 --skip-tshark-v

Generates the capture deterministically with the project's generator (cyclic PN-RT, other UDP and
PROFIdrive transactions of 8 drives: reads, changes, multi-parameter, NAKs, B5 polling), then times, in
the same run: `pd-analyze report`, `pd-analyze dump --format json`, tshark's PROFIdrive field extraction
and `tshark -V`, and prints wall time, frames per second, peak RSS and the ratios to tshark.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from pd_analyze.synth.mixed import make_capture

TSHARK_FIELDS = ("frame.number", "pn_io.profidrive.parameter.request_reference",
                 "pn_io.profidrive.parameter.request_id", "pn_io.profidrive.parameter.response_id",
                 "pn_io.profidrive.parameter.no_of_parameters", "pn_io.profidrive.parameter.number",
                 "pn_io.profidrive.parameter.index", "pn_io.profidrive.parameter.format",
                 "pn_io.profidrive.parameter.error_num")


def _run(cmd: list[str], stdout: int | None = subprocess.DEVNULL) -> tuple[float, int]:
    """Wall seconds and peak RSS (kB) of one command."""
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=stdout, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) not in (0,):
        raise SystemExit(f"command failed: {' '.join(cmd)}")
    return wall, usage.ru_maxrss


def bench(path: Path, frames: int, rounds: int, skip_v: bool, jobs: int) -> list[tuple[str, float, int]]:
    exe = [sys.executable, "-m", "pd_analyze.cli"]
    out_dir = tempfile.mkdtemp(prefix="pd-bench-")
    tests = [("pd-analyze report", exe + ["report", str(path), "--out", out_dir])]
    if jobs > 1:
        tests.append((f"pd-analyze report --jobs {jobs}", exe + ["report", str(path), "--out", out_dir,
                                                                "--jobs", str(jobs)]))
    tests += [("pd-analyze dump --format json", exe + ["dump", str(path), "--format", "json"]),
              ("tshark PROFIdrive fields", ["tshark", "-r", str(path), "-Y",
                                            "pn_io.profidrive.parameter.request_reference", "-T", "fields",
                                            *[x for f in TSHARK_FIELDS for x in ("-e", f)]])]
    if not skip_v:
        tests.append(("tshark -V", ["tshark", "-r", str(path), "-V"]))
    results = []
    for name, cmd in tests:
        runs = [_run(cmd) for _ in range(rounds)]
        wall = statistics.median(r[0] for r in runs)
        rss = max(r[1] for r in runs)
        results.append((name, wall, rss))
        print(f"  {name:<32} {wall:8.2f} s  {frames / wall:10,.0f} frames/s  {rss / 1024:8.1f} MB", flush=True)
    shutil.rmtree(out_dir, ignore_errors=True)
    return results


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=1, help="also time report --jobs N")
    ap.add_argument("--skip-tshark-v", action="store_true")
    ap.add_argument("--keep", metavar="FILE", help="write the capture here and keep it")
    ap.add_argument("--pnio-share", type=float, default=0.1,
                    help="fraction of PNIO RPC frames (the rest is cyclic PN-RT and other traffic)")
    args = ap.parse_args()
    path = Path(args.keep or tempfile.mkstemp(suffix=".pcap", prefix="pd-bench-")[1])
    t0 = time.perf_counter()
    count = make_capture(path, args.frames, pnio_share=args.pnio_share)
    print(f"capture: {count:,} frames ({args.pnio_share:.0%} PNIO RPC), {path.stat().st_size / 1e6:.0f} MB, "
          f"generated in {time.perf_counter() - t0:.0f} s ({path})")
    print(f"machine: {os.cpu_count()} cores, Python {sys.version.split()[0]}")
    results = {name: (wall, rss) for name, wall, rss in bench(path, count, args.rounds, args.skip_tshark_v,
                                                               args.jobs)}
    fields = results["tshark PROFIdrive fields"]
    print("ratios (tshark time / pd-analyze time; > 1 means pd-analyze is faster):")
    for name, (wall, rss) in results.items():
        if name.startswith("pd-analyze"):
            ref = results.get("tshark -V") if "dump" in name else fields
            if ref:
                print(f"  {name:<32} {ref[0] / wall:6.2f}x   peak RSS {rss / ref[1]:.2f} of tshark's")
    if not args.keep:
        path.unlink()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
