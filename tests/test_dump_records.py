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
from devtools.synth.pd_encode import change_request, pd_response, read_request, value_block
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
        "present (value 10; expected 12)"]
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
        "present (value 21; expected 24)"]
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
        "present (value 13; expected 18)"]


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
    assert [line for line in lines if line.startswith("  !") and " H7 " not in line] == [  # H7: the write
        # responses of this capture mirror the bytes present
        "  ! E H5 record_truncated [iod.record_len]: record at index 0xb02e truncated: RecordDataLength 12, 10 bytes "
        "present (value 10; expected 12)",
        "  ! E H5 record_truncated [iod.record_len]: record at index 0xb02e truncated: RecordDataLength 24, 21 bytes "
        "present (value 21; expected 24)",
        "  ! E H5 record_truncated [iod.record_len]: record at index 0xb02e truncated: RecordDataLength 18, 13 bytes "
        "present (value 13; expected 18)"]
    records = [json.loads(line) for line in dump(path, "--format", "json")]
    assert {r["frame"]: [f["rule"] for f in r["findings"]] for r in records if r["findings"]} == \
        {1: ["H5"], 2: ["H7"], 5: ["H5"], 6: ["H7"], 12: ["H5"]}
    a = analyze(str(path))
    assert list(a.transactions["verdict"].astype(str)) == ["malformed", "malformed", "malformed"]
    assert list(a.parameters["param"].astype(str)) == ["P964[0]", "P2000[0..1]"]  # a cut request is not taken
