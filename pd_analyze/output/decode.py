"""Decode one PROFIdrive parameter block given as hex, as pasted from PLC buffers, logs and manuals."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from pd_analyze.model.layout import Field, Layout
from pd_analyze.model.rules import Finding, finding
from pd_analyze.protocol import profidrive, profidrive_view
from pd_analyze.protocol.profidrive_checks import Checker

DPV1 = Layout("PROFIBUS DP-V1 header", ">", (("dpv1.function", "B"), ("dpv1.slot", "B"), ("dpv1.index", "B"),
                                             ("dpv1.length", "B")))
DPV1_READ, DPV1_WRITE, DPV1_PROFIDRIVE_INDEX = 0x5E, 0x5F, 47
_HEX = re.compile(r"^[0-9a-fA-F]*$")


@dataclass(slots=True)
class Decoded:
    response: bool
    sections: list[tuple[str, list[Field]]] = field(default_factory=list)
    findings: list[Finding] = field(default_factory=list)


def parse_hex(text: str) -> bytes:
    """Hex with or without spaces, colons, commas or 0x prefixes; ValueError says what is wrong."""
    cleaned = re.sub(r"0[xX](?=[0-9a-fA-F]{2})", "", text)
    cleaned = re.sub(r"[\s:,;\-_]", "", cleaned)
    if not _HEX.match(cleaned):
        bad = next(ch for ch in cleaned if ch not in "0123456789abcdefABCDEF")
        raise ValueError(f"not hex: unexpected character {bad!r}")
    if len(cleaned) % 2:
        raise ValueError(f"odd number of hex digits ({len(cleaned)}): a byte is cut in half")
    if not cleaned:
        raise ValueError("no bytes given")
    return bytes.fromhex(cleaned)


def decode(data: bytes, response: bool | None, checker: Checker, dpv1: bool = False,
           request: bytes | None = None) -> Decoded:
    """Fields and findings of a parameter request/response (optionally behind a DP-V1 header)."""
    sections: list[tuple[str, list[Field]]] = []
    findings: list[Finding] = []
    base = 0
    if dpv1:
        if len(data) < 4:
            raise ValueError("a DP-V1 header needs 4 bytes: function, slot, index, length")
        values = DPV1.unpack(data)
        func, _slot, index, length = values
        if response is None and func in (DPV1_READ, DPV1_WRITE):
            response = func == DPV1_READ  # a write carries the request, a read response the response
        head = DPV1.annotate(data, 0, values)
        sections.append((DPV1.title, head))
        body = data[4:]
        if func not in (DPV1_READ, DPV1_WRITE):
            findings.append(finding("dpv1_header", 0, "dpv1.function", f"{func:#04x}", "0x5e or 0x5f",
                                    "DP-V1 function number is neither read (0x5E) nor write (0x5F)"))
        if index != DPV1_PROFIDRIVE_INDEX:
            findings.append(finding("dpv1_header", 0, "dpv1.index", index, DPV1_PROFIDRIVE_INDEX,
                                    "the PROFIdrive parameter channel of DP-V1 is index 47"))
        if length != len(body):
            findings.append(finding("dpv1_header", 0, "dpv1.length", length, len(body),
                                    f"DP-V1 length {length} differs from the {len(body)} bytes that follow"))
        data, base = body, 4
    if response is None:
        raise ValueError("say --request or --response (or give --dpv1 with function 0x5F/0x5E)")
    req = None
    if request is not None:
        req = profidrive.parse_request(request, 0, [], checker.ids)
    if response:
        parsed = profidrive.parse_response(data, 0, findings, checker.ids)
        findings += checker.response(parsed, 0, req)
    else:
        parsed = profidrive.parse_request(data, 0, findings, checker.ids)
        findings += checker.request(parsed, 0)
    sections += profidrive_view.annotate(parsed, data, base, checker, req)
    return Decoded(response, sections, findings)
