"""The simulated capture: a deterministic clock, hosts, the link media a frame is written for, and the
frame list being built (Ethernet, IP with fragmentation, UDP).

Nothing here reads the wall clock or the environment: time starts at EPOCH_NS and only moves when a
sender advances it, so the same calls always give the same frames.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Final

from . import net_encode
from .capture_files import Frame
from .net_encode import LINKTYPE_ETHERNET, LINKTYPE_LINUX_SLL, LINKTYPE_LINUX_SLL2, LINKTYPE_RAW, VlanTag

EPOCH_NS: Final = 1_767_225_600 * 1_000_000_000  # 2026-01-01T00:00:00Z


class Clock:
    """Capture time in integer nanoseconds; never reads the wall clock."""

    def __init__(self, start_ns: int = EPOCH_NS) -> None:
        self.now_ns = start_ns

    def advance_us(self, us: float) -> int:
        self.now_ns += round(us * 1000)
        return self.now_ns

    def set_rel(self, seconds: float, base_ns: int = EPOCH_NS) -> int:
        """Jump to base + seconds (for tables such as protocol.md 9)."""
        self.now_ns = base_ns + round(seconds * 1e9)
        return self.now_ns


@dataclass
class Host:
    mac: bytes
    ip: str
    ip_ident: int = 0x0100  # next IPv4 identification

    def next_ident(self) -> int:
        ident = self.ip_ident
        self.ip_ident = (self.ip_ident + 1) & 0xFFFF
        return ident


def host(mac_text: str, ip: str, ip_ident: int = 0x0100) -> Host:
    return Host(net_encode.mac(mac_text), ip, ip_ident)


@dataclass(frozen=True)
class Medium:
    """How an IP packet or Ethernet payload becomes captured bytes.

    For SLL/SLL2, `local_ip` is the capturing host: packets it sends are
    marked "outgoing", others "to us".
    """

    linktype: int = LINKTYPE_ETHERNET
    vlans: tuple[VlanTag, ...] = ()
    mtu: int = 1500
    iface: int = 0
    local_ip: str | None = None

    def frame(self, src_mac: bytes, dst_mac: bytes, ethertype: int, payload: bytes, src_ip: str | None) -> bytes:
        if self.linktype == LINKTYPE_ETHERNET:
            return net_encode.ethernet(dst_mac, src_mac, ethertype, payload, vlans=self.vlans)
        pkttype = net_encode.SLL_OUTGOING if src_ip is not None and src_ip == self.local_ip else net_encode.SLL_HOST
        if self.linktype == LINKTYPE_LINUX_SLL:
            return net_encode.sll(ethertype, payload, pkttype=pkttype, addr=src_mac)
        if self.linktype == LINKTYPE_LINUX_SLL2:
            return net_encode.sll2(ethertype, payload, pkttype=pkttype, addr=src_mac, ifindex=self.iface + 1)
        if self.linktype == LINKTYPE_RAW:
            if ethertype != net_encode.ETH_IPV4:
                raise ValueError("raw IP link type carries IPv4 only")
            return payload
        raise ValueError(f"unsupported link type {self.linktype}")


@dataclass
class Capture:
    """The frame list being built, in file order, plus the shared clock."""

    clock: Clock = field(default_factory=Clock)
    medium: Medium = field(default_factory=Medium)
    frames: list[Frame] = field(default_factory=list)

    def add(self, data: bytes, *, ts_ns: int | None = None, medium: Medium | None = None) -> Frame:
        m = medium or self.medium
        frame = Frame(self.clock.now_ns if ts_ns is None else ts_ns, data, m.linktype, iface=m.iface)
        self.frames.append(frame)
        return frame

    def send_ether(
        self,
        src: Host,
        dst_mac: bytes,
        ethertype: int,
        payload: bytes,
        *,
        ts_ns: int | None = None,
        medium: Medium | None = None,
    ) -> Frame:
        m = medium or self.medium
        return self.add(m.frame(src.mac, dst_mac, ethertype, payload, None), ts_ns=ts_ns, medium=m)

    def send_ip(
        self,
        src: Host,
        dst: Host,
        ip_payload: bytes,
        *,
        ts_ns: int | None = None,
        medium: Medium | None = None,
        ident: int | None = None,
        df: bool = False,
        fragment_order: Sequence[int] | None = None,
        fragment_gap_ns: int = 20_000,
    ) -> list[Frame]:
        """One IP datagram, split into fragments when it exceeds the MTU.
        fragment_order lists fragment indexes in emission order (e.g. [2, 0, 1])."""
        m = medium or self.medium
        t = self.clock.now_ns if ts_ns is None else ts_ns
        ip_id = src.next_ident() if ident is None else ident
        if 20 + len(ip_payload) <= m.mtu:
            packets = [net_encode.ipv4(src.ip, dst.ip, ip_payload, ident=ip_id, df=df)]
        else:
            packets = net_encode.ip_fragments(src.ip, dst.ip, ip_payload, ident=ip_id, mtu=m.mtu)
        order = range(len(packets)) if fragment_order is None else fragment_order
        out = []
        for k, i in enumerate(order):
            data = m.frame(src.mac, dst.mac, net_encode.ETH_IPV4, packets[i], src.ip)
            out.append(self.add(data, ts_ns=t + k * fragment_gap_ns, medium=m))
        return out

    def send_udp(self, src: Host, sport: int, dst: Host, dport: int, payload: bytes, **ip_kw: Any) -> list[Frame]:
        segment = net_encode.udp(sport, dport, payload, src_ip=src.ip, dst_ip=dst.ip)
        return self.send_ip(src, dst, segment, **ip_kw)

    def repeat(self, frame: Frame, ts_ns: int) -> Frame:
        """Identical bytes again later: a retransmission or capture duplicate."""
        copy = Frame(ts_ns, frame.data, frame.linktype, frame.orig_len, frame.iface)
        self.frames.append(copy)
        return copy

    def number(self, frame: Frame) -> int:
        """1-based frame number in file order (by identity, duplicates differ)."""
        for i, f in enumerate(self.frames):
            if f is frame:
                return i + 1
        raise ValueError("frame not in capture")

    def time_sorted(self) -> list[Frame]:
        """Frames ordered by timestamp (stable), for merged interleavings."""
        return sorted(self.frames, key=lambda f: f.ts_ns or 0)
