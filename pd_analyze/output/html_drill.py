"""The HTML report's drill-down: the frames and fields of chosen transactions, each frame with every finding
the analysis holds for it, and the field that decided a failed transaction's verdict.

Which transactions: the first `max_failed` failed ones, every one the summary text names (the slowest, the
one with the most B5 answers), then up to `max_more` others with MAX_MORE_FRAMES frames in all (those with
a finding first, then those of the change trail, then in txn order). Any other transaction number on the
page still opens a drill-down, which says how to get its frames.

A frame's item for the page's script: number, time, addresses, summary line; its layers (title, depth,
fields, folded) with each field as [offset, bytes, name, value, check, role]; its findings. The role colours
the check: E/W/I a finding of that severity names the field, F a refused record service ("failed: ..."),
R a PROFIdrive error number (the drive refused the parameter), N a B5 "not ready" answer, ok a passed check.
"""

from __future__ import annotations

import html
import re
from collections.abc import Iterable, Mapping, Sequence
from datetime import UTC, datetime
from typing import Any

import pandas as pd

from pd_analyze.analysis.api import Analysis
from pd_analyze.analysis.drilldown import annotated_frames, with_findings
from pd_analyze.analysis.stations import device_label, merged
from pd_analyze.model.rules import SEVERITY_RANK, Finding
from pd_analyze.model.times import DEFAULT_DIGITS, ms_text
from pd_analyze.output.frame_view import template_of
from pd_analyze.output.html_tables import column
from pd_analyze.output.summary_words import few, reason
from pd_analyze.protocol.frames import FrameResult

MAX_FAILED = 50
MAX_MORE = 60
MAX_MORE_FRAMES = 600  # frames of those others at most (the page grows by some 3 kB a frame)
MAX_FRAMES_PER_TXN = 30  # the first 20 and the last 10 frames of a transaction with more ...
MAX_FINDING_FRAMES = 10  # ... and up to this many frames between them that carry a finding
MAX_FINDINGS_PER_FRAME = 100  # listed under a frame; the findings table lists any more
_RAW_BYTES = 16  # bytes of a field shown
SHOW_CHARS = 300  # characters of a value shown (the page says where a value is cut)
_ROLE = {"error": "E", "warning": "W", "info": "I"}
_MARKED = frozenset({"E", "W", "I", "F", "R"})  # roles that keep a lower layer unfolded
_REFUSALS = frozenset({"pd.val[i].error"})  # the field a NAK's error block names the refusal in
# the layers below the record (link, IP, UDP, RPC headers) are folded; a layer of one or two fields (the
# call's request/response frame, a fragment's reassembly) is left open
_LOWER = frozenset({"eth", "vlan", "sll", "ip", "udp", "rpc"})
_TXN_WORD = re.compile(r"\b(transaction|txn) (\d+)\b")


def named_in(text: str) -> set[int]:
    """The transaction numbers a text names ('transaction 14', 'txn 5')."""
    return {int(m.group(2)) for m in _TXN_WORD.finditer(text)}


def linked(text: str) -> str:
    """`text` HTML-escaped, each transaction number it names a link to its drill-down."""
    return _TXN_WORD.sub(lambda m: f'{m.group(1)} <a href="#txn-{m.group(2)}">{m.group(2)}</a>',
                         html.escape(text, quote=False))


def choose(t: pd.DataFrame, f: pd.DataFrame, c: pd.DataFrame, named: Iterable[int], max_failed: int = MAX_FAILED,
           max_more: int = MAX_MORE) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(the failed transactions drilled, the others drilled), each in txn order. The others are those `named`
    (whatever their verdict) and ok ones."""
    failed = t[t.verdict != "ok"].head(max_failed)
    rest = t[~t.txn.isin(failed.txn)]
    named_rows = rest[rest.txn.isin(list(named))]
    rest = rest[~rest.txn.isin(named_rows.txn) & (rest.verdict == "ok")]
    rank = pd.Series(2, index=rest.index)
    rank[rest.txn.isin(c.txn.dropna())] = 1
    rank[rest.txn.isin(f.txn.dropna())] = 0
    more = rest.assign(_rank=rank).sort_values(["_rank", "txn"], kind="stable").head(max_more).drop(columns="_rank")
    frames = (more.frames.fillna("").str.count(" ") + 1).clip(upper=MAX_FRAMES_PER_TXN)
    more = more[frames.cumsum() <= MAX_MORE_FRAMES]
    return failed, pd.concat([named_rows, more]).sort_values("txn", kind="stable")


def drilldown(analysis: Analysis, txns: pd.DataFrame) -> dict[int, dict[str, object]]:
    """Per transaction: its verdict ("v"), its frames as the page shows them ("F", with {"gap": n} for frames
    left out) and the field that decided its verdict ("x": [frame, field name], None when no field did).

    One annotated pass per capture (a --chain analysis: over the chain), stopping after the last frame
    needed; each frame gets the findings of the findings table at it."""
    out: dict[int, dict[str, object]] = {}
    if txns.empty:
        return out
    groups = [("", txns)] if analysis.chain else txns.groupby("capture", observed=True, sort=False)
    for capture, group in groups:
        frames_of = {int(txn): sorted(int(n) for n in _text(frames).split())
                     for txn, frames in zip(group.txn, group.frames, strict=True)}
        every = {n for frames in frames_of.values() for n in frames}
        found = _findings_at(analysis.findings, "" if analysis.chain else str(capture), every)
        wanted: dict[int, list[int]] = {}
        for txn, frames in frames_of.items():
            for number in frames_to_show(frames, found):
                wanted.setdefault(number, []).append(txn)
        items: dict[int, list[dict[str, Any]]] = {txn: [] for txn in frames_of}
        results = annotated_frames(str(capture), wanted, analysis.profile, analysis.rpc_timeout, analysis.chain)
        for res in with_findings(results, found):
            item = frame_item(res)
            for txn in wanted[res.frame]:
                items[txn].append(item)
        verdicts = dict(zip(group.txn.astype(int), group.verdict.astype(str), strict=True))
        for txn, frames in frames_of.items():
            out[txn] = {"v": verdicts[txn], "F": _with_gaps(items[txn], frames),
                        "x": deciding_field(items[txn], verdicts[txn] != "ok")}
    return out


def _findings_at(f: pd.DataFrame, capture: str, frames: set[int]) -> dict[int, list[Finding]]:
    """The findings table's rows at `frames` of one capture ('' for all) as Findings, by frame."""
    f = f[f.frame.isin(list(frames))]
    if capture:
        f = f[f.capture.astype(str) == capture]
    out: dict[int, list[Finding]] = {}
    for r in f.itertuples():
        out.setdefault(int(r.frame), []).append(Finding(
            str(r.rule), str(r.name), str(r.severity), int(r.frame), _text(r.field), _text(r.value),
            _text(r.expected), _text(r.source), _text(r.message)))
    return out


def _text(value: object) -> str:
    return "" if value is None or pd.isna(value) else str(value)


def frames_to_show(frames: list[int], found: Mapping[int, object]) -> list[int]:
    """A transaction's frames to show: all up to MAX_FRAMES_PER_TXN, else the first 20, the last 10 and the
    first MAX_FINDING_FRAMES between them that carry a finding."""
    if len(frames) <= MAX_FRAMES_PER_TXN:
        return frames
    head, tail = frames[:20], frames[20 - MAX_FRAMES_PER_TXN:]
    middle = [n for n in frames[20:20 - MAX_FRAMES_PER_TXN] if n in found][:MAX_FINDING_FRAMES]
    return head + middle + tail


def _with_gaps(items: list[dict[str, Any]], frames: list[int]) -> list[dict[str, Any]]:
    """The items in frame order, a {"gap": n} where n frames of the transaction are left out."""
    if not items:
        return []
    shown = {int(i["n"]) for i in items}
    out: list[dict[str, Any]] = []
    left_out = 0
    by_number = {i["n"]: i for i in items}
    for n in frames:
        if n not in shown:
            left_out += 1
            continue
        if left_out:
            out.append({"gap": left_out})
            left_out = 0
        out.append(by_number[n])
    if left_out:
        out.append({"gap": left_out})
    return out


def frame_item(res: FrameResult) -> dict[str, Any]:
    severity: dict[str, str] = {}
    for f in res.findings:
        if SEVERITY_RANK.get(f.severity, 0) > SEVERITY_RANK.get(severity.get(f.field, ""), 0):
            severity[f.field] = f.severity
    layers = []
    for layer in res.layers:
        fields = [[f.offset, _raw(f.raw), f.name, _short(f.show), f.check, role(f.name, f.check, severity)]
                  for f in layer.fields]
        lower = len(fields) > 2 and all(f.name.partition(".")[0] in _LOWER for f in layer.fields)
        folded = lower and not any(fld[5] in _MARKED for fld in fields)
        layers.append([layer.title, layer.depth, fields, int(folded)])
    findings = [[f.severity, f.rule, f.name, f.field, f.message, f.value, f.expected]
                for f in res.findings[:MAX_FINDINGS_PER_FRAME]]
    item = {"n": res.frame, "t": _utc(res.ts), "src": res.src, "dst": res.dst, "s": res.summary, "L": layers,
            "F": findings}
    if len(res.findings) > MAX_FINDINGS_PER_FRAME:
        item["more"] = len(res.findings) - MAX_FINDINGS_PER_FRAME
    return item


def role(name: str, check: str, severity: Mapping[str, str]) -> str:
    """How the page colours a field's check (the module's docstring lists the roles)."""
    if name in severity:
        return _ROLE.get(severity[name], "I")
    if check.startswith("failed: "):  # a refused record service (protocol.pnio_view.status_check)
        return "F"
    if template_of(name) in _REFUSALS:
        return "R"
    if check.startswith("not ready: "):
        return "N"
    if "BREAKS" in check:  # a vendor limit broken without a finding of its own
        return "W"
    return "ok" if check == "ok" or check.endswith(": ok") else ""


def deciding_field(items: Sequence[dict[str, Any]], failed: bool) -> list[object] | None:
    """[frame, field name] of the field that decided the verdict of a failed transaction: the last field an
    error finding names; else the last refused service or PROFIdrive error (the first of its frame); else the
    last field a warning names; else the last B5 answer. For an ok transaction the first field any finding
    names (why it is worth a look). None when no field qualifies."""
    marked = [(int(item["n"]), fld[2], fld[5]) for item in items
              for layer in item["L"] for fld in layer[2] if fld[5] in _MARKED or fld[5] == "N"]
    if not failed:
        first = next((m for m in marked if m[2] in "EWI"), None)
        return [first[0], first[1]] if first else None
    for roles in ("E", "FR", "W", "N"):
        picked = [m for m in marked if m[2] in roles]
        if picked:
            last_frame = picked[-1][0]
            hit = next(m for m in picked if m[0] == last_frame) if roles == "FR" else picked[-1]
            return [hit[0], hit[1]]
    return None


def _raw(raw: bytes) -> str:
    text = raw[:_RAW_BYTES].hex(" ")
    return text + (" …" if len(raw) > _RAW_BYTES else "")


def _short(text: str) -> str:
    return text if len(text) <= SHOW_CHARS else text[:SHOW_CHARS - 1] + "…"


def _utc(ts: float) -> str:
    return datetime.fromtimestamp(ts, UTC).strftime("%Y-%m-%d %H:%M:%S.%f")


# --- the section ----------------------------------------------------------------------------------------------

def section(analysis: Analysis, failed_all: int, failed: pd.DataFrame, others: pd.DataFrame,
            drill: Mapping[int, Mapping[str, object]], max_failed: int) -> str:
    head = "<section id=\"frames\"><h2>Transactions: frames and fields</h2>\n"
    intro = ("<p class=\"intro\">Open a transaction to see each of its frames as the dump shows it: offset, bytes, "
             "field, value and check, the frame's findings below it. The field that decided a failed "
             "transaction's verdict is red and the frames open scrolled to it; the Ethernet, IP, UDP and RPC "
             "headers are folded (click a layer to unfold it). Frames beyond "
             f"{MAX_FRAMES_PER_TXN} per transaction are left out in the middle. Every txn number on the page opens "
             "its transaction here.</p>\n")
    note = ""
    if failed_all > len(failed):
        note = (f"<p class=\"note cap\">The frames of the first {max_failed:,} of {failed_all:,} failed transactions "
                "are embedded; <code>pd-analyze dump CAPTURE -Y 'txn.id == N'</code> shows any other.</p>\n")
    names = merged(analysis.captures)
    p = analysis.parameters
    named = p[p.txn.isin(pd.concat([failed.txn, others.txn])) & p.pnu_name.fillna("").ne("")]
    pnu_names = dict(zip(named.pnu.astype(int), named.pnu_name.astype(str), strict=True))
    parts = [head, intro, note]
    for title, rows in ((f"Failed ({len(failed):,} of {failed_all:,})", failed),
                        (f"Others ({len(others):,}: named by the summary, with a finding, in the change trail, "
                         "then in txn order)", others)):
        if rows.empty:
            continue
        parts.append(f"<h3>{html.escape(title)}</h3>\n")
        parts += [_details(r, names, pnu_names, bool(drill.get(int(r.txn), {}).get("F")), analysis.rows.digits)
                  for r in _heading_rows(rows, analysis)]
    if failed.empty:
        parts.append("<p class=\"intro\">No transaction failed.</p>\n")
    parts.append("<div id=\"more-txns\"></div></section>\n")
    return "".join(parts)


def _heading_rows(rows: pd.DataFrame, analysis: Analysis) -> Iterable:
    errors = column(rows.errors, "errors", analysis.rows.names)
    return (r._replace(errors=e or "") for r, e in zip(rows.itertuples(), errors, strict=True))


def heading(r: Any, names: Mapping[str, str], pnu_names: dict[int, str],
            digits: Mapping[str, int] | None = None) -> list[tuple[str, str, str]]:
    """A drill-down's heading as (css class, text, full text where the text is shortened) parts, empty fields
    left out; times at the capture's resolution (`digits`: Rows.digits)."""
    places = (digits or {}).get(_text(r.capture), DEFAULT_DIGITS)
    verdict = str(r.verdict)
    parts = [("txn", f"txn {int(r.txn)}", ""), (f"badge v-{verdict}", verdict, "")]
    where = [device_label(str(r.device), names)] if _text(r.device) else []
    where += [f"{label} {_text(v)}" for label, v in (("DO", r.do), ("ref", r.ref)) if _text(v)]
    if where:
        parts.append(("", " ".join(where), ""))
    what = _what(r, places)
    params = _text(r.params)
    if params and not (verdict == "nak" and all(p in what for p in params.split())):
        short = few(params, pnu_names)  # (a NAK's errors name its parameters already)
        parts.append(("", short, params if len(short.split()) < len(params.split()) else ""))
    if what:
        parts.append(("what", what, ""))
    frames = len(_text(r.frames).split())
    total = "" if pd.isna(r.t_total) else f", {ms_text(float(r.t_total), places, False)} ms"
    parts.append(("dim", f"{frames} frame{'s' if frames != 1 else ''}{total}", ""))
    return parts


def _what(r: Any, digits: int) -> str:
    verdict = str(r.verdict)
    if verdict == "ok":
        return ""
    if verdict == "nak":
        return _text(r.errors)
    return reason(verdict, _text(r.pnio_error_text), _text(r.closed_by), _value(r.b5_retries), _value(r.t_last_read),
                  digits)


def _value(value: object) -> object:
    return None if value is None or pd.isna(value) else value


def _details(r: Any, names: Mapping[str, str], pnu_names: dict[int, str], found: bool,
             digits: Mapping[str, int]) -> str:
    txn = int(r.txn)
    parts = heading(r, names, pnu_names, digits)
    if not found:
        parts.append(("dim", "not found again in the capture", ""))
    spans = [_span(c, text, full) for c, text, full in parts]
    summary = " ".join(spans[:2]) + "".join(f"<span class=\"sep\"> · </span>{s}" for s in spans[2:])
    return (f"<details id=\"txn-{txn}\" data-txn=\"{txn}\"><summary>{summary}</summary>"
            "<div class=\"drill\"></div></details>\n")


def _span(cls: str, text: str, full: str) -> str:
    if not cls and not full:
        return html.escape(text)
    attrs = (f' class="{html.escape(cls)}"' if cls else "") + (f' title="{html.escape(full)}"' if full else "")
    return f"<span{attrs}>{html.escape(text)}</span>"
