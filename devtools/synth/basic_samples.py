"""The older sample captures of sample_pcaps/ (record services, link types, file formats, the fault trace
and the untrusted strings), one builder each.

Every function builds its file from constants only (fixed UUIDs, addresses,
timestamps from EPOCH_NS, seeded Random), so the output is byte for byte
the same on every run. sample_pcaps/README.md describes what a decoder
should find in each file; keep it in step when changing a function here.
"""

from __future__ import annotations

import random
import struct
import uuid
from typing import Any

from . import net_encode, pnio_encode, rpc_encode
from .capture_files import Frame, Pcapng, gzip_bytes
from .catalog import intent_of, sample
from .expect import Intent
from .fixtures import (
    BROADCAST,
    arp_exchange,
    epm_lookup,
    fixed_uuid,
    pcap_of,
    pcapng_of,
    plant,
    pn_rt,
    session,
    txn_change_float,
    txn_global_do,
    txn_read_multi,
    txn_read_one,
    udp_noise,
)
from .net_encode import ETH_ARP, LINKTYPE_ETHERNET, LINKTYPE_LINUX_SLL, LINKTYPE_LINUX_SLL2, LINKTYPE_RAW, VlanTag
from .pd_encode import ParamAddress as P
from .pd_encode import (
    change_ok,
    change_request,
    description,
    error_block,
    pd_response,
    read_request,
    text_entries,
    value_block,
)
from .pnio_encode import InnerWrite, control_block
from .scenario import EPOCH_NS, Capture, Clock, Medium, PnioSession, host

# ---- 1. worked example -------------------------------------------------------

WORKED_REQUEST = read_request(1, 1, [P(964, n_elems=1), P(2000, n_elems=3)])
WORKED_RESPONSE = pd_response(1, 0x01, 1, [value_block(0x42, [0x1234]), value_block(0x43, [1, 2, 3])])


@intent_of("worked_example.pcap")
def worked_example_capture() -> tuple[Capture, Intent]:
    """protocol.md section 9: frames and times exactly as its table."""
    cap = Capture(Clock(EPOCH_NS))
    ctrl = host("02:00:00:00:01:01", "192.168.0.1")
    dev = host("02:00:00:00:02:01", "192.168.0.2")
    s = PnioSession(
        cap,
        ctrl,
        dev,
        activity=uuid.UUID("11111111-2222-3333-4444-555566667777"),
        ar_uuid=uuid.UUID("aaaaaaaa-bbbb-cccc-dddd-eeeeffff0001"),
        object_uuid=rpc_encode.pnio_object_uuid(1, 0x0002, 0x0002),
    )
    x = Intent(cap)
    calls = [
        s.write(0xB02E, WORKED_REQUEST, rtt_us=2100, gap_us=400),  # frames 1, 2
        s.read(0xB02E, status=pnio_encode.STATUS_B5, rtt_us=1900, gap_us=10200),  # frames 3, 4
        s.read(0xB02E, WORKED_RESPONSE, rtt_us=1700),  # frames 5, 6
    ]
    x.txn(calls, 1, "ok", "protocol.md 9: t_write_rtt 2.1 ms, t_total 16.3 ms")
    return cap, x


@sample("worked_example.pcap")
def worked_example() -> bytes:
    return pcap_of(worked_example_capture()[0])


# ---- 2./3. record read/write with background traffic ------------------------


def record_rw_capture(drep: bytes) -> tuple[Capture, Intent]:
    cap = Capture()
    x = Intent(cap)
    s = session(cap, 1, drep=drep, rtt_us=1800, gap_us=900)
    other = host("02:00:00:00:03:01", "192.168.1.50")
    arp_exchange(cap, s.controller, s.device)
    epm_lookup(cap, s.controller, s.device, drep)
    pn_rt(cap, s.device, s.controller, 0x0100)
    x.txn(txn_read_one(s, 1, b5=1), 1, "ok", "P964[0], one B5")
    pn_rt(cap, s.device, s.controller, 0x0180)
    x.txn(txn_change_float(s, 2), 2, "ok", "change P1120[0]")
    udp_noise(cap, s.controller, other)
    x.txn(txn_read_multi(s, 3, b5=2), 3, "ok", "three parameters, two B5, final pad")
    pn_rt(cap, s.device, s.controller, 0x0200)
    x.txn(txn_global_do(s, 4), 4, "ok", "0xB02F DO 2")
    return cap, x


intent_of("record_rw_le.pcap", "record_rw_le.pcap.gz")(lambda: record_rw_capture(rpc_encode.DREP_LE))
intent_of("record_rw_be.pcap")(lambda: record_rw_capture(rpc_encode.DREP_BE))


@sample("record_rw_le.pcap")
def record_rw_le() -> bytes:
    return pcap_of(record_rw_capture(rpc_encode.DREP_LE)[0])


@sample("record_rw_be.pcap")
def record_rw_be() -> bytes:
    return pcap_of(record_rw_capture(rpc_encode.DREP_BE)[0])


@sample("record_rw_le.pcap.gz")
def record_rw_le_gz() -> bytes:
    return gzip_bytes(record_rw_le())


# ---- 4. VLAN tags ------------------------------------------------------------


@intent_of("vlan_stacked.pcap")
def vlan_stacked_capture() -> tuple[Capture, Intent]:
    cap = Capture()
    x = Intent(cap)
    single = Medium(vlans=(VlanTag(100, pcp=6),))
    stacked = Medium(vlans=(VlanTag(200, tpid=net_encode.ETH_QINQ), VlanTag(100, pcp=6)))
    s1 = session(cap, 1, medium=single)
    s2 = session(cap, 2, medium=stacked)
    x.txn(txn_read_one(s1, 1, b5=1), 1, "ok", "VLAN 100")
    x.txn(txn_read_one(s2, 1, b5=0), 1, "ok", "VLAN 200/100")
    x.txn(txn_change_float(s2, 2), 2, "ok", "VLAN 200/100")
    return cap, x


@sample("vlan_stacked.pcap")
def vlan_stacked() -> bytes:
    return pcap_of(vlan_stacked_capture()[0])


# ---- 5. IP fragments ---------------------------------------------------------


@intent_of("ip_fragments.pcap")
def ip_fragments_capture() -> tuple[Capture, Intent]:
    cap = Capture()
    x = Intent(cap)
    # No CL fragmentation: the big bodies travel as one RPC PDU and IP cuts them.
    s = session(cap, 1, max_frag_body=None)
    s.write(0x1000, bytes(i & 0xFF for i in range(3000)))  # 3 fragments in order
    # Write-Multiple carrying a PROFIdrive request, fragments sent last-first.
    inner = [
        (0xB02E, read_request(1, 1, [P(964)])),
        (0x1001, bytes(1500)),
    ]
    write = s.write_multiple(inner, req_ip={"fragment_order": [1, 0]})
    read = s.read(0xB02E, pd_response(1, 0x01, 1, [value_block(0x42, [0x1234])]))
    # the write request is frames 5 (last piece, sent first) and 6: timed at frame 5 (protocol.md 7.6)
    x.txn([write, read], 1, "ok", "opened by the inner B02E write of the Write-Multiple in IP fragments 5-6")
    return cap, x


@sample("ip_fragments.pcap")
def ip_fragments() -> bytes:
    return pcap_of(ip_fragments_capture()[0])


# ---- 6. CL fragments with FACKs ----------------------------------------------


@sample("cl_fragments_fack.pcapng")
def cl_fragments_fack() -> bytes:
    cap = Capture()
    s = session(cap, 1)
    clk = cap.clock
    # Write with a 2900-byte record: body 20 + 64 + 2900 = 2984 -> 1384 + 1384 + 216.
    data = bytes((7 * i) & 0xFF for i in range(2900))
    req, res = s.write_stubs(0x1000, data, api=0, slot=1, subslot=1)
    seq = s.next_seq()
    frags = s.pdus(rpc_encode.REQUEST, req, seq=seq, opnum=3, from_client=True)
    assert len(frags) == 3
    s.send(frags[0], from_client=True)  # 1
    clk.advance_us(800)
    s.fack(seq=seq, opnum=3, frag_num=0, from_client=False)  # 2
    clk.advance_us(300)
    s.send(frags[2], from_client=True)  # 3: out of order, last fragment first
    clk.advance_us(200)
    s.send(frags[1], from_client=True)  # 4
    clk.advance_us(700)
    s.fack(seq=seq, opnum=3, frag_num=1, from_client=False)  # 5
    clk.advance_us(400)
    s.send(frags[1], from_client=True)  # 6: retransmission, identical RPC PDU
    clk.advance_us(1500)
    s.reply(3, res, seq=seq)  # 7
    clk.advance_us(2000)

    # Read with a 1500-byte answer: body 20 + 64 + 1500 = 1584 -> 1384 + 200;
    # the response fragments ask for FACKs, the client FACKs the first one.
    rec = bytes((3 * i) & 0xFF for i in range(1500))
    req, res, _ = s.read_stubs(0x1000, rec, api=0, slot=1, subslot=1, max_len=1600)
    seq = s.next_seq()
    s.send(s.pdu(rpc_encode.REQUEST, req, seq=seq, opnum=2, from_client=True), from_client=True)  # 8
    clk.advance_us(1200)
    rfrags = s.pdus(rpc_encode.RESPONSE, res, seq=seq, opnum=2, from_client=False, flags1=0)
    assert len(rfrags) == 2
    s.send(rfrags[0], from_client=False)  # 9
    clk.advance_us(300)
    s.fack(seq=seq, opnum=2, frag_num=0, from_client=True)  # 10
    clk.advance_us(250)
    s.send(rfrags[1], from_client=False)  # 11
    return pcapng_of(cap.frames)


# ---- 7. implicit read --------------------------------------------------------


def im0_record() -> bytes:
    """I&M0 block (0x0020): vendor (2, as the object UUID), order id, serial,
    hardware/software revision, revision counter, profile 0x3A00, I&M version
    1.1, I&M1-4 supported."""
    body = struct.pack(">H", 0x0002) + b"PD-SYNTH-DRIVE-01".ljust(20) + b"SN-0001".ljust(16)
    body += struct.pack(">H", 3) + b"V" + bytes([4, 7, 0]) + struct.pack(">HHHHH", 0, 0x3A00, 0x0000, 0x0101, 0x001E)
    return pnio_encode.block(0x0020, body)


@intent_of("implicit_read.pcap")
def implicit_read_capture() -> tuple[Capture, Intent]:
    cap = Capture()
    x = Intent(cap)
    s = session(cap, 1)
    s.read_implicit(0xAFF0, im0_record(), api=0, slot=0, subslot=1, max_len=4096)  # frames 1, 2
    write = s.write(0xB02E, read_request(5, 1, [P(964)]))  # frames 3, 4
    read = s.read_implicit(0xB02E, pd_response(5, 0x01, 1, [value_block(0x42, [0x1234])]))  # frames 5, 6
    x.txn([write, read], 5, "ok", "read through ReadImplicit (TargetARUUID)")
    return cap, x


@sample("implicit_read.pcap")
def implicit_read() -> bytes:
    return pcap_of(implicit_read_capture()[0])


# ---- 8. Write-Multiple ---------------------------------------------------------


@intent_of("write_multiple.pcap")
def write_multiple_capture() -> tuple[Capture, Intent]:
    cap = Capture()
    x = Intent(cap)
    s = session(cap, 1)
    ar = s.ar_uuid
    pd_req = read_request(7, 1, [P(964)])  # 10 bytes: 64 + 10 -> 2 pad bytes
    s.iod_seq = 10
    writes = [
        InnerWrite(0xB02E, pd_req, 11, ar, api=0x3A00, slot=1, subslot=1),
        InnerWrite(0x1000, bytes([1, 2, 3, 4, 5]), 12, ar, api=0, slot=2, subslot=1),  # 64 + 5 -> 3 pad bytes
        InnerWrite(0x1001, bytes(range(8)), 13, ar, api=0, slot=2, subslot=1),  # last: no pad
    ]
    calls = [s.write_multiple(writes)]  # frames 1, 2 (outer SeqNumber 10)
    s.iod_seq = 14
    calls.append(s.read(0xB02E, status=pnio_encode.STATUS_B5))  # frames 3, 4
    calls.append(s.read(0xB02E, pd_response(7, 0x01, 1, [value_block(0x42, [0x0815])])))  # frames 5, 6
    x.txn(calls, 7, "ok", "opened by the inner B02E write of a Write-Multiple")
    return cap, x


@sample("write_multiple.pcap")
def write_multiple() -> bytes:
    return pcap_of(write_multiple_capture()[0])


# ---- 9. response from another port, retransmitted request --------------------


@intent_of("other_port_response.pcap")
def other_port_response_capture() -> tuple[Capture, Intent]:
    cap = Capture()
    x = Intent(cap)
    s = session(cap, 1, reply_port=49153)
    calls = [s.write(0xB02E, read_request(9, 1, [P(964)]))]  # 1, 2
    calls.append(s.read(0xB02E, status=pnio_encode.STATUS_B5))  # 3, 4
    # final read: request lost from the controller's view, sent again after 100 ms
    calls.append(s.read(0xB02E, pd_response(9, 0x01, 1, [value_block(0x42, [0x4711])]),
                        retransmit_after_us=[100_000]))  # 5, 6, 7  # fmt: skip
    x.txn(calls, 9, "ok", "answers from port 49153; final read request retransmitted")
    return cap, x


@sample("other_port_response.pcap")
def other_port_response() -> bytes:
    return pcap_of(other_port_response_capture()[0])


# ---- 10. pcapng with two interfaces --------------------------------------------


@intent_of("two_interfaces.pcapng")
def two_interfaces_capture() -> tuple[Capture, Intent]:
    """The frames in file order: the SPB (no timestamp) is frame 5."""
    cap = Capture()
    x = Intent(cap, resolution_ns={0: 1000, 1: 1})  # if_tsresol 6 and 9
    eth = Medium(LINKTYPE_ETHERNET, iface=0)
    a = session(cap, 1, medium=eth)
    ctrl_b, dev_b = plant(2)
    cooked = Medium(LINKTYPE_LINUX_SLL, iface=1, local_ip=ctrl_b.ip)
    b = PnioSession(
        cap, ctrl_b, dev_b, activity=fixed_uuid(0xAC, 2), ar_uuid=fixed_uuid(0xA2, 2), medium=cooked,
        rtt_us=1234.567, gap_us=765.433,
    )  # fmt: skip
    x.txn(txn_read_one(a, 1, b5=0), 1, "ok", "interface 0, µs")  # iface 0, file frames 1-4
    cap.clock.advance_us(0.123)  # make interface-1 times need nanoseconds
    x.txn(txn_read_one(b, 1, b5=1), 1, "ok", "interface 1 (SLL), ns")  # iface 1, file frames 6-11
    arp_request = net_encode.arp(1, a.controller.mac, a.controller.ip, bytes(6), a.device.ip)
    spb_frame = Frame(None, net_encode.ethernet(BROADCAST, a.controller.mac, ETH_ARP, arp_request))
    cap.frames.insert(4, spb_frame)
    return cap, x


@sample("two_interfaces.pcapng")
def two_interfaces() -> bytes:
    cap = two_interfaces_capture()[0]
    ng = Pcapng()
    ng.section_header()
    ng.interface(LINKTYPE_ETHERNET, tsresol=6, name="eth0")
    ng.interface(LINKTYPE_LINUX_SLL, tsresol=9, name="any")
    for i, f in enumerate(cap.frames):
        if i == 2:
            # unknown block type between packets; readers must skip it by length
            ng.block(0x0000_0B0B, b"unknown block: skip me\x00\x00")
        if f.ts_ns is None:
            ng.spb(f)  # frame 5: a Simple Packet Block has no timestamp
        else:
            ng.epb(f)
    return ng.tobytes()


# ---- 11. gzip-compressed pcapng named .pcap -----------------------------------


@intent_of("gzip_pcapng_named.pcap")
def gzip_pcapng_named_capture() -> tuple[Capture, Intent]:
    cap = Capture()
    x = Intent(cap)
    s = session(cap, 1)
    x.txn(txn_read_one(s, 1, b5=1), 1, "ok")
    x.txn(txn_change_float(s, 2), 2, "ok")
    return cap, x


@sample("gzip_pcapng_named.pcap")
def gzip_pcapng_named() -> bytes:
    return gzip_bytes(pcapng_of(gzip_pcapng_named_capture()[0].frames))


# ---- 12. other link types --------------------------------------------------------


def _one_link(medium: Medium) -> tuple[Capture, Intent]:
    cap = Capture(medium=medium)
    x = Intent(cap)
    s = session(cap, 1, medium=medium)
    if medium.linktype != LINKTYPE_RAW:
        arp_exchange(cap, s.controller, s.device)
    x.txn(txn_read_one(s, 1, b5=1), 1, "ok")
    x.txn(txn_read_multi(s, 2, b5=0), 2, "ok", "final pad byte")
    return cap, x


SLL = Medium(LINKTYPE_LINUX_SLL, local_ip="192.168.1.11")
SLL2 = Medium(LINKTYPE_LINUX_SLL2, local_ip="192.168.1.11")
RAW = Medium(LINKTYPE_RAW)
intent_of("linux_sll.pcap")(lambda: _one_link(SLL))
intent_of("linux_sll2.pcap")(lambda: _one_link(SLL2))
intent_of("raw_ipv4.pcap")(lambda: _one_link(RAW))


@sample("linux_sll.pcap")
def linux_sll() -> bytes:
    return pcap_of(_one_link(SLL)[0])


@sample("linux_sll2.pcap")
def linux_sll2() -> bytes:
    return pcap_of(_one_link(SLL2)[0])


@sample("raw_ipv4.pcap")
def raw_ipv4() -> bytes:
    return pcap_of(_one_link(RAW)[0])


# ---- 13. nanosecond big-endian pcap ----------------------------------------------


@intent_of("pcap_nsec_be.pcap")
def pcap_nsec_be_capture() -> tuple[Capture, Intent]:
    cap = Capture(Clock(EPOCH_NS + 123_456_789))
    x = Intent(cap, resolution_ns=1)
    s = session(cap, 1, rtt_us=1111.111, gap_us=2222.222)
    x.txn(txn_read_one(s, 1, b5=1), 1, "ok", "ns timestamps")
    return cap, x


@sample("pcap_nsec_be.pcap")
def pcap_nsec_be() -> bytes:
    return pcap_of(pcap_nsec_be_capture()[0], nanosecond=True, big_endian=True)


# ---- 14. RPC control PDUs ---------------------------------------------------------


@sample("rpc_control_pdus.pcap")
def rpc_control_pdus() -> bytes:
    cap = Capture()
    s = session(cap, 1)
    clk = cap.clock
    ar, key = s.ar_uuid, 1
    ctrl_obj = rpc_encode.pnio_object_uuid(1, 0x0001, 0x002A)
    # Connect (seq 1): ARBlockReq / ARBlockRes only, blocks shown raw
    s.cm_call(
        0,
        pnio_encode.ar_block_req(
            ar_uuid=ar, session_key=key, initiator_mac=s.controller.mac, initiator_object=ctrl_obj, station_name="plc1"
        ),
        pnio_encode.ar_block_res(ar_uuid=ar, session_key=key, responder_mac=s.device.mac),
        rtt_us=9000,
    )
    # Control PrmEnd (seq 2), not idempotent: the client acks the response
    c = s.cm_call(
        4,
        control_block(pnio_encode.IOD_CONTROL_REQ, ar_uuid=ar, session_key=key, command=pnio_encode.CMD_PRM_END),
        control_block(pnio_encode.IOD_CONTROL_RES, ar_uuid=ar, session_key=key, command=pnio_encode.CMD_DONE),
        req_rpc={"flags1": 0},
        gap_us=200,
    )
    s.send_pdu(rpc_encode.ACK, seq=c.seq, opnum=4, from_client=True)
    clk.advance_us(5000)

    # Long write (seq 3): ping -> working twice, then the response
    req, res = s.write_stubs(0x1000, b"\x00\x01\x02\x03", api=0)
    seq = s.next_seq()
    s.send(s.pdu(rpc_encode.REQUEST, req, seq=seq, opnum=3, from_client=True), from_client=True)
    for _ in range(2):
        clk.advance_us(300_000)
        s.send_pdu(rpc_encode.PING, seq=seq, opnum=3, from_client=True)
        clk.advance_us(800)
        s.send_pdu(rpc_encode.WORKING, seq=seq, opnum=3, from_client=False)
    clk.advance_us(150_000)
    s.reply(3, res, seq=seq)
    clk.advance_us(3000)

    # Read (seq 4): device has no record of the call -> nocall; the client
    # sends the request again (identical RPC PDU) and gets the answer
    req, res, _ = s.read_stubs(0x1000, b"\x00\x01\x02\x03", api=0, max_len=64)
    seq = s.next_seq()
    req_pdu = s.pdu(rpc_encode.REQUEST, req, seq=seq, opnum=2, from_client=True)
    s.send(req_pdu, from_client=True)
    clk.advance_us(500_000)
    s.send_pdu(rpc_encode.PING, seq=seq, opnum=2, from_client=True)
    clk.advance_us(700)
    s.send_pdu(rpc_encode.NOCALL, seq=seq, opnum=2, from_client=False)
    clk.advance_us(1000)
    s.send(req_pdu, from_client=True)
    clk.advance_us(1500)
    s.reply(2, res, seq=seq)
    clk.advance_us(3000)

    # Fault (seq 5): read addressed to the Supervisor interface -> unknown interface
    supervisor = {"interface": rpc_encode.PNIO_SUPERVISOR_IF}
    c = s.read(0x1000, api=0, max_len=64, respond=False, req_rpc=supervisor, gap_us=900)
    s.status_pdu(rpc_encode.FAULT, 0x1C010003, seq=c.seq, opnum=2, interface=rpc_encode.PNIO_SUPERVISOR_IF)
    clk.advance_us(3000)

    # Reject (seq 6): unknown opnum 9 -> operation range error
    c = s.call(9, s.req_stub(b"", args_max=0), None, gap_us=700)
    s.status_pdu(rpc_encode.REJECT, 0x1C010002, seq=c.seq, opnum=9)
    clk.advance_us(3000)

    # Cancelled write (seq 7): cl_cancel, cancel_ack, then fault nca_s_fault_cancel
    c = s.write(0x1001, b"\x0a\x0b\x0c\x0d", api=0, respond=False, gap_us=200_000)
    s.send_pdu(rpc_encode.CL_CANCEL, seq=c.seq, opnum=3, from_client=True, body=rpc_encode.cancel_body(1, s.little))
    clk.advance_us(900)
    cancel_ack = rpc_encode.cancel_ack_body(1, s.little)
    s.send_pdu(rpc_encode.CANCEL_ACK, seq=c.seq, opnum=3, from_client=False, body=cancel_ack)
    clk.advance_us(1200)
    s.status_pdu(rpc_encode.FAULT, 0x1C00000D, seq=c.seq, opnum=3)
    clk.advance_us(5000)

    # Release (seq 8)
    s.cm_call(
        1,
        control_block(pnio_encode.IOD_RELEASE_REQ, ar_uuid=ar, session_key=key, command=pnio_encode.CMD_RELEASE),
        control_block(pnio_encode.IOD_RELEASE_RES, ar_uuid=ar, session_key=key, command=pnio_encode.CMD_DONE),
    )
    return pcap_of(cap)


# ---- 15. snaplen truncation ---------------------------------------------------------


@intent_of("truncated_snaplen.pcap")
def truncated_snaplen_capture() -> tuple[Capture, Intent]:
    cap = Capture()
    x = Intent(cap)
    s = session(cap, 1)
    other = host("02:00:00:00:03:01", "192.168.1.50")
    arp_exchange(cap, s.controller, s.device)
    x.txn(txn_read_one(s, 1, b5=0), 1, "ok")  # frames 3-6, all <= 256 bytes
    # change request with 20 Unsigned32 values: 92-byte record, 298-byte frame
    req = change_request(2, 1, [(P(2000, n_elems=20), value_block(0x07, list(range(1, 21))))])
    calls = s.parameter_access(req, change_ok(2, 1, 1))  # frames 7-10, frame 7 cut
    x.txn(calls, 2, "malformed", "write request cut by the snaplen (R1, H5)")
    cap.send_udp(s.controller, 50010, other, 50020, bytes(400))  # frame 11, cut
    return cap, x


@sample("truncated_snaplen.pcap")
def truncated_snaplen() -> bytes:
    return pcap_of(truncated_snaplen_capture()[0], snaplen=256)


# ---- fault_trace.pcap: three drives interleaved, for the notebook and the HTML report -------------------


@intent_of("fault_trace.pcap")
def fault_trace_capture() -> tuple[Capture, Intent]:
    """Commissioning of three drives by three controllers at once (own clocks,
    merged by time): change trails preceded by reads, NAKs with several error
    numbers, B5 polling, a write refused with DF 80 B1 00, a timeout and its
    retry. sample_pcaps/README.md lists what the analyser must find."""
    cap = Capture()
    x = Intent(cap)
    f32, w16, u16 = 0x08, 0x42, 0x06
    df_b1 = pnio_encode.pnio_status(0xDF, 0x80, 0xB1, 0x00)
    refs: dict[str, int] = {}  # last Request Reference per device
    pauses: dict[str, random.Random] = {}  # the controllers' idle times between transactions

    def drive(n: int, start_ms: int, rtt_us: float, jitter_us: float) -> PnioSession:
        s = session(cap, n, own_clock=Clock(EPOCH_NS + start_ms * 1_000_000), rtt_us=rtt_us, gap_us=1500,
                    jitter_us=jitter_us, rng=random.Random(n))
        refs[s.device.ip], pauses[s.device.ip] = 0, random.Random(10 + n)
        return s

    def nxt(s: PnioSession) -> int:
        refs[s.device.ip] += 1
        return refs[s.device.ip]

    def access(s: PnioSession, request: bytes, response: bytes | None, pause_ms: float, retry: bool = False,
               **kw: Any) -> None:
        """One transaction, then the controller's idle time before the next one."""
        calls = s.parameter_access(request, response, **kw)
        if "write_status" in kw:
            verdict = "pnio_error"
        elif response is None:
            verdict = "timeout"  # no answer after the B5 polls: closed by the 10 s deadline
        else:
            verdict = "nak" if response[1] & 0x80 else "ok"
        x.txn(calls, request[0], verdict, findings=[(x.write_req(calls), "retry")] if retry else ())
        s.clock.advance_us(pauses[s.device.ip].uniform(0.6, 1.4) * pause_ms * 1000)

    def read1(s: PnioSession, pnu: int, fmt: int, value: float, pause_ms: float, **kw: Any) -> None:
        r = nxt(s)
        access(s, read_request(r, 1, [P(pnu)]), pd_response(r, 0x01, 1, [value_block(fmt, [value])]), pause_ms, **kw)

    def change1(s: PnioSession, pnu: int, fmt: int, value: float, pause_ms: float, error: int = -1,
                ref: int = 0, **kw: Any) -> None:
        r = ref or nxt(s)
        block = error_block(error, 0) if error in (0x01, 0x02, 0x14) else error_block(error)  # with subindex
        res = change_ok(r, 1, 1) if error < 0 else pd_response(r, 0x82, 1, [block])
        access(s, change_request(r, 1, [(P(pnu), value_block(fmt, [value]))]), res, pause_ms, retry=bool(ref),
               **kw)

    # drive 1 (.21): quick (1.2 ms RTT), one change below the limit, one PNU that does not exist
    d1 = drive(1, 0, 1200, 400)
    read1(d1, 1082, f32, 1500.0, 300)  # max. speed, read before the change
    change1(d1, 1082, f32, 3000.0, 300, b5_retries=1)
    read1(d1, 1120, f32, 10.0, 300)  # ramp-up time
    change1(d1, 1120, f32, 5.0, 300)
    read1(d1, 1121, f32, 10.0, 300)  # ramp-down time
    change1(d1, 1121, f32, 0.001, 300, error=0x02)  # below the lower limit
    change1(d1, 1121, f32, 2.0, 300)
    r = nxt(d1)  # three parameters at once, one of them does not exist
    access(d1, read_request(r, 1, [P(964), P(9999), P(2000)]),
           pd_response(r, 0x81, 1, [value_block(w16, [0x1234]), error_block(0x00), value_block(f32, [3000.0])]),
           300, b5_retries=1)
    for k in range(16):  # monitoring: actual speed
        read1(d1, 63, f32, 2950.0 + 5 * k, 1200, b5_retries=int(k % 3 == 0))

    # drive 2 (.22): slow (4 ms RTT, B5 polling 20 ms apart), refuses changes while running
    d2 = drive(2, 120, 4000, 2500)
    slow = {"read_gap_us": 20_000}
    read1(d2, 2, u16, 7, 400)
    change1(d2, 2, u16, 1, 400, error=0x01)  # P2 is read-only
    read1(d2, 1300, u16, 20, 400)  # control mode
    change1(d2, 1300, u16, 21, 400, error=0x11, b5_retries=2, **slow)  # not while the drive runs
    change1(d2, 971, u16, 1, 400, b5_retries=12, **slow)  # save to non-volatile memory: long B5 polling
    for k in range(16):
        read1(d2, 63, f32, 1400.0 + k, 1200, b5_retries=2 + k % 4, **slow)
    change1(d2, 1300, u16, 21, 400, error=0x11)

    # drive 3 (.23): a refused write, a timeout and its retry, NAKs on subindex and data type
    d3 = drive(3, 260, 1800, 600)
    read1(d3, 964, w16, 0x1234, 500)
    r = nxt(d3)  # a 20-parameter read the device's parameter buffer cannot take
    access(d3, read_request(r, 1, [P(2000 + i) for i in range(20)]), None, 500, write_status=df_b1)
    read1(d3, 1082, f32, 1500.0, 500)
    r = nxt(d3)  # after three B5 the drive stops answering: a timeout (10 s deadline)
    access(d3, change_request(r, 1, [(P(1082), value_block(f32, [2800.0]))]), None, 12_000, b5_retries=3)
    change1(d3, 1082, f32, 2800.0, 500, ref=r, b5_retries=1)  # the controller retries with the same reference
    r = nxt(d3)
    access(d3, read_request(r, 1, [P(945, 40)]), pd_response(r, 0x81, 1, [error_block(0x03, 40)]), 500)
    change1(d3, 1120, w16, 5, 500, error=0x05)  # Word written to a Float32 parameter
    change1(d3, 1120, f32, 5.0, 500)
    for k in range(8):
        read1(d3, 63, f32, 2790.0 + k, 1000)
    cap.frames = cap.time_sorted()
    return cap, x


@sample("fault_trace.pcap")
def fault_trace() -> bytes:
    return pcap_of(fault_trace_capture()[0])


# ---- crafted_strings.pcap: untrusted text in every place a capture carries it ----------------------------


@sample("crafted_strings.pcap")
def crafted_strings() -> bytes:
    """Strings a hostile device (or a forged capture) could send, in every place a capture carries text:
    a text array (attribute 0x30), a description's name (attribute 0x20, subindex 0), VisibleString,
    OctetString and UnicodeString values, read and written. Markup and script (<script>, attribute and
    URL injection), terminal control (ANSI CSI and OSC, C1 CSI, CR, BS, BEL) and spreadsheet formulas
    (leading =, +, -, @, tab, CR). Every output must show them inertly (tests/test_untrusted_strings.py)."""
    cap = Capture()
    s = session(cap, 1)

    def text(pnu: int, value: str, fmt: int = 0x09) -> tuple[P, bytes]:
        return P(pnu, n_elems=len(value)), value_block(fmt, value)

    # ref 1 (frames 1-4): a text array and a description whose name is markup
    names = text_entries(["<script>alert(1)", "</script><b>x</b"])
    desc = description(0x0009, 16, "<svg/onload=a()>")
    s.parameter_access(read_request(1, 1, [P(1, n_elems=2, attr=0x30), P(2, attr=0x20)]),
                       pd_response(1, 0x01, 1, [value_block(0x09, names), value_block(0x0A, desc)]))
    # ref 2 (frames 5-8): attribute and URL injection, answered with a NAK (so the HTML drill-down shows it)
    html = [text(20, '"><img src=x onerror=alert(2)>'), text(21, "javascript:alert(3)"),
            text(22, "' onmouseover='alert(4)")]
    s.parameter_access(read_request(2, 1, [a for a, _ in html] + [P(23)]),
                       pd_response(2, 0x81, 1, [b for _, b in html] + [error_block(0x00)]))
    # ref 3 (frames 9-12): terminal control sequences, NAK
    term = [text(30, "\x1b[31mRED\x1b[0m\x1b]0;pwned\x07"), text(31, "\x9b2J\rOVER\x08WRITTEN"),
            (P(32, n_elems=12), value_block(0x0A, b"\x1b[2J<script>")), text(33, "\u202eevil\u2028x", 0x27)]
    s.parameter_access(read_request(3, 1, [a for a, _ in term] + [P(34)]),
                       pd_response(3, 0x81, 1, [b for _, b in term] + [error_block(0x00)]))
    # ref 4 (frames 13-16) reads formulas, ref 5 (17-20) writes others over them: the change trail has both
    formulas = ["=cmd|' /C calc'!A0", "+SUM(1,2)", "-2+3", "@SUM(1,2)", "\t=1+2", "\r=1+2"]
    read = [text(40 + i, f) for i, f in enumerate(formulas)]
    s.parameter_access(read_request(4, 1, [a for a, _ in read]), pd_response(4, 0x01, 1, [b for _, b in read]))
    written = [text(40 + i, f) for i, f in enumerate(["=1+1", "+1-1", "-1+1", "@A1", "\t@A1", "\r-1"])]
    s.parameter_access(change_request(5, 1, written), change_ok(5, 1, len(written)))
    return pcap_of(cap)
