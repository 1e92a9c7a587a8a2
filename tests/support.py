"""Helpers shared by the test modules: what a test needs from the machine (tshark, Chromium) and from
beside the repository (the real public captures of ../shared/captures)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import NoReturn

import pytest


def in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


def unavailable(message: str) -> NoReturn:
    """A test's tool is missing: skipped on a developer's machine, a failure in CI (nothing is skipped there)."""
    if in_ci():
        pytest.fail(f"{message} -- CI is set, and this test must not be skipped in CI", pytrace=False)
    pytest.skip(message)


# The real public captures sit beside the repository in CI (../shared/captures) and are absent from a clone of
# the project alone. Only this module names that directory (tests/test_architecture.py holds every other test
# module to it): a test that globs it gets nothing when it is absent, a test that needs one of its files skips
# with the reason. What the project promises is also tested on a capture of sample_pcaps/.
SHARED_CAPTURES = Path(__file__).resolve().parents[2] / "shared" / "captures"


def shared_captures(patterns: tuple[str, ...] = ("*.pcap", "*.pcapng", "*.gz")) -> list[Path]:
    """The shared captures matching `patterns`, sorted; none when the directory is absent."""
    if not SHARED_CAPTURES.is_dir():
        return []
    return sorted({p for pattern in patterns for p in SHARED_CAPTURES.glob(pattern) if p.is_file()})


def shared_capture(name: str) -> Path:
    """One shared capture; the test is skipped, with the reason, when it is absent (a plain clone)."""
    path = SHARED_CAPTURES / name
    if not path.is_file():
        pytest.skip(f"{path} absent: the shared real-world captures are beside the repository in CI, not in a "
                    "clone of the project alone")
    return path
