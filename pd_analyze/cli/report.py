"""`pd-analyze report` (the tables, the summary, the HTML page) and `pd-analyze audit` (findings like a
linter, exit codes for pipelines)."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable

import click

from pd_analyze.analysis.capture_run import CaptureResult, Settings
from pd_analyze.cli.base import (
    EXIT_FINDINGS,
    EXIT_OK,
    EXIT_USAGE,
    capture_files,
    expected_set,
    main,
    profile_option,
    progress_bar,
    run_options,
    some_readable,
    without_pandas,
    writable_dir,
)
from pd_analyze.output.terminal import safe

REPORT_EXAMPLES = """\b
Examples:
  pd-analyze report sample_pcaps/pd_negative.pcap
  pd-analyze report captures/ --out report/ --format parquet --profile sinamics
  pd-analyze report 'line3/*.pcapng' --timeout 30
  pd-analyze report sample_pcaps/fault_trace.pcap --format html --out report/
  pd-analyze report commissioning.pcapng --format html --expect intended.csv
"""
AUDIT_EXAMPLES = """\b
Examples:
  pd-analyze audit commissioning.pcapng
  pd-analyze audit captures/ --fail-on warning --profile yaskawa
  pd-analyze audit sample_pcaps/audit_commissioning.pcap --expect sample_pcaps/sets/audit_commissioning.csv
  pd-analyze audit commissioning.pcapng --expect intended.csv --expect-strict
"""


@main.command("report", epilog=REPORT_EXAMPLES)
@click.argument("captures", nargs=-1, metavar="CAPTURE...")
@click.option("-r", "--read", "read", metavar="FILE", help="Capture to read (as tshark -r).")
@click.option("--out", "out_dir", default="pd-report", show_default=True, metavar="DIR",
              help="Directory for transactions, parameters, findings and changes files.")
@click.option("--format", "fmt", type=click.Choice(["csv", "parquet", "json", "html"]), default="csv",
              show_default=True, help="csv, parquet (DIR/<table>/capture=<file name>/part-0.parquet) and json (JSON "
                                      "Lines) are written in chunks as the capture is read, so memory stays flat "
                                      "whatever its size. html: DIR/report.html (self-contained: summary, plots, "
                                      "tables, drill-down) plus the tables as CSV; it holds every table in memory.")
@click.option("--expect", "expect_path", metavar="EXPECTED.csv",
              help="With --format html: show each drive's parameter state against this intended set (as audit "
                   "--expect).")
@click.option("-v", "--verbose", is_flag=True, help="Also say on stderr how each capture was read: how many of its "
                                                      "PNIO RPC frames the column decode and the vector path took.")
@profile_option
@run_options
def report_command(captures: tuple[str, ...], read: str | None, out_dir: str, fmt: str, expect_path: str | None,
                   verbose: bool, profile: str, timeout: float, rpc_timeout: float, jobs: int, chain: bool) -> None:
    """Pair requests with responses; write the tables and print a summary (worst offenders first)."""
    if expect_path and fmt != "html":
        raise click.UsageError("--expect belongs to --format html (the page's parameter state); for findings use "
                               "`pd-analyze audit --expect`")
    expected = expected_set(expect_path) if expect_path else None
    paths = capture_files(captures, read, profile)
    some_readable(paths)
    writable_dir(out_dir)
    progress = progress_bar() if jobs == 1 else None
    try:
        written, text, errors, results = _report(paths, out_dir, fmt, profile, timeout, rpc_timeout, progress, jobs,
                                                 chain, expected)
    except OSError as exc:  # the disk filled up, the directory went away...
        if exc.filename is not None and not os.path.abspath(exc.filename).startswith(os.path.abspath(out_dir)):
            raise  # not the report's files: a fault to report
        raise click.ClickException(safe(f"cannot write the report to {out_dir}: {exc}")) from None
    click.echo("\n".join(safe(line) for line in text.split("\n")))
    if verbose:
        for result in results:
            click.echo(safe(result.work_text()), err=True)
    for error in errors:  # before "Wrote": what could not be read is said first
        click.echo(safe(f"pd-analyze: {error}"), err=True)
    click.echo("\nWrote " + ", ".join(written), err=True)
    sys.exit(EXIT_USAGE if errors else EXIT_OK)


def _report(paths: list[str], out_dir: str, fmt: str, profile: str, timeout: float, rpc_timeout: float,
            progress: Callable[[str, int], None] | None, jobs: int, chain: bool,
            expected: object = None) -> tuple[list[str], str, list[str], list[CaptureResult]]:
    """The files written, the summary text, the capture errors and the captures' results."""
    from pd_analyze.output import report

    if fmt in ("csv", "json"):  # these files need no DataFrame: pandas would only cost start-up time (Parquet's
        without_pandas()  # schema carries the pandas metadata of an empty DataFrame, made by pandas)
    if fmt == "html":  # plots and drill-down need the whole tables
        from pd_analyze.analysis.api import analyze
        from pd_analyze.output import html_report

        analysis = analyze(paths, profile, timeout, rpc_timeout, progress, jobs, chain)
        written = report.write_tables(analysis, out_dir, "csv")
        written.append(html_report.write(analysis, f"{out_dir}/report.html",
                                         tables_dir_note="the CSV files beside this page",
                                         expected=expected))  # type: ignore[arg-type]
        return written, report.summary(analysis), analysis.errors, list(analysis.captures)
    streamed = report.stream(paths, out_dir, fmt, Settings(profile, timeout, rpc_timeout), progress, jobs, chain)
    return streamed.written, streamed.summary, streamed.errors, streamed.captures


@main.command("audit", epilog=AUDIT_EXAMPLES)
@click.argument("captures", nargs=-1, metavar="CAPTURE...")
@click.option("-r", "--read", "read", metavar="FILE", help="Capture to read (as tshark -r).")
@click.option("--fail-on", type=click.Choice(["error", "warning", "info", "never"]), default="error",
              show_default=True, help="Exit 1 when a finding reaches this severity.")
@click.option("--expect", "expect_path", metavar="EXPECTED.csv",
              help="Check every drive's parameter state against an intended set (CSV: device,do,pnu,subindex,"
                   "value[,tolerance]; device * for every drive): findings S1-S4.")
@click.option("--expect-strict", is_flag=True, help="With --expect: also report parameters written that the set "
                                                    "does not list (S5 unexpected_write, info).")
@profile_option
@run_options
def audit_command(captures: tuple[str, ...], read: str | None, fail_on: str, expect_path: str | None,
                  expect_strict: bool, profile: str, timeout: float, rpc_timeout: float, jobs: int,
                  chain: bool) -> None:
    """Findings like a linter (file:frame: severity rule message); exit 1 at the --fail-on threshold.

    Findings are sorted by capture and frame through a bounded on-disk sort: memory stays flat. With
    --expect, the parameter state (one entry per parameter element, not per frame) is checked against the
    intended set after the capture's own findings; a missing parameter is reported at its line of the set."""
    from pd_analyze.model.rules import SEVERITIES, SEVERITY_RANK
    from pd_analyze.output import report

    if expect_strict and not expect_path:
        raise click.UsageError("--expect-strict needs --expect EXPECTED.csv")
    expected = expected_set(expect_path) if expect_path else None
    if expected is None:  # findings only, no DataFrame: pandas would only cost start-up time (a pipeline's step)
        without_pandas()
    paths = capture_files(captures, read, profile)
    state = _StateHolder()
    rows, results = report.stream_findings(paths, Settings(profile, timeout, rpc_timeout), jobs, chain,
                                           progress=progress_bar() if jobs == 1 else None,
                                           wrap=state.wrap if expected else None)
    if expected is not None:
        from pd_analyze.analysis import intended

        rows = _chain_rows(rows, intended.finding_rows(intended.check(expected, state.table(), expect_strict)))
    counts: dict[str, int] = dict.fromkeys(SEVERITIES, 0)
    total = worst = 0
    for capture, frame, txn, severity, rule, name, *_, message in rows:
        severity = severity if severity in counts else "nan"  # as pandas shows a value outside the categories
        txn_note = f" [txn {txn}]" if txn is not None else ""
        click.echo(safe(f"{capture}:{_na(frame)}: {severity} {rule} {name}: {message}{txn_note}"))
        total += 1
        if severity in counts:
            counts[severity] += 1
            worst = max(worst, SEVERITY_RANK[severity])
    files = len(results)
    click.echo(f"{total} findings in {files} capture{'s' if files != 1 else ''}: "
               + ", ".join(f"{counts[s]} {s}" for s in ("error", "warning", "info")))
    errors = [f"{c.path}: {c.error}" for c in results if c.error]
    for error in errors:
        click.echo(safe(f"pd-analyze: {error}"), err=True)
    if errors:
        sys.exit(EXIT_USAGE)
    threshold = SEVERITY_RANK.get(fail_on, 99)
    sys.exit(EXIT_FINDINGS if worst >= threshold else EXIT_OK)


def _na(value: object) -> str:
    return "<NA>" if value is None else str(value)


class _StateHolder:
    """The StateRows audit puts in front of its findings, kept to read the state once the run is done."""

    def __init__(self) -> None:
        self.rows: object = None

    def wrap(self, inner: object) -> object:
        from pd_analyze.analysis.param_state import StateRows

        self.rows = StateRows(inner)  # type: ignore[arg-type]
        return self.rows

    def table(self) -> object:
        self.rows.fold()  # type: ignore[attr-defined]
        return self.rows.state  # type: ignore[attr-defined]


def _chain_rows(first: object, then: list[tuple]) -> object:
    yield from first  # type: ignore[misc]
    yield from then
