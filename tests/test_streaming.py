"""The streamed report: files equal to analyze()'s DataFrames in every format, whatever the chunk size;
the summary text of the stream equals summary(analyze()); --jobs and --chain stream the same tables;
rows held in memory stay bounded however long the capture; no pandas on the CSV/JSON path."""

import csv
import json
import math
import os
import random
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import pd_analyze
from pd_analyze.output import report
from pd_analyze.output.spool import FAN_IN, Spool
from pd_analyze.output.summary import quantile
from pd_analyze.output.writers import neutralise

SAMPLES = Path("sample_pcaps")
ALL = sorted(str(p) for p in SAMPLES.glob("*.pcap*"))
TABLES = ("transactions", "parameters", "findings", "changes")


def _settings():
    from pd_analyze.analysis.capture_run import Settings

    return Settings()


def _time(value: pd.Timestamp, digits: int, sep: str) -> str:
    """A capture time with `digits` decimals of a second (cut), from its nanoseconds."""
    fraction = f"{value.value % 10**9:09d}"[:digits]
    return value.strftime(f"%Y-%m-%d{sep}%H:%M:%S") + (f".{fraction}" if digits else "")


def _seconds(value: float, digits: int) -> str:
    """A duration with at most `digits` decimals (the nearest), trailing zeros dropped but one, no exponent."""
    whole, _, decimals = f"{value:.{digits}f}".partition(".")
    return f"{whole}.{decimals.rstrip('0') or '0'}"


def _csv_cell(value: object, digits: int) -> str:
    """A DataFrame cell as the CSV writes it; `digits`: its capture's resolution."""
    if value is pd.NA or value is pd.NaT or value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    if isinstance(value, pd.Timestamp):
        return _time(value, digits, " ") + "+00:00"
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (float, np.floating)):
        return _seconds(float(value), digits)
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return str(neutralise(str(value)))


def _json_value(value: object, digits: int) -> object:
    if value is pd.NA or value is pd.NaT or value is None:
        return None
    if isinstance(value, pd.Timestamp):
        return _time(value, digits, "T") + "Z"
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (float, np.floating)):  # (read back as its text: see assert_files_equal_tables)
        return _seconds(float(value), digits)
    if isinstance(value, (int, np.integer)):
        return int(value)
    return str(value)


def assert_files_equal_tables(out: Path, fmt: str, analysis: pd_analyze.Analysis) -> None:
    """The files hold the DataFrames' cells, each row's times and durations at its capture's resolution."""
    for name in TABLES:
        df: pd.DataFrame = getattr(analysis, name)
        places = [analysis.rows.digits[str(c)] for c in df.capture.astype(object)]  # every capture's is known
        if fmt == "csv":
            with open(out / f"{name}.csv", newline="", encoding="utf-8") as f:
                got = list(csv.reader(f))
            assert got[0] == list(df.columns)
            assert got[1:] == [[_csv_cell(v, d) for v in row]
                               for row, d in zip(df.astype(object).itertuples(index=False), places, strict=True)]
        elif fmt == "json":
            # numbers with a fraction as their text: a duration is written as _seconds writes it
            lines = (out / f"{name}.jsonl").read_text("ascii").splitlines()
            got = [json.loads(line, parse_float=str) for line in lines]
            want = [dict(zip(df.columns, (_json_value(v, d) for v in row), strict=True))
                    for row, d in zip(df.astype(object).itertuples(index=False), places, strict=True)]
            assert got == want
        else:
            back = pd.read_parquet(out / name)
            assert list(back.columns) == [c for c in df.columns if c != "capture"] + ["capture"]
            for col in df.columns:  # the same dtypes back; categoricals hold the same values
                assert str(back[col].dtype) == str(df[col].dtype), col
            # partitioned by the capture's file name (#16), which is what reads back as `capture`
            assert sorted(back.capture.astype(str).unique()) == sorted(
                {os.path.basename(c) for c in df.capture.astype(str).unique()})
            for capture, part in df.groupby("capture", observed=True, sort=False):  # each partition in table order
                mine = back[back.capture.astype(str) == os.path.basename(capture)].reset_index(drop=True)
                theirs = part.reset_index(drop=True)
                for col in df.columns:
                    if col == "capture":  # the file name, compared above
                        continue
                    a, b = mine[col], theirs[col]
                    if isinstance(b.dtype, pd.CategoricalDtype):
                        assert list(a.dtype.categories) == list(b.dtype.categories) or not b.dtype.ordered
                        a, b = a.astype(object), b.astype(object)
                    pd.testing.assert_series_equal(a, b, check_names=False, check_categorical=False)


@pytest.fixture(scope="module")
def samples() -> pd_analyze.Analysis:
    return pd_analyze.analyze(ALL)


@pytest.mark.parametrize("fmt", ["csv", "json", "parquet"])
@pytest.mark.parametrize("chunk_rows", [3, report.CHUNK_ROWS])
def test_streamed_files_equal_the_dataframes(tmp_path, samples, fmt, chunk_rows):
    streamed = report.stream(ALL, str(tmp_path), fmt, _settings(), chunk_rows=chunk_rows)
    assert_files_equal_tables(tmp_path, fmt, samples)
    assert streamed.summary == report.summary(samples)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        f"{n}.{'jsonl' if fmt == 'json' else fmt}" if fmt != "parquet" else n for n in TABLES)  # no spill left


@pytest.mark.parametrize("fmt", ["csv", "json"])
def test_chunk_boundaries_do_not_change_the_files(tmp_path, fmt):
    outs = []
    for chunk_rows in (1, 2, 7, 100_000):
        out = tmp_path / str(chunk_rows)
        report.stream(ALL, str(out), fmt, _settings(), chunk_rows=chunk_rows)
        outs.append({p.name: p.read_bytes() for p in out.iterdir()})
    assert all(o == outs[0] for o in outs)


def test_write_tables_of_an_analysis_equals_the_stream(tmp_path, samples):
    report.write_tables(samples, str(tmp_path / "a"), "csv")
    report.stream(ALL, str(tmp_path / "b"), "csv", _settings(), chunk_rows=5)
    for name in TABLES:
        assert (tmp_path / "a" / f"{name}.csv").read_bytes() == (tmp_path / "b" / f"{name}.csv").read_bytes()


@pytest.mark.parametrize("path", ALL)
def test_streamed_summary_equals_summary_of_analyze(tmp_path, path):
    streamed = report.stream([path], str(tmp_path), "csv", _settings(), chunk_rows=2)
    assert streamed.summary == report.summary(pd_analyze.analyze(path))


def test_summary_text_of_the_readme_example(tmp_path):
    files = [str(SAMPLES / n) for n in ("worked_example.pcap", "record_rw_le.pcap", "truncated_snaplen.pcap",
                                        "write_multiple.pcap")]
    text = report.stream(files, str(tmp_path), "csv", _settings()).summary
    readme = Path("README.md").read_text(encoding="utf-8")
    block = readme.split("`pd-analyze report sample_pcaps/worked_example.pcap")[1].split("```\n")[1]
    assert text + "\n" == block


def test_ranked_lists_break_ties_by_key(tmp_path):
    """Equal counts are listed in key order (pandas' default sort is not stable: it was arbitrary)."""
    text = report.stream([str(SAMPLES / "pd_out_of_range.pcap")], str(tmp_path), "csv", _settings()).summary
    findings = text.split("Findings: ")[1].splitlines()[1:]
    counted = [(-int(line.split()[0]), line.split(None, 1)[1]) for line in findings]
    assert counted == sorted(counted)


def test_quantile_matches_numpy_bit_for_bit():
    rng = random.Random(7)
    for n in (1, 2, 3, 10, 101, 1000):
        values = sorted(rng.uniform(0.0001, 0.05) for _ in range(n))
        for q in (0.5, 0.9, 0.99, 0.0, 1.0, 0.25):
            assert quantile(values, q) == float(np.quantile(np.array(values), q))


def test_jobs_and_chain_stream_the_same_tables(tmp_path):
    files = ALL[:8]
    for jobs, chain in ((2, False), (1, True)):
        analysis = pd_analyze.analyze(files, jobs=jobs, chain=chain)
        out = tmp_path / f"{jobs}-{chain}"
        streamed = report.stream(files, str(out), "csv", _settings(), jobs=jobs, chain=chain, chunk_rows=3)
        assert_files_equal_tables(out, "csv", analysis)
        assert streamed.summary == report.summary(analysis)


def test_audit_streams_findings_by_capture_and_frame(samples):
    rows, captures = report.stream_findings(ALL, _settings(), chunk_rows=2)
    got = [(r[0], r[1], r[2], r[3], r[10]) for r in rows]
    f = samples.findings.sort_values(["capture", "frame"], kind="stable")
    want = [(str(r.capture), int(r.frame), None if pd.isna(r.txn) else int(r.txn), str(r.severity), r.message)
            for r in f.itertuples()]
    assert got == want and len(captures) == len(ALL)


def test_rows_held_stay_bounded_while_a_long_capture_streams(tmp_path):
    """Not timed: with 64 rows per table allowed in memory, a capture of thousands of transactions is
    written with never more than a small multiple of 64 rows held, and the files are still exact."""
    from devtools.synth.mixed_capture import make_capture

    path = tmp_path / "mixed.pcap"
    make_capture(path, 40_000, pnio_share=0.5)
    out = tmp_path / "out"
    streamed = report.stream([str(path)], str(out), "csv", _settings(), chunk_rows=64)
    analysis = pd_analyze.analyze(str(path))
    assert len(analysis.transactions) > 2_000 and len(analysis.parameters) > 2_000
    assert max(streamed.peak_held.values()) <= 2 * 64
    assert_files_equal_tables(out, "csv", analysis)


def test_spool_sorts_stably_in_bounded_memory(tmp_path):
    rng = random.Random(3)
    rows = [(rng.randrange(200), i) for i in range(5_000)]  # heavily out of order: many runs, merged in steps
    spool = Spool(lambda r: r[0], memory_rows=20, tmp_dir=str(tmp_path))
    spool.extend(rows)
    assert len(spool._runs) > FAN_IN
    got = [r for chunk in spool.chunks(33) for r in chunk]
    assert got == sorted(rows, key=lambda r: r[0])
    assert spool.peak_held <= 2 * 20 + FAN_IN
    assert list(tmp_path.iterdir()) == []  # spill files removed


@pytest.mark.parametrize("fmt", ["csv", "json"])
def test_csv_and_json_report_do_not_load_the_plots_or_the_html(tmp_path, fmt):
    """The engine builds its tables with pyarrow (which loads pandas on its first conversion of Python
    values), so every report has them; matplotlib and the HTML page's modules only `--format html` loads."""
    code = ("import sys; from pd_analyze.cli import main; sys.argv = ['pd-analyze', 'report', "
            f"'{SAMPLES / 'fault_trace.pcap'}', '--out', '{tmp_path}', '--format', '{fmt}']\n"
            "try:\n    main()\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'matplotlib' or m in "
            "('pd_analyze.output.plots', 'pd_analyze.output.html_report', 'pd_analyze.output.html_plots', "
            "'pd_analyze.output.html_tables')), file=sys.stderr)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stderr.splitlines()[-1] == "[]"
    assert "Transactions: 62" in r.stdout

