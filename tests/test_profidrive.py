"""PROFIdrive request/response dissection: exact fields, every format, pad rule, error blocks, checks."""

import math
import struct

import pytest

from devtools.synth.pd_encode import (
    ParamAddress,
    change_request,
    error_block,
    pd_request,
    pd_response,
    read_request,
    value_block,
    zero_block,
)
from pd_analyze.model import pd_values as pt
from pd_analyze.protocol import profidrive as pd
from pd_analyze.protocol import profidrive_view as pdv
from pd_analyze.protocol import profiles
from pd_analyze.protocol.profidrive_checks import Checker
from tests.worked_example import FRAME1_WRITE_REQ, FRAME6_READ_RES

GENERIC = Checker(profiles.generic())


def names(findings) -> list[str]:
    return [f.name for f in findings]


def req(data: bytes, checker: Checker = GENERIC):
    found: list = []
    p = pd.parse_request(data, 1, found)
    return p, found + checker.request(p, 1)


def res(data: bytes, request=None, checker: Checker = GENERIC):
    found: list = []
    p = pd.parse_response(data, 2, found)
    return p, found + checker.response(p, 2, request)


def shown(block_bytes: bytes) -> list[tuple[object, str]]:
    p, _ = res(pd_response(1, 1, 1, [block_bytes]))
    return [(v, s) for _, _, v, s in pdv.values_of(p.blocks[0])]


def test_worked_example_request_and_response_exactly():
    p, found = req(FRAME1_WRITE_REQ[164:])
    assert found == [] and p.complete
    assert (p.ref, p.ident, p.do, p.n) == (1, 1, 1, 2)
    assert [(a.offset, a.attr, a.n_elems, a.pnu, a.subindex) for a in p.addresses] == [
        (4, 0x10, 1, 964, 0), (10, 0x10, 3, 2000, 0)]
    assert [a.label() for a in p.addresses] == ["P964[0]", "P2000[0..2]"]
    r, found = res(FRAME6_READ_RES[164:], p)
    assert found == [] and r.complete and r.end == 22
    assert [(b.offset, b.format, b.n_values) for b in r.blocks] == [(4, 0x42, 1), (8, 0x43, 3)]
    assert [v for _, _, v, _ in pdv.values_of(r.blocks[1])] == [1, 2, 3]
    sections = pdv.annotate(r, FRAME6_READ_RES[164:], 164, GENERIC, p)
    titles = [t for t, _ in sections]
    assert titles == ["Parameter response header", "Parameter [0]: P964[0] (drive unit identification) Word x 1",
                      "Parameter [1]: P2000[0..2] Double word x 3"]
    value = sections[1][1][2]
    assert (value.name, value.offset, value.raw, value.value, value.show) == (
        "pd.val[0].value[0]", 170, b"\x12\x34", 0x1234, "0x1234")


@pytest.mark.parametrize(("fmt", "raw", "value", "text"), [
    (0x01, b"\x01", 1, "true"), (0x01, b"\x00", 0, "false"), (0x01, b"\x07", 7, "7 (not 0/1)"),
    (0x02, b"\xff", -1, "-1"), (0x03, b"\xff\xfe", -2, "-2"), (0x04, b"\x80\x00\x00\x00", -2**31, str(-2**31)),
    (0x05, b"\xff", 255, "255"), (0x06, b"\xff\xfe", 65534, "65534"), (0x07, b"\xff\xff\xff\xff", 2**32 - 1,
                                                                        str(2**32 - 1)),
    (0x08, struct.pack(">f", 1.5), 1.5, "1.5"), (0x0F, struct.pack(">d", -0.25), -0.25, "-0.25"),
    (0x37, (-5).to_bytes(8, "big", signed=True), -5, "-5"), (0x38, (2**64 - 1).to_bytes(8, "big"), 2**64 - 1,
                                                              str(2**64 - 1)),
    (0x41, b"\x80", 0x80, "0x80"), (0x42, b"\x12\x34", 0x1234, "0x1234"),
    (0x43, b"\xde\xad\xbe\xef", 0xDEADBEEF, "0xdeadbeef"),
    (0x71, (0x4000).to_bytes(2, "big"), 0x4000, "100.0000 % (raw 16384; x 100/16384 % (0x4000 = 100 %))"),
    (0x71, (-0x2000).to_bytes(2, "big", signed=True), -0x2000,
     "-50.0000 % (raw -8192; x 100/16384 % (0x4000 = 100 %))"),
    (0x72, (0x40000000).to_bytes(4, "big"), 0x40000000,
     "100.000000 % (raw 1073741824; x 100/2^30 % (0x40000000 = 100 %))"),
    (0x79, (-256).to_bytes(2, "big", signed=True), -256, "-2 (raw -256; / 128)"),
    (0x7A, (123456).to_bytes(4, "big"), 123456, "12.3456 (raw 123456; / 10000)"),
    (0x76, (40000).to_bytes(2, "big"), 40000, "0 x Ts (> 32767 means 0)"),
    (0x77, (10).to_bytes(4, "big"), 10, "10 (x Ts)"),
    (0x73, (0x8001).to_bytes(2, "big"), 0x8001, "0x8001 (bits set: 0, 15)"),
    (0x74, (0x1A2F).to_bytes(2, "big"), 0x1A2F, "nibbles 1 a 2 f"),
    (0x34, (3_723_004).to_bytes(4, "big"), 3_723_004, "3723004 (ms since midnight)"),
    (0x0C, (3_723_004).to_bytes(4, "big") + (366).to_bytes(2, "big"), int.from_bytes(
        (3_723_004).to_bytes(4, "big") + (366).to_bytes(2, "big"), "big"),
     "1985-01-01 01:02:03.004 (ms 3723004, days 366)"),
])
def test_every_numeric_format_is_decoded_at_its_true_size(fmt, raw, value, text):
    assert pt.FORMATS[fmt].size == len(raw)
    assert pdv.value_of(fmt, raw) == (value, text)


def test_float_nan_is_shown_not_crashing():
    value, text = pdv.value_of(0x08, struct.pack(">f", math.nan))
    assert (value, text) == ("nan", "nan")


def test_date_format():
    raw = bytes([0x75, 0x30, 5, 14, 21, 3, 26])  # 30.000 s, 14:05, 21 March 2026
    assert pdv.value_of(0x32, raw) == (raw.hex(), "2026-03-21 14:05:30.000")


def test_strings_are_one_value_of_n_characters_with_pad():
    request = change_request(5, 1, [(ParamAddress(100, n_elems=5), value_block(0x09, "ABCDE")),
                                    (ParamAddress(101), value_block(0x06, [7]))])
    p, found = req(request)
    assert found == [] and p.complete
    s = p.blocks[0]
    assert (s.format, s.n_values, s.data, s.pad, s.pad_offset) == (0x09, 5, b"ABCDE", 0, 23)
    assert [(v, t) for _, _, v, t in pdv.values_of(s)] == [("ABCDE", '"ABCDE"')]
    assert p.blocks[1].offset == 24 and p.end == len(request)
    octets = value_block(0x0A, b"\x00\xff\x10")
    assert shown(octets) == [("00ff10", "00 ff 10")]
    assert shown(value_block(0x27, "Hé")) == [("Hé", '"Hé"')]


def test_pad_rule_variants():
    addr = [ParamAddress(1), ParamAddress(2)]
    odd, even = value_block(0x05, [3]), value_block(0x06, [4])
    p, found = req(pd_request(1, 2, 1, addr, [odd, even]))
    assert found == [] and p.blocks[0].pad == 0
    nonzero = value_block(0x05, [3], pad=b"\x55")
    p, found = req(pd_request(1, 2, 1, addr, [nonzero, even]))
    assert names(found) == ["pad_nonzero"] and p.blocks[1].format == 0x06 and p.complete
    missing = value_block(0x05, [3], pad=b"")
    p, found = req(pd_request(1, 2, 1, addr, [missing, even]))
    assert names(found) == ["pad_missing"] and p.blocks[1].offset == 4 + 12 + 3 and p.complete
    p, found = req(pd_request(1, 2, 1, addr[:1], [missing]))
    assert names(found) == ["pad_missing_final"]
    p, found = req(pd_request(1, 2, 1, addr[:1], [odd]))
    assert found == [] and p.end == 4 + 6 + 4


def test_error_blocks_and_negative_responses():
    request, _ = req(read_request(9, 1, [ParamAddress(964), ParamAddress(2000, n_elems=3)]))
    nak = pd_response(9, 0x81, 1, [value_block(0x06, [1]), error_block(0x02, 1)])
    r, found = res(nak, request)
    assert found == [] and [(b.error, b.error_subindex) for b in r.blocks] == [(-1, -1), (2, 1)]
    titles = [t for t, _ in pdv.annotate(r, nak, 0, GENERIC, request)]
    assert titles[2] == "Parameter [1]: P2000[0..2] error 0x02 (low or high limit exceeded)"
    r, found = res(pd_response(9, 0x81, 1, [error_block(0x00), error_block(0x02)]), request)
    assert names(found) == ["error_subindex_presence"]
    r, found = res(pd_response(9, 0x81, 1, [error_block(0x00, 3), error_block(0x02, 0, extra=[9])]), request)
    assert names(found) == ["error_subindex_presence", "error_block_count"]
    r, found = res(pd_response(9, 0x81, 1, [error_block(0x0A), error_block(0x87)]), request)
    assert names(found) == ["error_reserved", "error_manufacturer"]
    sinamics = Checker(profiles.generic(), profiles.load("sinamics"))
    r, found = res(pd_response(9, 0x81, 1, [error_block(0x0A), error_block(0x87)]), request, sinamics)
    assert found[1].message == "manufacturer-specific 0x87: know-how protection active, access locked"


def test_header_level_single_error_block():
    r, found = res(pd_response(3, 0x81, 1, [error_block(0x23)], n_params=4))
    assert names(found) == ["header_level_error"] and r.complete
    r, found = res(pd_response(3, 0x81, 1, [error_block(0x02, 0)], n_params=4))
    assert names(found) == ["pd_response_truncated"] and not r.complete
    r, found = res(pd_response(3, 0x80, 1, [error_block(0x21)], n_params=1))
    assert found == [] and r.blocks[0].error == 0x21


def test_change_responses():
    r, found = res(pd_response(3, 0x02, 1, n_params=2))
    assert found == [] and r.end == 4
    r, found = res(pd_response(3, 0x02, 1, n_params=1, trailer=b"\x00\x00"))
    assert names(found) == ["change_response_body"]
    akd = Checker(profiles.generic(), profiles.load("akd"))
    r, found = res(pd_response(3, 0x02, 0, n_params=1, trailer=b"\x00\x00"), checker=akd)
    assert names(found) == ["akd_trailing_zero"]
    r, found = res(pd_response(3, 0x82, 1, [zero_block(), error_block(0x11)]))
    assert found == []
    r, found = res(pd_response(3, 0x82, 1, [zero_block(), zero_block()]))
    assert names(found) == ["nak_blocks"]
    r, found = res(pd_response(3, 0x82, 0, [zero_block(fmt=0x00), error_block(0x11)]))
    assert names(found) == ["format_zero_akd", "nak_blocks"]
    r, found = res(pd_response(3, 0x82, 0, [zero_block(fmt=0x00), error_block(0x11)]), checker=akd)
    assert found == []


def test_unknown_format_sizes():
    r, found = res(pd_response(1, 1, 1, [value_block(0x06, [1]), bytes([0x0B, 2, 1, 2, 3])]))
    assert names(found) == ["format_unsupported"] and r.blocks[1].unknown_size and r.blocks[1].data == b"\x01\x02\x03"
    r, found = res(pd_response(1, 1, 1, [bytes([0x0B, 2, 1, 2]), value_block(0x06, [1])]))
    assert names(found) == ["format_unsupported_stop"] and not r.complete


def test_description_complete_element():
    desc = (struct.pack(">HHfH", 0x4208, 1, 1.0, 0) + bytes(4) + b"Speed setpoint  " +
            struct.pack(">ffHHHH", 0.0, 100.0, 0, 0, 2000, 0))
    request, _ = req(read_request(2, 1, [ParamAddress(1082, attr=0x20, n_elems=0)]))
    data = pd_response(2, 1, 1, [value_block(0x0A, desc)])
    r, found = res(data, request)
    assert found == []
    (_, header), (title, fields) = pdv.annotate(r, data, 0, GENERIC, request)
    assert title == "Parameter [0]: P1082[0] OctetString x 46, description element 0 (complete description)"
    by = {f.name: f for f in fields}
    assert by["pd.val[0].desc.identifier"].show == "0x4208 (data type FloatingPoint32; read-only, array)"
    assert by["pd.val[0].desc.name"].value == "Speed setpoint  "
    assert by["pd.val[0].desc.high_limit"].show == "0x42c80000 (as Float32 100)"
    assert by["pd.val[0].desc.reference_parameter"].value == 2000


def test_request_rules_triggered():
    p, found = req(b"\x01\x01")
    assert names(found) == ["pd_too_short"]
    p, found = req(pd_request(0, 3, 1, [ParamAddress(0, attr=0x40, n_elems=235, subindex=0xFFFF)]))
    assert names(found) == ["pd_request_range"] * 5 + ["subindex_ffff"]
    p, found = req(read_request(1, 1, [ParamAddress(5)]) + b"\x00\x00")
    assert names(found) == ["read_request_length"]
    p, found = req(pd_request(1, 2, 1, [ParamAddress(5), ParamAddress(6)], [value_block(0x06, [1])]))
    assert names(found) == ["change_blocks"] and found[0].value == "1" and not p.complete
    p, found = req(pd_request(1, 2, 1, [ParamAddress(5)], [zero_block()]))
    assert names(found) == ["change_blocks"]
    p, found = req(pd_request(1, 2, 1, [ParamAddress(5, n_elems=2)], [value_block(0x06, [1])]))
    assert names(found) == ["n_values_mismatch"]
    p, found = req(pd_request(1, 2, 1, [ParamAddress(5, n_elems=0)], [value_block(0x0A, bytes(230))]))
    assert names(found) == ["n_values_mismatch", "value_too_long"]
    p, found = req(pd_request(1, 2, 1, [ParamAddress(5, attr=0x20)], [value_block(0x06, [1])]))
    assert names(found) == ["change_description"]
    p, found = req(pd_request(1, 2, 1, [ParamAddress(5)], [value_block(0x06, [1])], trailer=b"\x00\x00"))
    assert names(found) == ["request_trailing"]
    p, found = req(pd_request(1, 2, 1, [ParamAddress(5)], [value_block(0x06, [1, 2, 3])]))
    assert names(found) == ["n_values_mismatch"]
    p, found = req(pd_request(1, 2, 1, [ParamAddress(5)], [bytes([0x06, 5, 0, 1])]))
    assert names(found) == ["block_overrun"] and not p.complete


def test_response_rules_triggered():
    request, _ = req(read_request(1, 1, [ParamAddress(5, n_elems=2)]))
    r, found = res(b"\x01\x01")
    assert names(found) == ["pd_response_too_short"]
    r, found = res(pd_response(1, 0x05, 1, []))
    assert names(found) == ["response_id"]
    r, found = res(pd_response(1, 0x01, 1, [error_block(0x02, 0)]))
    assert names(found) == ["read_response_blocks"]
    r, found = res(pd_response(1, 0x01, 1, [value_block(0x06, [1])]), request)
    assert names(found) == ["n_values_read"]
    r, found = res(pd_response(1, 0x81, 1, [value_block(0x06, [1])]))
    assert names(found) == ["nak_blocks"]
    r, found = res(pd_response(1, 0x01, 1, [value_block(0x0A, bytes(240))]))
    assert names(found) == ["response_too_long"]
    r, found = res(pd_response(1, 0x01, 1, [value_block(0x06, [1])], trailer=b"\x00\x00"))
    assert names(found) == ["response_trailing"]
    r, found = res(pd_response(1, 0x01, 1, [value_block(0x09, "A\x1bB")]))
    assert names(found) == ["string_nonprintable"]
    r, found = res(pd_response(1, 0x01, 1, [value_block(0x01, [2])]))
    assert names(found) == ["boolean_value"]


def test_vendor_limits_name_their_seed():
    yaskawa = Checker(profiles.generic(), profiles.load("yaskawa"))
    p, found = req(read_request(1, 0, [ParamAddress(5, attr=0x20), ParamAddress(6)]), yaskawa)
    assert names(found) == ["vendor_limit"] * 3
    assert {f.field for f in found} == {"pd.do", "pd.n_params", "pd.addr[0].attr"}
    assert all(f.source.startswith("Yaskawa SI-EP3 PROFINET Technical Manual SIEP C730600 89E, p. 38") for f in found)
    assert all(f.severity == "warning" for f in found)
    assert yaskawa.describe("request.n_params", 2) == "generic 1 ... 39: ok; yaskawa 1: BREAKS (vendor_limit)"


def test_akd_address_echo_recognised():
    request, _ = req(read_request(1, 0, [ParamAddress(5)]))
    data = pd_response(1, 1, 0, [ParamAddress(5).encode() + value_block(0x43, [7])], n_params=1)
    r, found = res(data, request)
    assert names(found) == ["akd_address_echo"] and r.echo == 6 and r.blocks[0].format == 0x43


def test_multi_parameter_request_of_39():
    addrs = [ParamAddress(1000 + i) for i in range(39)]
    p, found = req(read_request(7, 1, addrs))
    assert found == [] and len(p.addresses) == 39 and p.length == 238
    p, found = req(read_request(7, 1, addrs + [ParamAddress(2000)]))
    assert names(found) == ["pd_request_range"]


def test_plausibility_for_index_47():
    assert pd.plausible(read_request(1, 1, [ParamAddress(5)]))
    assert not pd.plausible(b"\x00\x01\x01\x01" + bytes(6))
    assert not pd.plausible(b"I&M0 data, not a parameter block")


@pytest.mark.parametrize("vendor", sorted(profiles.packaged()))
def test_limit_shortcut_agrees_with_every_range(vendor):
    """Checker.limit decides in-range values by one intersected range: never a finding lost or added."""
    checker = Checker(profiles.generic(), profiles.load(vendor))
    for key, pairs in checker._by_key.items():
        edges = {v + d for _, lim in pairs for lo, hi in lim.ranges for v in (lo, hi) for d in (-1, 0, 1)}
        for value in sorted(edges | {0, 1, 0xFFFF, 0xFFFFFFFF}):
            got: list = []
            checker.limit(key, "f", value, 1, got)
            broken = [lim.rule for _, lim in pairs if not any(lo <= value <= hi for lo, hi in lim.ranges)]
            assert [f.name for f in got] == broken, (key, value)
