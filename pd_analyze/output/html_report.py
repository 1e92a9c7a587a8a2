"""`pd-analyze report --format html`: the analysis as one self-contained HTML file.

The page holds the summary (cards, the capture table, the text of `pd-analyze report` with every transaction
it names linked), the plots (output.html_plots: SVG images, the timeline's failures linked), sortable and
filterable tables of transactions, findings and changes (output.html_tables), the parameter state per drive
(output.html_params, with the intended set's outcome under `--expect`), and the frames and fields of the
failed transactions and of those the summary names (output.html_drill). Every txn number on the page opens
its transaction's drill-down.
Nothing is fetched: CSS and the script are inline, a Content-Security-Policy forbids every network request
and lets only this module's own script run (by hash).

Big captures: each table embeds at most `max_rows` rows (transactions: every failed one first, then ok
ones in txn order; findings: errors first), the page says how many it left out, and the full tables are in
the CSV files written beside it. The drill-down embeds the frames of the first `max_drilldown` failed
transactions and a bounded number of others, from one annotated pass per capture that stops after the last
frame needed.

Every string that comes from a capture reaches the page either through html.escape or as JSON data inside
`<script type="application/json">` (with <, > and & written as \\u escapes), and the script puts it into the
page with textContent only.
"""

from __future__ import annotations

import base64
import hashlib
import html
import json
import os
from functools import cache
from importlib import resources
from typing import Any

import pandas as pd

from pd_analyze import __version__
from pd_analyze.analysis.api import Analysis
from pd_analyze.analysis.intended import ExpectedSet
from pd_analyze.analysis.schema import capture_text
from pd_analyze.model.verdicts import VERDICTS
from pd_analyze.output import html_drill, html_params, html_plots
from pd_analyze.output.html_params import Audit
from pd_analyze.output.html_tables import (
    CHANGE_COLS,
    FINDING_COLS,
    TRANSACTION_COLS,
    cap_findings,
    cap_transactions,
    cols,
    table,
)

MAX_ROWS = 5_000
MAX_DRILLDOWN = html_drill.MAX_FAILED
MAX_CAPTURE_ROWS = 500
PAGE_SIZE = 50
_SCRIPTS = ("tables.js", "drill.js")  # one inline script, in this order


def write(analysis: Analysis, path: str, *, max_rows: int = MAX_ROWS, max_drilldown: int = MAX_DRILLDOWN,
          tables_dir_note: str = "", expected: ExpectedSet | None = None) -> str:
    """Write the report to `path` (UTF-8) and return the path."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    text = render(analysis, max_rows=max_rows, max_drilldown=max_drilldown, tables_dir_note=tables_dir_note,
                  expected=expected)
    with open(path, "w", encoding="utf-8") as out:
        out.write(text)
    return path


def render(analysis: Analysis, *, max_rows: int = MAX_ROWS, max_drilldown: int = MAX_DRILLDOWN,
           tables_dir_note: str = "", expected: ExpectedSet | None = None) -> str:
    """The whole page as one string; `expected`: the intended set the parameter state is checked against."""
    from pd_analyze.output import report

    t, f, c = analysis.transactions, analysis.findings, analysis.changes
    several = len(analysis.captures) > 1
    where = tables_dir_note or "the tables that pd-analyze report writes (CSV, Parquet, JSON)"
    names, digits = analysis.rows.names, analysis.rows.digits
    tables = {
        "transactions": table(*cap_transactions(t, max_rows), cols(TRANSACTION_COLS, several), where,
                              "transactions", names, digits),
        "findings": table(*cap_findings(f, max_rows), cols(FINDING_COLS, several), where, "findings"),
        "changes": table(c.head(max_rows), len(c), "in txn order", cols(CHANGE_COLS, several), where, "changes",
                         digits=digits),
    }
    summary_text = report.summary(analysis)
    failed, others = html_drill.choose(t, f, c, html_drill.named_in(summary_text), max_drilldown)
    drill = html_drill.drilldown(analysis, pd.concat([failed, others]))
    param_tables, param_section, audit = html_params.section(analysis, expected)
    tables |= param_tables
    single = capture_text(analysis.captures[0].path) if len(analysis.captures) == 1 else ""
    data = {"tables": tables, "drill": {str(k): v for k, v in drill.items()}, "page": PAGE_SIZE,
            "capture": single, "cut": html_drill.SHOW_CHARS}
    script = "\n".join(_asset(name) for name in _SCRIPTS)
    digest = base64.b64encode(hashlib.sha256(script.encode("utf-8")).digest()).decode("ascii")
    files = [os.path.basename(capture_text(cap.path)) for cap in analysis.captures]
    title = "pd-analyze report: " + (files[0] if files else "no capture") + (
        f" and {len(files) - 1} more" if len(files) > 1 else "")
    failed_all = int((t.verdict != "ok").sum()) if not t.empty else 0
    parts = [
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n",
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n",
        f"<meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; img-src data:; "
        f"style-src 'unsafe-inline'; script-src 'sha256-{digest}'\">\n",
        f"<title>{_e(title)}</title>\n<style>{_asset('report.css')}</style>\n</head>\n<body>\n",
        _header(analysis, title, audit),
        _summary(analysis, audit),
        html_plots.section(analysis),
        _summary_text(summary_text),
        _table_section("transactions", "Transactions", tables["transactions"],
                       "One row per parameter access (write request, B5 answers, final read). Click a "
                       "header to sort, type in the boxes under it to filter: text, <code>=exact</code>, "
                       "<code>!not</code>; <code>&gt;</code> <code>&lt;</code> <code>=</code> on numbers and on "
                       "times (<code>&gt;2026-01-01 00:00:05</code>, or a time of day <code>&lt;00:00:05.5</code>); "
                       "a number in <i>frames</i> matches that frame exactly. A txn number opens its frames."),
        _table_section("findings", "Findings", tables["findings"],
                       "Every check that fired, with the field, the observed and expected value and the "
                       "document the limit comes from."),
        _table_section("changes", "Changes", tables["changes"],
                       "The change trail: every change request, with the value read before it (when the "
                       "capture holds such a read) and its result."),
        param_section,
        html_drill.section(analysis, failed_all, failed, others, drill, max_drilldown),
        f"<script type=\"application/json\" id=\"pd-data\">{_json(data)}</script>\n",
        f"<script>{script}</script>\n</body>\n</html>\n",
    ]
    return "".join(parts)


# --- page parts -----------------------------------------------------------------------------------------------

def _e(text: object) -> str:
    return html.escape(str(text), quote=True)


def _json(data: object) -> str:
    """JSON that cannot end its <script> element or open a comment: <, > and & as \\u escapes."""
    text = json.dumps(data, ensure_ascii=True, separators=(",", ":"), allow_nan=False)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def _header(analysis: Analysis, title: str, audit: Audit | None) -> str:
    caps = ", ".join(_e(capture_text(c.path)) for c in analysis.captures[:5])
    if len(analysis.captures) > 5:
        caps += f" and {len(analysis.captures) - 5:,} more"
    state = "Parameter state"
    if audit is not None:  # the intended set's outcome is stated in the section: say it here too
        state += f" ({audit.as_intended():,} of {audit.elements:,} as intended)"
    return (f"<header><h1>{_e(title)}</h1>\n<p class=\"meta\">Captures: {caps or 'none'}<br>"
            f"Profile <b>{_e(analysis.profile)}</b>, transaction timeout {analysis.txn_timeout:g} s, RPC timeout "
            f"{analysis.rpc_timeout:g} s. Written by pd-analyze {_e(__version__)}; this file needs no network.</p>\n"
            "<nav><a href=\"#summary\">Summary</a> <a href=\"#plots\">Plots</a> "
            "<a href=\"#transactions\">Transactions</a> <a href=\"#findings\">Findings</a> "
            f"<a href=\"#changes\">Changes</a> <a href=\"#params\">{_e(state)}</a> "
            "<a href=\"#frames\">Frames and fields</a></nav>\n"
            "<noscript><p class=\"warn\">The tables and the drill-down need JavaScript; the summary and the plots "
            "do not.</p></noscript></header>\n")


def _summary(analysis: Analysis, audit: Audit | None) -> str:
    t, f = analysis.transactions, analysis.findings
    counts = t.verdict.astype(str).value_counts() if not t.empty else pd.Series(dtype="int64")
    sev = f.severity.astype(str).value_counts() if not f.empty else pd.Series(dtype="int64")
    cards = [("transactions", f"{len(t):,}", "total", "#transactions")]
    cards += [(v, f"{int(counts.get(v, 0)):,}", v, "#transactions") for v in VERDICTS]
    cards += [("B5 retries", f"{int(t.b5_retries.sum()) if not t.empty else 0:,}", "b5", "#transactions"),
              ("findings", f"{len(f):,}", "findings", "#findings"),
              ("errors / warnings", f"{int(sev.get('error', 0)):,} / {int(sev.get('warning', 0)):,}", "findings",
               "#findings")]
    if audit is not None:
        ok = audit.as_intended() == audit.elements
        cards.append(("as intended (--expect)", f"{audit.as_intended():,} / {audit.elements:,}",
                      "audit-ok" if ok else "audit-bad", "#params"))
    card_html = "".join(f"<a class=\"card c-{_e(cls)}\" href=\"{href}\"><span class=\"n\">{_e(n)}</span>"
                        f"<span class=\"l\">{_e(label)}</span></a>" for label, n, cls, href in cards)
    acc = analysis.accounting
    rows = "".join(
        f"<tr><td class=\"path\">{_e(r.capture)}</td><td class=\"r\">{r.read:,}</td><td class=\"r\">{r.decoded:,}</td>"
        f"<td class=\"r\">{r.skipped:,}</td><td class=\"r\">{r.malformed:,}</td>"
        f"<td class=\"r\">{r.transactions:,}</td><td>{_e(r.error)}</td></tr>"
        for r in acc.head(MAX_CAPTURE_ROWS).itertuples())
    more = (f"<p class=\"note\">{MAX_CAPTURE_ROWS:,} of {len(acc):,} captures listed.</p>"
            if len(acc) > MAX_CAPTURE_ROWS else "")
    audit_line = ""
    if audit is not None:
        ok = "ok" if audit.as_intended() == audit.elements else "bad"
        audit_line = (f"<p class=\"audit audit-{ok}\">Intended set (<code>--expect</code>): {_e(audit.text())} "
                      "(<a href=\"#params\">parameter state</a>).</p>\n")
    return ("<section id=\"summary\"><h2>Summary</h2>\n"
            f"<div class=\"cards\">{card_html}</div>\n{audit_line}"
            "<table class=\"static\"><thead><tr><th>capture</th><th>frames read</th><th>decoded</th><th>skipped</th>"
            f"<th>malformed</th><th>transactions</th><th>error</th></tr></thead><tbody>{rows}</tbody></table>{more}\n"
            "</section>\n")


def _summary_text(text: str) -> str:
    return ("<section id=\"summary-text\"><details open><summary>The summary of <code>pd-analyze report</code>, "
            f"worst offenders first</summary><pre>{html_drill.linked(text)}</pre></details></section>\n")


def _table_section(key: str, title: str, spec: dict[str, Any], intro: str) -> str:
    note = f"<p class=\"note cap\">{_e(spec['note'])}</p>" if spec["note"] else ""
    return (f"<section id=\"{key}\"><h2>{_e(title)} <small>({spec['total']:,})</small></h2>\n"
            f"<p class=\"intro\">{intro}</p>{note}\n"
            f"<div class=\"pdtable\" data-table=\"{key}\"></div></section>\n")


@cache
def _asset(name: str) -> str:
    """The page's stylesheet or script, package data files beside this module (html_assets/)."""
    return resources.files("pd_analyze.output").joinpath("html_assets", name).read_text(encoding="utf-8")
