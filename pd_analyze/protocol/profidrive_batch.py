"""PROFIdrive parameter requests and responses of a batch decoded as columns (protocol.md 3, 4).

The same decode as `profidrive.parse_request` / `parse_response` and the table cells of
`analysis.rows.block_values`, applied to many records at once: the header of each record, its
parameter addresses (requests) exploded one row each, its value and error blocks walked position by
position over all records together. A record whose parse is not ordinary is `regular = False` and its
frame goes to the per-frame dissector: a record shorter than its header or than its addresses, an
unknown Response ID, a block overrunning the record, a format of unknown size, a Date (0x32), a pad byte
missing before a following block (the per-frame parse looks ahead there), the AKD address echo, a
header-level error (fewer blocks than parameters), a change request with fewer value blocks than
addresses.

`flag` marks the records on which a P or Q rule of the record alone may report something (limits of
the generic and vendor profiles, P5-P10, Q1, Q6-Q13 as far as they need no request): the caller has
their findings made by the per-frame checks. Q7's No. of values against the request is the caller's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pd_analyze.protocol.profidrive_checks import Checker


@dataclass(slots=True)
class RecordColumns:
    """One entry per record given, in the order given."""

    regular: np.ndarray  # bool
    flag: np.ndarray  # bool
    plausible: np.ndarray  # bool: profidrive.plausible(record, response) (index 0x002F carries PROFIdrive)
    ref: np.ndarray  # uint8 Request Reference
    ident: np.ndarray  # uint8 Request ID (requests) or Response ID (responses)
    do: np.ndarray  # uint8 DO-ID
    n: np.ndarray  # uint8 No. of parameters
    first_addr: np.ndarray  # int64: index of the record's first row in AddressColumns (requests)
    n_addr: np.ndarray  # int32: its address rows
    first_block: np.ndarray  # int64: index of the record's first row in BlockColumns
    n_blocks: np.ndarray  # int32: its block rows


@dataclass(slots=True)
class AddressColumns:
    """One entry per parameter address of the (regular) requests, in record and address order."""

    record: np.ndarray  # int64 index into RecordColumns
    attr: np.ndarray  # uint8
    n_elems: np.ndarray  # uint8
    pnu: np.ndarray  # uint16
    subindex: np.ndarray  # uint16


@dataclass(slots=True)
class BlockColumns:
    """One entry per value, Zero or error block of the (regular) records, in record and block order:
    the value blocks of a change request, the blocks of a response."""

    record: np.ndarray  # int64 index into RecordColumns
    format: np.ndarray  # uint8
    n_values: np.ndarray  # uint8
    data_start: np.ndarray  # int64: offset of the first value byte in buf
    data_len: np.ndarray  # int32: n_values x the format's size
    error: np.ndarray  # int32: error number of an error block (Format 0x44), -1 otherwise
    error_subindex: np.ndarray  # int32: its second value when it has one, -1 otherwise
    # The block's values as the tables show them: analysis.rows.block_values(block), "" for error and
    # Zero blocks (a pyarrow string array, or a numpy object array of str)
    text: object


@dataclass(slots=True)
class DecodedRecords:
    records: RecordColumns
    addresses: AddressColumns
    blocks: BlockColumns


def decode(buf: bytes, start: np.ndarray, length: np.ndarray, response: np.ndarray,
           checker: Checker) -> DecodedRecords:
    """The records buf[start[i] : start[i] + length[i]], parameter responses where `response[i]`,
    parameter requests (write) elsewhere."""
    raise NotImplementedError
