"""The transactions a batch closes are made into tables slice by slice (engine.txncols.in_slices) and held for
late copies under a byte cap too (engine.late): a batch of long requests costs a slice's memory. Before, a
flood of never-answered 39-parameter writes made 1.5 million rows in one go (peak RSS 450 MiB at 50,000
frames). Slicing changes no row: the tables are those of one go, in the same order."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pyarrow as pa
import pytest

from devtools import hostile
from devtools.synth import fault_rich
from pd_analyze.analysis.api import Analysis
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.analysis.engine import late as late_mod
from pd_analyze.analysis.engine import txncols
from pd_analyze.analysis.engine.late import LateCopies
from pd_analyze.analysis.engine.txncols import TxnCols, in_slices
from pd_analyze.analysis.jobs import run as run_files
from pd_analyze.analysis.rows import Rows
from pd_analyze.model.capped import Cap

TABLES = ("transactions", "parameters", "findings", "changes", "accounting")


def _cols(numbers: list[int], n_params: list[int]) -> TxnCols:
    """Entries whose every value tells which entry it is: entry k's reads are 10k.., its frames 100k.."""
    n = len(numbers)
    reads = [[10 * k + j for j in range(k % 3)] for k in range(n)]
    frames = [[100 * k + j for j in range(1 + k % 2)] for k in range(n)]

    def flat(lists: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
        offsets = np.cumsum([0] + [len(x) for x in lists]).astype(np.int64)
        return np.array([v for x in lists for v in x], np.int64), offsets

    values: dict[str, object] = {}
    for i, f in enumerate(fields(TxnCols)):
        if f.name in ("findings", "values_before"):
            continue
        values[f.name] = np.arange(n, dtype=np.int64) * 1000 + i
    values.update(channel=[("ch", k) for k in range(n)], ch=np.arange(n, dtype=np.int64),
                  verdict=[f"v{k}" for k in range(n)], pnio_status=[f"s{k}" for k in range(n)],
                  closed_by=[f"c{k}" for k in range(n)], capture_ended=np.arange(n) % 2 == 1,
                  number=np.array(numbers, np.int64), n_params=np.array(n_params, np.int64))
    values["read_frames"], values["read_offsets"] = flat(reads)
    values["frames"], values["frame_offsets"] = flat(frames)
    return TxnCols(**values, findings={1: ["f1"], 3: ["f3"]}, values_before={0: ["b0"], 3: ["b3"]})  # type: ignore[arg-type]


def test_take_keeps_each_entry_whole() -> None:
    cols = _cols([1, 2, 3, 4, 5], [1, 1, 1, 1, 1])
    part = cols.take(np.array([1, 3, 4], np.int64))
    assert len(part) == 3
    assert part.number.tolist() == [2, 4, 5] and part.ch.tolist() == [1, 3, 4]
    assert part.t_start.tolist() == cols.t_start[[1, 3, 4]].tolist()
    assert part.verdict == ["v1", "v3", "v4"] and part.closed_by == ["c1", "c3", "c4"]
    assert part.capture_ended.tolist() == [True, True, False]
    # entry 1 has one read (10), entry 3 none, entry 4 one (40); frames: 100 101 | 300 301 | 400
    assert part.read_frames.tolist() == [10, 40] and part.read_offsets.tolist() == [0, 1, 1, 2]
    assert part.frames.tolist() == [100, 101, 300, 301, 400] and part.frame_offsets.tolist() == [0, 2, 4, 5]
    assert part.findings == {0: ["f1"], 1: ["f3"]} and part.values_before == {1: ["b3"]}
    assert part.channel == cols.channel  # (the channel list is shared; `ch` indexes it)


def test_slices_cut_by_number_at_the_rows_given() -> None:
    # the loop's transactions 1, 4, 6 and the vector path's 2, 3, 5, 7; parameters as given
    txns = [SimpleNamespace(number=n, n_params=p) for n, p in ((1, 3), (4, 2), (6, -1))]
    cols = _cols([2, 3, 5, 7], [1, 4, 2, 2])
    got = [([t.number for t in part], [] if c is None else c.number.tolist())
           for part, c in in_slices(txns, cols, rows=4)]  # type: ignore[arg-type]
    # rows before each in number order: 1:0 2:3 3:4 4:8 5:10 6:12 7:13 -> slices at 4, 8, 12 rows
    assert got == [([1], [2]), ([], [3]), ([4], [5]), ([6], [7])]
    whole = list(in_slices(txns, cols, rows=100))  # type: ignore[arg-type]
    assert len(whole) == 1 and whole[0][0] is txns and whole[0][1] is cols
    # a transaction longer than a slice is a slice of its own
    long = [SimpleNamespace(number=1, n_params=39), SimpleNamespace(number=2, n_params=39)]
    assert [[t.number for t in p] for p, _ in in_slices(long, None, rows=8)] == [[1], [2]]  # type: ignore[arg-type]


def _table(nbytes: int) -> dict[str, list[pa.Table]]:
    return {"transactions": [pa.table({"txn": pa.array([1], pa.int64()), "pad": pa.array([b"x" * nbytes])})]}


def test_late_copies_are_held_under_a_byte_cap_too(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(late_mod, "LATE_COPIES", Cap("held", 4096, 3000))
    late = LateCopies(rpc_timeout_ns=10**9)
    late.hold(_table(1000), [], None, 0, now=0)
    assert late.release(now=1) == []  # within the time, under both caps: held
    late.hold(_table(2500), [], None, 0, now=1)
    released = late.release(now=2)  # over 3000 bytes: the oldest goes, the newest stays
    assert len(released) == 1 and released[0]["transactions"][0].column("pad")[0].as_py() == b"x" * 1000
    assert len(late.release(now=3, everything=True)) == 1


def _analysed(path: Path, monkeypatch: pytest.MonkeyPatch, rows: int | None) -> Analysis:
    if rows is not None:
        monkeypatch.setattr(txncols, "SLICE_ROWS", rows)
    settings = Settings()
    out = Rows()
    results = run_files([str(path)], out, settings)
    return Analysis(out, results, settings.profile, settings.txn_timeout, settings.rpc_timeout)


@pytest.mark.parametrize("kind", ["fault_rich", "calls"])
def test_slices_of_one_row_give_the_tables_of_one_go(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                     kind: str) -> None:
    path = tmp_path / f"{kind}.pcap"
    if kind == "fault_rich":
        fault_rich.make_fault_rich(path, 2000, seed=3)
    else:
        hostile.write_pcap("calls", 3000, path)
    one_go = _analysed(path, monkeypatch, 10**9)
    sliced = _analysed(path, monkeypatch, 1)
    assert len(one_go.transactions) > 100 and len(one_go.parameters) > len(one_go.transactions)
    for table in TABLES:
        pd.testing.assert_frame_equal(getattr(one_go, table), getattr(sliced, table), obj=table)
