"""`dump` of a capture file shows what `audit` and `report` say of each frame (issue 28 points 1-2): the
transaction findings (Q2-Q5, T1-T9) and R7 at their frames and fields, also with -Y and --findings-only, and
the links (rpc.request_frame, pd.request_frame) of the report's pairing, on small generated captures."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from devtools.synth.fault_rich import make_fault_rich
from devtools.synth.fixtures import pcap_of, session
from devtools.synth.pd_encode import ParamAddress as P
from devtools.synth.pd_encode import pd_response, read_request, value_block
from devtools.synth.sim_capture import Capture
from pd_analyze.cli.base import main


def run(*args: str) -> list[str]:
    result = CliRunner().invoke(main, [*args])
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    return result.stdout.splitlines()


def frame_lines(lines: list[str], frame: int) -> list[str]:
    start = lines.index(next(line for line in lines if line.startswith(f"Frame {frame} ")))
    end = next((i for i in range(start + 1, len(lines)) if not lines[i]), len(lines))
    return lines[start:end]


def mirror_capture(path: Path) -> Path:
    """Frame 1: a read request of P964 (reference 1); frame 4: its read response, reference 67, Response ID
    0x02 (a change's), no parameters."""
    cap = Capture()
    s = session(cap, 1)
    s.parameter_access(read_request(1, 1, [P(964)]), pd_response(67, 0x02, 1, []))
    path.write_bytes(pcap_of(cap))
    return path


def orphan_capture(path: Path) -> Path:
    """Frames 1-2: a read request of P964 written and acknowledged; frame 3: its read, never answered;
    frame 4: a read response of another sequence number (99), reference (7) and Response ID (0x02)."""
    cap = Capture()
    s = session(cap, 1)
    s.parameter_access(read_request(1, 1, [P(964)]), None)
    s.read(0xB02E, respond=False)
    _request, response, _args_max = s.read_stubs(0xB02E, pd_response(7, 0x02, 1, [value_block(0x42, [0x1234])]))
    s.reply(2, response, seq=99)
    path.write_bytes(pcap_of(cap))
    return path


Q_FINDINGS = [
    "  ! E Q2 reference_mismatch [pd.ref]: response reference 67 does not mirror the request's 1 (value 67; "
    "expected 1)",
    "  ! E Q3 response_id_mismatch [pd.resp_id]: Response ID 0x02 does not answer Request ID 0x01 (value 0x02; "
    "expected 0x01/0x81)",
    "  ! W Q5 n_params_not_mirrored [pd.n_params]: No. of parameters not mirrored (value 0; expected 1)"]


def test_pairing_findings_mark_their_fields_in_the_tree(tmp_path: Path) -> None:
    lines = frame_lines(run("dump", str(mirror_capture(tmp_path / "m.pcap")), "--color", "never"), 4)
    assert lines[lines.index("  Call"):lines.index("  Call") + 5] == [
        "  Call",
        "                                      rpc.request_frame = 3",
        "                                      rpc.rtt = 0.001500 s",
        "  Parameter access",
        "                                      pd.request_frame = 1"]
    assert lines[-8:] == [
        "      Parameter response header",
        "        00ce  43                          pd.ref = 67  [Q2 error: response reference 67 does not mirror "
        "the request's 1]",
        "        00cf  02                          pd.resp_id = 0x02 (change parameter, positive)  [Q3 error: "
        "Response ID 0x02 does not answer Request ID 0x01]",
        "        00d0  01                          pd.do = 1",
        "        00d1  00                          pd.n_params = 0  [Q5 warning: No. of parameters not mirrored]",
        *Q_FINDINGS]


def test_a_filter_on_a_finding_prints_the_frame_with_it(tmp_path: Path) -> None:
    path = str(mirror_capture(tmp_path / "m.pcap"))
    full = frame_lines(run("dump", path, "--color", "never"), 4)
    selected = run("dump", path, "--color", "never", "-Y", 'finding.rule == "Q2"')
    assert selected == [*full, ""]  # the one frame, as the full dump prints it
    only = run("dump", path, "--color", "never", "-Y", 'finding.rule == "Q2"', "--findings-only")
    assert only == [full[0], *Q_FINDINGS, ""]


def test_an_orphan_response_is_linked_to_nothing(tmp_path: Path) -> None:
    path = str(orphan_capture(tmp_path / "o.pcap"))
    lines = frame_lines(run("dump", path, "--color", "never"), 4)
    assert not any("request_frame" in line for line in lines)  # (pd.request_frame = 1 before: a timeout's)
    assert [line for line in lines if line.startswith("  !")] == [
        "  ! I R7 orphan_response [rpc.seq]: response without an open request (decoded with its own opnum) "
        "(value 99; expected an open request)",
        "  ! W Q6 change_response_body [pd.trailing]: positive change response carries a body (it is header-only) "
        "(value 4; expected 0)"]
    assert run("dump", path, "-T", "fields", "-Y", "pd.request_frame", "-e", "frame.number") == []


def test_findings_only_lists_every_finding_audit_lists_at_its_frame(tmp_path: Path) -> None:
    path = str(orphan_capture(tmp_path / "o.pcap"))
    assert run("dump", path, "--findings-only", "--color", "never") == [
        "Frame 1  1767225600.000000  192.168.1.11 -> 192.168.1.21  Write request, seq 1, IODWriteReqHeader api "
        "0x3a00 slot 1/0x1 index 0xb02e 10 bytes",
        "  ! W T8 txn_failed [txn.verdict]: the transaction of frame 1 failed: timeout: the capture ended (value "
        "timeout; expected ok or nak)",
        "",
        "Frame 3  1767225600.002500  192.168.1.11 -> 192.168.1.21  Read request, seq 2, IODReadReqHeader api "
        "0x3a00 slot 1/0x1 index 0xb02e",
        "  ! W R7 rpc_unanswered [rpc.seq]: request not answered (end of capture) (value 2; expected a response "
        "within 5 s)",
        "",
        "Frame 4  1767225600.003500  192.168.1.21 -> 192.168.1.11  Read response, seq 99, IODReadResHeader api "
        "0x3a00 slot 1/0x1 index 0xb02e 8 bytes",
        "  ! I R7 orphan_response [rpc.seq]: response without an open request (decoded with its own opnum) "
        "(value 99; expected an open request)",
        "  ! W Q6 change_response_body [pd.trailing]: positive change response carries a body (it is header-only) "
        "(value 4; expected 0)",
        ""]


def test_an_unanswered_request_keeps_its_r7_at_its_frame(tmp_path: Path) -> None:
    """Frame 1134 of this fault-rich capture: a read whose answer never comes, while other drives' frames
    pass; its R7 was listed among 'Findings on frames that are not PNIO RPC'."""
    path = tmp_path / "fr.pcap"
    make_fault_rich(path, 3_000, seed=3)
    lines = run("dump", str(path), "--findings-only", "--color", "never")
    assert not any(line.startswith("Findings on frames that are not PNIO RPC") for line in lines)
    assert frame_lines(lines, 1134) == [
        "Frame 1134  1767225610.168911  192.168.10.1 -> 192.168.10.101  Read request, seq 167, IODReadReqHeader "
        "api 0x3a00 slot 1/0x1 index 0xb02e",
        "  ! W R7 rpc_unanswered [rpc.seq]: request not answered (no response within 5 s) (value 167; expected a "
        "response within 5 s)"]
    audit = run("audit", str(path))
    findings = sum(1 for line in lines if line.startswith("  !"))
    assert audit[-1].startswith(f"{findings} findings in 1 capture")
