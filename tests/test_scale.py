"""Many captures: --jobs gives the same tables as one process, --chain pairs across files,
Parquet datasets are partitioned by capture, and the Dask API runs on a local two-worker cluster."""

import struct
from pathlib import Path

import pandas as pd
import pytest

import pd_analyze
from pd_analyze.capture import frames

SAMPLES = Path("sample_pcaps")


def assert_same_tables(one: pd_analyze.Analysis, two: pd_analyze.Analysis) -> None:
    for name in ("transactions", "parameters", "findings", "changes"):
        pd.testing.assert_frame_equal(getattr(one, name), getattr(two, name))


def split_and_whole(path: Path, monkeypatch: pytest.MonkeyPatch, jobs: int) -> tuple:
    """One process, and `jobs` processes over parts with a 0.5 s lead-in (short timeouts to match):
    the parts really start mid-stream with calls and channels open. Their tables must be equal."""
    from pd_analyze.analysis import jobs as job_ways
    from pd_analyze.analysis import split

    monkeypatch.setattr(split, "LEAD_IN", 0.5)
    monkeypatch.setattr(job_ways, "PARALLEL_MIN_BYTES", 0)
    one = pd_analyze.analyze(str(path), timeout=0.3, rpc_timeout=0.2)
    two = pd_analyze.analyze(str(path), timeout=0.3, rpc_timeout=0.2, jobs=jobs)
    assert_same_tables(one, two)
    return one, two


def split_pcap(src: Path, cut: int, a: Path, b: Path) -> None:
    """Write frames 1..cut to a and the rest to b (a ring buffer's two files)."""
    raw = src.read_bytes()
    header, pos, records = raw[:24], 24, []
    while pos < len(raw):
        caplen = struct.unpack_from("<I", raw, pos + 8)[0]
        records.append(raw[pos:pos + 16 + caplen])
        pos += 16 + caplen
    a.write_bytes(header + b"".join(records[:cut]))
    b.write_bytes(header + b"".join(records[cut:]))


def test_jobs_gives_identical_tables(monkeypatch):
    from pd_analyze.analysis import jobs as job_ways

    monkeypatch.setattr(job_ways, "PARALLEL_MIN_BYTES", 0)  # the samples are small: force the processes
    files = sorted(str(p) for p in SAMPLES.glob("*.pcap*"))[:8]
    one = pd_analyze.analyze(files)
    two = pd_analyze.analyze(files, jobs=2)
    assert_same_tables(one, two)
    assert one.transactions.txn.tolist() == list(range(1, len(one.transactions) + 1))


def test_chain_pairs_a_transaction_split_over_two_files(tmp_path):
    a, b = tmp_path / "ring_00001.pcap", tmp_path / "ring_00002.pcap"
    split_pcap(SAMPLES / "worked_example.pcap", 3, a, b)
    assert [f.number for f in frames(str(b))] == [1, 2, 3]
    apart = pd_analyze.analyze([str(a), str(b)])
    assert apart.transactions.verdict.tolist() == ["timeout"]
    assert bool(apart.transactions.capture_ended.iloc[0])
    assert "read_without_request" in apart.findings.name.tolist()
    chained = pd_analyze.analyze([str(a), str(b)], chain=True)
    (t,) = chained.transactions.itertuples()
    assert (t.verdict, t.capture, t.write_req_frame, t.read_res_frame, t.b5_retries) == ("ok", str(a), 1, 6, 1)
    acc = chained.accounting
    assert acc.read.tolist() == [3, 3] and acc.balanced.all()
    assert chained.findings.empty


def test_parquet_dataset_partitioned_by_capture(tmp_path):
    from pd_analyze.output import report

    files = [str(SAMPLES / "record_rw_le.pcap"), str(SAMPLES / "worked_example.pcap")]
    analysis = pd_analyze.analyze(files)
    report.write_tables(analysis, str(tmp_path), "parquet")
    parts = sorted(p.parent.name for p in (tmp_path / "transactions").rglob("*.parquet"))
    assert len(parts) == 2 and all(p.startswith("capture=") for p in parts)
    back = pd.read_parquet(tmp_path / "transactions")
    assert sorted(back.txn.tolist()) == [1, 2, 3, 4, 5]
    assert set(back.capture.astype(str)) == set(files)


def test_dask_api_on_a_local_two_worker_cluster():
    distributed = pytest.importorskip("distributed")
    import pd_analyze.analysis.distributed as pdd

    files = [str(SAMPLES / "record_rw_le.pcap"), str(SAMPLES / "worked_example.pcap"),
             str(SAMPLES / "vlan_stacked.pcap")]
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    with cluster, distributed.Client(cluster):
        tables = pdd.analyze(files)
        assert tables.transactions.npartitions == 3
        got = tables.transactions.compute()
        acc = tables.accounting.compute()
    assert got.groupby("capture", observed=True).size().to_dict() == {files[0]: 4, files[1]: 1, files[2]: 3}
    assert got.verdict.astype(str).tolist() == ["ok"] * 8
    assert acc.read.tolist() == [30, 6, 14]


def test_jobs_splits_one_large_capture_identically(tmp_path, monkeypatch):
    from devtools.synth.mixed_capture import make_capture

    path = tmp_path / "mixed.pcap"
    count = make_capture(path, 12_000, pnio_share=0.5)
    one, two = split_and_whole(path, monkeypatch, jobs=2)
    assert int(one.accounting.read.iloc[0]) == int(two.accounting.read.iloc[0]) == count
    assert two.accounting.balanced.all()
    assert len(one.transactions) > 900


def test_small_inputs_are_analysed_in_one_process(monkeypatch):
    """Process start-up would cost more than a few small captures take: --jobs runs them in-process."""
    import concurrent.futures

    from pd_analyze.analysis import jobs as analysis

    def no_pool(*args, **kwargs):
        raise AssertionError("a process pool was started")

    monkeypatch.setattr(concurrent.futures, "ProcessPoolExecutor", no_pool)
    files = sorted(str(p) for p in SAMPLES.glob("*.pcap*"))[:8]
    assert analysis._input_bytes(files) < analysis.PARALLEL_MIN_BYTES
    two = pd_analyze.analyze(files, jobs=2)
    pd.testing.assert_frame_equal(pd_analyze.analyze(files).transactions, two.transactions)
    assert analysis._input_bytes(["x.pcap.gz", "-"]) == 2 * analysis.PARALLEL_MIN_BYTES  # unknown: parallel


def test_split_parts_stitch_value_before_from_reads_before_their_lead_in(tmp_path, monkeypatch):
    """A change in the second part whose parameter was last read long before (beyond the lead-in):
    the parent fills in value_before from the earlier part's reads, so the tables equal one process."""
    from devtools.synth.capture_files import pcap_bytes
    from devtools.synth.fixtures import session
    from devtools.synth.pd_encode import ParamAddress as P
    from devtools.synth.pd_encode import change_ok, change_request, pd_response, read_request, value_block
    from devtools.synth.sim_capture import Capture

    cap = Capture()
    s = session(cap, 1)
    s.parameter_access(read_request(1, 1, [P(1120, n_elems=2)]), pd_response(1, 1, 1, [value_block(0x43, [7, 8])]))
    for ref in range(2, 3000):  # some 10 s of other reads: the lead-in below reaches back 0.5 s only
        s.parameter_access(read_request(ref % 255 + 1, 1, [P(964)]), pd_response(ref % 255 + 1, 1, 1,
                                                                                   [value_block(0x42, [3])]))
        cap.clock.advance_us(3000)
    s.parameter_access(change_request(9, 1, [(P(1120, n_elems=2), value_block(0x43, [9, 9]))]), change_ok(9, 1, 1))
    path = tmp_path / "late_change.pcap"
    path.write_bytes(pcap_bytes(cap.frames))
    one, two = split_and_whole(path, monkeypatch, jobs=2)
    assert one.changes.value_before.tolist() == ["7 8"]


def test_split_parts_stitch_reference_reuse_across_the_split(tmp_path, monkeypatch):
    """T1 on the first write of a channel in the second part: its last transaction lies in the lead-in
    (numbered by the first part) or before it (the channel idle longer); both as in one process."""
    from devtools.synth.capture_files import pcap_bytes
    from devtools.synth.fixtures import session
    from devtools.synth.pd_encode import ParamAddress as P
    from devtools.synth.pd_encode import pd_response, read_request, value_block
    from devtools.synth.sim_capture import Capture

    cap = Capture()
    busy, idle = session(cap, 1), session(cap, 2)

    def access(s, ref: int) -> None:
        s.parameter_access(read_request(ref, 1, [P(964)]), pd_response(ref, 1, 1, [value_block(0x42, [3])]))

    access(idle, 9)
    for _ in range(1500):  # the busy channel keeps reference 5 (T1 each time), some 4 s in all
        access(busy, 5)
        cap.clock.advance_us(2500)
    access(idle, 9)  # idle for 4 s, far beyond the 0.5 s lead-in
    path = tmp_path / "reuse.pcap"
    path.write_bytes(pcap_bytes(cap.frames))
    one, two = split_and_whole(path, monkeypatch, jobs=3)
    assert one.findings.name.value_counts().to_dict() == {"reference_reused": 1499 + 1}


def test_split_parts_read_about_as_much_with_their_lead_in():
    from pd_analyze.analysis import split as analysis

    points = [(i * 512 + 1, 24 + i * 40_000, i * 0.1) for i in range(1000)]  # a split point every 0.1 s
    leads = analysis._lead_points(points, 20.0)
    assert leads[:3] == [0, 0, 0] and leads[500] == 300  # 200 points = 20 s before
    for jobs in (2, 3, 4):
        starts = analysis._balanced_starts(leads, len(points), jobs)
        ends = [*starts[1:], len(points)]
        work = [end - (leads[start] if k else 0) for k, (start, end) in enumerate(zip(starts, ends, strict=True))]
        assert starts[0] == 0 and starts == sorted(starts) and max(work) - min(work) <= 1, (jobs, work)
    assert analysis._balanced_starts(analysis._lead_points(points[:4], 20.0), 4, 2) == [0, 2]  # no room: halves


def test_long_captures_split_into_parts_of_bounded_length(tmp_path, monkeypatch):
    """More parts than workers once a capture is longer than PART_LEAD_INS lead-ins: each worker's rows
    stay bounded by a part's length, and the tables still equal one process."""
    from devtools.synth.mixed_capture import make_capture
    from pd_analyze.analysis import jobs as job_ways
    from pd_analyze.analysis import split as analysis

    path = tmp_path / "long.pcap"
    make_capture(path, 12_000, pnio_share=0.5)
    monkeypatch.setattr(analysis, "LEAD_IN", 0.05)
    monkeypatch.setattr(analysis, "PART_LEAD_INS", 4)
    monkeypatch.setattr(job_ways, "PARALLEL_MIN_BYTES", 0)
    tasks = []
    real = analysis._analyze_range
    monkeypatch.setattr(analysis, "_analyze_range", lambda task: (tasks.append(task), real(task))[1])
    from concurrent.futures import ThreadPoolExecutor  # the counting wrapper cannot be pickled

    monkeypatch.setattr("concurrent.futures.ProcessPoolExecutor", ThreadPoolExecutor)
    one = pd_analyze.analyze(str(path), timeout=0.02, rpc_timeout=0.02)
    two = pd_analyze.analyze(str(path), timeout=0.02, rpc_timeout=0.02, jobs=2)
    assert len(tasks) > 2
    assert_same_tables(one, two)
    points = [(1, 24, 0.0), (513, 99, 5.0), (1025, 199, 3.0), (1537, 299, 30.0)]  # time goes back at 2
    assert analysis._lead_points(points, 2.5) == [0, 0, 0, 2]
