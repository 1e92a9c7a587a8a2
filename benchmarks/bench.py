"""Benchmark pd-analyze against tshark and check every speed and memory target in one run.

    python benchmarks/bench.py                      # 1,000,000 frames per capture, 3 rounds, every step
    python benchmarks/bench.py --frames 200000 --rounds 1 --skip-tshark-v --skip-scale --skip-files

Generates two captures deterministically with the project's generator (8 drives: reads, changes,
multi-parameter requests, NAKs, B5 polling, and --faults of transactions that go wrong: timeouts,
error statuses, RPC faults, unanswered calls, retries):

  dense       every frame PNIO RPC (a capture filtered to the drives' traffic)
  mix         10 % PNIO RPC among cyclic PN-RT and other UDP (--pnio-share)

then times:

  commands    on dense: `pd-analyze report`, `report --jobs N` (N from --jobs, 2 by default; 1 leaves it
              out), `dump --format json`, `params`, `audit`, tshark's PROFIdrive field extraction and
              `tshark -V`; on mix: `report` and tshark's field extraction
  scale       `report`, `params` and `audit` once on a dense capture of 4x the frames (--skip-scale: not run)
  floods      `report` and `report --jobs 2` on 300,000-frame floods of never-answered calls, IP
              fragments and CL fragments (devtools.hostile; --flood-frames; --skip-floods)
  classes     the mix split into the frames the dissector decodes as PNIO RPC and all the others;
              (time - start-up) / frames is the cost per frame of each class
  files       the mix cut into 8 files of consecutive frames; `report DIR --jobs 1` and `--jobs 2`
              (--skip-files: not run)

Every command is a subprocess: wall time is the median of --rounds, peak RSS the largest (wait4's
ru_maxrss of the children: the largest single process, --jobs workers included, not their sum; the
flood rows add the workers' peaks up). Prints the machine, each command as it ends, then two Markdown
tables for the README: the commands, and the targets (target | measured | met?). Without tshark on
PATH the tshark comparisons are n/a. Derived files go to a temporary directory removed at the end.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import pcapfiles  # beside this script, whose directory Python puts first on sys.path

sys.path.insert(1, str(Path(__file__).resolve().parent.parent))  # the repository root: devtools/ is not installed
from devtools.synth.mixed_capture import make_capture

TSHARK_FIELDS = ("frame.number", "pn_io.profidrive.parameter.request_reference",
                 "pn_io.profidrive.parameter.request_id", "pn_io.profidrive.parameter.response_id",
                 "pn_io.profidrive.parameter.no_of_parameters", "pn_io.profidrive.parameter.number",
                 "pn_io.profidrive.parameter.index", "pn_io.profidrive.parameter.format",
                 "pn_io.profidrive.parameter.error_num")
PD = [sys.executable, "-m", "pd_analyze.cli"]
REPORT, DUMP = "dense: pd-analyze report", "dense: pd-analyze dump --format json"
FIELDS, VERBOSE = "dense: tshark PROFIdrive fields", "dense: tshark -V"
MIX_REPORT, MIX_FIELDS = "mix: pd-analyze report", "mix: tshark PROFIdrive fields"
SCALE = "dense: pd-analyze report, 4x frames"
PARAMS, AUDIT = "dense: pd-analyze params", "dense: pd-analyze audit"
PARAMS_SCALE, AUDIT_SCALE = "dense: pd-analyze params, 4x frames", "dense: pd-analyze audit, 4x frames"
FLOOD = "flood of {}: report{}"
FLOOD_KINDS = ("calls", "ip", "cl")
ONLY_PNIO, ONLY_OTHER, STARTUP = "report, PNIO RPC frames only", "report, other frames only", "report, start-up"
MANY = "report DIR of {} files --jobs {}"
PARTS = 8
STARTUP_FRAMES = 10
CLASS_ROUNDS = 3  # the per-frame costs are differences of wall times: one round is too noisy
NOISE = 0.2  # seconds: start-up varies by about this much on a busy machine
OTHER_REPEAT = 8  # copies of the non-PNIO frames timed (900,000 of them take some 0.15 s)


@dataclass
class Timing:
    frames: int
    wall: float  # seconds, median
    rss: int  # kB, largest


def _run(cmd: list[str]) -> tuple[float, int]:
    """Wall seconds and peak RSS (kB) of one command; its stderr is shown if it fails."""
    with tempfile.TemporaryFile() as err:
        start = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here: keep Popen from waiting again
        if proc.returncode != 0:
            err.seek(0)
            tail = err.read()[-2000:].decode(errors="replace")
            raise SystemExit(f"command failed ({proc.returncode}): {' '.join(cmd)}\n{tail}")
    return wall, usage.ru_maxrss


class Bench:
    def __init__(self, rounds: int) -> None:
        self.rounds = rounds
        self.results: dict[str, Timing] = {}

    def time(self, name: str, cmd: list[str], frames: int, rounds: int | None = None) -> Timing:
        runs = [_run(cmd) for _ in range(rounds or self.rounds)]
        t = Timing(frames, statistics.median(r[0] for r in runs), max(r[1] for r in runs))
        self.results[name] = t
        print(f"  {name:<38} {t.wall:8.2f} s  {frames / t.wall:10,.0f} frames/s  {t.rss / 1024:8.1f} MB",
              flush=True)
        return t

    def get(self, name: str) -> Timing | None:
        return self.results.get(name)


def _tshark_version() -> str | None:
    if not shutil.which("tshark"):
        return None
    out = subprocess.run(["tshark", "-v"], capture_output=True, text=True, check=False).stdout
    return (out.splitlines() or ["tshark (version unknown)"])[0]


def _generate(path: Path, frames: int, share: float, label: str = "capture", faults: float = 0.0) -> int:
    t0 = time.perf_counter()
    count = make_capture(path, frames, pnio_share=share, faults=faults)
    print(f"{label}: {count:,} frames ({share:.0%} PNIO RPC), {path.stat().st_size / 1e6:.1f} MB, "
          f"generated in {time.perf_counter() - t0:.1f} s ({path})", flush=True)
    return count


def _fields(path: Path) -> list[str]:
    return ["tshark", "-r", str(path), "-Y", "pn_io.profidrive.parameter.request_reference", "-T", "fields",
            *[x for f in TSHARK_FIELDS for x in ("-e", f)]]


def commands(b: Bench, dense: Path, n_dense: int, mix: Path, n_mix: int, out: Path, jobs: int, tshark: bool,
             verbose: bool) -> None:
    report = [*PD, "report", str(dense), "--out", str(out)]
    b.time(REPORT, report, n_dense)
    if jobs > 1:
        b.time(f"{REPORT} --jobs {jobs}", [*report, "--jobs", str(jobs)], n_dense)
    b.time(DUMP, [*PD, "dump", str(dense), "--format", "json"], n_dense)
    b.time(PARAMS, [*PD, "params", str(dense), "--out", str(out)], n_dense)
    b.time(AUDIT, [*PD, "audit", str(dense), "--fail-on", "never"], n_dense)
    b.time(MIX_REPORT, [*PD, "report", str(mix), "--out", str(out)], n_mix)
    if tshark:
        b.time(FIELDS, _fields(dense), n_dense)
        b.time(MIX_FIELDS, _fields(mix), n_mix)
        if verbose:
            b.time(VERBOSE, ["tshark", "-r", str(dense), "-V"], n_dense)


def scale(b: Bench, tmp: Path, frames: int, faults: float, out: Path) -> None:
    big = tmp / "scale-4x.pcap"
    count = _generate(big, 4 * frames, 1.0, "  4x dense capture", faults)
    b.time(SCALE, [*PD, "report", str(big), "--out", str(out)], count, rounds=1)
    b.time(PARAMS_SCALE, [*PD, "params", str(big), "--out", str(out)], count, rounds=1)
    b.time(AUDIT_SCALE, [*PD, "audit", str(big), "--fail-on", "never"], count, rounds=1)
    big.unlink()  # the largest file of the run: free the disk before the next steps


def floods(b: Bench, tmp: Path, frames: int, out: Path) -> None:
    """Each flood written as a pcap, then reported in one process and with --jobs 2."""
    from devtools import hostile

    for kind in FLOOD_KINDS:
        path = tmp / f"flood-{kind}.pcap"
        with path.open("wb") as f:
            f.write(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 262144, 1))
            for raw in hostile.frames(kind, frames):
                sec = int(raw.ts)
                f.write(struct.pack("<IIII", sec, round((raw.ts - sec) * 1e6), len(raw.data), len(raw.data)))
                f.write(raw.data)
        report = [*PD, "report", str(path), "--out", str(out)]
        b.time(FLOOD.format(kind, ""), report, frames, rounds=1)
        b.time(FLOOD.format(kind, " --jobs 2"), [*report, "--jobs", "2"], frames, rounds=1)
        path.unlink()


@dataclass
class Costs:
    skip: float | None  # us per frame, None when not measurable
    analyse: float | None
    noisy: bool  # a class took less than NOISE seconds beyond start-up: its cost is rough


def classes(b: Bench, path: Path, tmp: Path, out: Path) -> Costs:
    pnio, other, tiny = tmp / "pnio.pcap", tmp / "other.pcap", tmp / "startup.pcap"
    t0 = time.perf_counter()
    n_pnio, n_other = pcapfiles.split_classes(path, pcapfiles.pnio_frames(path), pnio, other)
    n_tiny = pcapfiles.head(other, STARTUP_FRAMES, tiny)
    print(f"  {n_pnio:,} PNIO RPC frames, {n_other:,} others (split in {time.perf_counter() - t0:.1f} s)",
          flush=True)
    if n_other:  # the skipped frames, repeated to run well beyond start-up's variation
        many = tmp / "other-repeated.pcap"
        n_other = pcapfiles.repeat(other, OTHER_REPEAT, many)
        other.unlink()
        many.rename(other)
    rounds = max(CLASS_ROUNDS, b.rounds)
    base = b.time(STARTUP, [*PD, "report", str(tiny), "--out", str(out)], n_tiny, rounds).wall
    costs, noisy = [], False
    for name, file, n in ((ONLY_OTHER, other, n_other), (ONLY_PNIO, pnio, n_pnio)):
        net = b.time(name, [*PD, "report", str(file), "--out", str(out)], n, rounds).wall - base
        costs.append(net / (n - n_tiny) * 1e6 if n > n_tiny and net > 0 else None)
        noisy |= net < NOISE
    for file in (pnio, other, tiny):
        file.unlink()
    return Costs(costs[0], costs[1], noisy)


def many_files(b: Bench, path: Path, count: int, tmp: Path, out: Path) -> None:
    parts = tmp / "parts"
    parts.mkdir()
    pcapfiles.split_even(path, PARTS, parts)
    for jobs in (1, 2):
        b.time(MANY.format(PARTS, jobs), [*PD, "report", str(parts), "--out", str(out), "--jobs", str(jobs)],
               count)
    shutil.rmtree(parts)


def _met(*checks: bool | None) -> str:
    """no if any measured check fails; n/a if one could not be measured; else yes."""
    if any(c is False for c in checks):
        return "no"
    return "n/a" if any(c is None for c in checks) else "yes"


def _speedup(ref: Timing | None, t: Timing | None) -> float | None:
    return ref.wall / t.wall if ref and t else None


def _x(value: float | None, why_not: str) -> str:
    return f"n/a ({why_not})" if value is None else f"{value:.2f}x"


def targets(b: Bench, jobs: int, costs: Costs | None, skip_v: bool) -> list[list[str]]:
    rows = []
    no_tshark = "tshark not on PATH"
    fields, report = b.get(FIELDS), b.results[REPORT]
    r = _speedup(fields, report)
    rows.append(["dense: `report` >= 5x faster than tshark's field extraction", _x(r, no_tshark),
                 _met(None if r is None else r >= 5)])
    par = b.get(f"{REPORT} --jobs {jobs}")
    r = _speedup(fields, par)
    rows.append([f"dense: `report --jobs {max(jobs, 2)}` >= 8x faster than tshark's field extraction",
                 _x(r, no_tshark) if par else "n/a (--jobs 1)", _met(None if r is None else r >= 8)])
    r = _speedup(b.get(MIX_FIELDS), b.get(MIX_REPORT))
    rows.append(["mix: `report` >= 10x faster than tshark's field extraction", _x(r, no_tshark),
                 _met(None if r is None else r >= 10)])
    r = _speedup(b.get(VERBOSE), b.get(DUMP))
    rows.append(["dense: `dump --format json` no slower than `tshark -V`",
                 _x(r, "--skip-tshark-v" if skip_v else no_tshark), _met(None if r is None else r >= 1)])
    rows.append(_rss_row(report, fields, b.get(SCALE)))
    for name, big in ((PARAMS, PARAMS_SCALE), (AUDIT, AUDIT_SCALE)):
        rows.append(_flat_row(name.split(": ")[1], b.results[name], b.get(big)))
    floods = [(name, t) for name, t in b.results.items() if name.startswith("flood of")]
    if floods:
        worst_one = max((t.rss for name, t in floods if "--jobs" not in name), default=0)
        worst_two = max((t.rss for name, t in floods if "--jobs" in name), default=0)
        rows.append(["floods: peak RSS < 200 MiB in one process, < 400 MiB with --jobs 2",
                     f"{worst_one / 1024:.0f} MiB, {worst_two / 1024:.0f} MiB (worst kind)",
                     _met(worst_one < 200 * 1024 and worst_two < 400 * 1024)])
    if costs is not None:
        rows.append(_cost_row(costs))
    one, two = b.get(MANY.format(PARTS, 1)), b.get(MANY.format(PARTS, 2))
    r = _speedup(one, two)
    measured = f"{two.wall:.2f} s against {one.wall:.2f} s ({r:.2f}x)" if one and two else "n/a (--skip-files)"
    rows.append([f"{PARTS} files: `report DIR --jobs 2` faster than `--jobs 1`", measured,
                 _met(None if r is None else r > 1)])
    return rows


def _rss_row(report: Timing, fields: Timing | None, big: Timing | None) -> list[str]:
    below = report.rss < fields.rss if fields else None
    flat = big.rss <= 1.2 * report.rss if big else None
    vs = f"{report.rss / fields.rss:.2f}x tshark's {fields.rss / 1024:.0f} MB" if fields else "tshark's n/a"
    growth = (f"{big.rss / 1024:.0f} MB with 4x the frames ({big.rss / report.rss:.2f}x)" if big
              else "4x capture n/a (--skip-scale)")
    return ["dense: peak RSS of `report` below tshark's, and flat: 4x the frames <= 1.2x the RSS",
            f"{report.rss / 1024:.0f} MB = {vs}; {growth}", _met(below, flat)]


def _flat_row(what: str, one: Timing, big: Timing | None) -> list[str]:
    """`params` keeps one entry per parameter element, `audit` sorts its findings on disk: flat memory."""
    flat = big.rss <= 1.2 * one.rss if big else None
    growth = (f"{one.rss / 1024:.0f} MB; {big.rss / 1024:.0f} MB with 4x the frames ({big.rss / one.rss:.2f}x)"
              if big else f"{one.rss / 1024:.0f} MB; 4x capture n/a (--skip-scale)")
    return [f"dense: peak RSS of `{what.removeprefix('pd-analyze ')}` flat: 4x the frames <= 1.2x the RSS", growth,
            _met(flat)]


def _cost_row(c: Costs) -> list[str]:
    target = "non-PNIO frames skipped >= 5x faster than PNIO frames are analysed"
    if c.skip is None or c.analyse is None:
        return [target, "n/a: a class is empty or no slower than start-up (use more frames)", "n/a"]
    note = f"; rough: under {NOISE} s beyond start-up, use more frames" if c.noisy else ""
    return [target, f"{c.skip:.2f} us against {c.analyse:.2f} us per frame: {c.analyse / c.skip:.1f}x{note}",
            _met(None if c.noisy else c.analyse >= 5 * c.skip)]  # noise alone can pass or fail it


def markdown(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(row) + " |" for row in rows])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1_000_000, help="frames of each capture")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=2, help="also time report --jobs N on the capture (1: do not)")
    ap.add_argument("--faults", type=float, default=0.05, help="share of the transactions that go wrong")
    ap.add_argument("--pnio-share", type=float, default=0.1, help="fraction of PNIO RPC frames in the mix")
    ap.add_argument("--flood-frames", type=int, default=300_000)
    ap.add_argument("--skip-tshark-v", action="store_true", help="do not time tshark -V (nor compare dump)")
    ap.add_argument("--skip-scale", action="store_true", help="do not generate and time the 4x capture")
    ap.add_argument("--skip-floods", action="store_true", help="do not time the floods")
    ap.add_argument("--skip-classes", action="store_true", help="do not time the frame classes")
    ap.add_argument("--skip-files", action="store_true", help=f"do not time the capture cut into {PARTS} files")
    ap.add_argument("--keep", metavar="DIR", help="write the two captures here and keep them")
    args = ap.parse_args()
    tshark = _tshark_version()
    print(f"machine: {os.cpu_count()} cores, Python {sys.version.split()[0]}, "
          f"{tshark or 'tshark not on PATH: the tshark comparisons are skipped (n/a)'}", flush=True)
    b = Bench(args.rounds)
    costs = None
    with tempfile.TemporaryDirectory(prefix="pd-bench-") as tmp_name:
        tmp = Path(tmp_name)
        out = tmp / "out"
        where = Path(args.keep) if args.keep else tmp
        where.mkdir(parents=True, exist_ok=True)
        dense, mix = where / "dense.pcap", where / "mix.pcap"
        n_dense = _generate(dense, args.frames, 1.0, "dense", args.faults)
        n_mix = _generate(mix, args.frames, args.pnio_share, "mix", args.faults)
        print("commands:", flush=True)
        commands(b, dense, n_dense, mix, n_mix, out, args.jobs, tshark is not None, not args.skip_tshark_v)
        if not args.skip_scale:
            print("scale:", flush=True)
            scale(b, tmp, args.frames, args.faults, out)
        if not args.skip_floods:
            print("floods:", flush=True)
            floods(b, tmp, args.flood_frames, out)
        if not args.skip_classes:
            print("frame classes (mix):", flush=True)
            costs = classes(b, mix, tmp, out)
        if not args.skip_files:
            print("many files (mix):", flush=True)
            many_files(b, mix, n_mix, tmp, out)
    print("\n" + markdown(["Command", "Frames", "Wall", "Frames/s", "Peak RSS"],
                          [[name, f"{t.frames:,}", f"{t.wall:.2f} s", f"{t.frames / t.wall:,.0f}",
                            f"{t.rss / 1024:.0f} MB"] for name, t in b.results.items()]))
    print("\n" + markdown(["Target", "Measured", "Met?"], targets(b, args.jobs, costs, args.skip_tshark_v)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
