"""Transactions end to end on the samples: verdicts and figures asserted exactly."""

import pytest

import pd_analyze

SAMPLES = "sample_pcaps"


def test_worked_example_transaction_figures():
    a = pd_analyze.analyze(f"{SAMPLES}/worked_example.pcap")
    (t,) = a.transactions.itertuples()
    assert (t.txn, t.verdict, t.ref, t.req_id, t.do, t.n_params, t.params) == (
        1, "ok", 1, "0x01", 1, 2, "P964[0] P2000[0..2]")
    assert (t.b5_retries, t.reads, t.write_req_frame, t.write_res_frame, t.read_req_frames, t.read_res_frame) == (
        1, 2, 1, 2, "3 5", 6)
    assert t.t_write_rtt == pytest.approx(0.0021, abs=2e-6)
    assert t.t_total == pytest.approx(0.0163, abs=2e-6)
    assert t.t_final_read_rtt == pytest.approx(0.0017, abs=2e-6)
    assert (t.device, t.controller, t.index, t.resp_id, t.pnio_status, t.capture_ended) == (
        "192.168.0.2", "192.168.0.1", "0xb02e", "0x01", "", False)
    p = a.parameters
    assert p.param.tolist() == ["P964[0]", "P2000[0..2]"]
    assert p.values_read.tolist() == ["0x1234", "0x00000001 0x00000002 0x00000003"]
    assert a.findings.empty and bool(a.accounting.balanced.iloc[0])


def test_record_rw_samples_both_byte_orders():
    for name in ("record_rw_le.pcap", "record_rw_be.pcap", "record_rw_le.pcap.gz"):
        a = pd_analyze.analyze(f"{SAMPLES}/{name}")
        t = a.transactions
        assert t.verdict.tolist() == ["ok"] * 4, name
        assert t.b5_retries.tolist() == [1, 0, 2, 0]
        assert t.ref.tolist() == [1, 2, 3, 4]
        assert t["index"].tolist() == ["0xb02e", "0xb02e", "0xb02e", "0xb02f"]
        assert t.params.tolist() == ["P964[0]", "P1120[0]", "P2000[0] P2001[0..1] P107[0..2]", "P10[0]"]
        c = a.changes
        assert (c.param.tolist(), c.value_written.tolist(), c.result.tolist()) == (["P1120[0]"], ["10"], ["ok"])
        acc = a.accounting.iloc[0]
        assert (acc.read, acc.decoded, acc.skipped, acc.malformed) == (30, 22, 8, 0)


def test_truncated_write_makes_a_malformed_transaction():
    a = pd_analyze.analyze(f"{SAMPLES}/truncated_snaplen.pcap")
    assert a.transactions.verdict.tolist() == ["ok", "malformed"]
    f = a.findings
    assert sorted(zip(f.frame, f.name, strict=True)) == [
        (7, "record_truncated"), (7, "rpc_truncated"), (7, "truncated_capture_pnio"), (7, "txn_failed"),
        (11, "truncated_capture")]  # T8 at the write request that cannot be decoded (protocol.md 6.5)
    assert f.loc[f.frame == 7, "txn"].tolist() == [2, 2, 2, 2]
    assert f.loc[f.frame == 11, "txn"].isna().all()


def test_routing_samples_pair_without_ports():
    a = pd_analyze.analyze([f"{SAMPLES}/other_port_response.pcap", f"{SAMPLES}/implicit_read.pcap",
                            f"{SAMPLES}/write_multiple.pcap", f"{SAMPLES}/ip_fragments.pcap"])
    t = a.transactions
    assert t.verdict.tolist() == ["ok"] * 4 and t.txn.tolist() == [1, 2, 3, 4]
    assert t.capture.astype(str).str.rsplit("/", n=1).str[-1].tolist() == [
        "other_port_response.pcap", "implicit_read.pcap", "write_multiple.pcap", "ip_fragments.pcap"]
    assert t.rpc_retransmissions.tolist() == [1, 0, 0, 0]
    assert t.b5_retries.tolist() == [1, 0, 1, 0]


def test_drill_down_fields_of_a_transaction():
    a = pd_analyze.analyze(f"{SAMPLES}/worked_example.pcap")
    fields = a.fields(1)
    assert sorted(set(fields.frame)) == [1, 2, 3, 4, 5, 6]
    row = fields[(fields.frame == 6) & (fields.name == "pd.val[0].value[0]")].iloc[0]
    assert (row.offset, row.raw, row.show) == (0xD4, "12 34", "0x1234")


def test_retransmissions_of_an_unanswered_call_count_in_a_timeout(tmp_path):
    """protocol.md 7.6: rpc_retransmissions counts the duplicate request PDUs of the transaction, also of a call
    that is never answered (the CL-RPC client re-sends it before the transaction times out). The engine
    used to add a call's copies only when its response arrived, so this timeout reported 0."""
    from devtools.synth import fixtures, pnio_encode
    from devtools.synth.pd_encode import ParamAddress, read_request
    from devtools.synth.sim_capture import Capture

    cap = Capture()
    s = fixtures.session(cap, 1)
    s.parameter_access(read_request(1, 1, [ParamAddress(964)]), None, b5_retries=1)
    s.read(0xB02E, respond=False, retransmit_after_us=[1_000_000, 2_000_000])  # sent three times, never answered
    s.write(0xB02E, read_request(2, 1, [ParamAddress(964)]), retransmit_after_us=[20_000])  # answered after a copy
    s.read(0xB02E, status=pnio_encode.STATUS_B5, retransmit_after_us=[20_000])
    path = tmp_path / "unanswered_retransmitted.pcap"
    path.write_bytes(fixtures.pcap_of(cap))
    t = pd_analyze.analyze(str(path)).transactions
    assert t.verdict.tolist() == ["timeout", "timeout"]  # the first superseded by the second write
    assert t.closed_by.astype(str).tolist() == ["superseded", "capture_end"]
    assert t.rpc_retransmissions.tolist() == [2, 2]
    assert t.reads.tolist() == [2, 1] and t.b5_retries.tolist() == [1, 1]
