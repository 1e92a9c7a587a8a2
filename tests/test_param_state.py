"""Parameter state per drive (`params`, Analysis.parameter_state), the intended-set check (`audit --expect`)
and the comparison of two captures (`diff`), on the commissioning-audit samples."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

import pd_analyze
from devtools.synth import build
from pd_analyze.analysis import intended
from pd_analyze.analysis.capture_run import Settings
from pd_analyze.analysis.param_state import (
    STATE_COLUMNS,
    ParamCells,
    StateTable,
    TxnInfo,
    collect,
    state_of,
)
from pd_analyze.analysis.schema import TIME
from pd_analyze.output import param_diff
from tests.support import shared_capture

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_pcaps"
A = "sample_pcaps/audit_commissioning.pcap"  # the commands run from the repository root
B = "sample_pcaps/audit_recommissioning.pcap"
SET = "sample_pcaps/sets/audit_commissioning.csv"
HEADER = "device,do,pnu,subindex,value,tolerance\n"


@pytest.fixture(autouse=True)
def _at_root(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pd_analyze.cli", *args], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)


def pick(row: tuple, *names: str) -> tuple:
    index = [c.name for c in STATE_COLUMNS]
    return tuple(row[index.index(n)] for n in names)


# --- the state ----------------------------------------------------------------------------------------------

def test_state_of_the_commissioning_sample() -> None:
    state, results = collect([A], Settings())
    assert not [r.error for r in results if r.error]
    cols = ("device", "do", "param", "format", "written", "written_frame", "read", "read_frame", "agrees",
            "writes", "refused", "last_error", "last_error_text", "refused_frame")
    assert [pick(r, *cols) for r in state.rows()] == [
        ("192.168.1.21", 1, "P730[0]", "Unsigned8", "1", 1, "1", 16, True, 1, 0, "", "", None),
        ("192.168.1.21", 1, "P730[1]", "Unsigned8", "0", 1, "0", 16, True, 1, 0, "", "", None),
        ("192.168.1.21", 1, "P730[2]", "Unsigned8", "1", 1, "1", 16, True, 1, 0, "", "", None),
        ("192.168.1.21", 1, "P1000[0]", "Integer16", "-300", 1, "-300", 16, True, 1, 0, "", "", None),
        ("192.168.1.21", 1, "P1120[0]", "FloatingPoint32", "10", 1, "10", 16, True, 1, 0, "", "", None),
        # answered by a Zero block inside the 0x82 negative response: confirmed
        ("192.168.1.21", 1, "P1121[0]", "FloatingPoint32", "0.1", 5, "0.1", 16, True, 1, 0, "", "", None),
        ("192.168.1.21", 1, "P1300[0]", "Unsigned16", None, None, None, None, None, 2, 2, "0x02",
         "low or high limit exceeded", 9),
        ("192.168.1.21", 1, "P2900[0]", "VisibleString", "Pump1", 1, "Pump1", 16, True, 1, 0, "", "", None),
        ("192.168.1.22", 1, "P1120[0]", "FloatingPoint32", "10", 17, "10", 24, True, 1, 0, "", "", None),
    ]


def test_api_frame_is_typed_and_matches_the_streamed_state() -> None:
    df = pd_analyze.analyze(A).parameter_state
    assert list(df.columns) == [c.name for c in STATE_COLUMNS]
    assert str(df.written_t.dtype) == TIME and str(df.read_t.dtype) == TIME
    assert len(df) == 9 and df.pnu.tolist() == [730, 730, 730, 1000, 1120, 1121, 1300, 2900, 1120]
    state, _ = collect([A], Settings())
    assert df.equals(state.frame())
    assert df.station.tolist() == ["pump-1"] * 8 + [""]  # the PN-DCP Identify response of frame 25


def test_station_names_from_pn_dcp() -> None:
    """The promise on a sample: the name frame 25 of audit_commissioning announces is found by the columnar
    batches and by the per-frame path's own pass alike, per capture, in a set and in a chain."""
    from pd_analyze.analysis.jobs import run
    from pd_analyze.analysis.rows import Rows
    from pd_analyze.analysis.stations import names_in_file
    from pd_analyze.protocol.dcp import station

    for columns in (False, True):
        for size in (1, 7, 100, 0):
            results = run([B, A, "sample_pcaps/worked_example.pcap"], Rows(), Settings(vector=columns,
                                                                                        batch_frames=size))
            assert [r.stations for r in results] == [{}, {"192.168.1.21": "pump-1"}, {}], (columns, size)
        chain = run([B, A], Rows(), Settings(vector=columns), chain=True)
        assert [r.stations for r in chain] == [{}, {"192.168.1.21": "pump-1"}]
    assert names_in_file(A) == {"192.168.1.21": "pump-1"}
    assert names_in_file("-") == {} and names_in_file(str(ROOT / "sample_pcaps" / "absent.pcap")) == {}
    eth = bytes(12) + b"\x88\x92"
    ident = bytes.fromhex("feff0501000010010000") + (28).to_bytes(2, "big")
    ip = bytes.fromhex("0102000e0000") + bytes([10, 0, 0, 7]) + bytes(8)
    name = bytes.fromhex("02020005" "0000") + b"abc" + b"\x00"
    assert station(eth + ident + ip + name) == ("10.0.0.7", "abc")
    assert station(bytes(12) + b"\x81\x00\x00\x05" + b"\x88\x92" + ident + ip + name) == ("10.0.0.7", "abc")
    assert station(eth + ident[:3] + b"\x00" + ident[4:] + ip + name) is None  # a request, not a response
    assert station(eth + ident + ip) is None and station(eth + ident[:5]) is None and station(bytes(10)) is None
    cut = eth + ident[:-2] + (40).to_bytes(2, "big") + ip + name  # DCPDataLength beyond the frame
    assert station(cut) == ("10.0.0.7", "abc")


def test_station_names_of_a_real_capture() -> None:
    """The same on a real capture (../shared; skipped in a clone of the project alone): frame 466 of
    profinet_io_cm_mixed_1 names .2, as tshark shows it."""
    from pd_analyze.analysis.jobs import run
    from pd_analyze.analysis.rows import Rows

    real = shared_capture("cisagov_icsnpp-profinet-io-cm__profinet_io_cm_mixed_1.pcap")
    for columns in (False, True):
        for size in (1, 100, 0):
            results = run([str(real), A], Rows(), Settings(vector=columns, batch_frames=size))
            assert [r.stations for r in results] == [{"192.168.1.2": "versamax-pns11"},
                                                     {"192.168.1.21": "pump-1"}], (columns, size)
        chain = run([A, str(real)], Rows(), Settings(vector=columns), chain=True)
        assert [r.stations for r in chain] == [{"192.168.1.21": "pump-1"}, {"192.168.1.2": "versamax-pns11"}]


def test_station_names_behind_vlan_tags_are_found_on_both_paths(tmp_path: Path) -> None:
    """Untagged, one 802.1Q tag, QinQ (two tags), and a cyclic PN-RT frame and an IPv4 frame that look alike:
    the columns' pre-filter and the per-frame walk agree."""
    from devtools.synth.audit_samples import dcp_identify_response
    from devtools.synth.capture_files import Frame, pcap_bytes
    from pd_analyze.analysis.jobs import run
    from pd_analyze.analysis.rows import Rows

    head = bytes.fromhex("010203040506") + bytes.fromhex("0a0b0c0d0e0f")
    tag = lambda tpid: bytes.fromhex(tpid) + b"\x00\x05"  # noqa: E731
    frames = [head + b"\x88\x92" + dcp_identify_response("10.0.0.1", "plain", 1),
              head + tag("8100") + b"\x88\x92" + dcp_identify_response("10.0.0.2", "one-tag", 2),
              head + tag("88a8") + tag("8100") + b"\x88\x92" + dcp_identify_response("10.0.0.3", "qinq", 3),
              head + tag("9100") + tag("88a8") + tag("8100") + b"\x88\x92" + dcp_identify_response("10.0.0.4", "three",
                                                                                                   4),
              head + b"\x88\x92" + b"\x80\x00" + bytes(40),  # cyclic RT data
              head + b"\x08\x00" + bytes(2) + b"\x88\x92\xfe\xff" + bytes(40)]  # IPv4 with the pattern inside
    path = tmp_path / "dcp.pcap"
    path.write_bytes(pcap_bytes([Frame(1_000_000_000 * (k + 1), f) for k, f in enumerate(frames)]))
    want = {"10.0.0.1": "plain", "10.0.0.2": "one-tag", "10.0.0.3": "qinq", "10.0.0.4": "three"}
    for columns in (False, True):
        assert run([str(path)], Rows(), Settings(vector=columns))[0].stations == want, columns


@pytest.mark.parametrize("path", sorted(p for p in SAMPLES.glob("*") if p.suffix in (".pcap", ".pcapng", ".gz")),
                         ids=lambda p: p.name)
def test_columnar_and_per_frame_paths_give_the_same_state(path: Path) -> None:
    one, _ = collect([str(path)], Settings(vector=False))
    for size in (1, 7, 0):
        two, _ = collect([str(path)], Settings(vector=True, batch_frames=size))
        assert list(two.rows()) == list(one.rows()), size


def test_state_of_generated_mixed_capture_is_the_same_on_both_paths(tmp_path: Path) -> None:
    from devtools.synth.mixed_capture import make_capture

    path = tmp_path / "mixed.pcap"
    make_capture(path, 3_000, seed=5, pnio_share=0.5)
    one, _ = collect([str(path)], Settings(vector=False))
    two, _ = collect([str(path)], Settings(vector=True, batch_frames=333))
    assert one.elements and list(two.rows()) == list(one.rows())
    assert list(state_of(pd_analyze.analyze(str(path)).rows).rows()) == list(one.rows())


def _txn(req: str, verdict: str, errors: str = "") -> TxnInfo:
    return TxnInfo("c.pcap", req, verdict, errors, 10, 12, 1_000_000, 0.5)


def _param(txn: int, pnu: int, fmt: str, written: str | None = None, read: str | None = None, error: str = "",
           sub: int = 0, n: int = 1) -> ParamCells:
    return ParamCells(txn, "10.0.0.1", 1, pnu, sub, n, "Value", fmt, written, read, error, "")


def test_fold_rules_header_error_timeout_strings_and_order() -> None:
    st = StateTable()
    # given out of order: txn 3 (read) before txn 2 (write); "last" is by txn, not by arrival
    st.add({3: _txn("0x01", "ok")}, [_param(3, 5, "Unsigned16", read="4 5", sub=2, n=2)])
    st.add({2: _txn("0x02", "ok")}, [_param(2, 5, "Unsigned16", written="7 8", sub=2, n=2)])
    st.add({4: _txn("0x02", "nak", "*:0x22 too many")}, [_param(4, 6, "Unsigned16", written="1")])  # header error
    st.add({5: _txn("0x02", "timeout")}, [_param(5, 7, "FloatingPoint32", written="0.5")])
    st.add({6: _txn("0x02", "ok")}, [_param(6, 8, "VisibleString", written="abc def", n=7)])
    e = st.elements
    assert sorted(e) == [("10.0.0.1", 1, 5, 2), ("10.0.0.1", 1, 5, 3), ("10.0.0.1", 1, 6, 0), ("10.0.0.1", 1, 7, 0),
                         ("10.0.0.1", 1, 8, 0)]
    assert e["10.0.0.1", 1, 5, 3].written.value == "8" and e["10.0.0.1", 1, 5, 3].read.value == "5"
    assert e["10.0.0.1", 1, 5, 3].agrees is False and e["10.0.0.1", 1, 5, 3].last.value == "5"
    assert e["10.0.0.1", 1, 6, 0].refused.note.startswith("0x22 ") and e["10.0.0.1", 1, 6, 0].n_refused == 1
    assert e["10.0.0.1", 1, 7, 0].n_unconfirmed == 1 and e["10.0.0.1", 1, 7, 0].unconfirmed.note == "timeout"
    assert e["10.0.0.1", 1, 8, 0].written.value == "abc def"  # one value, in the first subindex's row


# --- the intended set -----------------------------------------------------------------------------------------

def test_audit_with_the_matching_set_exits_0() -> None:
    r = run("audit", A, "--expect", SET)
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stdout == "0 findings in 1 capture: 0 error, 0 warning, 0 info\n"
    assert intended.check(intended.load(SET), collect([A], Settings())[0]) == []


def test_the_set_is_generated() -> None:
    committed = (SAMPLES / "sets" / "audit_commissioning.csv").read_bytes()
    assert build.build_sets() == {"audit_commissioning.csv": committed}


FIVE = HEADER + """\
*,1,1120,0,10.5,
192.168.1.21,1,1000,0,-301,
192.168.1.21,1,730,0,1,
192.168.1.21,1,730,1,1,
192.168.1.21,1,730,2,1,
192.168.1.21,1,2900,0,Pump2,
192.168.1.21,1,1121,0,0.1,
192.168.1.21,1,1300,0,7,
"""


def test_five_values_differ(tmp_path: Path) -> None:
    path = tmp_path / "five.csv"
    path.write_text(FIVE)
    r = run("audit", A, "--expect", str(path))
    assert r.returncode == 1
    a = "sample_pcaps/audit_commissioning.pcap"
    assert r.stdout.splitlines() == [
        f"{a}:9: error S2 expect_refused: P1300[0] of 192.168.1.21 DO 1: every write refused (2 of 2), last error "
        "0x02 low or high limit exceeded; intended 7; not read back",
        f"{a}:16: error S1 expect_mismatch: P1120[0] of 192.168.1.21 DO 1: intended 10.5, read back 10 "
        "(FloatingPoint32, frame 16)",
        f"{a}:16: error S1 expect_mismatch: P1000[0] of 192.168.1.21 DO 1: intended -301, read back -300 "
        "(Integer16, frame 16)",
        f"{a}:16: error S1 expect_mismatch: P730[1] of 192.168.1.21 DO 1: intended 1, read back 0 "
        "(Unsigned8, frame 16)",
        f"{a}:16: error S1 expect_mismatch: P2900[0] of 192.168.1.21 DO 1: intended Pump2, read back Pump1 "
        "(VisibleString, frame 16)",
        f"{a}:24: error S1 expect_mismatch: P1120[0] of 192.168.1.22 DO 1: intended 10.5, read back 10 "
        "(FloatingPoint32, frame 24)",
        "6 findings in 1 capture: 6 error, 0 warning, 0 info",
    ]


def test_one_value_changed_names_exactly_that_parameter(tmp_path: Path) -> None:
    path = tmp_path / "one.csv"
    path.write_text((SAMPLES / "sets" / "audit_commissioning.csv").read_text().replace(",1000,0,-300,", ",1000,0,-30,"))
    r = run("audit", A, "--expect", str(path))
    assert r.returncode == 1
    assert r.stdout == ("sample_pcaps/audit_commissioning.pcap:16: error S1 expect_mismatch: P1000[0] of 192.168.1.21 "
                        "DO 1: intended -30, read back -300 (Integer16, frame 16)\n"
                        "1 findings in 1 capture: 1 error, 0 warning, 0 info\n")


def test_never_written_tolerance_and_strict(tmp_path: Path) -> None:
    path = tmp_path / "more.csv"
    text = (SAMPLES / "sets" / "audit_commissioning.csv").read_text().replace(",1121,0,0.1,", ",1121,0,0.12,0.05")
    path.write_text(text + "192.168.1.21,1,1500,0,3,\n")
    r = run("audit", A, "--expect", str(path), "--expect-strict", "--fail-on", "warning")
    assert r.returncode == 1
    assert r.stdout.splitlines() == [
        "sample_pcaps/audit_commissioning.pcap:9: info S5 unexpected_write: P1300[0] of 192.168.1.21 DO 1: written "
        "2 times, last 7; not in the intended set",
        f"{path}:10: warning S4 expect_missing: P1500[0] of 192.168.1.21 DO 1: intended 3, never written or read in "
        "the capture",
        "2 findings in 1 capture: 0 error, 1 warning, 1 info",
    ]
    assert run("audit", A, "--expect", str(path)).returncode == 0  # a warning is below the default --fail-on


def test_float_compares_in_the_wire_format() -> None:
    state = collect([A], Settings())[0]
    for value, ok in (("0.1", True), ("0.10000000149011612", True), ("1e-1", True), ("0.1000001", False)):
        lines = tuple(intended.parse(HEADER + f"192.168.1.21,1,1121,0,{value}\n"))
        found = intended.check(intended.ExpectedSet("x.csv", lines), state)
        assert (found == []) is ok, value


def test_unconfirmed_write() -> None:
    st = StateTable()
    st.add({1: _txn("0x02", "timeout")}, [_param(1, 7, "FloatingPoint32", written="0.5")])
    found = intended.check(intended.ExpectedSet("x.csv", tuple(intended.parse(HEADER + "10.0.0.1,1,7,0,0.5\n"))), st)
    assert [(c, f.name, f.frame, f.message) for c, f in found] == [
        ("c.pcap", "expect_unconfirmed", 10, "P7[0] of 10.0.0.1 DO 1: 0.5 written but not confirmed (the transaction "
         "ended timeout) and not read back after it; intended 0.5")]


@pytest.mark.parametrize(("text", "error"), [
    ("", "x.csv:1: no header row (expected device,do,pnu,subindex,value[,tolerance])"),
    ("device,do,pnu,value\n", "x.csv:1: the header lacks subindex (expected device,do,pnu,subindex,value[,tolerance])"),
    ("device,do,pnu,subindex,value,colour\n", "x.csv:1: unknown column 'colour' (the columns are device, do, pnu, "
                                             "subindex, value, tolerance)"),
    (HEADER + "10.0.0.300,1,5,0,1,\n", "x.csv:2: device '10.0.0.300' is neither an IPv4 address nor *"),
    (HEADER + "*,1,5,0,1,\n# note\n*,1,70000,0,1,\n", "x.csv:4: pnu '70000' is not a whole number from 0 to 65535"),
    (HEADER + "*,1,5,1.5,1,\n", "x.csv:2: subindex '1.5' is not a whole number from 0 to 65535"),
    (HEADER + "*,1,5,0,,\n", "x.csv:2: value is empty"),
    (HEADER + "*,1,5,0,1,-1\n", "x.csv:2: tolerance '-1' is not a number >= 0"),
    (HEADER + "*,1,5,0\n", "x.csv:2: 4 fields, the header has 6"),
    (HEADER + "*,1,5,0,1,,9\n", "x.csv:2: 7 fields, the header has 6"),
    (HEADER + "*,1,5,0,1,\n*,1,5,0,2,\n", "x.csv:3: P5[0] of * DO 1 is already on line 2"),
    (HEADER + "*,1,5,0,nan,\n", "x.csv:2: value 'nan' cannot be intended: NaN equals no value, not even NaN (give the "
                                "number meant)"),
    (HEADER + "*,1,5,0, -NaN ,0.5\n", "x.csv:2: value '-NaN' cannot be intended: NaN equals no value, not even NaN "
                                      "(give the number meant)"),
])
def test_bad_set_lines(text: str, error: str) -> None:
    with pytest.raises(intended.ExpectError) as exc:
        intended.parse(text, "x.csv")
    assert str(exc.value) == error


def test_bad_set_is_a_one_line_error_exit_2(tmp_path: Path) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(HEADER + "*,1,5,0,1,\nnot-an-ip,1,5,0,1,\n")
    r = run("audit", A, "--expect", str(path))
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr == f"pd-analyze: {path}:3: device 'not-an-ip' is neither an IPv4 address nor *\n"
    r = run("audit", A, "--expect", str(tmp_path / "absent.csv"))
    assert r.returncode == 2 and r.stderr == f"pd-analyze: {tmp_path / 'absent.csv'}: no such file\n"
    assert run("audit", A, "--expect-strict").returncode == 2


# --- params and diff on the command line ----------------------------------------------------------------------

def test_params_text_csv_json_and_out(tmp_path: Path) -> None:
    r = run("params", A)
    assert r.returncode == 0
    lines = r.stdout.splitlines()
    assert lines[0].split() == ["device", "DO", "parameter", "format", "written", "frame", "read", "frame", "agrees",
                                "writes", "refused", "last", "error", "name"]
    assert lines[7].split() == ["192.168.1.21", "(pump-1)", "1", "P1300[0]", "Unsigned16", "2", "2", "0x02"]
    assert lines[9].split()[:2] == ["192.168.1.22", "1"]  # no station name in the capture
    csv_lines = run("params", A, "--format", "csv").stdout.splitlines()
    assert csv_lines[0] == ",".join(c.name for c in STATE_COLUMNS) and len(csv_lines) == 10
    rows = [json.loads(line) for line in run("params", A, "--format", "json").stdout.splitlines()]
    assert rows[5]["param"] == "P1121[0]" and rows[5]["written_t"].endswith("Z") and rows[6]["written"] is None
    r = run("params", A, "--out", str(tmp_path), "--format", "parquet")
    assert r.returncode == 0 and (tmp_path / "parameter_state.parquet").exists()
    assert run("params", A, "--format", "parquet").returncode == 2


def test_diff_of_the_two_samples() -> None:
    r = run("diff", A, B, "--format", "csv")
    assert r.returncode == 1
    assert r.stdout.splitlines()[1:] == [
        "192.168.1.21,192.168.1.21,1,730,1,P730[1],,differs,ok,Unsigned8,0,,ok,Unsigned8,1,",
        "192.168.1.21,192.168.1.21,1,1120,0,P1120[0],,differs,ok,FloatingPoint32,10,,ok,FloatingPoint32,12,",
        "192.168.1.21,192.168.1.21,1,1121,0,P1121[0],,only in A,ok,FloatingPoint32,0.1,,missing,,,",
        "192.168.1.21,192.168.1.21,1,1300,0,P1300[0],,refused in A,refused,Unsigned16,7,0x02 low or high limit "
        "exceeded,ok,Unsigned16,7,",
        "192.168.1.21,192.168.1.21,1,2900,0,P2900[0],,differs,ok,VisibleString,Pump1,,ok,VisibleString,Pump2,",
        "192.168.1.22,192.168.1.22,1,1120,0,P1120[0],,only in A,ok,FloatingPoint32,10,,missing,,,",
    ]
    assert r.stderr == "6 parameter elements differ (A: 9, B: 7)\n"
    same = run("diff", A, A)
    assert same.returncode == 0 and same.stdout == "" and same.stderr.startswith("0 parameter elements differ")
    text = run("diff", A, B).stdout.splitlines()
    assert text[0].split() == ["device", "DO", "parameter", "difference", "A", "B"] and len(text) == 7


def test_diff_with_a_damaged_b_compares_what_b_holds_before_the_damage(tmp_path: Path) -> None:
    """`diff` with a truncated B printed nothing; every other command keeps the frames before the damage. Cut
    inside B's read-back, its writes are there but not yet confirmed."""
    cut = tmp_path / "cut.pcap"
    cut.write_bytes((ROOT / B).read_bytes()[:700])
    r = run("diff", A, str(cut))
    assert r.returncode == 2
    assert r.stdout.splitlines()[1:4] == [
        "192.168.1.21  1   P730[0]    unconfirmed in B                1                1; unconfirmed",
        "192.168.1.21  1   P730[1]    unconfirmed in B                0                1; unconfirmed",
        "192.168.1.21  1   P730[2]    unconfirmed in B                1                1; unconfirmed"]
    assert len(r.stdout.splitlines()) == 10
    assert r.stderr.splitlines() == ["9 parameter elements differ (A: 9, B: 7)",
                                     f"pd-analyze: {cut}: byte 530: record data truncated (154 of 206 bytes present)"]
    r = run("diff", A, str(tmp_path / "absent.pcap"))  # nothing of B to read: no comparison, the reason
    assert (r.returncode, r.stdout, r.stderr) == (2, "", f"pd-analyze: {tmp_path / 'absent.pcap'}: no such file\n")


def _two_drives(path: Path, net: str, names: tuple[str, str], p1120: tuple[float, float]) -> str:
    """A capture of two drives (.21, .22 of `net`), each announcing its station name and changing P1120."""
    from devtools.synth import fixtures
    from devtools.synth.audit_samples import dcp_identify_response
    from devtools.synth.net_encode import ETH_PNRT
    from devtools.synth.pd_encode import ParamAddress, change_ok, change_request, value_block
    from devtools.synth.sim_capture import Capture

    cap = Capture()
    for n, (name, value) in enumerate(zip(names, p1120, strict=True), start=1):
        s = fixtures.session(cap, n, net=net)
        s.parameter_access(change_request(n, 1, [(ParamAddress(1120), value_block(0x08, [value]))]),
                           change_ok(n, 1, 1))
        ctrl, dev = fixtures.plant(n, net=net)
        cap.send_ether(dev, ctrl.mac, ETH_PNRT, dcp_identify_response(dev.ip, name, n))
    path.write_bytes(fixtures.pcap_of(cap))
    return str(path)


def test_diff_by_do_pairs_several_drives_by_station_name_or_as_told(tmp_path: Path) -> None:
    """`diff --by do` refused captures of several drives; the drives are paired by the station name each announced
    (pump-1 is .21 in A and .22 in B), or as --pair names them."""
    a = _two_drives(tmp_path / "line1.pcap", "192.168.1", ("pump-1", "fan-1"), (10.0, 5.0))
    b = _two_drives(tmp_path / "line2.pcap", "192.168.2", ("fan-1", "pump-1"), (5.0, 12.0))
    r = run("diff", a, b, "--by", "do")
    assert (r.returncode, r.stdout.splitlines()) == (1, [
        "device A / B                 DO  parameter  difference  A   B",
        "192.168.1.21 / 192.168.2.22  1   P1120[0]   differs     10  12"])
    r = run("diff", a, b, "--by", "do", "--pair", "pump-1=192.168.2.21", "--format", "csv")  # as told
    assert (r.returncode, r.stdout.splitlines()[1:]) == (1, [
        "192.168.1.21,192.168.2.21,1,1120,0,P1120[0],,differs,ok,FloatingPoint32,10,,ok,FloatingPoint32,5,"])
    assert run("diff", a, b, "--by", "do", "--pair", "fan-1=fan-1").returncode == 0
    r = run("diff", A, B, "--by", "do")  # .22 of A announced no name: which pairs to compare must be said
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr == ("pd-analyze: --by do pairs the drives of A and B by the station name each announced, but A's "
                        "192.168.1.21, A's 192.168.1.22, B's 192.168.1.21 have no partner of that name (A: "
                        "192.168.1.21 (pump-1), 192.168.1.22; B: 192.168.1.21); name the pairs with --pair "
                        "A_DRIVE=B_DRIVE (address or station name), or use --by device (see 'pd-analyze diff "
                        "--help')\n")
    r = run("diff", A, B, "--by", "do", "--pair", "pump-9=192.168.1.21")
    assert r.returncode == 2 and "--pair: A holds no drive 'pump-9' (its drives: 192.168.1.21 (pump-1), " \
                                 "192.168.1.22)" in r.stderr
    assert run("diff", A, B, "--pair", "pump-1=192.168.1.21").returncode == 2  # --pair is for --by do
    single = collect([B], Settings())[0]
    assert param_diff.diff_rows(single, single, "do") == []


@pytest.mark.parametrize("path", sorted(p for p in SAMPLES.glob("*") if p.suffix in (".pcap", ".pcapng", ".gz")),
                         ids=lambda p: p.name)
def test_params_and_diff_work_on_every_sample(path: Path) -> None:
    rel = str(path.relative_to(ROOT))
    r = run("params", rel, "--format", "csv")
    assert r.returncode == 0, r.stderr
    r = run("diff", rel, rel)
    assert r.returncode == 0, r.stderr


def test_params_of_an_unreadable_capture_prints_only_the_error(tmp_path: Path) -> None:
    r = run("params", str(tmp_path / "missing.pcap"))
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.strip() == f"pd-analyze: {tmp_path / 'missing.pcap'}: no such file"


# --- the HTML report ------------------------------------------------------------------------------------------

def test_html_report_has_a_state_table_per_drive_with_the_set(tmp_path: Path) -> None:
    import re

    five = tmp_path / "five.csv"
    five.write_text(FIVE + "192.168.1.21,1,1500,0,3,\n")
    r = run("report", A, "--format", "html", "--out", str(tmp_path), "--expect", str(five))
    assert r.returncode == 0, r.stderr
    page = (tmp_path / "report.html").read_text()
    assert ("Checked against the intended set (<code>--expect</code>): 10 intended elements: 3 as intended, "
            "5 expect_mismatch, 1 expect_missing, 1 expect_refused.") in page
    assert re.findall(r"<h3>([^<]+) <small>\((\d+)\)</small></h3>", page) == [("192.168.1.21 (pump-1)", "9"),
                                                                           ("192.168.1.22", "1")]
    data = json.loads(re.search(r'<script type="application/json" id="pd-data">(.*?)</script>', page, re.S).group(1))
    t = data["tables"]["params-0"]
    names = [c["name"] for c in t["columns"]]
    assert names[:5] == ["param", "do", "result", "intended", "why"]  # the element and its result first
    by_param = {row[0]: dict(zip(names, row, strict=True)) for row in t["rows"]}
    assert by_param["P1500[0]"]["result"] == "expect_missing" and by_param["P1500[0]"]["writes"] is None
    assert by_param["P1300[0]"]["result"] == "expect_refused" and by_param["P1300[0]"]["last_error"] == "0x02"
    assert by_param["P1121[0]"]["result"] == "as intended" and by_param["P1121[0]"]["agrees"] == "yes"
    assert by_param["P730[1]"]["intended"] == "1" and by_param["P730[1]"]["read"] == "0"
    plain = run("report", A, "--format", "html", "--out", str(tmp_path / "plain"))
    assert plain.returncode == 0
    page = (tmp_path / "plain" / "report.html").read_text()
    assert '<section id="params"><h2>Parameter state</h2>' in page and "Checked against" not in page
    assert run("report", A, "--expect", str(five)).returncode == 2  # csv: no page to show it on


def test_readme_shows_what_the_commands_print(tmp_path: Path) -> None:
    """Every `$ pd-analyze ...` of the README's audit section prints what the README shows; the changed set
    (made with sed there) names exactly P1000 and exits 1."""
    import re
    import shlex

    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("### Auditing a commissioning"):readme.index("## Python API")]
    blocks = re.findall(r"```\n(.*?)```", section, re.S)
    shown = 0
    for block in blocks:
        for command, output in re.findall(r"^\$ (pd-analyze [^;\n]*)\n((?:(?!\$ ).*\n)*)", block, re.M):
            if "changed.csv" in command:
                continue
            r = run(*shlex.split(command)[1:])
            assert r.stdout == output, command
            shown += 1
    assert shown == 3
    changed = tmp_path / "changed.csv"
    changed.write_text((SAMPLES / "sets" / "audit_commissioning.csv").read_text().replace(",1000,0,-300,",
                                                                                         ",1000,0,-250,"))
    r = run("audit", A, "--expect", str(changed))
    assert r.returncode == 1
    assert r.stdout + f"exit {r.returncode}\n" in section


def test_audit_expect_over_two_captures_in_parallel_is_the_same() -> None:
    one = run("audit", A, B, "--expect", SET)
    two = run("audit", A, B, "--expect", SET, "--jobs", "2")
    assert one.returncode == two.returncode == 1 and one.stdout == two.stdout
    assert one.stdout.splitlines()[-1] == "3 findings in 2 captures: 3 error, 0 warning, 0 info"
    # the later capture's values are the last seen: .21's P1120 was set to 12 in B
    assert "P1120[0] of 192.168.1.21 DO 1: intended 10.0, read back 12 (FloatingPoint32, frame 8)" in one.stdout
