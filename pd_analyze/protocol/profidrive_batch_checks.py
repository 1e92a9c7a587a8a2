"""Which records of a decoded batch a P or Q rule of the record alone may report something on (`flag`).

Mirrors `profidrive_checks.Checker.request` / `response` (and the pad findings of the parse) as
comparisons over whole columns: each condition under which the reference may emit a finding marks the
record. A condition may be broader than the reference's (that only sends a record to the per-frame
checks for nothing), never narrower. Q2-Q5 and Q7's No. of values against the request are not here:
they need the request.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pd_analyze.model import pd_values as pt
from pd_analyze.protocol.profidrive_checks import Checker

# Error numbers by what Q9/Q10 say of them (indexed by the 16-bit error number)
_PROFILE_ERROR = np.zeros(1 << 16, bool)
_SUBINDEX_EXPECTED = np.zeros(1 << 16, bool)  # "yes": one value only is a finding
_SUBINDEX_UNDEFINED = np.zeros(1 << 16, bool)  # "no": a second value is a finding
for _number, _known in pt.ERRORS.items():
    _PROFILE_ERROR[_number] = True
    _SUBINDEX_EXPECTED[_number] = _known.subindex == "yes"
    _SUBINDEX_UNDEFINED[_number] = _known.subindex == "no"
# str.isprintable of each Latin-1 character (a VisibleString is checked as Latin-1 text)
_NOT_PRINTABLE = np.array([not chr(c).isprintable() for c in range(256)])
_NOT_BOOLEAN = np.arange(256) > 1


def breaks(checker: Checker, key: str, values: np.ndarray) -> np.ndarray:
    """Whether each value breaks a limit of `key` of the generic or the vendor profile (Checker.limit
    reports one finding per limit broken)."""
    out = np.zeros(len(values), bool)
    values = values.astype(np.int64)
    for profile in (checker.generic, checker.vendor):
        for lim in profile.limits_for(key) if profile is not None else ():
            allowed = np.zeros(len(values), bool)
            for lo, hi in lim.ranges:
                allowed |= (values >= lo) & (values <= hi)
            out |= ~allowed
    return out


@dataclass(slots=True)
class Columns:
    """What the checks read: record, address and block columns of a decoded batch."""

    regular: np.ndarray
    response: np.ndarray
    length: np.ndarray  # int64
    end: np.ndarray  # int64: bytes the parse consumed
    pad_note: np.ndarray  # bool: the parse reported a pad byte (pad_nonzero, pad_missing_final)
    ref: np.ndarray
    ident: np.ndarray
    do: np.ndarray
    n: np.ndarray
    first_addr: np.ndarray
    addr_record: np.ndarray
    attr: np.ndarray
    n_elems: np.ndarray
    pnu: np.ndarray
    subindex: np.ndarray
    block_record: np.ndarray
    block_position: np.ndarray  # the block's number within its record
    format: np.ndarray
    n_values: np.ndarray
    data_start: np.ndarray
    data_len: np.ndarray
    error: np.ndarray


def flags(c: Columns, b: np.ndarray, checker: Checker) -> tuple[np.ndarray, np.ndarray]:
    """The `flag` column: irregular records, and regular ones on which a record-local rule may report; and
    `limits_only`: the regular records flagged only because their header or an address breaks a limit (the
    engine states those findings from the columns, Checker.request_limits and response_limits, instead of
    parsing the record again; a regular record is never a vendor service's)."""
    request = c.regular & ~c.response
    response = c.regular & c.response
    limits = np.zeros(len(c.regular), bool)
    for field, req_ident, res_ident in (("ref", None, None), ("ident", "request.req_id", "response.resp_id"),
                                        ("do", None, None), ("n", "request.n_params", "response.n_params")):
        values = getattr(c, field)
        limits |= request & breaks(checker, req_ident or f"request.{field}", values)
        limits |= response & breaks(checker, res_ident or f"response.{field}", values)
    limits |= response & breaks(checker, "response.length", c.length)  # Q11
    bad_address = (breaks(checker, "request.attribute", c.attr) | breaks(checker, "request.n_elems", c.n_elems)
                   | breaks(checker, "request.pnu", c.pnu) | breaks(checker, "request.subindex", c.subindex))
    limits[c.addr_record[bad_address]] = True
    flag = ~c.regular
    # P5, P10, Q12, Q6 (a positive change response's end is its header): bytes after the parsed record
    flag |= c.regular & (c.end < c.length)
    flag |= c.pad_note  # P8: pad_nonzero, pad_missing_final
    flag[c.block_record[_block_flags(c, b, checker)]] = True
    # Q8: a negative read or change response without any error block
    has_error = np.bincount(c.block_record[c.format == pt.FMT_ERROR], minlength=len(flag)) > 0
    flag |= response & ((c.ident == pt.RES_READ_NAK) | (c.ident == pt.RES_CHANGE_NAK)) & ~has_error
    return flag | limits, limits & ~flag


def _block_flags(c: Columns, b: np.ndarray, checker: Checker) -> np.ndarray:
    """Per block: a rule may report on it."""
    fmt, m = c.format, c.n_values.astype(np.int64)
    in_response = c.response[c.block_record]
    ident = c.ident[c.block_record]
    is_error = fmt == pt.FMT_ERROR
    zero_like = (fmt == pt.FMT_ZERO) | (fmt == pt.FMT_AKD_ZERO)
    tolerate_00 = "format_00_zero" in checker.tolerate
    # change requests (P6-P9): block i goes with address i
    in_request = ~in_response
    sized = in_request & ~is_error & ~zero_like
    out = in_request & (is_error | zero_like)  # P6: Zero/Error format in a change request
    address = np.where(in_request, c.first_addr[c.block_record] + c.block_position, 0)
    attr = c.attr[address] if len(c.attr) else np.zeros(len(fmt), np.uint8)
    n_elems = (c.n_elems[address] if len(c.n_elems) else np.zeros(len(fmt), np.uint8)).astype(np.int64)
    out |= sized & (breaks(checker, "request.format", fmt) | breaks(checker, "request.n_values", m))
    out |= sized & (attr == pt.ATTR_VALUE) & ~((m == n_elems) | ((n_elems == 0) & (m == 1)))  # P7
    out |= sized & (c.data_len > checker.record.max_value_bytes)  # P8
    out |= sized & ((attr == pt.ATTR_DESCRIPTION) | (attr == pt.ATTR_TEXT))  # P9
    # responses (Q7-Q10)
    out |= in_response & breaks(checker, "response.format", fmt)
    error = np.where(is_error & (c.error >= 0), c.error, 0)
    out |= in_response & is_error & ((m < 1) | (m > 2) | ((c.error >= 0) & ~_PROFILE_ERROR[error])
                                     | (_SUBINDEX_EXPECTED[error] & (m == 1))
                                     | (_SUBINDEX_UNDEFINED[error] & (m == 2)))
    value = in_response & ~is_error
    out |= value & breaks(checker, "response.n_values", m)
    if not tolerate_00:
        out |= value & (fmt == pt.FMT_AKD_ZERO)  # F3
    out |= in_response & (ident == pt.RES_READ) & ((fmt == pt.FMT_ZERO) | is_error)  # Q7
    written = (fmt == pt.FMT_ZERO) | ((fmt == pt.FMT_AKD_ZERO) & tolerate_00)
    out |= in_response & (ident == pt.RES_CHANGE_NAK) & ~is_error & ~(written & (m == 0))  # Q8
    # Q13 on the values of both directions
    checked = sized | value
    strings = np.flatnonzero(checked & (fmt == pt.FMT_VISIBLE_STRING))
    out[strings] |= _any_byte(b, c.data_start[strings], c.data_len[strings], _NOT_PRINTABLE)
    booleans = np.flatnonzero(checked & (fmt == 0x01))
    out[booleans] |= _any_byte(b, c.data_start[booleans], c.data_len[booleans], _NOT_BOOLEAN)
    return out


def _any_byte(b: np.ndarray, start: np.ndarray, length: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Per byte range: whether `table` is true for any of its bytes."""
    length = length.astype(np.int64)
    total = int(length.sum())
    if not total:
        return np.zeros(len(start), bool)
    owner = np.repeat(np.arange(len(start)), length)
    at = np.repeat(start - (np.cumsum(length) - length), length) + np.arange(total)
    return np.bincount(owner[table[b[at]]], minlength=len(start)) > 0
