"""What the dump shows of a PROFIdrive record, line by line, on small captures built with devtools.synth:
records cut short decoded as far as their bytes go (issue 28 point 5), error blocks as the frame holds them
and value-block headings that name the address (issue 28 point 6, issue 26 point 9), negative responses
named in the frame heading and the JSON summary (issue 28 point 9)."""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from devtools.synth.fixtures import pcap_of, session
from devtools.synth.pd_encode import ParamAddress as P
from devtools.synth.pd_encode import change_request, error_block, pd_response, read_request, value_block
from devtools.synth.sim_capture import Capture
from pd_analyze.analysis.api import analyze
from pd_analyze.cli.base import main


def dump(path: Path, *args: str) -> list[str]:
    """The lines `pd-analyze dump` writes to stdout."""
    result = CliRunner().invoke(main, ["dump", str(path), *args])
    assert result.exit_code == 0, result.output
    return result.stdout.splitlines()


def record_lines(lines: list[str], frame: int) -> list[str]:
    """The lines of one frame from its IOD header's RecordDataLength on, without the trailing Call layer."""
    start = lines.index(next(line for line in lines if line.startswith(f"Frame {frame} ")))
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("Frame ")), len(lines))
    body = lines[start:end]
    first = next(i for i, line in enumerate(body) if "iod.record_len" in line)
    return [line for line in body[first:] if "iod.rw_pad" not in line and line]


# --- records cut short (issue 28 point 5) -------------------------------------------------------------------

def cut_capture(path: Path) -> Path:
    """Frame 1: a complete read request of P964 (10 bytes) whose RecordDataLength says 12; frame 5: a change
    request of P2000[0..2] cut inside its second value; frame 8: a read response cut inside its second block."""
    cap = Capture()
    s = session(cap, 1)
    request = read_request(1, 1, [P(964)])
    s.parameter_access(request, pd_response(1, 0x01, 1, [value_block(0x42, [0x1234])]),
                       write_kw={"req_iod": {"record_len": len(request) + 2}})
    change = change_request(2, 1, [(P(2000, n_elems=3), value_block(0x07, [1, 2, 3]))])
    s.parameter_access(change[:-3], pd_response(2, 0x02, 1, [], n_params=1),
                       write_kw={"req_iod": {"record_len": len(change)}})
    response = pd_response(3, 0x01, 1, [value_block(0x42, [0x1234]), value_block(0x43, [7, 8])])
    s.parameter_access(read_request(3, 1, [P(964), P(2000, n_elems=2)]), response[:-5],
                       read_kw={"res_iod": {"record_len": len(response)}})
    path.write_bytes(pcap_of(cap))
    return path


def test_a_record_cut_short_is_decoded_as_far_as_its_bytes_go(tmp_path: Path) -> None:
    lines = dump(cut_capture(tmp_path / "cut.pcap"))
    assert record_lines(lines, 1) == [
        "      00b2  00 00 00 0c                 iod.record_len = 12  [H5 error: record at index 0xb02e truncated: "
        "RecordDataLength 12, 10 bytes present]",
        "      Parameter request header",
        "        00ce  01                          pd.ref = 1  [generic 1 ... 255: ok]",
        "        00cf  01                          pd.req_id = 0x01 (request parameter (read))  "
        "[generic 0x01, 0x02: ok]",
        "        00d0  01                          pd.do = 1  [generic 0 ... 255: ok]",
        "        00d1  01                          pd.n_params = 1  [generic 1 ... 39: ok]",
        "      Parameter address [0]: P964[0] (drive unit identification)",
        "        00d2  10                          pd.addr[0].attr = 0x10 (Value)  [generic 0x10, 0x20, 0x30: ok]",
        "        00d3  01                          pd.addr[0].n_elems = 1  [generic 0 ... 234: ok]",
        "        00d4  03 c4                       pd.addr[0].pnu = 964 (drive unit identification)  "
        "[generic 1 ... 65535: ok]",
        "        00d6  00 00                       pd.addr[0].subindex = 0  [generic 0 ... 65534: ok]",
        "  Call",
        "                                      rpc.response_frame = 2",
        "  ! E H5 record_truncated [iod.record_len]: record at index 0xb02e truncated: RecordDataLength 12, 10 bytes "
        "present (value 10; expected 12)",
        "  ! W T8 txn_failed [txn.verdict]: the transaction of frame 1 failed: malformed: the write request of frame 1 "
        "cannot be decoded (value malformed; expected ok or nak)"]
    assert record_lines(lines, 5)[11:] == [
        "      Parameter [0]: P2000[0..2] Unsigned32 (cut: 2 of 3 values before the record ends)",
        "        00d8  07                          pd.val[0].format = 0x07 (Unsigned32)",
        "        00d9  03                          pd.val[0].n_values = 3",
        "        00da  00 00 00 01                 pd.val[0].value[0] = 1",
        "        00de  00 00 00 02                 pd.val[0].value[1] = 2",
        "        00e2  00                          pd.cut = value 3 cut: 1 of 4 bytes before the record ends",
        "  Call",
        "                                      rpc.response_frame = 6",
        "  ! E H5 record_truncated [iod.record_len]: record at index 0xb02e truncated: RecordDataLength 24, 21 bytes "
        "present (value 21; expected 24)",
        "  ! W T8 txn_failed [txn.verdict]: the transaction of frame 5 failed: malformed: the write request of frame 5 "
        "cannot be decoded (value malformed; expected ok or nak)"]
    assert record_lines(lines, 12)[3:] == [  # the response: its blocks are not labelled with the request's addresses
        "      Parameter response header",
        "        00ce  03                          pd.ref = 3",
        "        00cf  01                          pd.resp_id = 0x01 (request parameter, positive)  "
        "[generic 0x01, 0x02, 0x80, 0x81, 0x82: ok]",
        "        00d0  01                          pd.do = 1",
        "        00d1  02                          pd.n_params = 2",
        "      Parameter [0]: block [0] Word x 1",
        "        00d2  42                          pd.val[0].format = 0x42 (Word)",
        "        00d3  01                          pd.val[0].n_values = 1",
        "        00d4  12 34                       pd.val[0].value[0] = 0x1234",
        "      Parameter [1]: block [1] Double word (cut: 0 of 2 values before the record ends)",
        "        00d6  43                          pd.val[1].format = 0x43 (Double word)",
        "        00d7  02                          pd.val[1].n_values = 2",
        "        00d8  00 00 00                    pd.cut = value 1 cut: 3 of 4 bytes before the record ends",
        "  ! E H5 record_truncated [iod.record_len]: record at index 0xb02e truncated: RecordDataLength 18, 13 bytes "
        "present (value 13; expected 18)",
        "  ! W T8 txn_failed [txn.verdict]: the transaction of frame 9 failed: malformed: the read response of frame "
        "12 cannot be decoded (value malformed; expected ok or nak)"]


def test_a_filter_finds_the_parameter_of_a_record_cut_short(tmp_path: Path) -> None:
    path = cut_capture(tmp_path / "cut.pcap")
    found = dump(path, "-Y", "pn_io.profidrive.parameter.number == 964", "-T", "fields", "-e", "frame.number")
    assert found == ["1", "9"]  # the request cut short, as tshark finds it, and the whole one
    found = dump(path, "-Y", "pd.addr.pnu == 2000", "-T", "fields", "-e", "frame.number", "-e", "pd.val.value")
    assert found == ["5\t0x00000001,0x00000002", "9\t"]  # as tshark prints an Unsigned32
    assert dump(path, "-Y", "pd.cut", "-T", "fields", "-e", "frame.number") == ["5", "12"]


def test_the_finding_of_a_record_cut_short_is_as_before(tmp_path: Path) -> None:
    path = cut_capture(tmp_path / "cut.pcap")
    lines = dump(path, "--findings-only")
    assert [line for line in lines if line.startswith("  !") and " H7 " not in line and " T8 " not in line] == [
        # H7: the write responses of this capture mirror the bytes present; T8: each transaction is malformed
        "  ! E H5 record_truncated [iod.record_len]: record at index 0xb02e truncated: RecordDataLength 12, 10 bytes "
        "present (value 10; expected 12)",
        "  ! E H5 record_truncated [iod.record_len]: record at index 0xb02e truncated: RecordDataLength 24, 21 bytes "
        "present (value 21; expected 24)",
        "  ! E H5 record_truncated [iod.record_len]: record at index 0xb02e truncated: RecordDataLength 18, 13 bytes "
        "present (value 13; expected 18)"]
    records = [json.loads(line) for line in dump(path, "--format", "json")]
    assert {r["frame"]: [f["rule"] for f in r["findings"]] for r in records if r["findings"]} == \
        {1: ["H5", "T8"], 2: ["H7"], 5: ["H5", "T8"], 6: ["H7"], 12: ["H5", "T8"]}
    a = analyze(str(path))
    assert list(a.transactions["verdict"].astype(str)) == ["malformed", "malformed", "malformed"]
    assert list(a.parameters["param"].astype(str)) == ["P964[0]", "P2000[0..1]"]  # a cut request is not taken


# --- error blocks and value-block headings (issue 28 point 6, issue 26 point 9) ---------------------------

def blocks_capture(path: Path) -> Path:
    """Frame 4: P964 answered by an error block of No. of values 0; frame 8: a one-element address of P2000
    answered with two values."""
    cap = Capture()
    s = session(cap, 1)
    s.parameter_access(read_request(1, 1, [P(964)]), pd_response(1, 0x81, 1, [error_block(0x00, n_values=0)[:2]]))
    s.parameter_access(read_request(2, 1, [P(2000)]), pd_response(2, 0x01, 1, [value_block(0x43, [1, 2])]))
    path.write_bytes(pcap_of(cap))
    return path


def test_an_error_block_without_values_shows_no_error_number(tmp_path: Path) -> None:
    lines = record_lines(dump(blocks_capture(tmp_path / "blocks.pcap")), 4)
    assert lines[-5:] == [
        "      Parameter [0]: P964[0] (drive unit identification) error block without an error number "
        "(No. of values 0)",
        "        00d2  44                          pd.val[0].format = 0x44 (Error)",
        "        00d3  00                          pd.val[0].n_values = 0  [Q9 error: error block must carry 1 or 2 "
        "values (consumed 2 x m bytes)]",
        "  ! E Q9 error_block_count [pd.val[0].n_values]: error block must carry 1 or 2 values (consumed 2 x m "
        "bytes) (value 0; expected 1 or 2)",
        "  ! I T9 txn_refused [txn.verdict]: the drive refused the transaction of frame 1: no error number given "
        "(value nak; expected ok)"]
    assert not any("error -0x1" in line or "pd.val[0].error" in line for line in lines)


def test_decode_shows_an_error_block_without_values_as_the_bytes_hold_it() -> None:
    result = CliRunner().invoke(main, ["decode", "01 81 01 01 44 00", "--response",
                                       "--for-request", "01 01 01 01 10 01 03 c4 00 00"])
    assert result.stdout.splitlines()[6:] == [
        "  Parameter [0]: P964[0] (drive unit identification) error block without an error number (No. of values 0)",
        "    0004  44                          pd.val[0].format = 0x44 (Error)",
        "    0005  00                          pd.val[0].n_values = 0",
        "  ! E Q9 error_block_count [pd.val[0].n_values]: error block must carry 1 or 2 values (consumed 2 x m "
        "bytes) (value 0; expected 1 or 2)"]


def test_a_value_block_heading_names_the_address_not_the_count(tmp_path: Path) -> None:
    lines = dump(blocks_capture(tmp_path / "blocks.pcap"))
    assert record_lines(lines, 8)[-6:] == [
        "      Parameter [0]: P2000[0] Double word x 2",  # the address is one element; the block holds two
        "        00d2  43                          pd.val[0].format = 0x43 (Double word)",
        "        00d3  02                          pd.val[0].n_values = 2  [Q7 warning: P2000[0]: No. of values "
        "differs from the requested elements]",
        "        00d4  00 00 00 01                 pd.val[0].value[0] = 0x00000001",
        "        00d8  00 00 00 02                 pd.val[0].value[1] = 0x00000002",
        "  ! W Q7 n_values_read [pd.val[0].n_values]: P2000[0]: No. of values differs from the requested elements "
        "(value 2; expected 1)"]


# --- negative responses in the heading (issue 28 point 9) ----------------------------------------------

def test_a_negative_response_says_so_in_the_heading_and_the_json_summary(tmp_path: Path) -> None:
    cap = Capture()
    s = session(cap, 1)
    s.parameter_access(read_request(7, 1, [P(9999)]), pd_response(7, 0x81, 1, [error_block(0x00)]))
    s.parameter_access(change_request(8, 1, [(P(1300), value_block(0x06, [7]))]),
                       pd_response(8, 0x82, 1, [error_block(0x02, 0)]))
    s.parameter_access(read_request(9, 1, [P(964)]), pd_response(9, 0x01, 1, [value_block(0x42, [0x1234])]))
    path = tmp_path / "negative.pcap"
    path.write_bytes(pcap_of(cap))
    headings = [line for line in dump(path) if line.startswith("Frame ")]
    assert headings[3] == ("Frame 4  1767225600.004000  192.168.1.21 -> 192.168.1.11  Read response, seq 2, "
                           "IODReadResHeader api 0x3a00 slot 1/0x1 index 0xb02e 8 bytes, "
                           "PROFIdrive negative read response (0x81), ref 7")
    assert headings[7] == ("Frame 8  1767225600.009000  192.168.1.21 -> 192.168.1.11  Read response, seq 4, "
                           "IODReadResHeader api 0x3a00 slot 1/0x1 index 0xb02e 10 bytes, "
                           "PROFIdrive negative change response (0x82), ref 8")
    assert headings[11].endswith("Read response, seq 6, IODReadResHeader api 0x3a00 slot 1/0x1 index 0xb02e 8 bytes")
    summaries = {r["frame"]: r["summary"] for r in map(json.loads, dump(path, "--format", "json"))}
    assert summaries[4] == ("Read response, seq 2, IODReadResHeader api 0x3a00 slot 1/0x1 index 0xb02e 8 bytes, "
                            "PROFIdrive negative read response (0x81), ref 7")
    assert summaries[8].endswith(", PROFIdrive negative change response (0x82), ref 8")
    assert [n for n, text in summaries.items() if "negative" in text] == [4, 8]


def test_the_negative_responses_of_the_sample_are_named_as_tshark_names_them() -> None:
    """pd_negative.pcap: tshark's Info says "RspId:Negative read response" on 8 frames, "Negative change
    response" on 6 and "Unknown response" on the 0x80 of frame 42 (protocol.md 8.3 #8: it has no name)."""
    lines = dump(Path(__file__).resolve().parents[1] / "sample_pcaps" / "pd_negative.pcap")
    named = {int(line.split()[1]): line.partition(" bytes, PROFIdrive ")[2] for line in lines
             if line.startswith("Frame ") and "PROFIdrive negative" in line}
    assert named == {
        6: "negative read response (0x81), ref 1", 10: "negative change response (0x82), ref 2",
        14: "negative read response (0x81), ref 3", 18: "negative change response (0x82), ref 4",
        22: "negative read response (0x81), ref 5", 26: "negative read response (0x81), ref 6",
        30: "negative change response (0x82), ref 7", 34: "negative change response (0x82), ref 8",
        38: "negative read response (0x81), ref 9", 42: "negative response, request not supported (0x80), ref 10",
        46: "negative read response (0x81), ref 11", 50: "negative change response (0x82), ref 12",
        54: "negative read response (0x81), ref 13", 60: "negative read response (0x81), ref 14",
        64: "negative change response (0x82), ref 15"}
