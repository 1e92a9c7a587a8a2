"""The fuzz harness (devtools.fuzz): a quick deterministic run, and proof that it catches what it claims to.

The long run (1,000,000 mutated frames, README "Robustness") is `python -m devtools.fuzz --frames 1000000
--seed 1 --jobs 2`; this quick run feeds 100,000 mutated frames (about half a minute on two cores).
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from devtools.fuzz import campaign, corpus, harness, mutators
from pd_analyze import capture
from pd_analyze.output import dump
from pd_analyze.protocol import profidrive, rpc
from pd_analyze.protocol.frames import Accounting

QUICK_FRAMES = 100_000
QUICK_SEED = 20_260_101


@pytest.fixture(scope="module")
def seeds() -> list[corpus.Seed]:
    return corpus.load_seeds(corpus.seed_paths())


def test_every_capture_is_a_seed(seeds: list[corpus.Seed]) -> None:
    paths = corpus.seed_paths()
    assert any(p.endswith("worked_example.pcap") for p in paths)
    assert {s.path for s in seeds} == {p for p in paths if list(capture.frames(p))}
    assert sum(1 for s in seeds for f in s.frames if f.rpc >= 0) > 100  # frames with a DCE/RPC header
    assert all(f.fields for s in seeds for f in s.frames if f.rpc >= 0)  # mutations know their fields


def test_quick_run_no_crash_no_hang_invariant_holds() -> None:
    stats = campaign.fuzz(QUICK_FRAMES, base_seed=QUICK_SEED, jobs=2)
    text = campaign.report_text(stats, QUICK_FRAMES, QUICK_SEED, 2)
    assert stats.mutated >= QUICK_FRAMES, text
    assert stats.ok, text  # no crash, no hang, accounting and field bounds held, output inert
    assert stats.files > 500 and stats.file_frames > 10_000 and stats.transactions > 1000, text


def test_cases_replay_exactly(seeds: list[corpus.Seed]) -> None:
    for number in (0, 1, 4711):
        a, b = mutators.make_case(seeds, number, 3), mutators.make_case(seeds, number, 3)
        assert a.frames == b.frames and a.seed == b.seed
    assert mutators.make_case(seeds, 5, 3).frames != mutators.make_case(seeds, 5, 4).frames
    mutated = [mutators.make_case(seeds, n, 3) for n in range(200)]
    assert sum(c.mutated for c in mutated) > 0.8 * sum(len(c.frames) for c in mutated)


def test_file_mutations_cover_lengths_and_truncation(seeds: list[corpus.Seed]) -> None:
    import random

    seed = next(s for s in seeds if s.name == "worked_example.pcap")
    records = mutators._records(seed.data)
    assert [r[0] for r in records][:2] == [24, 24 + 16 + len(seed.frames[0].raw.data)]
    outcomes = set()
    for n in range(300):
        mutated = mutators.mutate_file(random.Random(n), seed.data)
        path = Path(harness._tmp_root() or "/tmp") / f"pd-fuzz-test-{n}.pcap"
        path.write_bytes(mutated)
        try:
            list(capture.frames(str(path)))
            outcomes.add("read")
        except capture.CaptureError as exc:
            outcomes.add(exc.reason.split(" ")[0])
        finally:
            path.unlink()
    assert "read" in outcomes and len(outcomes) >= 4, outcomes  # damaged in several distinct ways


def test_a_crash_is_reported(seeds: list[corpus.Seed], monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(*args: object, **kwargs: object) -> None:
        raise ValueError("planted bug")

    monkeypatch.setattr(profidrive, "parse_response", broken)
    stats = harness.Runner(seeds, 1).run(0, 64)
    assert stats.crashes and "ValueError: planted bug" in stats.crashes[0] and not stats.ok


def test_a_hang_is_reported(seeds: list[corpus.Seed], monkeypatch: pytest.MonkeyPatch) -> None:
    real = rpc.header

    def slow(payload: bytes) -> rpc.Header:
        time.sleep(5)
        return real(payload)

    monkeypatch.setattr(rpc, "header", slow)
    started = time.perf_counter()
    stats = harness.Runner(seeds, 1, frame_limit=0.05).run(0, 3)
    assert stats.hangs and "more than 0.05 s" in stats.hangs[0]
    assert time.perf_counter() - started < 10  # interrupted, not waited for


def test_a_broken_invariant_is_reported(seeds: list[corpus.Seed], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(Accounting, "balanced", lambda self: False)
    stats = harness.Runner(seeds, 1).run(0, 8)
    assert stats.violations and "accounting" in stats.violations[0]


def test_raw_terminal_output_is_reported(seeds: list[corpus.Seed], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(dump, "safe", lambda text: text)  # as if the dump forgot to escape
    crafted = [s for s in seeds if s.name == "crafted_strings.pcap"]
    assert crafted, "sample_pcaps/crafted_strings.pcap missing"
    stats = harness.Runner(crafted, 1).run(0, 40)
    assert any("text dump emits" in v for v in stats.violations)
