"""The columnar report path against the per-frame reference: the same tables (transactions, parameters,
findings, changes), the same accounting and summary, on every sample and real capture, the fuzz corpus,
generated captures with mixed verdicts (most of their groups on the columns) and captures whose frames
mostly fail a guard; at batch sizes 1, 7, 1000 and the default."""

from __future__ import annotations

import random
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import pd_analyze
from devtools import hostile
from devtools.fuzz.corpus import load_seeds, seed_paths
from devtools.fuzz.mutators import make_case
from devtools.synth.mixed_capture import make_capture
from pd_analyze.analysis.api import Analysis
from pd_analyze.analysis.capture_run import CaptureResult, Settings
from pd_analyze.analysis.columnar.run import ColumnarRun
from pd_analyze.analysis.pipeline import run_frames
from pd_analyze.analysis.rows import Rows
from pd_analyze.analysis.stations import names_in_frames
from pd_analyze.capture import RawFrame
from pd_analyze.capture.batches import FrameBatch
from pd_analyze.output.report import summary
from tests.support import shared_captures

ROOT = Path(__file__).resolve().parents[1]
CAPTURES = sorted(p for p in (ROOT / "sample_pcaps").glob("*") if p.suffix in (".pcap", ".pcapng", ".gz")) \
    + shared_captures()
TABLES = ("transactions", "parameters", "findings", "changes")
SIZES = (1, 7, 1000, 0)  # 0: the default


def analyses(path: str, size: int, **kw: object) -> tuple[pd_analyze.Analysis, pd_analyze.Analysis]:
    """The capture analysed frame by frame and in batches of `size` frames."""
    from pd_analyze.analysis.jobs import run

    out = []
    for settings in (Settings(columns=False, **kw), Settings(columns=True, batch_frames=size, **kw)):
        rows = Rows()
        results = run([path], rows, settings)
        out.append(Analysis(rows, results, settings.profile, settings.txn_timeout, settings.rpc_timeout))
    return out[0], out[1]


def assert_same(one: pd_analyze.Analysis, two: pd_analyze.Analysis) -> None:
    for name in TABLES:
        pd.testing.assert_frame_equal(getattr(one, name), getattr(two, name), obj=name)
    pd.testing.assert_frame_equal(one.accounting, two.accounting, obj="accounting")
    assert one.errors == two.errors


@pytest.mark.parametrize("path", CAPTURES, ids=lambda p: p.name)
def test_samples_and_real_captures_give_the_reference_tables(path: Path) -> None:
    for size in SIZES:
        assert_same(*analyses(str(path), size))


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Captures of the generator with mixed verdicts: all PNIO RPC, and a 30 % mix."""
    base = tmp_path_factory.mktemp("columnar")
    out = {"dense": base / "dense.pcap", "mix": base / "mix.pcap"}
    make_capture(out["dense"], 12_000, seed=11, pnio_share=1.0, faults=0.08)
    make_capture(out["mix"], 12_000, seed=12, pnio_share=0.3, faults=0.08)
    return out


@pytest.mark.parametrize("name", ["dense", "mix"])
@pytest.mark.parametrize("size", SIZES[1:])
def test_generated_captures_give_the_reference_tables(generated: dict[str, Path], name: str, size: int) -> None:
    one, two = analyses(str(generated[name]), size)
    assert_same(one, two)
    verdicts = set(one.transactions.verdict.astype(str))
    assert {"ok", "nak", "timeout", "pnio_error"} <= verdicts  # mixed verdicts, really
    assert (one.findings.name == "rpc_unanswered").any() and (one.findings.name == "rpc_fault").any()


@pytest.mark.parametrize("size", [7, 1000])
def test_short_timeouts_expire_calls_and_transactions_as_the_reference(generated: dict[str, Path], size: int) -> None:
    """Deadlines and rpc_timeout passing inside and across batches."""
    assert_same(*analyses(str(generated["dense"]), size, txn_timeout=0.004, rpc_timeout=0.003))


def test_batches_decoded_in_parts_give_the_reference_tables(generated: dict[str, Path],
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """A batch whose records declare more parameters than one decode may hold is decoded in parts (here
    parts of about 50 parameters), with the same tables; and the parts really are made."""
    from pd_analyze.analysis.columnar import batch_view
    from pd_analyze.capture.batches import batches

    monkeypatch.setattr(batch_view, "PARAMETERS_PER_DECODE", 50)
    batch = next(batches(str(generated["dense"]), 5000))
    parts = [part for part, _view in batch_view.BatchView.parts(batch, Settings().checker())]
    assert len(parts) > 10 and sum(len(p) for p in parts) == len(batch)
    assert np.array_equal(np.concatenate([p.number for p in parts]), batch.number)
    assert_same(*analyses(str(generated["dense"]), 5000))


def test_the_columns_take_the_ordinary_groups(generated: dict[str, Path]) -> None:
    """The differential tests are not vacuous: on the generated capture nearly every frame is analysed by
    the columns, not handed to the per-frame dissector."""
    from pd_analyze.capture.batches import batches

    run = ColumnarRun(Settings(), Rows(), lambda _f: "dense", [CaptureResult("dense", None)])
    for batch in batches(str(generated["dense"]), 4096):
        run.feed(batch)
    by_dissector = run.d.accounting.read
    run.finish()
    assert run.totals().read == 12_000 + 2 or run.totals().read > 12_000
    assert by_dissector < run.totals().read * 0.05


def batches_of(frames: Sequence[RawFrame], size: int) -> list[FrameBatch]:
    """Frames as the batch reader would give them, `size` at a time."""
    out = []
    for first in range(0, len(frames), size):
        part = frames[first:first + size]
        buf = b"".join(f.data for f in part)
        lengths = np.array([len(f.data) for f in part], np.int64)
        start = np.zeros(len(part), np.int64)
        np.cumsum(lengths[:-1], out=start[1:])
        out.append(FrameBatch(buf, np.array([f.number for f in part], np.int64), np.array([f.ts for f in part]),
                              np.array([f.linktype for f in part], np.int32), start, lengths,
                              np.zeros(len(part), np.int32)))
    return out


def tables_of(frames: Sequence[RawFrame], size: int | None, settings: Settings) -> tuple[dict, tuple]:
    """The four tables and the accounting of frames, by the per-frame loop (size None) or the columns."""
    rows = Rows()
    results = [CaptureResult("case", None)]
    if size is None:
        d = settings.dissector()
        run_frames(iter(frames), d, settings.engine(), rows, lambda _f: "case", results, None)
        names_in_frames(frames, results[0].stations)  # (analyze_file's own pass over the file)
        acc = d.accounting
    else:
        run = ColumnarRun(settings, rows, lambda _f: "case", results)
        for batch in batches_of(frames, size):
            run.feed(batch)
        run.finish()
        acc = run.totals()
    results[0].accounting = acc
    analysis = Analysis(rows, results, settings.profile, settings.txn_timeout, settings.rpc_timeout)
    tables = {name: getattr(analysis, name) for name in TABLES}
    return tables, (acc.read, acc.decoded, dict(acc.skipped), dict(acc.malformed), summary(analysis))


@pytest.fixture(scope="module")
def seeds() -> list:
    return load_seeds(seed_paths())


@pytest.mark.parametrize("chunk", range(4))
def test_fuzz_corpus_gives_the_reference_tables(seeds: list, chunk: int) -> None:
    """Mutated windows of every seed capture (cut, flipped, spliced, reordered, flooded, time warped)."""
    settings = Settings(profile="sinamics")
    for number in range(chunk * 150, chunk * 150 + 150):
        case = make_case(seeds, number, base_seed=7)
        want = tables_of(case.frames, None, settings)
        for size in (3, 64):
            got = tables_of(case.frames, size, settings)
            assert got[1] == want[1], (number, size)
            for name in TABLES:
                pd.testing.assert_frame_equal(got[0][name], want[0][name], obj=f"case {number} {name}")


@pytest.mark.parametrize("kind", hostile.KINDS)
def test_frames_that_fail_the_guards_give_the_reference_tables(kind: str) -> None:
    """Hostile floods (IP and CL fragments, never-answered calls...): most frames go to the per-frame
    path, from the columns or after them."""
    frames = list(hostile.frames(kind, 3000, seed=5))
    rng = random.Random(5)
    want = tables_of(frames, None, Settings())
    got = tables_of(frames, rng.choice((7, 500)), Settings())
    assert got[1] == want[1]
    for name in TABLES:
        pd.testing.assert_frame_equal(got[0][name], want[0][name], obj=name)
