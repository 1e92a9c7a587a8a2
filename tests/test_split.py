"""One capture on several cores (issue #25): `--jobs N` and `analysis.distributed.analyze_capture` decode its
pieces elsewhere and run the one engine over them in frame order. Their tables, accounting, errors and
summary are those of one process, byte for byte, wherever the split points fall: here they fall after every
frame (pieces of 1 record), or every 3rd or 7th, so every transaction, CL fragment set and IP datagram of
more than one frame straddles one."""

from __future__ import annotations

import random
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from devtools import hostile
from devtools.fuzz.corpus import load_seeds, seed_paths
from devtools.fuzz.mutators import make_case
from devtools.synth.capture_files import Frame, pcap_bytes
from pd_analyze.analysis import split
from pd_analyze.analysis.api import Analysis
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.analysis.rows import Rows
from pd_analyze.capture import frames
from pd_analyze.capture.batches import FrameBatch
from pd_analyze.capture.split import piece_batches, pieces
from tests.test_engine import TABLES, analysed, assert_same

SAMPLES = sorted(p for p in Path("sample_pcaps").glob("*") if p.suffix in (".pcap", ".pcapng", ".gz"))
WAYS = ((2, 1), (3, 3), (7, 7))  # (--jobs, records or frames between split points)


def split_run(path: str, jobs: int, every: int, **kw: object) -> Analysis:
    """The capture analysed in batches of `every` frames, its decode in `jobs` - 1 workers, a split point
    at every batch (a plain pcap: pieces of one batch, each read by its worker; pcapng, gzip: read in this
    process, each batch a worker's task). One process in batches of `every` frames is what it equals (the
    engine sees the very same batches)."""
    settings = Settings(batch_frames=every, **kw)
    rows, result = split.analyze_file(path, settings, jobs, piece_frames=every)
    return Analysis(rows, [result], settings.profile, settings.txn_timeout, settings.rpc_timeout)


@pytest.mark.parametrize("path", SAMPLES, ids=lambda p: p.name)
def test_samples_split_anywhere_give_the_tables_of_one_process(path: Path) -> None:
    for jobs, every in WAYS:
        assert_same(analysed(str(path), every), split_run(str(path), jobs, every))


def test_split_points_straddle_transactions_fragment_sets_and_datagrams() -> None:
    """Split after every frame, the samples above hold each kind of open state across split points: an IP
    datagram of three fragments and a transaction of five frames (ip_fragments.pcap, frames 1-3 and 5-9), a
    CL fragment set sent out of order (cl_fragments_fack.pcapng, read here and decoded a batch of one frame
    a task), the transactions of every other sample."""
    path = "sample_pcaps/ip_fragments.pcap"
    assert [p.first for p in pieces(path, piece_frames=1, size=1)] == list(range(1, 10))
    assert analysed(path).transactions.frames.tolist() == ["5 6 7 8 9"]
    assert len(split_run(path, 2, 1).transactions) == 1
    from pd_analyze.capture.batches import batches

    assert len(list(batches("sample_pcaps/cl_fragments_fack.pcapng", 1))) == 11


def _write(path: Path, raw: list) -> None:
    path.write_bytes(pcap_bytes([Frame(round(f.ts * 1e9), f.data) for f in raw], nanosecond=True))


@pytest.fixture(scope="module")
def fuzz_capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Mutated windows (over 3,000 frames) of the fuzz corpus's seeds one after the other (Ethernet ones with
    times a pcap holds): cut, flipped, spliced, flooded frames, and time going backwards where one case ends."""
    seeds = load_seeds(seed_paths())
    raw = []
    for number in range(300):
        case = make_case(seeds, number, base_seed=11)
        if all(f.linktype == 1 and 0 <= f.ts < 2**32 for f in case.frames):
            raw += case.frames
        if len(raw) > 3000:
            break
    path = tmp_path_factory.mktemp("fuzz") / "fuzz.pcap"
    _write(path, raw)
    return path


def test_fuzz_corpus_capture_split_anywhere(fuzz_capture: Path) -> None:
    one = analysed(str(fuzz_capture), profile="sinamics")
    assert int(one.accounting.read.sum()) > 3000
    for jobs, every in WAYS:
        path = str(fuzz_capture)
        assert_same(analysed(path, every, profile="sinamics"), split_run(path, jobs, every, profile="sinamics"))


def test_mutated_capture_split(tmp_path: Path) -> None:
    """devtools.fuzz.mutated's capture (the benchmark's, small): 30 % of the seeds' frames mutated."""
    from devtools.fuzz.mutated import mutated_capture

    path = tmp_path / "mutated.pcap"
    assert mutated_capture(path, 4000) == 4000
    one = analysed(str(path))
    assert int(one.accounting.read.sum()) == 4000
    for jobs, every in ((2, 5), (3, 61)):
        assert_same(analysed(str(path), every), split_run(str(path), jobs, every))


def test_time_going_backwards_split_anywhere(tmp_path: Path) -> None:
    """A capture whose clock steps back 30 s in the middle of its transactions (and forward again)."""
    raw = list(frames("sample_pcaps/pd_retries_and_duplicates.pcap"))
    shifted = [f._replace(ts=f.ts - 30.0) if 200 <= f.number < 400 else f for f in raw]
    path = tmp_path / "backwards.pcap"
    _write(path, shifted)
    one = analysed(str(path))
    assert len(one.transactions) > 200
    for jobs, every in WAYS:
        assert_same(analysed(str(path), every), split_run(str(path), jobs, every))


@pytest.mark.parametrize("kind", hostile.KINDS)
def test_floods_split(kind: str, tmp_path: Path) -> None:
    path = tmp_path / f"{kind}.pcap"
    hostile.write_pcap(kind, 3000, path, seed=5)
    one = analysed(str(path))
    assert int(one.accounting.read.sum()) == 3000
    for jobs, every in ((2, 7), (3, random.Random(5).choice((61, 500)))):
        assert_same(analysed(str(path), every), split_run(str(path), jobs, every))


@pytest.mark.parametrize("cut", ["truncated", "too_long"])
def test_damaged_pcap_split_reports_the_error_of_one_process(cut: str, tmp_path: Path) -> None:
    """The walk cuts no piece after the damage: the last piece's reader meets it and raises what one reader
    of the whole file raises (same text, same offset), after the same frames."""
    data = Path("sample_pcaps/pd_commissioning.pcap").read_bytes()
    path = tmp_path / "damaged.pcap"
    if cut == "truncated":
        path.write_bytes(data[:len(data) * 2 // 3])
    else:
        at = 24 + sum(16 + len(f.data) for f in list(frames("sample_pcaps/pd_commissioning.pcap"))[:9])  # record 10
        path.write_bytes(data[:at + 8] + (10**6).to_bytes(4, "little") + data[at + 12:])
    one = analysed(str(path))
    assert one.errors
    cut_points = pieces(str(path), piece_frames=1, size=1)
    assert cut_points[-1].stop is None
    if cut == "too_long":  # a cut at each batch (of one frame) before the damaged record 10, none after it
        assert [p.first for p in cut_points] == list(range(1, 10))
    for jobs, every in WAYS:
        two = split_run(str(path), jobs, every)
        assert_same(analysed(str(path), every), two)
        assert two.errors == one.errors


def test_pieces_are_the_batches_of_one_reader() -> None:
    """Each piece's reader makes the very batches `batches` makes of the same frames (numbers, times, bytes):
    the engine downstream is fed what one process feeds it."""
    from pd_analyze.capture.batches import batches

    def key(b: FrameBatch) -> tuple:
        frames = zip(b.start.tolist(), b.caplen.tolist(), strict=True)
        return b.number.tolist(), b.ns.tolist(), [bytes(b.buf[s:s + c]) for s, c in frames]

    for path in ("sample_pcaps/pd_interleaved.pcap", "sample_pcaps/pcap_nsec_be.pcap"):
        for every, size in ((1, 1), (4, 3), (1000, 1000), (1, 65_536)):
            cut = pieces(path, piece_frames=every, size=size)
            assert [key(b) for p in cut for b in piece_batches(path, p, size)] == [key(b) for b in batches(path, size)]
    assert pieces("sample_pcaps/cl_fragments_fack.pcapng") is None  # read in one process
    assert pieces("sample_pcaps/record_rw_le.pcap.gz") is None


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pd_analyze.cli", *args], capture_output=True, check=False,
                          timeout=600)


@pytest.fixture(scope="module")
def big(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A capture over PARALLEL_MIN_BYTES, so that --jobs 2 splits it (two pieces and more)."""
    from devtools.synth.mixed_capture import make_capture

    path = tmp_path_factory.mktemp("big") / "big.pcap"
    make_capture(path, 60_000, pnio_share=0.6, faults=0.05)
    return path


@pytest.mark.parametrize("command", ["report", "audit", "params"])
def test_cli_jobs_2_on_one_file_is_byte_for_byte_one_process(big: Path, command: str, tmp_path: Path) -> None:
    from pd_analyze.analysis.jobs import PARALLEL_MIN_BYTES

    assert big.stat().st_size > PARALLEL_MIN_BYTES and len(pieces(str(big))) >= 2
    outs = []
    for jobs in ("1", "2"):
        out = tmp_path / jobs
        extra = ["--out", str(out)] if command == "report" else []
        proc = _cli(command, str(big), "--jobs", jobs, *extra)
        files = {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()} if extra else {}
        outs.append((proc.returncode, proc.stdout, files))
    assert outs[0] == outs[1]
    assert outs[0][1]  # (something was compared)


def test_distributed_one_capture_on_a_local_two_worker_cluster(big: Path) -> None:
    distributed = pytest.importorskip("distributed", reason="dask is the optional extra pd-analyze[dask]")
    import pd_analyze.analysis.distributed as pdd

    one = analysed(str(big))
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    with cluster, distributed.Client(cluster) as client:
        tables = pdd.analyze_capture(str(big), client=client, piece_bytes=1 << 20)
        got = {name: getattr(tables, name).compute() for name in (*TABLES, "accounting")}
        fragments = pdd.analyze_capture("sample_pcaps/cl_fragments_fack.pcapng", client=client)  # read here
        cl = fragments.transactions.compute()
    assert len(pieces(str(big), piece_bytes=1 << 20)) >= 2
    for name in TABLES:
        pd.testing.assert_frame_equal(got[name], getattr(one, name), obj=name)
    pd.testing.assert_frame_equal(got["accounting"], one.accounting)
    pd.testing.assert_frame_equal(cl, analysed("sample_pcaps/cl_fragments_fack.pcapng").transactions)


def test_rows_of_a_split_run_go_to_the_sink_given() -> None:
    rows = Rows()
    _, result = split.analyze_file("sample_pcaps/pd_interleaved.pcap", Settings(), 2, rows=rows, piece_frames=5)
    assert result.transactions == len(analysed("sample_pcaps/pd_interleaved.pcap").transactions) > 0
