"""`dump - -T fields` (standard input) reads the capture as batches, as a file is read: its lines are the
file's, byte for byte, every frame and every record field included (the per-frame path it took before printed
only the PNIO RPC frames of standard input, with no record fields and times from floats)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from pd_analyze.cli.base import main
from tests.test_dump_columns import SAMPLE_FILES

FIELDS = ["-e", "frame.number", "-e", "frame.time_epoch", "-e", "frame.iface", "-e", "frame.caplen", "-e", "ip.src",
          "-e", "pd.ref", "-e", "pd.addr.pnu", "-e", "pd.val.value"]
CAPTURES = [p for p in SAMPLE_FILES if p.suffix in (".pcap", ".pcapng", ".gz")]


def _from_file(path: Path, *args: str) -> tuple[bytes, int]:
    r = CliRunner().invoke(main, ["dump", str(path), "-T", "fields", *FIELDS, *args])
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    return r.stdout_bytes, r.exit_code


def _from_stdin(path: Path, *args: str) -> tuple[bytes, int]:
    r = subprocess.run([sys.executable, "-m", "pd_analyze.cli", "dump", "-", "-T", "fields", *FIELDS, *args],
                       input=path.read_bytes(), capture_output=True, timeout=120)
    return r.stdout, r.returncode


@pytest.mark.parametrize("path", CAPTURES, ids=[p.name for p in CAPTURES])
def test_standard_input_prints_the_files_lines(path: Path) -> None:
    args = ("-Y", "pd.ref or frame.number < 5 or frame.iface == 1", "-E", "header=y")
    from_file = _from_file(path, *args)
    assert from_file[0].count(b"\n") >= 2, path.name
    assert _from_stdin(path, *args) == from_file, path.name


def test_analysis_fields_on_standard_input_are_refused_as_before() -> None:
    """txn.* needs the capture read twice: standard input is refused with the reason (exit 2)."""
    data = (Path(__file__).resolve().parents[1] / "sample_pcaps" / "pd_negative.pcap").read_bytes()
    r = subprocess.run([sys.executable, "-m", "pd_analyze.cli", "dump", "-", "-T", "fields", "-e", "txn.id"],
                       input=data, capture_output=True, timeout=120)
    assert r.returncode == 2 and b"give a file, not - (standard input)" in r.stderr, r.stderr
