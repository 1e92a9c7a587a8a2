"""The `pd-analyze` command line: argument parsing, output streams and exit codes only.

Exit codes: 0 done, 1 a finding reached the --fail-on threshold (audit), 2 unreadable input or bad
usage, 141 the reader of stdout went away (as a Unix tool killed by SIGPIPE). Data goes to stdout,
progress and errors to stderr; no traceback ever reaches the user.
"""
# Longer than 450 lines: every command's options, help and examples are declared here, in one place, so that
# `--help` and the shared options (profile, timeouts, jobs) cannot drift apart; the work is in the layers below.

# Longer than 450 lines: six commands, each with its options, help text and examples in one place, so
# that `--help`, the README and the exit codes are read and changed together; the work is done elsewhere.
from __future__ import annotations

import gc
import os
import sys
from collections.abc import Callable
from typing import NoReturn

import click

from pd_analyze import __version__, cli_wireshark
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.analysis.transactions import TransactionEngine
from pd_analyze.capture import CaptureError
from pd_analyze.capture.reader import unreadable_reason
from pd_analyze.model.fields import FIELDS
from pd_analyze.output import dump
from pd_analyze.output.decode import decode, parse_hex
from pd_analyze.output.dump_findings import with_transaction_findings
from pd_analyze.protocol import profiles
from pd_analyze.protocol.dissector import DEFAULT_RPC_TIMEOUT, Dissector, dissect
from pd_analyze.protocol.profidrive_checks import Checker

EXIT_OK, EXIT_FINDINGS, EXIT_USAGE = 0, 1, 2
EXIT_CLOSED_PIPE = 128 + 13  # SIGPIPE, as the shell reports a tool that wrote into a closed pipe
_COLOURS = {"error": "red", "warning": "yellow", "info": "cyan", "frame": "green", "dim": "bright_black"}

DUMP_EXAMPLES = """\b
Examples:
  pd-analyze dump sample_pcaps/worked_example.pcap
  pd-analyze dump -r capture.pcapng --frames 1,5-9
  pd-analyze dump capture.pcap.gz --findings-only
  pd-analyze dump capture.pcapng --format json | jq .summary
  pd-analyze dump captures/ --findings-only -t ad
  pd-analyze dump capture.pcap --color always | less -R
  tcpdump -w - udp | pd-analyze dump -
  pd-analyze dump trace.pcap -Y 'pd.addr.pnu == 964 and txn.verdict == "nak"' -T fields -e frame.number -e pd.ref
"""


class _Seconds(click.FloatRange):
    """A time limit in seconds, at least 1 ms; NaN is refused (it compares false with every limit)."""

    def convert(self, value: object, param: click.Parameter | None, ctx: click.Context | None) -> object:
        seconds = super().convert(value, param, ctx)
        if seconds != seconds:
            self.fail(f"{value!r} is not a number of seconds", param, ctx)
        return seconds


SECONDS = _Seconds(min=0.001)


def _batch_gc() -> None:
    """The frame loop makes millions of short-lived objects and hardly any cycles: the collector, run
    every 700 allocations by default, would scan them again and again (some 6 % of a report). Objects
    alive at start-up are moved out of its sight and the youngest generation is collected less often;
    cycles are still collected, so memory stays bounded. The CLI only: a notebook keeps its own settings."""
    gc.freeze()
    gc.set_threshold(50_000, 20, 20)


class _Group(click.Group):
    def invoke(self, ctx: click.Context) -> object:
        try:
            return super().invoke(ctx)
        except BrokenPipeError:  # before click's own handler, which would exit 1
            _closed_pipe()

    def main(self, *args: object, **kwargs: object) -> object:
        """Any unexpected exception becomes a one-line error with exit code 2, never a traceback."""
        _batch_gc()
        try:
            try:
                super().main(*args, standalone_mode=False, **kwargs)
            except SystemExit:
                sys.stdout.flush()  # a reader that went away is noticed here, not at interpreter exit
                raise
            sys.stdout.flush()
            return None
        except click.exceptions.Exit as exc:
            sys.exit(exc.exit_code)
        except click.Abort:
            click.echo("pd-analyze: aborted", err=True)
            sys.exit(EXIT_USAGE)
        except click.ClickException as exc:
            exc.show()
            sys.exit(EXIT_USAGE)
        except BrokenPipeError:
            _closed_pipe()
        except KeyboardInterrupt:
            click.echo("pd-analyze: interrupted", err=True)
            sys.exit(130)
        except Exception as exc:
            click.echo(dump.safe(f"pd-analyze: internal error: {exc.__class__.__name__}: {exc} "
                                 "(please report it with the capture)"), err=True)
            sys.exit(EXIT_USAGE)


def _closed_pipe() -> NoReturn:
    """The reader went away (`| head`): stop quietly with the status a Unix tool killed by SIGPIPE has
    in the shell (128 + 13), never 1, which `audit` uses for findings. Output still buffered goes to
    the null device, so the interpreter's last flush cannot fail again."""
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, sys.stdout.fileno())
    os.close(null)
    sys.exit(EXIT_CLOSED_PIPE)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="pd-analyze")
def main() -> None:
    """Offline analyser of PROFIdrive parameter access in PROFINET IO captures.

    Reads pcap/pcapng (also gzip-compressed) and decodes PNIO record Read/Write down to the record,
    checking every field against protocol limits.
    """


def _some_readable(paths: list[str]) -> None:
    """Exit 2 with each reason when no input can be read: nothing to report on, no files, no output."""
    unreadable = [error for error in map(unreadable_reason, paths) if error]
    if len(unreadable) == len(paths):
        for error in unreadable:
            click.echo(dump.safe(f"pd-analyze: {error}"), err=True)
        sys.exit(EXIT_USAGE)


def _inputs(captures: tuple[str, ...], read: str | None) -> list[str]:
    paths = ([read] if read else []) + list(captures)
    if not paths:
        raise click.UsageError("no capture given: pass CAPTURE or -r FILE (use - for standard input)")
    return paths


def _style(enabled: bool) -> dump.Style:
    if not enabled:
        return dump.plain_style
    return lambda text, role: click.style(text, fg=_COLOURS.get(role))


def _lines(coloured: bool) -> Callable[[str], None]:
    """Where the dump's lines go: plain text straight to stdout (click.echo flushes and looks for colour
    codes to strip on every line, some 7 us of a dump's frame), coloured text through click.echo."""
    if coloured:  # asked for (always) or on a terminal: click.echo would strip the codes into a pipe
        return lambda text: click.echo(text, color=True)
    write = sys.stdout.write

    def line(text: str) -> None:
        write(text + "\n")
    return line


def _checker(profile: str) -> Checker:
    try:
        return Checker.for_profile(profile)
    except profiles.ProfileError as exc:
        raise click.BadParameter(str(exc), param_hint="--profile") from None


def profile_option(func: Callable) -> Callable:
    return click.option("--profile", default=profiles.DEFAULT, show_default=True, metavar="NAME|FILE.toml",
                        help="Vendor limits to check against (see `pd-analyze profiles`).")(func)


@main.command("dump", epilog=DUMP_EXAMPLES)
@click.argument("captures", nargs=-1, metavar="CAPTURE...")
@click.option("-r", "--read", "read", metavar="FILE", help="Capture to read (as tshark -r); - for stdin.")
@click.option("--frames", "frames", metavar="LIST", help="Only these frames, e.g. 1,5-9,20-.")
@click.option("--findings-only", is_flag=True, help="Only frames with findings, and only the findings.")
@click.option("--format", "-T", "fmt", type=click.Choice(["text", "json", "fields"]), default="text", show_default=True,
              help="text: indented tree; json: JSON Lines, one object per PNIO RPC frame; fields: see -e.")
@cli_wireshark.dump_options
@click.option("--color", "color", type=click.Choice(["always", "never", "auto"]), default="auto",
              show_default=True, is_flag=False, flag_value="always",
              help="Colour the text output: always, never, or auto (on a terminal). --color alone: always.")
@click.option("--no-color", "no_color", is_flag=True, hidden=True, help="The same as --color never.")
@click.option("-t", "--time-format", "time_format", type=click.Choice(dump.TIME_FORMATS), default="e",
              show_default=True, help="Frame times as tshark -t: e epoch seconds, ad/a local date and time/time, "
              "ud/u the same in UTC, r since the first PNIO RPC frame, dd since the previous frame shown.")
@click.option("--rpc-timeout", type=SECONDS, default=DEFAULT_RPC_TIMEOUT,
              show_default=True, help="Seconds of capture time before a request counts as unanswered.")
@profile_option
def dump_command(captures: tuple[str, ...], read: str | None, frames: str | None, findings_only: bool,
                 fmt: str, flt: str | None, field_names: tuple[str, ...], field_options: tuple[str, ...],
                 color: str, no_color: bool, time_format: str, rpc_timeout: float, profile: str) -> None:
    """Every PNIO RPC frame as a tree of layers and fields: offset, bytes, value, meaning, check.

    CAPTURE may be a file, a directory (its captures, sorted) or a glob pattern, as for report and audit.
    With --findings-only the transaction engine runs too, so every finding audit reports (also the
    pairing and channel rules Q2-Q5, T1-T7) is shown at its frame."""
    paths = _files(captures, read, profile) if not (read == "-" or captures == ("-",)) else ["-"]
    checker = _checker(profile)
    try:
        ranges = dump.frame_ranges(frames) if frames else []
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--frames") from None
    wanted: Callable[[int], bool] = (lambda n: any(lo <= n <= hi for lo, hi in ranges)) if ranges else \
        (lambda n: True)
    colour = sys.stdout.isatty() if color == "auto" and not no_color else color == "always" and not no_color
    style = _style(colour and fmt == "text")
    if flt is not None or fmt == "fields" or field_names:  # the frames a filter selects, or -T fields
        out = _lines(colour and fmt == "text")
        sys.exit(cli_wireshark.fields_dump(paths, Settings(profile, rpc_timeout=rpc_timeout), checker, flt, fmt,
                 field_names, field_options, wanted, lambda found: dump.render(found, fmt, out, style, findings_only)))
    status = EXIT_OK
    for path in paths:
        if len(paths) > 1 and fmt == "text":
            click.echo(dump.safe(f"==> {path} <=="))
        d = Dissector(annotate=True, rpc_timeout=rpc_timeout, checker=checker)
        clock = dump.Clock(time_format)
        results = clock.watch(dissect(path, dissector=d))
        if findings_only:  # the transaction engine's findings too, at their frames (as audit shows them)
            results = with_transaction_findings(results, TransactionEngine())
        results = (r for r in results if wanted(r.frame))
        try:
            dump.render(results, fmt, _lines(colour and fmt == "text"), style, findings_only, clock)
        except CaptureError as exc:
            click.echo(dump.safe(f"pd-analyze: {exc}"), err=True)
            status = EXIT_USAGE
        outside = dump.beyond(ranges, d.accounting.read)
        if outside and status == EXIT_OK:
            click.echo(dump.safe(f"pd-analyze: {path}: --frames {','.join(outside)} lies beyond the capture's "
                                 f"{d.accounting.read} frames"), err=True)
        loose = [f for f in d.loose_findings if wanted(f.frame)]
        if loose and fmt == "text":
            click.echo("Findings on frames that are not PNIO RPC:")
            for f in loose:
                click.echo(f"  frame {f.frame} " + dump.finding_line(f, "", style))
            if d.loose_dropped:
                click.echo(f"  ... and {d.loose_dropped} more (only the first {len(d.loose_findings)} are kept)")
        elif loose:
            click.echo(f"pd-analyze: {len(loose)} findings on frames that are not PNIO RPC "
                       "(see --format text)", err=True)
        click.echo(dump.safe(f"{path}: {d.accounting.line()}"), err=True)
    sys.exit(status)


DECODE_EXAMPLES = """\b
Examples:
  pd-analyze decode "01 01 01 02 10 01 03 C4 00 00 10 03 07 D0 00 00" --request
  pd-analyze decode 0101010142011234 --response --for-request 01010101100103c40000
  pd-analyze decode "5F 00 2F 0A 01 01 01 01 10 00 00 2F 00 00" --dpv1
  pd-analyze decode "..." --request --profile sinamics --format json
"""


@main.command("decode", epilog=DECODE_EXAMPLES)
@click.argument("hex_text", nargs=-1, required=True, metavar="HEX")
@click.option("--request", "side", flag_value="request", help="The bytes are a parameter request.")
@click.option("--response", "side", flag_value="response", help="The bytes are a parameter response.")
@click.option("--dpv1", is_flag=True, help="A DP-V1 header (0x5E read / 0x5F write, slot, index, length) "
                                           "precedes the block.")
@click.option("--for-request", "for_request", metavar="HEX",
              help="The request a response answers, to label its blocks P<pnu>[<sub>].")
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text", show_default=True)
@profile_option
def decode_command(hex_text: tuple[str, ...], side: str | None, dpv1: bool, for_request: str | None,
                   fmt: str, profile: str) -> None:
    """Decode a raw PROFIdrive parameter block given as hex (spaces or not)."""
    checker = _checker(profile)
    try:
        data = parse_hex(" ".join(hex_text))
        request = parse_hex(for_request) if for_request else None
        result = decode(data, None if side is None else side == "response", checker, dpv1, request)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="HEX") from None
    if fmt == "json":
        click.echo(dump.decoded_json(result.sections, result.findings))
    else:
        kind = "response" if result.response else "request"
        click.echo(f"PROFIdrive parameter {kind}, {len(data)} bytes, profile {profile}")
        click.echo(dump.decoded_text(result.sections, result.findings, _style(sys.stdout.isatty())))
    sys.exit(EXIT_OK)


@main.command("profiles")
@click.argument("names", nargs=-1, metavar="[NAME|FILE.toml]...")
@click.option("--format", "fmt", type=click.Choice(["text", "markdown"]), default="text", show_default=True)
def profiles_command(names: tuple[str, ...], fmt: str) -> None:
    """Print the limits of the vendor profiles side by side, with their sources."""
    try:
        chosen = [profiles.load(n) for n in (names or sorted(profiles.packaged(), key=_profile_order))]
    except profiles.ProfileError as exc:
        raise click.BadParameter(str(exc), param_hint="NAME") from None
    click.echo(profiles_table(chosen, fmt))


def _profile_order(name: str) -> tuple[int, str]:
    return (0 if name == profiles.DEFAULT else 1, name)


def profiles_table(chosen: list[profiles.Profile], fmt: str) -> str:
    keys = [k for k in profiles.LIMIT_KEYS if any(p.limits_for(k) for p in chosen)]
    header = ["limit"] + [p.name for p in chosen]
    rows = [[k] + [" / ".join(lim.text() for lim in p.limits_for(k)) or "-" for p in chosen] for k in keys]
    lines = []
    if fmt == "markdown":
        lines.append("| " + " | ".join(header) + " |")
        lines.append("|" + "---|" * len(header))
        lines += ["| " + " | ".join(row) + " |" for row in rows]
    else:
        widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
        lines.append("  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)))
        lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)) for row in rows]
    lines.append("")
    lines.append("Sources:")
    for p in chosen:
        lines.append(f"  {p.name}: {p.title}. {p.description}")
        for lim in p.limits:
            lines.append(f"    {lim.key} = {lim.text()}  <- {lim.source}")
        if p.tolerate:
            lines += [f"    tolerates: {profiles.TOLERATIONS[t]}" for t in sorted(p.tolerate)]
        if p.error_texts:
            lines.append(f"    vendor error texts: {', '.join(f'{k:#04x}' for k in p.error_texts)}")
        if p.pnu_names:
            shown = ", ".join(f"P{k}" for k in sorted(p.pnu_names)[:8]) + (", ..." if len(p.pnu_names) > 8 else "")
            lines.append(f"    parameter names: {len(p.pnu_names)} ({shown})")
        lines += p.ids.listing() if p.ids is not None else []
    return "\n".join(lines)



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


def _progress() -> Callable[[str, int], None] | None:
    """Percent of the capture's bytes read and the time left, on stderr when it is a terminal."""
    from pd_analyze.output.progress import terminal_progress

    return terminal_progress()


def _files(captures: tuple[str, ...], read: str | None, profile: str) -> list[str]:
    from pd_analyze.analysis.api import expand

    given = _inputs(captures, read)
    paths = expand(given)
    if not paths:
        raise click.UsageError(dump.safe(f"no capture files matched {' '.join(given)} (a directory is searched for "
                                         "*.pcap, *.pcapng, *.cap and *.gz files)"))
    _checker(profile)  # a bad profile is a usage error before any file is read
    return paths


def _timeouts(func: Callable) -> Callable:
    func = click.option("--jobs", "-j", type=click.IntRange(min=1), default=1, show_default=True,
                        help="Analyse files in N parallel processes (same tables as one process; each worker "
                             "returns its file's rows whole). One file is always one process.")(func)
    func = click.option("--chain", is_flag=True,
                        help="The files continue one another (ring buffer): pair across file boundaries.")(func)
    func = click.option("--timeout", type=SECONDS, default=10.0, show_default=True,
                        help="Seconds of capture time a transaction may take before it is a timeout.")(func)
    return click.option("--rpc-timeout", type=SECONDS, default=DEFAULT_RPC_TIMEOUT,
                        show_default=True, help="Seconds of capture time before an RPC call is unanswered.")(func)


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
@profile_option
@_timeouts
def report_command(captures: tuple[str, ...], read: str | None, out_dir: str, fmt: str, expect_path: str | None,
                   profile: str, timeout: float, rpc_timeout: float, jobs: int, chain: bool) -> None:
    """Pair requests with responses; write the tables and print a summary (worst offenders first)."""
    if expect_path and fmt != "html":
        raise click.UsageError("--expect belongs to --format html (the page's parameter state); for findings use "
                               "`pd-analyze audit --expect`")
    expected = _expected(expect_path) if expect_path else None
    paths = _files(captures, read, profile)
    _some_readable(paths)
    _writable(out_dir)
    progress = _progress() if jobs == 1 else None
    try:
        written, text, errors = _report(paths, out_dir, fmt, profile, timeout, rpc_timeout, progress, jobs, chain,
                                        expected)
    except OSError as exc:  # the disk filled up, the directory went away...
        if exc.filename is not None and not os.path.abspath(exc.filename).startswith(os.path.abspath(out_dir)):
            raise  # not the report's files: a fault to report
        raise click.ClickException(dump.safe(f"cannot write the report to {out_dir}: {exc}")) from None
    click.echo("\n".join(dump.safe(line) for line in text.split("\n")))
    for error in errors:  # before "Wrote": what could not be read is said first
        click.echo(dump.safe(f"pd-analyze: {error}"), err=True)
    click.echo("\nWrote " + ", ".join(written), err=True)
    sys.exit(EXIT_USAGE if errors else EXIT_OK)



def _writable(out_dir: str) -> None:
    """--out must be a directory we can write to: said before any capture is read."""
    import tempfile

    try:
        os.makedirs(out_dir, exist_ok=True)
        tempfile.TemporaryFile(dir=out_dir).close()
    except OSError as exc:
        raise click.UsageError(dump.safe(f"--out {out_dir}: cannot write there ({exc.strerror or exc})")) from None


def _report(paths: list[str], out_dir: str, fmt: str, profile: str, timeout: float, rpc_timeout: float,
            progress: Callable[[str, int], None] | None, jobs: int, chain: bool,
            expected: object = None) -> tuple[list[str], str, list[str]]:
    """The files written, the summary text and the capture errors."""
    from pd_analyze.output import report

    if fmt == "html":  # plots and drill-down need the whole tables
        from pd_analyze.analysis.api import analyze
        from pd_analyze.output import html_report

        analysis = analyze(paths, profile, timeout, rpc_timeout, progress, jobs, chain)
        written = report.write_tables(analysis, out_dir, "csv")
        written.append(html_report.write(analysis, f"{out_dir}/report.html",
                                         tables_dir_note="the CSV files beside this page",
                                         expected=expected))  # type: ignore[arg-type]
        text, errors = report.summary(analysis), analysis.errors
    else:
        streamed = report.stream(paths, out_dir, fmt, Settings(profile, timeout, rpc_timeout), progress, jobs, chain)
        written, text, errors = streamed.written, streamed.summary, streamed.errors
    return written, text, errors


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
@_timeouts
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
    expected = _expected(expect_path) if expect_path else None
    paths = _files(captures, read, profile)
    state = _StateHolder()
    rows, results = report.stream_findings(paths, Settings(profile, timeout, rpc_timeout), jobs, chain,
                                           progress=_progress() if jobs == 1 else None,
                                           wrap=state.wrap if expected else None)
    if expected is not None:
        from pd_analyze.analysis import intended

        rows = _chain_rows(rows, intended.finding_rows(intended.check(expected, state.table(), expect_strict)))
    counts: dict[str, int] = dict.fromkeys(SEVERITIES, 0)
    total = worst = 0
    for capture, frame, txn, severity, rule, name, *_, message in rows:
        severity = severity if severity in counts else "nan"  # as pandas shows a value outside the categories
        txn_note = f" [txn {txn}]" if txn is not None else ""
        click.echo(dump.safe(f"{capture}:{_na(frame)}: {severity} {rule} {name}: {message}{txn_note}"))
        total += 1
        if severity in counts:
            counts[severity] += 1
            worst = max(worst, SEVERITY_RANK[severity])
    files = len(results)
    click.echo(f"{total} findings in {files} capture{'s' if files != 1 else ''}: "
               + ", ".join(f"{counts[s]} {s}" for s in ("error", "warning", "info")))
    errors = [f"{c.path}: {c.error}" for c in results if c.error]
    for error in errors:
        click.echo(dump.safe(f"pd-analyze: {error}"), err=True)
    if errors:
        sys.exit(EXIT_USAGE)
    threshold = SEVERITY_RANK.get(fail_on, 99)
    sys.exit(EXIT_FINDINGS if worst >= threshold else EXIT_OK)


def _na(value: object) -> str:
    return "<NA>" if value is None else str(value)


# --- parameter state: params, diff, audit --expect (the logic is in analysis.param_state, analysis.intended,
# output.param_tables and output.param_diff) ------------------------------------------------------------------

def _expected(path: str) -> object:
    """The intended set, read before any capture: a malformed one is a one-line error naming its line."""
    from pd_analyze.analysis import intended

    try:
        return intended.load(path)
    except intended.ExpectError as exc:
        raise click.ClickException(dump.safe(str(exc))) from None


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


PARAMS_EXAMPLES = """\b
Examples:
  pd-analyze params sample_pcaps/audit_commissioning.pcap
  pd-analyze params commissioning.pcapng --format csv > state.csv
  pd-analyze params captures/ --out state/ --format parquet
"""
DIFF_EXAMPLES = """\b
Examples:
  pd-analyze diff sample_pcaps/audit_commissioning.pcap sample_pcaps/audit_recommissioning.pcap
  pd-analyze diff drive_a.pcapng drive_b.pcapng --by do --format csv
"""


@main.command("params", epilog=PARAMS_EXAMPLES)
@click.argument("captures", nargs=-1, metavar="CAPTURE...")
@click.option("-r", "--read", "read", metavar="FILE", help="Capture to read (as tshark -r).")
@click.option("--out", "out_dir", default=None, metavar="DIR", help="Write DIR/parameter_state.<format> instead "
                                                                      "of printing to stdout.")
@click.option("--format", "fmt", type=click.Choice(["text", "csv", "json", "parquet"]), default=None,
              help="text: a table (stdout's default); csv, json (JSON Lines); parquet needs --out (whose default "
                   "is csv).")
@profile_option
@_timeouts
def params_command(captures: tuple[str, ...], read: str | None, out_dir: str | None, fmt: str | None, profile: str,
                   timeout: float, rpc_timeout: float, jobs: int, chain: bool) -> None:
    """Parameter state per drive: per device, DO, PNU and subindex the last value confirmed written and the last
    read back (frame and time), whether they agree, writes, refused writes and the last error.

    Memory holds one entry per parameter element, whatever the capture's size."""
    from pd_analyze.analysis.param_state import collect
    from pd_analyze.output import param_tables

    if out_dir is None and fmt == "parquet":
        raise click.UsageError("--format parquet needs --out DIR")
    if out_dir is not None and fmt == "text":
        raise click.UsageError("--out writes csv, json or parquet")
    paths = _files(captures, read, profile)
    _some_readable(paths)
    if out_dir is not None:
        _writable(out_dir)
    state, results = collect(paths, Settings(profile, timeout, rpc_timeout), _progress() if jobs == 1 else None,
                             jobs, chain)
    if out_dir is not None:
        click.echo("Wrote " + param_tables.write_state(state, out_dir, fmt or "csv"), err=True)
    elif fmt in ("csv", "json"):
        sys.stdout.write(param_tables.state_formatted(state, fmt))
    else:
        click.echo("\n".join(dump.safe(line) for line in param_tables.state_text(state)))
    errors = [f"{c.path}: {c.error}" for c in results if c.error]
    for error in errors:
        click.echo(dump.safe(f"pd-analyze: {error}"), err=True)
    sys.exit(EXIT_USAGE if errors else EXIT_OK)


@main.command("diff", epilog=DIFF_EXAMPLES)
@click.argument("a", metavar="A")
@click.argument("b", metavar="B")
@click.option("--by", type=click.Choice(["device", "do"]), default="device", show_default=True,
              help="device: each drive against the same drive (before and after); do: the one drive of A against "
                   "the one drive of B (drives that should be alike).")
@click.option("--format", "fmt", type=click.Choice(["text", "csv", "json"]), default="text", show_default=True)
@profile_option
@_timeouts
def diff_command(a: str, b: str, by: str, fmt: str, profile: str, timeout: float, rpc_timeout: float, jobs: int,
                 chain: bool) -> None:
    """Parameter state of capture A against B: one row per parameter element that differs, is missing on one side,
    or was refused (or left unconfirmed) on one side. Exit 0 when the states agree, 1 when they differ, 2 on
    trouble, as diff(1)."""
    from pd_analyze.analysis.param_state import collect
    from pd_analyze.output import param_diff

    files = [_files((side,), None, profile) for side in (a, b)]
    settings = Settings(profile, timeout, rpc_timeout)
    (state_a, res_a), (state_b, res_b) = (collect(f, settings, None, jobs, chain) for f in files)
    errors = [f"{c.path}: {c.error}" for c in res_a + res_b if c.error]
    for error in errors:
        click.echo(dump.safe(f"pd-analyze: {error}"), err=True)
    if errors:
        sys.exit(EXIT_USAGE)
    try:
        rows = param_diff.diff_rows(state_a, state_b, by)
    except param_diff.DiffError as exc:
        raise click.UsageError(dump.safe(str(exc))) from None
    if fmt == "text":
        if rows:
            click.echo("\n".join(dump.safe(line) for line in param_diff.diff_text(rows, by)))
    else:
        sys.stdout.write(param_diff.diff_formatted(rows, fmt))
    click.echo(f"{len(rows)} parameter element{'s' if len(rows) != 1 else ''} differ"
               f"{'s' if len(rows) == 1 else ''} (A: {len(state_a.elements)}, B: {len(state_b.elements)})", err=True)
    sys.exit(EXIT_FINDINGS if rows else EXIT_OK)


@main.command("fields")
@click.option("--format", "fmt", type=click.Choice(["text", "markdown"]), default="text", show_default=True)
def fields_command(fmt: str) -> None:
    """List every field name of the registry with its type, tshark name and description."""
    if fmt == "markdown":
        click.echo("| Field | Type | tshark | Description |\n|---|---|---|---|")
    for f in FIELDS.values():
        if fmt == "markdown":
            click.echo(f"| `{f.name}` | {f.type} | {f'`{f.tshark}`' if f.tshark else ''} | {f.description} |")
        else:
            click.echo(f"{f.name:<24} {f.type:<6} {f.tshark or '-':<44} {f.description}")


for _command in (cli_wireshark.annotate_command, cli_wireshark.extract_command):
    main.add_command(_command)

if __name__ == "__main__":
    main()
