"""Why a file cannot be read, in the same words for every input: `pd-analyze: FILE: no such file` for a capture,
a profile and an intended set alike (capture.reader words a capture's reasons the same way; tests/test_cli.py
holds every option to it)."""

from __future__ import annotations

NO_SUCH_FILE = "no such file"
PERMISSION_DENIED = "permission denied (check the file's read rights)"


def open_problem(exc: OSError) -> str:
    """The reason an open or read failed, as the error line after the file's name shows it."""
    if isinstance(exc, FileNotFoundError):
        return NO_SUCH_FILE
    if isinstance(exc, PermissionError):
        return PERMISSION_DENIED
    if isinstance(exc, IsADirectoryError):
        return "is a directory, not a file"
    return f"cannot open ({exc.strerror or exc})"
