"""Link, network and transport layer encoders: Ethernet II, 802.1Q/802.1ad
tags, Linux SLL/SLL2, IPv4 (with fragmentation), UDP, plus the small
background frames (ARP, PN-RT) a decoder must skip.

Every function returns bytes. Fields that a test may want to corrupt are
keyword arguments whose default (None) means "the correct computed value".
"""

from __future__ import annotations

import functools
import ipaddress
import struct
from collections.abc import Sequence
from dataclasses import dataclass

ETH_IPV4 = 0x0800
ETH_ARP = 0x0806
ETH_VLAN = 0x8100
ETH_QINQ = 0x88A8
ETH_PNRT = 0x8892

LINKTYPE_ETHERNET = 1
LINKTYPE_RAW = 101
LINKTYPE_LINUX_SLL = 113
LINKTYPE_LINUX_SLL2 = 276

IPPROTO_UDP = 17

# Linux packet types used in SLL/SLL2 headers (as the kernel reports them).
SLL_HOST = 0  # addressed to us
SLL_OUTGOING = 4  # sent by us
ARPHRD_ETHER = 1


def mac(text: str) -> bytes:
    """'02:00:00:00:00:01' -> 6 bytes."""
    raw = bytes.fromhex(text.replace(":", "").replace("-", ""))
    if len(raw) != 6:
        raise ValueError(f"not a MAC address: {text!r}")
    return raw


@functools.cache  # a capture names a few hosts millions of times (the large generated ones)
def ip4(text: str) -> bytes:
    return ipaddress.IPv4Address(text).packed


@dataclass(frozen=True)
class VlanTag:
    """One 802.1Q-style tag; tpid 0x8100 (C-tag), 0x88A8 (S-tag) or 0x9100."""

    vid: int
    pcp: int = 0
    dei: int = 0
    tpid: int = ETH_VLAN

    def encode(self) -> bytes:
        """TPID + TCI (4 bytes); the next type follows as the next tag's TPID
        or, after the last tag, as the real EtherType."""
        tci = (self.pcp & 0x7) << 13 | (self.dei & 0x1) << 12 | (self.vid & 0xFFF)
        return struct.pack("!HH", self.tpid, tci)


def ethernet(
    dst: bytes,
    src: bytes,
    ethertype: int,
    payload: bytes,
    *,
    vlans: Sequence[VlanTag] = (),
    pad_to_min: bool = True,
) -> bytes:
    """Ethernet II frame without FCS; tags are listed outermost first.

    Frames are zero-padded to the 60-byte minimum like a real NIC sends them,
    so decoders must bound the IP datagram by its total length.
    """
    tags = b"".join(tag.encode() for tag in vlans)
    frame = dst + src + tags + struct.pack("!H", ethertype) + payload
    if pad_to_min and len(frame) < 60:
        frame += b"\x00" * (60 - len(frame))
    return frame


def sll(
    proto: int,
    payload: bytes,
    *,
    pkttype: int = SLL_HOST,
    hatype: int = ARPHRD_ETHER,
    addr: bytes = b"",
    addr_len: int | None = None,
) -> bytes:
    """Linux cooked v1 header (16 bytes) + payload, linktype 113."""
    alen = len(addr) if addr_len is None else addr_len
    return struct.pack("!HHH8sH", pkttype, hatype, alen, addr.ljust(8, b"\x00"), proto) + payload


def sll2(
    proto: int,
    payload: bytes,
    *,
    ifindex: int = 1,
    pkttype: int = SLL_HOST,
    hatype: int = ARPHRD_ETHER,
    addr: bytes = b"",
    addr_len: int | None = None,
    reserved: int = 0,
) -> bytes:
    """Linux cooked v2 header (20 bytes) + payload, linktype 276."""
    alen = len(addr) if addr_len is None else addr_len
    return struct.pack("!HHIHBB8s", proto, reserved, ifindex, hatype, pkttype, alen, addr.ljust(8, b"\x00")) + payload


def inet_checksum(data: bytes) -> int:
    if len(data) % 2:
        data += b"\x00"
    total = sum(struct.unpack(f"!{len(data) // 2}H", data))
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    return ~total & 0xFFFF


def ipv4(
    src: str,
    dst: str,
    payload: bytes,
    *,
    ident: int = 0,
    proto: int = IPPROTO_UDP,
    ttl: int = 64,
    tos: int = 0,
    df: bool = False,
    mf: bool = False,
    frag_offset: int = 0,
    options: bytes = b"",
    ihl: int | None = None,
    total_length: int | None = None,
    checksum: int | None = None,
    version: int = 4,
) -> bytes:
    """IPv4 packet. frag_offset is in 8-byte units as on the wire."""
    if len(options) % 4:
        raise ValueError("IPv4 options must be a multiple of 4 bytes")
    hl = 5 + len(options) // 4 if ihl is None else ihl
    tl = 20 + len(options) + len(payload) if total_length is None else total_length
    flags_frag = (0x4000 if df else 0) | (0x2000 if mf else 0) | (frag_offset & 0x1FFF)
    header = (
        struct.pack("!BBHHHBBH4s4s", version << 4 | hl, tos, tl, ident, flags_frag, ttl, proto, 0, ip4(src), ip4(dst))
        + options
    )
    csum = inet_checksum(header) if checksum is None else checksum
    return header[:10] + struct.pack("!H", csum) + header[12:] + payload


def ip_fragments(
    src: str,
    dst: str,
    ip_payload: bytes,
    *,
    ident: int,
    mtu: int = 1500,
    proto: int = IPPROTO_UDP,
    ttl: int = 64,
) -> list[bytes]:
    """Split one IP payload (e.g. a whole UDP datagram) into IPv4 fragments
    that each fit `mtu`; returned in offset order (reorder in the caller)."""
    chunk = (mtu - 20) // 8 * 8  # every piece but the last must be a multiple of 8
    if chunk <= 0:
        raise ValueError("mtu too small")
    pieces = []
    for off in range(0, len(ip_payload), chunk):
        part = ip_payload[off : off + chunk]
        last = off + chunk >= len(ip_payload)
        pieces.append(ipv4(src, dst, part, ident=ident, proto=proto, ttl=ttl, mf=not last, frag_offset=off // 8))
    return pieces


def udp(
    sport: int,
    dport: int,
    payload: bytes,
    *,
    src_ip: str | None = None,
    dst_ip: str | None = None,
    length: int | None = None,
    checksum: int | None = None,
) -> bytes:
    """UDP datagram. The checksum is computed when both IPs are given, else 0
    ("not computed", legal for IPv4)."""
    ln = 8 + len(payload) if length is None else length
    if checksum is None:
        if src_ip is None or dst_ip is None:
            checksum = 0
        else:
            pseudo = ip4(src_ip) + ip4(dst_ip) + struct.pack("!BBH", 0, IPPROTO_UDP, 8 + len(payload))
            checksum = inet_checksum(pseudo + struct.pack("!HHHH", sport, dport, ln, 0) + payload)
            # 0 means "no checksum" on the wire, so a computed 0 is sent as 0xFFFF.
            checksum = checksum or 0xFFFF
    return struct.pack("!HHHH", sport, dport, ln, checksum) + payload


def arp(
    op: int,
    sender_mac: bytes,
    sender_ip: str,
    target_mac: bytes,
    target_ip: str,
) -> bytes:
    """ARP payload for Ethernet/IPv4 (op 1 request, 2 reply)."""
    return struct.pack("!HHBBH", 1, ETH_IPV4, 6, 4, op) + sender_mac + ip4(sender_ip) + target_mac + ip4(target_ip)


def pn_rt_cyclic(frame_id: int, data: bytes, *, cycle_counter: int, data_status: int = 0x35) -> bytes:
    """PN-RT cyclic payload (EtherType 0x8892): FrameID, IO data,
    CycleCounter, DataStatus, TransferStatus. Out of the analyser's scope,
    present so decoders prove they skip it cheaply."""
    return struct.pack("!H", frame_id) + data + struct.pack("!HBB", cycle_counter & 0xFFFF, data_status, 0)
