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


def test_chain_drilldown_follows_the_chain_numbering(tmp_path):
    """fields() and the HTML drill-down find a chained transaction's frames by the report's numbers, in
    whichever file each frame is (frames 4-6 are frames 1-3 of the second file)."""
    from pd_analyze.output import html_drill

    a, b = tmp_path / "ring_00001.pcap", tmp_path / "ring_00002.pcap"
    split_pcap(SAMPLES / "worked_example.pcap", 3, a, b)
    chained = pd_analyze.analyze([str(a), str(b)], chain=True)
    f = chained.fields(1)
    assert sorted(set(f.frame)) == [1, 2, 3, 4, 5, 6]
    assert f.loc[f.name == "rpc.seq", ["frame", "value"]].values.tolist() == [[1, 1], [2, 1], [3, 2], [4, 2],
                                                                             [5, 3], [6, 3]]
    assert f.loc[f.name == "pd.resp_id", "frame"].tolist() == [6]  # the response, in the second file
    drill = html_drill.drilldown(chained, chained.transactions)
    assert [item["n"] for item in drill[1]["F"]] == [1, 2, 3, 4, 5, 6]
    whole = pd_analyze.analyze(str(SAMPLES / "worked_example.pcap")).fields(1)
    assert f.drop(columns="value").equals(whole.drop(columns="value"))  # as if one capture


def test_parquet_dataset_partitioned_by_capture(tmp_path):
    from pd_analyze.output import report

    files = [str(SAMPLES / "record_rw_le.pcap"), str(SAMPLES / "worked_example.pcap")]
    analysis = pd_analyze.analyze(files)
    report.write_tables(analysis, str(tmp_path), "parquet")
    parts = sorted(p.parent.name for p in (tmp_path / "transactions").rglob("*.parquet"))
    assert len(parts) == 2 and all(p.startswith("capture=") for p in parts)
    back = pd.read_parquet(tmp_path / "transactions")
    assert sorted(back.txn.tolist()) == [1, 2, 3, 4, 5]
    assert set(back.capture.astype(str)) == {"record_rw_le.pcap", "worked_example.pcap"}  # file names (#16)
    assert sorted(parts) == ["capture=record_rw_le.pcap", "capture=worked_example.pcap"]


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


def test_jobs_on_one_large_capture_gives_the_tables_of_one_process(tmp_path):
    """A file under PARALLEL_MIN_BYTES is analysed in one process whatever --jobs says; one over it has its
    decode split (tests/test_split.py): either way the tables and the accounting are those of --jobs 1."""
    from devtools.synth.mixed_capture import make_capture

    path = tmp_path / "mixed.pcap"
    count = make_capture(path, 12_000, pnio_share=0.5, faults=0.05)
    one = pd_analyze.analyze(str(path), timeout=0.3, rpc_timeout=0.2)
    two = pd_analyze.analyze(str(path), timeout=0.3, rpc_timeout=0.2, jobs=2)
    assert_same_tables(one, two)
    pd.testing.assert_frame_equal(one.accounting, two.accounting)
    assert int(two.accounting.read.iloc[0]) == count and two.accounting.balanced.all()
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
