"""Plots of an Analysis, shared by the notebook and the HTML report (matplotlib, no pyplot state).

    from pd_analyze.output import plots
    plots.timeline(a)          # a matplotlib Figure; in a notebook it shows inline
    plots.latency(a, ax=ax)    # or draw into an axes of your own figure

Every function takes an `Analysis` (or anything with the same `transactions` / `parameters` tables),
draws one chart and returns its Figure. Empty tables give a chart that says so, never an error.
Scatter layers with many points are rasterised, so an SVG of a 250,000-transaction capture stays small.
"""

from __future__ import annotations

import io
import textwrap
from collections.abc import Callable
from typing import Protocol

import pandas as pd
from matplotlib import rc_context
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, LogLocator, NullLocator
from matplotlib.transforms import Bbox

from pd_analyze.analysis.stations import device_label, merged
from pd_analyze.model.verdicts import VERDICTS

VERDICT_COLOURS = {"ok": "#7cb36a", "nak": "#e68a00", "reference_mismatch": "#8d6e63", "timeout": "#d32f2f",
                   "pnio_error": "#7b1fa2", "malformed": "#263238"}
VERDICT_MARKERS = {"ok": "|", "nak": "o", "reference_mismatch": "s", "timeout": "X", "pnio_error": "D",
                   "malformed": "P"}
DEVICE_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
                  "#bcbd22", "#17becf")
RASTERISE_ABOVE = 2_000  # points in one scatter layer
MAX_DEVICES = 20  # lanes / boxes per chart; the rest is named in the title
MAX_LABELS = 30  # failures annotated on the timeline when there are at most this many
TXN_URL = "#txn-"  # a failure marker's link in the SVG (+ its txn number): the HTML report's drill-down
NAK_LABEL_WIDTH = 44  # characters per line of a NAK chart label (longer ones wrap, never cut)
WIDTH = 9.0
TIMELINE_WIDTH = 14.0  # the timeline's own width (its failure labels are placed for it: resize it, and they may meet)


class Tables(Protocol):
    @property
    def transactions(self) -> pd.DataFrame: ...

    @property
    def parameters(self) -> pd.DataFrame: ...


def _axes(ax: Axes | None, height: float, width: float = WIDTH) -> Axes:
    if ax is not None:
        return ax
    fig = Figure(figsize=(width, height), layout="constrained")
    return fig.add_subplot()


def _empty(ax: Axes, title: str, text: str) -> Figure:
    ax.set_title(title, loc="left")
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="#666666")
    ax.set_xticks([])
    ax.set_yticks([])
    return ax.get_figure(root=True)


def _seconds(t: pd.DataFrame) -> tuple[pd.Series, pd.Timestamp]:
    start = t.t_start.min()
    return (t.t_start - start).dt.total_seconds(), start


def _named(a: Tables) -> Callable[[str], str]:
    """How a chart names a device: its address, with its PN-DCP station name where the captures have one
    (an Analysis knows its captures; other tables name addresses alone)."""
    names = merged(getattr(a, "captures", ()))
    return lambda device: device_label(device, names)


def _devices(t: pd.DataFrame, key: pd.Series | None = None) -> tuple[list[str], int]:
    """Devices to draw (at most MAX_DEVICES, by `key` descending, else by name) and how many were left out."""
    names = sorted(str(d) for d in t.device.dropna().unique())
    if key is not None:
        names = [str(d) for d in key.sort_values(ascending=False).index]
    return names[:MAX_DEVICES], max(0, len(names) - MAX_DEVICES)


def verdicts(a: Tables, ax: Axes | None = None) -> Figure:
    """Transactions per verdict (horizontal bars, counts written at the bars)."""
    t = a.transactions
    ax = _axes(ax, 2.6)
    title = "Transactions by verdict"
    if t.empty:
        return _empty(ax, title, "no PROFIdrive transactions")
    counts = t.verdict.astype(str).value_counts().reindex(VERDICTS, fill_value=0)
    bars = ax.barh(list(counts.index)[::-1], list(counts.values)[::-1],
                   color=[VERDICT_COLOURS[v] for v in counts.index][::-1])
    ax.bar_label(bars, padding=3, fontsize=9)
    ax.set_title(f"{title} ({len(t):,} in all)", loc="left")
    ax.set_xlabel("transactions")
    ax.margins(x=0.12)
    ax.spines[["top", "right"]].set_visible(False)
    return ax.get_figure(root=True)


def naks(a: Tables, ax: Axes | None = None, top: int = 15) -> Figure:
    """Refused parameters by PNU and PROFIdrive error number, most frequent first."""
    p = a.parameters
    errs = p[p.error.fillna("") != ""] if not p.empty else p
    grouped = (errs.groupby(["pnu", "error", "error_text"], observed=True, dropna=False).size()
               .sort_values(ascending=False)) if not errs.empty else pd.Series(dtype="int64")
    shown = grouped.head(top)
    labels = [textwrap.fill(f"P{pnu}  {err}  {text}", NAK_LABEL_WIDTH) for pnu, err, text in shown.index]
    extra = sum(label.count("\n") for label in labels)  # wrapped lines
    ax = _axes(ax, 1.0 + 0.3 * min(top, max(len(grouped), 3)) + 0.13 * extra)
    title = "NAKs by PNU and error"
    if errs.empty:
        return _empty(ax, title, "no parameter was refused")
    errors = sorted({e for _, e, _ in grouped.index})
    colour = {e: DEVICE_COLOURS[i % len(DEVICE_COLOURS)] for i, e in enumerate(errors)}
    bars = ax.barh(labels[::-1], list(shown.values)[::-1], color=[colour[e] for _, e, _ in shown.index][::-1])
    ax.bar_label(bars, padding=3, fontsize=9)
    more = f"; the top {top} of {len(grouped)} pairs shown" if len(grouped) > top else ""
    ax.set_title(title, loc="left")
    ax.set_xlabel(f"refused parameters ({int(grouped.sum()):,} in all{more})")
    ax.tick_params(axis="y", labelsize=8)
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.margins(x=0.1)
    ax.spines[["top", "right"]].set_visible(False)
    return ax.get_figure(root=True)


def timeline(a: Tables, ax: Axes | None = None) -> Figure:
    """Every transaction at its start time, one lane per device, coloured and shaped by verdict.

    Failures are drawn large on top of the ok ticks; with at most MAX_LABELS failures each is labelled
    with its transaction number and what failed. With more than RASTERISE_ABOVE transactions the lane
    splits into one row per verdict, so dense failures of one kind cannot hide another. Each failure marker
    carries the link TXN_URL + its txn number in an SVG (for at most RASTERISE_ABOVE failures of a verdict:
    more are drawn as one image): the HTML report puts a link over each.
    """
    t = a.transactions
    n_dev = min(t.device.nunique(), MAX_DEVICES) if not t.empty else 1
    labelled = int((t.verdict != "ok").sum()) <= MAX_LABELS
    # labels take turns above and below their lane; they are placed for the figure's size (TIMELINE_WIDTH wide)
    ax = _axes(ax, 1.4 + (0.9 if labelled else 0.55) * n_dev, TIMELINE_WIDTH)
    title = "Timeline of transactions per device"
    if t.empty:
        return _empty(ax, title, "no PROFIdrive transactions")
    secs, start = _seconds(t)
    devices, hidden = _devices(t)
    lane = {d: i for i, d in enumerate(devices)}
    y = t.device.astype(str).map(lane)
    drawn = y.notna()
    failures = t[drawn & (t.verdict != "ok")]
    dense = len(t) > RASTERISE_ABOVE
    for k, verdict in enumerate(VERDICTS):
        sel = drawn & (t.verdict == verdict)
        n = int(sel.sum())
        if not n:
            continue
        ok = verdict == "ok"
        row = (k - 2.5) * 0.13 if dense else 0.0  # dense: a row per verdict inside the lane
        ax.scatter(secs[sel], y[sel] + row, marker=VERDICT_MARKERS[verdict], s=(20 if dense else 60 if ok else 70),
                   c=VERDICT_COLOURS[verdict], linewidths=1.2 if ok else 0.6,
                   edgecolors=None if ok or dense else "white", zorder=2 if ok else 3, label=f"{verdict} ({n:,})",
                   rasterized=n > RASTERISE_ABOVE,
                   urls=None if ok or n > RASTERISE_ABOVE else [f"{TXN_URL}{v}" for v in t.txn[sel]])
    ax.set_yticks(range(len(devices)), list(map(_named(a), devices)))
    ax.set_ylim(len(devices) - 0.4, -0.6)
    ax.set_xlabel(_since(start))
    more = f"; {hidden} more devices not drawn" if hidden else ""
    heading = f"{title} ({len(t):,} transactions{more}"
    ax.set_title(heading + ")", loc="left")
    ax.grid(axis="x", color="#e0e0e0", linewidth=0.6)
    ax.set_axisbelow(True)
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False)
    if labelled and len(failures):
        unlabelled = _label_failures(ax, failures, secs, y)
        if unlabelled:  # (the same one-line title: the layout made for it still holds)
            ax.set_title(f"{heading}; {unlabelled} failure{'s' if unlabelled != 1 else ''} without a label: "
                         "too close to others)", loc="left")
    return ax.get_figure(root=True)


def _label_levels(ax: Axes, renderer: object) -> list[float]:
    """Offsets in points above (+) and below (-) a lane where a label may sit, nearest first, taking turns:
    clear of the markers (about 5 points either side), inside the lane's half of the gap to the next."""
    (_, y0), (_, y1) = ax.transData.transform([(0, 0), (0, 1)])
    room = abs(y1 - y0) / 2 - 2  # points from a lane to the middle of the gap (a point is a pixel at 72 dpi)
    room *= 72 / ax.get_figure(root=True).dpi
    above = [7.0 + 10 * k for k in range(8) if 7 + 10 * k + 8 <= room]  # a 7-point text is about 8 points high
    below = [-15.0 - 10 * k for k in range(8) if 15 + 10 * k <= room]
    levels = [level for pair in zip(above, below, strict=False) for level in pair]
    longer = above if len(above) > len(below) else below
    return levels + longer[len(levels) // 2:]


def _label_failures(ax: Axes, failures: pd.DataFrame, secs: pd.Series, y: pd.Series) -> int:
    """Transaction number and what failed beside each failure, placed where it overprints no other label
    and no failure marker and stays inside the axes: right of the marker, else left, at the first level
    with room. Placed for the figure at its present size (draw the chart at the size it is shown at). Returns
    how many failures found no room (the title says so)."""
    fig = ax.get_figure(root=True)
    if not hasattr(fig.canvas, "get_renderer"):
        FigureCanvasAgg(fig)  # a canvas that measures text (saving as SVG uses its own)
    fig.draw_without_rendering()  # the layout: the axes' final place at this size
    renderer = fig.canvas.get_renderer()
    inside = ax.get_window_extent(renderer)
    order = failures.sort_values("t_start")
    points = ax.transData.transform(list(zip(secs[order.index].astype(float), y[order.index].astype(float),
                                             strict=True)))
    taken = [Bbox.from_bounds(px - 5, py - 5, 10, 10) for px, py in points]  # the markers (about 10 points)
    levels = _label_levels(ax, renderer)
    unlabelled = 0
    for row, _point in zip(order.itertuples(), points, strict=True):
        what = row.errors or " ".join(str(v) for v in (row.verdict, row.pnio_error_text) if v)
        text = f"{row.txn}: {_short(str(what), 28)}"
        for dy, dx in ((dy, dx) for dy in levels for dx in (4, -4)):
            label = ax.annotate(text, (float(secs[row.Index]), float(y[row.Index])), xytext=(dx, dy),
                                textcoords="offset points", fontsize=7, ha="left" if dx > 0 else "right",
                                color=VERDICT_COLOURS[str(row.verdict)], annotation_clip=False)
            label.set_in_layout(False)  # (placed inside the axes: the layout need not make room for it)
            box = label.get_window_extent(renderer)
            if inside.x0 <= box.x0 and box.x1 <= inside.x1 and inside.y0 <= box.y0 and box.y1 <= inside.y1 \
                    and not any(box.overlaps(other) for other in taken):
                taken.append(box.padded(3))  # (a gap, so neighbouring labels do not read as one)
                break
            label.remove()
        else:
            unlabelled += 1
    return unlabelled


def _since(start: pd.Timestamp) -> str:
    return f"seconds since {start:%Y-%m-%d %H:%M:%S}.{start.microsecond // 1000:03d} UTC"


def latency(a: Tables, ax: Axes | None = None) -> Figure:
    """Write request to final response (t_total), per device: box plot (log scale) with every transaction on top."""
    t = a.transactions
    done = t[t.t_total.notna()] if not t.empty else t
    n_dev = min(done.device.nunique(), MAX_DEVICES) if not done.empty else 1
    ax = _axes(ax, 1.3 + 0.5 * n_dev)
    title = "Latency per device, write request to final response"
    if done.empty:
        return _empty(ax, title, "no transaction completed")
    ms = done.t_total.astype("float64") * 1000.0
    p90 = ms.groupby(done.device.astype(str)).quantile(0.9)
    devices, hidden = _devices(done, p90)
    data = [ms[done.device.astype(str) == d].to_numpy() for d in devices]
    ax.boxplot(data, orientation="horizontal", widths=0.55, showfliers=False,
               medianprops={"color": "#222222"}, boxprops={"color": "#555555"}, whiskerprops={"color": "#555555"},
               capprops={"color": "#555555"})
    n_points = sum(len(d) for d in data)
    for i, values in enumerate(data):
        jitter = ((pd.Series(range(len(values))) * 0.618034) % 1.0 - 0.5) * 0.35
        ax.scatter(values, i + 1 + jitter.to_numpy(), s=9, alpha=0.6, color=DEVICE_COLOURS[i % len(DEVICE_COLOURS)],
                   linewidths=0, rasterized=n_points > RASTERISE_ABOVE, zorder=3)
    ax.set_yticks(range(1, len(devices) + 1), list(map(_named(a), devices)))
    ax.set_ylim(len(devices) + 0.6, 0.4)
    ax.set_xscale("log")
    ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
    ax.xaxis.set_minor_locator(NullLocator())  # labelled 1-2-5 ticks only: minor labels cost most of the drawing
    ax.set_xlabel("ms (log scale)")
    more = f"; {hidden} faster devices not drawn" if hidden else ""
    ax.set_title(f"{title} (slowest p90 first{more})", loc="left")
    ax.grid(axis="x", which="both", color="#e8e8e8", linewidth=0.5)
    ax.set_axisbelow(True)
    return ax.get_figure(root=True)


def b5_retries(a: Tables, ax: Axes | None = None) -> Figure:
    """B5 (state conflict, response not ready) answers per transaction over time, one colour per device."""
    t = a.transactions
    ax = _axes(ax, 3.0)
    title = "B5 retries over time"
    b5 = t[t.b5_retries.fillna(0) > 0] if not t.empty else t
    if b5.empty:
        return _empty(ax, title, "no read was answered B5 (not ready)")
    secs, start = _seconds(t)
    devices, hidden = _devices(b5, b5.groupby(b5.device.astype(str)).b5_retries.sum())
    named = _named(a)
    for i, dev in enumerate(devices):
        sel = b5.device.astype(str) == dev
        xs, ys = secs[sel.reindex(t.index, fill_value=False)], b5.b5_retries[sel].astype("float64")
        if len(xs) <= RASTERISE_ABOVE:  # stems help a sparse chart; for a dense one they cost seconds
            ax.vlines(xs, 0, ys, color=DEVICE_COLOURS[i % len(DEVICE_COLOURS)], linewidth=0.8, alpha=0.5)
        ax.scatter(xs, ys, s=16, color=DEVICE_COLOURS[i % len(DEVICE_COLOURS)], zorder=3,
                   label=f"{named(dev)} ({int(ys.sum()):,} in {len(ys):,} txns)",
                   rasterized=len(xs) > RASTERISE_ABOVE)
    ax.set_ylim(bottom=0)
    ax.yaxis.get_major_locator().set_params(integer=True)
    ax.set_xlabel(_since(start))
    ax.set_ylabel("B5 answers")
    more = f"; {hidden} more devices not drawn" if hidden else ""
    ax.set_title(f"{title} ({int(t.b5_retries.sum()):,} in {len(b5):,} transactions{more})", loc="left")
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False)
    ax.grid(axis="y", color="#e8e8e8", linewidth=0.5)
    ax.set_axisbelow(True)
    return ax.get_figure(root=True)


CHARTS = {  # name: (title, draw), in the order of the HTML report
    "verdicts": ("Verdicts", verdicts),
    "naks": ("NAKs by PNU and error", naks),
    "timeline": ("Timeline per device", timeline),
    "latency": ("Latency per device", latency),
    "b5": ("B5 retries over time", b5_retries),
}


def svg(fig: Figure) -> str:
    """The figure as SVG text: text kept as text, fixed ids and no date, so equal input gives equal bytes."""
    buf = io.StringIO()
    with rc_context({"svg.fonttype": "none", "svg.hashsalt": "pd-analyze"}):
        # tight: the saved area grows to hold every label, legend and annotation, so none is cut off
        fig.savefig(buf, format="svg", bbox_inches="tight", metadata={"Date": None, "Creator": "pd-analyze"})
    return buf.getvalue()


def _short(text: str, limit: int) -> str:
    return text if len(text) <= limit else text[: limit - 1] + "…"

