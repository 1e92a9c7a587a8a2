"""The field registry: one stable dotted name per field, its type, value table and description.

The dump, the JSON output, the findings, the DataFrame columns and `pd-analyze fields` all read this
module; `tshark` names the tshark 4.0 field it is compared with (protocol.md 8.2).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from types import MappingProxyType

from pd_analyze.model import pd_values as pt
from pd_analyze.model import values as t
from pd_analyze.model.verdicts import VERDICTS

# Field types: how a value is held and shown.
UINT, HEX, INT, BYTES, UUID, IPV4, FLOAT, TIME, TEXT, FLAGS, FRAMEREF, LIST = (
    "uint", "hex", "int", "bytes", "uuid", "ipv4", "float", "time", "text", "flags", "frame", "list")


@dataclass(frozen=True, slots=True)
class FieldDef:
    name: str
    type: str
    description: str
    values: Mapping[int, str] | None = None
    tshark: str | None = None
    flags: Mapping[int, str] | None = None  # bit names for FLAGS fields
    # how tshark 4.0 prints the field's value in `-T fields` where it differs from what the type says
    # (its own base: SHOWN_HEX, SHOWN_DEC, SHOWN_DATE, SHOWN_RELTIME); "" as the type says
    tshark_shown: str = ""


def _defs(*defs: FieldDef) -> dict[str, FieldDef]:
    return {d.name: d for d in defs}


# tshark's bases where they differ from the registry type (seen in `tshark -T fields` output, 4.0.17)
SHOWN_HEX, SHOWN_DEC, SHOWN_DATE, SHOWN_RELTIME = "hex", "dec", "date", "reltime"
F = FieldDef
_PD = "pn_io.profidrive.parameter"
_FIELDS = _defs(
    # capture / frame
    F("frame.no", UINT, "Frame number, 1-based as in Wireshark", tshark="frame.number"),
    F("frame.ts", TIME, "Capture timestamp, seconds since the epoch", tshark="frame.time_epoch"),
    F("frame.iface", UINT, "pcapng interface id"),
    F("frame.linktype", UINT, "Link-layer type of the frame's interface", t.LINKTYPE),
    F("frame.caplen", UINT, "Bytes captured"),
    # link layer
    F("eth.dst", BYTES, "Destination MAC address"),
    F("eth.src", BYTES, "Source MAC address"),
    F("eth.type", HEX, "EtherType", t.ETHERTYPE),
    F("eth.vlan_ids", LIST, "VLAN IDs of all 802.1Q/802.1ad tags, outer first", tshark="vlan.id"),
    F("vlan.tpid", HEX, "Tag protocol identifier", t.ETHERTYPE),
    F("vlan.pcp", UINT, "Priority code point"),
    F("vlan.dei", UINT, "Drop eligible indicator"),
    F("vlan.id", UINT, "VLAN identifier"),
    F("vlan.etype", HEX, "EtherType after the tag", t.ETHERTYPE),
    F("sll.pkttype", UINT, "Linux cooked capture packet type"),
    F("sll.hatype", UINT, "Linux cooked capture ARPHRD type"),
    F("sll.halen", UINT, "Link-layer address length"),
    F("sll.addr", BYTES, "Link-layer address"),
    F("sll.protocol", HEX, "Protocol (EtherType)", t.ETHERTYPE),
    F("sll.ifindex", UINT, "Interface index (SLL2)"),
    F("sll.reserved", HEX, "Reserved (SLL2)"),
    # IPv4 / UDP
    F("ip.version", UINT, "IP version"),
    F("ip.ihl", UINT, "Header length in 32-bit words"),
    F("ip.tos", HEX, "Type of service / DSCP+ECN"),
    F("ip.len", UINT, "Total length"),
    F("ip.id", HEX, "Identification", tshark="ip.id"),
    F("ip.flags", HEX, "Flags (0x2 DF, 0x1 MF) and fragment offset word"),
    F("ip.mf", UINT, "More fragments", tshark="ip.flags.mf"),
    F("ip.frag_offset", UINT, "Fragment offset in 8-byte units (wire value)", tshark="ip.frag_offset"),
    F("ip.ttl", UINT, "Time to live"),
    F("ip.proto", UINT, "Protocol", t.IP_PROTO),
    F("ip.checksum", HEX, "Header checksum (not verified)"),
    F("ip.src", IPV4, "Source address", tshark="ip.src"),
    F("ip.dst", IPV4, "Destination address", tshark="ip.dst"),
    F("ip.options", BYTES, "IP options"),
    F("ip.reassembled_from", LIST, "Frames whose IP fragments make this datagram"),
    F("udp.sport", UINT, "Source port", tshark="udp.srcport"),
    F("udp.dport", UINT, "Destination port", tshark="udp.dstport"),
    F("udp.len", UINT, "UDP length"),
    F("udp.checksum", HEX, "UDP checksum (not verified)"),
    # DCE/RPC CL header (protocol.md 2.1)
    F("rpc.ver", UINT, "RPC version (4 = connectionless)", tshark="dcerpc.ver"),
    F("rpc.ptype", UINT, "Packet type", t.RPC_PTYPE, tshark="dcerpc.pkt_type"),
    F("rpc.flags1", FLAGS, "Flags1", tshark="dcerpc.dg_flags1", flags=t.RPC_FLAGS1),
    F("rpc.flags2", FLAGS, "Flags2", tshark="dcerpc.dg_flags2", flags=t.RPC_FLAGS2),
    F("rpc.drep", BYTES, "Data representation: integer order/charset, float, reserved",
      tshark="dcerpc.drep"),
    F("rpc.serial_hi", UINT, "Serial number, high byte", tshark="dcerpc.dg_serial_hi", tshark_shown=SHOWN_HEX),
    F("rpc.object", UUID, "Object UUID (dea00000-...-IIIIDDDDVVVV for PNIO)", tshark="dcerpc.obj_id"),
    F("rpc.interface", UUID, "Interface UUID", tshark="dcerpc.dg_if_id"),
    F("rpc.activity", UUID, "Activity UUID (client's; same in request and response)",
      tshark="dcerpc.dg_act_id"),
    F("rpc.boot_time", UINT, "Server boot time", tshark="dcerpc.dg_server_boot",
      tshark_shown=SHOWN_DATE),
    F("rpc.if_version", UINT, "Interface version", tshark="dcerpc.dg_if_ver"),
    F("rpc.seq", UINT, "Sequence number", tshark="dcerpc.dg_seqnum"),
    F("rpc.opnum", UINT, "Operation number", t.PNIO_OPNUM, tshark="dcerpc.opnum"),
    F("rpc.ihint", HEX, "Interface hint (0xFFFF none)", tshark="dcerpc.dg_ihint"),
    F("rpc.ahint", HEX, "Activity hint (0xFFFF none)", tshark="dcerpc.dg_ahint"),
    F("rpc.frag_len", UINT, "Fragment body length", tshark="dcerpc.dg_frag_len"),
    F("rpc.frag_num", UINT, "Fragment number", tshark="dcerpc.dg_frag_num"),
    F("rpc.auth_proto", UINT, "Authentication protocol (0 none)", tshark="dcerpc.dg_auth_proto"),
    F("rpc.serial_lo", UINT, "Serial number, low byte", tshark="dcerpc.dg_serial_lo", tshark_shown=SHOWN_HEX),
    F("rpc.fault_status", HEX, "NCA status of a fault/reject", t.NCA_STATUS, tshark="dcerpc.dg_status"),
    F("rpc.body", BYTES, "PDU body not decoded further"),
    F("rpc.request_frame", FRAMEREF, "Frame of the request this PDU answers", tshark="dcerpc.request_in"),
    F("rpc.response_frame", FRAMEREF, "Frame of the response to this request", tshark="dcerpc.response_in"),
    F("rpc.rtt", FLOAT, "Seconds from request to response", tshark="dcerpc.time", tshark_shown=SHOWN_RELTIME),
    F("rpc.reassembled_in", FRAMEREF, "Frame in which this fragment's PDU is reassembled",
      tshark="dcerpc.reassembled_in"),
    F("rpc.fragments", LIST, "Frames of the fragments of a reassembled body"),
    F("rpc.retransmissions", UINT, "Identical copies of this request seen so far"),
    # NDR args header (protocol.md 2.5)
    F("ndr.args_max", UINT, "ArgsMaximum: largest response args the client accepts", tshark="pn_io.args_max"),
    F("ndr.status.code", HEX, "PNIOStatus ErrorCode", t.PNIO_ERROR_CODE, tshark="pn_io.error_code"),
    F("ndr.status.decode", HEX, "PNIOStatus ErrorDecode", t.PNIO_ERROR_DECODE, tshark="pn_io.error_decode"),
    F("ndr.status.code1", HEX, "PNIOStatus ErrorCode1", tshark="pn_io.error_code1", tshark_shown=SHOWN_DEC),
    F("ndr.status.code2", HEX, "PNIOStatus ErrorCode2", tshark="pn_io.error_code2", tshark_shown=SHOWN_DEC),
    F("ndr.args_len", UINT, "ArgsLength = stub length - 20", tshark="pn_io.args_len"),
    F("ndr.max_count", UINT, "Array MaximumCount", tshark="pn_io.array_max_count"),
    F("ndr.offset", UINT, "Array Offset", tshark="pn_io.array_offset"),
    F("ndr.actual_count", UINT, "Array ActualCount", tshark="pn_io.array_act_count"),
    F("ndr.blocks", BYTES, "Blocks not decoded (Connect/Release/Control)"),
    # IOD header blocks (protocol.md 2.6)
    F("iod.block_type", HEX, "BlockType", t.BLOCK_TYPE, tshark="pn_io.block_type"),
    F("iod.block_length", UINT, "BlockLength (60)", tshark="pn_io.block_length"),
    F("iod.version_high", UINT, "BlockVersionHigh", tshark="pn_io.block_version_high"),
    F("iod.version_low", UINT, "BlockVersionLow", tshark="pn_io.block_version_low"),
    F("iod.seq", UINT, "SeqNumber", tshark="pn_io.seq_number"),
    F("iod.ar_uuid", UUID, "ARUUID", tshark="pn_io.ar_uuid"),
    F("iod.api", HEX, "API", t.API, tshark="pn_io.api"),
    F("iod.slot", UINT, "SlotNumber", tshark="pn_io.slot_nr", tshark_shown=SHOWN_HEX),
    F("iod.subslot", HEX, "SubslotNumber", tshark="pn_io.subslot_nr"),
    F("iod.pad", HEX, "Padding", tshark="pn.padding"),
    F("iod.index", HEX, "Index", t.RECORD_INDEX, tshark="pn_io.index"),
    F("iod.record_len", UINT, "RecordDataLength", tshark="pn_io.record_data_length"),
    F("iod.add_val1", UINT, "AdditionalValue1", tshark="pn_io.add_val1"),
    F("iod.add_val2", UINT, "AdditionalValue2", tshark="pn_io.add_val2"),
    F("iod.status.code", HEX, "PNIOStatus ErrorCode (block)", t.PNIO_ERROR_CODE, tshark="pn_io.error_code"),
    F("iod.status.decode", HEX, "PNIOStatus ErrorDecode (block)", t.PNIO_ERROR_DECODE,
      tshark="pn_io.error_decode"),
    F("iod.status.code1", HEX, "PNIOStatus ErrorCode1 (block)", tshark="pn_io.error_code1",
      tshark_shown=SHOWN_DEC),
    F("iod.status.code2", HEX, "PNIOStatus ErrorCode2 (block)", tshark="pn_io.error_code2",
      tshark_shown=SHOWN_DEC),
    F("iod.target_ar_uuid", UUID, "TargetARUUID (implicit read)", tshark="pn_io.target_ar_uuid"),
    F("iod.rw_pad", BYTES, "RWPadding", tshark="pn.padding"),
    F("iod.multi_pad", BYTES, "Write-Multiple alignment padding"),
    F("record.data", BYTES, "Record data (not decoded)"),
    # PROFIdrive parameter request / response (protocol.md 3; tshark prefix pn_io.profidrive.parameter)
    F("pd.ref", UINT, "Request Reference (response: mirrored)", tshark=f"{_PD}.request_reference",
      tshark_shown=SHOWN_HEX),
    F("pd.req_id", HEX, "Request ID", pt.REQUEST_ID, tshark=f"{_PD}.request_id"),
    F("pd.resp_id", HEX, "Response ID", pt.RESPONSE_ID, tshark=f"{_PD}.response_id"),
    F("pd.do", UINT, "DO-ID (axis / drive object)", tshark=f"{_PD}.do"),
    F("pd.n_params", UINT, "No. of parameters", tshark=f"{_PD}.no_of_parameters"),
    F("pd.addr[i].attr", HEX, "Attribute", pt.ATTRIBUTE, tshark=f"{_PD}.attribute"),
    F("pd.addr[i].n_elems", UINT, "No. of elements (0 = single value)", tshark=f"{_PD}.no_of_elems"),
    F("pd.addr[i].pnu", UINT, "Parameter number (PNU)", tshark=f"{_PD}.number"),
    F("pd.addr[i].subindex", UINT, "Subindex (first array element)", tshark=f"{_PD}.index"),
    F("pd.val[i].format", HEX, "Format (data type)", pt.FORMAT_NAME, tshark=f"{_PD}.format"),
    F("pd.val[i].n_values", UINT, "No. of values (strings: characters)", tshark=f"{_PD}.no_of_values"),
    F("pd.val[i].value[j]", TEXT, "One value of a numeric format, decoded by its format",
      tshark=f"{_PD}.value_b|{_PD}.value_w|{_PD}.value_dw|{_PD}.value_float", tshark_shown=SHOWN_HEX),
    # a name of its own, not pd.val[i].value: without its indexes that name collected the numbers too
    F("pd.val[i].string", TEXT, "A VisibleString, OctetString or UnicodeString value: No. of values characters "
      "or bytes as one value", tshark=f"{_PD}.value_str"),
    F("pd.val[i].pad", HEX, "Word-alignment pad byte after an odd value list"),
    F("pd.val[i].error", HEX, "Error number", MappingProxyType({k: v.text for k, v in pt.ERRORS.items()}),
      tshark=f"{_PD}.error_num"),
    F("pd.val[i].error_subindex", UINT, "Subindex of the first faulty element", tshark=f"{_PD}.error_subindex",
      tshark_shown=SHOWN_HEX),
    F("pd.val[i].desc.identifier", HEX, "Description: identifier (data type and flags)"),
    F("pd.val[i].desc.elements", UINT, "Description: number of array elements / string length"),
    F("pd.val[i].desc.standardisation_factor", FLOAT, "Description: standardisation factor"),
    F("pd.val[i].desc.variable_attribute", HEX, "Description: variable attribute"),
    F("pd.val[i].desc.reserved1", HEX, "Description: reserved"),
    F("pd.val[i].desc.name", TEXT, "Description: name (16 characters)"),
    F("pd.val[i].desc.low_limit", HEX, "Description: low limit"),
    F("pd.val[i].desc.high_limit", HEX, "Description: high limit"),
    F("pd.val[i].desc.reserved2", HEX, "Description: reserved"),
    F("pd.val[i].desc.id_extension", HEX, "Description: ID extension"),
    F("pd.val[i].desc.reference_parameter", UINT, "Description: reference parameter"),
    F("pd.val[i].desc.normalisation", HEX, "Description: normalisation"),
    F("dpv1.function", HEX, "PROFIBUS DP-V1 function number", MappingProxyType({0x5E: "read", 0x5F: "write"})),
    F("dpv1.slot", UINT, "DP-V1 slot"),
    F("dpv1.index", UINT, "DP-V1 index (47 = PROFIdrive parameter channel)"),
    F("dpv1.length", UINT, "DP-V1 data length"),
    F("pd.request_frame", FRAMEREF, "Frame of the parameter request (Write) this response answers"),
    F("pd.echo", BYTES, "Parameter address echoed before the first block (AKD manual layout)"),
    F("pd.trailing", BYTES, "Bytes after the parsed parameter request/response"),
    F("pd.cut", BYTES, "The bytes of a field the record ends inside (decoded as far as the bytes go)"),
    F("record.trailing", BYTES, "Bytes after the record that RecordDataLength does not cover"),
    # what the analysis says of a frame (display filters, `-T fields`): of the transactions it belongs to
    # and of the findings at it, as the report's tables hold them
    F("txn.id", UINT, "Transaction the frame belongs to (the tables' txn)"),
    F("txn.verdict", TEXT, f"Verdict of that transaction: {', '.join(VERDICTS)}"),
    F("txn.b5_retries", UINT, "Reads of that transaction answered B5 (state conflict: not ready yet)"),
    F("finding.rule", TEXT, "Rule id of a finding at the frame (protocol.md 6), e.g. H5"),
    F("finding.severity", TEXT, "Severity of a finding at the frame: error, warning or info"),
)
FIELDS: Mapping[str, FieldDef] = MappingProxyType(_FIELDS)
ANALYSIS_FIELDS = frozenset({"txn.id", "txn.verdict", "txn.b5_retries", "finding.rule", "finding.severity"})

# tshark names one registry field splits by the value's width in bytes (0: a float value)
TSHARK_VALUE_WIDTH: Mapping[str, int] = MappingProxyType({
    f"{_PD}.value_b": 1, f"{_PD}.value_w": 2, f"{_PD}.value_dw": 4, f"{_PD}.value_float": 0})


_INDEX = re.compile(r"\[\d+\]")


def template(name: str) -> str:
    """The registry name of a concrete field name: pd.val[3].value[1] -> pd.val[i].value[j]."""
    if "[" not in name:
        return name
    letters = iter("ij")
    return _INDEX.sub(lambda _m: f"[{next(letters, 'k')}]", name)


@lru_cache(maxsize=65_536)  # concrete names repeat frame after frame in a dump
def field(name: str) -> FieldDef:
    """The registry entry of a field (concrete indexed names allowed); KeyError if unknown."""
    found = FIELDS.get(name)
    return found if found is not None else FIELDS[template(name)]


def value_text(name: str, value: int) -> str:
    """An integer of a field as the registry presents it everywhere (the dump's field and the findings
    about it alike): hex for IDs, codes and formats (0x28), decimal for counts, numbers and lengths (40)."""
    try:
        hexa = field(name).type in (HEX, FLAGS)
    except KeyError:
        hexa = False
    return f"0x{value:02x}" if hexa else str(value)
