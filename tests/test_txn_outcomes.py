"""How a transaction ended, said at the frame that decided it (issue #28 points 3 and 4, protocol.md 6.5): T8
txn_failed and T9 txn_refused, T3 naming the verdict the superseded transaction gets; H1/H2 making a
transaction malformed (7.4 rule 1); the same findings whichever way (loop or vector) a transaction went.
Exact lines on the generated samples (sample_pcaps/README.md says what each holds)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

import pd_analyze
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.analysis.engine.run import analyze_frames
from pd_analyze.analysis.rows import Rows
from pd_analyze.capture.reader import frames as read_frames
from pd_analyze.model.rules import RULES, TRANSACTION_RULES

SAMPLES = Path(__file__).resolve().parents[1] / "sample_pcaps"


def audit_lines(name: str, *rules: str) -> list[str]:
    r = subprocess.run([sys.executable, "-m", "pd_analyze.cli", "audit", str(SAMPLES / name)], capture_output=True,
                       text=True, timeout=120)
    return [line.split(":", 1)[1] for line in r.stdout.splitlines() if any(f" {rule} " in line for rule in rules)]


def test_t8_and_t9_are_registered_transaction_rules() -> None:
    assert (RULES["txn_failed"].id, RULES["txn_failed"].severity) == ("T8", "warning")
    assert (RULES["txn_refused"].id, RULES["txn_refused"].severity) == ("T9", "info")
    assert {"txn_failed", "txn_refused"} <= TRANSACTION_RULES


def test_refused_record_services_faults_and_rejects() -> None:
    """pd_b5_and_pnio_errors: writes refused DF80B1/B0/B7, reads refused DE80B1/B2, a fault and a reject: T8 at
    the answer, with the status in words."""
    assert audit_lines("pd_b5_and_pnio_errors.pcap", "T8") == [
        "26: warning T8 txn_failed: the transaction of frame 25 failed: pnio_error: DF80B100 write: access write "
        "length error (parameter request above the record limit or shorter than its header, or read buffer too "
        "small) (in the answer to the write) [txn 3]",
        "28: warning T8 txn_failed: the transaction of frame 27 failed: pnio_error: DF80B000 write: access invalid "
        "index (no parameter access point at this slot/subslot/index) (in the answer to the write) [txn 4]",
        "30: warning T8 txn_failed: the transaction of frame 29 failed: pnio_error: DF80B700 write: access invalid "
        "range (error in the parameter request header) (in the answer to the write) [txn 5]",
        "34: warning T8 txn_failed: the transaction of frame 31 failed: pnio_error: DE80B100 read: access write "
        "length error (parameter request above the record limit or shorter than its header, or read buffer too "
        "small) (in the answer to the read) [txn 6]",
        "40: warning T8 txn_failed: the transaction of frame 35 failed: pnio_error: DE80B200 read: access invalid "
        "slot/subslot (in the answer to the read) [txn 7]",
        "42: warning T8 txn_failed: the transaction of frame 41 failed: pnio_error: 1C010014 RPC fault/reject: "
        "nca_server_too_busy (in the answer to the write) [txn 8]",
        "48: warning T8 txn_failed: the transaction of frame 43 failed: pnio_error: 1C01000B RPC fault/reject: "
        "nca_proto_error (in the answer to the read) [txn 9]",
    ]


def test_unanswered_busy_superseded_malformed_and_refused() -> None:
    """pd_edge_cases: two cut writes (malformed at the cut request), a deadline mid-capture, a busy drive given up
    by the next write (T3 names its verdict, T8 at that write) and by the deadline, two whole-request NAKs (T9
    with the error's text), a transaction still open at the capture's end."""
    assert audit_lines("pd_edge_cases.pcap", "T3", "T8", "T9") == [
        "1: warning T8 txn_failed: the transaction of frame 1 failed: malformed: the write request of frame 1 "
        "cannot be decoded [txn 1]",
        "9: warning T8 txn_failed: the transaction of frame 9 failed: malformed: the write request of frame 9 "
        "cannot be decoded [txn 2]",
        "19: warning T8 txn_failed: the transaction of frame 19 failed: timeout: no final response within 10 s "
        "[txn 4]",
        "37: warning T3 write_while_pending: write while the transaction of frame 29 (ref 1) is pending: it ends "
        "as pnio_error DE80B500 (busy: every read answered B5) [txn 7]",
        "37: warning T8 txn_failed: the transaction of frame 29 failed: pnio_error: DE80B500 read: access state "
        "conflict (PROFIdrive: response not ready yet / request still processed): every read answered B5 (3), "
        "superseded by the write of frame 37 [txn 6]",
        "43: warning T8 txn_failed: the transaction of frame 43 failed: pnio_error: DE80B500 read: access state "
        "conflict (PROFIdrive: response not ready yet / request still processed): every read answered B5 (4), no "
        "final response within 10 s [txn 8]",
        "64: info T9 txn_refused: the drive refused the transaction of frame 61: the whole request: error 0x23 "
        "(multi-parameter access not supported) [txn 10]",
        "68: info T9 txn_refused: the drive refused the transaction of frame 65: the whole request: error 0x16 "
        "(parameter address impermissible (attribute, elements, PNU, subindex or combination)) [txn 11]",
        "69: warning T8 txn_failed: the transaction of frame 69 failed: timeout: the capture ended, after 2 B5 "
        "answers [txn 12]",
    ]


def test_a_nak_names_each_error_of_its_parameters() -> None:
    lines = audit_lines("fault_trace.pcap", "T9")
    assert len(lines) == 7
    assert lines[0] == ("22: info T9 txn_refused: the drive refused the transaction of frame 19: P2[0]: error 0x01 "
                        "(parameter value cannot be changed) [txn 5]")


def test_a_superseded_timeout_is_named_a_timeout() -> None:
    """T3 on a write while an unanswered transaction is pending: the old one ends a timeout, and T3 says so."""
    a = pd_analyze.analyze(str(SAMPLES / "pd_interleaved.pcap"))
    f = a.findings
    t3 = f[f.name == "write_while_pending"]
    t = a.transactions.set_index("txn")
    for message, txn in zip(t3.message, t3.txn, strict=True):
        old = int(message.split("transaction of frame ")[1].split()[0])
        verdict = t[t.write_req_frame == old].verdict.iloc[0]
        assert message.endswith("it ends as a timeout" if verdict == "timeout" else f"it ends as {verdict} "
                                f"{t[t.write_req_frame == old].pnio_status.iloc[0]} (busy: every read answered B5)")
        del txn


@pytest.mark.parametrize("name", ["pd_timeouts.pcap", "pd_edge_cases.pcap", "pd_b5_and_pnio_errors.pcap"])
def test_audit_fails_on_warning_where_parameter_access_failed(name: str) -> None:
    r = subprocess.run([sys.executable, "-m", "pd_analyze.cli", "audit", str(SAMPLES / name), "--fail-on", "warning"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and " T8 txn_failed: " in r.stdout


def test_refusals_alone_are_info() -> None:
    """audit_commissioning: two NAKs and nothing else: T9 (info) does not fail --fail-on warning."""
    r = subprocess.run([sys.executable, "-m", "pd_analyze.cli", "audit", str(SAMPLES / "audit_commissioning.pcap"),
                        "--fail-on", "warning"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0
    assert [line.split(":", 1)[1].split(" T9 ")[0] for line in r.stdout.splitlines() if " T9 " in line] == \
        ["8: info", "12: info"]


@pytest.mark.parametrize("name", ["fault_trace.pcap", "pd_b5_and_pnio_errors.pcap", "pd_retries_and_duplicates.pcap",
                                  "pd_edge_cases.pcap"])
def test_loop_and_vector_raise_the_same_outcomes(name: str) -> None:
    tables = []
    for vector in (True, False):
        rows = Rows()
        analyze_frames(read_frames(str(SAMPLES / name)), Settings(vector=vector), rows, capture=name)
        tables.append(pd_analyze.Analysis(rows, [], "generic", 10.0, 5.0).findings)
    one, two = tables
    outcome = one.name.isin(["txn_failed", "txn_refused"])
    assert outcome.any()
    pd.testing.assert_frame_equal(one, two)


def test_a_blocklength_not_60_is_malformed() -> None:
    """A write request whose IOD BlockLength is 56 (H2), refused DF80B700 by the drive: malformed (protocol.md
    7.4 rule 1 comes before pnio_error), T8 at the request; the same by the loop and the vector path."""
    import tempfile

    from devtools.synth import fault_rich

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "h2.pcap"
        truth = fault_rich.make_fault_rich(path, 800, seed=5)
        a = pd_analyze.analyze(str(path))
    broken = [t for t in truth["transactions"] if t["kind"] == "broken_block_length"]
    assert broken
    t = a.transactions.set_index("write_req_frame")
    f = a.findings
    for item in broken:
        frame = item["write_req_frame"]
        assert t.loc[frame, "verdict"] == "malformed"
        at = f[(f.frame == frame)]
        assert {"block_length", "txn_failed"} <= set(at.name)
        assert at[at.name == "txn_failed"].message.iloc[0] == (
            f"the transaction of frame {frame} failed: malformed: the write request of frame {frame} cannot be "
            "decoded")
