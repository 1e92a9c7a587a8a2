"""`pd-analyze report --format html`: the analysis as one self-contained HTML file.

The page holds the summary, the plots of `pd_analyze.output.plots` (SVG, embedded as data: images), sortable and
filterable tables of transactions, findings and changes, the parameter state per drive (output.html_params, with
the intended set's results under `--expect`), and the frames and fields of failed transactions.
Nothing is fetched: CSS and the script are inline, a Content-Security-Policy forbids every network request
and lets only this module's own script run (by hash).

Big captures: each table embeds at most `max_rows` rows (transactions: every failed one first, then ok
ones in txn order; findings: errors first), the page says how many it left out, and the full tables are in
the CSV files written beside it. The drill-down covers the first `max_drilldown` failed transactions, at most
MAX_FRAMES_PER_TXN frames each, from one annotated pass per capture that stops after the last frame needed.

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
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import cache
from importlib import resources
from typing import Any

import pandas as pd

from pd_analyze import __version__
from pd_analyze.analysis.api import Analysis
from pd_analyze.analysis.intended import ExpectedSet
from pd_analyze.model import pd_values as pt
from pd_analyze.model.verdicts import VERDICTS
from pd_analyze.output import plots
from pd_analyze.protocol.frames import FrameResult

MAX_ROWS = 5_000
MAX_DRILLDOWN = 50
MAX_FRAMES_PER_TXN = 30  # the first 20 and the last 10 frames of a transaction with more
MAX_CAPTURE_ROWS = 500
PAGE_SIZE = 50
_RAW_BYTES = 16  # bytes of a field shown in the drill-down
_SHOW_CHARS = 300


@dataclass(frozen=True, slots=True)
class Col:
    name: str  # column of the DataFrame
    label: str
    kind: str  # num, str, time (UTC datetime), ms (seconds shown as milliseconds), verdict, severity


TRANSACTION_COLS = (
    Col("txn", "txn", "num"), Col("t_start", "time (UTC)", "time"), Col("capture", "capture", "str"),
    Col("device", "device", "str"), Col("controller", "controller", "str"), Col("index", "index", "str"),
    Col("do", "DO", "num"), Col("ref", "ref", "num"), Col("req_id", "request", "req_id"),
    Col("params", "parameters", "str"), Col("resp_id", "response", "resp_id"),
    Col("verdict", "verdict", "verdict"), Col("errors", "errors", "str"), Col("pnio_error_text", "PNIOStatus", "str"),
    Col("b5_retries", "B5", "num"), Col("reads", "reads", "num"), Col("t_write_rtt", "write rtt ms", "ms"),
    Col("t_total", "total ms", "ms"), Col("closed_by", "closed by", "str"), Col("frames", "frames", "str"),
)
FINDING_COLS = (
    Col("capture", "capture", "str"), Col("frame", "frame", "num"), Col("txn", "txn", "num"),
    Col("severity", "severity", "severity"), Col("rule", "rule", "str"), Col("name", "name", "str"),
    Col("field", "field", "str"), Col("value", "value", "str"), Col("expected", "expected", "str"),
    Col("message", "message", "str"), Col("source", "source", "str"),
)
CHANGE_COLS = (
    Col("t", "time (UTC)", "time"), Col("capture", "capture", "str"), Col("device", "device", "str"),
    Col("do", "DO", "num"), Col("txn", "txn", "num"), Col("frame", "frame", "num"), Col("param", "parameter", "str"),
    Col("pnu_name", "name", "str"), Col("value_before", "value before", "str"),
    Col("value_written", "value written", "str"), Col("result", "result", "str"),
)


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
    from pd_analyze.output import html_params, report

    t, f, c = analysis.transactions, analysis.findings, analysis.changes
    several = len(analysis.captures) > 1
    where = tables_dir_note or "the tables that pd-analyze report writes (CSV, Parquet, JSON)"
    tables = {
        "transactions": _table(*_cap_transactions(t, max_rows), _cols(TRANSACTION_COLS, several), where,
                               "transactions"),
        "findings": _table(*_cap_findings(f, max_rows), _cols(FINDING_COLS, several), where, "findings"),
        "changes": _table(c.head(max_rows), len(c), "in txn order", _cols(CHANGE_COLS, several), where, "changes"),
    }
    failed = t[t.verdict != "ok"]
    drill_rows = failed.head(max_drilldown)
    drill = drilldown(analysis, drill_rows)
    tables["transactions"]["links"] = sorted(drill)
    param_tables, param_section = html_params.section(analysis, expected)
    tables |= param_tables
    data = {"tables": tables, "drill": {str(k): v for k, v in drill.items()}, "page": PAGE_SIZE}
    script = _asset("report.js")
    digest = base64.b64encode(hashlib.sha256(script.encode("utf-8")).digest()).decode("ascii")
    names = [os.path.basename(cap.path) for cap in analysis.captures]
    title = "pd-analyze report: " + (names[0] if names else "no capture") + (
        f" and {len(names) - 1} more" if len(names) > 1 else "")
    parts = [
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n",
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n",
        f"<meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; img-src data:; "
        f"style-src 'unsafe-inline'; script-src 'sha256-{digest}'\">\n",
        f"<title>{_e(title)}</title>\n<style>{_asset('report.css')}</style>\n</head>\n<body>\n",
        _header(analysis, title),
        _summary(analysis),
        _plots(analysis),
        _summary_text(report.summary(analysis)),
        _table_section("transactions", "Transactions", tables["transactions"],
                       "One row per parameter access (write request, B5 answers, final read). Click a "
                       "header to sort, type in the boxes under it to filter (text, <code>=exact</code>, "
                       "<code>!not</code>, or <code>&gt;</code> <code>&lt;</code> <code>=</code> for numbers). "
                       "A linked txn number jumps to its frames."),
        _table_section("findings", "Findings", tables["findings"],
                       "Every check that fired, with the field, the observed and expected value and the "
                       "document the limit comes from."),
        _table_section("changes", "Changes", tables["changes"],
                       "The change trail: every change request, with the value read before it (when the "
                       "capture holds such a read) and its result."),
        param_section,
        _drill_section(failed, drill_rows, drill, max_drilldown),
        f"<script type=\"application/json\" id=\"pd-data\">{_json(data)}</script>\n",
        f"<script>{script}</script>\n</body>\n</html>\n",
    ]
    return "".join(parts)


# --- tables ---------------------------------------------------------------------------------------------------

def _cols(cols: tuple[Col, ...], several_captures: bool) -> tuple[Col, ...]:
    return cols if several_captures else tuple(c for c in cols if c.name != "capture")


def _cap_transactions(t: pd.DataFrame, limit: int) -> tuple[pd.DataFrame, int, str]:
    if len(t) <= limit:
        return t, len(t), "in txn order"
    failed = t[t.verdict != "ok"].head(limit)
    ok = t[t.verdict == "ok"].head(limit - len(failed))
    shown = pd.concat([failed, ok]).sort_values("txn", kind="stable")
    if ok.empty:
        return shown, len(t), f"the first {len(failed):,} failed ones"
    return shown, len(t), f"every failed transaction ({len(failed):,}), then the first {len(ok):,} ok ones"


def _cap_findings(f: pd.DataFrame, limit: int) -> tuple[pd.DataFrame, int, str]:
    if len(f) <= limit:
        return f, len(f), "in frame order"
    order = f.assign(_rank=f.severity.cat.codes).sort_values(["_rank", "frame"], ascending=[False, True],
                                                              kind="stable")
    return order.head(limit).drop(columns="_rank").sort_values("frame", kind="stable"), len(f), "errors first"


def _table(df: pd.DataFrame, total: int, chosen: str, cols: tuple[Col, ...], where: str,
           name: str) -> dict[str, Any]:
    columns = [{"name": c.name, "label": c.label, "kind": "str" if c.kind in ("req_id", "resp_id") else c.kind}
               for c in cols]
    values = [_column(df[c.name], c.kind) for c in cols]
    rows = [list(r) for r in zip(*values, strict=True)] if values and len(df) else []
    note = ""
    if len(df) < total:
        note = (f"{len(df):,} of {total:,} {name} embedded ({chosen}); the other {total - len(df):,} are in "
                f"{where}.")
    return {"columns": columns, "rows": rows, "total": total, "note": note, "links": []}


def _column(s: pd.Series, kind: str) -> list[object]:
    if kind == "time":
        text = s.dt.strftime("%Y-%m-%d %H:%M:%S.%f")
        return [None if pd.isna(v) else v for v in text.astype("object")]
    if kind == "ms":
        ms = (s.astype("Float64") * 1000).round(3)
        return [None if pd.isna(v) else float(v) for v in ms.astype("object")]
    if kind == "num":
        return [None if pd.isna(v) else (int(v) if float(v).is_integer() else float(v)) for v in s.astype("object")]
    if kind in ("req_id", "resp_id"):  # the ID with its name: "0x81 request parameter, negative"
        names = pt.REQUEST_ID if kind == "req_id" else pt.RESPONSE_ID
        return [None if pd.isna(v) else _named_id(str(v), names) for v in s.astype("object")]
    return [None if pd.isna(v) else str(v) for v in s.astype("object")]


def _named_id(text: str, names: Mapping[int, str]) -> str:
    try:
        name = names.get(int(text, 16), "") if text else ""
    except ValueError:
        return text
    return f"{text} {name}" if name else text


# --- drill-down -----------------------------------------------------------------------------------------------

def drilldown(analysis: Analysis, txns: pd.DataFrame) -> dict[int, list[dict[str, object]]]:
    """Frames (with layers, fields, checks and findings) of the given transactions, as the dump shows them.

    One annotated pass per capture, stopping after the last frame any of them needs.
    """
    from pd_analyze.analysis.drilldown import annotated_frames

    out: dict[int, list[dict[str, object]]] = {}
    if txns.empty:
        return out
    # a --chain analysis numbers the frames of all its files as one capture: one pass over the chain
    groups = [("", txns)] if analysis.chain else txns.groupby("capture", observed=True, sort=False)
    for capture, group in groups:
        wanted: dict[int, list[int]] = {}
        for row in group.itertuples():
            out[int(row.txn)] = []
            for number in _frames_to_show([int(n) for n in str(row.frames).split()]):
                wanted.setdefault(number, []).append(int(row.txn))
        if not wanted:
            continue
        for res in annotated_frames(str(capture), wanted, analysis.profile, analysis.rpc_timeout, analysis.chain):
            item = _frame_item(res)
            for txn in wanted[res.frame]:
                out[txn].append(item)
    for txn, items in out.items():
        total = len(str(txns.loc[txns.txn == txn, "frames"].iloc[0]).split())
        if total > len(items) and items:
            items.insert(20 if len(items) > 20 else len(items),
                         {"gap": total - len(items)})
    return out


def _frames_to_show(frames: list[int]) -> list[int]:
    frames = sorted(frames)
    if len(frames) <= MAX_FRAMES_PER_TXN:
        return frames
    return frames[:20] + frames[-(MAX_FRAMES_PER_TXN - 20):]


def _frame_item(res: FrameResult) -> dict[str, object]:
    layers = []
    for layer in res.layers:
        fields = [[f.offset, _raw(f.raw), f.name, _short(f.show), f.check] for f in layer.fields]
        layers.append([layer.title, layer.depth, fields])
    findings = [[f.severity, f"{f.rule} {f.name} [{f.field}]: {f.message}"] for f in res.findings]
    return {"n": res.frame, "t": _utc(res.ts), "src": res.src, "dst": res.dst, "s": res.summary, "L": layers,
            "F": findings}


def _raw(raw: bytes) -> str:
    text = raw[:_RAW_BYTES].hex(" ")
    return text + (" …" if len(raw) > _RAW_BYTES else "")


def _short(text: str) -> str:
    return text if len(text) <= _SHOW_CHARS else text[:_SHOW_CHARS - 1] + "…"


def _utc(ts: float) -> str:
    return datetime.fromtimestamp(ts, UTC).strftime("%Y-%m-%d %H:%M:%S.%f")


# --- page parts -----------------------------------------------------------------------------------------------

def _e(text: object) -> str:
    return html.escape(str(text), quote=True)


def _json(data: object) -> str:
    """JSON that cannot end its <script> element or open a comment: <, > and & as \\u escapes."""
    text = json.dumps(data, ensure_ascii=True, separators=(",", ":"), allow_nan=False)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def _header(analysis: Analysis, title: str) -> str:
    caps = ", ".join(_e(c.path) for c in analysis.captures[:5])
    if len(analysis.captures) > 5:
        caps += f" and {len(analysis.captures) - 5:,} more"
    return (f"<header><h1>{_e(title)}</h1>\n<p class=\"meta\">Captures: {caps or 'none'}<br>"
            f"Profile <b>{_e(analysis.profile)}</b>, transaction timeout {analysis.txn_timeout:g} s, RPC timeout "
            f"{analysis.rpc_timeout:g} s. Written by pd-analyze {_e(__version__)}; this file needs no network.</p>\n"
            "<nav><a href=\"#summary\">Summary</a> <a href=\"#plots\">Plots</a> "
            "<a href=\"#transactions\">Transactions</a> <a href=\"#findings\">Findings</a> "
            "<a href=\"#changes\">Changes</a> <a href=\"#failed\">Failed transactions</a></nav>\n"
            "<noscript><p class=\"warn\">The tables and the drill-down need JavaScript; the summary and the plots "
            "do not.</p></noscript></header>\n")


def _summary(analysis: Analysis) -> str:
    t, f = analysis.transactions, analysis.findings
    counts = t.verdict.astype(str).value_counts() if not t.empty else pd.Series(dtype="int64")
    sev = f.severity.astype(str).value_counts() if not f.empty else pd.Series(dtype="int64")
    cards = [("transactions", f"{len(t):,}", "total")]
    cards += [(v, f"{int(counts.get(v, 0)):,}", v) for v in VERDICTS]
    cards += [("B5 retries", f"{int(t.b5_retries.sum()) if not t.empty else 0:,}", "b5"),
              ("findings", f"{len(f):,}", "findings"),
              ("errors / warnings", f"{int(sev.get('error', 0)):,} / {int(sev.get('warning', 0)):,}", "findings")]
    card_html = "".join(f"<div class=\"card c-{_e(cls)}\"><span class=\"n\">{_e(n)}</span>"
                        f"<span class=\"l\">{_e(label)}</span></div>" for label, n, cls in cards)
    acc = analysis.accounting
    rows = "".join(
        f"<tr><td>{_e(r.capture)}</td><td class=\"r\">{r.read:,}</td><td class=\"r\">{r.decoded:,}</td>"
        f"<td class=\"r\">{r.skipped:,}</td><td class=\"r\">{r.malformed:,}</td>"
        f"<td class=\"r\">{r.transactions:,}</td><td>{_e(r.error)}</td></tr>"
        for r in acc.head(MAX_CAPTURE_ROWS).itertuples())
    more = (f"<p class=\"note\">{MAX_CAPTURE_ROWS:,} of {len(acc):,} captures listed.</p>"
            if len(acc) > MAX_CAPTURE_ROWS else "")
    return ("<section id=\"summary\"><h2>Summary</h2>\n"
            f"<div class=\"cards\">{card_html}</div>\n"
            "<table class=\"static\"><thead><tr><th>capture</th><th>frames read</th><th>decoded</th><th>skipped</th>"
            f"<th>malformed</th><th>transactions</th><th>error</th></tr></thead><tbody>{rows}</tbody></table>{more}\n"
            "</section>\n")


def _summary_text(text: str) -> str:
    return ("<section id=\"summary-text\"><details open><summary>The summary of <code>pd-analyze report</code>, "
            f"worst offenders first</summary><pre>{_e(text)}</pre></details></section>\n")


_CAPTIONS = {
    "verdicts": "How every transaction ended (protocol.md 7.4: the first matching rule wins).",
    "timeline": "Each transaction at its write request time, one lane per device; ok ones as ticks, failures as "
                "large markers labelled with their txn number and what failed (where a label has room: the title "
                "counts the failures left without one).",
    "naks": "Refused parameters (negative responses 0x81/0x82) by PNU and PROFIdrive error number.",
    "latency": "Write request to final response per device (completed transactions): box = quartiles, "
               "whiskers 1.5 IQR, dots = transactions.",
    "b5": "Reads answered B5 (state conflict: response not ready) per transaction, over time.",
}


_PLOT_WIDTH = {"timeline": plots.TIMELINE_WIDTH}  # inches; the others 7.0, two side by side


def _plots(analysis: Analysis) -> str:
    figures = []
    for name, (title, draw) in plots.CHARTS.items():
        fig = draw(analysis)
        fig.set_size_inches(_PLOT_WIDTH.get(name, 7.0), fig.get_figheight())  # shown at natural size in the grid
        svg = plots.svg(fig)
        src = "data:image/svg+xml;base64," + base64.b64encode(svg.encode("utf-8")).decode("ascii")
        caption = _CAPTIONS[name]
        failed = int((analysis.transactions.verdict != "ok").sum()) if name == "timeline" else 0
        if failed > plots.MAX_LABELS:  # the labels would overprint: say so rather than promise them
            caption = caption.replace("large markers labelled with their txn number and what failed (where a label "
                                      "has room: the title counts the failures left without one)",
                                      f"large markers ({failed:,} failures: too many to label; the Transactions "
                                      "table lists them)")
        figures.append(f"<figure id=\"plot-{name}\"><img class=\"plot\" src=\"{src}\" alt=\"{_e(title)}\">"
                       f"<figcaption>{_e(caption)}</figcaption></figure>")
    return "<section id=\"plots\"><h2>Plots</h2>\n<div class=\"plots\">" + "\n".join(figures) + "</div>\n</section>\n"


def _table_section(key: str, title: str, table: dict[str, Any], intro: str) -> str:
    note = f"<p class=\"note cap\">{_e(table['note'])}</p>" if table["note"] else ""
    return (f"<section id=\"{key}\"><h2>{_e(title)} <small>({table['total']:,})</small></h2>\n"
            f"<p class=\"intro\">{intro}</p>{note}\n"
            f"<div class=\"pdtable\" data-table=\"{key}\"></div></section>\n")


def _drill_section(failed: pd.DataFrame, shown: pd.DataFrame, drill: dict[int, list[dict[str, object]]],
                   limit: int) -> str:
    head = "<section id=\"failed\"><h2>Failed transactions: frames and fields</h2>\n"
    if failed.empty:
        return head + "<p class=\"intro\">No transaction failed.</p></section>\n"
    note = ""
    if len(failed) > len(shown):
        note = (f"<p class=\"note cap\">The first {limit:,} of {len(failed):,} failed transactions are shown; "
                "use <code>pd-analyze dump --frames</code> or <code>Analysis.fields(txn)</code> for the others.</p>")
    items = []
    for row in shown.itertuples():
        what = row.errors or row.pnio_error_text or ""
        frames = len(str(row.frames).split())
        items.append(
            f"<details id=\"txn-{int(row.txn)}\" data-txn=\"{int(row.txn)}\"><summary>"
            f"<b>txn {int(row.txn)}</b> <span class=\"badge v-{_e(row.verdict)}\">{_e(row.verdict)}</span> "
            f"{_e(row.device)} DO {_e(_na(row.do))} ref {_e(_na(row.ref))} {_e(row.params)} "
            f"<span class=\"what\">{_e(what)}</span> <span class=\"dim\">{frames} frames"
            f"{'' if drill.get(int(row.txn)) else ', not found again'}</span></summary>"
            "<div class=\"drill\"></div></details>")
    return (head + "<p class=\"intro\">Open a transaction to see each of its frames as the dump shows it: offset, "
            f"bytes, field, value and check, then the frame's findings. Frames beyond {MAX_FRAMES_PER_TXN} per "
            f"transaction are left out in the middle.</p>{note}\n" + "\n".join(items) + "\n</section>\n")


def _na(value: object) -> str:
    return "" if value is None or pd.isna(value) else str(value)


@cache
def _asset(name: str) -> str:
    """The page's stylesheet or script, package data files beside this module (html_assets/)."""
    return resources.files("pd_analyze.output").joinpath("html_assets", name).read_text(encoding="utf-8")
