"""The allocator measures of engine.allocator: the command line's pyarrow pool and the heap given back."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

from pd_analyze.analysis.engine import allocator

SAMPLE = Path(__file__).resolve().parent.parent / "sample_pcaps" / "fault_trace.pcap"


def test_the_system_pool_is_preferred_unless_the_user_chose(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ARROW_DEFAULT_MEMORY_POOL", raising=False)
    allocator.prefer_system_pool()
    assert os.environ["ARROW_DEFAULT_MEMORY_POOL"] == "system"
    monkeypatch.setenv("ARROW_DEFAULT_MEMORY_POOL", "jemalloc")
    allocator.prefer_system_pool()
    assert os.environ["ARROW_DEFAULT_MEMORY_POOL"] == "jemalloc"


def _backend_after_report(tmp_path: Path, env_pool: str | None) -> str:
    """pyarrow's pool in a process that ran `pd-analyze report` of a sample, as the console script runs it
    (pyarrow imported only by the command: the CLI sets the environment before anything imports it)."""
    argv = ["pd-analyze", "report", str(SAMPLE), "--out", str(tmp_path / "out")]
    code = (f"import sys\nfrom pd_analyze.cli import main\nsys.argv = {argv!r}\n"
            "try:\n    main()\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
            "import pyarrow\nprint(pyarrow.default_memory_pool().backend_name)\n")
    env = {k: v for k, v in os.environ.items() if k != "ARROW_DEFAULT_MEMORY_POOL"}
    if env_pool is not None:
        env["ARROW_DEFAULT_MEMORY_POOL"] = env_pool
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert r.returncode == 0, r.stderr
    return r.stdout.split()[-1]


def test_the_command_line_runs_pyarrow_on_the_system_pool(tmp_path: Path) -> None:
    assert _backend_after_report(tmp_path, None) == "system"


def test_a_users_pool_choice_is_kept(tmp_path: Path) -> None:
    import pyarrow as pa

    available = pa.supported_memory_backends()
    other = next((b for b in ("mimalloc", "jemalloc") if b in available), None)
    if other is None:
        pytest.skip(f"this pyarrow offers no pool but the system's: {available}")
    assert _backend_after_report(tmp_path, other) == other


def test_the_heap_is_given_back_where_the_c_library_can() -> None:
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        pytest.skip(f"malloc_trim is glibc's; this is {platform.system()} {platform.libc_ver()}")
    assert allocator._trim() is not None
    allocator.give_back()  # (returns nothing: what it does shows only in the resident set)
