"""The commands that hand results back to Wireshark: `annotate` (packet comments), `extract` (the frames of
chosen transactions), and the display filter (-Y) and `-T fields` output of `dump`.

Registered on the main group by the cli package; errors are click exceptions, which it turns into one line on
stderr and exit code 2.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

import click

from pd_analyze.analysis.capture_run import Settings
from pd_analyze.capture import CaptureError
from pd_analyze.cli.base import (
    EXIT_OK,
    EXIT_USAGE,
    checker_for,
    frames_beyond,
    frames_read,
    main,
    profile_option,
    timeout_options,
)
from pd_analyze.model.verdicts import VERDICTS
from pd_analyze.output import dump
from pd_analyze.output.capture_copy import Copied, UsageError
from pd_analyze.output.display_filter import DisplayFilter, FilterError, parse
from pd_analyze.protocol.dissector import Dissector
from pd_analyze.protocol.frames import FrameResult
from pd_analyze.protocol.profidrive_checks import Checker

if TYPE_CHECKING:
    from pd_analyze.output.frame_select import FieldsFormat
    from pd_analyze.output.frame_view import FieldRef

ANNOTATE_EXAMPLES = """\b
Examples:
  pd-analyze annotate sample_pcaps/fault_trace.pcap -w annotated.pcapng
  tshark -r annotated.pcapng -Y frame.comment -T fields -e frame.number -e frame.comment
  pd-analyze annotate trace.pcapng -w naks.pcapng -Y 'txn.verdict == "nak"'
"""

EXTRACT_EXAMPLES = """\b
Examples:
  pd-analyze extract sample_pcaps/fault_trace.pcap -w for-vendor.pcap --verdict nak,timeout,pnio_error
  pd-analyze extract trace.pcapng -w p1082.pcapng --pnu 1082 --device 192.168.1.21
  pd-analyze extract trace.pcap -w one.pcap --txn 14
  pd-analyze extract trace.pcap -w rule.pcap -Y 'finding.rule == "T4"'
"""


def display_filter(text: str | None) -> DisplayFilter | None:
    """-Y parsed; a syntax error or an unknown field: one line pointing at the column, exit 2."""
    if text is None:
        return None
    try:
        return parse(text)
    except FilterError as exc:
        raise click.ClickException(dump.safe(f"-Y {text!r}: column {exc.column}: {exc.message}")) from None


def filter_option(func: Callable) -> Callable:
    return click.option("-Y", "--display-filter", "flt", metavar="FILTER",
                        help="Only frames matching this tshark-like filter, e.g. 'pd.addr.pnu == 964 and "
                             "txn.verdict == \"nak\"' (fields: `pd-analyze fields`, tshark names too, and "
                             "txn.id, txn.verdict, txn.b5_retries, finding.rule, finding.severity).")(func)


def dump_options(func: Callable) -> Callable:
    """-Y, -e and -E of `dump` (-T is its --format)."""
    func = click.option("-E", "field_options", multiple=True, metavar="OPTION",
                        help="-T fields option as tshark's: header=y, separator=,|/t|/s, quote=d, "
                             "occurrence=f|l|a, aggregator=,")(func)
    func = click.option("-e", "field_names", multiple=True, metavar="FIELD",
                        help="A field for -T fields (repeatable): a registry or tshark name.")(func)
    return filter_option(func)


def _settings(profile: str, timeout: float, rpc_timeout: float) -> Settings:
    checker_for(profile)  # a bad profile is a usage error before any file is read
    return Settings(profile, timeout, rpc_timeout)


def _common(func: Callable) -> Callable:
    func = profile_option(timeout_options(func))
    func = filter_option(func)
    func = click.option("-w", "out", required=True, metavar="OUT",
                        help="File to write (- for standard output; a name ending .gz is gzip-compressed).")(func)
    return click.argument("capture", metavar="CAPTURE")(func)


def _finish(result: Copied, what: str) -> None:
    click.echo(dump.safe(f"{result.path}: {what}"), err=True)
    for error in result.errors:
        click.echo(dump.safe(f"pd-analyze: {error}"), err=True)
    sys.exit(EXIT_USAGE if result.errors else EXIT_OK)


def _usage(run: Callable[[], Copied]) -> Copied:
    try:
        return run()
    except UsageError as exc:
        raise click.UsageError(dump.safe(str(exc))) from None
    except CaptureError as exc:
        raise click.ClickException(dump.safe(str(exc))) from None


@main.command("annotate", epilog=ANNOTATE_EXAMPLES)
@_common
def annotate_command(capture: str, out: str, flt: str | None, profile: str, timeout: float,
                     rpc_timeout: float) -> None:
    """Write a pcapng copy of CAPTURE whose frames carry the findings and transactions as packet comments
    (Wireshark shows them; tshark filters them as frame.comment). Every frame is kept as it is; with -Y
    only the matching frames are written, as tshark -Y -w does."""
    from pd_analyze.output.annotate import annotate

    parsed = display_filter(flt)
    result = _usage(lambda: annotate(capture, out, _settings(profile, timeout, rpc_timeout), parsed))
    _finish(result, f"{result.frames} frames written, {result.comments} with a pd-analyze comment")


@main.command("extract", epilog=EXTRACT_EXAMPLES)
@_common
@click.option("--verdict", metavar="LIST", default="", help="Transactions with one of these verdicts, e.g. "
              f"nak,timeout,pnio_error ({', '.join(VERDICTS)}).")
@click.option("--pnu", metavar="LIST", default="", help="Transactions addressing one of these parameters, "
              "e.g. 964,2000.")
@click.option("--device", metavar="LIST", default="", help="Transactions with one of these devices (IP).")
@click.option("--txn", metavar="LIST", default="", help="These transactions (the report's txn numbers).")
def extract_command(capture: str, out: str, flt: str | None, profile: str, timeout: float, rpc_timeout: float,
                    verdict: str, pnu: str, device: str, txn: str) -> None:
    """Write only the frames of the chosen transactions (every frame of their write and read calls:
    fragments, retransmissions and B5 polls included), in CAPTURE's format, times and bytes unchanged:
    `report` on OUT finds the same transactions with the same verdicts. Criteria combine with "and", a
    list within one with "or"; -Y keeps the transactions with a matching frame."""
    from pd_analyze.output import extract

    parsed = display_filter(flt)

    def run() -> Copied:
        selection = extract.selection_of(extract.words(verdict), extract.numbers(pnu, "--pnu"),
                                         extract.words(device), extract.numbers(txn, "--txn"), parsed)
        return extract.extract(capture, out, _settings(profile, timeout, rpc_timeout), selection)

    result = _usage(run)
    _finish(result, f"{result.frames} frames of {result.transactions} transactions written")


def fields_dump(paths: list[str], settings: Settings, checker: Checker, flt: str | None, out_type: str,
                names: tuple[str, ...], options: tuple[str, ...], ranges: list[tuple[int, int]],
                render: Callable[[Iterator[FrameResult]], object]) -> int:
    """`dump -Y` and `dump -T fields` (of the frames in `ranges`, --frames; all when empty): the exit code.
    `render(results)` writes the text or JSON dump of the frames kept."""
    from pd_analyze.output import fields_file, frame_select

    parsed = display_filter(flt)
    try:
        refs = frame_select.field_refs(names) if out_type == "fields" else []
        fmt = frame_select.FieldsFormat.parse(options)
    except FilterError as exc:
        raise click.ClickException(dump.safe(exc.message)) from None
    except UsageError as exc:
        raise click.UsageError(dump.safe(str(exc))) from None
    if out_type == "fields" and not refs:
        raise click.UsageError("-T fields needs at least one -e FIELD, e.g. -e frame.number -e pd.ref")
    def wanted(number: int) -> bool:
        return not ranges or any(lo <= number <= hi for lo, hi in ranges)

    status = 0
    if out_type == "fields" and fmt.header:
        click.echo(frame_select.header_line(names, fmt))
    for path in paths:
        facts = None
        try:
            facts = frame_select.report_facts(path, settings, parsed, refs)
        except CaptureError as exc:  # (the per-frame read below reports the damage it meets)
            click.echo(dump.safe(f"pd-analyze: {exc}"), err=True)
            status = EXIT_USAGE
            continue
        columns = fields_file.takes(path, frame_select.reads_analysis(refs, parsed))
        if out_type == "fields" and facts is None and columns:
            status = _fields_file(path, settings, checker, refs, fmt, parsed, ranges, status)
            continue
        d = Dissector(annotate=True, rpc_timeout=settings.rpc_timeout, checker=checker,
                      links=facts.links if facts is not None else None)
        try:
            views = frame_select.views(path, settings, d, parsed, refs, every_frame=out_type == "fields",
                                       facts=facts)
            if out_type == "fields":
                write = sys.stdout.write
                for view in views:
                    if wanted(view.number):
                        write(frame_select.fields_line(view, refs, fmt) + "\n")
            else:
                render(v.result for v in views if v.result is not None and wanted(v.number))
        except UsageError as exc:
            raise click.UsageError(dump.safe(str(exc))) from None
        except CaptureError as exc:
            click.echo(dump.safe(f"pd-analyze: {exc}"), err=True)
            status = EXIT_USAGE
        frames_beyond(path, ranges, d.accounting.read, status == EXIT_USAGE)
        frames_read(path, d.accounting, status == EXIT_USAGE)
    return status


def _fields_file(path: str, settings: Settings, checker: Checker, refs: list[FieldRef], fmt: FieldsFormat,
                 flt: DisplayFilter | None, ranges: list[tuple[int, int]], status: int) -> int:
    """`-T fields` of one capture file read as batches (output.fields_file), after files that ended with
    `status`: the exit code so far (as the per-frame path below says it)."""
    from pd_analyze.output import frame_notes, frame_select
    from pd_analyze.output.fields_file import FieldsFile

    needs_notes = frame_select.reads_analysis(refs, flt)
    notes = None
    lines = FieldsFile(path, settings, checker, refs, fmt, flt, None, ranges)
    try:
        notes = lines.notes = frame_notes.collect(path, settings) if needs_notes else None
        write = sys.stdout.write
        for line in lines.lines():
            write(line + "\n")
    except CaptureError as exc:
        click.echo(dump.safe(f"pd-analyze: {exc}"), err=True)
        status = EXIT_USAGE
    finally:
        if notes is not None:
            notes.close()
    frames_beyond(path, ranges, lines.accounting.read, status == EXIT_USAGE)
    frames_read(path, lines.accounting, status == EXIT_USAGE)
    return status
