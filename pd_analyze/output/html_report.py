"""`pd-analyze report --format html`: the analysis as one self-contained HTML file.

The page holds the summary, the plots of `pd_analyze.output.plots` (SVG, embedded as data: images), sortable and
filterable tables of transactions, findings and changes, and the frames and fields of failed transactions.
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
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import pandas as pd

from pd_analyze import __version__
from pd_analyze.analysis.api import Analysis
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
    Col("do", "DO", "num"), Col("ref", "ref", "num"), Col("req_id", "req", "str"), Col("params", "parameters", "str"),
    Col("verdict", "verdict", "verdict"), Col("errors", "errors", "str"), Col("pnio_status", "PNIOStatus", "str"),
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
    Col("value_before", "value before", "str"), Col("value_written", "value written", "str"),
    Col("result", "result", "str"),
)


def write(analysis: Analysis, path: str, *, max_rows: int = MAX_ROWS, max_drilldown: int = MAX_DRILLDOWN,
          tables_dir_note: str = "") -> str:
    """Write the report to `path` (UTF-8) and return the path."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    text = render(analysis, max_rows=max_rows, max_drilldown=max_drilldown, tables_dir_note=tables_dir_note)
    with open(path, "w", encoding="utf-8") as out:
        out.write(text)
    return path


def render(analysis: Analysis, *, max_rows: int = MAX_ROWS, max_drilldown: int = MAX_DRILLDOWN,
           tables_dir_note: str = "") -> str:
    """The whole page as one string."""
    from pd_analyze.output import report

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
    data = {"tables": tables, "drill": {str(k): v for k, v in drill.items()}, "page": PAGE_SIZE}
    script = _SCRIPT
    digest = base64.b64encode(hashlib.sha256(script.encode("utf-8")).digest()).decode("ascii")
    names = [os.path.basename(cap.path) for cap in analysis.captures]
    title = "pd-analyze report: " + (names[0] if names else "no capture") + (
        f" and {len(names) - 1} more" if len(names) > 1 else "")
    parts = [
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n",
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n",
        f"<meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; img-src data:; "
        f"style-src 'unsafe-inline'; script-src 'sha256-{digest}'\">\n",
        f"<title>{_e(title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n",
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
    columns = [{"name": c.name, "label": c.label, "kind": c.kind} for c in cols]
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
    return [None if pd.isna(v) else str(v) for v in s.astype("object")]


# --- drill-down -----------------------------------------------------------------------------------------------

def drilldown(analysis: Analysis, txns: pd.DataFrame) -> dict[int, list[dict[str, object]]]:
    """Frames (with layers, fields, checks and findings) of the given transactions, as the dump shows them.

    One annotated pass per capture, stopping after the last frame any of them needs.
    """
    from pd_analyze.analysis.drilldown import annotated_frames

    out: dict[int, list[dict[str, object]]] = {}
    if txns.empty:
        return out
    for capture, group in txns.groupby("capture", observed=True, sort=False):
        wanted: dict[int, list[int]] = {}
        for row in group.itertuples():
            out[int(row.txn)] = []
            for number in _frames_to_show([int(n) for n in str(row.frames).split()]):
                wanted.setdefault(number, []).append(int(row.txn))
        if not wanted:
            continue
        for res in annotated_frames(str(capture), wanted, analysis.profile, analysis.rpc_timeout):
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
                "large markers labelled with their txn number and what failed.",
    "naks": "Refused parameters (negative responses 0x81/0x82) by PNU and PROFIdrive error number.",
    "latency": "Write request to final response per device (completed transactions): box = quartiles, "
               "whiskers 1.5 IQR, dots = transactions.",
    "b5": "Reads answered B5 (state conflict: response not ready) per transaction, over time.",
}


_PLOT_WIDTH = {"timeline": 14.0}  # inches; the others 7.0, two side by side


def _plots(analysis: Analysis) -> str:
    figures = []
    for name, (title, draw) in plots.CHARTS.items():
        fig = draw(analysis)
        fig.set_size_inches(_PLOT_WIDTH.get(name, 7.0), fig.get_figheight())  # shown at natural size in the grid
        svg = plots.svg(fig)
        src = "data:image/svg+xml;base64," + base64.b64encode(svg.encode("utf-8")).decode("ascii")
        figures.append(f"<figure id=\"plot-{name}\"><img class=\"plot\" src=\"{src}\" alt=\"{_e(title)}\">"
                       f"<figcaption>{_e(_CAPTIONS[name])}</figcaption></figure>")
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
        what = row.errors or row.pnio_status or ""
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


_CSS = """
:root{--fg:#1d2329;--dim:#65707a;--line:#d9dee3;--bg:#fff;--head:#f3f5f7;--ok:#4e8f3a;--nak:#c06f00;
--timeout:#c62828;--pnio_error:#7b1fa2;--reference_mismatch:#6d4c41;--malformed:#263238}
*{box-sizing:border-box}
body{font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,"DejaVu Sans",sans-serif;color:var(--fg);
background:var(--bg);margin:0 auto;padding:0 24px 48px;max-width:1500px}
h1{font-size:22px;margin:18px 0 4px}h2{font-size:18px;margin:28px 0 8px;border-bottom:2px solid var(--line);
padding-bottom:4px}h2 small{color:var(--dim);font-weight:normal}
.meta,.intro,.note,figcaption,.dim{color:var(--dim)}.note.cap{color:#8a5a00;font-weight:600}
nav a{margin-right:14px}a{color:#1565c0}
.cards{display:flex;flex-wrap:wrap;gap:8px;margin:8px 0 14px}
.card{border:1px solid var(--line);border-radius:6px;padding:6px 12px;min-width:92px;background:var(--head)}
.card .n{display:block;font-size:20px;font-weight:700}.card .l{font-size:12px;color:var(--dim)}
.c-nak .n{color:var(--nak)}.c-timeout .n{color:var(--timeout)}.c-pnio_error .n{color:var(--pnio_error)}
.c-malformed .n{color:var(--malformed)}.c-ok .n{color:var(--ok)}
.c-reference_mismatch .n{color:var(--reference_mismatch)}
pre{background:var(--head);border:1px solid var(--line);padding:10px;overflow:auto;font-size:12px}
.plots{display:grid;grid-template-columns:repeat(auto-fit,minmax(600px,1fr));gap:4px 28px}
#plot-timeline{grid-column:1/-1}figure{margin:6px 0 14px}img.plot{max-width:100%;height:auto;display:block}
table{border-collapse:collapse;font-size:12.5px}
th,td{border-bottom:1px solid var(--line);padding:3px 7px;text-align:left;vertical-align:top}
td.r,td.num{text-align:right;font-variant-numeric:tabular-nums}
thead th{background:var(--head);position:sticky;top:0;z-index:1}
.pdtable .wrap{overflow:auto;max-height:70vh;border:1px solid var(--line)}
.pdtable th.sortable{cursor:pointer;user-select:none;white-space:nowrap}
.pdtable th.sortable:after{content:" \\2195";color:#b0b8c0}
.pdtable th[aria-sort=ascending]:after{content:" \\25B2";color:var(--fg)}
.pdtable th[aria-sort=descending]:after{content:" \\25BC";color:var(--fg)}
.pdtable tr.filters th{top:25px;padding:2px 3px}
.pdtable input{width:100%;min-width:48px;font:inherit;font-size:12px;padding:1px 3px;border:1px solid #c4ccd4;
border-radius:3px}
.pdtable tbody tr:hover{background:#f7fafc}
.pdtable td{white-space:nowrap;max-width:26em;overflow:hidden;text-overflow:ellipsis}
.pager{margin:6px 0;display:flex;gap:8px;align-items:center;flex-wrap:wrap}
.pager button{font:inherit;font-size:12px}
.badge,td.v{font-weight:600}.v-ok{color:var(--ok)}.v-nak{color:var(--nak)}.v-timeout{color:var(--timeout)}
.v-pnio_error{color:var(--pnio_error)}.v-reference_mismatch{color:var(--reference_mismatch)}
.v-malformed{color:var(--malformed)}.s-error{color:#c62828;font-weight:600}.s-warning{color:#b26a00;font-weight:600}
.s-info{color:#1565c0}
details{border:1px solid var(--line);border-radius:5px;margin:6px 0;padding:4px 10px}
details>summary{cursor:pointer}.what{font-family:ui-monospace,monospace}
.frame{margin:10px 0 14px}.fhead{font-family:ui-monospace,monospace;font-size:12px;font-weight:600;
background:var(--head);padding:3px 6px;border-left:3px solid #90a4ae}
table.fields{font-family:ui-monospace,"DejaVu Sans Mono",monospace;font-size:11.5px;margin-top:2px}
table.fields td{border:none;padding:0 8px 0 0;white-space:pre-wrap}
table.fields tr.layer td{font-weight:600;font-family:system-ui,sans-serif;padding-top:4px}
table.fields td.bad{color:#c62828}table.fields td.good{color:var(--ok)}
ul.findings{margin:4px 0;padding-left:18px;font-size:12px}.gap{color:var(--dim);font-style:italic}
.warn{color:#c62828}
"""

_SCRIPT = r"""
(function () {
  "use strict";
  var DATA = JSON.parse(document.getElementById("pd-data").textContent);
  var PAGE = DATA.page;
  var CLASS = {verdict: "v", severity: "s"};

  function el(tag, text, cls) {
    var e = document.createElement(tag);
    if (text !== undefined && text !== null) { e.textContent = String(text); }
    if (cls) { e.className = cls; }
    return e;
  }
  function isNum(kind) { return kind === "num" || kind === "ms"; }
  function shown(v) { return v === null ? "" : String(v); }

  function parseFilter(text, kind) {
    if (!text) { return null; }
    var neg = false;
    if (text.charAt(0) === "!") { neg = true; text = text.slice(1); }
    var m = /^(<=|>=|<|>|=)\s*(.*)$/.exec(text), test;
    if (m && isNum(kind) && m[2] !== "" && !isNaN(Number(m[2]))) {
      var n = Number(m[2]), op = m[1];
      test = function (v) {
        if (v === null) { return false; }
        return op === "<" ? v < n : op === ">" ? v > n : op === "<=" ? v <= n : op === ">=" ? v >= n : v === n;
      };
    } else if (m && m[1] === "=") {
      var exact = m[2].toLowerCase();
      test = function (v) { return shown(v).toLowerCase() === exact; };
    } else {
      var needle = text.toLowerCase();
      test = function (v) { return shown(v).toLowerCase().indexOf(needle) >= 0; };
    }
    return neg ? function (v) { return !test(v); } : test;
  }

  function compare(kind, dir) {
    return function (a, b) {  /* empty cells last in either direction */
      if (a === null || a === "") { return (b === null || b === "") ? 0 : 1; }
      if (b === null || b === "") { return -1; }
      if (isNum(kind)) { return dir * (a - b); }
      return dir * String(a).localeCompare(String(b), undefined, {numeric: true});
    };
  }

  function makeTable(host, spec) {
    var cols = spec.columns, rows = spec.rows;
    var links = {};
    (spec.links || []).forEach(function (t) { links[t] = true; });
    var state = {sort: -1, dir: 1, tests: cols.map(function () { return null; }), page: 0, size: PAGE};
    var table = el("table"), thead = table.createTHead();
    var hrow = thead.insertRow(), frow = thead.insertRow();
    frow.className = "filters";
    var heads = [];
    cols.forEach(function (c, i) {
      var th = el("th", c.label, "sortable");
      th.setAttribute("data-col", c.name);
      th.setAttribute("aria-sort", "none");
      th.tabIndex = 0;
      th.title = "sort by " + c.label;
      th.addEventListener("click", function () { sortBy(i); });
      th.addEventListener("keydown", function (e) { if (e.key === "Enter") { sortBy(i); } });
      hrow.appendChild(th);
      heads.push(th);
      var fth = el("th"), input = el("input");
      input.type = "search";
      input.placeholder = isNum(c.kind) ? "> < =" : "filter";
      input.setAttribute("aria-label", "filter " + c.label);
      input.setAttribute("data-col", c.name);
      input.addEventListener("input", function () {
        state.tests[i] = parseFilter(input.value.trim(), c.kind);
        state.page = 0;
        draw();
      });
      fth.appendChild(input);
      frow.appendChild(fth);
    });
    var tbody = table.createTBody();
    var wrap = el("div", null, "wrap");
    wrap.appendChild(table);
    var pager = el("div", null, "pager"), info = el("span");
    var first = el("button", "\u00ab first"), prev = el("button", "\u2039 previous");
    var next = el("button", "next \u203a"), last = el("button", "last \u00bb");
    var size = el("select");
    [25, 50, 100, 500, 5000].forEach(function (n) {
      var o = el("option", n + " rows per page");
      o.value = n;
      if (n === PAGE) { o.selected = true; }
      size.appendChild(o);
    });
    [first, prev, next, last, size, info].forEach(function (x) { pager.appendChild(x); });
    host.appendChild(pager);
    host.appendChild(wrap);
    var view = [];

    function sortBy(i) {
      state.dir = state.sort === i ? -state.dir : 1;
      state.sort = i;
      heads.forEach(function (th, k) {
        th.setAttribute("aria-sort", k !== i ? "none" : state.dir > 0 ? "ascending" : "descending");
      });
      state.page = 0;
      draw();
    }
    function pages() { return Math.max(1, Math.ceil(view.length / state.size)); }
    first.addEventListener("click", function () { state.page = 0; page(); });
    prev.addEventListener("click", function () { state.page = Math.max(0, state.page - 1); page(); });
    next.addEventListener("click", function () { state.page = Math.min(pages() - 1, state.page + 1); page(); });
    last.addEventListener("click", function () { state.page = pages() - 1; page(); });
    size.addEventListener("change", function () { state.size = Number(size.value); state.page = 0; page(); });

    function draw() {
      view = [];
      for (var r = 0; r < rows.length; r++) {
        var keep = true;
        for (var i = 0; i < cols.length && keep; i++) {
          if (state.tests[i] && !state.tests[i](rows[r][i])) { keep = false; }
        }
        if (keep) { view.push(r); }
      }
      if (state.sort >= 0) {
        var i = state.sort, cmp = compare(cols[i].kind, state.dir);
        view.sort(function (a, b) { return cmp(rows[a][i], rows[b][i]) || a - b; });
      }
      page();
    }
    function page() {
      var start = state.page * state.size, end = Math.min(view.length, start + state.size);
      var frag = document.createDocumentFragment();
      for (var k = start; k < end; k++) {
        var row = rows[view[k]], tr = document.createElement("tr");
        for (var i = 0; i < cols.length; i++) {
          var c = cols[i], v = row[i], td = el("td", null, isNum(c.kind) ? "num" : "");
          if (CLASS[c.kind] && v !== null) { td.className = CLASS[c.kind] + " " + CLASS[c.kind] + "-" + v; }
          if (c.name === "txn" && v !== null && links[v]) {
            var a = el("a", v);
            a.href = "#txn-" + v;
            td.appendChild(a);
          } else {
            td.textContent = shown(v);
            if (td.textContent.length > 40) { td.title = td.textContent; }  /* cut with an ellipsis */
          }
          tr.appendChild(td);
        }
        frag.appendChild(tr);
      }
      tbody.replaceChildren(frag);
      var filtered = view.length < rows.length ? " (filtered from " + rows.length.toLocaleString("en") + ")" : "";
      info.textContent = view.length ? "rows " + (start + 1).toLocaleString("en") + "\u2013" +
        end.toLocaleString("en") + " of " + view.length.toLocaleString("en") + filtered :
        "no row matches" + filtered;
      host.setAttribute("data-visible", String(end - start));
      host.setAttribute("data-matching", String(view.length));
      first.disabled = prev.disabled = state.page === 0;
      next.disabled = last.disabled = state.page >= pages() - 1;
    }
    draw();
  }

  function drawFrames(box, frames) {
    if (!frames || !frames.length) {
      box.appendChild(el("p", "No frame of this transaction was found again in the capture.", "dim"));
      return;
    }
    frames.forEach(function (f) {
      if (f.gap) {
        box.appendChild(el("p", "\u2026 " + f.gap + " frames left out \u2026", "gap"));
        return;
      }
      var div = el("div", null, "frame");
      div.appendChild(el("div", "Frame " + f.n + "  " + f.t + "  " + f.src + " \u2192 " + f.dst + "  " + f.s,
        "fhead"));
      var table = el("table", null, "fields"), body = table.createTBody();
      f.L.forEach(function (layer) {
        var tr = body.insertRow(), td = el("td", layer[0]);
        td.colSpan = 5;
        td.style.paddingLeft = (layer[1] * 14) + "px";
        tr.className = "layer";
        tr.appendChild(td);
        layer[2].forEach(function (fd) {
          var r = body.insertRow();
          var off = fd[0] >= 0 ? ("0000" + fd[0].toString(16)).slice(-4) : "";
          var check = fd[4] || "";
          r.appendChild(el("td", off, "dim"));
          r.appendChild(el("td", fd[1], "dim"));
          r.appendChild(el("td", fd[2]));
          r.appendChild(el("td", fd[3]));
          r.appendChild(el("td", check ? "[" + check + "]" : "", check === "ok" ? "good" :
            (/BREAKS| error:| warning:/.test(check) ? "bad" : "dim")));
        });
      });
      div.appendChild(table);
      if (f.F.length) {
        var ul = el("ul", null, "findings");
        f.F.forEach(function (x) { ul.appendChild(el("li", x[0] + " " + x[1], "s-" + x[0])); });
        div.appendChild(ul);
      }
      box.appendChild(div);
    });
  }

  function openDrill(details) {
    if (!details || details.getAttribute("data-drawn")) { return; }
    details.setAttribute("data-drawn", "1");
    drawFrames(details.querySelector(".drill"), DATA.drill[details.getAttribute("data-txn")]);
  }

  document.querySelectorAll("div.pdtable").forEach(function (host) {
    makeTable(host, DATA.tables[host.getAttribute("data-table")]);
  });
  document.querySelectorAll("details[data-txn]").forEach(function (d) {
    d.addEventListener("toggle", function () { if (d.open) { openDrill(d); } });
  });
  function follow() {
    var m = /^#txn-(\d+)$/.exec(location.hash);
    var d = m && document.getElementById("txn-" + m[1]);
    if (d) { d.open = true; openDrill(d); d.scrollIntoView(); }
  }
  window.addEventListener("hashchange", follow);
  follow();
  document.body.setAttribute("data-ready", "1");
})();
"""
