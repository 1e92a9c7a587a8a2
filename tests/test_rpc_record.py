"""Exact values of the CL-RPC header, NDR args and IOD headers (protocol.md 2, worked example 9)."""

from pd_analyze.model.layout import Field
from pd_analyze.model.values import OP_READ, OP_WRITE
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol import rpc
from tests.worked_example import FRAME1_WRITE_REQ, FRAME4_NDR, FRAME6_READ_RES


def _by_name(fields: list[Field]) -> dict[str, Field]:
    return {f.name: f for f in fields}


def test_rpc_header_of_worked_example_frame1():
    assert rpc.plausible(FRAME1_WRITE_REQ)
    hdr = rpc.header(FRAME1_WRITE_REQ)
    assert hdr.little and hdr.ptype == 0 and hdr.flags1 == 0x20 and hdr.seq == 1 and hdr.opnum == 3
    assert hdr.frag_len == 100 and hdr.frag_num == 0
    assert rpc.is_pnio_uuid(hdr.interface)
    f = _by_name(rpc.HEADER_LE.annotate(FRAME1_WRITE_REQ, 0, hdr.values))
    assert f["rpc.object"].value == "dea00000-6c97-11d1-8271-000100020002"
    assert f["rpc.interface"].value == "dea00001-6c97-11d1-8271-00a02442df7d"
    assert f["rpc.activity"].value == "11111111-2222-3333-4444-555566667777"
    assert f["rpc.drep"].raw == b"\x10\x00\x00"
    assert (f["rpc.boot_time"].value, f["rpc.if_version"].value, f["rpc.seq"].value) == (0, 1, 1)
    assert (f["rpc.ihint"].value, f["rpc.ahint"].value) == (0xFFFF, 0xFFFF)
    assert (f["rpc.opnum"].offset, f["rpc.opnum"].length, f["rpc.opnum"].show) == (68, 2, "3 (Write)")
    assert (f["rpc.serial_hi"].offset, f["rpc.serial_lo"].offset) == (7, 79)


def test_big_endian_drep_gives_the_same_canonical_activity():
    be = bytearray(FRAME1_WRITE_REQ[:80])
    be[4] = 0x00  # big-endian integers
    act = FRAME1_WRITE_REQ[40:56]
    be[40:56] = act[3::-1] + act[5:3:-1] + act[7:5:-1] + act[8:]
    be[64:68] = (1).to_bytes(4, "big")
    hdr = rpc.header(bytes(be))
    assert not hdr.little
    assert hdr.activity == rpc.header(FRAME1_WRITE_REQ).activity
    assert hdr.seq == 1


def test_plausibility_rejects_non_rpc():
    assert not rpc.plausible(FRAME1_WRITE_REQ[:79])
    for pos, value in ((0, 5), (1, 11), (3, 0x04), (4, 0x20), (5, 4)):
        bad = bytearray(FRAME1_WRITE_REQ)
        bad[pos] = value
        assert not rpc.plausible(bytes(bad)), pos


def test_write_request_stub_of_worked_example():
    stub_bytes = FRAME1_WRITE_REQ[80:]
    found: list = []
    stub = rec.parse_stub(stub_bytes, True, False, OP_WRITE, 1, found)
    assert found == []
    ndr = _by_name(stub.ndr_layout.annotate(stub_bytes, 0, stub.ndr))
    assert [ndr[n].value for n in ("ndr.args_max", "ndr.args_len", "ndr.max_count", "ndr.offset",
                                   "ndr.actual_count")] == [16696, 80, 16696, 0, 80]
    (block,) = stub.blocks
    assert block.layout is rec.WRITE_REQ and block.offset == 20 and block.record_offset == 84
    iod = _by_name(block.layout.annotate(stub_bytes, block.offset, block.values))
    assert iod["iod.block_type"].value == 0x0008 and iod["iod.block_length"].value == 60
    assert (iod["iod.version_high"].value, iod["iod.version_low"].value, iod["iod.seq"].value) == (1, 0, 1)
    assert iod["iod.ar_uuid"].value == "aaaaaaaa-bbbb-cccc-dddd-eeeeffff0001"
    assert (iod["iod.api"].value, iod["iod.slot"].value, iod["iod.subslot"].value) == (0x3A00, 1, 1)
    assert (iod["iod.index"].value, iod["iod.record_len"].value) == (0xB02E, 16)
    assert iod["iod.index"].offset == 20 + 34 and iod["iod.rw_pad"].length == 24
    assert block.record == bytes.fromhex("01010102 100103c40000 100307d00000")
    assert stub.trailing == 0


def test_read_response_stub_of_worked_example():
    stub_bytes = FRAME6_READ_RES[80:]
    found: list = []
    stub = rec.parse_stub(stub_bytes, True, True, OP_READ, 6, found)
    assert found == [] and stub.status == rec.OK_STATUS
    (block,) = stub.blocks
    assert block.layout is rec.READ_RES
    assert (block.values[rec.B_SEQ], block.index, block.record_len) == (3, 0xB02E, 22)
    assert block.get("iod.add_val1") == 0 and block.get("iod.add_val2") == 0
    assert block.record == bytes.fromhex("01010102 42011234 4303000000010000000200000003")


def test_ndr_status_is_reversed_with_little_endian_drep():
    found: list = []
    stub = rec.parse_stub(FRAME4_NDR, True, True, OP_READ, 4, found)
    assert stub.status == rec.Status(0xDE, 0x80, 0xB5, 0x00)
    assert stub.status.text() == "DE80B500"
    fields = _by_name(stub.ndr_layout.annotate(FRAME4_NDR, 0, stub.ndr))
    assert fields["ndr.status.code"].offset == 3 and fields["ndr.status.code2"].offset == 0
    assert fields["ndr.args_len"].value == 0 and fields["ndr.max_count"].value == 304
    stub_be = rec.parse_stub(bytes.fromhex("de80b500") + FRAME4_NDR[4:8][::-1] + bytes(12), False, True,
                             OP_READ, 4, found)
    assert stub_be.status == rec.Status(0xDE, 0x80, 0xB5, 0x00)


def test_record_bounded_by_record_data_length_and_truncation_reported():
    stub_bytes = FRAME1_WRITE_REQ[80:]
    found: list = []
    stub = rec.parse_stub(stub_bytes[:-3], True, False, OP_WRITE, 7, found)
    assert stub.truncated and len(stub.blocks[0].record) == 13
    assert [(f.rule, f.name, f.value, f.expected) for f in found] == [("H5", "record_truncated", "13", "16")]
    found = []
    stub = rec.parse_stub(stub_bytes + b"\x00\x00", True, False, OP_WRITE, 7, found)
    assert stub.blocks[0].record == stub_bytes[84:] and stub.trailing == 2


def test_hostile_record_length_never_reads_beyond_the_stub():
    bad = bytearray(FRAME1_WRITE_REQ[80:])
    bad[20 + 36:20 + 40] = (0xFFFFFFFF).to_bytes(4, "big")
    found: list = []
    stub = rec.parse_stub(bytes(bad), True, False, OP_WRITE, 1, found)
    assert len(stub.blocks[0].record) == 16 and stub.truncated
    assert found[0].name == "record_truncated"
