"""Samples 1-9 (worked_example.pcap to other_port_response.pcap): PNIO record services over Ethernet.

The worked example of protocol.md 9, record read/write with background traffic (both DREPs, and
gzipped), VLAN tags, IP fragments, CL fragments with FACKs, an implicit read, a Write-Multiple, and
answers from another port with a retransmitted request.

Every function builds its file from constants only (fixed UUIDs, addresses,
timestamps from EPOCH_NS, seeded Random), so the output is byte for byte
the same on every run. sample_pcaps/README.md describes what a decoder
should find in each file; keep it in step when changing a function here.
"""

from __future__ import annotations

import struct
import uuid

from . import net_encode, pnio_encode, rpc_encode
from .capture_files import gzip_bytes
from .catalog import intent_of, sample
from .expect import Intent
from .fixtures import (
    arp_exchange,
    epm_lookup,
    pcap_of,
    pcapng_of,
    pn_rt,
    session,
    txn_change_float,
    txn_global_do,
    txn_read_multi,
    txn_read_one,
    udp_noise,
)
from .net_encode import VlanTag
from .pd_encode import ParamAddress as P
from .pd_encode import pd_response, read_request, value_block
from .pnio_encode import InnerWrite
from .pnio_session import PnioSession
from .sim_capture import EPOCH_NS, Capture, Clock, Medium, host

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
