"""The columnar report end against today's row path: batches (analysis/table_batches), their CSV, JSON
and Parquet files (writers.write_batch), the ordered sink (output/table_sink) and the summary from
batches (Summary.add_batch) give exactly what the rows give, whatever order the batches come in.

The reference is always today's code on the same rows: schema.frame_of, the writers' write(rows) on
the rows sorted stably by schema.sort_key (in the order they reached the sink), Summary.add."""

from __future__ import annotations

import csv
import json
import math
import random
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import pd_analyze
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.analysis.schema import COLUMNS, ROW_TYPES, SORT_COLUMN, frame_of, sort_key
from pd_analyze.analysis.table_batches import batch_schema, conform, frame_from_batches, rows_to_batch
from pd_analyze.model.times import NS
from pd_analyze.model.times import duration_text as duration_of
from pd_analyze.output import report
from pd_analyze.output.batch_cells import duration_text, int_text, row_digits, time_text
from pd_analyze.output.summary import Summary
from pd_analyze.output.table_sink import FAN_IN, TableSink
from pd_analyze.output.writers import csv_time, json_time, open_table
from tests.support import table_rows
from tests.test_streaming import assert_files_equal_tables

SAMPLES = Path("sample_pcaps")
ALL = sorted(str(p) for p in SAMPLES.glob("*.pcap*"))
TABLES = report.TABLES
SUFFIX = {"csv": ".csv", "json": ".jsonl", "parquet": ""}


@pytest.fixture(scope="module")
def samples() -> pd_analyze.Analysis:
    return pd_analyze.analyze(ALL)


def _batches(name: str, rows: list[tuple], rng: random.Random, size: int = 13,
             whole_keys: bool = False) -> list[list[tuple]]:
    """The rows cut into batches of 1 to size - 1 rows, the batches shuffled (out of txn or frame order).
    `whole_keys` puts all the rows of one sort key in one batch, in their order, so rows that tie keep their
    order: also those of several captures that tie (findings of the same frame number in two files), which
    are not next to each other in the rows."""
    col = list(ROW_TYPES[name]._fields).index(SORT_COLUMN[name])
    if whole_keys:  # rows that tie need not be neighbours (frame 6 of two captures): bring them together first
        groups: dict[object, list[tuple]] = {}
        for r in rows:
            groups.setdefault(r[col], []).append(r)
        rows = [r for g in groups.values() for r in g]
    batches, start = [], 0
    while start < len(rows):
        end = min(len(rows), start + rng.randrange(1, size))
        while whole_keys and end < len(rows) and rows[end][col] == rows[end - 1][col]:
            end += 1
        batches.append(rows[start:end])
        start = end
    rng.shuffle(batches)
    return batches


def _watermark(name: str, rest: list[list[tuple]], by_capture: bool) -> object:
    """The smallest key still to come (None: nothing left that bounds it): what the analysis would know.
    By capture, a row without a key still holds its capture back: (capture, inf)."""
    col = list(ROW_TYPES[name]._fields).index(SORT_COLUMN[name])
    if by_capture:
        keys = [(r.capture, math.inf if r[col] is None else r[col]) for b in rest for r in b]
    else:
        keys = [r[col] for b in rest for r in b if r[col] is not None]
    return min(keys) if keys else None


def _feed(sink: TableSink, name: str, batches: list[list[tuple]], by_capture: bool = False,
          every: int = 2) -> list[tuple]:
    """The batches into the sink, flushed at the watermark every `every` batches; the rows as they came."""
    arrived = []
    for k, b in enumerate(batches):
        sink.add(rows_to_batch(name, b))
        arrived += b
        if k % every == every - 1:
            watermark = _watermark(name, batches[k + 1:], by_capture)
            if watermark is not None:
                sink.flush(watermark)
    sink.close()
    return arrived


def _today(out: Path, name: str, fmt: str, rows: list[tuple], by_capture: bool = False,
           digits: dict[str, int] | None = None) -> Path:
    """Today's file of these rows (in the order they came): sorted stably, written row by row; `digits`: each
    capture's resolution."""
    out.mkdir(parents=True, exist_ok=True)
    writer = open_table(str(out), name, fmt, digits)
    ordered = sorted(rows, key=sort_key(name, by_capture))
    for i in range(0, len(ordered), 100):
        writer.write(ordered[i:i + 100])
    return Path(writer.close())


def _assert_same_files(a: Path, b: Path, fmt: str) -> None:
    if fmt == "parquet":
        for part in sorted(p.relative_to(a) for p in a.rglob("*.parquet")):
            assert pq.read_schema(a / part).equals(pq.read_schema(b / part), check_metadata=True), part
        assert sorted(p.relative_to(a) for p in a.rglob("*")) == sorted(p.relative_to(b) for p in b.rglob("*"))
        mine, theirs = pd.read_parquet(a), pd.read_parquet(b)
        assert [str(t) for t in mine.dtypes] == [str(t) for t in theirs.dtypes]
        for col in mine.columns:  # a categorical's categories come in the order its chunks met them
            if isinstance(mine[col].dtype, pd.CategoricalDtype) and not mine[col].dtype.ordered:
                mine[col], theirs[col] = mine[col].astype(object), theirs[col].astype(object)
        pd.testing.assert_frame_equal(mine, theirs)
        return
    assert a.read_bytes() == b.read_bytes()
    if fmt == "csv":
        with a.open(newline="", encoding="utf-8") as f, b.open(newline="", encoding="utf-8") as g:
            assert list(csv.reader(f)) == list(csv.reader(g))


# --- batches and DataFrames -------------------------------------------------------------------------

def test_batch_schema_types_every_column():
    kinds = {"Int64": pa.int64(), "string": pa.large_string(), "category": pa.large_string(),
             "Float64": pa.float64(), "boolean": pa.bool_(), "datetime64[ns, UTC]": pa.timestamp("ns", tz="UTC"),
             "category:verdict": pa.large_string(), "category:severity": pa.large_string()}
    for name in TABLES:
        schema = batch_schema(name)
        assert schema.names == [c.name for c in COLUMNS[name]]
        assert [f.type for f in schema] == [kinds[c.dtype] for c in COLUMNS[name]]
        assert all(f.nullable for f in schema)


@pytest.mark.parametrize("name", TABLES)
def test_frame_from_batches_equals_frame_of(samples, name):
    rows = table_rows(samples.rows, name)
    want = frame_of(name, rows)
    pd.testing.assert_frame_equal(frame_from_batches(name, [rows_to_batch(name, rows)]), want)
    rng = random.Random(len(rows))
    cuts = sorted(rng.sample(range(1, len(rows)), min(9, len(rows) - 1)))
    pieces = [rows[a:b] for a, b in zip([0, *cuts], [*cuts, len(rows)], strict=True)]  # in order, uneven
    pd.testing.assert_frame_equal(frame_from_batches(name, [rows_to_batch(name, p) for p in pieces]), want)


@pytest.mark.parametrize("name", TABLES)
def test_frame_from_batches_sorts_batches_that_came_out_of_order(samples, name):
    batches = _batches(name, table_rows(samples.rows, name), random.Random(name))
    arrived = [r for b in batches for r in b]
    got = frame_from_batches(name, [rows_to_batch(name, b) for b in batches])
    pd.testing.assert_frame_equal(got, frame_of(name, arrived))


@pytest.mark.parametrize("name", TABLES)
def test_frame_from_batches_of_nothing_and_of_missing_columns(samples, name):
    pd.testing.assert_frame_equal(frame_from_batches(name, []), frame_of(name, []))
    pd.testing.assert_frame_equal(frame_from_batches(name, [rows_to_batch(name, [])]), frame_of(name, []))
    row = ROW_TYPES[name]._make([None] * len(COLUMNS[name]))  # a row missing everything: object columns
    rows = [row, row._replace(**{SORT_COLUMN[name]: 3})]
    pd.testing.assert_frame_equal(frame_from_batches(name, [rows_to_batch(name, rows)]), frame_of(name, rows))


# --- tricky cells -----------------------------------------------------------------------------------

TEXTS = ["=1+2", "+cmd", "-5", "-5\n", "-x", "@SUM(A1)", "\tx", "\rx", "-12.5e3", "+.5", "-٣", "=", "",
         None, "Ölpumpe, 50 °C", "日本語", "emoji \U0001f600", 'quote "inner"', "a,b", "line\nbreak",
         "crlf\r\nend", "cr\ronly", "trailing space ", "  ", "nan", "0x1f", 12, 1.5, float("nan")]
FLOATS = [0.0014998912811279297, 0.1, 1e-05, 1e16, 5e-324, -0.0, 0.0, 123456789012345680.0, 1.0, -2.5,
          float("nan"), float("inf"), -float("inf"), 1e-7, 9.999999999999999e15, 1e15, 2.5e-4, None, 0.001499,
          1.5e-05, 0.123456789, -0.0000005, 9007199.254740991]
TIMES = [1767225600_026500000, 0, -1_500_000_000, -86400_000001000, -9_100_000_000 * NS, 9_100_000_000 * NS,
         9_300_000_000 * NS, -9_300_000_000 * NS, float("nan"), None, 1767225600 * NS, 951782400_500000000,
         1714982400_002936123, 1714982400_002936000]  # ns: before 1970 kept; before 1677 and after 2262 missing
# the tricky captures' resolutions (one left unknown: written to the nanosecond)
TRICKY_DIGITS = {"a.pcap": 6, "b, c.pcap": 0}


def _tricky_rows(name: str) -> list[tuple]:
    cols = COLUMNS[name]
    rng = random.Random(name)
    rows = []
    for i in range(60):
        cells = []
        for c in cols:
            if c.name == SORT_COLUMN[name]:
                cells.append(None if i % 17 == 5 else rng.randrange(1, 20))  # ties, and missing keys
            elif c.dtype == "Int64":
                cells.append(rng.choice([None, 0, -1, 7, 2**40, -(2**40)]))
            elif c.dtype == "Float64":
                cells.append(FLOATS[(i + len(cells)) % len(FLOATS)])
            elif c.dtype == "boolean":
                cells.append(rng.choice([True, False, None]))
            elif c.dtype == "datetime64[ns, UTC]":
                cells.append(TIMES[i % len(TIMES)])
            elif c.dtype == "category:verdict":
                cells.append(rng.choice(["ok", "nak", "timeout", "bogus", None]))
            elif c.dtype == "category:severity":
                cells.append(rng.choice(["info", "warning", "error", "fatal", None]))
            elif c.name == "capture":
                cells.append(rng.choice(["a.pcap", "b, c.pcap", "ü.pcap"]))
            elif c.name == "name":
                cells.append(rng.choice(["rpc_truncated", "truncated_capture", "not_a_rule", None]))
            elif c.dtype == "category":  # text only: a categorical keeps what it is given, its files str()
                cells.append(rng.choice([t for t in TEXTS if t is None or isinstance(t, str)]))
            else:
                cells.append(TEXTS[(i * 7 + len(cells)) % len(TEXTS)])
        rows.append(ROW_TYPES[name]._make(cells))
    return rows


@pytest.mark.filterwarnings("ignore:Constructing a Categorical")  # frame_of of a verdict outside its categories
@pytest.mark.parametrize("fmt", ["csv", "json", "parquet"])
@pytest.mark.parametrize("name", TABLES)
def test_tricky_cells_as_today(tmp_path, name, fmt):
    rows = _tricky_rows(name)
    if fmt == "parquet":  # one partition file open at a time: grouped by capture, as the report orders them
        rows = sorted(rows, key=lambda r: r.capture)
    by_capture = fmt == "parquet"
    pd.testing.assert_frame_equal(frame_from_batches(name, [rows_to_batch(name, rows)]), frame_of(name, rows))
    (tmp_path / "new").mkdir()
    writer = open_table(str(tmp_path / "new"), name, fmt, TRICKY_DIGITS)
    sink = TableSink(name, writer, by_capture=by_capture, spill_dir=str(tmp_path), max_held=16, chunk_rows=9,
                     min_write=1)
    arrived = _feed(sink, name, _batches(name, rows, random.Random(1), 8), by_capture)
    writer.close()
    today = _today(tmp_path / "today", name, fmt, arrived, by_capture, TRICKY_DIGITS)
    _assert_same_files(today, tmp_path / "new" / (name + SUFFIX[fmt]), fmt)


def test_duration_text_is_the_rows_text_at_every_resolution():
    """The columns' durations are model.times.duration_text's, at one resolution or one per row; a value that
    is a whole number of the resolution's last decimal is written as exactly that decimal."""
    rng = random.Random(5)
    values = [float(f"{rng.uniform(1, 10)}e{e}") for e in range(-330, 310) for _ in range(2)]
    values += [np.frombuffer(rng.getrandbits(64).to_bytes(8, "little"), "<f8")[0].item() for _ in range(5_000)]
    values += [rng.uniform(-0.05, 0.05) for _ in range(5_000)] + [x for x in FLOATS if x is not None]
    values += [float(2**53), 2.0**63, 1e22, 0.00009999999999999999, 1e-4, 9.999999999999999e14, 2**53 / 1e9,
               -(2**53) / 1e6, 0.5e-9, 1.5e-9, -2.5e-6]
    values = [v for v in values if not math.isnan(v)]
    array = pa.array(values + [None], pa.float64())
    for digits in range(10):
        assert duration_text(array, digits).to_pylist() == [duration_of(v, digits) for v in values] + [None]
    per_row = np.array([rng.randrange(10) for _ in range(len(values) + 1)])
    assert duration_text(array, per_row).to_pylist() == [duration_of(v, int(d)) for v, d in
                                                         zip(values, per_row, strict=False)] + [None]
    for digits in (6, 9):  # exact durations (ns / 1e9) of a capture of this resolution: the exact decimal
        ks = [rng.randrange(-10**13, 10**13) for _ in range(20_000)] + [1499, 1, -1, 0, 10**digits, 15]
        unit = 10 ** (9 - digits)
        text = duration_text(pa.array([k * unit / NS for k in ks], pa.float64()), digits).to_pylist()
        want = [("-" if k < 0 else "") + f"{abs(k) // 10**digits}." + (f"{abs(k) % 10**digits:0{digits}d}".rstrip("0")
                                                                      or "0") for k in ks]
        assert text == want
    assert duration_text(pa.array([0.001499, 1.5e-05, 1.0, 0.0015], pa.float64()), 6).to_pylist() == [
        "0.001499", "0.000015", "1.0", "0.0015"]


def test_time_and_int_text():
    rng = random.Random(6)
    ns = [rng.randrange(-9_200_000_000 * NS + 1, 9_200_000_000 * NS) for _ in range(20_000)] + [0, -1, 1]
    times = pa.array(ns + [None], pa.int64()).cast(pa.timestamp("ns", tz="UTC"))
    for digits in range(10):
        assert time_text(times, digits).to_pylist() == [csv_time(v, digits) for v in ns] + [None]
        assert time_text(times.slice(5, 10), digits).to_pylist() == [csv_time(v, digits) for v in ns[5:15]]
    per_row = np.array([rng.randrange(10) for _ in range(len(ns) + 1)])
    assert time_text(times, per_row, "T", "Z").to_pylist() == [json_time(v, int(d)) for v, d in
                                                               zip(ns, per_row, strict=False)] + [None]
    stamp = pa.array([1714982400_002936000, 1714982400_002936123], pa.int64()).cast(pa.timestamp("ns", tz="UTC"))
    assert time_text(stamp, 6).to_pylist() == ["2024-05-06 08:00:00.002936+00:00"] * 2  # cut, as a clock reads
    assert time_text(stamp, 9, "T", "Z").to_pylist() == ["2024-05-06T08:00:00.002936000Z",
                                                         "2024-05-06T08:00:00.002936123Z"]
    assert time_text(stamp, 0).to_pylist() == ["2024-05-06 08:00:00+00:00"] * 2
    for ints in ([rng.randrange(-3, 40) for _ in range(500)], [rng.randrange(-2**63, 2**63) for _ in range(500)]):
        values = pa.array([*ints, None], pa.int64())
        assert int_text(values).to_pylist() == [str(v) for v in ints] + [None]


def test_each_row_is_written_at_its_captures_resolution():
    captures = pa.array(["a.pcap", "b.pcap", None, "c.pcap", "a.pcap"], pa.large_string())
    assert row_digits(captures, {"a.pcap": 6, "b.pcap": 9}).tolist() == [6, 9, 9, 9, 6]
    assert row_digits(captures.slice(0, 1), {"a.pcap": 6}) == 6
    assert row_digits(pa.array([], pa.large_string()), {}) == 9


def test_conform_makes_a_batch_hold_what_rows_hold():
    schema = batch_schema("transactions")
    good = rows_to_batch("transactions", _tricky_rows("transactions"))
    assert conform("transactions", good) is good
    loose = pa.table({n: good.column(n) for n in reversed(schema.names)})  # other order, other types
    loose = loose.set_column(loose.schema.get_field_index("device"), "device", good.column("device").cast(pa.string()))
    assert conform("transactions", loose).equals(good)
    raw = good.set_column(schema.get_field_index("t_total"), "t_total", pa.chunked_array([[math.nan] * len(good)]))
    raw = raw.set_column(schema.get_field_index("verdict"), "verdict", pa.chunked_array([["bogus"] * len(good)],
                                                                                        pa.large_string()))
    far = pa.array([9_210_000_000 * NS] * len(good), pa.int64()).cast(pa.timestamp("ns", tz="UTC"))  # after 2262
    raw = raw.set_column(schema.get_field_index("t_start"), "t_start", far)
    fixed = conform("transactions", raw)
    assert {fixed.column(c).null_count for c in ("t_total", "verdict", "t_start")} == {len(good)}


# --- the sink, the writers, the summary on the samples ----------------------------------------------

@pytest.mark.parametrize("fmt", ["csv", "json", "parquet"])
@pytest.mark.parametrize("name", TABLES)
def test_shuffled_batches_through_the_sink_equal_todays_files(tmp_path, samples, name, fmt):
    by_capture = report._by_capture(name, fmt)
    rows = table_rows(samples.rows, name)
    (tmp_path / "new").mkdir()
    writer = open_table(str(tmp_path / "new"), name, fmt, samples.rows.digits)
    sink = TableSink(name, writer, by_capture=by_capture, spill_dir=str(tmp_path), chunk_rows=50,
                     min_write=1 if fmt != "json" else 100)  # JSON: flushes wait for 100 rows
    batches = _batches(name, rows, random.Random(name + fmt))
    arrived = _feed(sink, name, batches, by_capture)
    assert arrived != rows and sink.rows_in == sink.rows_out == len(rows)  # out of order, nothing lost
    writer.close()
    _assert_same_files(_today(tmp_path / "today", name, fmt, arrived, by_capture, samples.rows.digits),
                       tmp_path / "new" / (name + SUFFIX[fmt]), fmt)


@pytest.mark.parametrize("name", TABLES)
def test_the_sink_spills_and_still_writes_in_order(tmp_path, samples, name):
    rows = table_rows(samples.rows, name)
    (tmp_path / "new").mkdir()
    writer = open_table(str(tmp_path / "new"), name, "csv", samples.rows.digits)
    sink = TableSink(name, writer, spill_dir=str(tmp_path / "new"), max_held=10, chunk_rows=7, min_write=1)
    arrived = _feed(sink, name, _batches(name, rows, random.Random(7), 6), every=5)
    writer.close()
    assert sink.runs_made > FAN_IN  # runs were merged before they were read
    assert sink.peak_held <= 10 + 5 + (FAN_IN + 1) * sink.block  # memory, one batch, a block per run merged
    _assert_same_files(_today(tmp_path / "today", name, "csv", arrived, digits=samples.rows.digits),
                       tmp_path / "new" / f"{name}.csv", "csv")
    assert sorted(p.name for p in (tmp_path / "new").iterdir()) == [f"{name}.csv"]  # spill files removed


def test_the_sink_sorts_rows_far_out_of_order_stably(tmp_path):
    """Keys in random order with many ties and no flush before the end: many runs, merged in steps."""
    rng = random.Random(3)
    base = _tricky_rows("parameters")
    rows = [base[i % len(base)]._replace(txn=rng.choice([None, *range(40)]), values_read=str(i))
            for i in range(3_000)]
    batches = [rows[i:i + 11] for i in range(0, len(rows), 11)]
    got = []

    class Collect:
        def write_batch(self, table: pa.Table) -> None:
            got.extend(table.column("values_read").to_pylist())

    sink = TableSink("parameters", Collect(), spill_dir=str(tmp_path), max_held=20)
    for b in batches:
        sink.add(rows_to_batch("parameters", b))
    sink.close()
    assert sink.runs_made > 4 * FAN_IN and sink.peak_held <= 20 + 11 + (FAN_IN + 1) * sink.block
    assert got == [r.values_read for r in sorted(rows, key=sort_key("parameters"))]
    assert list(tmp_path.iterdir()) == []


def test_a_row_below_a_flushed_watermark_is_refused(tmp_path):
    rows = _tricky_rows("transactions")
    sink = TableSink("transactions", open_table(str(tmp_path), "transactions", "csv"), min_write=3)
    sink.add(rows_to_batch("transactions", [r._replace(txn=5) for r in rows[:2]]))
    assert sink.flush(6) == 0  # fewer than min_write complete: they wait
    sink.add(rows_to_batch("transactions", [rows[0]._replace(txn=7)]))
    assert sink.flush(8) == 3
    with pytest.raises(ValueError, match="watermark"):
        sink.add(rows_to_batch("transactions", [rows[0]._replace(txn=6)]))
    sink.add(rows_to_batch("transactions", [rows[0]._replace(txn=8), rows[1]._replace(txn=None)]))
    assert sink.close() == 2
    by_capture = TableSink("findings", open_table(str(tmp_path), "findings", "parquet"), by_capture=True)
    with pytest.raises(TypeError):
        by_capture.flush(3)


def test_summary_from_batches_equals_summary_from_rows(samples):
    rng = random.Random(11)
    for paths in [ALL, *([p] for p in ALL[::3])]:
        analysis = samples if paths is ALL else pd_analyze.analyze(paths)
        rows_acc, batch_acc = Summary(analysis.rows.digits), Summary(analysis.rows.digits)
        for name in ("transactions", "parameters", "findings"):
            rows = sorted(table_rows(analysis.rows, name), key=sort_key(name))  # table order, as the sink feeds it
            rows_acc.add(name, rows)
            i = 0
            while i < len(rows):
                n = rng.randrange(1, 40)
                batch_acc.add_batch(name, rows_to_batch(name, rows[i:i + n]))
                i += n
        assert batch_acc.text(analysis.captures) == rows_acc.text(analysis.captures)
        state = ("transactions", "verdicts", "any_failed", "failed", "naks", "by_error", "by_do", "first",
                 "b5_total", "b5_transactions", "b5_max", "added", "findings", "severities", "rules", "refused",
                 "slowest", "pnu_names", "error_texts", "unitemised", "naks_unitemised")
        assert {k: getattr(batch_acc, k) for k in state} == {k: getattr(rows_acc, k) for k in state}
        assert {d: tuple(map(list, a)) for d, a in batch_acc.latency.items()} == \
            {d: tuple(map(list, a)) for d, a in rows_acc.latency.items()}


@pytest.mark.parametrize("fmt", ["csv", "json", "parquet"])
def test_write_batches_equals_the_stream(tmp_path, samples, fmt):
    """The whole end: every table in shuffled batches through BatchReport, flushed as the pipeline would,
    gives analyze()'s tables, today's stream's files and its summary (ties kept whole in a batch, so the
    rows that tie come in the order the rows path has them)."""
    rng = random.Random(fmt)
    with report.BatchReport(str(tmp_path / "new"), fmt, max_held=40, chunk_rows=30, digits=samples.rows.digits) as out:
        for name in TABLES:
            batches = _batches(name, table_rows(samples.rows, name), rng, whole_keys=True)
            for k, b in enumerate(batches):
                out.add(name, rows_to_batch(name, b))
                watermark = _watermark(name, batches[k + 1:], out.by_capture(name))
                if watermark is not None:
                    out.flush(name, watermark)
        got = out.close(samples.captures)
    assert_files_equal_tables(tmp_path / "new", fmt, samples)
    streamed = report.stream(ALL, str(tmp_path / "today"), fmt, Settings())
    assert got.summary == streamed.summary == report.summary(samples)
    assert [Path(p).name for p in got.written] == [Path(p).name for p in streamed.written]
    for name in TABLES:
        _assert_same_files(tmp_path / "today" / (name + SUFFIX[fmt]), tmp_path / "new" / (name + SUFFIX[fmt]), fmt)
    assert sorted(p.name for p in (tmp_path / "new").iterdir()) == sorted(n + SUFFIX[fmt] for n in TABLES)


def test_a_failed_report_leaves_no_spill_behind(tmp_path, samples):
    rows = table_rows(samples.rows, "transactions")
    with pytest.raises(RuntimeError), report.BatchReport(str(tmp_path), "csv", max_held=10) as out:
        out.add("transactions", rows_to_batch("transactions", rows[::-1]))  # spills
        assert any(p.name.startswith(".pd-analyze-") for p in tmp_path.iterdir())
        raise RuntimeError("the analysis failed")
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())


def test_write_tables_writes_csv_and_parquet_through_the_batches(tmp_path, samples):
    for fmt in ("csv", "parquet"):
        report.write_tables(samples, str(tmp_path / fmt), fmt)
        for name in TABLES:
            _assert_same_files(_today(tmp_path / f"today-{fmt}", name, fmt, table_rows(samples.rows, name),
                                      report._by_capture(name, fmt), samples.rows.digits),
                               tmp_path / fmt / (name + SUFFIX[fmt]), fmt)
        assert not [p for p in (tmp_path / fmt).iterdir() if p.name.startswith(".")]  # no spill left


def test_json_batch_lines_are_todays_lines(samples, tmp_path):
    for name in TABLES:
        rows = sorted(table_rows(samples.rows, name), key=sort_key(name))
        writer = open_table(str(tmp_path), name, "json", samples.rows.digits)
        writer.write_batch(rows_to_batch(name, rows))
        writer.close()
        text = (tmp_path / f"{name}.jsonl").read_text("ascii")
        assert text == "".join(writer.line(r) for r in rows)
        assert [json.loads(line) for line in text.splitlines()] == [json.loads(writer.line(r)) for r in rows]
