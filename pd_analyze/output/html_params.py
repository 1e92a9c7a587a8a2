"""The "Parameter state" section of the HTML report: one table per drive (analysis.param_state), with the
intended set's value and result per element when `report --expect SET.csv` gives one (analysis.intended).

The tables use the page's table data format (html_report._table): the page's script sorts and filters them.
Intended elements the capture never shows get a row of their own (result `expect_missing`).
"""

from __future__ import annotations

import html
from collections import Counter
from typing import TYPE_CHECKING, Any

from pd_analyze.analysis.intended import AS_INTENDED, ExpectedSet, Outcome, outcomes
from pd_analyze.analysis.param_state import (
    STATE_COLUMNS,
    StateTable,
    device_order,
    state_of,
    state_row,
)
from pd_analyze.analysis.stations import device_label, merged

if TYPE_CHECKING:
    from pd_analyze.analysis.api import Analysis

# (state column, label, kind as html_report.Col)
STATE_COLS = (("do", "DO", "num"), ("param", "parameter", "str"), ("name", "name", "str"), ("format", "format", "str"),
              ("written", "written", "str"), ("written_frame", "frame", "num"), ("read", "read back", "str"),
              ("read_frame", "frame", "num"), ("agrees", "agrees", "str"), ("writes", "writes", "num"),
              ("refused", "refused", "num"), ("unconfirmed", "unconfirmed", "num"), ("last_error", "last error", "str"),
              ("last_error_text", "its meaning", "str"))
EXPECT_COLS = (("intended", "intended", "str"), ("result", "result", "str"), ("why", "why", "str"))
_INDEX = {c.name: i for i, c in enumerate(STATE_COLUMNS)}


def _cell(value: object) -> object:
    if value is None:
        return None
    if value is True or value is False:
        return "yes" if value else "no"
    return value


def section(analysis: Analysis, expected: ExpectedSet | None = None) -> tuple[dict[str, dict[str, Any]], str]:
    """The tables to embed (by data-table key) and the section's HTML."""
    return render_state(state_of(analysis.rows, merged(analysis.captures)), expected)


def render_state(state: StateTable, expected: ExpectedSet | None) -> tuple[dict[str, dict[str, Any]], str]:
    checked = {o.key: o for o in outcomes(expected, state)} if expected is not None else {}
    keys = sorted(set(state.elements) | set(checked), key=lambda k: (device_order(k[0]), k[1], k[2], k[3]))
    cols = STATE_COLS + (EXPECT_COLS if expected is not None else ())
    columns = [{"name": n, "label": label, "kind": kind} for n, label, kind in cols]
    by_device: dict[str, list[list[object]]] = {}
    for key in keys:
        st = state.elements.get(key)
        if st is not None:
            row = state_row(key, st, names=state.names)
            cells = [_cell(row[_INDEX[n]]) for n, _, _ in STATE_COLS]
        else:  # intended, never seen
            cells = [key[1], f"P{key[2]}[{key[3]}]", state.names.pnu(key[2])] + [None] * (len(STATE_COLS) - 3)
        if expected is not None:
            o: Outcome | None = checked.get(key)
            cells += [o.line.value, o.result, o.message] if o is not None else [None, "not in the set", None]
        by_device.setdefault(key[0], []).append(cells)
    tables = {f"params-{i}": {"columns": columns, "rows": rows, "total": len(rows), "note": "", "links": []}
              for i, rows in enumerate(by_device.values())}
    devices = [device_label(d, state.stations) for d in by_device]
    return tables, _html(devices, tables, checked if expected is not None else None)


def _html(devices: list[str], tables: dict[str, dict[str, Any]], checked: dict | None) -> str:
    head = "<section id=\"params\"><h2>Parameter state</h2>\n"
    intro = ("<p class=\"intro\">Per drive, DO, parameter and array element: the last value confirmed written "
             "(positive change response, or no error inside a 0x82), the last value read back, whether they "
             "agree, and how many writes were refused. "
             "<code>pd-analyze params</code> writes the same table as CSV, JSON or Parquet.")
    if checked is not None:
        counts = Counter(o.result for o in checked.values())
        done = ", ".join(f"{n} {r}" for r, n in sorted(counts.items(), key=lambda x: (x[0] != AS_INTENDED, x[0])))
        intro += (f" Checked against the intended set: {len(checked)} intended element"
                  f"{'s' if len(checked) != 1 else ''}: {html.escape(done)}.")
    intro += "</p>\n"
    if not devices:
        return head + intro + "<p class=\"intro\">No parameter value was written or read.</p></section>\n"
    parts = [f"<h3>{html.escape(device)} <small>({tables[key]['total']:,})</small></h3>\n"
             f"<div class=\"pdtable\" data-table=\"{key}\"></div>\n"
             for device, key in zip(devices, tables, strict=True)]
    return head + intro + "".join(parts) + "</section>\n"
