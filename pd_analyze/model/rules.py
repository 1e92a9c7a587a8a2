"""The rule registry and the Finding record.

Every check the analyser makes is one Rule here: its id from protocol.md section 6 (or a named
finding of sections 1-3), severity, group (Wireshark's expert-info groups) and source. A rule id
with two severities (R3, H5, H9, ...) has one entry per variant, told apart by `name`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

ERROR, WARNING, INFO = "error", "warning", "info"
SEVERITY_RANK = MappingProxyType({INFO: 1, WARNING: 2, ERROR: 3})
SEVERITIES = tuple(SEVERITY_RANK)  # least severe first: the categories of the `severity` column

# Expert-info groups, as Wireshark uses them.
MALFORMED, PROTOCOL, SEQUENCE, COMMENT = "malformed", "protocol", "sequence", "comment"

IEC = "IEC 61158-6-10"
DCE = "DCE 1.1 CL-RPC"
PCAP = "pcap/pcapng file format"
YASKAWA_EP3 = "Yaskawa SI-EP3 PROFINET Technical Manual SIEP C730600 89E, p. 38"
AKD = "Kollmorgen AKD PROFINET manual, parameter request/response tables"
PD = "PROFIdrive profile V4.2, Base Mode Parameter Access"
EXPECT = "the intended parameter set (pd-analyze audit --expect)"


@dataclass(frozen=True, slots=True)
class Rule:
    id: str
    name: str
    severity: str
    group: str
    source: str
    summary: str


@dataclass(frozen=True, slots=True)
class Finding:
    rule: str
    name: str
    severity: str
    frame: int
    field: str
    value: str
    expected: str
    source: str
    message: str

    def as_dict(self) -> dict[str, object]:
        return {"rule": self.rule, "name": self.name, "severity": self.severity, "frame": self.frame,
                "field": self.field, "value": self.value, "expected": self.expected,
                "source": self.source, "message": self.message}


R = Rule
# In the order the per-frame analysis applies them, layer after layer: the findings of one frame are listed
# in this order (analysis.schema.RULE_RANK), whichever part of the analysis found them first.
_RULES = (
    # capture and link layer (protocol.md 1.3)
    R("L1", "truncated_capture", INFO, MALFORMED, PCAP, "frame captured shorter than its IP total length"),
    R("L2", "ip_frag_overlap", WARNING, MALFORMED, "RFC 791", "IP fragments overlap with different bytes"),
    R("L2", "ip_frag_incomplete", INFO, SEQUENCE, "RFC 791", "IP datagram incomplete at end of capture"),
    R("L2", "ip_frag_evicted", WARNING, SEQUENCE, "RFC 791", "IP reassembly table full: oldest dropped"),
    R("L3", "link_malformed", WARNING, MALFORMED, "IEEE 802.3 / RFC 791 / RFC 768",
      "link, IP or UDP header inconsistent"),
    # the DCE/RPC header, then a PDU cut short (protocol.md 1.4, 2.1, 6.1)
    R("R2", "rpc_extra_bytes", WARNING, MALFORMED, DCE, "bytes after the fragment body"),
    R("R5", "rpc_header_values", WARNING, PROTOCOL, DCE,
      "interface version, authentication or maybe/broadcast flags unexpected"),
    R("R9", "auth_present", WARNING, PROTOCOL, DCE, "authenticated PDU: body not decoded"),
    R("R6", "rpc_float_repr", WARNING, PROTOCOL, DCE, "DREP float representation not IEEE"),
    R("R3", "rpc_serial", INFO, PROTOCOL, DCE, "serial number differs from fragment number"),
    R("R1", "rpc_truncated", ERROR, MALFORMED, DCE, "fragment length exceeds the bytes present"),
    R("L1", "truncated_capture_pnio", ERROR, MALFORMED, PCAP, "capture cut inside a PNIO RPC PDU"),
    # CL fragments (protocol.md 2.3)
    R("R3", "rpc_frag_conflict", WARNING, MALFORMED, DCE, "same fragment number, different bytes"),
    R("R3", "rpc_frag_inconsistent", ERROR, MALFORMED, DCE, "fragment beyond the last, or a second last"),
    R("R3", "rpc_frag_evicted", WARNING, SEQUENCE, DCE, "fragment table full: oldest set dropped"),
    R("R3", "rpc_frag_missing", ERROR, MALFORMED, DCE, "fragment set incomplete"),
    # calls (protocol.md 2.2, 2.4)
    R("R7", "rpc_retransmission", INFO, SEQUENCE, DCE, "request retransmitted"),
    R("R7", "rpc_key_reused", WARNING, SEQUENCE, DCE, "call key reused with a different body"),
    R("R7", "rpc_call_evicted", WARNING, SEQUENCE, DCE, "open-call table full: oldest call dropped"),
    R("R8", "pnio_interface", INFO, PROTOCOL, IEC, "Read/Write on a PNIO interface other than Device"),
    R("R8", "pnio_object", INFO, PROTOCOL, IEC, "object UUID not of the dea00000 form"),
    R("R7", "orphan_response", INFO, SEQUENCE, DCE, "response without an open request"),
    R("R4", "rpc_response_mismatch", WARNING, PROTOCOL, DCE, "response interface/opnum differ from the request"),
    R("R4", "rpc_addresses_not_swapped", WARNING, PROTOCOL, DCE, "response IP addresses not swapped"),
    R("R7", "rpc_fault", WARNING, PROTOCOL, DCE, "call answered with fault/reject"),
    R("R7", "rpc_nocall", WARNING, SEQUENCE, DCE, "server has no record of the call"),
    R("R7", "rpc_cancel", INFO, SEQUENCE, DCE, "client cancelled the call"),
    R("R7", "rpc_unanswered", WARNING, SEQUENCE, DCE, "request not answered within rpc_timeout"),
    # the stub: NDR args (protocol.md 2.5, 6.1)
    R("N0", "ndr_truncated", ERROR, MALFORMED, IEC, "stub shorter than the 20-byte NDR header"),
    R("H0", "iod_truncated", ERROR, MALFORMED, IEC, "IOD header block cut short"),
    R("H5", "record_truncated", ERROR, MALFORMED, IEC, "record shorter than RecordDataLength"),
    R("H11", "multi_write_padding", WARNING, PROTOCOL, IEC, "Write-Multiple alignment/padding wrong"),
    R("H11", "multi_write_structure", ERROR, MALFORMED, IEC, "Write-Multiple structure broken"),
    R("N1", "ndr_args_len", ERROR, MALFORMED, IEC, "ArgsLength differs from stub length - 20"),
    R("N2", "ndr_array", ERROR, MALFORMED, IEC, "ActualCount differs from ArgsLength, or Offset not 0"),
    R("N3", "ndr_max_count", WARNING, PROTOCOL, IEC, "request MaximumCount differs from ArgsMaximum"),
    R("N5", "ndr_args_max_small", INFO, PROTOCOL, IEC, "read ArgsMaximum below 64 + RecordDataLength"),
    R("N4", "ndr_response_max", WARNING, PROTOCOL, IEC,
      "response MaximumCount/ArgsLength inconsistent with the request's ArgsMaximum"),
    R("N6", "pnio_status_form", WARNING, PROTOCOL, IEC, "PNIOStatus partially zero or unknown ErrorDecode"),
    R("N7", "pnio_status_service", WARNING, PROTOCOL, IEC, "ErrorCode does not match the service"),
    R("N7", "pnio_status_generic", INFO, PROTOCOL, IEC, "ErrorCode 0x81 (generic PNIO) on a record service"),
    R("N9", "error_with_blocks", INFO, PROTOCOL, IEC, "read response with error status carries blocks"),
    R("N8", "pnio_status_differs", WARNING, PROTOCOL, IEC, "NDR and block PNIOStatus differ"),
    # IOD headers (protocol.md 2.6, 6.2)
    R("H1", "block_type", ERROR, MALFORMED, IEC, "BlockType does not match service and direction"),
    R("H2", "block_length", ERROR, MALFORMED, IEC, "BlockLength is not 60"),
    R("H3", "block_version", WARNING, PROTOCOL, IEC, "block version is not 1.0"),
    R("H4", "padding_nonzero", WARNING, PROTOCOL, f"{IEC}; {YASKAWA_EP3}", "padding bytes not zero"),
    R("H12", "additional_values", INFO, COMMENT, YASKAWA_EP3, "AdditionalValue1/2 not zero"),
    R("H9", "aruuid_nil_write", ERROR, PROTOCOL, IEC, "NIL ARUUID in a write"),
    R("H9", "aruuid_implicit", WARNING, PROTOCOL, IEC, "NIL ARUUID with opnum 2, or non-NIL with opnum 5"),
    R("H10", "profibus_index", INFO, COMMENT, "PROFIdrive profile", "PROFIdrive over index 0x002F"),
    R("H10", "api_dap_yaskawa", INFO, PROTOCOL, YASKAWA_EP3, "API 0x0000 (Yaskawa device access point)"),
    R("H10", "api_not_profidrive", WARNING, PROTOCOL, "PROFIdrive profile", "API is not 0x3A00"),
    R("H13", "pd_record_length", ERROR, PROTOCOL, "PROFIdrive profile", "PROFIdrive record length out of range"),
    R("H14", "pd_read_buffer_small", INFO, PROTOCOL, "PROFIdrive profile", "read buffer below the record limit"),
    R("H5", "trailing_stub_bytes", WARNING, MALFORMED, IEC, "bytes after the record"),
    R("H6", "response_not_mirrored", WARNING, PROTOCOL, IEC, "response header does not mirror the request"),
    R("H7", "write_length_mirror", WARNING, PROTOCOL, IEC, "write response RecordDataLength differs"),
    R("H8", "read_length_exceeded", WARNING, PROTOCOL, IEC, "read response longer than requested"),
    R("H15", "not_profidrive", INFO, COMMENT, "protocol.md 1.4", "record is not PROFIdrive"),
    # PROFIdrive parameter request (protocol.md 3, 6.3)
    R("P1", "pd_too_short", ERROR, MALFORMED, PD, "request shorter than its header and addresses"),
    R("P6", "change_blocks", ERROR, MALFORMED, PD, "change request value blocks wrong in number or format"),
    R("P6", "block_overrun", ERROR, MALFORMED, PD, "value block overruns the record"),
    R("P8", "pad_nonzero", WARNING, PROTOCOL, PD, "pad byte not zero"),
    R("P8", "pad_missing", WARNING, PROTOCOL, PD, "pad byte after an odd value list missing"),
    R("P8", "pad_missing_final", WARNING, PROTOCOL, PD, "final pad byte missing"),
    R("F1", "format_unsupported", WARNING, MALFORMED, PD, "format of unknown size in the last block"),
    R("F1", "format_unsupported_stop", ERROR, MALFORMED, PD, "format of unknown size before the last block"),
    R("F2", "date_padded", WARNING, PROTOCOL, PD, "Date values padded to 8 bytes"),
    R("P2", "pd_request_range", ERROR, PROTOCOL, PD, "request field outside the PROFIdrive profile range"),
    R("P3", "subindex_ffff", WARNING, PROTOCOL, PD, "subindex 0xFFFF (refused by devices)"),
    R("P4", "vendor_limit", WARNING, PROTOCOL, "vendor profile", "field outside the selected vendor's limit"),
    R("P5", "read_request_length", WARNING, PROTOCOL, PD, "read request longer than 4 + 6n"),
    R("P7", "n_values_mismatch", WARNING, PROTOCOL, PD, "No. of values differs from No. of elements"),
    R("P8", "value_too_long", WARNING, PROTOCOL, PD, "one parameter's values longer than a request can carry"),
    R("P9", "change_description", INFO, COMMENT, PD, "change of a Description or Text attribute"),
    R("F3", "format_zero_akd", WARNING, PROTOCOL, AKD, "format 0x00 used for Zero (AKD only)"),
    R("Q13", "string_nonprintable", INFO, COMMENT, PD, "VisibleString with non-printable characters"),
    R("Q13", "boolean_value", WARNING, PROTOCOL, PD, "Boolean value not 0 or 1"),
    R("P10", "request_trailing", WARNING, MALFORMED, PD, "bytes left after the parsed request"),
    # PROFIdrive parameter response (protocol.md 3.3, 6.4)
    R("Q1", "pd_response_too_short", ERROR, MALFORMED, PD, "response shorter than its header"),
    R("Q12", "response_block_overrun", ERROR, MALFORMED, PD, "response block overruns the record"),
    R("V1", "akd_address_echo", WARNING, PROTOCOL, AKD, "response repeats the parameter address"),
    R("Q5", "header_level_error", INFO, COMMENT, PD, "whole request refused with one error block"),
    R("Q12", "pd_response_truncated", ERROR, MALFORMED, PD, "response ends before n blocks"),
    R("Q11", "response_too_long", WARNING, PROTOCOL, PD, "response longer than the record limit"),
    R("Q1", "response_id", ERROR, PROTOCOL, PD, "Response ID not in the profile's table"),
    R("Q6", "change_response_body", WARNING, PROTOCOL, PD, "positive change response carries a body"),
    R("Q6", "akd_trailing_zero", INFO, COMMENT, AKD, "AKD positive change response with trailing 00 00"),
    R("Q7", "read_response_blocks", ERROR, PROTOCOL, PD, "positive read response with Zero/Error blocks"),
    R("Q7", "n_values_read", WARNING, PROTOCOL, PD, "No. of values differs from the requested elements"),
    R("Q8", "nak_blocks", WARNING, PROTOCOL, PD, "negative response blocks inconsistent"),
    R("Q9", "error_block_count", ERROR, MALFORMED, PD, "error block No. of values not 1 or 2"),
    R("Q9", "error_subindex_presence", INFO, COMMENT, PD, "error subindex present/absent against 4.5"),
    R("Q10", "error_reserved", WARNING, PROTOCOL, PD, "error number reserved in the profile"),
    R("Q10", "error_manufacturer", INFO, COMMENT, PD, "manufacturer-specific error number"),
    R("Q12", "response_trailing", WARNING, MALFORMED, PD, "bytes left after the parsed response"),
    # channel and transaction (protocol.md 6.5, 7)
    R("T3", "write_while_pending", WARNING, SEQUENCE, PD, "write while a transaction is pending"),
    R("T1", "reference_reused", WARNING, SEQUENCE, PD, "Request Reference reused from the previous transaction"),
    R("T4", "retry", INFO, SEQUENCE, PD, "re-write after pnio_error/timeout with the same reference"),
    R("T6", "fallback_pairing", WARNING, SEQUENCE, PD, "read paired by device, controller, AR and index only"),
    R("T2", "read_without_request", WARNING, SEQUENCE, PD, "read with no pending write on the channel"),
    R("Q2", "reference_mismatch", ERROR, SEQUENCE, PD, "Request Reference not mirrored"),
    R("Q3", "response_id_mismatch", ERROR, SEQUENCE, PD, "Response ID does not answer the Request ID"),
    R("Q4", "do_not_mirrored", WARNING, SEQUENCE, PD, "DO-ID not mirrored"),
    R("Q5", "n_params_not_mirrored", WARNING, SEQUENCE, PD, "No. of parameters not mirrored"),
    R("T5", "b5_polling", INFO, SEQUENCE, PD, "B5 retries above the threshold"),
    R("T7", "txn_evicted", WARNING, SEQUENCE, "pd-analyze limits",
      "transaction table full, or a transaction with too many frames: it ends as a timeout"),
    R("T8", "txn_failed", WARNING, SEQUENCE, PD, "transaction failed: pnio_error, timeout or malformed"),
    R("T9", "txn_refused", INFO, SEQUENCE, PD, "transaction refused by the drive (nak)"),
    # the parameter state against an intended set (pd-analyze audit --expect, analysis.intended)
    R("S1", "expect_mismatch", ERROR, COMMENT, EXPECT, "confirmed or read-back value differs from the intended one"),
    R("S2", "expect_refused", ERROR, COMMENT, EXPECT, "every write of an intended parameter was refused"),
    R("S3", "expect_unconfirmed", WARNING, COMMENT, EXPECT, "written, but neither confirmed nor read back"),
    R("S4", "expect_missing", WARNING, COMMENT, EXPECT, "intended parameter never written or read"),
    R("S5", "unexpected_write", INFO, COMMENT, EXPECT, "parameter written that the intended set does not list"),
    # PROFIBUS DP-V1 header (pd-analyze decode --dpv1)
    R("D1", "dpv1_header", WARNING, PROTOCOL, "PROFIBUS DP-V1", "DP-V1 header inconsistent with the block"),
)
RULES: Mapping[str, Rule] = MappingProxyType({r.name: r for r in _RULES})
# Found by the transaction engine, not by a frame's own decode: pairing a response with its request (Q2-Q5)
# and the channel rules (protocol.md 6.5). `dump --findings-only` runs the engine to show them too.
TRANSACTION_RULES = frozenset({
    "reference_mismatch", "response_id_mismatch", "do_not_mirrored", "n_params_not_mirrored",
    "write_while_pending", "reference_reused", "retry", "fallback_pairing", "read_without_request",
    "b5_polling", "txn_evicted", "txn_failed", "txn_refused"})


def finding(name: str, frame: int, field: str, value: object, expected: object, message: str,
            source: str = "") -> Finding:
    """A finding of rule `name` at a frame; severity and (unless given) source from the registry."""
    rule = RULES[name]
    return Finding(rule.id, name, rule.severity, frame, field, _text(value), _text(expected),
                   source or rule.source, message)


def _text(value: object) -> str:
    if value is None:
        return ""
    return value if isinstance(value, str) else str(value)
