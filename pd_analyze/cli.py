"""The `pd-analyze` command line: argument parsing, output streams and exit codes only.

Exit codes: 0 done, 1 a finding reached the --fail-on threshold (audit), 2 unreadable input or bad
usage. Data goes to stdout, progress and errors to stderr; no traceback ever reaches the user.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

import click

from pd_analyze import __version__, checks, dump
from pd_analyze.capture import CaptureError
from pd_analyze.dissect import DEFAULT_RPC_TIMEOUT, Dissector, dissect
from pd_analyze.registry import FIELDS

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


class _Group(click.Group):
    def main(self, *args: object, **kwargs: object) -> object:
        """Any unexpected exception becomes a one-line error with exit code 2, never a traceback."""
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
            click.echo(f"pd-analyze: internal error: {exc.__class__.__name__}: {exc} "
                       "(please report it with the capture)", err=True)
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


@main.command("dump", epilog=DUMP_EXAMPLES)
@click.argument("captures", nargs=-1, metavar="CAPTURE...")
@click.option("-r", "--read", "read", metavar="FILE", help="Capture to read (as tshark -r); - for stdin.")
@click.option("--frames", "frames", metavar="LIST", help="Only these frames, e.g. 1,5-9,20-.")
@click.option("--findings-only", is_flag=True, help="Only frames with findings, and only the findings.")
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text", show_default=True,
              help="text: indented tree; json: JSON Lines, one object per PNIO RPC frame.")
@click.option("--color/--no-color", default=None, help="Colour the text output (default: on a terminal).")
@click.option("--rpc-timeout", type=click.FloatRange(min=0.001), default=DEFAULT_RPC_TIMEOUT,
              show_default=True, help="Seconds of capture time before a request counts as unanswered.")
def dump_command(captures: tuple[str, ...], read: str | None, frames: str | None, findings_only: bool,
                 fmt: str, color: bool | None, rpc_timeout: float) -> None:
    """Every PNIO RPC frame as a tree of layers and fields: offset, bytes, value, meaning, check."""
    paths = _inputs(captures, read)
    try:
        wanted: Callable[[int], bool] = dump.parse_frames(frames) if frames else (lambda n: True)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--frames") from None
    colour = sys.stdout.isatty() if color is None else color
    style = _style(colour and fmt == "text")
    status = EXIT_OK
    for path in paths:
        if len(paths) > 1 and fmt == "text":
            click.echo(f"==> {path} <==")
        d = Dissector(annotate=True, rpc_timeout=rpc_timeout)
        results = (r for r in dissect(path, dissector=d) if wanted(r.frame))
        try:
            dump.render(results, fmt, click.echo, style, findings_only, checks.CHECKED_FIELDS)
        except CaptureError as exc:
            click.echo(f"pd-analyze: {exc}", err=True)
            status = EXIT_USAGE
        loose = [f for f in d.loose_findings if wanted(f.frame)]
        if loose and fmt == "text":
            click.echo("Findings on frames that are not PNIO RPC:")
            for f in loose:
                click.echo(f"  frame {f.frame} " + dump.finding_line(f, "", style))
        elif loose:
            click.echo(f"pd-analyze: {len(loose)} findings on frames that are not PNIO RPC "
                       "(see --format text)", err=True)
        click.echo(f"{path}: {d.accounting.line()}", err=True)
    sys.exit(status)


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
