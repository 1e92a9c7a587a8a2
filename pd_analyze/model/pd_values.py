"""PROFIdrive value tables (protocol.md 4): IDs, attributes, formats with their sizes, error numbers.

Source: PROFIdrive profile V4.2 Base Mode Parameter Access, as summarised in protocol.md section 4;
vendor-specific error texts live in the vendor profiles (pd_analyze/profiles/*.toml).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import NamedTuple

REQ_READ, REQ_CHANGE = 0x01, 0x02
RES_READ, RES_CHANGE, RES_NOT_SUPPORTED, RES_READ_NAK, RES_CHANGE_NAK = 0x01, 0x02, 0x80, 0x81, 0x82
ATTR_VALUE, ATTR_DESCRIPTION, ATTR_TEXT = 0x10, 0x20, 0x30
FMT_ZERO, FMT_ERROR, FMT_AKD_ZERO = 0x40, 0x44, 0x00
FMT_VISIBLE_STRING, FMT_OCTET_STRING, FMT_UNICODE_STRING, FMT_DATE = 0x09, 0x0A, 0x27, 0x32

REQUEST_ID: Mapping[int, str] = MappingProxyType({
    0x01: "request parameter (read)", 0x02: "change parameter (write)"})
RESPONSE_ID: Mapping[int, str] = MappingProxyType({
    0x01: "request parameter, positive", 0x02: "change parameter, positive",
    0x80: "negative: request not supported", 0x81: "request parameter, negative",
    0x82: "change parameter, negative"})
# A negative response as the dump's frame heading names it (tshark's Info column: "Negative read response")
NEGATIVE_RESPONSE: Mapping[int, str] = MappingProxyType({
    0x80: "negative response, request not supported", 0x81: "negative read response",
    0x82: "negative change response"})
ATTRIBUTE: Mapping[int, str] = MappingProxyType({0x10: "Value", 0x20: "Description", 0x30: "Text"})


class Format(NamedTuple):
    name: str
    size: int  # bytes per value; 0 = no values
    kind: str  # how values are decoded and shown (see protocol.profidrive_view.value_of)
    scale: str = ""  # the scaling an engineer needs to read the raw value


_F = Format
FORMATS: Mapping[int, Format] = MappingProxyType({
    0x01: _F("Boolean", 1, "bool"),
    0x02: _F("Integer8", 1, "int"), 0x03: _F("Integer16", 2, "int"), 0x04: _F("Integer32", 4, "int"),
    0x05: _F("Unsigned8", 1, "uint"), 0x06: _F("Unsigned16", 2, "uint"), 0x07: _F("Unsigned32", 4, "uint"),
    0x08: _F("FloatingPoint32", 4, "float"),
    0x09: _F("VisibleString", 1, "string"), 0x0A: _F("OctetString", 1, "octets"),
    0x0C: _F("TimeOfDay with date indication", 6, "time_date", "ms since midnight + days since 1984-01-01"),
    0x0F: _F("FloatingPoint64", 8, "float"),
    0x27: _F("UnicodeString", 2, "unicode"),
    0x32: _F("Date", 7, "date"),
    0x34: _F("TimeOfDay without date indication", 4, "uint", "ms since midnight"),
    0x35: _F("TimeDifference with date indication", 6, "time_date", "ms + days"),
    0x36: _F("TimeDifference without date indication", 4, "uint", "ms"),
    0x37: _F("Integer64", 8, "int"), 0x38: _F("Unsigned64", 8, "uint"),
    0x40: _F("Zero", 0, "zero"),
    0x41: _F("Byte", 1, "hex"), 0x42: _F("Word", 2, "hex"), 0x43: _F("Double word", 4, "hex"),
    0x44: _F("Error", 2, "error"),
    0x71: _F("N2 normalised 16 bit", 2, "n2", "x 100/16384 % (0x4000 = 100 %)"),
    0x72: _F("N4 normalised 32 bit", 4, "n4", "x 100/2^30 % (0x40000000 = 100 %)"),
    0x73: _F("V2 bit sequence", 2, "bits"), 0x74: _F("L2 nibble", 2, "nibbles"),
    0x75: _F("R2 reciprocal time constant", 2, "uint", "raw; unit from the sampling time"),
    0x76: _F("T2 time constant", 2, "t2", "x Ts"), 0x77: _F("T4 time constant", 4, "uint", "x Ts"),
    0x78: _F("D2 time constant", 2, "t2", "x Ts"),
    0x79: _F("E2 fixed point 16 bit", 2, "e2", "/ 128"), 0x7A: _F("C4 fixed point 32 bit", 4, "c4", "/ 10000"),
    0x7B: _F("X2 normalised, variable", 2, "int", "normalised by a reference parameter"),
    0x7C: _F("X4 normalised, variable", 4, "int", "normalised by a reference parameter"),
    0x00: _F("no data (AKD)", 0, "zero"),
})
FORMAT_NAME: Mapping[int, str] = MappingProxyType({code: f.name for code, f in FORMATS.items()})


class ErrorNumber(NamedTuple):
    text: str
    subindex: str  # "yes": second value (subindex) expected; "no"; "optional"


_E = ErrorNumber
ERRORS: Mapping[int, ErrorNumber] = MappingProxyType({
    0x00: _E("impermissible parameter number (PNU does not exist)", "no"),
    0x01: _E("parameter value cannot be changed", "yes"),
    0x02: _E("low or high limit exceeded", "yes"),
    0x03: _E("faulty subindex", "yes"),
    0x04: _E("no array (subindex access to a non-indexed parameter)", "no"),
    0x05: _E("incorrect data type", "no"),
    0x06: _E("setting not permitted (may only be reset)", "yes"),
    0x07: _E("description element cannot be changed", "yes"),
    0x09: _E("no description data available", "no"),
    0x0B: _E("no operation priority (no master control / no change rights)", "no"),
    0x0F: _E("no text array available", "no"),
    0x10: _E("reserved in the profile; SINAMICS: read request refused, know-how protection active", "no"),
    0x11: _E("request cannot be executed because of operating state", "no"),
    0x14: _E("value impermissible (within limits but not allowed)", "yes"),
    0x15: _E("response too long (exceeds the maximum transfer length)", "no"),
    0x16: _E("parameter address impermissible (attribute, elements, PNU, subindex or combination)", "no"),
    0x17: _E("illegal format (change request)", "no"),
    0x18: _E("number of values not consistent (change request)", "no"),
    0x19: _E("axis / DO does not exist", "no"),
    0x20: _E("parameter text element cannot be changed", "optional"),
    0x21: _E("service not supported (illegal Request ID)", "no"),
    0x22: _E("too many parameter requests (multi-parameter)", "no"),
    0x23: _E("multi-parameter access not supported", "no"),
})
# Errors a device may answer with one error block for the whole request (protocol.md 3.3).
HEADER_LEVEL_ERRORS = frozenset({0x19, 0x21, 0x22, 0x23})


def error_class(number: int) -> str:
    """'profile', 'reserved' or 'manufacturer' (protocol.md 4.5)."""
    if number in ERRORS:
        return "profile"
    return "manufacturer" if 0x65 <= number <= 0xFF else "reserved"


def error_text(number: int, vendor_texts: Mapping[int, str] | None = None) -> str:
    """The meaning of a PROFIdrive error number, with the vendor's text where it has one."""
    if number in ERRORS:
        return ERRORS[number].text
    if vendor_texts and number in vendor_texts:
        return f"manufacturer-specific {number:#04x}: {vendor_texts[number]}"
    if 0x65 <= number <= 0xFF:
        return f"manufacturer-specific {number:#04x}"
    return f"reserved {number:#04x}"


# Description elements (attribute 0x20) by subindex (protocol.md 4.4).
DESCRIPTION_ELEMENT: Mapping[int, str] = MappingProxyType({
    0: "complete description", 1: "identifier", 2: "number of array elements / string length",
    3: "standardisation factor", 4: "variable attribute", 5: "reserved", 6: "name", 7: "low limit",
    8: "high limit", 9: "reserved", 10: "ID extension", 11: "reference parameter", 12: "normalisation"})
# The complete description (subindex 0): 46 octets, (offset, size, element, struct code or "" for text).
DESCRIPTION_LAYOUT = (
    (0, 2, "identifier", ">H"), (2, 2, "elements", ">H"), (4, 4, "standardisation_factor", ">f"),
    (8, 2, "variable_attribute", ">H"), (10, 4, "reserved1", ">I"), (14, 16, "name", ""),
    (30, 4, "low_limit", ">I"), (34, 4, "high_limit", ">I"), (38, 2, "reserved2", ">H"),
    (40, 2, "id_extension", ">H"), (42, 2, "reference_parameter", ">H"), (44, 2, "normalisation", ">H"))
DESCRIPTION_SIZE = 46
IDENTIFIER_BITS: Mapping[int, str] = MappingProxyType({
    8: "standardisation not relevant", 9: "read-only", 10: "text array available",
    12: "changed vs factory setting", 13: "reset only", 14: "array"})


def float_text(value: float, size: int) -> str:
    """The shortest text that reads back to the same IEEE 754 bits at the value's width (4: Float32,
    8: Float64), as Python writes a float without a trailing ".0": 46 ca a3 40 is 25937.625 (not the
    25937.62 a fixed 7 digits would give), 1500 is 1500, 1e-45 stays 1e-45; nan, inf, -inf as str()."""
    if value != value or value in (math.inf, -math.inf):
        return str(value)
    text = repr(value)
    if size == 4:
        bits = struct.pack(">f", value)
        for digits in range(1, 10):  # 9 significant digits always read back to the same Float32
            candidate = float(f"{value:.{digits - 1}e}")
            try:
                if struct.pack(">f", candidate) == bits:
                    text = repr(candidate)
                    break
            except OverflowError:  # rounded up beyond the largest Float32: more digits are needed
                continue
    return text[:-2] if text.endswith(".0") else text


# Profile parameters (PNU 900 ... 999) have the same meaning on every drive (protocol.md 4.7; names as
# public drive manuals print them). A vendor profile may add its own names ([pnu_names] in its TOML).
PROFILE_PARAMETERS: Mapping[int, str] = MappingProxyType({
    915: "DO IO data assignment, setpoint telegram", 916: "DO IO data assignment, actual value telegram",
    918: "node address", 919: "device system number", 922: "telegram selection",
    923: "list of all parameters for signals", 925: "controller sign-of-life failures tolerated",
    927: "operator control rights", 930: "operating mode", 944: "fault message counter", 945: "fault code",
    947: "fault number", 948: "fault time", 949: "fault value", 952: "number of fault situations",
    964: "drive unit identification", 965: "profile identification number",
    971: "transfer into non-volatile memory", 974: "base mode parameter access service identification",
    975: "drive object identification",
    **{pnu: "number list of defined parameters" for pnu in range(980, 990)},
})


def pnu_name(pnu: int, names: Mapping[int, str] | None = None) -> str:
    """The name of a parameter number: the profile's own table first, then the PROFIdrive profile
    parameters; '' when neither knows it."""
    if names:
        name = names.get(pnu)
        if name:
            return name
    return PROFILE_PARAMETERS.get(pnu, "")


@dataclass(frozen=True, slots=True)
class Names:
    """What the selected profile names beyond the PROFIdrive tables: its own parameter names ([pnu_names]) and
    manufacturer-specific error texts ([error_texts]). Every output that names a parameter or an error asks
    the run's Names, so the dump, the tables, the summary and the state agree."""

    pnus: Mapping[int, str] = field(default_factory=dict)
    errors: Mapping[int, str] = field(default_factory=dict)

    def pnu(self, pnu: int) -> str:
        return pnu_name(pnu, self.pnus)

    def error(self, number: int) -> str:
        return error_text(number, self.errors)


PROFIDRIVE_NAMES = Names()  # the PROFIdrive profile's own names alone (no vendor profile)
