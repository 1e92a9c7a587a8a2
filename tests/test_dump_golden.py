"""The dump's output pinned byte for byte: text, JSON Lines and coloured text of every sample capture and of
a generated commissioning capture (`mixed.pcap`: 3,000 frames of the benchmark generator, all PNIO RPC, 30 %
of the transactions faulty).

`tests/dump_golden.json` holds the SHA-256 of `pd-analyze dump` of each capture in each form (what a user gets
on stdout). A change to the dump's formatting must leave these equal unless it means to
change the output; when it does, the exact new lines are asserted by a test of their own, and the digests
are written again with `python tests/test_dump_golden.py` (the diff then names the samples whose output
changed).
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from pd_analyze.cli.base import main

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = sorted(p for p in (ROOT / "sample_pcaps").iterdir() if p.is_file() and p.name != "README.md")
MIXED = "mixed.pcap"
GOLDEN = Path(__file__).with_name("dump_golden.json")
FORMS = {"text": ("--color", "never"), "json": ("--format", "json"), "colour": ("--color", "always")}


def digest(path: Path, form: str) -> str:
    """The SHA-256 of what `dump` writes to stdout for one capture in one form."""
    name = str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)
    result = CliRunner().invoke(main, ["dump", name, *FORMS[form]])
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    return hashlib.sha256(result.stdout_bytes).hexdigest()


def mixed(directory: Path) -> Path:
    from devtools.synth.mixed_capture import make_capture

    path = directory / MIXED
    make_capture(path, 3_000, pnio_share=1.0, faults=0.3)
    return path


def digests(directory: Path) -> dict[str, dict[str, str]]:
    paths = [*SAMPLES, mixed(directory)]
    return {path.name: {form: digest(path, form) for form in FORMS} for path in paths}


@pytest.mark.parametrize("path", SAMPLES, ids=[p.name for p in SAMPLES])
def test_dump_output_is_pinned(path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)
    pinned = json.loads(GOLDEN.read_text())
    assert set(pinned) == {p.name for p in SAMPLES} | {MIXED}, "a sample was added or removed: write them again"
    assert {form: digest(path, form) for form in FORMS} == pinned[path.name]


def test_dump_of_a_generated_capture_is_pinned(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = mixed(tmp_path)
    monkeypatch.chdir(ROOT)
    assert {form: digest(path, form) for form in FORMS} == json.loads(GOLDEN.read_text())[MIXED]


if __name__ == "__main__":  # python tests/test_dump_golden.py: write the digests of the output as it is now
    sys.path.insert(0, str(ROOT))
    import os
    import tempfile

    os.chdir(ROOT)
    with tempfile.TemporaryDirectory() as tmp:
        GOLDEN.write_text(json.dumps(digests(Path(tmp)), indent=1, sort_keys=True) + "\n")
    print(f"wrote {GOLDEN}")
