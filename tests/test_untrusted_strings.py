"""Nothing from a capture executes: sample_pcaps/crafted_strings.pcap carries markup and script, terminal
control sequences and spreadsheet formulas in its text arrays, descriptions and values. Each output shows
them inertly: the terminal (dump text and JSON, audit, report summary), the CSV files, the HTML report (in
headless Chromium: no script of the capture runs). Profiles are TOML data, never code.

HTML in the browser: skipped with an install hint when Chromium is missing on a developer's machine, a
failure when CI is set (as tests/test_html_report.py). Without pd_analyze/html_report.py the HTML part skips.
"""

from __future__ import annotations

import ast
import csv
import importlib.util
import json
import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import pytest

from devtools.synth import trace_samples
from pd_analyze.protocol import profiles

REPO = Path(__file__).resolve().parents[1]
CRAFTED = REPO / "sample_pcaps" / "crafted_strings.pcap"
HTML_MODULE = importlib.util.find_spec("pd_analyze.output.html_report") is not None
# What the capture carries (exactly as the sample generator writes it)
MARKUP = ("<script>alert(1)", '"><img src=x onerror=alert(2)>', "javascript:alert(3)", "' onmouseover='alert(4)",
          "<svg/onload=a()>")
CONTROL = ("\x1b[31m", "\x1b]0;pwned\x07", "\x9b2J", "\r", "\x08", "\u202e", "\u2028")
FORMULAS = ("=cmd|' /C calc'!A0", "+SUM(1,2)", "-2+3", "@SUM(1,2)", "\t=1+2", "\r=1+2", "=1+1", "+1-1", "-1+1",
            "@A1", "\t@A1", "\r-1")
FORMULA_START = re.compile(r"^[=+\-@\t\r]")
NUMBER = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$")


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pd_analyze.cli", *args], capture_output=True, timeout=300,
                          cwd=REPO)


def test_the_sample_is_generated_and_carries_every_string() -> None:
    data = trace_samples.crafted_strings()
    assert CRAFTED.read_bytes() == data
    raw = data.decode("latin-1")
    for text in MARKUP + CONTROL[:5] + FORMULAS:
        assert text in raw or text.encode("utf-16-be").decode("latin-1") in raw, text
    assert "\u202eevil\u2028x".encode("utf-16-be").decode("latin-1") in raw  # UnicodeString, UCS-2 BE


def inert(text: str) -> list[str]:
    """Lines of terminal output holding a character a terminal would act on (anything not printable)."""
    return [line for line in text.split("\n") if not line.isprintable()]


@pytest.mark.parametrize("args", [("dump",), ("dump", "--color"), ("dump", "--findings-only"),
                                  ("audit", "--fail-on", "never")])
def test_terminal_output_shows_control_characters_escaped(args: tuple[str, ...]) -> None:
    r = run(args[0], str(CRAFTED), *args[1:])
    out, err = r.stdout.decode("utf-8"), r.stderr.decode("utf-8")
    assert r.returncode == 0, err
    if "--color" not in args:
        assert inert(out) == [] and inert(err) == []
    else:  # only our own colour codes: SGR sequences around our own labels, never one from the capture
        stripped = re.sub(r"\x1b\[[0-9;]*m", "", out)
        assert inert(stripped) == [] and "\x1b]" not in out and "\x1b[31mRED" not in out
    if args == ("dump",):
        for shown in (r"\x1b[31mRED\x1b[0m\x1b]0;pwned\x07", r"\x9b2J\rOVER\x08WRITTEN", r"\u202eevil\u2028x",
                      "<script>alert(1)</script><b>x</b", "<svg/onload=a()>", "1b 5b 32 4a 3c 73 63 72"):
            assert shown in out, shown


def test_json_lines_are_ascii_and_keep_the_exact_strings() -> None:
    r = run("dump", str(CRAFTED), "--format", "json")
    assert r.returncode == 0 and r.stdout.isascii()
    shows = [f["show"] for line in r.stdout.decode().splitlines() for f in json.loads(line)["fields"]]
    assert any('"><img src=x onerror=alert(2)>' in s for s in shows)
    assert any("javascript:alert(3)" in s for s in shows)


def test_report_summary_and_tables(tmp_path: Path) -> None:
    r = run("report", str(CRAFTED), "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert inert(r.stdout.decode()) == [] and "Transactions: 5  ok=3  nak=2" in r.stdout.decode()
    cells = []
    for name in ("transactions", "parameters", "findings", "changes"):
        with open(tmp_path / f"{name}.csv", newline="", encoding="utf-8") as f:
            cells += [c for row in csv.reader(f) for c in row]
    dangerous = [c for c in cells if FORMULA_START.match(c) and not NUMBER.match(c)]
    assert dangerous == []  # no cell a spreadsheet would evaluate
    for formula in ("=cmd|' /C calc'!A0",):  # quoted in its cell (it has a space), so the cell starts with "
        assert f'"{formula}"' in cells
    for formula in ("+SUM(1,2)", "-2+3", "@SUM(1,2)", "=1+1", "+1-1", "-1+1", "@A1"):
        assert "'" + formula in cells, formula  # neutralised with a leading apostrophe
    assert "'\\t=1+2'" in cells and "'\\r-1'" in cells  # control characters shown escaped, quoted


def test_profiles_are_data_never_code(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    marker = tmp_path / "ran"
    code = tmp_path / "evil.toml"
    code.write_text(f'__import__("os").system("touch {marker}")\n')
    with pytest.raises(profiles.ProfileError, match="not valid TOML"):
        profiles.load(str(code))
    py = tmp_path / "evil.py"
    py.write_text(f'open("{marker}", "w").write("x")\n')
    monkeypatch.setenv(profiles.ENV_DIR, str(tmp_path))
    assert "evil" in profiles.packaged()  # the .toml is listed (and refused when loaded), the .py never
    with pytest.raises(profiles.ProfileError):
        profiles.load("evil")
    r = run("profiles")
    assert r.returncode == 2 or "evil" not in r.stdout.decode()
    assert not marker.exists()
    for path in sorted((REPO / "pd_analyze").rglob("*.py")):  # no code path can run text as code
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Call):
                name = ast.unparse(node.func)
                assert name not in ("eval", "exec", "compile", "__import__", "os.system", "os.popen",
                                    "pickle.load", "pickle.loads", "marshal.loads", "yaml.load"), (path, name)
                assert not any(k.arg == "shell" for k in node.keywords), (path, name)


# --- the HTML report -------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def crafted_html(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if not HTML_MODULE:
        pytest.skip("pd_analyze/html_report.py not present: the HTML checks run once it exists")
    out = tmp_path_factory.mktemp("crafted")
    r = run("report", str(CRAFTED), "--format", "html", "--out", str(out))
    assert r.returncode == 0, r.stderr
    return out / "report.html"


class _Tags(HTMLParser):
    """Every start tag with its attributes, and the text outside script and style elements."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, list[tuple[str, str | None]]]] = []
        self.text: list[str] = []
        self._skip = 0

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append((tag, attrs))
        self._skip += tag in ("script", "style")

    def handle_endtag(self, tag: str) -> None:
        self._skip -= tag in ("script", "style")

    def handle_data(self, data: str) -> None:
        if not self._skip:
            self.text.append(data)


def test_html_escapes_every_capture_string(crafted_html: Path) -> None:
    page = crafted_html.read_text(encoding="utf-8")
    parser = _Tags()
    parser.feed(page)
    scripts = [attrs for tag, attrs in parser.tags if tag == "script"]
    assert len(scripts) == 2  # the page's own script and its JSON data, nothing from the capture
    assert [tag for tag, _ in parser.tags if tag in ("img", "svg", "iframe", "object", "embed")] == [
        "img"] * 5  # the five plots only
    for tag, attrs in parser.tags:
        for name, value in attrs:
            assert not name.startswith("on"), (tag, name)  # no event handler attribute
            assert not (value or "").strip().lower().startswith(("javascript:", "vbscript:")), (tag, name)
    for text in MARKUP:
        if "<" in text or '"' in text:
            assert text not in page  # raw markup never reaches the page: escaped, or \\u-escaped in the JSON
    assert "\x1b" not in page and "\x9b" not in page


def test_html_runs_no_capture_script_in_chromium(crafted_html: Path, browser) -> None:
    from selenium.common.exceptions import NoAlertPresentException
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.wait import WebDriverWait

    driver = browser
    driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": (
        "window.__fired = [];"
        "for (const name of ['alert', 'confirm', 'prompt']) {"
        "  window[name] = (...a) => { window.__fired.push(name + ':' + a.join(',')); };"
        "}")})
    driver.get(crafted_html.resolve().as_uri())
    WebDriverWait(driver, 15).until(lambda d: d.execute_script("return document.body.dataset.ready") == "1")
    for summary in driver.find_elements(By.CSS_SELECTOR, "details[data-txn] > summary"):
        summary.click()  # open every drill-down: the failed transactions' fields, values included
    WebDriverWait(driver, 5).until(lambda d: all(
        e.text for e in d.find_elements(By.CSS_SELECTOR, "details[data-txn] .drill")))
    for box in driver.find_elements(By.CSS_SELECTOR, "input[data-col]"):
        box.send_keys("<")  # filtering re-renders the tables from the data
        box.clear()
    text = driver.execute_script("return document.body.innerText")
    for shown in ('"><img src=x onerror=alert(2)>', "' onmouseover='alert(4)", "javascript:alert(3)"):
        assert shown in text, shown  # shown as text ...
    assert driver.execute_script("return window.__fired") == []  # ... and never run
    with pytest.raises(NoAlertPresentException):
        driver.switch_to.alert.text  # noqa: B018
    assert driver.execute_script("return document.scripts.length") == 2
    assert driver.execute_script(
        "return [...document.querySelectorAll('*')].flatMap(e => [...e.attributes])"
        ".filter(a => a.name.startsWith('on') || /^\\s*javascript:/i.test(a.value)).length") == 0
    assert driver.execute_script("return document.querySelectorAll('img:not(.plot), svg script').length") == 0
    errors = [e["message"] for e in driver.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]
    assert errors == []
