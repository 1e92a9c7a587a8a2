"""`pd-analyze dump`: every PNIO RPC frame as a tree of layers and fields, or the frames a display filter
selects, or `-T fields` columns (cli.wireshark)."""

from __future__ import annotations

import sys
from collections.abc import Callable

import click
import numpy as np

from pd_analyze.analysis.capture_run import Settings
from pd_analyze.capture import CaptureError
from pd_analyze.cli import wireshark
from pd_analyze.cli.base import (
    EXIT_OK,
    EXIT_USAGE,
    SECONDS,
    capture_files,
    checker_for,
    frames_beyond,
    frames_read,
    main,
    profile_option,
    text_style,
)
from pd_analyze.model.rules import Finding
from pd_analyze.output import dump, dump_facts, dump_file
from pd_analyze.protocol.dissector import DEFAULT_RPC_TIMEOUT, Dissector, dissect
from pd_analyze.protocol.profidrive_checks import Checker

# fields of a capture record the second pass does not see (it reads frames, not records): -Y naming one
# takes the per-frame path of -T fields
_RECORD_FIELDS = frozenset({"frame.iface", "frame.linktype", "frame.caplen"})

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


def lines_out(coloured: bool) -> Callable[[str], None]:
    """Where the dump's lines go: plain text straight to stdout (click.echo flushes and looks for colour
    codes to strip on every line, some 7 us of a dump's frame), coloured text through click.echo."""
    if coloured:  # asked for (always) or on a terminal: click.echo would strip the codes into a pipe
        return lambda text: click.echo(text, color=True)
    write = sys.stdout.write

    def line(text: str) -> None:
        write(text + "\n")
    return line


@main.command("dump", epilog=DUMP_EXAMPLES)
@click.argument("captures", nargs=-1, metavar="CAPTURE...")
@click.option("-r", "--read", "read", metavar="FILE", help="Capture to read (as tshark -r); - for stdin.")
@click.option("--frames", "frames", metavar="LIST", help="Only these frames, e.g. 1,5-9,20-.")
@click.option("--findings-only", is_flag=True, help="Only frames with findings, and only the findings.")
@click.option("--format", "-T", "fmt", type=click.Choice(["text", "json", "fields"]), default="text", show_default=True,
              help="text: indented tree; json: JSON Lines, one object per PNIO RPC frame; fields: see -e.")
@wireshark.dump_options
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
    paths = capture_files(captures, read, profile) if not (read == "-" or captures == ("-",)) else ["-"]
    checker = checker_for(profile)
    try:
        ranges = dump.frame_ranges(frames) if frames else []
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--frames") from None
    wanted: Callable[[int], bool] = (lambda n: any(lo <= n <= hi for lo, hi in ranges)) if ranges else \
        (lambda n: True)
    colour = sys.stdout.isatty() if color == "auto" and not no_color else color == "always" and not no_color
    style = text_style(colour and fmt == "text")
    stdin = read == "-" or captures == ("-",)
    parsed = wireshark.display_filter(flt)
    if parsed is not None and fmt != "fields" and not field_names and not stdin and \
            not any(r.names[0] in _RECORD_FIELDS for r in parsed.refs):  # the frames a filter selects
        status = EXIT_OK
        for path in paths:  # (no file headings: the frames matched, one after the other, as before)
            selection = dump_file.Filtered(parsed, ranges, findings_only)
            status = max(status, _dump_file(path, Settings(profile, rpc_timeout=rpc_timeout), checker, selection,
                                            ranges, findings_only, fmt, lines_out(colour and fmt == "text"), style,
                                            time_format))
        sys.exit(status)
    if flt is not None or fmt == "fields" or field_names:  # -T fields (and -Y on standard input)
        out = lines_out(colour and fmt == "text")
        sys.exit(wireshark.fields_dump(paths, Settings(profile, rpc_timeout=rpc_timeout), checker, flt, fmt,
                 field_names, field_options, ranges, lambda found: dump.render(found, fmt, out, style, findings_only)))
    status = EXIT_OK
    out = lines_out(colour and fmt == "text")
    for path in paths:
        if len(paths) > 1 and fmt == "text":
            click.echo(dump.safe(f"==> {path} <=="))
        if path != "-":  # read twice: the report's findings and pairing first, then the frames it prints
            selection = dump_file.WithFindings(ranges) if findings_only else dump_file.Selection(ranges)
            status = max(status, _dump_file(path, Settings(profile, rpc_timeout=rpc_timeout), checker, selection,
                                            ranges, findings_only, fmt, out, style, time_format))
            continue
        d = Dissector(annotate=True, rpc_timeout=rpc_timeout, checker=checker)
        clock = dump.Clock(time_format)
        results = clock.watch(dissect(path, dissector=d))
        results = (r for r in results if wanted(r.frame))
        failed = False
        try:
            dump.render(results, fmt, out, style, findings_only, clock)
        except CaptureError as exc:
            click.echo(dump.safe(f"pd-analyze: {exc}"), err=True)
            status, failed = EXIT_USAGE, True
        frames_beyond(path, ranges, d.accounting.read, failed)
        _loose([f for f in d.loose_findings if wanted(f.frame)], d.loose_dropped, fmt, style)
        frames_read(path, d.accounting, failed)
    sys.exit(status)


def _dump_file(path: str, settings: Settings, checker: Checker, selection: dump_file.Selection,
               ranges: list[tuple[int, int]], findings_only: bool, fmt: str, out: Callable[[str], None],
               style: dump.Style, time_format: str) -> int:
    """One capture file: the report's findings and pairing, then the frames `selection` prints; the exit
    code. The findings of frames that are not PNIO RPC follow, unless a display filter chose the frames."""
    try:
        facts = dump_facts.collect(path, settings, txns=selection.needs_txns)
    except CaptureError as exc:  # (the analysis records a capture's damage; this is what it could not open)
        click.echo(dump.safe(f"pd-analyze: {exc}"), err=True)
        return EXIT_USAGE
    frames = dump_file.DumpFrames(path, settings, checker, facts)
    clock = dump.Clock(time_format)
    spool = dump.FrameSpool(fmt, style, findings_only)  # (frames that wait behind a fragment wait on disk)
    failed = False
    try:
        dump.render(frames.timed(frames.results(selection, spool), clock), fmt, out, style, findings_only, clock)
    except CaptureError as exc:
        click.echo(dump.safe(f"pd-analyze: {exc}"), err=True)
        failed = True
    finally:
        spool.close()
        facts.close()
    frames_beyond(path, ranges, facts.accounting.read, failed)
    wanted = dump_file.Selection(ranges).wanted
    if not isinstance(selection, dump_file.Filtered):  # (as tshark -Y: only the frames the filter matches)
        _loose([f for f in frames.loose if wanted(np.array([f.frame]))[0]], frames.loose_dropped, fmt, style)
    frames_read(path, facts.accounting, failed)
    return EXIT_USAGE if failed else EXIT_OK


def _loose(loose: list[Finding], dropped: int, fmt: str, style: dump.Style) -> None:
    """The findings on frames that are not PNIO RPC, after the frames (text), or how many there are (JSON)."""
    if loose and fmt == "text":
        click.echo("Findings on frames that are not PNIO RPC:")
        for f in loose:
            click.echo(f"  frame {f.frame} " + dump.finding_line(f, "", style))
        if dropped:
            click.echo(f"  ... and {dropped} more (only the first {len(loose)} are kept)")
    elif loose:
        click.echo(f"pd-analyze: {len(loose)} findings on frames that are not PNIO RPC "
                   "(see --format text)", err=True)
