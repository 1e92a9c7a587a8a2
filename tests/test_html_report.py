"""`pd-analyze report --format html`: a self-contained page, escaped, and working in a real browser.

The structure tests read the HTML; the browser tests open it in headless Chromium (Debian's `chromium` and
`chromium-driver`, installed by .ci/run) through Selenium: every sample capture's report loads without a
console error, and on the fault trace the plots render, a header click sorts, typing in a filter filters and
a txn link opens the frames. The fault trace's page is saved as docs/report_screenshot.png (the README's).

Chromium missing: skip with an install hint on a developer's machine, fail when CI is set.
"""

from __future__ import annotations

import base64
import hashlib
import json
import re
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pandas as pd
import pytest

import pd_analyze
from devtools.synth import fixtures
from devtools.synth.pd_encode import ParamAddress, error_block, pd_response, read_request, value_block
from devtools.synth.sim_capture import Capture
from pd_analyze.output import html_drill, html_report

REPO = Path(__file__).resolve().parents[1]
SAMPLES = sorted(p for p in (REPO / "sample_pcaps").iterdir() if p.is_file() and p.name != "README.md")
FAULT = REPO / "sample_pcaps" / "fault_trace.pcap"
SCREENSHOT = REPO / "docs" / "report_screenshot.png"
HOSTILE = "</script><script>alert(1)</script><!--"


def _report(capture: str, out: str) -> str:
    """One capture's report (a process-pool task)."""
    return html_report.write(pd_analyze.analyze(capture), out)


@pytest.fixture(scope="session")
def reports(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The HTML report of every sample capture, built two at a time."""
    out = tmp_path_factory.mktemp("html")
    targets = {p.name: out / f"{p.name}.html" for p in SAMPLES}
    with ProcessPoolExecutor(max_workers=2) as pool:
        list(pool.map(_report, [str(p) for p in SAMPLES], [str(t) for t in targets.values()]))
    return targets


@pytest.fixture(scope="session")
def fault_html(reports: dict[str, Path]) -> str:
    return reports["fault_trace.pcap"].read_text(encoding="utf-8")


def embedded(page: str) -> dict:
    m = re.search(r'<script type="application/json" id="pd-data">(.*?)</script>', page, re.S)
    assert m, "no embedded data"
    return json.loads(m.group(1))


# --- the file itself -----------------------------------------------------------------------------------------

def test_self_contained(fault_html: str) -> None:
    assert "http://" not in fault_html and "https://" not in fault_html  # no URL of any kind, not even xmlns
    for attr, value in re.findall(r'\b(src|href|action|srcset)\s*=\s*"([^"]*)"', fault_html):
        assert value.startswith(("data:image/svg+xml;base64,", "#")), (attr, value[:60])
    assert "<link" not in fault_html and "@import" not in fault_html and "url(" not in fault_html
    csp = re.search(r'http-equiv="Content-Security-Policy" content="([^"]+)"', fault_html).group(1)
    assert "default-src 'none'" in csp
    scripts = re.findall(r"<script>(.*?)</script>", fault_html, re.S)
    assert len(scripts) == 1
    digest = base64.b64encode(hashlib.sha256(scripts[0].encode()).digest()).decode()
    assert f"script-src 'sha256-{digest}'" in csp  # only this script may run


def test_plots_are_embedded_svg(fault_html: str) -> None:
    images = re.findall(r'<img class="plot" src="data:image/svg\+xml;base64,([^"]+)"', fault_html)
    assert len(images) == 5
    for img in images:
        svg = base64.b64decode(img).decode()
        assert "<svg" in svg and "</svg>" in svg and "<script" not in svg
    timeline = base64.b64decode(images[2]).decode()  # the faults are drawn and labelled
    for label in ("15: pnio_error DE80B500", "7: pnio_error DF80B100", "13: P1121[0]:0x02", "192.168.1.22"):
        assert label in timeline


# fault_trace's findings: the T4 of txn 42, T8 txn_failed of its 2 pnio_error and T9 txn_refused of its 7 nak
# transactions (protocol.md 6.5)
FAULT_TRACE_RULES = ["T4"] + ["T8"] * 2 + ["T9"] * 7


def test_tables_and_drilldown_data(fault_html: str) -> None:
    data = embedded(fault_html)
    t = data["tables"]["transactions"]
    names = [c["name"] for c in t["columns"]]
    assert len(t["rows"]) == t["total"] == 62 and t["note"] == ""
    verdicts = [r[names.index("verdict")] for r in t["rows"]]
    assert {v: verdicts.count(v) for v in set(verdicts)} == {"ok": 53, "nak": 7, "pnio_error": 2}
    f = data["tables"]["findings"]
    rules = [r[[c["name"] for c in f["columns"]].index("rule")] for r in f["rows"]]
    assert sorted(rules) == FAULT_TRACE_RULES and len(data["tables"]["changes"]["rows"]) == 12
    drilled = {int(k) for k, v in data["drill"].items() if v["v"] != "ok"}
    assert drilled == {5, 7, 12, 13, 15, 17, 43, 46, 59}  # every failed transaction has its frames
    assert len(data["drill"]) == 62  # and, the capture being small, every other one too
    busy = data["drill"]["15"]["F"]  # given up after three B5 answers: pnio_error DE80B500 (protocol.md 7.3 step 5)
    assert [f["n"] for f in busy] == [60, 62, 63, 64, 65, 66, 67, 68]
    names = {fld[2] for f in busy for layer in f["L"] for fld in layer[2]}
    assert {"ndr.status.code1", "pd.ref", "iod.index"} <= names
    assert data["drill"]["15"]["x"] == [68, "ndr.status.code"]  # the last B5 answer: the drive was still busy
    assert '<details id="txn-15" data-txn="15">' in fault_html


def test_caps_say_what_they_leave_out(reports: dict[str, Path]) -> None:
    a = pd_analyze.analyze(str(FAULT))
    page = html_report.render(a, max_rows=10, max_drilldown=3)
    data = embedded(page)
    t = data["tables"]["transactions"]
    assert len(t["rows"]) == 10 and t["total"] == 62
    assert "10 of 62 transactions embedded (every failed transaction (9), then the first 1 ok ones)" in t["note"]
    verdicts = [r[[c["name"] for c in t["columns"]].index("verdict")] for r in t["rows"]]
    assert verdicts.count("ok") == 1
    failed = sorted(int(k) for k, v in data["drill"].items() if v["v"] != "ok")
    assert failed == [5, 7, 12]
    named = {14, 20, 22, 25, 31, 34, 39, 41, 53, 56}  # the slowest transactions the summary names (14: most B5)
    assert named <= {int(k) for k in data["drill"]}
    assert "The frames of the first 3 of 9 failed transactions are embedded" in page


@pytest.fixture(scope="module")
def big_report(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, float]:
    """The fault trace's tables repeated to 250,000 transactions (frames stay those of the real capture, so
    the drill-down still finds them), rendered with the default caps; returns the page and its render time."""
    a = pd_analyze.analyze(str(FAULT))
    t = a.transactions
    copies = 250_000 // len(t) + 1

    def tile(df: pd.DataFrame, time_col: str | None) -> pd.DataFrame:
        big = pd.concat([df] * copies, ignore_index=True)
        copy = pd.Series(range(copies)).repeat(len(df)).reset_index(drop=True)
        big["txn"] += copy * len(t)
        if time_col:
            big[time_col] += pd.to_timedelta(copy * 26, unit="s")
        return big

    a.__dict__.update(transactions=tile(t, "t_start").head(250_000), parameters=tile(a.parameters, None),
                      findings=tile(a.findings, None), changes=tile(a.changes, "t"))  # the cached tables
    start = time.perf_counter()
    path = Path(html_report.write(a, str(tmp_path_factory.mktemp("big") / "report.html")))
    return path, time.perf_counter() - start


def test_250000_transactions_are_capped(big_report: tuple[Path, float]) -> None:
    path, seconds = big_report
    page = path.read_text(encoding="utf-8")
    assert seconds < 60 and len(page) < 8_000_000
    data = embedded(page)
    t = data["tables"]["transactions"]
    assert len(t["rows"]) == html_report.MAX_ROWS and t["total"] == 250_000
    assert t["note"].startswith("5,000 of 250,000 transactions embedded (the first 5,000 failed ones)")
    assert len(data["tables"]["changes"]["rows"]) == 5_000 and "of 48,396 changes" in data["tables"]["changes"]["note"]
    failed = sorted(int(k) for k, v in data["drill"].items() if v["v"] != "ok")
    assert failed == sorted(data_failed_first(page, html_report.MAX_DRILLDOWN))
    others = [int(k) for k, v in data["drill"].items() if v["v"] == "ok"]
    assert 0 < len(others) <= html_drill.MAX_MORE + 12
    assert "The frames of the first 50 of 36,293 failed transactions are embedded" in page


def data_failed_first(page: str, n: int) -> list[int]:
    """The first n failed transactions of the page's transactions table (which holds every failed one first)."""
    t = embedded(page)["tables"]["transactions"]
    at = [c["name"] for c in t["columns"]]
    return [r[at.index("txn")] for r in t["rows"] if r[at.index("verdict")] != "ok"][:n]


def hostile_capture(path: Path) -> None:
    """A NAK whose VisibleString value tries to end the data script and start another."""
    cap = Capture()
    s = fixtures.session(cap, 1)
    req = read_request(1, 1, [ParamAddress(975), ParamAddress(9999)])
    res = pd_response(1, 0x81, 1, [value_block(0x09, HOSTILE), error_block(0x00)])
    s.parameter_access(req, res)
    path.write_bytes(fixtures.pcap_of(cap))


@pytest.fixture(scope="session")
def hostile_report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("hostile")
    captures = [folder / 'a<img src=x onerror="alert(2)">.pcap', folder / "b&amp;<b>.pcap"]
    for c in captures:
        hostile_capture(c)
    return Path(html_report.write(pd_analyze.analyze([str(c) for c in captures]), str(folder / "report.html")))


def test_capture_strings_are_escaped(hostile_report: Path) -> None:
    page = hostile_report.read_text(encoding="utf-8")
    assert HOSTILE not in page and "<img src=x" not in page and "<b>.pcap" not in page
    assert page.count("<script") == 2 and page.count("</script>") == 2
    assert "a&lt;img src=x onerror=&quot;alert(2)&quot;&gt;.pcap" in page and "b&amp;amp;&lt;b&gt;.pcap" in page
    data = embedded(page)  # the JSON still carries the exact strings
    shows = [fld[3] for f in data["drill"]["1"]["F"] for layer in f["L"] for fld in layer[2]]
    assert any(HOSTILE in s for s in shows)
    t = data["tables"]["transactions"]
    at = [c["name"] for c in t["columns"]].index("capture")
    captures = {r[at] for r in t["rows"]}
    assert any(c.endswith('a<img src=x onerror="alert(2)">.pcap') for c in captures)


def test_cli_writes_report_and_csv(tmp_path: Path) -> None:
    out = tmp_path / "rep"
    r = subprocess.run([sys.executable, "-m", "pd_analyze.cli", "report", str(FAULT), "--format", "html",
                        "--out", str(out)], capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["changes.csv", "findings.csv", "parameters.csv", "report.html",
                                                      "transactions.csv"]
    assert "Transactions: 62  ok=53  nak=7" in r.stdout and "report.html" in r.stderr


# --- in Chromium ---------------------------------------------------------------------------------------------

def load(driver, path: Path) -> None:
    from selenium.webdriver.support.wait import WebDriverWait

    driver.get(path.resolve().as_uri())
    WebDriverWait(driver, 15).until(lambda d: d.execute_script("return document.body.dataset.ready") == "1")


def console_errors(driver) -> list[str]:
    return [e["message"] for e in driver.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]


def plots_drawn(driver) -> int:
    return driver.execute_script(
        "return [...document.querySelectorAll('img.plot')].filter(i => i.complete && i.naturalWidth > 300).length")


def column(driver, table: str, col: str) -> list[str]:
    return driver.execute_script(
        "const h = document.querySelector(`div[data-table='${arguments[0]}']`);"
        "const i = [...h.querySelectorAll('thead tr:first-child th')].findIndex(t => t.dataset.col === arguments[1]);"
        "return [...h.querySelectorAll('tbody tr')].map(r => r.cells[i].textContent);", table, col)


def type_filter(driver, table: str, col: str, text: str) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    box = driver.find_element(By.CSS_SELECTOR, f"div[data-table='{table}'] input[data-col='{col}']")
    box.send_keys(Keys.CONTROL, "a")
    box.send_keys(Keys.BACKSPACE)
    if text:
        box.send_keys(text)


def click_header(driver, table: str, col: str) -> None:
    from selenium.webdriver.common.by import By

    driver.find_element(By.CSS_SELECTOR, f"div[data-table='{table}'] th[data-col='{col}']").click()


def test_every_sample_report_opens_without_errors(browser, reports: dict[str, Path]) -> None:
    from selenium.webdriver.support.wait import WebDriverWait

    problems = []
    for name, path in reports.items():
        load(browser, path)
        errors = console_errors(browser)
        drawn = plots_drawn(browser)
        tables = browser.execute_script("return document.querySelectorAll('div.pdtable table').length")
        analysis = pd_analyze.analyze(str(REPO / "sample_pcaps" / name))
        expected_rows = min(len(analysis.transactions), html_report.PAGE_SIZE)
        expected_tables = 3 + analysis.parameter_state.device.nunique()  # and a parameter-state table per drive
        rows = browser.execute_script("return document.querySelectorAll(\"div[data-table='transactions'] tbody tr\")"
                                      ".length")
        browser.execute_script("document.querySelectorAll('details[data-txn]').forEach(d => { d.open = true; })")
        WebDriverWait(browser, 10).until(lambda d: d.execute_script(  # every drill-down drawn (on toggle)
            "return document.querySelectorAll('details[data-txn]:not([data-drawn])').length") == 0)
        errors += console_errors(browser)
        if errors or drawn != 5 or tables != expected_tables or rows != expected_rows:
            problems.append(f"{name}: errors {errors}, plots {drawn}/5, tables {tables}/{expected_tables}, "
                            f"rows {rows}/{expected_rows}")
    assert not problems, "\n".join(problems)


def test_fault_report_sorts_filters_and_drills_down(browser, reports: dict[str, Path]) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.wait import WebDriverWait

    load(browser, reports["fault_trace.pcap"])
    assert plots_drawn(browser) == 5
    assert len(column(browser, "transactions", "txn")) == 50  # first page of 62
    pager = browser.find_element(By.CSS_SELECTOR, "div[data-table='transactions'] .pager span").text
    assert pager == "rows 1–50 of 62"
    assert sorted(column(browser, "findings", "rule")) == FAULT_TRACE_RULES
    assert len(column(browser, "changes", "param")) == 12

    click_header(browser, "transactions", "t_total")  # numeric sort, ascending, empty cells last
    totals = [float(v) for v in column(browser, "transactions", "t_total") if v]
    assert totals == sorted(totals) and totals[0] < 5
    click_header(browser, "transactions", "t_total")  # descending
    assert column(browser, "transactions", "t_total")[0] == "310.375"
    assert column(browser, "transactions", "txn")[0] == "14"  # the P971 save with 12 B5
    th = browser.find_element(By.CSS_SELECTOR, "div[data-table='transactions'] th[data-col='t_total']")
    assert th.get_attribute("aria-sort") == "descending"

    type_filter(browser, "transactions", "verdict", "=nak")
    assert column(browser, "transactions", "verdict") == ["nak"] * 7
    type_filter(browser, "transactions", "verdict", "!ok")
    assert sorted(column(browser, "transactions", "verdict")) == ["nak"] * 7 + ["pnio_error", "pnio_error"]
    type_filter(browser, "transactions", "verdict", "")
    type_filter(browser, "transactions", "b5_retries", ">4")
    assert sorted(int(v) for v in column(browser, "transactions", "b5_retries")) == [5, 5, 5, 5, 12]
    type_filter(browser, "transactions", "b5_retries", "")
    type_filter(browser, "changes", "result", "error 0x")  # refused by the drive ("pnio_error" is not one)
    assert len(column(browser, "changes", "param")) == 5
    type_filter(browser, "changes", "result", "!ok")  # and the change given up on a busy drive
    assert column(browser, "changes", "result").count("pnio_error") == 1 and len(column(browser, "changes", "t")) == 6

    type_filter(browser, "transactions", "pnio_error_text", "DE80B500")
    assert column(browser, "transactions", "txn") == ["15"]
    browser.find_element(By.CSS_SELECTOR, "div[data-table='transactions'] tbody a[href='#txn-15']").click()
    WebDriverWait(browser, 5).until(lambda d: d.find_elements(By.CSS_SELECTOR, "#txn-15 .fhead"))  # on hashchange
    details = browser.find_element(By.ID, "txn-15")
    assert details.get_attribute("open") is not None
    heads = [e.text for e in details.find_elements(By.CSS_SELECTOR, ".fhead")]
    assert len(heads) == 8 and heads[0].startswith("Frame 60") and "192.168.1.13 → 192.168.1.23" in heads[0]
    assert "ndr.status.code1" in details.text
    assert console_errors(browser) == []


def test_250000_transaction_report_in_chromium(browser, big_report: tuple[Path, float]) -> None:
    load(browser, big_report[0])
    assert plots_drawn(browser) == 5
    assert len(column(browser, "transactions", "txn")) == html_report.PAGE_SIZE
    type_filter(browser, "transactions", "pnio_error_text", "DE80B500")  # txn 15 of each copy, given up busy
    host = "div[data-table='transactions']"
    assert browser.execute_script(f"return document.querySelector(\"{host}\").dataset.matching") == "556"
    click_header(browser, "transactions", "txn")
    click_header(browser, "transactions", "txn")
    assert int(column(browser, "transactions", "txn")[0]) > int(column(browser, "transactions", "txn")[1])
    assert console_errors(browser) == []


def test_hostile_report_runs_no_injected_script(browser, hostile_report: Path) -> None:
    from selenium.common.exceptions import NoAlertPresentException
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.wait import WebDriverWait

    load(browser, hostile_report)
    browser.find_element(By.CSS_SELECTOR, "#txn-1 > summary").click()
    WebDriverWait(browser, 5).until(lambda d: d.find_element(By.CSS_SELECTOR, "#txn-1 .drill").text)  # on toggle
    drill = browser.find_element(By.CSS_SELECTOR, "#txn-1 .drill").text
    assert HOSTILE in drill  # shown as text
    with pytest.raises(NoAlertPresentException):
        browser.switch_to.alert.text  # noqa: B018
    assert browser.execute_script("return document.scripts.length") == 2
    assert browser.execute_script("return document.querySelectorAll('img:not(.plot), b img').length") == 0
    assert console_errors(browser) == []


def test_screenshot_for_the_readme(browser, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/report_screenshot.png: the fault trace's report as the README shows it: summary, plots, and the
    transactions table filtered to the failed ones (the text summary folded away)."""
    monkeypatch.chdir(REPO)  # the page names the capture as the README's command does
    page = Path(html_report.write(pd_analyze.analyze("sample_pcaps/fault_trace.pcap"), str(tmp_path / "r.html")))
    browser.set_window_size(1400, 2200)
    try:
        load(browser, page)
        assert plots_drawn(browser) == 5
        browser.execute_script("document.querySelector('#summary-text details').open = false")
        type_filter(browser, "transactions", "verdict", "!ok")
        assert len(column(browser, "transactions", "txn")) == 9
        png = browser.get_screenshot_as_png()
    finally:
        browser.set_window_size(1400, 1000)
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 50_000
    SCREENSHOT.parent.mkdir(exist_ok=True)
    if not SCREENSHOT.exists() or SCREENSHOT.read_bytes() != png:
        SCREENSHOT.write_bytes(png)
