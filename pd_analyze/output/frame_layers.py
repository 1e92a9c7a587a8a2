"""The fields of a frame the dissector passes by (not PNIO RPC): its link header, IPv4 and UDP headers and, where
the UDP payload is a connectionless DCE/RPC header, that header. `dump -T fields` fills their cells from these
as tshark fills the cells of the layers it decodes (an endpoint-mapper call's `dcerpc.pkt_type`, a UDP frame's
`udp.srcport`); the layers above them are not decoded, as the analyser does not know them.

Read only for the frames `-T fields` or `-Y` look at, one header walk each; a frame cut inside its IPv4 or UDP
header gives its Ethernet header alone, and bad bytes never an exception.
"""

from __future__ import annotations

import struct

from pd_analyze.model.layout import Field
from pd_analyze.model.values import ETHERTYPE_IPV6, IP_PROTO_UDP, LINKTYPE_ETHERNET
from pd_analyze.protocol import link, rpc

_IPV6_HEADER = 40


def fields_of(linktype: int, data: bytes) -> list[Field]:
    """Every header field of the frame, in frame order (empty for a link type the analyser does not read)."""
    try:
        chain = link.headers(linktype, data)
        ethernet = _ethernet(data, chain.tags) if linktype == LINKTYPE_ETHERNET else []
    except (struct.error, IndexError, ValueError):
        return []
    if chain.l3 < 0:  # PN-RT, ARP, LLDP, IPv6 ...
        return ethernet + _udp_over_ipv6(data, 14 + 4 * len(chain.tags)) if ethernet else ethernet
    out: list[Field] = []
    try:
        ip = link.IPV4.unpack(data, chain.l3)
        ihl, proto, flags = (ip[0] & 0x0F) * 4, ip[6], ip[4]
        udp_at = chain.l3 + ihl
        # a fragment (more fragments, or an offset) shows its IPv4 header alone, as tshark's does
        is_udp = proto == IP_PROTO_UDP and not flags & 0x3FFF and len(data) >= udp_at + 8
        sport, dport = struct.unpack_from(">HH", data, udp_at) if is_udp else (0, 0)
        payload = data[udp_at + 8:] if is_udp else b""
        dgram = link.Datagram(ip[8], ip[9], sport, dport, payload, udp_at + 8, chain.l3, False, ())
        layers = link.annotate(linktype, data, dgram)
        for _title, fields in layers if is_udp else layers[:-1]:  # (the last: UDP)
            out += fields
        if is_udp and rpc.plausible(payload):
            hdr = rpc.header(payload)
            layout = rpc.HEADER_LE if hdr.little else rpc.HEADER_BE
            out += layout.annotate(payload, 0, hdr.values, udp_at + 8)
    except (struct.error, IndexError, ValueError):  # cut inside a header
        return ethernet
    return out


def _udp_over_ipv6(data: bytes, at: int) -> list[Field]:
    """The UDP header behind an IPv6 header with no extension header (LLMNR, DHCPv6 beside PROFINET)."""
    if data[at - 2:at] != ETHERTYPE_IPV6.to_bytes(2, "big") or data[at + 6:at + 7] != bytes([IP_PROTO_UDP]):
        return []
    try:
        return link.UDP.annotate(data, at + _IPV6_HEADER, link.UDP.unpack(data, at + _IPV6_HEADER))
    except (struct.error, IndexError, ValueError):
        return []


def _ethernet(data: bytes, tags: tuple[int, ...]) -> list[Field]:
    out = link.ETH.annotate(data, 0, link.ETH.unpack(data))
    for tag in tags:
        out += link.VLAN.annotate(data, tag, link.VLAN.unpack(data, tag))
    return out
