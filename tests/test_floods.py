"""Issue #23's floods (devtools.hostile) through the analysis, small: every frame read once, every open item
stated (each half-finished transaction and each never-answered 40-parameter change request is a row, ended by
the capture or by a cap with its finding), and the columnar path giving the per-frame path's tables.

The large runs (300,000 frames: speed against tshark, peak RSS) are benchmarks/bench.py's flood step.
"""

from __future__ import annotations

import struct
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import pandas as pd
import pytest

from devtools import hostile
from pd_analyze.analysis.api import Analysis
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.analysis.jobs import run
from pd_analyze.analysis.rows import Rows
from pd_analyze.output.report import summary

FRAMES = 3000  # the 40-parameter flood reaches the pending transactions' byte cap at about 2,100
SMALL = 1500  # the floods that only need every frame counted
HOWS = ("loop", 1000)  # the engine's loop alone; its vector path in batches of 1,000 frames
TABLES = ("transactions", "parameters", "findings", "changes", "accounting")
@pytest.fixture(scope="module")
def floods(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    base = tmp_path_factory.mktemp("floods")
    out = {}
    for kind in hostile.ALL_KINDS:
        out[kind] = base / f"{kind}.pcap"
        assert hostile.write_pcap(kind, size(kind), out[kind], seed=3) == size(kind)
    return out


def size(kind: str) -> int:
    return FRAMES if kind in hostile.TRANSACTION_KINDS else SMALL


@pytest.fixture(scope="module")
def analysed(floods: dict[str, Path]) -> Callable[[str, object], Analysis]:
    """Each flood analysed once per way, on demand."""
    cache: dict[tuple[str, object], Analysis] = {}

    def get(kind: str, how: object) -> Analysis:
        if (kind, how) not in cache:
            settings = Settings(vector=how != "loop", batch_frames=0 if how == "loop" else int(how))
            rows = Rows()
            results = run([str(floods[kind])], rows, settings)
            cache[kind, how] = Analysis(rows, results, settings.profile, settings.txn_timeout, settings.rpc_timeout)
        return cache[kind, how]

    return get


def calls(path: Path) -> Counter[tuple[int, int]]:
    """(RPC packet type, opnum) of every frame of a flood written by hostile.write_pcap (Ethernet, IPv4 without
    options: the RPC header at byte 42; fragments and their bodies counted by their own headers)."""
    data = path.read_bytes()
    out: Counter[tuple[int, int]] = Counter()
    at = 24
    while at < len(data):
        length = struct.unpack_from("<I", data, at + 8)[0]
        frame = data[at + 16:at + 16 + length]
        if len(frame) >= 42 + 80 and frame[42] == 4:
            out[frame[42 + 1], struct.unpack_from("<H", frame, 42 + 68)[0]] += 1
        at += 16 + length
    return out


@pytest.mark.parametrize("how", HOWS)
@pytest.mark.parametrize("kind", hostile.ALL_KINDS)
def test_every_frame_is_read_once(analysed, kind: str, how: object) -> None:
    acc = analysed(kind, how).accounting.iloc[0]
    assert (int(acc["read"]), bool(acc["balanced"])) == (size(kind), True)


@pytest.mark.parametrize("how", HOWS)
def test_every_half_finished_transaction_is_stated(analysed, floods: dict[str, Path], how: object) -> None:
    """Each write answered OK opens a transaction on its own channel; its B5 answers are counted; none is
    answered, so each ends a timeout when the capture ends (its deadline lies beyond: 1 us a frame)."""
    t = analysed("txns", how).transactions
    seen = calls(floods["txns"])
    writes, b5_answers = seen[0, 3], seen[2, 2]
    assert writes > 500 and b5_answers > 500 and seen[2, 3] == writes and seen[0, 2] == b5_answers
    assert len(t) == writes
    assert (t.verdict == "timeout").all() and (t.closed_by == "capture_end").all() and t.capture_ended.all()
    assert int(t.b5_retries.sum()) == b5_answers and (t.reads == t.b5_retries).all()
    assert set(t.pnio_status) == {"", "DE80B500"}  # the last answer B5, or no read at all
    assert t.groupby(["slot", "subslot"]).size().max() == 1  # ever new channels


@pytest.mark.parametrize("how", HOWS)
def test_every_40_parameter_change_is_stated_with_its_p2(analysed, how: object) -> None:
    a = analysed("changes40", how)
    t, f = a.transactions, a.findings
    assert len(t) == FRAMES and (t.n_params == 40).all() and (t.verdict == "timeout").all()
    p2 = f[f.name == "pd_request_range"]
    assert sorted(p2.frame) == list(range(1, FRAMES + 1)) and set(p2.field) == {"pd.n_params"}
    assert sorted(f[f.name == "pd_record_length"].frame) == list(range(1, FRAMES + 1))  # 404 bytes: H13
    evicted = t.closed_by == "evicted"
    assert (t[~evicted].closed_by == "capture_end").all()
    assert sorted(f[f.name == "txn_evicted"].txn) == sorted(t[evicted].txn)  # each eviction stated


def _same(one: Analysis, two: Analysis) -> None:
    for name in TABLES:
        pd.testing.assert_frame_equal(getattr(one, name), getattr(two, name), obj=name)
    assert summary(one) == summary(two)


def test_half_finished_transactions_give_the_same_tables_by_loop_and_vector(analysed) -> None:
    _same(analysed("txns", "loop"), analysed("txns", 1000))


def test_40_parameter_changes_give_the_same_tables_by_loop_and_vector(analysed) -> None:
    _same(analysed("changes40", "loop"), analysed("changes40", 1000))
