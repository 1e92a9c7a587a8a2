"""Shared pytest hooks."""

from __future__ import annotations

import sys

import pytest


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """After a run of the tshark conformance test: which named rules accepted how many differences."""
    module = sys.modules.get("tests.test_tshark_conformance")
    used = getattr(module, "RULE_USE", None)
    if not used:
        return
    terminalreporter.section("tshark conformance: differences accepted by named rules (protocol.md 8)")
    for name, count in sorted(used.items()):
        terminalreporter.write_line(f"{count:6d}  {name}")
