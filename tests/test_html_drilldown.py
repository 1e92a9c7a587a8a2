"""The HTML report leads from a failed transaction to its cause (issue #27): the drill-down lists every finding
of the findings table under its frame and marks its field, the field that decided the verdict is red and the
frames open scrolled to it, every txn number on the page (tables, summary text, timeline markers) opens its
drill-down every time, the tables lead with what is read first, and the page does not scroll sideways.

The structure tests read the page's data; the browser tests (headless Chromium, as tests/test_html_report.py)
check each point as a reader meets it, on the sample captures and on a fault-rich capture generated here.
"""

from __future__ import annotations

import base64
import re
from pathlib import Path

import pandas as pd
import pytest

import pd_analyze
from devtools.synth.mixed_capture import make_capture
from pd_analyze.analysis.intended import load as load_set
from pd_analyze.model.rules import SEVERITY_RANK
from pd_analyze.output import html_plots, html_report, report
from tests.test_html_report import REPO, SAMPLES, column, console_errors, embedded, load, type_filter

AUDIT = REPO / "sample_pcaps" / "audit_commissioning.pcap"
DRILL_SCREENSHOT = REPO / "docs" / "report_drilldown.png"
AUDIT_SET = REPO / "sample_pcaps" / "sets" / "audit_commissioning.csv"
RED = "rgb(198, 40, 40)"  # report.css --bad


def _write(capture: Path, out: Path, **kw: object) -> Path:
    return Path(html_report.write(pd_analyze.analyze(str(capture)), str(out), **kw))  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def pages(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The reports of the samples these tests drill into (by absolute path: the page names the capture so)."""
    out = tmp_path_factory.mktemp("drill")
    names = ("fault_trace", "pd_interleaved", "pd_timeouts", "pd_retries_and_duplicates", "pd_edge_cases")
    return {n: _write(REPO / "sample_pcaps" / f"{n}.pcap", out / f"{n}.html") for n in names}


@pytest.fixture(scope="module")
def rich(tmp_path_factory: pytest.TempPathFactory) -> tuple[pd_analyze.Analysis, Path]:
    """A fault-rich capture (30 % of the transactions go wrong: timeouts, refused record services, RPC faults,
    unanswered requests, retries) and its report."""
    folder = tmp_path_factory.mktemp("rich")
    capture = folder / "rich.pcap"
    make_capture(capture, 4000, seed=3, pnio_share=0.5, faults=0.3)
    a = pd_analyze.analyze(str(capture))
    return a, Path(html_report.write(a, str(folder / "rich.html")))


def findings_of(item: dict) -> list[tuple[str, ...]]:
    return sorted((f[1], f[2], f[3], f[4]) for f in item["F"])


def table_findings(f: pd.DataFrame, frame: int) -> list[tuple[str, ...]]:
    at = f[f.frame == frame]
    return sorted(zip(at.rule.astype(str), at.name.astype(str), at.field.fillna("").astype(str),
                      at.message.fillna("").astype(str), strict=True))


def check_every_drilled_frame(a: pd_analyze.Analysis, data: dict) -> int:
    """Every drilled frame lists exactly the findings table's findings at it, and each field a finding names
    carries that finding's severity as its role. Returns how many findings were checked."""
    checked = 0
    roles = {"error": "E", "warning": "W", "info": "I"}
    for drill in data["drill"].values():
        for item in drill["F"]:
            if "gap" in item:
                continue
            expected = table_findings(a.findings, item["n"])
            assert findings_of(item) == expected, (item["n"], findings_of(item), expected)
            fields = {fld[2]: fld[5] for layer in item["L"] for fld in layer[2]}
            for field in {f[3] for f in item["F"]} & set(fields):
                worst = max((f[0] for f in item["F"] if f[3] == field), key=SEVERITY_RANK.__getitem__)
                assert fields[field] == roles[worst], (item["n"], field)
            checked += len(expected)
    return checked


# --- the page's data -----------------------------------------------------------------------------------------

def test_every_finding_of_a_drilled_frame_is_listed_under_it_on_every_sample() -> None:
    checked = 0
    for capture in SAMPLES:
        a = pd_analyze.analyze(str(capture))
        checked += check_every_drilled_frame(a, embedded(html_report.render(a)))
    # every finding of every drilled frame of the samples, each compared: 117 of frame and transaction rules
    # (3 R7 at the duplicate answers a transaction lists among its frames, protocol.md 7.6), 39 T8 txn_failed and
    # 50 T9 txn_refused (6.5)
    assert checked == 206


def test_every_finding_of_a_drilled_frame_is_listed_on_a_fault_rich_capture(rich) -> None:
    a, page = rich
    data = embedded(page.read_text(encoding="utf-8"))
    assert check_every_drilled_frame(a, data) == 149  # 85 of T1-T4, R7 and P2; 54 T8 and 10 T9 (protocol.md 6.5)
    failed = a.transactions[a.transactions.verdict != "ok"]
    named = set(re.findall(r"transaction (\d+)", report.summary(a)))  # drilled whatever their verdict
    named_failed = {int(n) for n in named} & set(failed.txn)
    assert {int(k) for k, v in data["drill"].items() if v["v"] != "ok"} == set(failed.txn.head(50)) | named_failed


def test_transaction_level_findings_reach_their_frames(pages: dict[str, Path]) -> None:
    data = embedded(pages["pd_interleaved"].read_text(encoding="utf-8"))
    frame = next(f for f in data["drill"]["19"]["F"] if f["n"] == 95)
    assert frame["F"] == [["error", "Q2", "reference_mismatch", "pd.ref",
                           "response reference 3 does not mirror the request's 2", "3", "2"]]
    assert [fld[4:] for layer in frame["L"] for fld in layer[2] if fld[2] == "pd.ref"] == \
        [["Q2 error: response reference 3 does not mirror the request's 2", "E"]]
    assert data["drill"]["19"]["x"] == [95, "pd.ref"]

    data = embedded(pages["pd_timeouts"].read_text(encoding="utf-8"))  # found after the timeout: R7, and T8 at
    # the write request the deadline closed (protocol.md 6.5)
    assert [f["F"] for f in data["drill"]["5"]["F"]] == [[
        ["warning", "R7", "rpc_unanswered", "rpc.seq", "request not answered (no response within 5 s)", "1",
         "a response within 5 s"],
        ["warning", "T8", "txn_failed", "txn.verdict", "the transaction of frame 15 failed: timeout: no final "
         "response within 10 s", "timeout", "ok or nak"]]]
    assert data["drill"]["5"]["x"] == [15, "rpc.seq"]
    assert data["drill"]["3"]["x"] is None  # a deadline timeout: no field decided it

    data = embedded(pages["pd_retries_and_duplicates"].read_text(encoding="utf-8"))  # T3, T4 on ok transactions
    t3 = next(f for f in data["drill"]["10"]["F"] if f["n"] == 52)
    # (and T8 of the transaction it superseded, at the superseding write: protocol.md 6.5)
    assert [x[1:3] for x in t3["F"]] == [["T3", "write_while_pending"], ["T8", "txn_failed"]]
    assert data["drill"]["10"]["x"] == [52, "pd.ref"]


def test_the_field_that_decided_the_verdict(pages: dict[str, Path]) -> None:
    data = embedded(pages["fault_trace"].read_text(encoding="utf-8"))
    decided = {txn: data["drill"][str(txn)]["x"] for txn in (5, 7, 12, 13, 15, 17, 43, 46, 59, 42, 1)}
    # a NAK: the error value in the final response; a refused write: its status; a busy drive given up: the last
    # B5 answer (sample_pcaps/README.md lists the frames)
    assert decided == {5: [22, "pd.val[0].error"], 7: [28, "ndr.status.code"], 12: [52, "pd.val[0].error"],
                       13: [56, "pd.val[0].error"], 15: [68, "ndr.status.code"], 17: [102, "pd.val[1].error"],
                       43: [300, "pd.val[0].error"], 46: [318, "pd.val[0].error"], 59: [396, "pd.val[0].error"],
                       42: [291, "pd.ref"],  # ok, but a T4 finding: the field worth a look
                       1: None}
    fields = {fld[2]: fld for f in data["drill"]["7"]["F"] if f["n"] == 28 for layer in f["L"] for fld in layer[2]}
    assert fields["ndr.status.code"][5] == "F" and fields["ndr.status.code"][4].startswith("failed: DF80B100 write")


def test_a_finding_of_any_rule_marks_its_field_and_an_error_decides() -> None:
    """A finding of a rule the drill-down has never heard of (the coming T8 txn_failed, at the frame that decided
    the verdict) is listed, marks its field, and as an error decides: by field name and severity, not rule id."""
    from pd_analyze.analysis.drilldown import annotated_frames, with_findings
    from pd_analyze.model.rules import Finding
    from pd_analyze.output.html_drill import deciding_field, frame_item

    capture = str(REPO / "sample_pcaps" / "fault_trace.pcap")  # txn 12: a NAK, its error value in frame 52
    decided = Finding("T8", "txn_failed", "error", 52, "pd.ref", "4", "", "", "the drive refused the request")
    found = {52: [decided, decided]}  # (listed once, however often the table holds it)
    items = [frame_item(r) for r in with_findings(annotated_frames(capture, {45, 52}, "generic", 5.0), found)]
    assert items[1]["F"] == [["error", "T8", "txn_failed", "pd.ref", "the drive refused the request", "4", ""]]
    marked = [fld for layer in items[1]["L"] for fld in layer[2] if fld[2] in ("pd.ref", "pd.val[0].error")]
    assert [fld[4:] for fld in marked] == [["T8 error: the drive refused the request", "E"], ["", "R"]]
    assert deciding_field(items, failed=True) == [52, "pd.ref"]  # an error finding's field before the error value
    assert deciding_field(items[:1] + [frame_item(next(annotated_frames(capture, {52}, "generic", 5.0)))],
                          failed=True) == [52, "pd.val[0].error"]  # without it, the error value


def test_headings_leave_out_empty_fields_and_give_the_reason(pages: dict[str, Path]) -> None:
    def headings(name: str) -> dict[int, str]:
        page = pages[name].read_text(encoding="utf-8")
        found = re.findall(r'<details id="txn-(\d+)" data-txn="\d+"><summary>(.*?)</summary>', page)
        return {int(n): re.sub(r"<[^>]+>", "", s) for n, s in found}

    edge = headings("pd_edge_cases")
    assert edge[1] == ("txn 1 malformed · 192.168.1.21 · malformed: a PDU could not be decoded (see the findings) · "
                       "8 frames, 9 ms")
    assert edge[11] == ("txn 11 nak · 192.168.1.25 DO 1 ref 2 · request error 0x16 parameter address impermissible "
                        "(attribute, elements, PNU, subindex or combination) · 4 frames, 4 ms")
    page = pages["fault_trace"].read_text(encoding="utf-8")  # a long parameter list: shortened, whole on hover
    params = " ".join(f"P{2000 + k}[0]" for k in range(20))
    assert f'<span title="{params}">P2000[0] P2001[0] P2002[0] ... (20 parameters)</span>' in page
    timeouts = headings("pd_timeouts")
    assert timeouts[5] == ("txn 5 timeout · 192.168.1.23 DO 1 ref 1 · P964[0] (drive unit identification) · "
                           "timeout: no answer within the transaction timeout · 1 frame")
    assert timeouts[20].endswith("timeout: no answer within the transaction timeout (the controller gave up: last "
                                 "read 5 ms after the write, 1 B5 answer) · 7 frames")


def test_every_transaction_the_summary_names_is_linked_and_drilled(pages: dict[str, Path]) -> None:
    a = pd_analyze.analyze(str(REPO / "sample_pcaps" / "fault_trace.pcap"))
    text = report.summary(a)
    page = pages["fault_trace"].read_text(encoding="utf-8")
    named = re.findall(r"transaction (\d+)", text)
    assert named == ["14", "25", "34", "41", "56", "22", "31", "53", "39", "20", "14"]
    pre = re.search(r"<pre>(.*?)</pre>", page, re.S).group(1)
    assert re.findall(r'transaction <a href="#txn-(\d+)">\1</a>', pre) == named
    data = embedded(page)
    assert {int(n) for n in named} <= {int(k) for k in data["drill"]}
    assert all(f'<details id="txn-{n}" data-txn="{n}">' in page for n in named)


def test_tables_lead_with_what_is_read_first(pages: dict[str, Path], tmp_path: Path) -> None:
    data = embedded(pages["fault_trace"].read_text(encoding="utf-8"))
    t = data["tables"]["transactions"]
    names = [c["name"] for c in t["columns"]]
    assert names[:6] == ["txn", "device", "params", "verdict", "errors", "pnio_error_text"]
    row = next(r for r in t["rows"] if r[0] == 5)
    assert row[names.index("errors")] == "P2[0] error 0x01 parameter value cannot be changed"
    assert [c["name"] for c in data["tables"]["findings"]["columns"]][:3] == ["frame", "txn", "severity"]
    assert [c["name"] for c in data["tables"]["changes"]["columns"]][:3] == ["txn", "device", "param"]

    a = pd_analyze.analyze(str(AUDIT))
    page = html_report.render(a, expected=load_set(str(AUDIT_SET)))
    state = embedded(page)["tables"]["params-0"]
    assert [c["name"] for c in state["columns"]][:5] == ["param", "do", "result", "intended", "why"]
    assert '<a href="#params">Parameter state (8 of 8 as intended)</a>' in page  # the audit outcome: navigation
    assert ('<a class="card c-audit-ok" href="#params"><span class="n">8 / 8</span>'  # and a card
            '<span class="l">as intended (--expect)</span></a>') in page
    assert "Intended set (<code>--expect</code>): 8 intended elements: 8 as intended" in page


def test_timeline_markers_link_their_transactions(pages: dict[str, Path], rich) -> None:
    page = pages["fault_trace"].read_text(encoding="utf-8")
    marks = re.findall(r'<a class="mark" href="#txn-(\d+)" style="[^"]+" title="([^"]+)"', page)
    assert sorted(int(n) for n, _ in marks) == [5, 7, 12, 13, 15, 17, 43, 46, 59]
    titles = dict(marks)
    assert titles["7"] == ("txn 7: P2000[0] P2001[0] P2002[0] P2003[0] P2004[0] P2005[0] P2006[0] P2007[0] "
                           "P2008[0] P2009[0] P2010[0] P2011[0] P2012[0] P2013[0] P2014[0] P2015[0] P2016[0] "
                           "P2017[0] P2018[0] P2019[0] pnio_error: DF80B100 write: access write length error "
                           "(parameter request above the record limit or shorter than its header, or read buffer "
                           "too small)")  # in full: the chart's label is cut
    assert titles["13"] == "txn 13: P1121[0] nak: P1121[0] error 0x02 low or high limit exceeded"
    a, rich_page = rich  # too many failures to label: each marker still leads to its transaction
    failed = a.transactions[a.transactions.verdict != "ok"]
    links = re.findall(r'<a class="mark" href="#txn-(\d+)"', rich_page.read_text(encoding="utf-8"))
    assert len(failed) > 30 and sorted(int(n) for n in links) == sorted(failed.txn)


def test_nak_chart_labels_are_not_cut(pages: dict[str, Path]) -> None:
    page = pages["fault_trace"].read_text(encoding="utf-8")
    naks = re.search(r'<figure id="plot-naks">.*?base64,([^"]+)"', page).group(1)
    svg = base64.b64decode(naks).decode()
    assert "…" not in svg
    for line in ("P1300  0x11  request cannot be executed", "because of operating state",
                 "P9999  0x00  impermissible parameter number", "(PNU does not exist)"):
        assert line in svg


def test_marker_positions_are_read_from_the_svg() -> None:
    svg = ('<svg width="200pt" height="100pt" viewBox="0 0 200 100"><a xlink:href="#txn-4" target="_blank"><g>'
           '<use xlink:href="#m1" x="50" y="25" style=""/></g></a><a xlink:href="#txn-9" target="_blank">'
           '<path d="M 100 40 L 110 50 L 100 60 L 90 50 z" style=""/></a></svg>')
    assert list(html_plots.markers(svg)) == [(4, 0.25, 0.25), (9, 0.5, 0.5)]


# --- in Chromium ---------------------------------------------------------------------------------------------

def open_hash(driver, page: Path, txn: int) -> None:
    driver.get(page.resolve().as_uri() + f"#txn-{txn}")
    load_ready(driver)


def load_ready(driver) -> None:
    from selenium.webdriver.support.wait import WebDriverWait

    WebDriverWait(driver, 15).until(lambda d: d.execute_script("return document.body.dataset.ready") == "1")


def row_state(driver, txn: int, frame: int, field: str) -> dict:
    """The field's row in a drill-down: its classes, the colour of its name, whether it is in view (in its box
    and in the window)."""
    return driver.execute_script("""
        const rows = [...document.querySelectorAll(`#txn-${arguments[0]} tr.fld[data-frame='${arguments[1]}']`)];
        const row = rows.find(r => r.dataset.f === arguments[2]);
        if (!row) return null;
        const box = row.closest('.fbox').getBoundingClientRect(), r = row.getBoundingClientRect();
        return {cls: row.className, colour: getComputedStyle(row.querySelector('td.name')).color,
                check: row.querySelector('td.check').textContent,
                inBox: r.top >= box.top && r.bottom <= box.bottom,
                inWindow: r.top >= 0 && r.bottom <= window.innerHeight};""", txn, frame, field)


def frame_findings(driver, txn: int) -> dict[str, list[str]]:
    return driver.execute_script("""
        const out = {};
        for (const li of document.querySelectorAll(`#txn-${arguments[0]} tbody.ffind li`)) {
          let body = li.closest('tbody.ffind');
          while (body && !body.classList.contains('fhead')) body = body.previousElementSibling;
          (out[body.dataset.frame] = out[body.dataset.frame] || []).push(li.textContent);
        }
        return out;""", txn)


def test_finding_under_its_frame_and_its_field_red_in_view(browser, pages: dict[str, Path]) -> None:
    open_hash(browser, pages["pd_interleaved"], 19)
    assert frame_findings(browser, 19) == {"95": [
        "E Q2 reference_mismatch [pd.ref]: response reference 3 does not mirror the request's 2 (value 3; expected 2)"]}
    state = row_state(browser, 19, 95, "pd.ref")
    assert "decisive" in state["cls"] and state["colour"] == RED and state["inBox"] and state["inWindow"]
    assert state["check"] == "[Q2 error: response reference 3 does not mirror the request's 2]"

    open_hash(browser, pages["fault_trace"], 7)  # a refused record service
    state = row_state(browser, 7, 28, "ndr.status.code")
    assert "decisive" in state["cls"] and state["inBox"] and state["inWindow"]
    assert browser.execute_script(
        "return getComputedStyle(document.querySelector(\"#txn-7 tr.decisive td.check\")).color") == RED
    open_hash(browser, pages["fault_trace"], 12)  # a NAK: the error value, at the end of the last of 8 frames
    state = row_state(browser, 12, 52, "pd.val[0].error")
    assert "decisive" in state["cls"] and state["colour"] == RED and state["inBox"] and state["inWindow"]
    assert state["check"] == "[refused by the drive]"
    assert console_errors(browser) == []


def test_drilldown_columns_headings_and_folded_layers(browser, pages: dict[str, Path]) -> None:
    open_hash(browser, pages["fault_trace"], 12)
    heads = browser.execute_script("return [...document.querySelectorAll('#txn-12 table.fields thead th')]"
                                   ".map(t => t.textContent)")
    assert heads == ["offset", "bytes", "field", "value", "check"]
    lefts = browser.execute_script("return [...new Set([...document.querySelectorAll('#txn-12 td.show')]"
                                   ".filter(td => td.offsetParent !== null)"
                                   ".map(td => Math.round(td.getBoundingClientRect().left)))]")
    assert len(lefts) == 1  # the value column at one place in every frame
    layers = browser.execute_script("""
        return [...document.querySelectorAll('#txn-12 tbody.layer')].slice(0, 7).map(b =>
          [b.querySelector('button.fold').firstChild.textContent, b.classList.contains('folded'),
           [...b.querySelectorAll('tr.fld')].filter(r => r.offsetParent !== null).length]);""")
    assert layers == [["Ethernet II", True, 0], ["Internet Protocol Version 4", True, 0],
                      ["User Datagram Protocol", True, 0], ["DCE/RPC connectionless header", True, 0],
                      ["NDR args (request)", False, 5], ["IODWriteReqHeader, index 0xb02e", False, 13],
                      ["Parameter request header", False, 4]]
    browser.execute_script("document.querySelector('#txn-12 tbody.layer button.fold').click()")
    assert browser.execute_script("return [...document.querySelector('#txn-12 tbody.layer').querySelectorAll("
                                  "'tr.fld')].filter(r => r.offsetParent !== null).length") == 3
    rows = browser.execute_script("return document.querySelectorAll('#txn-12 tr.fld').length")
    shown = browser.execute_script("return [...document.querySelectorAll('#txn-12 tr.fld')]"
                                   ".filter(r => r.offsetParent !== null).length")
    assert rows > 400 and shown < rows * 0.6  # 8 frames: the headers folded away


def click_link(driver, selector: str) -> None:
    from selenium.webdriver.common.by import By

    link = driver.find_element(By.CSS_SELECTOR, selector)
    driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", link)
    link.click()


def is_open(driver, txn: int) -> bool:
    """The transaction's drill-down is open, drawn, and its heading in the window."""
    return driver.execute_script(f"const d = document.getElementById('txn-{txn}'); "
                                 "const top = d ? d.getBoundingClientRect().top : -1; "
                                 "return !!d && d.open && !!d.querySelector('.drill').firstChild && "
                                 "top >= -1 && top + 30 < window.innerHeight")


def close(driver, txn: int) -> None:
    driver.execute_script(f"document.querySelector('#txn-{txn} > summary').click()")
    assert driver.execute_script(f"return document.getElementById('txn-{txn}').open") is False


def test_every_txn_link_opens_its_drilldown_every_time(browser, pages: dict[str, Path]) -> None:
    load(browser, pages["fault_trace"])
    links = [("div[data-table='transactions'] tbody a[href='#txn-13']", 13),
             ("div[data-table='findings'] tbody a[href='#txn-42']", 42),  # an ok transaction with a finding
             ("div[data-table='changes'] tbody a[href='#txn-16']", 16),
             ("#summary-text pre a[href='#txn-14']", 14),  # the slowest transaction the summary names
             ("#plot-timeline a.mark[href='#txn-7']", 7)]  # a timeline marker
    for selector, txn in links:
        for _ in range(2):  # clicked again after closing: opens again
            click_link(browser, selector)
            assert is_open(browser, txn), (selector, txn)
            assert browser.execute_script("return location.hash") == f"#txn-{txn}"
            close(browser, txn)
    title = browser.execute_script("return document.querySelector(\"a.mark[href='#txn-15']\").title")
    assert title.startswith("txn 15: P1082[0] pnio_error: DE80B500 read: access state conflict")
    assert console_errors(browser) == []


def test_a_transaction_without_embedded_frames_still_opens(browser, tmp_path: Path) -> None:
    page = _write(REPO / "sample_pcaps" / "pd_retries_and_duplicates.pcap", tmp_path / "r.html")
    load(browser, page)
    type_filter(browser, "transactions", "txn", "200")
    assert column(browser, "transactions", "txn") == ["200"]
    for _ in range(2):
        click_link(browser, "div[data-table='transactions'] tbody a[href='#txn-200']")
        assert is_open(browser, 200)
        text = browser.execute_script("return document.querySelector('#txn-200').textContent")
        assert "txn 200" in text and "P2900[0]" in text and "4 frames" in text
        capture = REPO / "sample_pcaps" / "pd_retries_and_duplicates.pcap"
        assert f"pd-analyze dump '{capture}' -Y 'txn.id == 200'" in text
        close(browser, 200)
    assert browser.execute_script("return document.querySelectorAll('#txn-200').length") == 1


def test_first_columns_visible_at_1400_and_the_txn_column_stays(browser, pages: dict[str, Path],
                                                                  tmp_path: Path) -> None:
    load(browser, pages["fault_trace"])
    geometry = """
        const h = document.querySelector(`div[data-table='${arguments[0]}']`), wrap = h.querySelector('.wrap');
        const w = wrap.getBoundingClientRect(), right = (c) => h.querySelector(`th[data-col='${c}']`)
          .getBoundingClientRect().right;
        return {wrapRight: w.right, wrapLeft: w.left, cols: arguments[1].map(right)};"""
    g = browser.execute_script(geometry, "transactions", ["verdict", "errors", "pnio_error_text"])
    assert all(r <= g["wrapRight"] for r in g["cols"]), g
    browser.execute_script("document.querySelector(\"div[data-table='transactions'] .wrap\").scrollLeft = 100000")
    txn = browser.execute_script("""
        const w = document.querySelector("div[data-table='transactions'] .wrap").getBoundingClientRect();
        const td = document.querySelector("div[data-table='transactions'] tbody td");
        return [Math.round(td.getBoundingClientRect().left - w.left), td.textContent];""")
    assert txn[0] in (0, 1) and txn[1] == "1"  # scrolled to the far right, the txn column stays in place

    a = pd_analyze.analyze(str(AUDIT))
    page = Path(html_report.write(a, str(tmp_path / "audit.html"), expected=load_set(str(AUDIT_SET))))
    load(browser, page)
    g = browser.execute_script(geometry, "params-0", ["result", "intended", "why"])
    assert all(r <= g["wrapRight"] for r in g["cols"]), g


@pytest.mark.parametrize("width", [768, 1024])
def test_no_sideways_scroll(browser, pages: dict[str, Path], rich, width: int) -> None:
    overflow = "return document.documentElement.scrollWidth - document.documentElement.clientWidth"
    browser.set_window_size(width, 1000)
    try:
        for page, txn in ((pages["fault_trace"], 7), (pages["pd_edge_cases"], 1), (rich[1], 0)):
            load(browser, page)  # the capture table holds the capture's absolute path
            assert str(REPO) in browser.execute_script("return document.querySelector('td.path').textContent") \
                or page == rich[1]
            assert browser.execute_script(overflow) == 0, page
            if txn:
                browser.execute_script(f"location.hash = '#txn-{txn}'")
                assert browser.execute_script(overflow) == 0, (page, txn)
    finally:
        browser.set_window_size(1400, 1000)


def test_filters_on_times_and_exact_frames(browser, pages: dict[str, Path]) -> None:
    a = pd_analyze.analyze(str(REPO / "sample_pcaps" / "fault_trace.pcap"))
    t = a.transactions
    load(browser, pages["fault_trace"])
    host = "div[data-table='transactions']"
    matching = f"return document.querySelector(\"{host}\").dataset.matching"
    type_filter(browser, "transactions", "t_start", ">2026-01-01 00:00:20")
    assert int(browser.execute_script(matching)) == int((t.t_start > pd.Timestamp("2026-01-01 00:00:20Z")).sum()) == 10
    type_filter(browser, "transactions", "t_start", "<00:00:01.5")  # a time of day
    assert sorted(int(v) for v in column(browser, "transactions", "txn")) == \
        sorted(t.txn[t.t_start < pd.Timestamp("2026-01-01 00:00:01.5Z")]) == list(range(1, 13))
    type_filter(browser, "transactions", "t_start", "")
    type_filter(browser, "transactions", "frames", "13")  # frame 13 only, not 113 or 131
    assert column(browser, "transactions", "txn") == ["4"] and "13" in t.frames[t.txn == 4].iloc[0].split()
    type_filter(browser, "transactions", "frames", ">400")
    assert column(browser, "transactions", "txn") == ["61", "62"]
    type_filter(browser, "transactions", "frames", "")
    type_filter(browser, "transactions", "txn", "13")  # a number in a number column: that number
    assert column(browser, "transactions", "txn") == ["13"]
    assert console_errors(browser) == []


def test_fault_rich_capture_in_the_browser(browser, rich) -> None:
    """Every drilled failed transaction of the fault-rich capture: its findings under its frames, as the table
    has them, and the field that decided its verdict red and in view when its link is followed."""
    a, page = rich
    data = embedded(page.read_text(encoding="utf-8"))
    load(browser, page)
    failed = sorted(int(k) for k, v in data["drill"].items() if v["v"] != "ok")
    import re

    from pd_analyze.output.report import summary

    named = {int(n) for n in re.findall(r"transaction (\d+)", summary(a))}
    bad = [int(n) for n, v in zip(a.transactions.txn, a.transactions.verdict.astype(str), strict=True) if v != "ok"]
    assert failed == sorted(set(bad[:50]) | (named & set(bad)))  # the first 50 and those the summary names
    decided = 0
    for txn in failed:
        browser.execute_script(f"history.replaceState(null, '', '#'); location.hash = '#txn-{txn}'")
        shown = frame_findings(browser, txn)
        frames = [f["n"] for f in data["drill"][str(txn)]["F"] if "n" in f]
        expected = {str(n): len(table_findings(a.findings, n)) for n in frames if table_findings(a.findings, n)}
        assert {n: len(v) for n, v in shown.items()} == expected, txn
        x = data["drill"][str(txn)]["x"]
        if x:
            state = row_state(browser, txn, x[0], x[1])
            assert "decisive" in state["cls"] and state["colour"] == RED and state["inBox"], (txn, state)
            decided += 1
    assert decided == len(failed)
    first = int(failed[0])  # its timeline marker and its txn link open it, twice
    for selector in (f"#plot-timeline a.mark[href='#txn-{first}']",
                     f"div[data-table='transactions'] tbody a[href='#txn-{first}']"):
        for _ in range(2):
            click_link(browser, selector)
            assert is_open(browser, first), selector
            close(browser, first)
    assert browser.execute_script("""
        const w = document.querySelector("div[data-table='transactions'] .wrap").getBoundingClientRect();
        return ['verdict', 'errors', 'pnio_error_text'].every(c => document.querySelector(
          `div[data-table='transactions'] th[data-col='${c}']`).getBoundingClientRect().right <= w.right);""")
    assert console_errors(browser) == []


def test_screenshot_of_a_drilldown_for_the_readme(browser, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/report_drilldown.png: the reference mismatch of sample_pcaps/pd_interleaved.pcap opened from its link:
    the frame that decided it, its pd.ref in red with the Q2 finding, the finding listed under the frame."""
    monkeypatch.chdir(REPO)  # the page names the capture as the README's command does
    page = _write(Path("sample_pcaps/pd_interleaved.pcap"), tmp_path / "r.html")
    browser.set_window_size(1400, 760)
    try:
        open_hash(browser, page, 19)
        browser.execute_script("document.querySelectorAll('.flash').forEach(r => r.classList.remove('flash'))")
        state = row_state(browser, 19, 95, "pd.ref")
        assert "decisive" in state["cls"] and state["inBox"] and state["inWindow"]
        png = browser.get_screenshot_as_png()
    finally:
        browser.set_window_size(1400, 1000)
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 50_000
    if not DRILL_SCREENSHOT.exists() or DRILL_SCREENSHOT.read_bytes() != png:
        DRILL_SCREENSHOT.write_bytes(png)
