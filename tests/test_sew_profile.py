"""The SEW-EURODRIVE profile (protocol.md 5.5): MOVILINK services carried in the PROFIdrive record, decoded
as the profile file declares them (data, not code), and left reserved under every other profile.

The hex examples are the manuals' own: "DFE32B Fieldbus Interface PROFINET IO" ch. 7.2.4 and "PROFINET IO
Interfaces, Field Distributors" 22870857/EN 12/2016 ch. 9.3 (READ of index 8300, answer 0x311C7289; the
positive answer to WRITE parameter volatile, 4 bytes; the negative answer 0xC0 with one error word).
"""

import json
import subprocess
import sys
from pathlib import Path

import pytest

import pd_analyze
from pd_analyze.output.decode import decode, parse_hex
from pd_analyze.protocol import profiles
from pd_analyze.protocol.profidrive_checks import Checker

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_pcaps" / "pd_sew_movilink.pcap"
SEW = Checker.for_profile("sew")
GENERIC = Checker.for_profile("generic")

READ_8300 = "01 40 00 01 10 00 20 6C 00 00"  # READ parameter, index 8300 (firmware version)
READ_8300_OK = "01 40 00 01 43 01 31 1C 72 89"
WRITE_VOLATILE_P170 = "02 40 00 01 30 00 21 29 00 00 43 01 00 00 0B B8"  # P170 = index 0x2129, 3000
WRITE_OK = "02 40 00 01"
NEGATIVE = "01 C0 00 01 44 01 08 11"  # MOVILINK error class 0x08, additional code 0x11


def fields(hex_text: str, response: bool, checker: Checker = SEW, request: str | None = None) -> dict:
    d = decode(parse_hex(hex_text), response, checker, request=parse_hex(request) if request else None)
    return {f.name: (f.value, f.show) for _, section in d.sections for f in section} | {
        "findings": [f.name for f in d.findings], "titles": [title for title, _ in d.sections]}


def test_movilink_read_request_and_its_answer_in_full() -> None:
    got = fields(READ_8300, False)
    assert got["pd.req_id"] == (0x40, "0x40 (SEW MOVILINK service)")
    assert got["pd.do"][0] == 0 and got["pd.n_params"][0] == 1
    assert got["pd.addr[0].attr"] == (0x10, "0x10 (MOVILINK READ parameter)")
    assert got["pd.addr[0].n_elems"] == (0, "0 (single value / non-array)")
    assert got["pd.addr[0].pnu"] == (8300, "8300") and got["pd.addr[0].subindex"] == (0, "0")
    assert got["findings"] == []
    got = fields(READ_8300_OK, True, request=READ_8300)
    assert got["pd.resp_id"] == (0x40, "0x40 (SEW MOVILINK service, positive)")
    assert got["pd.val[0].format"] == (0x43, "0x43 (Double word)") and got["pd.val[0].n_values"][0] == 1
    assert got["pd.val[0].value[0]"] == (0x311C7289, "0x311c7289") and 0x311C7289 == 823947913
    assert got["titles"][-1] == "Parameter [0]: P8300[0] Double word x 1" and got["findings"] == []


def test_movilink_write_volatile_and_its_header_only_answer() -> None:
    got = fields(WRITE_VOLATILE_P170, False)
    assert got["pd.addr[0].attr"] == (0x30, "0x30 (MOVILINK WRITE parameter volatile)")
    assert got["pd.addr[0].pnu"][0] == 0x2129
    assert got["pd.val[0].format"][0] == 0x43 and got["pd.val[0].value[0]"] == (3000, "0x00000bb8")
    assert got["titles"][-1] == "Parameter [0]: P8489[0] Double word x 1"  # a value, not the Text attribute
    assert got["findings"] == []
    got = fields(WRITE_OK, True, request=WRITE_VOLATILE_P170)
    assert got["pd.resp_id"] == (0x40, "0x40 (SEW MOVILINK service, positive)")
    assert got["titles"] == ["Parameter response header"] and got["findings"] == []


def test_movilink_negative_answer_shows_class_and_additional_code() -> None:
    got = fields(NEGATIVE, True, request=READ_8300)
    assert got["pd.resp_id"] == (0xC0, "0xc0 (SEW MOVILINK service, negative)")
    assert got["pd.val[0].error"] == (0x0811, "0x811 (vendor error: class 0x08, additional code 0x11)")
    assert got["titles"][-1] == "Parameter [0]: P8300[0] error 0x0811 (vendor error: class 0x08, additional code 0x11)"
    assert got["findings"] == []  # a vendor error word is neither reserved nor manufacturer-specific here
    assert profiles.error_word_text("class_code", 0x0091) == "vendor error: 0x0080 + additional code 0x11"
    assert profiles.error_word_text("class_code", 0x0016) is None  # a PROFIdrive error number


def test_sew_limits_are_checked_as_vendor_warnings() -> None:
    d = decode(parse_hex("03 40 00 01 A0 00 20 6C 00 01"), False, SEW)  # reserved service 0xA0, subindex 1
    assert sorted((f.name, f.field) for f in d.findings) == [("vendor_limit", "pd.addr[0].attr"),
                                                             ("vendor_limit", "pd.addr[0].subindex")]
    assert all("DFE32B Fieldbus Interface PROFINET IO, ch. 7.2" in f.source for f in d.findings)
    got = fields("03 40 00 01 A0 00 20 6C 00 00", False)
    assert got["pd.addr[0].attr"] == (0xA0, "0xa0 (reserved service)")


def test_under_generic_0x40_stays_a_reserved_request_id() -> None:
    got = fields(READ_8300, False, GENERIC)
    assert got["pd.req_id"] == (0x40, "0x40") and got["pd.addr[0].attr"][1] == "0x10 (Value)"
    assert got["findings"] == ["pd_request_range"]
    d = decode(parse_hex(NEGATIVE), True, GENERIC)
    assert [f.name for f in d.findings] == ["response_id"]  # Q1: the body is not guessed at


def test_sew_capture_under_the_sew_profile() -> None:
    a = pd_analyze.analyze(str(SAMPLE), "sew")
    t = a.transactions
    assert t[["ref", "req_id", "resp_id", "verdict", "errors", "b5_retries"]].values.tolist() == [
        [1, "0x40", "0x40", "ok", "", 1], [2, "0x40", "0x40", "ok", "", 0],
        [3, "0x40", "0xc0", "nak", "P4660[0]:0x811", 0], [4, "0x40", "0x40", "ok", "", 0],
        [5, "0x01", "0x01", "ok", "", 0]]
    p = a.parameters
    assert p[["param", "attribute", "values_written", "values_read", "error", "error_text"]].values.tolist() == [
        ["P8300[0]", "MOVILINK READ parameter", "", "0x311c7289", "", ""],
        ["P8489[0]", "MOVILINK WRITE parameter volatile", "0x00000bb8", "", "", ""],
        ["P4660[0]", "MOVILINK READ parameter", "", "", "0x811", "vendor error: class 0x08, additional code 0x11"],
        ["P8489[0]", "MOVILINK READ minimum", "", "0x00000000", "", ""],
        ["P8300[0]", "Value", "", "0x311c7289", "", ""]]
    changes = a.changes[["txn", "param", "value_written", "result"]].values.tolist()
    assert changes == [[2, "P8489[0]", "0x00000bb8", "ok"]]  # a WRITE service is a change
    f = a.findings
    assert set(f.name) == {"profibus_index", "txn_refused"}  # every request header on 0x002F, and the NAK's T9
    assert f.loc[f.name != "profibus_index", ["frame", "txn", "severity", "rule", "message"]].values.tolist() == [
        [14, 3, "info", "T9", "the drive refused the transaction of frame 11: P4660[0]: error 0x811 (vendor error: "
                              "class 0x08, additional code 0x11)"]]  # at its negative response (protocol.md 6.5)


@pytest.mark.parametrize("bad, message", [
    ('id = 0x01\nname = "x"\nanswers = [1]\nsource = "s"', "0x01 and 0x02 are the profile's own Request IDs"),
    ('id = 0x40\nname = "x"\nsource = "s"', "'answers' must list the Response IDs"),
    ('id = 0x40\nname = "x"\nanswers = [0x40]', "every entry needs its 'source'"),
    ('id = 0x40\nname = "x"\nanswers = [0x40]\nsource = "s"\nlayout = "both"', "layout 'both' is not one of"),
])
def test_a_vendor_request_id_entry_is_checked(tmp_path: Path, bad: str, message: str) -> None:
    path = tmp_path / "acme.toml"
    path.write_text(f'name = "acme"\n[[request_id]]\n{bad}\n')
    with pytest.raises(profiles.ProfileError, match=message):
        profiles.load(str(path))


def test_another_vendor_adds_its_request_ids_as_data(tmp_path: Path) -> None:
    """The README's recipe: a profile file declares a Request ID, its layout and answers; decode follows it."""
    path = tmp_path / "acme.toml"
    path.write_text('name = "acme"\n'
                    '[[request_id]]\nid = 0x51\nname = "ACME bulk write"\nlayout = "change"\nanswers = [0x51, 0xD1]\n'
                    'source = "ACME manual, table 3"\n'
                    '[[response_id]]\nid = 0x51\nname = "ACME bulk write, positive"\nsource = "ACME manual, table 4"\n')
    out = subprocess.run([sys.executable, "-m", "pd_analyze.cli", "decode", "07 51 01 01 10 00 03 E8 00 00 42 01 12 34",
                          "--request", "--profile", str(path), "--format", "json"],
                         capture_output=True, check=True, cwd=REPO).stdout
    doc = json.loads(out)
    shown = {f["name"]: f["show"] for f in doc["fields"]}
    assert shown["pd.req_id"] == "0x51 (ACME bulk write)" and shown["pd.val[0].value[0]"] == "0x1234"
    assert doc["findings"] == []
