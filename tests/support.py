"""Helpers shared by the test modules: what a test needs from the machine (tshark, Chromium)."""

from __future__ import annotations

import os
from typing import NoReturn

import pytest


def in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


def unavailable(message: str) -> NoReturn:
    """A test's tool is missing: skipped on a developer's machine, a failure in CI (nothing is skipped there)."""
    if in_ci():
        pytest.fail(f"{message} -- CI is set, and this test must not be skipped in CI", pytrace=False)
    pytest.skip(message)
