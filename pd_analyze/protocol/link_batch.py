"""The link, IPv4 and UDP layers of a batch of frames as columns: which frames carry one whole UDP datagram
of ordinary shape, where its payload lies, and which frames the per-frame decoder skips silently.

The same decisions as `link.LinkDecoder.datagram` (with `link.headers`) for Ethernet frames, taken for all
frames at once with the field offsets of the link Layouts. What the per-frame decoder answers with a
finding or with state is left to it (`frames`): IP fragments, an invalid IPv4 header or UDP length, a
frame captured shorter than its IP total length; so are other link types and more than MAX_TAGS VLAN tags.
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
    sport: np.ndarray  # uint16 (ordinary datagrams only; 0 otherwise)
    dport: np.ndarray  # uint16
    start: np.ndarray  # int64: offset of the UDP payload in the batch buffer (ordinary datagrams only)
    length: np.ndarray  # int64: its length, udp.len - 8

    @property
    def ordinary(self) -> np.ndarray:
        """Frames carrying one whole UDP datagram the columnar decode goes on with."""
        return (self.skip < 0) & ~self.frames


def datagrams(data: np.ndarray, linktype: np.ndarray, start: np.ndarray, caplen: np.ndarray) -> Datagrams:
    """The frames data[start[i] : start[i] + caplen[i]] (link types per frame) down to their UDP payloads."""
    n = len(start)
    start = start.astype(np.int64, copy=False)
    caplen = caplen.astype(np.int64, copy=False)
    out = Datagrams(np.full(n, -1, np.int8), linktype != LINKTYPE_ETHERNET, np.zeros(n, np.uint64),
                    np.zeros(n, np.uint32), np.zeros(n, np.uint32), np.zeros(n, np.uint16), np.zeros(n, np.uint16),
                    np.zeros(n, np.int64), np.zeros(n, np.int64))
    l3 = _ethernet(data, linktype, start, caplen, out)
    _other_links(data, linktype, start, caplen, l3)
    _ipv4_udp(data, linktype, start, caplen, l3, out)
    return out


def _ethernet(data: np.ndarray, linktype: np.ndarray, start: np.ndarray, caplen: np.ndarray,
              out: Datagrams) -> np.ndarray:
    """Offset of the IPv4 header in each Ethernet frame (after its VLAN tags), -1 where there is none."""
    l3 = np.full(len(start), -1, np.int64)
    eth = linktype == LINKTYPE_ETHERNET
    out.skip[eth & (caplen < ETH.size)] = NOT_IPV4  # no whole EtherType: not IPv4 (data[12:14] compares short)
    e = np.flatnonzero(eth & (caplen >= ETH.size))
    etype = ETH.columns(data, start[e], ("eth.type",))["eth.type"].astype(np.int32)
    off = np.full(len(e), ETH.size, np.int64)
    cap = caplen[e]
    # link.headers: while the EtherType is a TPID and the tag's TCI is present, the next EtherType follows it
    walk = np.flatnonzero(np.isin(etype, _TPIDS) & (cap >= off + 2))
    for _ in range(MAX_TAGS):
        if len(walk) == 0:
            break
        whole = cap[walk] >= off[walk] + VLAN.size
        inner = np.full(len(walk), -1, np.int32)  # a cut EtherType is none
        at = walk[whole]
        inner[whole] = VLAN.columns(data, start[e[at]] + off[at], ("vlan.etype",))["vlan.etype"]
        etype[walk] = inner
        off[walk] += VLAN.size
        walk = walk[np.isin(inner, _TPIDS) & (cap[walk] >= off[walk] + 2)]
    out.frames[e[walk]] = True  # still tagged after MAX_TAGS tags
    ipv4 = etype == ETHERTYPE_IPV4
    ipv4[walk] = False
    l3[e[ipv4]] = off[ipv4]
    not_ip = ~ipv4
    not_ip[walk] = False
    out.skip[e[not_ip]] = NOT_IPV4
    return l3


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
              out: Datagrams) -> None:
    """LinkDecoder.datagram and _udp from the IPv4 header on, in their order of decisions."""
    has_l3 = l3 >= 0
    readable = has_l3 & (caplen >= l3 + IPV4.size)
    eth = linktype == LINKTYPE_ETHERNET
    out.skip[eth & has_l3 & ~readable & ~out.frames] = SHORT
    r = np.flatnonzero(readable)
    ip = IPV4.columns(data, start[r] + l3[r], ("ip.version", "ip.len", "ip.flags", "ip.proto", "ip.src", "ip.dst"))
    src, dst = be_uint(ip["ip.src"]), be_uint(ip["ip.dst"])
    out.src[r], out.dst[r] = src, dst
    lo, hi = np.minimum(src, dst).astype(np.uint64), np.maximum(src, dst).astype(np.uint64)
    out.group[r] = lo << np.uint64(32) | hi
    # from here on Ethernet frames only (the rest goes to the per-frame path whatever its headers say)
    keep = eth[r] & ~out.frames[r]
    ver_ihl, total = ip["ip.version"].astype(np.int64), ip["ip.len"].astype(np.int64)
    ihl = (ver_ihl & 0x0F) * 4
    not_udp = keep & (ip["ip.proto"] != IP_UDP)
    out.skip[r[not_udp]] = NOT_UDP
    keep &= ~not_udp
    # a finding (link_malformed, truncated_capture) or state (reassembly): the per-frame path's
    cap = caplen[r] - l3[r]
    odd = ((ver_ihl >> 4 != 4) | (ihl < IPV4.size) | (total < ihl) | (ip["ip.flags"] & IP_FRAGMENT != 0)
           | (cap < total))
    out.frames[r[keep & odd]] = True
    keep &= ~odd
    plen = total - ihl
    short = keep & (plen < UDP.size)
    out.skip[r[short]] = SHORT
    keep &= ~short
    u = r[keep]
    udp_at = start[u] + l3[u] + ihl[keep]
    udp = UDP.columns(data, udp_at, ("udp.sport", "udp.dport", "udp.len"))
    ulen = udp["udp.len"].astype(np.int64)
    bad = (ulen < UDP.size) | (ulen > plen[keep])
    out.frames[u[bad]] = True
    good = ~bad
    g = u[good]
    out.sport[g], out.dport[g] = udp["udp.sport"][good], udp["udp.dport"][good]
    out.start[g] = udp_at[good] + UDP.size
    out.length[g] = ulen[good] - UDP.size
