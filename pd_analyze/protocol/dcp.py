"""PN-DCP Identify and Get responses: the station name a device announces with its IP address, so the parameter
state can name a drive as its engineering tool does (`params`: "192.168.1.21 (pump-1)").

Layout (IEC 61158-6-10, PN-DCP; the same as Wireshark's PN-DCP dissector reads it): after EtherType 0x8892 (behind
any VLAN tags) a 2-byte FrameID (0xFEFF Identify response, 0xFEFD Get/Set), ServiceID (1: 3 Get, 5 Identify),
ServiceType (1: 1 response success), Xid (4), reserved (2), DCPDataLength (2), then blocks: Option (1),
Suboption (1), DCPBlockLength (2), in a response BlockInfo (2) before the value; a block of odd length is padded
to an even one. IP parameter: option 1 suboption 2 (address, mask, gateway); NameOfStation: option 2 suboption 2.

Only frames that carry both are used: a name without an address names no drive of the tables. Nothing here
raises on a short or odd frame: it is simply no announcement.
"""

from __future__ import annotations

import struct

from pd_analyze.model.values import VLAN_TPID_BYTES

PN_RT = b"\x88\x92"
FRAME_IDS = frozenset({0xFEFF, 0xFEFD})  # Identify response, Get/Set
SERVICES = frozenset({3, 5})  # Get, Identify
RESPONSE_SUCCESS = 1
IP_OPTION, NAME_OPTION = (1, 2), (2, 2)
_HEADER = struct.Struct(">HBBIHH")  # FrameID, ServiceID, ServiceType, Xid, reserved, DCPDataLength


def _payload(data: bytes) -> bytes | None:
    """The PN-RT payload of an Ethernet frame (after its VLAN tags), None when it is no PN-RT frame."""
    etype, off = data[12:14], 14
    while etype in VLAN_TPID_BYTES and len(data) >= off + 4:
        etype, off = data[off + 2:off + 4], off + 4
    return data[off:] if etype == PN_RT else None


def station(data: bytes) -> tuple[str, str] | None:
    """(IP address, station name) of an Ethernet frame that is a successful DCP Identify or Get response
    carrying both; None for every other frame."""
    p = _payload(data)
    if p is None or len(p) < _HEADER.size:
        return None
    frame_id, service, kind, _, _, length = _HEADER.unpack_from(p)
    if frame_id not in FRAME_IDS or service not in SERVICES or kind != RESPONSE_SUCCESS:
        return None
    at, end = _HEADER.size, min(len(p), _HEADER.size + length)
    ip = name = None
    while at + 4 <= end:
        option, size = (p[at], p[at + 1]), int.from_bytes(p[at + 2:at + 4], "big")
        value = p[at + 6:at + 4 + size] if size >= 2 and at + 4 + size <= end else None
        if value is not None and option == IP_OPTION and len(value) >= 4:
            ip = ".".join(str(b) for b in value[:4])
        elif value is not None and option == NAME_OPTION and value:  # (its length is the block's: 16 bit at most)
            name = value.decode("ascii", "replace")
        at += 4 + size + (size & 1)
    return (ip, name) if ip and name and ip != "0.0.0.0" else None
