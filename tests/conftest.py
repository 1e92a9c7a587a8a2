"""Shared pytest hooks."""

from __future__ import annotations

import shutil
import sys

import pytest

from tests.support import unavailable


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """After a run of the tshark conformance test: which named rules accepted how many differences."""
    module = sys.modules.get("tests.test_tshark_conformance")
    used = getattr(module, "RULE_USE", None)
    if not used:
        return
    terminalreporter.section("tshark conformance: differences accepted by named rules (protocol.md 8)")
    for name, count in sorted(used.items()):
        terminalreporter.write_line(f"{count:6d}  {name}")


CHROMIUM_FLAGS = ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--disable-dev-shm-usage", "--hide-scrollbars", "--force-device-scale-factor=1")
CHROMIUM_HINT = ("headless Chromium not found: apt-get install chromium chromium-driver "
                 "(and pip install -e '.[dev]' for selenium)")


@pytest.fixture(scope="module")
def browser(tmp_path_factory: pytest.TempPathFactory):
    """Headless Chromium through selenium, one per test module (the HTML report's browser tests)."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_path = shutil.which("chromedriver")
    try:
        from selenium import webdriver
    except ImportError:
        webdriver = None
    if not chromium or not driver_path or webdriver is None:
        unavailable(CHROMIUM_HINT)
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for flag in CHROMIUM_FLAGS:
        options.add_argument(flag)
    options.add_argument(f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}")
    options.add_argument("--window-size=1400,1000")
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=webdriver.ChromeService(executable_path=driver_path))
    driver.set_page_load_timeout(30)
    yield driver
    driver.quit()
