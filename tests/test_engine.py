"""The one analysis engine (analysis/engine): the same tables, accounting and summary whatever the batch
size (its state carries exactly from batch to batch), every frame of a capture accounted for, on every
sample and real capture, generated captures with faults of every kind, the fuzz corpus and the floods.

What the tables must say is asserted elsewhere against the captures' own truth (test_samples_expected,
test_fault_rich, test_transactions); here: that the batches change nothing, and that the columns decode
what they should while the per-frame dissector takes only what they cannot.
"""

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
from pd_analyze.analysis.engine.run import EngineRun, analyze_frames
from pd_analyze.analysis.jobs import run
from pd_analyze.analysis.rows import Rows
from pd_analyze.capture import RawFrame
from pd_analyze.capture.batches import batches
from pd_analyze.output.report import summary
from tests.support import shared_captures

ROOT = Path(__file__).resolve().parents[1]
CAPTURES = sorted(p for p in (ROOT / "sample_pcaps").glob("*") if p.suffix in (".pcap", ".pcapng", ".gz")) \
    + shared_captures()
TABLES = ("transactions", "parameters", "findings", "changes")
SIZES = (1, 7, 1000)


def analysed(path: str, size: int = 0, **kw: object) -> Analysis:
    """The capture analysed in batches of `size` frames (0: the reader's default)."""
    settings = Settings(batch_frames=size, **kw)
    rows = Rows()
    results = run([path], rows, settings)
    return Analysis(rows, results, settings.profile, settings.txn_timeout, settings.rpc_timeout)


def assert_same(one: Analysis, two: Analysis) -> None:
    for name in TABLES:
        pd.testing.assert_frame_equal(getattr(one, name), getattr(two, name), obj=name)
    pd.testing.assert_frame_equal(one.accounting, two.accounting, obj="accounting")
    assert one.errors == two.errors
    assert summary(one) == summary(two)


def frames_in_file(path: Path) -> int:
    from pd_analyze import capture

    count = 0
    try:
        for frame in capture.frames(str(path)):
            count += frame.run or 1
    except capture.CaptureError:
        pass
    return count


@pytest.mark.parametrize("path", CAPTURES, ids=lambda p: p.name)
def test_samples_and_real_captures_are_the_same_in_any_batches(path: Path) -> None:
    whole = analysed(str(path))
    assert int(whole.accounting.read.sum()) == frames_in_file(path)
    assert whole.accounting.balanced.all()
    for size in SIZES:
        assert_same(whole, analysed(str(path), size))


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Captures of the generator with mixed verdicts: all PNIO RPC, and a 30 % mix."""
    base = tmp_path_factory.mktemp("engine")
    out = {"dense": base / "dense.pcap", "mix": base / "mix.pcap"}
    make_capture(out["dense"], 12_000, seed=11, pnio_share=1.0, faults=0.08)
    make_capture(out["mix"], 12_000, seed=12, pnio_share=0.3, faults=0.08)
    return out


@pytest.mark.parametrize("name", ["dense", "mix"])
@pytest.mark.parametrize("size", SIZES[1:])
def test_generated_captures_are_the_same_in_any_batches(generated: dict[str, Path], name: str, size: int) -> None:
    whole = analysed(str(generated[name]))
    assert_same(whole, analysed(str(generated[name]), size))
    verdicts = set(whole.transactions.verdict.astype(str))
    assert {"ok", "nak", "timeout", "pnio_error"} <= verdicts  # mixed verdicts, really
    assert (whole.findings.name == "rpc_unanswered").any() and (whole.findings.name == "rpc_fault").any()


@pytest.mark.parametrize("size", [7, 1000])
def test_short_timeouts_expire_the_same_in_any_batches(generated: dict[str, Path], size: int) -> None:
    """Deadlines and rpc_timeout passing inside and across batches."""
    kw = {"txn_timeout": 0.004, "rpc_timeout": 0.003}
    whole = analysed(str(generated["dense"]), **kw)
    assert (whole.transactions.closed_by == "deadline").any()
    assert_same(whole, analysed(str(generated["dense"]), size, **kw))


def test_batches_decoded_in_parts_are_the_same(generated: dict[str, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    """A batch whose records declare more parameters than one decode may hold is decoded in parts (here
    parts of about 50 parameters), with the same tables; and the parts really are made."""
    from pd_analyze.analysis.engine import view

    whole = analysed(str(generated["dense"]), 5000)
    monkeypatch.setattr(view, "PARAMETERS_PER_DECODE", 50)
    batch = next(batches(str(generated["dense"]), 5000))
    parts = [part for part, _view in view.BatchView.parts(batch, Settings().checker())]
    assert len(parts) > 10 and sum(len(p) for p in parts) == len(batch)
    assert np.array_equal(np.concatenate([p.number for p in parts]), batch.number)
    assert_same(whole, analysed(str(generated["dense"]), 5000))


def test_the_columns_decode_the_ordinary_frames(generated: dict[str, Path]) -> None:
    """On a generated capture with 8 % faults nearly every PNIO frame is decoded by the columns, and the
    per-frame dissector takes the few others; each frame is counted once."""
    results = [CaptureResult("dense", None)]
    engine = EngineRun(Settings(), Rows(), lambda _f: "dense", results)
    for batch in batches(str(generated["dense"]), 4096):
        engine.feed(batch)
    engine.finish()
    totals = engine.totals()
    assert totals.read == frames_in_file(generated["dense"]) and totals.balanced()
    assert engine.decoder.accounting.read < totals.read * 0.02
    assert engine.accounting.decoded > totals.decoded * 0.98


def tables_of(frames: Sequence[RawFrame], size: int, settings: Settings) -> tuple[dict, tuple]:
    rows = Rows()
    result = analyze_frames(frames, settings, rows, "case", batch_frames=size)
    analysis = Analysis(rows, [result], settings.profile, settings.txn_timeout, settings.rpc_timeout)
    acc = result.accounting
    tables = {name: getattr(analysis, name) for name in TABLES}
    return tables, (acc.read, acc.decoded, dict(+acc.skipped), dict(+acc.malformed), summary(analysis))


@pytest.fixture(scope="module")
def seeds() -> list:
    return load_seeds(seed_paths())


@pytest.mark.parametrize("chunk", range(4))
def test_fuzz_corpus_is_the_same_in_any_batches(seeds: list, chunk: int) -> None:
    """Mutated windows of every seed capture (cut, flipped, spliced, reordered, flooded, time warped): every
    frame accounted for, and the same tables in batches of 3 and 64 frames as in one."""
    settings = Settings(profile="sinamics")
    for number in range(chunk * 150, chunk * 150 + 150):
        case = make_case(seeds, number, base_seed=7)
        want = tables_of(case.frames, len(case.frames) + 1, settings)
        assert want[1][0] == len(case.frames)
        for size in (3, 64):
            got = tables_of(case.frames, size, settings)
            assert got[1] == want[1], (number, size)
            for name in TABLES:
                pd.testing.assert_frame_equal(got[0][name], want[0][name], obj=f"case {number} {name}")


@pytest.mark.parametrize("kind", hostile.KINDS)
def test_floods_are_the_same_in_any_batches(kind: str) -> None:
    """Hostile floods (IP and CL fragments, never-answered calls...): every frame accounted for, the caps'
    evictions stated, the same tables in small batches as in one."""
    frames = list(hostile.frames(kind, 3000, seed=5))
    rng = random.Random(5)
    want = tables_of(frames, len(frames) + 1, Settings())
    assert want[1][0] == len(frames)
    got = tables_of(frames, rng.choice((7, 500)), Settings())
    assert got[1] == want[1]
    for name in TABLES:
        pd.testing.assert_frame_equal(got[0][name], want[0][name], obj=name)


def test_late_copies_are_counted_and_noted_as_in_one_batch(tmp_path: Path) -> None:
    """devtools.fuzz.mutated's capture (seeds repeated, so activity/sequence numbers come back; the clock
    steps back): a request under a known key with another body is a frame of its call's transaction, not one
    more retransmission, and a copy met after its transaction's rows were made has its findings noted with
    that transaction, in any batches (the loop alone: the reference)."""
    from devtools.fuzz.mutated import mutated_capture

    path = tmp_path / "mutated.pcap"
    mutated_capture(path, 2000)
    want = analysed(str(path), vector=False)
    if shared_captures():  # the capture is made of the corpus's seeds, the shared captures among them (CI)
        row = want.transactions.set_index("txn").loc[46]
        assert (row["frames"], row["rpc_retransmissions"]) == ("431 432 1180 1181", 0)
        at = want.findings[want.findings.frame == 1200]
        assert at[["txn", "rule", "name"]].values.tolist() == [[52, "R7", "rpc_key_reused"],
                                                               [52, "H4", "padding_nonzero"]]
    for size in (7, 1000):
        assert_same(analysed(str(path), size, vector=False), want)


def test_a_key_the_loop_meets_is_never_the_vector_paths(tmp_path: Path) -> None:
    """The mutated capture's seeds come back after some 11,500 frames with their activity/sequence numbers, the
    clock stepped back: frame 14004 repeats the key of the call answered at 2555, after a cut write request
    (the vector path's horizon). The loop must know that call when it meets the copy: the vector path leaves
    every call of a key the loop meets to the loop, and one batch, small batches and the loop alone agree."""
    from devtools.fuzz.mutated import mutated_capture

    path = tmp_path / "mutated.pcap"
    mutated_capture(path, 14100)
    want = analysed(str(path), vector=False)
    if shared_captures():  # (the seeds of CI: with the shared captures; a plain clone's capture differs)
        txns = want.transactions.set_index("txn")
        assert (txns.loc[385, "frames"], txns.loc[385, "rpc_retransmissions"]) == ("2552 2553 2554 2555 14004 14005",
                                                                                    1)
        assert txns.loc[1153, ["frames", "verdict", "closed_by"]].tolist() == ["14002", "timeout", "capture_end"]
    for size in (0, 1000):
        assert_same(analysed(str(path), size), want)


def test_analyze_is_the_engine(generated: dict[str, Path]) -> None:
    """pd_analyze.analyze() reads captures through the same engine, whatever their size."""
    assert_same(pd_analyze.analyze(str(generated["mix"])), analysed(str(generated["mix"])))


# --- the parameters table's address labels, a column at a time ------------------------------------------------
@pytest.mark.parametrize("repeat", [1, 200])  # under and over _labels' threshold for making each text once
def test_address_labels_as_columns_equal_the_reference_label(repeat: int) -> None:
    """tables._labels gives profidrive.Address.label of every address (protocol.md 3.3), the last element of a
    range counted past 65535 as the reference counts it (a 16-bit sum wrapped to 'P1[65535..1]')."""
    from pd_analyze.analysis.engine.tables import _labels
    from pd_analyze.model import pd_values as pt
    from pd_analyze.protocol.profidrive import Address

    cases = [(pt.ATTR_VALUE, 1, 1, 0), (pt.ATTR_VALUE, 3, 1, 65535), (pt.ATTR_VALUE, 0, 964, 2),
             (pt.ATTR_DESCRIPTION, 5, 2000, 7), (pt.ATTR_VALUE, 255, 65535, 65535), (pt.ATTR_TEXT, 2, 61000, 0)]
    cases = cases * repeat
    attr = np.array([c[0] for c in cases], np.uint8)
    n_elems = np.array([c[1] for c in cases], np.uint8)
    pnu = np.array([c[2] for c in cases], np.uint16)
    sub = np.array([c[3] for c in cases], np.uint16)
    count = np.maximum(n_elems, 1)
    got = _labels(pnu, sub, count, (attr == pt.ATTR_VALUE) & (count > 1)).to_pylist()
    want = [Address(0, *c).label() for c in cases]
    assert got == want
    assert want[:6] == ["P1[0]", "P1[65535..65537]", "P964[2]", "P2000[7]", "P65535[65535..65789]", "P61000[0]"]
