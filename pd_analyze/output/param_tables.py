"""The parameter state (`pd-analyze params`) and other small tables declared as schema.Column tuples, as an
aligned text table, CSV, JSON Lines or Parquet.

Cells are written as the report's files write them (output.writers): times at their capture's resolution
(the capture column before a time names it: written_capture for written_t) as
`2026-01-01 00:00:00.000000+00:00` (CSV) or `...Z` (JSON), missing cells empty (CSV) or null (JSON), text a
spreadsheet would run as a formula with a leading `'` in CSV. These tables hold one row per parameter
element, not per frame: they are built whole.
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Callable, Iterable, Mapping, Sequence

from pd_analyze.analysis.param_state import STATE_COLUMNS, StateTable
from pd_analyze.analysis.schema import TIME, Column
from pd_analyze.analysis.stations import device_label
from pd_analyze.model.times import DEFAULT_DIGITS
from pd_analyze.output.writers import csv_time, json_time, neutralise

STATE_TABLE = "parameter_state"
# The text table of `params`: (heading, column, width limit)
TEXT_COLUMNS = (("device", "device"), ("DO", "do"), ("parameter", "param"), ("format", "format"),
                ("written", "written"), ("frame", "written_frame"), ("read", "read"), ("frame", "read_frame"),
                ("agrees", "agrees"), ("writes", "writes"), ("refused", "refused"), ("last error", "last_error"),
                ("name", "name"))
_MAX_CELL = 40  # characters of a value shown in the text table (the CSV holds it whole)


def _cells(columns: Sequence[Column], digits: Mapping[str, int] | None,
           time_text: Callable[[int, int], str]) -> Callable[[tuple], list[object]]:
    """A row's cells as written: a time at the resolution of the capture named by the nearest capture column
    before it (DEFAULT_DIGITS without one, or for a capture not known)."""
    digits = digits or {}
    pairs = [(i, max((j for j in range(i) if columns[j].name.endswith("capture")), default=None))
             for i, c in enumerate(columns) if c.dtype == TIME]

    def cells(row: tuple) -> list[object]:
        out = list(row)
        for i, j in pairs:
            if out[i] is not None:
                out[i] = time_text(int(out[i]), digits.get(row[j], DEFAULT_DIGITS) if j is not None  # type: ignore[call-overload]
                                   else DEFAULT_DIGITS)
        return out
    return cells


def csv_text(columns: Sequence[Column], rows: Iterable[tuple], digits: Mapping[str, int] | None = None) -> str:
    """The rows as CSV; `digits`: each capture's resolution (Rows.digits)."""
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow([c.name for c in columns])
    cells = _cells(columns, digits, csv_time)
    for row in rows:
        w.writerow([neutralise(v) for v in cells(row)])
    return out.getvalue()


def json_text(columns: Sequence[Column], rows: Iterable[tuple], digits: Mapping[str, int] | None = None) -> str:
    """The rows as JSON Lines; `digits`: each capture's resolution (Rows.digits)."""
    names = [c.name for c in columns]
    encode = json.JSONEncoder(ensure_ascii=True, separators=(",", ":")).encode
    cells = _cells(columns, digits, json_time)
    return "".join(encode(dict(zip(names, cells(row), strict=True))) + "\n" for row in rows)


def aligned(headings: Sequence[str], rows: Iterable[Sequence[object]]) -> list[str]:
    """Columns padded to their widest cell; missing cells blank."""
    cells = [[_short(v) for v in row] for row in rows]
    widths = [max([len(h)] + [len(r[i]) for r in cells]) for i, h in enumerate(headings)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(headings, widths, strict=True)).rstrip()]
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in cells]
    return lines


def _short(value: object) -> str:
    if value is None:
        return ""
    if value is True or value is False:
        return "yes" if value else "no"
    text = str(value)
    return text if len(text) <= _MAX_CELL else text[:_MAX_CELL - 3] + "..."


def state_text(state: StateTable) -> list[str]:
    """`params`' table on a terminal: one line per element."""
    index = [c.name for c in STATE_COLUMNS]
    picks = [index.index(col) for _, col in TEXT_COLUMNS]
    rows = list(state.rows())
    if not rows:
        return ["no PROFIdrive parameter value written or read in the capture"]
    return aligned([h for h, _ in TEXT_COLUMNS], ([device_label(row[0], state.stations), *[row[i] for i in picks[1:]]]
                                                  for row in rows))


def state_formatted(state: StateTable, fmt: str) -> str:
    """The state as CSV or JSON Lines text."""
    rows = list(state.rows())
    return (csv_text(STATE_COLUMNS, rows, state.digits) if fmt == "csv"
            else json_text(STATE_COLUMNS, rows, state.digits))


def write_state(state: StateTable, out_dir: str, fmt: str) -> str:
    """DIR/parameter_state.csv, .json (JSON Lines) or .parquet; the path written."""
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, f"{STATE_TABLE}.{fmt}")
    if fmt == "parquet":
        state.frame().to_parquet(path, index=False)
        return path
    with open(path, "w", encoding="utf-8", newline="") as f:
        f.write(state_formatted(state, fmt))
    return path
