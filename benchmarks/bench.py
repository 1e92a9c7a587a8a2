"""Benchmark pd-analyze against tshark and check every speed and memory target in one run.

    python benchmarks/bench.py                      # 1,000,000 frames per capture, 3 rounds, every step
    python benchmarks/bench.py --frames 20000 --rounds 1 --flood-frames 5000    # a quick check of the script

Generates three captures deterministically with the project's generators:

  dense       devtools.synth.mixed_capture: 8 drives, every frame PNIO RPC (a capture filtered to the drives'
              traffic): reads, changes, multi-parameter requests, NAKs, B5 polling and --faults (5 %) of
              transactions that go wrong (timeouts, error statuses, RPC faults, unanswered calls, retries)
  mix         the same with 10 % PNIO RPC among cyclic PN-RT and other UDP (--pnio-share)
  fault-rich  devtools.synth.fault_rich: a commissioning capture with faults on every drive (issue #23's
              shape: two controllers, four drives, 8 % NAKs, record errors, timeouts, reference mismatches,
              reused references, duplicated frames, header fields out of range, snaplen cuts, broken
              requests, B5 polling and busy drives, half the frames priority-tagged)

then runs these steps, each a subprocess, timed (wall time: the median of --rounds; peak RSS: the largest,
wait4's ru_maxrss of the children: the largest single process, --jobs workers included, not their sum):

  commands    `report` and tshark's PROFIdrive field extraction (`tshark -Y
              pn_io.profidrive.parameter.request_reference -T fields -e ...`) on each capture
  share       `report -v` once more, untimed: the share of PNIO RPC frames the columns decoded, from its
              stderr line "N of M PNIO RPC frames decoded by the columns" (n/a without it) (--skip-share)
  dumps       issue #24 on dense and fault-rich: `dump -Y` selecting about 1 % of the frames against
              `tshark -Y ... -V` (both counted: the same frames?), `dump -Y 'pd.addr.pnu == 964'` against
              `tshark -Y 'pn_io.profidrive.parameter.number == 964' -V`, `dump -T fields` of three fields against
              tshark's, `dump` text of every frame against `tshark -V` (--skip-tshark-v leaves these two out),
              `dump --format json` against `tshark -T json`; `annotate`, `extract --verdict nak`, `annotate -Y` and
              `extract -Y` of one parameter, `params`
              and `audit` against `report` (--skip-dumps)
  jobs        issue #25 on dense and fault-rich: `report`, `audit` and `params` with --jobs N (--jobs, 2 by
              default; 1 leaves the step out) against one process, their output files and stdout compared
              byte for byte; then `report` against `report --jobs N` (compared likewise) on a capture of
              --frames frames, 30 % of them mutated (devtools.fuzz.mutated: time goes backwards where one
              seed follows another) and on each flood of devtools.hostile (--flood-frames)
  scale       `report` on a dense and a fault-rich capture of 4x the frames, `params` and `audit` on the
              dense one (--skip-scale)
  floods      each of devtools.hostile's floods (--flood-frames, 300,000 by default): never-answered calls,
              CL fragments, IP fragments, the three mixed, half-finished transactions, never-answered
              40-parameter change requests: `report` against tshark's field extraction on the same file, and
              whether the summary's "N frames read" is the frames in the file (--skip-floods)
  startup     `report` of a 10-frame capture (--skip-startup)
  classes     the mix split into the frames the dissector decodes as PNIO RPC and all the others;
              (time - start-up) / frames is the cost per frame of each class (--skip-classes)
  files       the mix cut into 8 files of consecutive frames; `report DIR --jobs 1` and `--jobs 2`
              (--skip-files)

Prints the machine, each command as it ends, then Markdown tables for the README: the commands, the
columns' share, and the targets (target | measured | met?; bench_targets.py). Without tshark on PATH the
tshark comparisons are n/a. Derived files go to a temporary directory removed at the end (--keep DIR keeps
the three captures).
"""

from __future__ import annotations

import argparse
import compileall
import filecmp
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import bench_targets  # beside this script, whose directory Python puts first on sys.path
import pcapfiles

sys.path.insert(1, str(Path(__file__).resolve().parent.parent))  # the repository root: devtools/ is not installed
import pd_analyze
from devtools import hostile
from devtools.fuzz.mutated import mutated_capture
from devtools.synth.fault_rich import make_fault_rich
from devtools.synth.mixed_capture import make_capture

TSHARK_FIELDS = ("frame.number", "pn_io.profidrive.parameter.request_reference",
                 "pn_io.profidrive.parameter.request_id", "pn_io.profidrive.parameter.response_id",
                 "pn_io.profidrive.parameter.no_of_parameters", "pn_io.profidrive.parameter.number",
                 "pn_io.profidrive.parameter.index", "pn_io.profidrive.parameter.format",
                 "pn_io.profidrive.parameter.error_num")
DUMP_FIELDS = ("frame.number", "pn_io.profidrive.parameter.request_reference", "pn_io.profidrive.parameter.number")
ONE_PERCENT = "pn_io.profidrive.parameter.request_reference in {1..5}"  # 5 of 255 references: about 1 %
ONE_PNU = ("pd.addr.pnu == 964", "pn_io.profidrive.parameter.number == 964")  # the frames of one parameter:
# judged on the columns first (output.dump_prefilter), tshark's name of the same field
PD = [sys.executable, "-m", "pd_analyze.cli"]
DENSE, MIX, FAULT = "dense", "mix", "fault-rich"
CAPTURES = (DENSE, FAULT, MIX)
DUMPED = (DENSE, FAULT)  # the captures of issue #24's and #25's targets
DECODED = re.compile(r"(\d+) of (\d+) PNIO RPC frames decoded by the columns")
FRAMES_READ = re.compile(r"(\d+) frames read")
FRAME_LINE = re.compile(rb"^Frame \d+[: ]", re.MULTILINE)  # a frame's first line in `dump` and in `tshark -V`
STARTUP_FRAMES = 10
CLASS_ROUNDS = 3  # the per-frame costs are differences of wall times: one round is too noisy
NOISE = 0.2  # seconds: start-up varies by about this much on a busy machine
OTHER_REPEAT = 8  # copies of the non-PNIO frames timed (900,000 of them take some 0.15 s)


def name(cap: str, what: str) -> str:
    """A row of the commands table: `dense: pd-analyze report`, `fault-rich: tshark -V`, ..."""
    return f"{cap}: {what}"


@dataclass
class Timing:
    frames: int
    wall: float  # seconds, median
    rss: int  # kB, largest


def _run(cmd: list[str], stdout: Path | None = None) -> tuple[float, int]:
    """Wall seconds and peak RSS (kB) of one command (stdout to a file, else discarded); its stderr is shown
    if it fails."""
    with tempfile.TemporaryFile() as err, (stdout.open("wb") if stdout else open(os.devnull, "wb")) as out:
        start = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here: keep Popen from waiting again
        if proc.returncode != 0:
            err.seek(0)
            tail = err.read()[-2000:].decode(errors="replace")
            raise SystemExit(f"command failed ({proc.returncode}): {' '.join(cmd)}\n{tail}")
    return wall, usage.ru_maxrss


@dataclass
class Bench:
    rounds: int
    results: dict[str, Timing] = field(default_factory=dict)
    notes: dict[str, str] = field(default_factory=dict)  # what a step found besides times (counts, yes/no)

    def time(self, label: str, cmd: list[str], frames: int, rounds: int | None = None,
             stdout: Path | None = None) -> Timing:
        runs = [_run(cmd, stdout) for _ in range(rounds or self.rounds)]
        t = Timing(frames, statistics.median(r[0] for r in runs), max(r[1] for r in runs))
        self.results[label] = t
        print(f"  {label:<50} {t.wall:8.2f} s  {frames / t.wall:10,.0f} frames/s  {t.rss / 1024:8.1f} MB",
              flush=True)
        return t

    def get(self, label: str) -> Timing | None:
        return self.results.get(label)


def _tshark_version() -> str | None:
    if not shutil.which("tshark"):
        return None
    out = subprocess.run(["tshark", "-v"], capture_output=True, text=True, check=False).stdout
    return (out.splitlines() or ["tshark (version unknown)"])[0]


def _generate(path: Path, frames: int, kind: str, args: argparse.Namespace, label: str) -> int:
    t0 = time.perf_counter()
    if kind == FAULT:
        count = make_fault_rich(path, frames, truth=False)["frames"]
        what = "issue #23's fault-rich shape"
    else:
        share = 1.0 if kind == DENSE else args.pnio_share
        count = make_capture(path, frames, pnio_share=share, faults=args.faults)
        what = f"{share:.0%} PNIO RPC"
    print(f"{label}: {count:,} frames ({what}), {path.stat().st_size / 1e6:.1f} MB, "
          f"generated in {time.perf_counter() - t0:.1f} s ({path})", flush=True)
    return count


def _fields(path: Path) -> list[str]:
    return ["tshark", "-r", str(path), "-Y", "pn_io.profidrive.parameter.request_reference", "-T", "fields",
            *[x for f in TSHARK_FIELDS for x in ("-e", f)]]


def _same_output(one: Path, two: Path) -> bool:
    """Two runs' outputs byte for byte: a file each, two directories holding the same files, or nothing."""
    if not one.exists() and not two.exists():
        return True  # (audit writes no directory: its standard output is compared)
    if one.is_file() or two.is_file():
        return one.is_file() and two.is_file() and filecmp.cmp(one, two, shallow=False)
    names = sorted(p.relative_to(one) for p in one.rglob("*") if p.is_file())
    if names != sorted(p.relative_to(two) for p in two.rglob("*") if p.is_file()):
        return False
    return all(filecmp.cmp(one / n, two / n, shallow=False) for n in names)


@dataclass
class Run:
    """One benchmark run's files and settings."""

    args: argparse.Namespace
    tmp: Path
    tshark: bool
    paths: dict[str, Path] = field(default_factory=dict)
    frames: dict[str, int] = field(default_factory=dict)

    def out(self, cap: str, what: str) -> Path:
        """Where a command writes: its --out directory (and `<that>.stdout` its standard output)."""
        path = self.tmp / "out" / cap / what.replace(" ", "_")
        path.parent.mkdir(parents=True, exist_ok=True)
        return path


def commands(b: Bench, r: Run) -> None:
    for cap in r.paths:
        path, n = r.paths[cap], r.frames[cap]
        out = r.out(cap, "report-1")
        b.time(name(cap, "pd-analyze report"), [*PD, "report", str(path), "--out", str(out)], n,
               stdout=out.with_suffix(".stdout"))
        if r.tshark:
            b.time(name(cap, "tshark PROFIdrive fields"), _fields(path), n)


def share(b: Bench, r: Run) -> None:
    """`report -v`, untimed: the columns' share of the PNIO RPC frames, if the command says it."""
    for cap, path in r.paths.items():
        proc = subprocess.run([*PD, "report", str(path), "-v", "--out", str(r.out(cap, "report-v"))],
                              capture_output=True, text=True, check=False)
        m = DECODED.search(proc.stderr) if proc.returncode == 0 else None
        b.notes[name(cap, "decoded")] = (f"{int(m[1]):,} of {int(m[2]):,} ({int(m[1]) / max(int(m[2]), 1):.1%})"
                                         if m else "n/a")
        print(f"  {cap}: PNIO RPC frames decoded by the columns: {b.notes[name(cap, 'decoded')]}", flush=True)


def dumps(b: Bench, r: Run) -> None:
    """Issue #24: dumps and the commands that print frames, against tshark and `report`."""
    for cap in DUMPED:
        if cap not in r.paths:
            continue
        path, n = str(r.paths[cap]), r.frames[cap]
        mine, theirs = r.out(cap, "dump-Y.txt"), r.out(cap, "tshark-Y.txt")
        b.time(name(cap, "pd-analyze dump -Y (about 1 %)"), [*PD, "dump", path, "-Y", ONE_PERCENT], n, stdout=mine)
        printed = len(FRAME_LINE.findall(mine.read_bytes()))
        note = f"{printed:,} frames ({printed / n:.1%})"
        if r.tshark:
            b.time(name(cap, "tshark -Y -V (about 1 %)"), ["tshark", "-r", path, "-Y", ONE_PERCENT, "-V"], n,
                   stdout=theirs)
            other = len(FRAME_LINE.findall(theirs.read_bytes()))
            note += f", tshark {other:,}: the same frames {'yes' if other == printed else 'no'}"
        b.notes[name(cap, "dump -Y")] = note
        mine.unlink()
        theirs.unlink(missing_ok=True)
        _one_parameter(b, r, cap)
        fields = [x for f in DUMP_FIELDS for x in ("-e", f)]
        b.time(name(cap, "pd-analyze dump -T fields"), [*PD, "dump", path, "-T", "fields", *fields], n)
        if not r.args.skip_tshark_v:
            b.time(name(cap, "pd-analyze dump (text)"), [*PD, "dump", path], n)
        b.time(name(cap, "pd-analyze dump --format json"), [*PD, "dump", path, "--format", "json"], n)
        if r.tshark:
            b.time(name(cap, "tshark -T fields"), ["tshark", "-r", path, "-T", "fields", *fields], n)
            if not r.args.skip_tshark_v:
                b.time(name(cap, "tshark -V"), ["tshark", "-r", path, "-V"], n)
            b.time(name(cap, "tshark -T json"), ["tshark", "-r", path, "-T", "json"], n)
        annotated, extracted = r.out(cap, "annotated.pcapng"), r.out(cap, "extracted.pcap")
        b.time(name(cap, "pd-analyze annotate"), [*PD, "annotate", path, "-w", str(annotated)], n)
        b.time(name(cap, "pd-analyze extract --verdict nak"),
               [*PD, "extract", path, "-w", str(extracted), "--verdict", "nak"], n)
        b.time(name(cap, "pd-analyze annotate -Y pnu"), [*PD, "annotate", path, "-w", str(annotated), "-Y", ONE_PNU[0]],
               n)
        b.time(name(cap, "pd-analyze extract -Y pnu"), [*PD, "extract", path, "-w", str(extracted), "-Y", ONE_PNU[0]],
               n)
        annotated.unlink()
        extracted.unlink()
        _params_audit(b, r, cap, 1)


def _one_parameter(b: Bench, r: Run, cap: str) -> None:
    """`dump -Y 'pd.addr.pnu == 964'` against `tshark -Y 'pn_io.profidrive.parameter.number == 964' -V`, both
    outputs' frames counted."""
    path, n = str(r.paths[cap]), r.frames[cap]
    mine, theirs = r.out(cap, "dump-pnu.txt"), r.out(cap, "tshark-pnu.txt")
    b.time(name(cap, "pd-analyze dump -Y pnu"), [*PD, "dump", path, "-Y", ONE_PNU[0]], n, stdout=mine)
    printed = len(FRAME_LINE.findall(mine.read_bytes()))
    note = f"{printed:,} frames"
    if r.tshark:
        b.time(name(cap, "tshark -Y pnu -V"), ["tshark", "-r", path, "-Y", ONE_PNU[1], "-V"], n, stdout=theirs)
        other = len(FRAME_LINE.findall(theirs.read_bytes()))
        note += f", tshark {other:,}: the same frames {'yes' if other == printed else 'no'}"
    b.notes[name(cap, "dump -Y pnu")] = note
    mine.unlink()
    theirs.unlink(missing_ok=True)


def _params_audit(b: Bench, r: Run, cap: str, jobs: int) -> None:
    """`params` and `audit` of a capture in `jobs` processes, their outputs kept for the jobs step."""
    suffix = "" if jobs == 1 else f" --jobs {jobs}"
    path, n, more = str(r.paths[cap]), r.frames[cap], ([] if jobs == 1 else ["--jobs", str(jobs)])
    if b.get(name(cap, f"pd-analyze params{suffix}")) is None:
        out = r.out(cap, f"params-{jobs}")
        b.time(name(cap, f"pd-analyze params{suffix}"), [*PD, "params", path, "--out", str(out), *more], n,
               stdout=out.with_suffix(".stdout"))
    if b.get(name(cap, f"pd-analyze audit{suffix}")) is None:
        b.time(name(cap, f"pd-analyze audit{suffix}"), [*PD, "audit", path, "--fail-on", "never", *more], n,
               stdout=r.out(cap, f"audit-{jobs}").with_suffix(".stdout"))


def jobs(b: Bench, r: Run) -> None:
    """Issue #25: report, audit and params of one capture in N processes against one, output compared."""
    n_jobs = r.args.jobs
    for cap in DUMPED:
        if cap not in r.paths:
            continue
        path, n = str(r.paths[cap]), r.frames[cap]
        out = r.out(cap, f"report-{n_jobs}")
        b.time(name(cap, f"pd-analyze report --jobs {n_jobs}"),
               [*PD, "report", path, "--out", str(out), "--jobs", str(n_jobs)], n, stdout=out.with_suffix(".stdout"))
        _params_audit(b, r, cap, 1)
        _params_audit(b, r, cap, n_jobs)
        for what in ("report", "params", "audit"):
            one, many = r.out(cap, f"{what}-1"), r.out(cap, f"{what}-{n_jobs}")
            same = all(_same_output(x, y) for x, y in ((one, many), (one.with_suffix(".stdout"),
                                                                     many.with_suffix(".stdout"))))
            b.notes[name(cap, f"{what} --jobs identical")] = "yes" if same else "no"
            print(f"  {cap}: {what} --jobs {n_jobs} output identical to one process: {'yes' if same else 'no'}",
                  flush=True)
    mutated = r.tmp / "mutated.pcap"
    _jobs_pair(b, r, "mutated", mutated, mutated_capture(mutated, r.args.frames), n_jobs)
    for kind in hostile.ALL_KINDS:
        path = r.tmp / f"flood-{kind}.pcap"
        _jobs_pair(b, r, f"flood of {kind}", path, hostile.write_pcap(kind, r.args.flood_frames, path), n_jobs)


def _jobs_pair(b: Bench, r: Run, cap: str, path: Path, n: int, n_jobs: int) -> None:
    """`report` of a capture in one process and in `n_jobs`, timed once each, output compared; the capture
    and the outputs removed after."""
    outs = []
    for jobs_ in (1, n_jobs):
        out = r.out(cap, f"jobs-report-{jobs_}")
        more = [] if jobs_ == 1 else ["--jobs", str(jobs_)]
        b.time(name(cap, f"pd-analyze report{' --jobs ' + str(jobs_) if more else ''}"),
               [*PD, "report", str(path), "--out", str(out), *more], n, rounds=1, stdout=out.with_suffix(".stdout"))
        outs.append(out)
    same = _same_output(*outs) and _same_output(*(o.with_suffix(".stdout") for o in outs))
    b.notes[name(cap, "report --jobs identical")] = "yes" if same else "no"
    print(f"  {cap}: report --jobs {n_jobs} output identical to one process: {'yes' if same else 'no'}", flush=True)
    path.unlink()
    for out in outs:
        shutil.rmtree(out, ignore_errors=True)


def scale(b: Bench, r: Run) -> None:
    for cap in (DENSE, FAULT):
        if cap not in r.paths:
            continue
        big = r.tmp / f"scale-4x-{cap}.pcap"
        count = _generate(big, 4 * r.args.frames, cap, r.args, f"  4x {cap} capture")
        out = r.out(cap, "scale")
        b.time(name(cap, "pd-analyze report, 4x frames"), [*PD, "report", str(big), "--out", str(out)], count,
               rounds=1)
        if cap == DENSE:
            b.time(name(cap, "pd-analyze params, 4x frames"), [*PD, "params", str(big), "--out", str(out)], count,
                   rounds=1)
            b.time(name(cap, "pd-analyze audit, 4x frames"), [*PD, "audit", str(big), "--fail-on", "never"],
                   count, rounds=1)
        big.unlink()  # the largest file of the run: free the disk before the next steps


def floods(b: Bench, r: Run) -> None:
    """Each flood written as a pcap: `report` (its summary's frame count checked) and tshark's extraction."""
    frames = r.args.flood_frames
    for kind in hostile.ALL_KINDS:
        path = r.tmp / f"flood-{kind}.pcap"
        hostile.write_pcap(kind, frames, path)
        out = r.out("flood", kind)
        b.time(f"flood of {kind}: report", [*PD, "report", str(path), "--out", str(out)], frames, rounds=1,
               stdout=out.with_suffix(".stdout"))
        m = FRAMES_READ.search(out.with_suffix(".stdout").read_text())
        b.notes[f"flood of {kind}: frames read"] = m[1] if m else "n/a"
        if r.tshark:
            b.time(f"flood of {kind}: tshark PROFIdrive fields", _fields(path), frames, rounds=1)
        path.unlink()
        shutil.rmtree(out, ignore_errors=True)


def startup(b: Bench, r: Run) -> float:
    tiny = r.tmp / "startup.pcap"
    n_tiny = pcapfiles.head(r.paths[MIX], STARTUP_FRAMES, tiny)
    t = b.time(bench_targets.STARTUP, [*PD, "report", str(tiny), "--out", str(r.out(MIX, "startup"))], n_tiny,
               max(CLASS_ROUNDS, b.rounds))
    return t.wall


def classes(b: Bench, r: Run, base: float) -> bench_targets.Costs:
    path = r.paths[MIX]
    pnio, other = r.tmp / "pnio.pcap", r.tmp / "other.pcap"
    t0 = time.perf_counter()
    n_pnio, n_other = pcapfiles.split_classes(path, pcapfiles.pnio_frames(path), pnio, other)
    print(f"  {n_pnio:,} PNIO RPC frames, {n_other:,} others (split in {time.perf_counter() - t0:.1f} s)",
          flush=True)
    if n_other:  # the skipped frames, repeated to run well beyond start-up's variation
        many = r.tmp / "other-repeated.pcap"
        n_other = pcapfiles.repeat(other, OTHER_REPEAT, many)
        other.unlink()
        many.rename(other)
    rounds = max(CLASS_ROUNDS, b.rounds)
    costs, noisy = [], False
    for label, file, n in ((bench_targets.ONLY_OTHER, other, n_other), (bench_targets.ONLY_PNIO, pnio, n_pnio)):
        net = b.time(label, [*PD, "report", str(file), "--out", str(r.out(MIX, "classes"))], n, rounds).wall - base
        costs.append(net / (n - STARTUP_FRAMES) * 1e6 if n > STARTUP_FRAMES and net > 0 else None)
        noisy |= net < NOISE
    for file in (pnio, other):
        file.unlink()
    return bench_targets.Costs(costs[0], costs[1], noisy, NOISE)


def many_files(b: Bench, r: Run) -> None:
    parts = r.tmp / "parts"
    parts.mkdir()
    pcapfiles.split_even(r.paths[MIX], bench_targets.PARTS, parts)
    for n_jobs in (1, 2):
        b.time(bench_targets.MANY.format(bench_targets.PARTS, n_jobs),
               [*PD, "report", str(parts), "--out", str(r.out(MIX, "parts")), "--jobs", str(n_jobs)], r.frames[MIX])
    shutil.rmtree(parts)


def markdown(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(row) + " |" for row in rows])


def _options() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1_000_000, help="frames of each capture")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=2, help="processes of the jobs step (1: leave it out)")
    ap.add_argument("--faults", type=float, default=0.05, help="share of the dense and mix transactions that go "
                                                               "wrong")
    ap.add_argument("--pnio-share", type=float, default=0.1, help="fraction of PNIO RPC frames in the mix")
    ap.add_argument("--flood-frames", type=int, default=300_000)
    for step, what in (("fault-rich", "generate and time the fault-rich capture"),
                       ("share", "run report -v for the columns' share"),
                       ("dumps", "time the dumps and the commands that print frames (issue #24)"),
                       ("tshark-v", "time tshark -V and the text dump"), ("scale", "generate and time the 4x captures"),
                       ("floods", "time the floods"), ("startup", "time the start-up"),
                       ("classes", "time the frame classes"),
                       ("files", f"time the mix cut into {bench_targets.PARTS} files")):
        ap.add_argument(f"--skip-{step}", action="store_true", help=f"do not {what}")
    ap.add_argument("--keep", metavar="DIR", help="write the three captures here and keep them")
    return ap.parse_args()


def main() -> int:
    args = _options()
    # An installed package starts from its compiled bytecode (an install compiles it); where the environment
    # forbids writing bytecode, every pd-analyze start would time the compiler too (about 0.25 s), so the
    # package is compiled once here and the commands may use it.
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    compileall.compile_dir(str(Path(pd_analyze.__file__).parent), quiet=1)
    tshark = _tshark_version()
    print(f"machine: {os.cpu_count()} cores, Python {sys.version.split()[0]}, "
          f"{tshark or 'tshark not on PATH: the tshark comparisons are skipped (n/a)'}", flush=True)
    b = Bench(args.rounds)
    costs, base = None, None
    with tempfile.TemporaryDirectory(prefix="pd-bench-") as tmp_name:
        r = Run(args, Path(tmp_name), tshark is not None)
        where = Path(args.keep) if args.keep else r.tmp
        where.mkdir(parents=True, exist_ok=True)
        for cap in CAPTURES:
            if cap != FAULT or not args.skip_fault_rich:
                r.paths[cap] = where / f"{cap}.pcap"
                r.frames[cap] = _generate(r.paths[cap], args.frames, cap, args, cap)
        steps = [("commands", lambda: commands(b, r), True), ("share", lambda: share(b, r), not args.skip_share),
                 ("dumps (issue #24)", lambda: dumps(b, r), not args.skip_dumps),
                 ("jobs (issue #25)", lambda: jobs(b, r), args.jobs > 1),
                 ("scale", lambda: scale(b, r), not args.skip_scale),
                 ("floods", lambda: floods(b, r), not args.skip_floods)]
        for title, step, wanted in steps:
            if wanted:
                print(f"{title}:", flush=True)
                step()
        if not (args.skip_startup and args.skip_classes):
            print("start-up and frame classes (mix):", flush=True)
            base = startup(b, r)
            if not args.skip_classes:
                costs = classes(b, r, base)
        if not args.skip_files:
            print("many files (mix):", flush=True)
            many_files(b, r)
    print("\n" + markdown(["Command", "Frames", "Wall", "Frames/s", "Peak RSS"],
                          [[label, f"{t.frames:,}", f"{t.wall:.2f} s", f"{t.frames / t.wall:,.0f}",
                            f"{t.rss / 1024:.0f} MB"] for label, t in b.results.items()]))
    if not args.skip_share:
        print("\n" + markdown(["Capture", "PNIO RPC frames decoded by the columns"],
                              [[cap, b.notes.get(name(cap, "decoded"), "n/a")] for cap in r.paths]))
    rows = bench_targets.targets(b, list(r.paths), args, costs, tshark is not None, hostile.ALL_KINDS)
    print("\n" + markdown(["Target", "Measured", "Met?"], rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
