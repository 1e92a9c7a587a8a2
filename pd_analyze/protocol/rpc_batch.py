"""Connectionless DCE/RPC v4 headers of many UDP payloads as columns: `rpc.plausible`, `rpc.header` and the
frame-local header rules (`rpc.check_header`, the dissector's pnio_interface) for a whole batch.

The header is read with rpc.HEADER_LE or rpc.HEADER_BE, chosen per PDU by its DREP byte, so PDUs of both
byte orders may share a batch; UUIDs are made canonical as `rpc.canonical_uuid` makes them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pd_analyze.model.layout import fields_by_order
from pd_analyze.model.values import (
    FLAG1_BROADCAST,
    FLAG1_MAYBE,
    PNIO_UUID_PREFIX,
    PNIO_UUID_SUFFIX,
    PTYPE_REQUEST,
    PTYPE_RESPONSE,
)
from pd_analyze.protocol import rpc
from pd_analyze.protocol.rpc import HEADER_BE, HEADER_LE

# rpc.is_pnio_uuid on the two canonical halves: prefix, any interface byte, suffix
_PNIO_HI_MASK = np.uint64(~(0xFF << 32) & (1 << 64) - 1)
_PNIO_HI = np.uint64(int.from_bytes(PNIO_UUID_PREFIX + b"\0" + PNIO_UUID_SUFFIX[:4], "big"))
_PNIO_LO = np.uint64(int.from_bytes(PNIO_UUID_SUFFIX[4:], "big"))
# A UUID as two big-endian halves, and (rpc.canonical_uuid) the little-endian DREP form: time_low, time_mid
# and time_hi_and_version in the DREP order, clock_seq and node as on the wire
_UUID_BIG = np.dtype([("hi", ">u8"), ("lo", ">u8")])
_UUID_LITTLE = np.dtype([("time_low", "<u4"), ("time_mid", "<u2"), ("time_hi", "<u2"), ("lo", ">u8")])
DEVICE_INTERFACE = 1  # canonical interface byte 3 of PNIO Device (dea00001-...), the record services' interface
IF_VERSION = 1  # the interface version R5 expects
_PLAUSIBLE = ("rpc.ver", "rpc.ptype", "rpc.flags2", "rpc.drep")
_NAMES = ("rpc.ptype", "rpc.flags1", "rpc.drep", "rpc.serial_hi", "rpc.interface", "rpc.activity",
          "rpc.if_version", "rpc.seq", "rpc.opnum", "rpc.frag_len", "rpc.frag_num", "rpc.auth_proto",
          "rpc.serial_lo")


@dataclass(slots=True)
class Headers:
    """One entry per UDP payload given, in its order; the columns but `plausible` mean nothing where it is False."""

    plausible: np.ndarray  # bool: rpc.plausible
    little: np.ndarray  # bool: DREP integers little-endian
    ptype: np.ndarray  # uint8
    flags1: np.ndarray  # uint8
    float_repr: np.ndarray  # uint8: DREP byte 1
    serial: np.ndarray  # uint16: serial_hi << 8 | serial_lo
    act_hi: np.ndarray  # uint64: activity UUID, canonical, bytes 0-7 as a big-endian integer
    act_lo: np.ndarray  # uint64: bytes 8-15
    if_hi: np.ndarray  # uint64: interface UUID, canonical
    if_lo: np.ndarray  # uint64
    if_version: np.ndarray  # uint32
    seq: np.ndarray  # uint32
    opnum: np.ndarray  # uint16
    frag_len: np.ndarray  # uint16
    frag_num: np.ndarray  # uint16
    auth: np.ndarray  # uint8: auth_proto

    @property
    def pnio(self) -> np.ndarray:
        """rpc.is_pnio_uuid of the interface."""
        return ((self.if_hi & _PNIO_HI_MASK) == _PNIO_HI) & (self.if_lo == _PNIO_LO)

    @property
    def interface_number(self) -> np.ndarray:
        """Byte 3 of the canonical interface UUID: which PNIO interface (1 Device, 2 Controller, ...)."""
        return (self.if_hi >> np.uint64(32)) & np.uint64(0xFF)


def decode(data: np.ndarray, at: np.ndarray, length: np.ndarray) -> Headers:
    """The UDP payloads data[at[i] : at[i] + length[i]]: which are plausible CL-RPC (rpc.plausible), and their
    headers (rpc.header), each read in its DREP byte order."""
    records = HEADER_BE.records(data, at, length >= rpc.HEADER_SIZE)  # zero bytes (not plausible) if shorter
    head = HEADER_BE.fields(records, _PLAUSIBLE)
    drep = head["rpc.drep"]
    plausible = ((head["rpc.ver"] == rpc.RPC_VERSION) & (head["rpc.ptype"] <= rpc.PTYPE_LAST)
                 & (head["rpc.flags2"] & rpc.FLAGS2_RESERVED == 0) & (drep[:, 0] & rpc.DREP_RESERVED == 0)
                 & (drep[:, 1] <= rpc.DREP_FLOAT_LAST))
    little = (drep[:, 0] & rpc.DREP_LITTLE) != 0
    cols = fields_by_order(HEADER_LE, HEADER_BE, records, little, _NAMES)
    act_hi, act_lo = _canonical(cols["rpc.activity"], little)
    if_hi, if_lo = _canonical(cols["rpc.interface"], little)
    serial = cols["rpc.serial_hi"].astype(np.uint16) << np.uint16(8) | cols["rpc.serial_lo"]
    return Headers(plausible, little, cols["rpc.ptype"], cols["rpc.flags1"], cols["rpc.drep"][:, 1].copy(), serial,
                   act_hi, act_lo, if_hi, if_lo, cols["rpc.if_version"], cols["rpc.seq"], cols["rpc.opnum"],
                   cols["rpc.frag_len"], cols["rpc.frag_num"], cols["rpc.auth_proto"])


def _canonical(raw: np.ndarray, little: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, 16) DREP-ordered UUIDs as the two big-endian halves of their canonical form (rpc.canonical_uuid)."""
    packed = np.ascontiguousarray(raw)
    big = packed.view(_UUID_BIG)[:, 0]
    hi, lo = big["hi"].astype(np.uint64), big["lo"].astype(np.uint64)
    if little.any():
        le = packed.view(_UUID_LITTLE)[:, 0]
        le_hi = (le["time_low"].astype(np.uint64) << np.uint64(32) | le["time_mid"].astype(np.uint64) << np.uint64(16)
                 | le["time_hi"].astype(np.uint64))
        hi = np.where(little, le_hi, hi)
    return hi, lo


def flags(h: Headers, present: np.ndarray, record_service: np.ndarray) -> np.ndarray:
    """PDUs on which rpc.check_header (R2, R5, R6, the serial note) or the pnio_interface rule may report.

    `present`: body bytes present after the header; `record_service`: the opnum is Read, Write or ReadImplicit."""
    request = h.ptype == PTYPE_REQUEST
    record_request = record_service & request
    return ((present > h.frag_len) | (h.if_version != IF_VERSION) | (h.auth != 0)
            | (record_request & (h.flags1 & (FLAG1_MAYBE | FLAG1_BROADCAST) != 0))
            | (h.float_repr != 0)
            | ((h.serial != h.frag_num) & ((h.ptype == PTYPE_REQUEST) | (h.ptype == PTYPE_RESPONSE)))
            | (record_request & (h.interface_number != DEVICE_INTERFACE)))
