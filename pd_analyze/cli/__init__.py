"""The `pd-analyze` command line: argument parsing, output streams and exit codes only; the work is done in
the layers below. One module per group of commands (dump; decode, profiles, fields; report, audit; params,
diff; annotate, extract), what they share in `base`.

Exit codes: 0 done, 1 a finding reached the --fail-on threshold (audit) or the states differ (diff), 2
unreadable input or bad usage, 141 the reader of stdout went away (as a Unix tool killed by SIGPIPE). Data
goes to stdout, progress and errors to stderr; no traceback ever reaches the user.

Each command's module is imported when the command is run (base.COMMAND_MODULES): start-up loads only what
the command needs.
"""

import os

# numpy's OpenBLAS starts a thread for every core when numpy is imported: no command multiplies matrices,
# and on a busy machine those threads cost 60-100 ms of start-up (issue #23: `import numpy` 0.17-0.24 s
# against 0.10 s). Set before anything imports numpy; a user's own setting is kept, --jobs workers inherit it.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from pd_analyze.cli.base import EXIT_CLOSED_PIPE, EXIT_FINDINGS, EXIT_OK, EXIT_USAGE, main

__all__ = ["EXIT_CLOSED_PIPE", "EXIT_FINDINGS", "EXIT_OK", "EXIT_USAGE", "main"]
