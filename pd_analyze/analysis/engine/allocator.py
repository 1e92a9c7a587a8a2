"""What the process gives back to the system between batches, and which allocator pyarrow uses.

A batch's columns, rows and tables are freed when its part is done, but an allocator keeps freed memory
for later: the peak resident set of a long capture grew with its length though the engine's live state
stays flat (issue #23: 1.21x the peak at 4x the frames). Two measures, measured on 200,000 and 800,000
fault-rich frames (README, Performance):

- pyarrow's default pool (mimalloc in the wheels) kept some 50-60 MiB more than the C library's malloc
  at every size, for the same CPU time: the command line asks pyarrow for the system pool
  (`SYSTEM_POOL`), through the environment so that `--jobs` workers inherit it; a user's own
  ARROW_DEFAULT_MEMORY_POOL wins. The notebook API leaves a user's process as it is.
- glibc returns memory freed inside its heap only when asked: `give_back` after each batch (about 2 ms
  a batch of 16,384 frames) keeps the peak at 4x the frames within some 12 % of the peak at 1x, where it
  grew by 18 % without it; and after each slice of a batch's tables (engine.txncols.SLICE_ROWS: a flood
  of long requests, 20 MiB less at its peak). Elsewhere than glibc it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
from collections.abc import Callable
from functools import cache

SYSTEM_POOL = {"ARROW_DEFAULT_MEMORY_POOL": "system"}  # read by pyarrow when it is first imported


def prefer_system_pool() -> None:
    """pyarrow's memory from the C library's malloc in this process and its children, unless the user chose;
    to be called before pyarrow is imported (a pool chosen later applies only to what is allocated later)."""
    for name, value in SYSTEM_POOL.items():
        os.environ.setdefault(name, value)


@cache
def _trim() -> Callable[[int], int] | None:
    """glibc's malloc_trim, or None where the C library has none (musl, macOS, Windows)."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
        trim = getattr(libc, "malloc_trim", None)
    except OSError:
        return None
    if trim is None:
        return None
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return trim


def give_back() -> None:
    """The free memory of the C library's heap returned to the system (glibc; elsewhere nothing)."""
    trim = _trim()
    if trim is not None:
        trim(0)
