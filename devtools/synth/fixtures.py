"""Helpers shared by the sample modules: deterministic UUIDs, hosts and sessions, background traffic
(ARP, PN-RT, plain UDP, an endpoint-mapper lookup), the pcap / pcapng wrappers, and the standard
PROFIdrive exchanges several files reuse.

Conventions as sample_pcaps/README.md: controller 192.168.1.1n talks to device 192.168.1.2n over
session n (activity 000000ac-...-n, ARUUID 000000a2-...-n).
"""

from __future__ import annotations

import uuid
from typing import Any

from . import net_encode, pnio_encode, rpc_encode
from .capture_files import Frame, Pcapng, pcap_bytes
from .net_encode import ETH_ARP, ETH_PNRT, LINKTYPE_ETHERNET
from .pd_encode import ParamAddress as P
from .pd_encode import change_ok, change_request, pd_response, read_request, value_block
from .pnio_session import PnioSession
from .rpc_session import Call
from .sim_capture import Capture, Host, Medium, host

BROADCAST = b"\xff" * 6

# PNIOStatus values the samples answer with (protocol.md 4.6)
DF_B0 = pnio_encode.pnio_status(0xDF, 0x80, 0xB0, 0x00)  # write: invalid index
DF_B1 = pnio_encode.pnio_status(0xDF, 0x80, 0xB1, 0x00)  # write: write length error (buffer too small)
DF_B5 = pnio_encode.pnio_status(0xDF, 0x80, 0xB5, 0x00)  # write: state conflict (the channel is busy)
DF_B7 = pnio_encode.pnio_status(0xDF, 0x80, 0xB7, 0x00)  # write: invalid range (request header)
DE_B1 = pnio_encode.pnio_status(0xDE, 0x80, 0xB1, 0x00)  # read: buffer too small for the response
DE_B2 = pnio_encode.pnio_status(0xDE, 0x80, 0xB2, 0x00)  # read: invalid slot/subslot


def fixed_uuid(kind: int, n: int) -> uuid.UUID:
    """Readable deterministic UUIDs: kind 0xAC = activity, 0xA2 = AR, ..."""
    return uuid.UUID(f"{kind:08x}-0000-1000-8000-{n:012x}")


def plant(n: int = 1, *, net: str = "192.168.1") -> tuple[Host, Host]:
    """Controller .10+n and device .20+n with matching MACs."""
    ctrl = host(f"02:00:00:00:01:{n:02x}", f"{net}.{10 + n}", ip_ident=0x1000 * n)
    dev = host(f"02:00:00:00:02:{n:02x}", f"{net}.{20 + n}", ip_ident=0x1000 * n + 0x800)
    return ctrl, dev


def session(cap: Capture, n: int = 1, *, net: str = "192.168.1", **kw: Any) -> PnioSession:
    """Session n of a plant: activity 000000ac-...-n, ARUUID 000000a2-...-n."""
    ctrl, dev = plant(n, net=net)
    return PnioSession(cap, ctrl, dev, activity=fixed_uuid(0xAC, n), ar_uuid=fixed_uuid(0xA2, n), **kw)


def arp_exchange(cap: Capture, asker: Host, target: Host, medium: Medium | None = None) -> None:
    request = net_encode.arp(1, asker.mac, asker.ip, bytes(6), target.ip)
    cap.send_ether(asker, BROADCAST, ETH_ARP, request, medium=medium)
    cap.clock.advance_us(180)
    reply = net_encode.arp(2, target.mac, target.ip, asker.mac, asker.ip)
    cap.send_ether(target, asker.mac, ETH_ARP, reply, medium=medium)
    cap.clock.advance_us(500)


def pn_rt(cap: Capture, src: Host, dst: Host, counter: int) -> None:
    """One cyclic PN-RT frame (EtherType 0x8892), VLAN-less as PN-RT class 1."""
    cap.send_ether(src, dst.mac, ETH_PNRT, net_encode.pn_rt_cyclic(0x8001, bytes(range(40)), cycle_counter=counter))
    cap.clock.advance_us(50)


def udp_noise(cap: Capture, src: Host, dst: Host) -> None:
    """A UDP datagram that is not DCE/RPC, between ports no dissector claims."""
    cap.send_udp(src, 50010, dst, 50020, b"plain UDP, not DCE/RPC " * 4)
    cap.clock.advance_us(300)


def epm_lookup(cap: Capture, ctrl: Host, dev: Host, drep: bytes) -> None:
    """Endpoint-mapper ept_lookup call + 'not registered' answer on the PNIO
    port: DCE/RPC v4 that a PNIO decoder must ignore silently."""
    le = rpc_encode.drep_little(drep)

    def u32(value: int) -> bytes:
        return rpc_encode.u32(value, le)

    act = fixed_uuid(0xE9, 1)
    # inquiry_type, NULL object ptr, NULL interface ptr, vers_option,
    # 20-byte NIL entry handle, max_ents
    body = u32(0) + u32(0) + u32(0) + u32(1) + bytes(20) + u32(1)
    epm = dict(activity=act, seq=0, opnum=2, interface=rpc_encode.EPM_IF, if_version=3, drep=drep)
    req = rpc_encode.rpc_pdu(body, ptype=rpc_encode.REQUEST, flags1=0x20, **epm)
    cap.send_udp(ctrl, 49160, dev, 34964, req)
    cap.clock.advance_us(900)
    # entry handle, num_ents 0, empty conformant varying array, ept_s_not_registered
    res_body = bytes(20) + u32(0) + u32(1) + u32(0) + u32(0) + u32(0x16C9A0D6)
    res = rpc_encode.rpc_pdu(res_body, ptype=rpc_encode.RESPONSE, flags1=0x0A, boot_time=0x5F000000, **epm)
    cap.send_udp(dev, 34964, ctrl, 49160, res)
    cap.clock.advance_us(2000)


def pcap_of(cap: Capture, **kw: Any) -> bytes:
    return pcap_bytes(cap.frames, linktype=cap.medium.linktype, **kw)


def pcapng_of(frames: list[Frame], linktype: int = LINKTYPE_ETHERNET) -> bytes:
    ng = Pcapng()
    ng.section_header()
    ng.interface(linktype, name="eth0")
    for f in frames:
        ng.epb(f)
    return ng.tobytes()


# ---- standard PROFIdrive exchanges reused by several files ------------------


def txn_read_one(s: PnioSession, ref: int, *, b5: int = 1) -> list[Call]:
    """Read P964[0] (Word 0x1234)."""
    return s.parameter_access(
        read_request(ref, 1, [P(964)]), pd_response(ref, 0x01, 1, [value_block(0x42, [0x1234])]), b5_retries=b5
    )


def txn_change_float(s: PnioSession, ref: int) -> list[Call]:
    """Change P1120[0] (ramp-up time) to 10.0 s; positive change response."""
    return s.parameter_access(change_request(ref, 1, [(P(1120), value_block(0x08, [10.0]))]), change_ok(ref, 1, 1))


def txn_read_multi(s: PnioSession, ref: int, *, b5: int = 2) -> list[Call]:
    """Read P2000[0] (Float32), P2001[0..1] (Double word), P107[0..2]
    (Unsigned8 x3: odd count -> pad byte after the last list)."""
    req = read_request(ref, 1, [P(2000), P(2001, n_elems=2), P(107, n_elems=3)])
    res = pd_response(
        ref,
        0x01,
        1,
        [value_block(0x08, [1500.0]), value_block(0x43, [0x000186A0, 0x00000001]), value_block(0x05, [1, 2, 3])],
    )
    return s.parameter_access(req, res, b5_retries=b5)


def txn_global_do(s: PnioSession, ref: int) -> list[Call]:
    """Global access (0xB02F) to DO 2: read P10[0] (Unsigned16 1)."""
    return s.parameter_access(
        read_request(ref, 2, [P(10)]), pd_response(ref, 0x01, 2, [value_block(0x06, [1])]), index=0xB02F, b5_retries=0
    )


def ok_read(ref: int, do: int, blocks: list[bytes]) -> bytes:
    """A positive read response (Response ID 0x01) carrying these value blocks."""
    return pd_response(ref, 0x01, do, blocks)
