"""PROFIdrive Base Mode parameter request / response records
(protocol.md section 3). All fields big-endian.

Every count, length and pad is computed by default and can be overridden so
tests can build records that violate the profile.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

# Request / Response IDs (4.1)
REQ_READ: Final = 0x01
REQ_CHANGE: Final = 0x02
RES_READ_OK: Final = 0x01
RES_CHANGE_OK: Final = 0x02
RES_NOT_SUPPORTED: Final = 0x80
RES_READ_NAK: Final = 0x81
RES_CHANGE_NAK: Final = 0x82

# Attributes (4.2)
ATTR_VALUE: Final = 0x10
ATTR_DESCRIPTION: Final = 0x20
ATTR_TEXT: Final = 0x30

FMT_ZERO: Final = 0x40
FMT_ERROR: Final = 0x44

# Bytes per value for the sized formats of 4.3, and the struct code used to
# pack a Python number. Signed formats are packed from their raw unsigned
# bits (value & mask) so callers may pass either -1 or 0xFFFF.
_NUMERIC: Final[dict[int, str]] = {
    0x01: "B", 0x02: "B", 0x03: "H", 0x04: "I", 0x05: "B", 0x06: "H", 0x07: "I",
    0x08: "f", 0x0F: "d", 0x34: "I", 0x36: "I", 0x37: "Q", 0x38: "Q",
    0x41: "B", 0x42: "H", 0x43: "I",
    0x71: "H", 0x72: "I", 0x73: "H", 0x74: "H", 0x75: "H", 0x76: "H", 0x77: "I",
    0x78: "H", 0x79: "H", 0x7A: "I", 0x7B: "H", 0x7C: "I",
}  # fmt: skip
# Formats whose values are byte arrays (no. of values = characters/octets)
# or fixed-size composites given as raw bytes per value.
FORMAT_SIZE: Final[dict[int, int]] = {
    **{code: struct.calcsize(">" + c) for code, c in _NUMERIC.items()},
    0x09: 1, 0x0A: 1, 0x27: 2, 0x0C: 6, 0x35: 6, 0x32: 7, 0x40: 0, 0x44: 2, 0x00: 0,
}  # fmt: skip

Value = int | float | bytes


def encode_values(fmt: int, values: Sequence[Value] | bytes | str) -> tuple[bytes, int]:
    """Raw value bytes and their count m for a value block.

    - str: VisibleString (0x09, one byte per char, latin-1) or
      UnicodeString (0x27, UCS-2 BE); m = characters;
    - bytes: raw array (m = len // size), e.g. OctetString or a preformatted
      Date;
    - sequence: each item an int/float packed per the format, or bytes
      taken verbatim (any size, for malformed values).
    """
    if isinstance(values, str):
        raw = values.encode("utf-16-be") if fmt == 0x27 else values.encode("latin-1")
        return raw, len(values)
    size = FORMAT_SIZE.get(fmt, 1) or 1
    if isinstance(values, bytes | bytearray):
        return bytes(values), len(values) // size
    out = b""
    for v in values:
        if isinstance(v, bytes | bytearray):
            out += bytes(v)
        elif fmt in (0x08, 0x0F):
            out += struct.pack(">" + _NUMERIC[fmt], float(v))
        elif fmt in _NUMERIC:
            code = _NUMERIC[fmt]
            out += struct.pack(">" + code, int(v) & ((1 << (8 * struct.calcsize(code))) - 1))
        elif fmt in (0x0C, 0x35):
            # (ms, days) composite given as one int: ms << 16 | days
            out += int(v).to_bytes(6, "big")
        else:
            raise ValueError(f"give raw bytes for values of format 0x{fmt:02X}")
    return out, len(values)


def value_block(
    fmt: int,
    values: Sequence[Value] | bytes | str,
    *,
    n_values: int | None = None,
    pad: bytes | None = None,
) -> bytes:
    """Format, No. of values, values, then the 3.2 pad byte when the value
    byte count is odd (pad=b"" drops it, pad=b"\\x55" makes it non-zero)."""
    raw, count = encode_values(fmt, values)
    m = count if n_values is None else n_values
    p = (b"\x00" if len(raw) % 2 else b"") if pad is None else pad
    return bytes([fmt, m & 0xFF]) + raw + p


def error_block(
    error: int,
    subindex: int | None = None,
    *,
    n_values: int | None = None,
    extra: Sequence[int] = (),
    fmt: int = FMT_ERROR,
) -> bytes:
    """Format 0x44 block: error number, optional subindex of the first faulty
    element; `extra` appends further words (for count violations)."""
    words = [error] + ([] if subindex is None else [subindex]) + list(extra)
    m = len(words) if n_values is None else n_values
    return bytes([fmt, m & 0xFF]) + b"".join(struct.pack(">H", w & 0xFFFF) for w in words)


def zero_block(*, fmt: int = FMT_ZERO, n_values: int = 0) -> bytes:
    """'Parameter written' entry of a 0x82 response (AKD: fmt 0x00)."""
    return bytes([fmt, n_values])


@dataclass(frozen=True)
class ParamAddress:
    """One parameter address of a request: P<pnu>[<subindex>...]."""

    pnu: int
    subindex: int = 0
    n_elems: int = 1
    attr: int = ATTR_VALUE

    def encode(self) -> bytes:
        return struct.pack(">BBHH", self.attr, self.n_elems, self.pnu, self.subindex)


def pd_request(
    ref: int,
    req_id: int,
    do: int,
    addresses: Sequence[ParamAddress | bytes],
    values: Sequence[bytes] = (),
    *,
    n_params: int | None = None,
    trailer: bytes = b"",
) -> bytes:
    """Parameter request: header, addresses, value blocks (change requests),
    then `trailer` (junk bytes for P5/P10 tests)."""
    n = len(addresses) if n_params is None else n_params
    out = bytes([ref, req_id, do, n & 0xFF])
    out += b"".join(a.encode() if isinstance(a, ParamAddress) else a for a in addresses)
    return out + b"".join(values) + trailer


def pd_response(
    ref: int,
    resp_id: int,
    do: int,
    blocks: Sequence[bytes] = (),
    *,
    n_params: int | None = None,
    trailer: bytes = b"",
) -> bytes:
    """Parameter response: header (n defaults to the block count; give it
    explicitly for a positive change response) + blocks + trailer."""
    n = len(blocks) if n_params is None else n_params
    return bytes([ref, resp_id, do, n & 0xFF]) + b"".join(blocks) + trailer


def read_request(ref: int, do: int, addresses: Sequence[ParamAddress]) -> bytes:
    return pd_request(ref, REQ_READ, do, addresses)


def change_request(ref: int, do: int, items: Sequence[tuple[ParamAddress, bytes]]) -> bytes:
    """Change request from (address, value block) pairs."""
    return pd_request(ref, REQ_CHANGE, do, [a for a, _ in items], [b for _, b in items])


def change_ok(ref: int, do: int, n_params: int) -> bytes:
    """Positive change response: the 4-byte header only."""
    return pd_response(ref, RES_CHANGE_OK, do, (), n_params=n_params)


# ---- composite values (protocol.md 4.3, 4.4) -----------------------------------------------------


def date_value(
    year: int, month: int, day: int, hour: int = 0, minute: int = 0, ms: int = 0, *, weekday: int = 0
) -> bytes:
    """One Date (0x32, BinaryDate) value, 7 bytes: ms within the minute
    (U16), minute, hour, day (weekday in bits 5-7, 1 = Monday), month,
    year - 1900 or - 2000 (< 50 means 20xx)."""
    return struct.pack(">HBBBBB", ms, minute, hour, (weekday << 5) | day, month, year % 100)


def time_value(ms: int, days: int | None = None) -> bytes:
    """TimeOfDay / TimeDifference: ms (U32) plus days (U16) for the 'with
    date indication' formats 0x0C / 0x35 (6 bytes); 4 bytes without."""
    return struct.pack(">I", ms) + (b"" if days is None else struct.pack(">H", days))


DESCRIPTION_SIZE: Final = 46


def description(
    identifier: int,
    elements: int,
    name: str,
    *,
    std_factor: float = 1.0,
    var_attr: int = 0,
    low: bytes = bytes(4),
    high: bytes = bytes(4),
    id_ext: int = 0,
    ref_param: int = 0,
    normalisation: int = 0,
) -> bytes:
    """The complete description (attribute 0x20, subindex 0): 46 octets in
    the layout of protocol.md 4.4; `name` is cut/padded to 16 characters."""
    out = struct.pack(">HHfHI", identifier, elements, std_factor, var_attr, 0)
    out += name.encode("latin-1")[:16].ljust(16) + low + high
    out += struct.pack(">HHHH", 0, id_ext, ref_param, normalisation)
    assert len(out) == DESCRIPTION_SIZE
    return out


def text_entries(texts: Sequence[str]) -> str:
    """Text array entries (attribute 0x30): 16 characters each, space-padded."""
    return "".join(t[:16].ljust(16) for t in texts)


def akd_echo_response(ref: int, resp_id: int, do: int, address: ParamAddress, block: bytes) -> bytes:
    """A one-parameter response in the AKD manual's layout: the 6-byte
    parameter address repeated before Format (protocol.md 5.3)."""
    return bytes([ref, resp_id, do, 1]) + address.encode() + block
