"""What every command shares: the main group (one-line errors, exit codes, a closed pipe), the options
more than one command takes (profile, timeouts, jobs), and how inputs and outputs are checked before any
work starts."""

from __future__ import annotations

import gc
import importlib
import os
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, NoReturn

import click

from pd_analyze import __version__
from pd_analyze.analysis.engine.allocator import prefer_system_pool
from pd_analyze.analysis.engine.collector import THRESHOLD
from pd_analyze.capture.reader import unreadable_reason
from pd_analyze.output.terminal import safe
from pd_analyze.protocol import profiles
from pd_analyze.protocol.dissector import DEFAULT_RPC_TIMEOUT
from pd_analyze.protocol.frames import Accounting
from pd_analyze.protocol.profidrive_checks import Checker

if TYPE_CHECKING:
    from pd_analyze.output.dump import Style

EXIT_OK, EXIT_FINDINGS, EXIT_USAGE = 0, 1, 2
EXIT_CLOSED_PIPE = 128 + 13  # SIGPIPE, as the shell reports a tool that wrote into a closed pipe
_COLOURS = {"error": "red", "warning": "yellow", "info": "cyan", "frame": "green", "dim": "bright_black"}


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
    cycles are still collected, so memory stays bounded. The CLI only: a notebook keeps its own settings (but
    for the engine's run: engine.collector)."""
    gc.freeze()
    gc.set_threshold(THRESHOLD, 20, 20)


# Each command's module, imported when the command is run or listed: `report` of a small capture should not
# first load the dump's filter engine, the capture copier and the decoders (about a third of a second).
COMMAND_MODULES = {"annotate": "wireshark", "audit": "report", "decode": "decode", "diff": "params", "dump": "dump",
                   "extract": "wireshark", "fields": "decode", "params": "params", "profiles": "decode",
                   "report": "report"}


class _Group(click.Group):
    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(self.commands) | set(COMMAND_MODULES))

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name not in self.commands and cmd_name in COMMAND_MODULES:
            importlib.import_module(f"pd_analyze.cli.{COMMAND_MODULES[cmd_name]}")  # its decorators add it
        return self.commands.get(cmd_name)

    def invoke(self, ctx: click.Context) -> object:
        try:
            return super().invoke(ctx)
        except BrokenPipeError:  # before click's own handler, which would exit 1
            _closed_pipe()

    def main(self, *args: object, **kwargs: object) -> object:
        """Any unexpected exception becomes a one-line error with exit code 2, never a traceback."""
        _batch_gc()
        prefer_system_pool()
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
            error_line(exc)
            sys.exit(EXIT_USAGE)
        except BrokenPipeError:
            _closed_pipe()
        except KeyboardInterrupt:
            click.echo("pd-analyze: interrupted", err=True)
            sys.exit(130)
        except Exception as exc:
            click.echo(safe(f"pd-analyze: internal error: {exc.__class__.__name__}: {exc} "
                            "(please report it with the capture)"), err=True)
            sys.exit(EXIT_USAGE)


def error_line(exc: click.ClickException) -> None:
    """Every error as one line that starts `pd-analyze:`, as a capture's errors do (click's own form, `Error:`
    after a usage block, differed from them); a usage error says where the help is."""
    message = exc.format_message()
    if isinstance(exc, click.UsageError):
        commands = []  # the subcommands, under the name users type (not `python -m pd_analyze.cli`)
        ctx = exc.ctx
        while ctx is not None and ctx.parent is not None:
            commands.insert(0, ctx.info_name or "")
            ctx = ctx.parent
        message = message.rstrip(".") + f" (see '{' '.join(['pd-analyze', *commands])} --help')"
    click.echo(safe(f"pd-analyze: {message}"), err=True)


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


class _NoPandas:
    """An import finder that says pandas is not installed (see `without_pandas`)."""

    def find_spec(self, name: str, path: object = None, target: object = None) -> None:
        if name == "pandas":
            raise ModuleNotFoundError("pandas is not loaded by a streamed report", name="pandas")


def without_pandas() -> None:
    """Keep pyarrow from loading pandas, about 0.2 s of a start-up meant to take 0.3 s (issue #23).

    The first time pyarrow converts Python values (`pa.array` of a list, a Python scalar handed to a compute
    function, an empty table's columns) it imports pandas, only to tell pandas inputs apart from others.
    A streamed CSV or JSON Lines report hands it none and converts no time to a Python object
    (times are written from their integer nanoseconds), so that first probe is answered here, once, with
    "not installed" (pyarrow remembers the answer). Nothing else is changed: an `import pandas` of ours
    still works, and so does pyarrow's `to_pandas` (it tries the import again). Not for Parquet (its schema's
    pandas metadata is made by pandas), `--format html` and the notebook API, which build DataFrames.
    tests/test_cli_startup.py holds the report to it."""
    if "pandas" in sys.modules:
        return
    import pyarrow as pa

    finder = _NoPandas()
    sys.meta_path.insert(0, finder)
    try:
        pa.array([])  # pyarrow's probe: it asks for pandas here and keeps the answer
    finally:
        sys.meta_path.remove(finder)


def some_readable(paths: list[str]) -> None:
    """Exit 2 with each reason when no input can be read: nothing to report on, no files, no output."""
    unreadable = [error for error in map(unreadable_reason, paths) if error]
    if len(unreadable) == len(paths):
        for error in unreadable:
            click.echo(safe(f"pd-analyze: {error}"), err=True)
        sys.exit(EXIT_USAGE)


def frames_read(path: str, accounting: Accounting, failed: bool) -> None:
    """A dumped capture's accounting line on stderr; none after an input that could not be read at all (its
    error said so: "0 frames read" after it told nothing)."""
    if not failed or accounting.read:
        click.echo(safe(f"{path}: {accounting.line()}"), err=True)


def frames_beyond(path: str, ranges: list[tuple[int, int]], read: int, failed: bool) -> None:
    """Say which part of --frames the capture of `read` frames does not hold: a range wholly beyond it, or the end
    of one that runs past it (`5-9` of 6 frames: 7-9). Not after a read error, which says why it stopped."""
    if failed:
        return
    from pd_analyze.output.dump import OPEN_END  # here: only the dump's commands take --frames

    parts = []
    for lo, hi in ranges:
        if lo > read:
            parts.append(f"{lo}-" if hi >= OPEN_END else f"{lo}-{hi}" if hi != lo else str(lo))
        elif read < hi < OPEN_END:
            parts.append(f"{read + 1}-{hi} (of {lo}-{hi})" if hi != read + 1 else f"{hi} (of {lo}-{hi})")
    if parts:
        click.echo(safe(f"pd-analyze: {path}: --frames {', '.join(parts)} lie{'s' if len(parts) == 1 else ''} "
                        f"beyond the capture's {read} frames"), err=True)


def inputs(captures: tuple[str, ...], read: str | None) -> list[str]:
    paths = ([read] if read else []) + list(captures)
    if not paths:
        raise click.UsageError("no capture given: pass CAPTURE or -r FILE (use - for standard input)")
    return paths


def text_style(enabled: bool) -> Style:
    from pd_analyze.output.dump import plain_style  # here: only the dump's commands style their text

    if not enabled:
        return plain_style
    return lambda text, role: click.style(text, fg=_COLOURS.get(role))


def checker_for(profile: str) -> Checker:
    try:
        return Checker.for_profile(profile)
    except profiles.ProfileError as exc:
        raise click.BadParameter(str(exc), param_hint="--profile") from None


def profile_option(func: Callable) -> Callable:
    return click.option("--profile", default=profiles.DEFAULT, show_default=True, metavar="NAME|FILE.toml",
                        help="Vendor limits to check against (see `pd-analyze profiles`).")(func)


def progress_bar() -> Callable[[str, int], None] | None:
    """Percent of the capture's bytes read and the time left, on stderr when it is a terminal."""
    from pd_analyze.output.progress import terminal_progress

    return terminal_progress()


def capture_files(captures: tuple[str, ...], read: str | None, profile: str) -> list[str]:
    from pd_analyze.capture.files import expand

    given = inputs(captures, read)
    paths = expand(given)
    if not paths:
        raise click.UsageError(safe(f"no capture files matched {' '.join(given)} (a directory is searched for "
                                    "*.pcap, *.pcapng, *.cap and *.gz files)"))
    checker_for(profile)  # a bad profile is a usage error before any file is read
    return paths


def run_options(func: Callable) -> Callable:
    """--jobs and --chain, and the timeouts."""
    func = click.option("--jobs", "-j", type=click.IntRange(min=1), default=1, show_default=True,
                        help="Use N processes: several files in parallel (each worker returns its file's "
                             "rows whole), or one file of 8 MB or more with its batches decoded by N-1 workers "
                             "and analysed here in order. Output identical to one process.")(func)
    func = click.option("--chain", is_flag=True,
                        help="The files continue one another (ring buffer): pair across file boundaries.")(func)
    return timeout_options(func)


def timeout_options(func: Callable) -> Callable:
    """--timeout (transactions) and --rpc-timeout (calls), in seconds of capture time."""
    func = click.option("--timeout", type=SECONDS, default=10.0, show_default=True,
                        help="Seconds of capture time a transaction may take before it is a timeout.")(func)
    return click.option("--rpc-timeout", type=SECONDS, default=DEFAULT_RPC_TIMEOUT,
                        show_default=True, help="Seconds of capture time before an RPC call is unanswered.")(func)


def writable_dir(out_dir: str) -> None:
    """--out must be a directory we can write to: said before any capture is read."""
    import tempfile

    try:
        os.makedirs(out_dir, exist_ok=True)
        tempfile.TemporaryFile(dir=out_dir).close()
    except OSError as exc:
        raise click.UsageError(safe(f"--out {out_dir}: cannot write there ({exc.strerror or exc})")) from None


def expected_set(path: str) -> object:
    """The intended set, read before any capture: a malformed one is a one-line error naming its line."""
    from pd_analyze.analysis import intended

    try:
        return intended.load(path)
    except intended.ExpectError as exc:
        raise click.ClickException(safe(str(exc))) from None
