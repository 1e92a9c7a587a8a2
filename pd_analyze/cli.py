"""The `pd-analyze` command line: argument parsing, output streams and exit codes only.

Exit codes: 0 done, 1 a finding reached the --fail-on threshold (audit), 2 unreadable input or bad
usage. Data goes to stdout, progress and errors to stderr; no traceback ever reaches the user.
"""

from __future__ import annotations

import gc
import os
import sys
from collections.abc import Callable

import click

from pd_analyze import __version__
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.capture import CaptureError
from pd_analyze.model.fields import FIELDS
from pd_analyze.output import dump
from pd_analyze.output.decode import decode, parse_hex
from pd_analyze.protocol import profiles
from pd_analyze.protocol.dissector import DEFAULT_RPC_TIMEOUT, Dissector, dissect
from pd_analyze.protocol.profidrive_checks import Checker

EXIT_OK, EXIT_FINDINGS, EXIT_USAGE = 0, 1, 2
_COLOURS = {"error": "red", "warning": "yellow", "info": "cyan", "frame": "green", "dim": "bright_black"}

DUMP_EXAMPLES = """\b
Examples:
  pd-analyze dump sample_pcaps/worked_example.pcap
  pd-analyze dump -r capture.pcapng --frames 1,5-9
  pd-analyze dump capture.pcap.gz --findings-only
  pd-analyze dump capture.pcapng --format json | jq .summary
  tcpdump -w - udp | pd-analyze dump -
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
    def main(self, *args: object, **kwargs: object) -> object:
        """Any unexpected exception becomes a one-line error with exit code 2, never a traceback."""
        _batch_gc()
        try:
            return super().main(*args, standalone_mode=False, **kwargs)
        except click.exceptions.Exit as exc:
            sys.exit(exc.exit_code)
        except click.Abort:
            click.echo("pd-analyze: aborted", err=True)
            sys.exit(EXIT_USAGE)
        except click.ClickException as exc:
            exc.show()
            sys.exit(EXIT_USAGE)
        except BrokenPipeError:
            sys.stderr.close()  # reader went away (e.g. `| head`): not an error
            sys.exit(EXIT_OK)
        except KeyboardInterrupt:
            click.echo("pd-analyze: interrupted", err=True)
            sys.exit(130)
        except Exception as exc:
            click.echo(dump.safe(f"pd-analyze: internal error: {exc.__class__.__name__}: {exc} "
                                 "(please report it with the capture)"), err=True)
            sys.exit(EXIT_USAGE)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="pd-analyze")
def main() -> None:
    """Offline analyser of PROFIdrive parameter access in PROFINET IO captures.

    Reads pcap/pcapng (also gzip-compressed) and decodes PNIO record Read/Write down to the record,
    checking every field against protocol limits.
    """


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
    if coloured:
        return click.echo
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
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text", show_default=True,
              help="text: indented tree; json: JSON Lines, one object per PNIO RPC frame.")
@click.option("--color/--no-color", default=None, help="Colour the text output (default: on a terminal).")
@click.option("--rpc-timeout", type=SECONDS, default=DEFAULT_RPC_TIMEOUT,
              show_default=True, help="Seconds of capture time before a request counts as unanswered.")
@profile_option
def dump_command(captures: tuple[str, ...], read: str | None, frames: str | None, findings_only: bool,
                 fmt: str, color: bool | None, rpc_timeout: float, profile: str) -> None:
    """Every PNIO RPC frame as a tree of layers and fields: offset, bytes, value, meaning, check."""
    paths = _inputs(captures, read)
    checker = _checker(profile)
    try:
        wanted: Callable[[int], bool] = dump.parse_frames(frames) if frames else (lambda n: True)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--frames") from None
    colour = sys.stdout.isatty() if color is None else color
    style = _style(colour and fmt == "text")
    status = EXIT_OK
    for path in paths:
        if len(paths) > 1 and fmt == "text":
            click.echo(dump.safe(f"==> {path} <=="))
        d = Dissector(annotate=True, rpc_timeout=rpc_timeout, checker=checker)
        results = (r for r in dissect(path, dissector=d) if wanted(r.frame))
        try:
            dump.render(results, fmt, _lines(colour and fmt == "text"), style, findings_only)
        except CaptureError as exc:
            click.echo(dump.safe(f"pd-analyze: {exc}"), err=True)
            status = EXIT_USAGE
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
        lines += p.ids.listing() if p.ids is not None else []
    return "\n".join(lines)



REPORT_EXAMPLES = """\b
Examples:
  pd-analyze report sample_pcaps/pd_negative.pcap
  pd-analyze report captures/ --out report/ --format parquet --profile sinamics
  pd-analyze report 'line3/*.pcapng' --timeout 30
  pd-analyze report sample_pcaps/fault_trace.pcap --format html --out report/
"""
AUDIT_EXAMPLES = """\b
Examples:
  pd-analyze audit commissioning.pcapng
  pd-analyze audit captures/ --fail-on warning --profile yaskawa
"""


def _progress() -> Callable[[str, int], None] | None:
    """A frame counter on stderr for long files; silent when stderr is not a terminal."""
    if not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    bars: dict[str, tqdm] = {}

    def update(path: str, frames: int) -> None:
        bar = bars.get(path)
        if bar is not None and frames - bar.n < 4096:  # called per PNIO frame; skipped frames jump the count
            return
        if bar is None:
            bar = bars[path] = tqdm(desc=path, unit=" frames", leave=False, file=sys.stderr)
        bar.n = frames
        bar.refresh()

    return update


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
                        help="Analyse files in N parallel processes, or one large uncompressed pcap in N parts "
                             "(same tables as one process; each worker returns its file's rows whole).")(func)
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
              show_default=True, help="csv, parquet (DIR/<table>/capture=<file>/part-0.parquet) and json (JSON "
                                      "Lines) are written in chunks as the capture is read, so memory stays flat "
                                      "whatever its size. html: DIR/report.html (self-contained: summary, plots, "
                                      "tables, drill-down) plus the tables as CSV; it holds every table in memory.")
@profile_option
@_timeouts
def report_command(captures: tuple[str, ...], read: str | None, out_dir: str, fmt: str, profile: str,
                   timeout: float, rpc_timeout: float, jobs: int, chain: bool) -> None:
    """Pair requests with responses; write the tables and print a summary (worst offenders first)."""
    paths = _files(captures, read, profile)
    _writable(out_dir)
    progress = _progress() if jobs == 1 else None
    try:
        written, text, errors = _report(paths, out_dir, fmt, profile, timeout, rpc_timeout, progress, jobs, chain)
    except OSError as exc:  # the disk filled up, the directory went away...
        if exc.filename is not None and not os.path.abspath(exc.filename).startswith(os.path.abspath(out_dir)):
            raise  # not the report's files: a fault to report
        raise click.ClickException(dump.safe(f"cannot write the report to {out_dir}: {exc}")) from None
    click.echo("\n".join(dump.safe(line) for line in text.split("\n")))
    click.echo("\nWrote " + ", ".join(written), err=True)
    for error in errors:
        click.echo(dump.safe(f"pd-analyze: {error}"), err=True)
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
            progress: Callable[[str, int], None] | None, jobs: int, chain: bool) -> tuple[list[str], str, list[str]]:
    """The files written, the summary text and the capture errors."""
    from pd_analyze.output import report

    if fmt == "html":  # plots and drill-down need the whole tables
        from pd_analyze.analysis.api import analyze
        from pd_analyze.output import html_report

        analysis = analyze(paths, profile, timeout, rpc_timeout, progress, jobs, chain)
        written = report.write_tables(analysis, out_dir, "csv")
        written.append(html_report.write(analysis, f"{out_dir}/report.html",
                                         tables_dir_note="the CSV files beside this page"))
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
@profile_option
@_timeouts
def audit_command(captures: tuple[str, ...], read: str | None, fail_on: str, profile: str, timeout: float,
                  rpc_timeout: float, jobs: int, chain: bool) -> None:
    """Findings like a linter (file:frame: severity rule message); exit 1 at the --fail-on threshold.

    Findings are sorted by capture and frame through a bounded on-disk sort: memory stays flat."""
    from pd_analyze.model.rules import SEVERITIES, SEVERITY_RANK
    from pd_analyze.output import report

    paths = _files(captures, read, profile)
    rows, results = report.stream_findings(paths, Settings(profile, timeout, rpc_timeout), jobs, chain,
                                           progress=_progress() if jobs == 1 else None)
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


if __name__ == "__main__":
    main()
