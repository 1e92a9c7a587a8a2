"""What the transactions of a fault-rich capture say: the drives' parameters and the PROFIdrive requests and
answers of each kind (reads and changes of one or more parameters, NAKs, whole-request refusals, header
fields out of range, structurally broken requests), with the error numbers the truth records.

A `Drive` keeps the value of every parameter element per slot and DO, so a change is answered by the values
read back later, and both controllers of the plant see each other's changes.
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

from .pd_encode import ParamAddress as P
from .pd_encode import change_ok, error_block, pd_request, pd_response, value_block, zero_block


@dataclass(frozen=True)
class Param:
    pnu: int
    fmt: int  # protocol.md 4.3
    elements: int  # 1: a single value
    writable: bool
    low: float = 0
    high: float = 65535


# A drive's parameters: profile parameters (protocol.md 4.7) and the usual setpoints, ramps and limits.
PARAMS: Final = (
    Param(964, 0x42, 7, False), Param(930, 0x06, 1, False), Param(944, 0x06, 1, False),
    Param(945, 0x06, 8, False), Param(947, 0x06, 8, False), Param(974, 0x06, 3, False),
    Param(922, 0x06, 1, True, 1, 999), Param(10, 0x06, 1, True, 0, 30), Param(971, 0x06, 1, True, 0, 1),
    Param(107, 0x05, 3, True, 0, 255), Param(730, 0x05, 3, True, 0, 1), Param(1000, 0x03, 1, True, -2000, 2000),
    Param(1001, 0x08, 3, True, -3000, 3000), Param(1082, 0x08, 1, True, 0, 3000),
    Param(1120, 0x08, 1, True, 0, 100), Param(1121, 0x08, 1, True, 0, 100), Param(1300, 0x06, 1, True, 0, 21),
    Param(2000, 0x08, 1, True, 6, 3000), Param(2001, 0x43, 2, True, 0, 1 << 31),
)  # fmt: skip
BY_PNU: Final = {p.pnu: p for p in PARAMS}
WRITABLE: Final = tuple(p for p in PARAMS if p.writable)
MISSING_PNU: Final = 61000  # a PNU no drive of the plant has: answered error 0x00
# Error numbers that name the faulty element (a second error value, protocol.md 4.5)
WITH_SUBINDEX: Final = frozenset({0x01, 0x02, 0x03, 0x06, 0x07, 0x14})
CHANGE_ERRORS: Final = (0x02, 0x11, 0x14, 0x6B)  # limit, operating state, impermissible, SINAMICS "enabled"

Address = tuple[Param, int, int]  # parameter, first subindex, elements
Row = list  # [pnu, subindex, error, whole_request]: one row of the parameters table


def _value(p: Param, rng: random.Random) -> float | int:
    if p.fmt == 0x08:
        return round(rng.uniform(p.low, p.high), 2)
    return rng.randint(int(p.low), int(p.high))


@dataclass
class Drive:
    """The parameter values of one drive, per (slot, DO), created on first use."""

    seed: int
    values: dict[tuple[int, int, int], list[float | int]] = field(default_factory=dict)

    def get(self, axis: tuple[int, int], p: Param) -> list[float | int]:
        key = (*axis, p.pnu)
        if key not in self.values:
            rng = random.Random(f"{self.seed} {key}")
            self.values[key] = [_value(p, rng) for _ in range(p.elements)]
        return self.values[key]


def addresses(rng: random.Random, count: int, *, writable: bool = False) -> list[Address]:
    """`count` distinct parameters, each a single element or a run of an array's elements."""
    pool = WRITABLE if writable else PARAMS
    out = []
    for p in rng.sample(pool, min(count, len(pool))):
        first = rng.randrange(p.elements) if p.elements > 1 else 0
        out.append((p, first, rng.randint(1, p.elements - first)))
    return out


def address(a: Address, **kw: int) -> P:
    p, first, n = a
    return P(p.pnu, subindex=first, n_elems=n, **kw)


def read_request(ref: int, do: int, addrs: Sequence[Address]) -> bytes:
    return pd_request(ref, 0x01, do, [address(a) for a in addrs])


def read_answer(drive: Drive, axis: tuple[int, int], ref: int, do: int, addrs: Sequence[Address]) -> bytes:
    blocks = [value_block(p.fmt, drive.get(axis, p)[first:first + n]) for p, first, n in addrs]
    return pd_response(ref, 0x01, do, blocks)


def change(drive: Drive, axis: tuple[int, int], ref: int, do: int, addrs: Sequence[Address],
           rng: random.Random) -> tuple[bytes, list[list[float | int]]]:
    """A change request of new values, and the values (applied by `apply` once the drive accepted them)."""
    new = [[_value(p, rng) for _ in range(n)] for p, _, n in addrs]
    blocks = [value_block(p.fmt, vals) for (p, _, _), vals in zip(addrs, new, strict=True)]
    return pd_request(ref, 0x02, do, [address(a) for a in addrs], blocks), new


def apply(drive: Drive, axis: tuple[int, int], addrs: Sequence[Address], new: Sequence[Sequence[float | int]],
          written: Sequence[bool] | None = None) -> None:
    for k, ((p, first, n), vals) in enumerate(zip(addrs, new, strict=True)):
        if written is None or written[k]:
            drive.get(axis, p)[first:first + n] = list(vals)


def change_answer(ref: int, do: int, n: int) -> bytes:
    return change_ok(ref, do, n)


def _error(err: int, sub: int) -> bytes:
    return error_block(err, sub if err in WITH_SUBINDEX else None)


def nak_read(drive: Drive, axis: tuple[int, int], ref: int, do: int, rng: random.Random
             ) -> tuple[bytes, bytes, list[Row]]:
    """A read of 1-4 parameters of which at least one fails: a PNU the drive lacks (0x00) or a subindex
    beyond the array (0x03 with the subindex); answered 0x81, values for the others."""
    addrs = addresses(rng, rng.randint(1, 4))
    bad = set(rng.sample(range(len(addrs)), rng.randint(1, len(addrs))))
    items, blocks, rows = [], [], []
    for k, (p, first, n) in enumerate(addrs):
        if k in bad and p.elements > 1 and rng.random() < 0.5:
            sub = p.elements + rng.randrange(3)
            items.append(P(p.pnu, subindex=sub))
            blocks.append(_error(0x03, sub))
            rows.append([p.pnu, sub, 0x03, False])
        elif k in bad:
            items.append(P(MISSING_PNU + k))
            blocks.append(_error(0x00, 0))
            rows.append([MISSING_PNU + k, 0, 0x00, False])
        else:
            items.append(P(p.pnu, subindex=first, n_elems=n))
            blocks.append(value_block(p.fmt, drive.get(axis, p)[first:first + n]))
            rows.append([p.pnu, first, None, False])
    return pd_request(ref, 0x01, do, items), pd_response(ref, 0x81, do, blocks), rows


def nak_change(drive: Drive, axis: tuple[int, int], ref: int, do: int, rng: random.Random
               ) -> tuple[bytes, bytes, list[Row]]:
    """A change of 1-3 parameters of which at least one is refused (read-only 0x01, or a limit, operating
    state, impermissible value or manufacturer error); answered 0x82, the others written (0x40 Zero)."""
    addrs = addresses(rng, rng.randint(1, 3))
    bad = set(rng.sample(range(len(addrs)), rng.randint(1, len(addrs))))
    new = [[_value(p, rng) for _ in range(n)] for p, _, n in addrs]
    blocks, rows, written = [], [], []
    for k, (p, first, _) in enumerate(addrs):
        err = 0x01 if not p.writable else rng.choice(CHANGE_ERRORS) if k in bad else None
        blocks.append(zero_block() if err is None else _error(err, first))
        rows.append([p.pnu, first, err, False])
        written.append(err is None and p.writable)
    vals = [value_block(p.fmt, v) for (p, _, _), v in zip(addrs, new, strict=True)]
    request = pd_request(ref, 0x02, do, [address(a) for a in addrs], vals)
    apply(drive, axis, addrs, new, written)
    return request, pd_response(ref, 0x82, do, blocks), rows


def nak_whole(ref: int, do: int, rng: random.Random) -> tuple[bytes, bytes, list[Row]]:
    """A request of 2-4 parameters refused as a whole with one error block (protocol.md 3.3): 0x23 (multi-
    parameter access not supported) or 0x19 (no such DO); No. of parameters still mirrors the request."""
    addrs = addresses(rng, rng.randint(2, 4))
    err = rng.choice((0x19, 0x23))
    request = read_request(ref, do, addrs)
    answer = pd_response(ref, 0x81, do, [_error(err, 0)], n_params=len(addrs))
    return request, answer, [[p.pnu, first, err, True] for p, first, _ in addrs]


# --- header fields out of the profile's range (P2, protocol.md 5.2 and 6.3) ----------------------------------
OUT_OF_RANGE: Final = ("ref0", "n0", "n40", "attribute", "elements")


def out_of_range(kind: str, drive: Drive, axis: tuple[int, int], ref: int, do: int, rng: random.Random
                 ) -> tuple[bytes, bytes | None, list[Row]]:
    """A request with one header field outside the profile, and the drive's answer (None: the write is
    refused with DF80B100, the request being longer than 240 bytes)."""
    if kind == "ref0":  # reference 0 (reserved), mirrored in an ordinary answer
        addrs = addresses(rng, rng.randint(1, 3))
        return read_request(0, do, addrs), read_answer(drive, axis, 0, do, addrs), []
    if kind == "n0":  # no parameter at all: refused as a whole, 0x16
        return (pd_request(ref, 0x01, do, []), pd_response(ref, 0x81, do, [_error(0x16, 0)], n_params=0),
                [[None, None, 0x16, True]])
    if kind == "n40":  # 40 addresses: one over the limit, 244 bytes (also H13)
        items = [P(p.pnu) for p in PARAMS] * 3
        return pd_request(ref, 0x01, do, items[:40]), None, []
    addrs = addresses(rng, rng.randint(1, 3))
    bad = rng.randrange(len(addrs))
    items, blocks, rows = [], [], []
    for k, a in enumerate(addrs):
        p, first, n = a
        if k != bad:
            items.append(address(a))
            blocks.append(value_block(p.fmt, drive.get(axis, p)[first:first + n]))
            rows.append([p.pnu, first, None, False])
        elif kind == "attribute":  # reserved attribute: parameter address impermissible
            items.append(address(a, attr=rng.choice((0x00, 0x40, 0x70))))
            blocks.append(_error(0x16, 0))
            rows.append([p.pnu, first, 0x16, False])
        else:  # more than 234 elements
            items.append(P(p.pnu, subindex=first, n_elems=rng.randint(235, 255)))
            blocks.append(_error(0x16, 0))
            rows.append([p.pnu, first, 0x16, False])
    return pd_request(ref, 0x01, do, items), pd_response(ref, 0x81, do, blocks), rows


# --- structurally broken requests (protocol.md 7.4 rule 1) ----------------------------------------------------
BROKEN: Final = ("block_overrun", "change_blocks", "format_unsupported_stop", "block_length")


def broken(kind: str, ref: int, do: int, rng: random.Random) -> tuple[bytes, dict[str, int]]:
    """A change request that cannot be parsed (the finding named `kind` at its frame), and IOD header
    overrides for the write (BlockLength not 60 for "block_length")."""
    addrs = addresses(rng, 2, writable=True)
    items = [address(a) for a in addrs]
    blocks = [value_block(p.fmt, [_value(p, rng) for _ in range(n)]) for p, _, n in addrs]
    if kind == "block_overrun":  # the last block claims more values than the record holds
        p, _, n = addrs[-1]
        blocks[-1] = value_block(p.fmt, [_value(p, rng) for _ in range(n)], n_values=n + 8)
    elif kind == "change_blocks":  # one value block for two addresses
        blocks = blocks[:1]
    elif kind == "format_unsupported_stop":  # a format of no known size before the last block
        blocks[0] = bytes([0x0B, 1, 0, 0])
    return pd_request(ref, 0x02, do, items, blocks), ({"block_length": 56} if kind == "block_length" else {})
