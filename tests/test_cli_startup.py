"""Start-up of `pd-analyze report` (issue #23): a streamed report loads none of what it does not use.

pandas (0.2 s: pyarrow's first conversion of a Python value asked for it), the notebook API, the dump, pyarrow's
query engine (the summary's group counts) and dpkt (its package loads every protocol module; a classic pcap
does not need it) once made a 10-frame report take 0.6 s. Each run here is a fresh interpreter, as a user's
is."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_pcaps" / "fault_trace.pcap"
NOT_LOADED = ("pandas", "pd_analyze.analysis.api", "pd_analyze.output.dump", "dpkt", "pd_analyze.capture.pcapng",
              "pyarrow.acero", "pyarrow.dataset")

_RUN = """
import sys
sys.argv = ["pd-analyze", *sys.argv[1:]]
from pd_analyze.cli import main
try:
    main()
except SystemExit as exc:
    code = exc.code
print("LOADED", sorted(m for m in {names!r} if m in sys.modules), "EXIT", code, file=sys.stderr)
"""


def _run(*args: str) -> tuple[str, list[str]]:
    done = subprocess.run([sys.executable, "-c", _RUN.format(names=NOT_LOADED), *args], cwd=REPO,
                          capture_output=True, text=True, timeout=120, check=False)
    return done.stdout, done.stderr.splitlines()


def test_a_csv_report_loads_neither_pandas_nor_the_api_dump_or_dpkt(tmp_path: Path) -> None:
    stdout, stderr = _run("report", str(SAMPLE), "--out", str(tmp_path))
    assert stderr[-1] == "LOADED [] EXIT 0"
    assert stdout.splitlines()[0] == (f"{SAMPLE}: 408 frames read = 408 decoded + 0 skipped + 0 malformed; "
                                      "62 transactions")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["changes.csv", "findings.csv", "parameters.csv",
                                                          "transactions.csv"]


def test_a_json_report_loads_no_pandas_either_parquet_does(tmp_path: Path) -> None:
    """Parquet's schema carries the pandas metadata of an empty DataFrame (read back as the API's dtypes)."""
    _, stderr = _run("report", str(SAMPLE), "--out", str(tmp_path / "json"), "--format", "json")
    assert stderr[-1] == "LOADED [] EXIT 0"
    _, stderr = _run("report", str(SAMPLE), "--out", str(tmp_path / "parquet"), "--format", "parquet")
    assert stderr[-1] == "LOADED ['pandas'] EXIT 0"


def test_audit_loads_no_pandas_either() -> None:
    """audit runs in pipelines once per capture: its start-up is a report's (with --expect the parameter state
    is a DataFrame)."""
    stdout, stderr = _run("audit", str(SAMPLE), "--fail-on", "never")
    assert stderr[-1] == "LOADED [] EXIT 0"
    assert stdout.splitlines()[-1] == "10 findings in 1 capture: 0 error, 2 warning, 8 info"


def test_a_pcapng_loads_dpkt_where_it_is_read_and_still_no_pandas(tmp_path: Path) -> None:
    _, stderr = _run("report", str(REPO / "sample_pcaps" / "two_interfaces.pcapng"), "--out", str(tmp_path))
    assert stderr[-1] == "LOADED ['dpkt', 'pd_analyze.capture.pcapng'] EXIT 0"


def test_pyarrow_still_builds_dataframes_after_the_probe_was_answered() -> None:
    """without_pandas leaves pandas importable, and pyarrow's to_pandas and pandas inputs working."""
    code = ("import sys; from pd_analyze.cli.base import without_pandas; without_pandas(); "
            "print('pandas' in sys.modules); import pyarrow as pa; "
            "df = pa.table({'t': pa.array([1, 2], pa.timestamp('ns', tz='UTC'))}).to_pandas(); "
            "print(str(df.t.dtype), df.t.iloc[1].value); import pandas as pd; "
            "print(pa.array(pd.Series([1, None], dtype='Int64')).to_pylist())")
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120,
                          check=True)
    assert done.stdout.splitlines() == ["False", "datetime64[ns, UTC] 2", "[1, None]"]


def test_the_command_line_keeps_openblas_to_one_thread_unless_the_user_says_otherwise() -> None:
    """Set before numpy is imported (its OpenBLAS starts a thread per core then: the command line's own import
    loads no numpy, the command's modules do); a user's setting is kept."""
    code = "import os, sys; import pd_analyze.cli; print(os.environ['OPENBLAS_NUM_THREADS'], 'numpy' in sys.modules)"
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    for given, expected in ((None, "1 False"), ("4", "4 False")):
        run_env = env if given is None else {**env, "OPENBLAS_NUM_THREADS": given}
        done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120,
                              check=True, env=run_env)
        assert done.stdout.strip() == expected
