"""The "Parameter state" section of the HTML report: one table per drive (analysis.param_state), with the
intended set's value and result per element when `report --expect SET.csv` gives one (analysis.intended).

The tables use the page's table data format (html_report._table): the page's script sorts and filters them.
Intended elements the capture never shows get a row of their own (result `expect_missing`).
"""

from __future__ import annotations

import html
from collections import Counter
from typing import TYPE_CHECKING, Any, NamedTuple

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

# (state column, label, kind as html_tables.Col), what a reader checks first leading: the element, its values,
# whether they agree and the error in words; with an intended set its result and intended value come second
STATE_COLS = (("param", "parameter", "str"), ("do", "DO", "num"), ("written", "written", "str"),
              ("read", "read back", "str"), ("agrees", "agrees", "str"), ("last_error", "last error", "str"),
              ("last_error_text", "its meaning", "str"), ("name", "name", "str"), ("refused", "refused", "num"),
              ("writes", "writes", "num"), ("unconfirmed", "unconfirmed", "num"), ("format", "format", "str"),
              ("written_frame", "written in frame", "num"), ("read_frame", "read in frame", "num"))
EXPECT_COLS = (("result", "result", "str"), ("intended", "intended", "str"), ("why", "why", "str"))
_EXPECT_AT = 2  # the intended set's columns follow the parameter and DO
_INDEX = {c.name: i for i, c in enumerate(STATE_COLUMNS)}


def _cell(value: object) -> object:
    if value is None:
        return None
    if value is True or value is False:
        return "yes" if value else "no"
    return value


class Audit(NamedTuple):
    """The intended set's outcome: how many elements it lists and how many ended with each result."""

    elements: int
    results: Counter[str]

    def as_intended(self) -> int:
        return self.results.get(AS_INTENDED, 0)

    def text(self) -> str:
        """'8 intended elements: 8 as intended' (as intended first, then the findings by name)."""
        done = ", ".join(f"{n} {r}" for r, n in sorted(self.results.items(),
                                                       key=lambda x: (x[0] != AS_INTENDED, x[0])))
        return f"{self.elements} intended element{'s' if self.elements != 1 else ''}" + (f": {done}" if done else "")


def section(analysis: Analysis, expected: ExpectedSet | None = None
            ) -> tuple[dict[str, dict[str, Any]], str, Audit | None]:
    """The tables to embed (by data-table key), the section's HTML and the intended set's outcome (None
    without one)."""
    return render_state(state_of(analysis.rows, merged(analysis.captures)), expected)


def render_state(state: StateTable, expected: ExpectedSet | None
                 ) -> tuple[dict[str, dict[str, Any]], str, Audit | None]:
    checked = {o.key: o for o in outcomes(expected, state)} if expected is not None else {}
    keys = sorted(set(state.elements) | set(checked), key=lambda k: (device_order(k[0]), k[1], k[2], k[3]))
    cols = STATE_COLS[:_EXPECT_AT] + (EXPECT_COLS if expected is not None else ()) + STATE_COLS[_EXPECT_AT:]
    columns = [{"name": n, "label": label, "kind": kind} for n, label, kind in cols]
    by_device: dict[str, list[list[object]]] = {}
    for key in keys:
        st = state.elements.get(key)
        if st is not None:
            row = state_row(key, st, names=state.names)
            cells = [_cell(row[_INDEX[n]]) for n, _, _ in STATE_COLS]
        else:  # intended, never seen
            seen = {"param": f"P{key[2]}[{key[3]}]", "do": key[1], "name": state.names.pnu(key[2])}
            cells = [seen.get(n) for n, _, _ in STATE_COLS]
        if expected is not None:
            o: Outcome | None = checked.get(key)
            cells[_EXPECT_AT:_EXPECT_AT] = ([o.result, o.line.value, o.message] if o is not None
                                            else ["not in the set", None, None])
        by_device.setdefault(key[0], []).append(cells)
    tables = {f"params-{i}": {"columns": columns, "rows": rows, "total": len(rows), "note": ""}
              for i, rows in enumerate(by_device.values())}
    devices = [device_label(d, state.stations) for d in by_device]
    audit = Audit(len(checked), Counter(o.result for o in checked.values())) if expected is not None else None
    return tables, _html(devices, tables, audit), audit


def _html(devices: list[str], tables: dict[str, dict[str, Any]], audit: Audit | None) -> str:
    head = "<section id=\"params\"><h2>Parameter state</h2>\n"
    intro = ("<p class=\"intro\">Per drive, DO, parameter and array element: the last value confirmed written "
             "(positive change response, or no error inside a 0x82), the last value read back, whether they "
             "agree, and how many writes were refused. "
             "<code>pd-analyze params</code> writes the same table as CSV, JSON or Parquet.")
    intro += "</p>\n"
    if audit is not None:
        ok = "ok" if audit.as_intended() == audit.elements else "bad"
        intro += (f"<p class=\"audit audit-{ok}\">Checked against the intended set (<code>--expect</code>): "
                  f"{html.escape(audit.text())}.</p>\n")
    if not devices:
        return head + intro + "<p class=\"intro\">No parameter value was written or read.</p></section>\n"
    parts = [f"<h3>{html.escape(device)} <small>({tables[key]['total']:,})</small></h3>\n"
             f"<div class=\"pdtable\" data-table=\"{key}\"></div>\n"
             for device, key in zip(devices, tables, strict=True)]
    return head + intro + "".join(parts) + "</section>\n"
