"""The `pd-analyze` command line: argument parsing, output streams and exit codes only; the work is done in
the layers below. One module per group of commands (dump; decode, profiles, fields; report, audit; params,
diff; annotate, extract), what they share in `base`.

Exit codes: 0 done, 1 a finding reached the --fail-on threshold (audit) or the states differ (diff), 2
unreadable input or bad usage, 141 the reader of stdout went away (as a Unix tool killed by SIGPIPE). Data
goes to stdout, progress and errors to stderr; no traceback ever reaches the user.

Each command's module is imported when the command is run (base.COMMAND_MODULES): start-up loads only what
the command needs.
"""

from pd_analyze.cli.base import EXIT_CLOSED_PIPE, EXIT_FINDINGS, EXIT_OK, EXIT_USAGE, main

__all__ = ["EXIT_CLOSED_PIPE", "EXIT_FINDINGS", "EXIT_OK", "EXIT_USAGE", "main"]
