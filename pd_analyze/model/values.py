"""Value-name tables of the protocols below the PROFIdrive record.

Every table is data with the document it comes from (protocol.md section numbers in the comments).
The field registry refers to these tables; nothing else hard-codes their texts.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType


def _frozen(table: dict[int, str]) -> Mapping[int, str]:
    return MappingProxyType(table)


# DCE CL-RPC packet types (protocol.md 2.2; DCE 1.1 connectionless RPC).
RPC_PTYPE = _frozen({
    0: "request", 1: "ping", 2: "response", 3: "fault", 4: "working", 5: "nocall",
    6: "reject", 7: "ack", 8: "cl_cancel", 9: "fack", 10: "cancel_ack",
})
PTYPE_REQUEST, PTYPE_PING, PTYPE_RESPONSE, PTYPE_FAULT, PTYPE_WORKING = 0, 1, 2, 3, 4
PTYPE_NOCALL, PTYPE_REJECT, PTYPE_ACK, PTYPE_CANCEL, PTYPE_FACK, PTYPE_CANCEL_ACK = 5, 6, 7, 8, 9, 10

# Flags1 / Flags2 bits (protocol.md 2.2).
RPC_FLAGS1 = _frozen({
    0x02: "last fragment", 0x04: "fragment", 0x08: "no fack", 0x10: "maybe",
    0x20: "idempotent", 0x40: "broadcast",
})
FLAG1_LASTFRAG, FLAG1_FRAG, FLAG1_NOFACK, FLAG1_MAYBE, FLAG1_IDEMPOTENT, FLAG1_BROADCAST = (
    0x02, 0x04, 0x08, 0x10, 0x20, 0x40)
RPC_FLAGS2 = _frozen({0x01: "implementation", 0x02: "cancel pending"})

# NCA status codes of fault/reject bodies (protocol.md 2.2).
NCA_STATUS = _frozen({
    0x1C010002: "nca_op_rng_error (operation range error)",
    0x1C010003: "nca_unk_if (unknown interface)",
    0x1C010006: "nca_wrong_boot_time",
    0x1C010009: "nca_s_you_crashed",
    0x1C01000B: "nca_proto_error",
    0x1C010013: "nca_out_args_too_big",
    0x1C010014: "nca_server_too_busy",
    0x1C010017: "nca_unsupported_type",
    **{0x1C000000 + n: f"nca_s_fault_{n:#04x}" for n in range(0x01, 0x26)},
})

# PNIO RPC interfaces (protocol.md 1.4) and the endpoint mapper, which is ignored silently.
PNIO_INTERFACES = _frozen({
    0xDEA00001: "PNIO Device", 0xDEA00002: "PNIO Controller",
    0xDEA00003: "PNIO Supervisor", 0xDEA00004: "PNIO ParameterServer",
})
PNIO_UUID_PREFIX = bytes.fromhex("dea000")  # time_low but its last byte, which names the interface
PNIO_UUID_SUFFIX = bytes.fromhex("6c9711d1827100a02442df7d")  # time_mid, time_hi, clock_seq, node
PNIO_OBJECT_PREFIX = 0xDEA00000
EPM_INTERFACE = "e1af8308-5d1f-11c9-91a4-08002b14a0fa"

# PNIO CM opnums (protocol.md 1.4).
PNIO_OPNUM = _frozen({0: "Connect", 1: "Release", 2: "Read", 3: "Write", 4: "Control", 5: "ReadImplicit"})
OP_CONNECT, OP_RELEASE, OP_READ, OP_WRITE, OP_CONTROL, OP_READ_IMPLICIT = 0, 1, 2, 3, 4, 5
RECORD_SERVICES = frozenset({OP_READ, OP_WRITE, OP_READ_IMPLICIT})  # their stubs carry IOD blocks and records

# DREP (protocol.md 2.1).
DREP_INTEGER = _frozen({0: "big-endian", 1: "little-endian"})
DREP_CHARSET = _frozen({0: "ASCII", 1: "EBCDIC"})
DREP_FLOAT = _frozen({0: "IEEE", 1: "VAX", 2: "Cray", 3: "IBM"})

# IOD header block types (protocol.md 2.6).
BLOCK_TYPE = _frozen({
    0x0008: "IODWriteReqHeader", 0x8008: "IODWriteResHeader",
    0x0009: "IODReadReqHeader", 0x8009: "IODReadResHeader",
})
BT_WRITE_REQ, BT_WRITE_RES, BT_READ_REQ, BT_READ_RES = 0x0008, 0x8008, 0x0009, 0x8009

# Record indices that matter to the analyser (protocol.md 1.4).
INDEX_PD_LOCAL, INDEX_PD_GLOBAL, INDEX_PD_DPV1, INDEX_WRITE_MULTIPLE = 0xB02E, 0xB02F, 0x002F, 0xE040
PROFIDRIVE_INDICES = frozenset({INDEX_PD_LOCAL, INDEX_PD_GLOBAL, INDEX_PD_DPV1})
RECORD_INDEX = _frozen({
    INDEX_PD_LOCAL: "PROFIdrive parameter access, local",
    INDEX_PD_GLOBAL: "PROFIdrive parameter access, global",
    INDEX_PD_DPV1: "data record 47 (PROFIdrive over DPV1 index)",
    INDEX_WRITE_MULTIPLE: "Write-Multiple",
    0xAFF0: "I&M0", 0xF840: "I&M0 filter data", 0xF841: "PDRealData", 0x800C: "diagnosis, subslot",
})
API_PROFIDRIVE = 0x3A00
API = _frozen({0x0000: "device access point / default", API_PROFIDRIVE: "PROFIdrive"})

# PNIOStatus (protocol.md 4.6).
PNIO_ERROR_CODE = _frozen({
    0x00: "OK", 0x81: "PNIO", 0xCF: "RTA error", 0xDA: "AlarmAck", 0xDB: "IODConnectRes",
    0xDC: "IODReleaseRes", 0xDD: "IODControlRes", 0xDE: "IODReadRes (error read)",
    0xDF: "IODWriteRes (error write)",
})
PNIO_ERROR_DECODE = _frozen({0x00: "OK", 0x80: "PNIORW", 0x81: "PNIO"})
ERROR_CODE_READ, ERROR_CODE_WRITE = 0xDE, 0xDF  # the ErrorCode of a failed read and write record service
ERROR_DECODE_PNIORW, ERROR_DECODE_PNIO = 0x80, 0x81

# ErrorCode1 under ErrorDecode PNIORW: IEC 61158-6-10 names, with the PROFIdrive meaning where
# protocol.md 4.6 gives one (the Yaskawa V1000 SI-EP3/V manual's names in brackets where they differ).
PNIORW_CODE1 = _frozen({
    0xA0: "application: read error", 0xA1: "application: write error",
    0xA2: "application: module failure",
    **{c: "application: not specified" for c in range(0xA3, 0xA7)},
    0xA7: "application: busy [Yaskawa: reserved]",
    0xA8: "application: version conflict", 0xA9: "application: feature not supported",
    **{c: "application: user-specific" for c in range(0xAA, 0xB0)},
    0xB0: "access: invalid index (no parameter access point at this slot/subslot/index)",
    0xB1: ("access: write length error (parameter request above the record limit or shorter than its header, "
           "or read buffer too small)"),
    0xB2: "access: invalid slot/subslot",
    0xB3: "access: type conflict", 0xB4: "access: invalid area",
    0xB5: "access: state conflict (PROFIdrive: response not ready yet / request still processed)",
    0xB6: "access: access denied",
    0xB7: "access: invalid range (error in the parameter request header)",
    0xB8: "access: invalid parameter", 0xB9: "access: invalid type",
    0xBA: "access: backup [Yaskawa: user-specific]",
    **{c: "access: user-specific" for c in range(0xBB, 0xC0)},
    0xC0: "resource: read constraint conflict", 0xC1: "resource: write constraint conflict",
    0xC2: "resource: busy", 0xC3: "resource: unavailable",
    **{c: "resource: not specified" for c in range(0xC4, 0xC8)},
    **{c: "resource: user-specific" for c in range(0xC8, 0xD0)},
    **{c: "user-specific" for c in range(0xD0, 0x100)},
})
# ErrorCode1 under ErrorDecode PNIO, the entries relevant to record access.
PNIO_CODE1 = _frozen({
    0x08: "Read/Write Record: faulty record", 0x3D: "CMDEV", 0x40: "CMRPC",
    0xCA: "CMRDR (read record)", 0xCC: "CMWRR (write record)", 0xFD: "RTA_ERR_CLS_PROTOCOL",
    0xFF: "user-specific",
})
PNIORW_STATE_CONFLICT = 0xB5
# ErrorCode2 under ErrorDecode PNIO, by ErrorCode1: what failed (protocol.md 4.6).
PNIO_CODE2: Mapping[int, Mapping[int, str]] = _frozen({
    0x08: _frozen({0: "BlockType", 1: "BlockLength", 2: "BlockVersionHigh", 3: "BlockVersionLow", 5: "ARUUID",
                   6: "API", 7: "SlotNumber", 8: "SubslotNumber", 9: "Padding", 10: "Index",
                   11: "RecordDataLength", 12: "TargetARUUID"}),
    0x3D: _frozen({0: "state conflict", 1: "resources"}),
    0x40: _frozen({0: "ArgsLength invalid", 1: "unknown blocks", 2: "IOCR missing", 3: "wrong block count",
                   4: "no AR resources", 5: "AR UUID unknown", 6: "state conflict",
                   7: "out of provider/consumer/alarm resources", 8: "out of memory"}),
    0xCA: _frozen({0: "invalid state", 1: "signalled error"}),
    0xCC: _frozen({0: "invalid state", 1: "AR state not primary"}),
})
# The record service an ErrorCode names, as a status text starts ("DF80B100 write: ...").
PNIO_SERVICE = _frozen({ERROR_CODE_READ: "read", ERROR_CODE_WRITE: "write"})


def code1_name(decode: int, code1: int) -> str:
    """The name of ErrorCode1, which depends on ErrorDecode (PNIORW or PNIO); '' when none is known."""
    if decode == ERROR_DECODE_PNIORW:
        return PNIORW_CODE1.get(code1, "reserved" if code1 < 0xA0 else "")
    if decode == ERROR_DECODE_PNIO:
        return PNIO_CODE1.get(code1, "")
    return ""


def code2_name(decode: int, code1: int, code2: int) -> str:
    """The name of ErrorCode2: under PNIO the detail of ErrorCode1, under PNIORW user-specific."""
    if decode == ERROR_DECODE_PNIO:
        return PNIO_CODE2.get(code1, {}).get(code2, "")
    if decode == ERROR_DECODE_PNIORW and code2:
        return "user-specific"
    return ""


def status_text(status: str) -> str:
    """A status as the tables hold it (8 hex digits) in words: 'DF80C300 write: resource unavailable'.

    The PNIOStatus bytes ErrorCode, ErrorDecode, ErrorCode1, ErrorCode2 (protocol.md 2.5, 4.6), or the
    NCA status of an RPC fault or reject (protocol.md 2.2), which closes a transaction the same way. ''
    for an empty status."""
    if not status:
        return ""
    try:
        value = int(status, 16)
    except ValueError:
        return status
    if value in NCA_STATUS or value >> 16 in (0x1C00, 0x1C01):
        return f"{status} RPC fault/reject: {NCA_STATUS.get(value, 'NCA status')}"
    code, decode, code1, code2 = value >> 24, value >> 16 & 0xFF, value >> 8 & 0xFF, value & 0xFF
    if not value:
        return f"{status} OK"
    service = PNIO_SERVICE.get(code) or (PNIO_ERROR_CODE.get(code) if code else "") or f"ErrorCode {code:#04x}"
    if decode not in (ERROR_DECODE_PNIORW, ERROR_DECODE_PNIO):
        return f"{status} {service}: ErrorDecode {decode:#04x} unknown, ErrorCode1 {code1:#04x}, " \
               f"ErrorCode2 {code2:#04x}"
    first = code1_name(decode, code1).replace(": ", " ", 1) or f"ErrorCode1 {code1:#04x}"
    if decode == ERROR_DECODE_PNIO:
        first = f"PNIO {first}"
    second = code2_name(decode, code1, code2)
    if second and decode == ERROR_DECODE_PNIO:
        first += f": {second}"
    elif code2:
        first += f", ErrorCode2 {code2:#04x}" + (f" ({second})" if second else "")
    return f"{status} {service}: {first}"

# Link layer (protocol.md 1.3).
ETHERTYPE = _frozen({0x0800: "IPv4", 0x0806: "ARP", 0x8100: "802.1Q", 0x88A8: "802.1ad",
                     0x9100: "802.1Q (legacy QinQ)", 0x8892: "PROFINET RT", 0x86DD: "IPv6"})
ETHERTYPE_IPV4 = 0x0800
ETHERTYPE_IPV6 = 0x86DD  # not analysed; `dump -T fields` fills the UDP cells of a frame over it, as tshark
VLAN_TPIDS = frozenset({0x8100, 0x88A8, 0x9100})  # 802.1Q C-tag, 802.1ad S-tag, legacy QinQ
# The same as the two bytes on the wire, for byte comparisons where every frame passes
VLAN_TPID_BYTES = frozenset(tpid.to_bytes(2, "big") for tpid in VLAN_TPIDS)
IPV4_ETHERTYPE_BYTES = ETHERTYPE_IPV4.to_bytes(2, "big")
IP_ETHERTYPES = VLAN_TPID_BYTES | {IPV4_ETHERTYPE_BYTES}  # an Ethernet frame that may carry IPv4
IP_PROTO_UDP = 17
IP_PROTO = _frozen({1: "ICMP", 6: "TCP", IP_PROTO_UDP: "UDP"})
LINKTYPE = _frozen({1: "Ethernet", 101: "raw IP", 228: "raw IPv4", 113: "Linux SLL", 276: "Linux SLL2"})
LINKTYPE_ETHERNET, LINKTYPE_RAW, LINKTYPE_IPV4, LINKTYPE_SLL, LINKTYPE_SLL2 = 1, 101, 228, 113, 276
PNIO_CM_PORT = 34964


def name_of(table: Mapping[int, str] | None, value: object) -> str:
    """The table's name for a value, or '' when the table has none."""
    if table is None or not isinstance(value, int):
        return ""
    return table.get(value, "")


def flag_names(table: Mapping[int, str], value: int) -> str:
    """Names of the set bits of a flags byte, e.g. 'no fack, last fragment'."""
    return ", ".join(name for bit, name in sorted(table.items(), reverse=True) if value & bit)
