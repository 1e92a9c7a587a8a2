"""Times exact, written as the capture has them (issue #26 point 5).

The worked example's six frames (write request, write response, read request, B5 answer, read request, read
response) timed anew and written as a microsecond pcap, a nanosecond pcap and pcapngs of several resolutions
(devtools.synth.capture_files): the DataFrames hold the capture's own nanoseconds and the exact differences,
and every file, the summary and the HTML page write them with the capture's decimals."""

from __future__ import annotations

import csv
from pathlib import Path

import pandas as pd
import pytest

import pd_analyze
from devtools.synth.capture_files import Frame, Pcapng, pcap_bytes
from pd_analyze import capture
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.analysis.engine.run import analyze_frames
from pd_analyze.analysis.rows import Rows
from pd_analyze.capture.batches import batches
from pd_analyze.capture.raw import RawFrame
from pd_analyze.model.times import NS
from pd_analyze.output import html_report, report
from tests.test_html_report import column, console_errors, embedded, load, type_filter

REPO = Path(__file__).resolve().parents[1]
DATA = [f.data for f in capture.frames(str(REPO / "sample_pcaps" / "worked_example.pcap"))]
BASE = 1714982400 * NS  # 2024-05-06 08:00:00 UTC
# the two frame times first (1714982400.002936 and .004435: the write RTT is 0.001499 exactly), then a
# read request 15 us after the write response (a gap repr would write 1.5e-05)
US = [BASE + us * 1000 for us in (2936, 4435, 4450, 6001, 8002, 10449)]
NANO = [BASE + ns for ns in (2_936_123, 4_435_456, 4_435_471, 6_001_000, 8_002_789, 10_449_999)]
FIGURES = ("t_write_rtt", "t_total", "t_final_read_rtt", "t_first_read_gap", "t_last_read")


def _pcap(path: Path, times: list[int], nanosecond: bool = False) -> Path:
    path.write_bytes(pcap_bytes([Frame(t, d) for t, d in zip(times, DATA, strict=True)], nanosecond=nanosecond))
    return path


def _pcapng(path: Path, times: list[int], *resolutions: int) -> Path:
    """The frames on the first interface; an interface per resolution (if_tsresol)."""
    out = Pcapng()
    out.section_header()
    for resol in resolutions:
        out.interface(1, tsresol=resol)
    for t, d in zip(times, DATA, strict=True):
        out.epb(Frame(t, d))
    path.write_bytes(out.tobytes())
    return path


def _report(paths: list[Path], out: Path, fmt: str) -> report.Streamed:
    return report.stream([str(p) for p in paths], str(out), fmt, Settings())


def _csv_rows(out: Path, name: str = "transactions") -> list[dict[str, str]]:
    with open(out / f"{name}.csv", newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def _latency(text: str) -> list[str]:
    return text.split("Latency per device, ms (write to final response; slowest first):\n")[1].split("\n\n")[0] \
        .splitlines()


def test_a_microsecond_pcap_gives_the_exact_figures_written_to_the_microsecond(tmp_path):
    path = _pcap(tmp_path / "us.pcap", US)
    a = pd_analyze.analyze(str(path))
    t = a.transactions.iloc[0]
    assert t.t_start.value == 1714982400_002936000 and str(a.transactions.t_start.dtype) == "datetime64[ns, UTC]"
    assert [t[c] for c in FIGURES] == [0.001499, 0.007513, 0.002447, 0.000015, 0.005066]
    assert repr(float(t.t_write_rtt)) == "0.001499"  # not 0.001499176025390625 (float seconds since 1970)
    assert a.rows.digits == {str(path): 6}
    cells = {"t_start": "2024-05-06 08:00:00.002936+00:00", "t_write_rtt": "0.001499", "t_total": "0.007513",
             "t_final_read_rtt": "0.002447", "t_first_read_gap": "0.000015", "t_last_read": "0.005066"}
    streamed = _report([path], tmp_path / "csv", "csv")
    assert [{k: row[k] for k in cells} for row in _csv_rows(tmp_path / "csv")] == [cells]
    _report([path], tmp_path / "json", "json")
    line = (tmp_path / "json" / "transactions.jsonl").read_text("ascii")
    assert ('"t_start":"2024-05-06T08:00:00.002936Z","t_write_rtt":0.001499,"t_total":0.007513,'
            '"t_final_read_rtt":0.002447,"t_first_read_gap":0.000015,"t_last_read":0.005066,') in line
    _report([path], tmp_path / "parquet", "parquet")
    back = pd.read_parquet(tmp_path / "parquet" / "transactions")
    assert back.t_start[0].value == 1714982400_002936000 and [back[c][0] for c in FIGURES] == [t[c] for c in FIGURES]
    # the summary: milliseconds to the microsecond
    assert streamed.summary == report.summary(a)
    assert _latency(streamed.summary) == [
        "  device                n      p50      p90      p99      max  write rtt p50",
        "  192.168.0.2           1    7.513    7.513    7.513    7.513  1.499"]
    assert "     7.513  192.168.0.2 slot 1 DO 1 P964[0] P2000[0..2] (transaction 1)" in streamed.summary.splitlines()


def test_the_html_page_shows_the_times_to_the_captures_resolution(tmp_path):
    a = pd_analyze.analyze(str(_pcap(tmp_path / "us.pcap", US)))
    page = html_report.render(a)
    table = embedded(page)["tables"]["transactions"]
    names = [c["name"] for c in table["columns"]]
    row = dict(zip(names, table["rows"][0], strict=True))
    assert {k: row[k] for k in ("t_start", "t_write_rtt", "t_total")} == {
        "t_start": "2024-05-06 08:00:00.002936", "t_write_rtt": 1.499, "t_total": 7.513}
    assert "6 frames, 7.513 ms</span>" in page  # the drill-down's heading
    ns = pd_analyze.analyze(str(_pcapng(tmp_path / "ns.pcapng", NANO, 9)))
    table = embedded(html_report.render(ns))["tables"]["transactions"]
    row = dict(zip(names, table["rows"][0], strict=True))
    assert {k: row[k] for k in ("t_start", "t_write_rtt", "t_total")} == {
        "t_start": "2024-05-06 08:00:00.002936123", "t_write_rtt": 1.499333, "t_total": 7.513876}


def test_a_nanosecond_pcapng_gives_the_figures_exact_to_the_nanosecond(tmp_path):
    path = _pcapng(tmp_path / "ns.pcapng", NANO, 9)
    a = pd_analyze.analyze(str(path))
    t = a.transactions.iloc[0]
    assert t.t_start.value == 1714982400_002936123
    assert [t[c] for c in FIGURES] == [0.001499333, 0.007513876, 0.00244721, 1.5e-08, 0.005066666]
    assert a.rows.digits == {str(path): 9}
    streamed = _report([path], tmp_path / "csv", "csv")
    assert [{k: row[k] for k in ("t_start", *FIGURES)} for row in _csv_rows(tmp_path / "csv")] == [{
        "t_start": "2024-05-06 08:00:00.002936123+00:00", "t_write_rtt": "0.001499333", "t_total": "0.007513876",
        "t_final_read_rtt": "0.00244721", "t_first_read_gap": "0.000000015", "t_last_read": "0.005066666"}]
    _report([path], tmp_path / "json", "json")
    assert ('"t_start":"2024-05-06T08:00:00.002936123Z","t_write_rtt":0.001499333,"t_total":0.007513876,'
            '"t_final_read_rtt":0.00244721,"t_first_read_gap":0.000000015,"t_last_read":0.005066666,'
            ) in (tmp_path / "json" / "transactions.jsonl").read_text("ascii")
    assert _latency(streamed.summary) == [
        "  device                n       p50       p90       p99       max  write rtt p50",
        "  192.168.0.2           1  7.513876  7.513876  7.513876  7.513876  1.499333"]
    # the same frames given one by one (capture.frames: each with its nanoseconds) give the same times
    rows = Rows()
    analyze_frames(capture.frames(str(path)), Settings(), rows, "frames")
    b = pd_analyze.Analysis(rows, [], "generic", 10.0, 5.0).transactions.iloc[0]
    assert [b.t_start.value, *(b[c] for c in FIGURES)] == [t.t_start.value, *(t[c] for c in FIGURES)]
    assert rows.digits == {"frames": 9}


def _quarter(ns: int) -> int:
    """A time as a pcapng of 2^-2 s units holds it (whole quarters of a second, cut)."""
    return (ns * 4 // NS) * NS // 4


@pytest.mark.parametrize(("kind", "digits", "start", "rtt"), [
    ("pcap us", 6, "2024-05-06 08:00:00.002936+00:00", "0.001499"),
    ("pcap ns", 9, "2024-05-06 08:00:00.002936123+00:00", "0.001499333"),
    ("pcapng ms", 3, "2024-05-06 08:00:00.002+00:00", "0.002"),  # if_tsresol 3: .002936 cut to .002, .004435 to .004
    ("pcapng 2^-10 s", 9, f"2024-05-06 08:00:00.{(1714982400_002936123 * 1024 // NS * NS >> 10) % NS:09d}+00:00",
     "0.000976563"),  # units of 1/1024 s: ten binary places need ten decimals; nanoseconds are held
    ("pcapng 2^-2 s", 2, "2024-05-06 08:00:00.00+00:00", "0.0"),
    ("pcapng us and ns interfaces", 9, "2024-05-06 08:00:00.002936000+00:00", "0.001499"),  # the finest
])
def test_each_capture_is_written_at_its_resolution(tmp_path, kind, digits, start, rtt):
    path = {"pcap us": lambda: _pcap(tmp_path / "c.pcap", US),
            "pcap ns": lambda: _pcap(tmp_path / "c.pcap", NANO, nanosecond=True),
            "pcapng ms": lambda: _pcapng(tmp_path / "c.pcapng", NANO, 3),
            "pcapng 2^-10 s": lambda: _pcapng(tmp_path / "c.pcapng", NANO, 0x8A),
            "pcapng 2^-2 s": lambda: _pcapng(tmp_path / "c.pcapng", [_quarter(t) for t in NANO], 0x82),
            "pcapng us and ns interfaces": lambda: _pcapng(tmp_path / "c.pcapng", US, 6, 9)}[kind]()
    assert all(b.digits == digits for b in batches(str(path)))
    _report([path], tmp_path / "out", "csv")
    (row,) = _csv_rows(tmp_path / "out")
    assert (row["t_start"], row["t_write_rtt"]) == (start, rtt)
    assert pd_analyze.analyze(str(path)).rows.digits == {str(path): digits}


def test_several_captures_each_at_its_own_resolution(tmp_path):
    us, ns = _pcap(tmp_path / "us.pcap", US), _pcapng(tmp_path / "ns.pcapng", NANO, 9)
    _report([us, ns], tmp_path / "out", "csv")
    assert [(r["capture"], r["t_start"], r["t_write_rtt"]) for r in _csv_rows(tmp_path / "out")] == [
        (str(us), "2024-05-06 08:00:00.002936+00:00", "0.001499"),
        (str(ns), "2024-05-06 08:00:00.002936123+00:00", "0.001499333")]
    a = pd_analyze.analyze([str(us), str(ns)])
    assert a.rows.digits == {str(us): 6, str(ns): 9}
    # one device in both captures: the summary's latency line at the finer resolution (p50 of 7.513 and 7.513876:
    # 7.513438; the write RTTs' 1.499 and 1.499333: 1.4991665, whose double is below the half)
    assert _latency(report.summary(a))[1] == \
        "  192.168.0.2           2  7.513438  7.513788  7.513867  7.513876  1.499166"


def test_frames_without_nanoseconds_are_taken_to_the_microsecond():
    """Frames made elsewhere (a fuzzer's: a float time only) are timed to the microsecond, written with six
    decimals; frames whose nanoseconds need nine get nine."""
    for times, ns, digits in ((NANO, False, 6), (NANO, True, 9), (US, True, 6)):
        frames = [RawFrame(n, t / NS, 1, d, 0, 0, t if ns else None)
                  for n, (t, d) in enumerate(zip(times, DATA, strict=True), 1)]
        rows = Rows()
        analyze_frames(frames, Settings(), rows, "given")
        t = pd_analyze.Analysis(rows, [], "generic", 10.0, 5.0).transactions.iloc[0]
        assert rows.digits == {"given": digits}
        assert t.t_start.value == (times[0] if ns else round(times[0] / 1000) * 1000)


def test_a_workers_resolutions_join_the_runs():
    """`--jobs`: a worker's rows come back with its captures' resolutions; the finer one wins."""
    mine, theirs = Rows(), Rows()
    mine.note_digits("a.pcap", 6)
    theirs.note_digits("a.pcap", 9)
    theirs.note_digits("b.pcapng", 3)
    theirs.note_digits("b.pcapng", 2)  # a coarser interface later: the finest stays
    mine.extend(theirs, 0)
    assert mine.digits == {"a.pcap": 9, "b.pcapng": 3}


def test_the_pages_time_filters_compare_times_of_any_resolution(browser, tmp_path):
    """A page of a microsecond and a nanosecond capture: cells of six and of nine decimals compare as times
    (the script pads each to nine), a filter typed to any decimal compares as the time it names."""
    us, ns = _pcap(tmp_path / "us.pcap", US), _pcapng(tmp_path / "ns.pcapng", NANO, 9)
    page = Path(html_report.write(pd_analyze.analyze([str(us), str(ns)]), str(tmp_path / "report.html")))
    load(browser, page)
    assert column(browser, "transactions", "t_start") == ["2024-05-06 08:00:00.002936",
                                                           "2024-05-06 08:00:00.002936123"]
    for text, txns in ((">2024-05-06 08:00:00.002936", ["2"]), ("<=2024-05-06 08:00:00.002936", ["1"]),
                       (">=2024-05-06 08:00:00.0029361", ["2"]), ("<08:00:00.002936001", ["1"]),
                       (">=08:00:00.002936", ["1", "2"]), (">8:00:00.003", [])):  # times of day
        type_filter(browser, "transactions", "t_start", text)
        assert column(browser, "transactions", "txn") == txns, text
    type_filter(browser, "transactions", "t_start", "")
    assert column(browser, "transactions", "t_write_rtt") == ["1.499", "1.499333"]
    assert console_errors(browser) == []
