"""The link, IPv4 and UDP layers of a batch of frames as columns: which frames carry one whole UDP datagram
of ordinary shape, where its payload lies, and which frames the per-frame decoder skips silently.

The same decisions as `link.LinkDecoder.datagram` (with `link.headers`) for Ethernet frames, taken for all
frames at once with the field offsets of the link Layouts. What the per-frame decoder answers with a
finding or with state is left to it (`frames`): IP fragments, an invalid IPv4 header or UDP length, a
frame captured shorter than its IP total length; so are other link types and more than MAX_TAGS VLAN tags
(their headers are still read for the address pair, `group`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pd_analyze.model.layout import be_uint
from pd_analyze.model.values import (
    ETHERTYPE_IPV4,
    LINKTYPE_ETHERNET,
    LINKTYPE_IPV4,
    LINKTYPE_RAW,
    LINKTYPE_SLL,
    LINKTYPE_SLL2,
    VLAN_TPIDS,
)
from pd_analyze.protocol import link
from pd_analyze.protocol.link import ETH, IPV4, SLL, SLL2, UDP, VLAN

# The silent skips, by code: Datagrams.skip indexes this tuple
SKIPS = (link.SKIP_NOT_IPV4, link.SKIP_SHORT, link.SKIP_NOT_UDP)
NOT_IPV4, SHORT, NOT_UDP = range(len(SKIPS))
MAX_TAGS = 4  # VLAN tags walked here (stacked Q-in-Q is two); a frame with more goes to the per-frame path
IP_UDP = 17  # IPv4 protocol number of UDP, as LinkDecoder.datagram compares it
IP_FRAGMENT = 0x3FFF  # ip.flags bits of a fragment: More Fragments, or a fragment offset
_TPIDS = np.array(sorted(VLAN_TPIDS), np.int32)


@dataclass(slots=True)
class Datagrams:
    """One entry per frame of the batch."""

    skip: np.ndarray  # int8: index into SKIPS when the per-frame decoder skips the frame silently, -1 otherwise
    frames: np.ndarray  # bool: the per-frame decoder must take the frame (module docstring)
    # min(src, dst) << 32 | max(src, dst) of a frame whose IPv4 header is readable (20 bytes present), else 0
    group: np.ndarray  # uint64
    src: np.ndarray  # uint32, big-endian integer of the address (0 without a readable IPv4 header)
    dst: np.ndarray  # uint32
    # the UDP datagram: meaningful for `ordinary` frames only
    sport: np.ndarray  # uint16
    dport: np.ndarray  # uint16
    start: np.ndarray  # int64: offset of the UDP payload in the batch buffer
    length: np.ndarray  # int64: its length, udp.len - 8

    @property
    def ordinary(self) -> np.ndarray:
        """Frames carrying one whole UDP datagram the columnar decode goes on with."""
        return (self.skip < 0) & ~self.frames


def datagrams(data: np.ndarray, linktype: np.ndarray, start: np.ndarray, caplen: np.ndarray) -> Datagrams:
    """The frames data[start[i] : start[i] + caplen[i]] (link types per frame) down to their UDP payloads."""
    start = start.astype(np.int64, copy=False)
    caplen = caplen.astype(np.int64, copy=False)
    skip = np.full(len(start), -1, np.int8)
    frames = linktype != LINKTYPE_ETHERNET
    l3 = _ethernet(data, linktype, start, caplen, skip, frames)
    _other_links(data, linktype, start, caplen, l3)
    return _ipv4_udp(data, linktype, start, caplen, l3, skip, frames)


def _ethernet(data: np.ndarray, linktype: np.ndarray, start: np.ndarray, caplen: np.ndarray, skip: np.ndarray,
              frames: np.ndarray) -> np.ndarray:
    """Offset of the IPv4 header in each Ethernet frame (after its VLAN tags), -1 where there is none."""
    eth = linktype == LINKTYPE_ETHERNET
    typed = eth & (caplen >= ETH.size)
    skip[eth & ~typed] = NOT_IPV4  # no whole EtherType: not IPv4 (data[12:14] compares short)
    etype = ETH.columns(data, start, ("eth.type",), typed)["eth.type"].astype(np.int32)
    off = np.full(len(start), ETH.size, np.int64)
    # link.headers: while the EtherType is a TPID and the tag's TCI is present, the next EtherType follows it
    walk = np.flatnonzero(typed & np.isin(etype, _TPIDS) & (caplen >= off + 2))
    tags = 0
    while len(walk):  # one step per tag, for all frames still walking (a tag takes 4 of a frame's bytes)
        if tags == MAX_TAGS:
            frames[walk] = True  # more tags than handled here: walked on only for the address pair
        whole = caplen[walk] >= off[walk] + VLAN.size
        inner = VLAN.columns(data, start[walk] + off[walk], ("vlan.etype",), whole)["vlan.etype"].astype(np.int32)
        inner[~whole] = -1  # a cut EtherType is none
        etype[walk] = inner
        off[walk] += VLAN.size
        walk = walk[np.isin(inner, _TPIDS) & (caplen[walk] >= off[walk] + 2)]
        tags += 1
    ipv4 = typed & (etype == ETHERTYPE_IPV4)
    skip[typed & ~ipv4 & ~frames] = NOT_IPV4
    return np.where(ipv4, off, -1)


def _other_links(data: np.ndarray, linktype: np.ndarray, start: np.ndarray, caplen: np.ndarray,
                 l3: np.ndarray) -> None:
    """IPv4 offsets of Linux SLL, SLL2 and raw IP frames, only for their `group`: the per-frame path takes them."""
    for kind, header in ((LINKTYPE_SLL, SLL), (LINKTYPE_SLL2, SLL2)):
        i = np.flatnonzero((linktype == kind) & (caplen >= header.size))
        proto = header.columns(data, start[i], ("sll.protocol",))["sll.protocol"]
        l3[i[proto == ETHERTYPE_IPV4]] = header.size
    i = np.flatnonzero(np.isin(linktype, (LINKTYPE_RAW, LINKTYPE_IPV4)) & (caplen >= 1))
    version = IPV4.columns(data, start[i], ("ip.version",))["ip.version"] >> 4  # ip.version holds version and IHL
    l3[i[version == 4]] = 0


def _ipv4_udp(data: np.ndarray, linktype: np.ndarray, start: np.ndarray, caplen: np.ndarray, l3: np.ndarray,
              skip: np.ndarray, frames: np.ndarray) -> Datagrams:
    """LinkDecoder.datagram and _udp from the IPv4 header on, in their order of decisions."""
    readable = (l3 >= 0) & (caplen >= l3 + IPV4.size)
    eth = linktype == LINKTYPE_ETHERNET
    skip[eth & (l3 >= 0) & ~readable & ~frames] = SHORT
    ip_at = start + l3
    ip = IPV4.columns(data, ip_at, ("ip.version", "ip.len", "ip.flags", "ip.proto", "ip.src", "ip.dst"), readable)
    src, dst = be_uint(ip["ip.src"]), be_uint(ip["ip.dst"])  # 0 where not readable, and so is the group
    group = np.minimum(src, dst).astype(np.uint64) << np.uint64(32) | np.maximum(src, dst).astype(np.uint64)
    # from here on Ethernet frames only (the rest goes to the per-frame path whatever its headers say)
    keep = readable & eth & ~frames
    ver_ihl, total = ip["ip.version"].astype(np.int64), ip["ip.len"].astype(np.int64)
    ihl = (ver_ihl & 0x0F) * 4
    not_udp = keep & (ip["ip.proto"] != IP_UDP)
    skip[not_udp] = NOT_UDP
    keep &= ~not_udp
    # a finding (link_malformed, truncated_capture) or state (reassembly): the per-frame path's
    odd = keep & ((ver_ihl >> 4 != 4) | (ihl < IPV4.size) | (total < ihl) | (ip["ip.flags"] & IP_FRAGMENT != 0)
                  | (caplen - l3 < total))
    frames |= odd
    keep &= ~odd
    plen = total - ihl
    short = keep & (plen < UDP.size)
    skip[short] = SHORT
    keep &= ~short
    udp_at = ip_at + ihl
    udp = UDP.columns(data, udp_at, ("udp.sport", "udp.dport", "udp.len"), keep)
    ulen = udp["udp.len"].astype(np.int64)
    frames |= keep & ((ulen < UDP.size) | (ulen > plen))
    return Datagrams(skip, frames, group, src, dst, udp["udp.sport"], udp["udp.dport"], udp_at + UDP.size,
                     ulen - UDP.size)
