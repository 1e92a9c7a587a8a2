"""Helpers shared by the test modules: what a test needs from the machine (tshark, Chromium) and from
beside the repository (the real public captures of ../shared/captures), and an analysis's tables as the
row tuples the row path made."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

import pytest

if TYPE_CHECKING:
    from pd_analyze.analysis.rows import Rows


def in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


def unavailable(message: str) -> NoReturn:
    """A test's tool is missing: skipped on a developer's machine, a failure in CI (nothing is skipped there)."""
    if in_ci():
        pytest.fail(f"{message} -- CI is set, and this test must not be skipped in CI", pytrace=False)
    pytest.skip(message)


# The real public captures sit beside the repository in CI (../shared/captures) and are absent from a clone of
# the project alone. Only this module names that directory (tests/test_architecture.py holds every other test
# module to it): a test that globs it gets nothing when it is absent, a test that needs one of its files skips
# with the reason. What the project promises is also tested on a capture of sample_pcaps/.
SHARED_CAPTURES = Path(__file__).resolve().parents[2] / "shared" / "captures"


def shared_captures(patterns: tuple[str, ...] = ("*.pcap", "*.pcapng", "*.gz")) -> list[Path]:
    """The shared captures matching `patterns`, sorted; none when the directory is absent."""
    if not SHARED_CAPTURES.is_dir():
        return []
    return sorted({p for pattern in patterns for p in SHARED_CAPTURES.glob(pattern) if p.is_file()})


def every_shared_capture() -> list[Path]:
    """Every shared capture, for a test that runs on all of them: skipped with the reason on a plain clone (no
    ../shared, CI or not, as shared_capture does); a directory that holds none is a failure in CI (unavailable)."""
    if not SHARED_CAPTURES.is_dir():
        pytest.skip(f"{SHARED_CAPTURES} absent: the shared real-world captures are beside the repository in CI, not "
                    "in a clone of the project alone")
    real = shared_captures()
    if not real:
        unavailable(f"no captures in {SHARED_CAPTURES}")
    return real


def shared_capture(name: str) -> Path:
    """One shared capture; the test is skipped, with the reason, when it is absent (a plain clone)."""
    path = SHARED_CAPTURES / name
    if not path.is_file():
        pytest.skip(f"{path} absent: the shared real-world captures are beside the repository in CI, not in a "
                    "clone of the project alone")
    return path


def table_rows(rows: Rows, name: str) -> list[tuple]:
    """One table's rows as the row path made them (schema.ROW_TYPES, times as integer nanoseconds, None missing),
    in the order `Analysis` reads them: the rows made one by one (`Rows.add`), then the rows of the
    engine's pyarrow tables (`Rows.tables`) in the order they were added. The tests of the row-to-batch
    machinery (writers, sink, summary) feed these to today's row code and to the batch code alike."""
    from pd_analyze.analysis.schema import COLUMNS, ROW_TYPES, TIME

    row_type = ROW_TYPES[name]
    out = list(getattr(rows, name))
    for table in rows.tables.get(name, ()):
        cells = []
        for c in COLUMNS[name]:
            column = table.column(c.name)  # type: ignore[attr-defined]
            if c.dtype == TIME:  # timestamp[ns] as the nanoseconds the rows hold
                cells.append(column.cast("int64").to_pylist())
            else:
                cells.append(column.to_pylist())
        out += [row_type._make(r) for r in zip(*cells, strict=True)]
    return out
