"""Time the columnar report end (TableSink + CSV write_batch + Summary.add_batch) against today's row path.

    python benchmarks/table_sink_bench.py                    # 450,000 rows, 5 rounds
    python benchmarks/table_sink_bench.py --rows 100000 --rounds 3 --format parquet

The rows are realistic: the project's generator writes a parameter-access capture (eight drives, reads,
changes, multi-parameter requests, NAKs, B5 polling), `analyze()` turns it into rows, and those rows are
repeated (transaction and frame numbers and times shifted) until the tables hold --rows rows in all,
split as a 1,000,000-frame capture splits them (transactions 39 %, parameters 54 %, changes 4 %,
findings 3 %; the findings are the sample captures', repeated). The rows arrive as the analysis hands
them on: in the order they closed (--disorder: transactions shuffled within windows of 8, as drives
answering at their own pace close them), in batches of --batch rows, each pair of neighbouring batches
swapped, a flush after each batch up to the smallest key still to come.

Timed, each the best of --rounds (the machine may be busy: the CPU time of this process is printed
beside the wall time, and is less disturbed by other processes):
  rows     today's report.stream end: each row counted into the Summary and formatted as its CSV line,
           a Spool sorting the lines, the lines written (the analysis and nothing else left out)
  batches  the same rows as pyarrow batches (converted beforehand: the columnar analysis makes them):
           a BatchReport, i.e. a TableSink per table, write_batch, Summary.add_batch
The files of both are compared byte for byte, and the summaries.
"""

from __future__ import annotations

import argparse
import filecmp
import glob
import os
import random
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(1, str(ROOT))  # devtools/ is not installed

import pd_analyze  # noqa: E402
from devtools.synth.mixed_capture import make_capture  # noqa: E402
from pd_analyze.analysis.schema import SORT_COLUMN, sort_key  # noqa: E402
from pd_analyze.analysis.table_batches import rows_to_batch  # noqa: E402
from pd_analyze.output import report  # noqa: E402
from pd_analyze.output.spool import Spool  # noqa: E402
from pd_analyze.output.summary import Summary  # noqa: E402
from pd_analyze.output.writers import open_table  # noqa: E402

SHARE = {"transactions": 0.39, "parameters": 0.54, "changes": 0.04, "findings": 0.03}


def realistic_rows(total: int, work: str) -> dict[str, list[tuple]]:
    """Rows of every table, about `total` in all, from a generated capture and the samples' findings."""
    capture = os.path.join(work, "bench.pcap")
    make_capture(Path(capture), 60_000, pnio_share=0.5)
    base = pd_analyze.analyze(capture).rows
    samples = pd_analyze.analyze(sorted(glob.glob(str(ROOT / "sample_pcaps" / "*.pcap*")))).rows
    sources = {"transactions": base.transactions, "parameters": base.parameters, "changes": base.changes,
               "findings": samples.findings}
    span_txn = max(r.txn for r in base.transactions)
    span_frame = max(r.frame for r in samples.findings)
    span_time = max(r.t_start for r in base.transactions) - min(r.t_start for r in base.transactions) + 1
    out = {}
    for name, rows in sources.items():
        want, got, copy = int(total * SHARE[name]), [], 0
        while len(got) < want:
            for r in rows[:want - len(got)]:
                txn = None if r.txn is None else r.txn + copy * span_txn
                if name == "findings":
                    got.append(r._replace(txn=txn, frame=r.frame + copy * span_frame))
                elif name == "changes":
                    got.append(r._replace(txn=txn, t=r.t + copy * span_time))
                elif name == "transactions":
                    got.append(r._replace(txn=txn, t_start=r.t_start + copy * span_time))
                else:
                    got.append(r._replace(txn=txn))
            copy += 1
        out[name] = got
    return out


def closing_order(name: str, rows: list[tuple], window: int, seed: int = 1) -> list[tuple]:
    """The rows as transactions close when drives answer at their own pace: the rows of one transaction
    (or frame) stay together, and such groups are shuffled within windows of `window` groups."""
    col = list(rows[0]._fields).index(SORT_COLUMN[name])
    groups: list[list[tuple]] = []
    for r in rows:
        if groups and groups[-1][0][col] == r[col]:
            groups[-1].append(r)
        else:
            groups.append([r])
    rng = random.Random(seed)
    for i in range(0, len(groups), max(1, window)):
        part = groups[i:i + window]
        rng.shuffle(part)
        groups[i:i + window] = part
    return [r for g in groups for r in g]


def arrivals(name: str, rows: list[tuple], batch: int) -> list[tuple[list[tuple], object]]:
    """Batches in the order the analysis hands them on, each with the watermark known after it."""
    batches = [rows[i:i + batch] for i in range(0, len(rows), batch)]
    for i in range(0, len(batches) - 1, 2):  # neighbours swapped: out of order, as parts finish
        batches[i], batches[i + 1] = batches[i + 1], batches[i]
    col = list(rows[0]._fields).index(SORT_COLUMN[name])
    lows = [min((r[col] for r in b if r[col] is not None), default=None) for b in batches]
    out = []
    for i, b in enumerate(batches):
        rest = [low for low in lows[i + 1:] if low is not None]
        out.append((b, min(rest) if rest else None))
    return out


def rows_path(tables: dict[str, list], fmt: str, out: str) -> str:
    """Today's stream end (report._Table, Spool, write_lines) on the rows; the summary text."""
    acc = Summary()
    written = {}
    for name, batches in tables.items():
        writer = open_table(out, name, fmt)
        spool = Spool(sort_key(name, report._by_capture(name, fmt)), report.CHUNK_ROWS, out)
        sink = report._Table(name, writer, spool, acc)
        for rows, _ in batches:
            sink.extend(rows)
        sink.flush()
        for chunk in spool.chunks(report.CHUNK_ROWS):
            writer.write(chunk) if sink.line is None else writer.write_lines(chunk)
        written[name] = writer.close()
    return acc.text([])


def batch_path(tables: dict[str, list], fmt: str, out: str) -> str:
    """The columnar end: a BatchReport fed the batches, flushed at each watermark."""
    with report.BatchReport(out, fmt) as rep:
        for name, batches in tables.items():
            for table, watermark in batches:
                rep.add(name, table)
                if watermark is not None and not rep.by_capture(name):
                    rep.flush(name, watermark)
        return rep.close([]).summary


def best(rounds: int, run: object, *args: object) -> tuple[float, float, object]:
    """The best wall time and the best CPU time (of this process) of `rounds` runs, and the last result."""
    walls, cpus, result, last = [], [], None, ""
    for i in range(rounds):
        out = tempfile.mkdtemp(prefix="bench-out-")
        start, cpu = time.perf_counter(), time.process_time()
        result = run(*args, out)  # type: ignore[operator]
        walls.append(time.perf_counter() - start)
        cpus.append(time.process_time() - cpu)
        if i < rounds - 1:
            shutil.rmtree(out)
        else:
            last = out
    return min(walls), min(cpus), (result, last)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rows", type=int, default=450_000)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--batch", type=int, default=16_384, help="rows per batch handed on")
    parser.add_argument("--format", default="csv", choices=["csv", "parquet", "json"])
    parser.add_argument("--disorder", type=int, default=8,
                        help="transactions closing out of order within windows of this many (1: in order)")
    args = parser.parse_args()
    work = tempfile.mkdtemp(prefix="bench-")
    try:
        rows = realistic_rows(args.rows, work)
        print("rows:", {n: len(r) for n, r in rows.items()}, "in all", sum(map(len, rows.values())))
        by_rows = {n: arrivals(n, closing_order(n, r, args.disorder), args.batch) for n, r in rows.items()}
        by_batches = {n: [(rows_to_batch(n, b), w) for b, w in a] for n, a in by_rows.items()}
        t_rows, c_rows, (text_rows, out_rows) = best(args.rounds, rows_path, by_rows, args.format)
        t_batches, c_batches, (text_batches, out_batches) = best(args.rounds, batch_path, by_batches, args.format)
        print(f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
        print("                                                 wall       CPU")
        print(f"today's row path (Spool, line(), Summary.add):  {t_rows:6.3f} s  {c_rows:6.3f} s")
        print(f"batches (TableSink, write_batch, add_batch):     {t_batches:6.3f} s  {c_batches:6.3f} s"
              f"  ({t_rows / t_batches:.1f}x faster)")
        same = text_rows == text_batches
        if args.format != "parquet":
            names = [f"{n}.{'jsonl' if args.format == 'json' else args.format}" for n in rows]
            same &= all(filecmp.cmp(os.path.join(out_rows, f), os.path.join(out_batches, f), shallow=False)
                        for f in names)
        print("files and summary identical:" if args.format != "parquet" else
              "summary identical (Parquet files are compared by tests/test_table_batches.py):", same)
        shutil.rmtree(out_rows)
        shutil.rmtree(out_batches)
    finally:
        shutil.rmtree(work)


if __name__ == "__main__":
    main()
