"""`pd-analyze params` (the parameter state per drive) and `pd-analyze diff` (two states compared); the
logic is in analysis.param_state and output.param_tables / param_diff."""

from __future__ import annotations

import sys

import click

from pd_analyze.analysis.capture_run import Settings
from pd_analyze.cli.base import (
    EXIT_FINDINGS,
    EXIT_OK,
    EXIT_USAGE,
    capture_files,
    main,
    profile_option,
    progress_bar,
    run_options,
    some_readable,
    writable_dir,
)
from pd_analyze.output import dump

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
  pd-analyze diff line1.pcapng line2.pcapng --by do --pair 192.168.1.21=192.168.2.21 --pair pump-1=pump-2
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
@run_options
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
    paths = capture_files(captures, read, profile)
    some_readable(paths)
    if out_dir is not None:
        writable_dir(out_dir)
    state, results = collect(paths, Settings(profile, timeout, rpc_timeout), progress_bar() if jobs == 1 else None,
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
              help="device: each drive against the same drive (before and after); do: drives that should be alike, "
                   "the one drive of A against the one of B, or, with several, those of the same PN-DCP station name "
                   "(or --pair).")
@click.option("--pair", "pairs", multiple=True, metavar="A_DRIVE=B_DRIVE",
              help="With --by do: compare this drive of A with this drive of B (an address or a station name; "
                   "repeatable).")
@click.option("--format", "fmt", type=click.Choice(["text", "csv", "json"]), default="text", show_default=True)
@profile_option
@run_options
def diff_command(a: str, b: str, by: str, pairs: tuple[str, ...], fmt: str, profile: str, timeout: float,
                 rpc_timeout: float, jobs: int, chain: bool) -> None:
    """Parameter state of capture A against B: one row per parameter element that differs, is missing on one side,
    or was refused (or left unconfirmed) on one side. Exit 0 when the states agree, 1 when they differ, 2 on
    trouble, as diff(1). A capture damaged part way is compared as far as it reads (its error follows, exit 2),
    as every command keeps the frames before the damage."""
    from pd_analyze.analysis.param_state import collect
    from pd_analyze.output import param_diff

    named = [p.partition("=")[::2] for p in pairs]
    if any(not x or not y for x, y in named):
        raise click.BadParameter("give A_DRIVE=B_DRIVE, e.g. 192.168.1.21=192.168.2.21 or pump-1=pump-2",
                                 param_hint="--pair")
    files = [capture_files((side,), None, profile) for side in (a, b)]
    for side in files:
        some_readable(side)  # a side with nothing to read: its reason, exit 2 (a diff against nothing says nothing)
    settings = Settings(profile, timeout, rpc_timeout)
    (state_a, res_a), (state_b, res_b) = (collect(f, settings, None, jobs, chain) for f in files)
    errors = [f"{c.path}: {c.error}" for c in res_a + res_b if c.error]
    try:
        rows = param_diff.diff_rows(state_a, state_b, by, named)
    except param_diff.DiffError as exc:
        raise click.UsageError(dump.safe(str(exc))) from None
    if fmt == "text":
        if rows:
            click.echo("\n".join(dump.safe(line) for line in param_diff.diff_text(rows, by)))
    else:
        sys.stdout.write(param_diff.diff_formatted(rows, fmt))
    click.echo(f"{len(rows)} parameter element{'s' if len(rows) != 1 else ''} differ"
               f"{'s' if len(rows) == 1 else ''} (A: {len(state_a.elements)}, B: {len(state_b.elements)})", err=True)
    for error in errors:
        click.echo(dump.safe(f"pd-analyze: {error}"), err=True)
    sys.exit(EXIT_USAGE if errors else EXIT_FINDINGS if rows else EXIT_OK)
