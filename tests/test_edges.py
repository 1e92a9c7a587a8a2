"""The edges of issue "Right on every edge" that the expected files do not cover: records decoded as far as
their bytes go (protocol.md 1.3), whole-request errors in the parameters table (3.3), the edge sample's
rows under both report paths."""

from pathlib import Path

import pandas as pd

import pd_analyze
from pd_analyze.output.decode import decode, parse_hex
from pd_analyze.protocol.profidrive_checks import Checker

REPO = Path(__file__).resolve().parents[1]
EDGES = REPO / "sample_pcaps" / "pd_edge_cases.pcap"
GENERIC = Checker.for_profile("generic")


def tree(hex_text: str, response: bool) -> list[tuple[str, list[tuple[int, str, str, str]]]]:
    """(title, [(offset, name, raw, show)]) per section, and the finding names last."""
    d = decode(parse_hex(hex_text), response, GENERIC)
    out = [(title, [(f.offset, f.name, f.raw.hex(), f.show) for f in fields]) for title, fields in d.sections]
    return out + [("findings", [(0, f.name, "", "") for f in d.findings])]


def test_a_record_shorter_than_its_header_shows_the_bytes_present() -> None:
    assert tree("07 02 01", False) == [
        ("Parameter request header (cut: 3 of 4 bytes)", [
            (0, "pd.ref", "07", "7"), (1, "pd.req_id", "02", "0x02 (change parameter (write))"),
            (2, "pd.do", "01", "1")]),
        ("findings", [(0, "pd_too_short", "", "")])]
    assert tree("07", True)[0] == ("Parameter response header (cut: 1 of 4 bytes)", [(0, "pd.ref", "07", "7")])


def test_a_request_cut_inside_an_address_shows_its_whole_fields_and_the_cut_one() -> None:
    sections = tree("01 01 01 02 10 01 03 C4 00 00 10 00 07", False)
    assert sections[2:] == [
        ("Parameter address [1] (cut: 3 of 6 bytes)", [
            (10, "pd.addr[1].attr", "10", "0x10 (Value)"), (11, "pd.addr[1].n_elems", "00", "0"),
            (12, "pd.cut", "07", "pd.addr[1].pnu cut: 1 of 2 bytes before the record ends")]),
        ("findings", [(0, "pd_too_short", "", "")])]


def test_a_block_overrunning_the_record_shows_its_head_and_whole_values() -> None:
    sections = tree("01 01 01 01 07 02 00 00 00 01 00", True)  # 2 Unsigned32 claimed, 1 and a byte sent
    assert sections[1:] == [
        ("Parameter [0]: block [0] Unsigned32 (cut: 1 of 2 values before the record ends)", [
            (4, "pd.val[0].format", "07", "0x07 (Unsigned32)"), (5, "pd.val[0].n_values", "02", "2"),
            (6, "pd.val[0].value[0]", "00000001", "1"),
            (10, "pd.cut", "00", "value 2 cut: 1 of 4 bytes before the record ends")]),
        ("findings", [(0, "response_block_overrun", "", "")])]
    sections = tree("01 81 01 01 44 02 00 02", True)  # an error block whose subindex word is missing
    assert sections[1] == ("Parameter [0]: block [0] Error (cut: 1 of 2 values before the record ends)", [
        (4, "pd.val[0].format", "44", "0x44 (Error)"), (5, "pd.val[0].n_values", "02", "2"),
        (6, "pd.val[0].error", "0002", "0x02 (low or high limit exceeded)")])
    sections = tree("01 01 01 02 42 01 12 34 08", True)  # the second block: its Format only
    assert sections[2] == ("Parameter [1]: block [1] FloatingPoint32 (cut: no values before the record ends)", [
        (8, "pd.val[1].format", "08", "0x08 (FloatingPoint32)")])


def test_whole_request_errors_reach_every_parameter_row() -> None:
    a = pd_analyze.analyze(str(EDGES))
    p = a.parameters[a.parameters.device == "192.168.1.25"]
    rows = [[None if pd.isna(v) else v for v in row]
            for row in p[["txn", "param", "pnu", "error", "error_text", "whole_request"]].values.tolist()]
    assert rows == [
        [10, "P964[0]", 964, "0x23", "multi-parameter access not supported", True],
        [10, "P965[0]", 965, "0x23", "multi-parameter access not supported", True],
        [10, "P10[0]", 10, "0x23", "multi-parameter access not supported", True],
        [11, "", None, "0x16", "parameter address impermissible (attribute, elements, PNU, subindex or "
                               "combination)", True]]
    t = a.transactions.set_index("txn")
    assert t.loc[10, "errors"] == "*:0x23" and t.loc[11, "errors"] == "*:0x16"
    assert not a.parameters[a.parameters.device != "192.168.1.25"].whole_request.any()


def test_edge_sample_verdicts_by_device() -> None:
    t = pd_analyze.analyze(str(EDGES)).transactions
    rows = [[None if pd.isna(v) else v for v in row]
            for row in t[["device", "ref", "verdict", "pnio_status", "closed_by"]].values.tolist()]
    assert rows == [
        ["192.168.1.21", None, "malformed", "", "response"], ["192.168.1.21", 2, "malformed", "", "response"],
        ["192.168.1.21", 3, "ok", "", "response"],
        ["192.168.1.22", 1, "timeout", "", "deadline"], ["192.168.1.22", 1, "ok", "", "response"],
        ["192.168.1.23", 1, "pnio_error", "DE80B500", "superseded"], ["192.168.1.23", 2, "ok", "", "response"],
        ["192.168.1.23", 3, "pnio_error", "DE80B500", "deadline"],
        ["192.168.1.24", 1, "ok", "", "response"],
        ["192.168.1.25", 1, "nak", "", "response"], ["192.168.1.25", 2, "nak", "", "response"],
        ["192.168.1.26", 1, "timeout", "DE80B500", "capture_end"]]
