"""Which files the user's arguments name: files, directories (their captures) and glob patterns.

Here, not in the notebook API: every command expands its arguments, and the command line should not load
the API (pandas, the drill-down) to do it."""

from __future__ import annotations

import glob
import os
from collections.abc import Iterable

CAPTURE_SUFFIXES = (".pcap", ".pcapng", ".cap", ".pcap.gz", ".pcapng.gz", ".gz")


def expand(paths: str | Iterable[str]) -> list[str]:
    """Files, directories (their captures, sorted) and glob patterns to a list of capture paths."""
    items = [paths] if isinstance(paths, str) else list(paths)
    out: list[str] = []
    for item in items:
        if item != "-" and os.path.isdir(item):
            out += sorted(os.path.join(item, n) for n in os.listdir(item)
                          if n.endswith(CAPTURE_SUFFIXES) and os.path.isfile(os.path.join(item, n)))
        elif any(ch in item for ch in "*?[") and not os.path.exists(item):
            out += sorted(glob.glob(item, recursive=True))
        else:
            out.append(item)
    return out
