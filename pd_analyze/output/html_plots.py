"""The HTML report's plots: the charts of `pd_analyze.output.plots` as SVG images, and over each failure marker
of the timeline a link to its transaction's drill-down with a hover title (number, parameters, verdict and
what failed, in full where the chart's label is cut).

A link inside an `<img>` cannot be clicked, so the page lays transparent links over the image: the timeline's
SVG carries each failure marker's link (plots.TXN_URL) around the marker it draws, which gives the marker's
place in the SVG's own coordinates, as a share of the image's width and height.
"""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Iterator

import pandas as pd

from pd_analyze.analysis.api import Analysis
from pd_analyze.model import pd_values as pt
from pd_analyze.output import plots
from pd_analyze.output.html_tables import column

MAX_MARKER_LINKS = 2_000  # links laid over the timeline's failure markers; past that, the first ones by time

_CAPTIONS = {
    "verdicts": "How every transaction ended (protocol.md 7.4: the first matching rule wins).",
    "timeline": "Each transaction at its write request time, one lane per device; ok ones as ticks, failures as "
                "large markers (labelled with their txn number and what failed where a label has room: the title "
                "counts the failures left without one). Point at a failure for its number, parameters and verdict; "
                "click it for its frames.",
    "naks": "Refused parameters (negative responses 0x81/0x82) by PNU and PROFIdrive error number.",
    "latency": "Write request to final response per device (completed transactions): box = quartiles, "
               "whiskers 1.5 IQR, dots = transactions.",
    "b5": "Reads answered B5 (state conflict: response not ready) per transaction, over time.",
}
_PLOT_WIDTH = {"timeline": plots.TIMELINE_WIDTH}  # inches; the others 7.0, two side by side
_SIZE = re.compile(r'viewBox="0 0 ([\d.]+) ([\d.]+)"')
_MARK = re.compile(re.escape(f'<a xlink:href="{plots.TXN_URL}') + r'(\d+)"[^>]*>(.*?)</a>', re.S)
_USE = re.compile(r'<use [^>]*?x="(-?[\d.]+)" y="(-?[\d.]+)"')  # a marker drawn as a reference to its shape
_PATH = re.compile(r'<path d="([^"]*)"')  # or drawn in place (few markers): the middle of its outline
_NUMBER = re.compile(r"-?[\d.]+")


def section(analysis: Analysis) -> str:
    figures = []
    t = analysis.transactions
    failed = int((t.verdict != "ok").sum()) if not t.empty else 0
    for name, (title, draw) in plots.CHARTS.items():
        fig = draw(analysis)
        fig.set_size_inches(_PLOT_WIDTH.get(name, 7.0), fig.get_figheight())  # shown at natural size in the grid
        svg = plots.svg(fig)
        src = "data:image/svg+xml;base64," + base64.b64encode(svg.encode("utf-8")).decode("ascii")
        caption = _CAPTIONS[name]
        links = ""
        if name == "timeline":
            if failed > plots.MAX_LABELS:  # the labels would overprint: say so rather than promise them
                caption = caption.replace(
                    "(labelled with their txn number and what failed where a label has room: the title counts the "
                    "failures left without one)", f"({failed:,} failures: too many to label)")
            marks = list(markers(svg))
            links = _links(marks, t, analysis.rows.names)
            if len(marks) < failed:
                caption += (f" {len(marks):,} of the {failed:,} failures carry a link; the Transactions table lists "
                            "them all.")
        figures.append(f"<figure id=\"plot-{name}\"><div class=\"plotbox\"><img class=\"plot\" src=\"{src}\" "
                       f"alt=\"{html.escape(title)}\">{links}</div>"
                       f"<figcaption>{html.escape(caption)}</figcaption></figure>")
    return "<section id=\"plots\"><h2>Plots</h2>\n<div class=\"plots\">" + "\n".join(figures) + "</div>\n</section>\n"


def markers(svg: str) -> Iterator[tuple[int, float, float]]:
    """(txn, x, y) of each linked marker of an SVG, x and y as shares (0..1) of its width and height."""
    size = _SIZE.search(svg)
    if size is None:
        return
    width, height = float(size.group(1)), float(size.group(2))
    for m in _MARK.finditer(svg):
        use, path = _USE.search(m.group(2)), _PATH.search(m.group(2))
        if use is not None:
            x, y = float(use.group(1)), float(use.group(2))
        elif path is not None:
            numbers = [float(n) for n in _NUMBER.findall(path.group(1))]
            xs, ys = numbers[0::2], numbers[1::2]
            if not xs or not ys:
                continue
            x, y = (min(xs) + max(xs)) / 2, (min(ys) + max(ys)) / 2
        else:
            continue
        yield int(m.group(1)), x / width, y / height


def _links(marks: list[tuple[int, float, float]], t: pd.DataFrame, names: pt.Names) -> str:
    if not marks:
        return ""
    marks = marks[:MAX_MARKER_LINKS]
    rows = t.drop_duplicates("txn").set_index("txn").loc[[txn for txn, _, _ in marks]]
    errors = column(rows.errors, "errors", names)
    out = []
    for (txn, x, y), r, error in zip(marks, rows.itertuples(), errors, strict=True):
        what = " ".join(str(v) for v in (error, r.pnio_error_text) if isinstance(v, str) and v)
        params = r.params if isinstance(r.params, str) and r.params else "(parameters not decoded)"
        title = f"txn {txn}: {params} {r.verdict}" + (f": {what}" if what else "")
        out.append(f"<a class=\"mark\" href=\"{plots.TXN_URL}{txn}\" style=\"left:{x * 100:.3f}%;top:{y * 100:.3f}%\" "
                   f"title=\"{html.escape(title)}\" aria-label=\"{html.escape(title)}\"></a>")
    return "".join(out)
