"""Progress on a terminal: percent of the capture's bytes read and the time left, per file.

The analysis reports frames read (analysis.capture_run.Progress); how far into the file that is comes
from the file's own read position, which Linux shows for every open file (/proc/self/fdinfo). Where it
cannot be seen (standard input, another system), the bar counts frames instead.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable

_EVERY = 4096  # frames between updates: the callback comes per PNIO frame


def terminal_progress() -> Callable[[str, int], None] | None:
    """The callback for analyze/report/audit: a tqdm bar per capture on stderr, None when stderr is not a
    terminal (a pipe or a log file gets no bar)."""
    if not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    bars: dict[str, list] = {}  # path -> [bar, its _Position or None, frames at the last update]

    def update(path: str, frames: int) -> None:
        held = bars.get(path)
        if held is not None and frames - held[2] < _EVERY:
            return
        if held is None:
            where = _Position.of(path)
            if where is not None:
                bar = tqdm(desc=path, total=where.size, unit="B", unit_scale=True, leave=False, file=sys.stderr)
            else:
                bar = tqdm(desc=path, unit=" frames", leave=False, file=sys.stderr)
            held = bars[path] = [bar, where, frames]
        bar, where, _ = held
        held[2] = frames
        if where is None:
            bar.n = frames
        else:
            position = where.read()
            if position is not None:
                bar.n = position
            bar.set_postfix_str(f"{frames:,} frames", refresh=False)
        bar.refresh()

    return update


class _Position:
    """Where the process is reading a file: the offset of the descriptor open on it."""

    def __init__(self, path: str, size: int) -> None:
        self.real = os.path.realpath(path)
        self.size = size
        self.fd: str | None = None

    @classmethod
    def of(cls, path: str) -> _Position | None:
        if path == "-" or not os.path.isdir("/proc/self/fdinfo"):
            return None
        try:
            size = os.stat(path).st_size
        except OSError:
            return None
        return cls(path, size) if size > 0 else None

    def read(self) -> int | None:
        """Bytes into the file, None when no descriptor is open on it (yet, or any more)."""
        for attempt in range(2):
            if self.fd is None or attempt:
                self.fd = self._find()
                if self.fd is None:
                    return None
            try:
                if os.readlink(f"/proc/self/fd/{self.fd}") != self.real:
                    continue
                with open(f"/proc/self/fdinfo/{self.fd}", encoding="ascii") as info:
                    for line in info:
                        if line.startswith("pos:"):
                            return min(int(line.split()[1]), self.size)
            except (OSError, ValueError):
                continue
        return None

    def _find(self) -> str | None:
        try:
            for fd in os.listdir("/proc/self/fd"):
                try:
                    if os.readlink(f"/proc/self/fd/{fd}") == self.real:
                        return fd
                except OSError:
                    continue
        except OSError:
            return None
        return None
