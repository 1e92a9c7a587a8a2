"""Link layer to UDP payload: Ethernet II / 802.1Q tags / Linux SLL, SLL2 / raw IP -> IPv4 -> UDP.

The fast path rejects everything that is not an IPv4/UDP datagram with a few byte comparisons
before any object is built (cyclic PN-RT, ARP, LLDP, ... are most of a PROFINET capture). IPv4
fragments are reassembled here, with caps on the table so a flood of unfinished fragments keeps
memory bounded.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from socket import inet_ntoa
from typing import NamedTuple

from pd_analyze.model import rules
from pd_analyze.model.capped import IP_DATAGRAMS, IP_PIECES, MAX_LISTED, CappedTable
from pd_analyze.model.layout import Field, Layout, plain
from pd_analyze.model.rules import Finding
from pd_analyze.model.values import (
    IP_ETHERTYPES,
    IPV4_ETHERTYPE_BYTES,
    LINKTYPE_ETHERNET,
    LINKTYPE_IPV4,
    LINKTYPE_RAW,
    LINKTYPE_SLL,
    LINKTYPE_SLL2,
    VLAN_TPID_BYTES,
)

ETH = Layout("Ethernet II", ">", (("eth.dst", "6s"), ("eth.src", "6s"), ("eth.type", "H")))
VLAN = Layout("802.1Q tag", ">", (("vlan.id", "H"), ("vlan.etype", "H")))
SLL = Layout("Linux cooked capture", ">", (("sll.pkttype", "H"), ("sll.hatype", "H"), ("sll.halen", "H"),
                                           ("sll.addr", "8s"), ("sll.protocol", "H")))
SLL2 = Layout("Linux cooked capture v2", ">", (("sll.protocol", "H"), ("sll.reserved", "H"),
                                               ("sll.ifindex", "I"), ("sll.hatype", "H"),
                                               ("sll.pkttype", "B"), ("sll.halen", "B"),
                                               ("sll.addr", "8s")))
IPV4 = Layout("Internet Protocol Version 4", ">", (
    ("ip.version", "B"), ("ip.tos", "B"), ("ip.len", "H"), ("ip.id", "H"), ("ip.flags", "H"),
    ("ip.ttl", "B"), ("ip.proto", "B"), ("ip.checksum", "H"), ("ip.src", "4s"), ("ip.dst", "4s")))
UDP = Layout("User Datagram Protocol", ">", (("udp.sport", "H"), ("udp.dport", "H"), ("udp.len", "H"),
                                             ("udp.checksum", "H")))
# What the dump shows of the IPv4 header: version and header length from their byte, the More Fragments bit
# and the fragment offset from the flags word; the offset is the wire value, in 8-byte units as tshark's
# ip.frag_offset (protocol.md 1.3, 8.2), with the bytes in the text.
IPV4_SHOWN = IPV4.shown(
    ("ip.version", "ip.version", lambda v: v >> 4), ("ip.ihl", "ip.version", lambda v: v & 0x0F),
    "ip.tos", "ip.len", "ip.id", "ip.flags", ("ip.mf", "ip.flags", lambda v: (v >> 13) & 1),
    ("ip.frag_offset", "ip.flags", lambda v: v & 0x1FFF, lambda v: f"{v} ({v * 8} bytes)"),
    "ip.ttl", "ip.proto", "ip.checksum", "ip.src", "ip.dst")
# What the dump shows of an 802.1Q tag: priority, DEI and VLAN ID from the TCI word, as Wireshark splits it
VLAN_SHOWN = VLAN.shown(("vlan.pcp", "vlan.id", lambda v: v >> 13), ("vlan.dei", "vlan.id", lambda v: (v >> 12) & 1),
                        ("vlan.id", "vlan.id", lambda v: v & 0x0FFF), "vlan.etype")
_ip_unpack = IPV4.struct.unpack_from
_udp_unpack = UDP.struct.unpack_from

# Skip reasons, counted per capture.
SKIP_LINKTYPE = "link type not Ethernet/SLL/raw IP"
SKIP_NOT_IPV4 = "not IPv4"
SKIP_NOT_UDP = "not UDP"
SKIP_SHORT = "frame too short for its headers"
SKIP_FRAGMENT = "IP fragment (reassembly pending)"
SKIP_MALFORMED = "malformed IPv4/UDP header"
MALFORMED = frozenset({SKIP_MALFORMED})  # reasons counted as malformed frames, not skipped ones
PIECE_OVERHEAD = 128  # bytes a held piece costs beyond its payload (objects), so tiny pieces count too


class Datagram(NamedTuple):
    src: bytes
    dst: bytes
    sport: int
    dport: int
    payload: bytes
    payload_offset: int  # offset of the UDP payload in the frame; -1 when reassembled from fragments
    ip_offset: int
    truncated: bool  # captured shorter than the IP total length
    fragments: tuple[int, ...]  # frames of the IP fragments, when reassembled


def ip_text(addr: bytes) -> str:
    return inet_ntoa(addr)


class LinkHeaders(NamedTuple):
    """Where the link headers of a frame lead: the one walk of the header chain."""

    l3: int  # offset of the IPv4 header, -1 when the frame carries none
    tags: tuple[int, ...] = ()  # offsets of the 802.1Q/802.1ad tag bodies (TCI, EtherType), outer first


def headers(linktype: int, data: bytes) -> LinkHeaders:
    """The link header chain of a frame: Ethernet and its VLAN tags, SLL, SLL2 or raw IP."""
    if linktype == LINKTYPE_ETHERNET:
        etype = data[12:14]
        off = 14
        tags = []
        while etype in VLAN_TPID_BYTES and len(data) >= off + 2:
            tags.append(off)
            etype = data[off + 2:off + 4]
            off += 4
        return LinkHeaders(off if etype == IPV4_ETHERTYPE_BYTES else -1, tuple(tags))
    if linktype == LINKTYPE_SLL:
        return LinkHeaders(16 if data[14:16] == IPV4_ETHERTYPE_BYTES else -1)
    if linktype == LINKTYPE_SLL2:
        return LinkHeaders(20 if data[0:2] == IPV4_ETHERTYPE_BYTES else -1)
    if linktype in (LINKTYPE_RAW, LINKTYPE_IPV4):
        return LinkHeaders(0 if data[:1] and data[0] >> 4 == 4 else -1)
    return LinkHeaders(-1)


def l3_offset(linktype: int, data: bytes) -> int:
    """Offset of an IPv4 header in the frame, or -1 when the frame carries none."""
    return headers(linktype, data).l3


@dataclass(slots=True)
class _Reassembly:
    first_frame: int
    pieces: list[tuple[int, bytes]] = field(default_factory=list)
    frames: list[int] = field(default_factory=list)
    total: int = -1  # length known once the MF-clear piece is in
    header: bytes = b""  # IP header of the offset-0 piece


class LinkDecoder:
    """Frame bytes to UDP datagrams, with IPv4 reassembly state for one capture."""

    def __init__(self) -> None:
        self._open: CappedTable[tuple[bytes, bytes, int, int], _Reassembly] = CappedTable(IP_DATAGRAMS)
        self.findings: list[Finding] = []  # drained by the caller after every frame

    @property
    def evicted(self) -> int:
        """Datagrams dropped by the caps."""
        return self._open.evicted

    def datagram(self, number: int, linktype: int, data: bytes) -> Datagram | str:
        """The frame's UDP datagram, or the reason it has none (a skip reason)."""
        etype = data[12:14] if linktype == LINKTYPE_ETHERNET else b""
        if etype == IPV4_ETHERTYPE_BYTES:
            off = 14  # untagged Ethernet, most frames: the chain is one header long
        elif linktype == LINKTYPE_ETHERNET and etype not in IP_ETHERTYPES:
            return SKIP_NOT_IPV4
        else:
            off = headers(linktype, data).l3
        if off < 0:
            if linktype not in (LINKTYPE_ETHERNET, LINKTYPE_SLL, LINKTYPE_SLL2, LINKTYPE_RAW,
                                LINKTYPE_IPV4):
                return SKIP_LINKTYPE
            return SKIP_NOT_IPV4
        if len(data) < off + 20:
            return SKIP_SHORT
        ver_ihl, _tos, total, ident, flags_frag, _ttl, proto, _ck, src, dst = _ip_unpack(data, off)
        if proto != 17:
            return SKIP_NOT_UDP
        ihl = (ver_ihl & 0x0F) * 4
        if ver_ihl >> 4 != 4 or ihl < 20 or total < ihl:
            self.findings.append(rules.finding(
                "link_malformed", number, "ip.len", total, f">= {ihl}",
                f"IPv4 header invalid (version {ver_ihl >> 4}, IHL {ihl}, total length {total})"))
            return SKIP_MALFORMED
        end = off + total
        truncated = len(data) < end
        ip_payload = data[off + ihl:end]
        if flags_frag & 0x3FFF:  # MF set or offset != 0
            whole = self._add_fragment(number, src, dst, ident, flags_frag, data[off:off + ihl],
                                       ip_payload, truncated)
            if whole is None:
                return SKIP_FRAGMENT
            ip_payload, frames = whole
            return self._udp(number, src, dst, ip_payload, -1, off, False, frames)
        return self._udp(number, src, dst, ip_payload, off + ihl, off, truncated, ())

    def _udp(self, number: int, src: bytes, dst: bytes, payload: bytes, udp_off: int, ip_off: int,
             truncated: bool, frames: tuple[int, ...]) -> Datagram | str:
        if len(payload) < 8:
            if truncated:
                self.findings.append(_truncated(number, len(payload), 8))
            return SKIP_SHORT
        sport, dport, ulen, _ck = _udp_unpack(payload, 0)
        if ulen < 8 or (ulen > len(payload) and not truncated):
            self.findings.append(rules.finding(
                "link_malformed", number, "udp.len", ulen, f"8 ... {len(payload)}",
                f"UDP length {ulen} does not fit the IP payload of {len(payload)} bytes"))
            return SKIP_MALFORMED
        body = payload[8:ulen]
        return Datagram(src, dst, sport, dport, body, udp_off + 8 if udp_off >= 0 else -1, ip_off,
                        truncated, frames)

    def _add_fragment(self, number: int, src: bytes, dst: bytes, ident: int, flags_frag: int,
                      header: bytes, piece: bytes, truncated: bool) -> tuple[bytes, tuple[int, ...]] | None:
        key = (src, dst, 17, ident)
        cost = len(piece) + PIECE_OVERHEAD
        entry = self._open.get(key)
        if entry is not None and len(entry.pieces) >= IP_PIECES:
            self._evicted(key, *self._open.evict(key, number), number, f"more than {IP_PIECES} fragments")
            entry = None
        for victim, old, listed in self._open.make_room(number, cost, key not in self._open, keep=key):
            self._evicted(victim, old, listed, number, "IP reassembly table full")
        if entry is None:
            entry = _Reassembly(number)
            self._open.put(key, entry)
        offset = (flags_frag & 0x1FFF) * 8
        for other_off, other in entry.pieces:
            if other_off == offset and other == piece:
                return None  # an identical copy: a retransmitted fragment, nothing new to hold
            lo, hi = max(offset, other_off), min(offset + len(piece), other_off + len(other))
            if lo < hi and piece[lo - offset:hi - offset] != other[lo - other_off:hi - other_off]:
                self.findings.append(rules.finding(
                    "ip_frag_overlap", number, "ip.frag_offset", offset // 8, "no overlap",
                    f"IP fragment at byte offset {offset} overlaps earlier bytes with different content "
                    f"(first kept; datagram id {ident:#06x})"))
                break
        entry.pieces.append((offset, piece))
        entry.frames.append(number)
        self._open.charge(key, cost)
        if offset == 0:
            entry.header = header
        if not flags_frag & 0x2000 and not truncated:
            entry.total = offset + len(piece)
        if entry.total < 0 or not _covered(entry.pieces, entry.total):
            return None
        self._open.pop(key)
        whole = bytearray(entry.total)
        for off, data in reversed(entry.pieces):  # earlier pieces written last: first one wins
            whole[off:off + len(data)] = data[:max(0, entry.total - off)]
        return bytes(whole), tuple(entry.frames)

    def _evicted(self, key: tuple, entry: _Reassembly, listed: bool, number: int, why: str) -> None:
        if listed:
            self.findings.append(rules.finding(
                IP_DATAGRAMS.rule, number, "ip.id", f"{key[3]:#06x}", f"{IP_DATAGRAMS.text()}, {IP_PIECES} pieces each",
                f"{why}: datagram from frame {entry.first_frame} dropped ({len(entry.frames)} fragments)"))

    def open_pairs(self) -> set[tuple[bytes, bytes]]:
        """(source, destination) of every incomplete datagram."""
        return {(key[0], key[1]) for key in self._open}

    def open_frames(self) -> Iterator[int]:
        """First frame of every incomplete datagram."""
        return (entry.first_frame for entry in self._open.values())

    def finish(self) -> list[Finding]:
        """Findings for datagrams still incomplete at the end of the capture."""
        more = self._open.unlisted()
        if more:
            self.findings.append(rules.finding(
                IP_DATAGRAMS.rule, self._open.last_eviction, "ip.id", self.evicted, IP_DATAGRAMS.text(),
                f"{more} more datagrams dropped by the reassembly caps ({self.evicted} in all; only the "
                f"first {MAX_LISTED} are listed one by one)"))
        out = self.findings + [rules.finding("ip_frag_incomplete", e.first_frame, "ip.id", f"{key[3]:#06x}",
                             "all fragments", f"IP datagram {ip_text(key[0])} -> {ip_text(key[1])} "
                             f"id {key[3]:#06x} incomplete at end of capture (frames "
                             f"{', '.join(map(str, e.frames))})")
               for key, e in self._open.items()]
        self.findings = []
        self._open.clear()
        return out


def _covered(pieces: list[tuple[int, bytes]], total: int) -> bool:
    reach = 0
    for off, data in sorted(pieces):
        if off > reach:
            return False
        reach = max(reach, off + len(data))
    return reach >= total


def _truncated(number: int, present: int, needed: int) -> Finding:
    return rules.finding("truncated_capture", number, "frame.caplen", present, f">= {needed}",
                         "frame captured shorter than its headers (snaplen)")


def annotate(linktype: int, data: bytes, dgram: Datagram) -> list[tuple[str, list[Field]]]:
    """The link, IPv4 and UDP layers of a frame as (title, fields) for the dump."""
    layers: list[tuple[str, list[Field]]] = []
    off = 0
    if linktype == LINKTYPE_ETHERNET:
        layers.append((ETH.title, ETH.annotate(data, 0, ETH.unpack(data))))
        chain = headers(linktype, data)
        for tag in chain.tags:
            layers.append((VLAN.title, VLAN_SHOWN.annotate(data, tag, VLAN.unpack(data, tag))))
        off = chain.l3
    elif linktype == LINKTYPE_SLL:
        layers.append((SLL.title, SLL.annotate(data, 0, SLL.unpack(data))))
        off = 16
    elif linktype == LINKTYPE_SLL2:
        layers.append((SLL2.title, SLL2.annotate(data, 0, SLL2.unpack(data))))
        off = 20
    values = IPV4.unpack(data, off)
    ip = IPV4_SHOWN.annotate(data, off, values)
    ver_ihl = values[0]
    if (ver_ihl & 0x0F) > 5:
        ip.append(plain("ip.options", off + 20, data, (ver_ihl & 0x0F) * 4 - 20,
                        bytes(data[off + 20:off + (ver_ihl & 0x0F) * 4])))
    if dgram.fragments:
        ip.append(Field("ip.reassembled_from", -1, 0, b"", dgram.fragments,
                        ", ".join(map(str, dgram.fragments))))
    layers.append((IPV4.title, ip))
    if dgram.payload_offset >= 0:
        udp_off = dgram.payload_offset - 8
        layers.append((UDP.title, UDP.annotate(data, udp_off, UDP.unpack(data, udp_off))))
    else:
        head = dgram.sport.to_bytes(2, "big") + dgram.dport.to_bytes(2, "big")
        layers.append((UDP.title + " (reassembled)", [plain("udp.sport", 0, head, 2, dgram.sport),
                                                      plain("udp.dport", 2, head, 2, dgram.dport)]))
    return layers


def vlan_ids(linktype: int, data: bytes) -> tuple[int, ...]:
    """VLAN IDs of all tags of an Ethernet frame, outer first."""
    return tuple(int.from_bytes(data[tag:tag + 2], "big") & 0x0FFF for tag in headers(linktype, data).tags)
