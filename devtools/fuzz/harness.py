"""The fuzz harness: a Runner feeds a case's frames through the dump path (`Dissector(annotate=True)`,
the check marks, the text and JSON renderers) and the report path (the analysis engine, in batches of
a few frames so every part of it meets the case, and its table rows), and a mutated seed file through
the engine (one in 32 of them
through `analyze()`, the summary, the CSV files and the HTML report), and records what counts as a
failure: a crash, a hang (SIGALRM after `frame_limit` seconds), or a broken invariant (accounting,
field bounds, inert output; `check_result`).
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import signal
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from devtools.hostile import peak_rss_mb
from pd_analyze import capture
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.analysis.engine.files import analyze_file
from pd_analyze.analysis.engine.run import analyze_frames
from pd_analyze.analysis.rows import Rows
from pd_analyze.capture import CaptureError
from pd_analyze.output import dump
from pd_analyze.protocol.dissector import Dissector
from pd_analyze.protocol.frames import FrameResult
from pd_analyze.protocol.profidrive_checks import Checker

from .corpus import Seed, frame_fields
from .mutators import Case, make_case, mutate_file

FILE_CASE_EVERY = 8  # every 8th case also mutates a seed file
REPORT_CASE_EVERY = 32  # every 32nd mutated file also goes through analyze(), the CSV files and the HTML page


class HangError(Exception):
    """Raised by the alarm when one frame or file takes longer than the limit."""


class InvariantError(Exception):
    """A property the analyser promises does not hold."""


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
        self.settings = Settings(profile="sinamics")
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
        for raw in case.frames:
            t0 = time.perf_counter()
            with _limit(self.frame_limit):
                for res in annotated.feed(raw):
                    check_result(res, data[res.frame])
            stats.slowest = max(stats.slowest, time.perf_counter() - t0)
        t0 = time.perf_counter()
        with _limit(self.frame_limit * max(4, len(case.frames))):
            for res in annotated.finish():
                check_result(res, data[res.frame])
            before = self.rows.transaction_count()
            result = analyze_frames(case.frames, self.settings, self.rows, case.seed, batch_frames=7)
            stats.transactions += self.rows.transaction_count() - before
        stats.slowest = max(stats.slowest, (time.perf_counter() - t0) / max(1, len(case.frames)))
        for acc in (annotated.accounting, result.accounting):
            if acc.read != len(case.frames) or not acc.balanced():
                raise InvariantError(f"accounting {acc.line()} for {len(case.frames)} frames fed")
        if self.rows.transaction_count() > 5000:
            self.tables()

    # --- file cases --------------------------------------------------------------------------
    def file_case(self, number: int, stats: Stats) -> None:
        rng = random.Random(f"pd-analyze fuzz file {self.base_seed} {number}")
        seed = self.seeds[rng.randrange(len(self.seeds))]
        mutated = mutate_file(rng, seed.data)
        path = os.path.join(self.workdir, f"case{number}.pcap")
        with open(path, "wb") as out:
            out.write(mutated)
        read = 0
        t0 = time.perf_counter()
        try:
            with _limit(self.frame_limit * 10):
                try:
                    for raw in capture.frames(path):
                        read += 1
                        if len(raw.data) > capture.MAX_CAPLEN:
                            raise InvariantError(f"frame {raw.number} of {len(raw.data)} bytes above MAX_CAPLEN")
                except CaptureError as exc:
                    size = len(mutated) if mutated[:2] != b"\x1f\x8b" else float("inf")  # gzip: decompressed
                    if exc.offset is not None and not 0 <= exc.offset <= size:
                        raise InvariantError(f"CaptureError offset {exc.offset} outside the file "
                                             f"({len(mutated)} bytes)") from None
                _rows, result = analyze_file(path, self.settings)
                stats.slowest = max(stats.slowest, (time.perf_counter() - t0) / max(1, read))
                if number % (FILE_CASE_EVERY * REPORT_CASE_EVERY) == 0:
                    self.report_case(path)  # whole tables and pages: not a frame's time
        finally:
            os.unlink(path)
        stats.files += 1
        stats.file_frames += read
        acc = result.accounting
        if acc.read != read or not acc.balanced():
            raise InvariantError(f"accounting {acc.line()} for {read} frames read")

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
        from pd_analyze.analysis.capture_run import CaptureResult
        from pd_analyze.output import report
        from pd_analyze.protocol.frames import Accounting

        analysis = Analysis(self.rows, [CaptureResult("fuzz", Accounting())], "sinamics", 10.0, 5.0)
        report.summary(analysis)
        report.write_tables(analysis, os.path.join(self.workdir, "tables"), "csv")
        self.rows = Rows()


def check_result(res: FrameResult, data: bytes) -> None:
    """Fields inside the frame with the frame's bytes; renderers emit inert text and ASCII JSON."""
    for f in frame_fields(res):
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


def _tmp_root() -> str | None:
    return "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None
