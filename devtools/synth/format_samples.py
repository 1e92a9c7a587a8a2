"""Samples 10-15 (two_interfaces.pcapng to truncated_snaplen.pcap): file formats, link types, RPC control PDUs.

pcapng with two interfaces (and an SPB and an unknown block), a gzipped pcapng named .pcap, Linux
SLL/SLL2 and raw IPv4 link types, a big-endian nanosecond pcap, the RPC control PDUs a decoder must
show but never take for record data, and a capture cut by its snaplen.

Built from constants only, byte for byte the same on every run; keep sample_pcaps/README.md in step.
"""

from __future__ import annotations

from . import net_encode, pnio_encode, rpc_encode
from .capture_files import Frame, Pcapng, gzip_bytes
from .catalog import intent_of, sample
from .expect import Intent
from .fixtures import (
    BROADCAST,
    arp_exchange,
    fixed_uuid,
    pcap_of,
    pcapng_of,
    plant,
    session,
    txn_change_float,
    txn_read_multi,
    txn_read_one,
)
from .net_encode import ETH_ARP, LINKTYPE_ETHERNET, LINKTYPE_LINUX_SLL, LINKTYPE_LINUX_SLL2, LINKTYPE_RAW
from .pd_encode import ParamAddress as P
from .pd_encode import change_ok, change_request, value_block
from .pnio_encode import control_block
from .pnio_session import PnioSession
from .sim_capture import EPOCH_NS, Capture, Clock, Medium, host

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
    x.txn(calls, 2, "malformed", "write request cut by the snaplen (R1, H5)", decided=x.write_req(calls))
    cap.send_udp(s.controller, 50010, other, 50020, bytes(400))  # frame 11, cut
    return cap, x


@sample("truncated_snaplen.pcap")
def truncated_snaplen() -> bytes:
    return pcap_of(truncated_snaplen_capture()[0], snaplen=256)
