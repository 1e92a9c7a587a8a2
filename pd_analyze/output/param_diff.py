"""`pd-analyze diff A B`: the parameter state of one capture against another's.

`by="device"` compares each drive with the same drive (device IP, DO, PNU, subindex: before and after);
`by="do"` compares drives that should be alike (DO, PNU, subindex), a drive of A with a drive of B: the one drive
of each side, or, where a side holds several, the drives that announced the same PN-DCP station name, or the
pairs given (`pairs`: each drive by its address or station name). One row per element whose value differs (in the
wire format, analysis.param_values), that one side lacks, or whose last write was refused, or left unconfirmed, on
one side only.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

from pd_analyze.analysis.param_state import ElementState, Key, StateTable, device_order
from pd_analyze.analysis.param_values import cells_agree
from pd_analyze.analysis.schema import Column
from pd_analyze.output.param_tables import aligned, csv_text, json_text

BY = ("device", "do")
DIFF_COLUMNS: tuple[Column, ...] = tuple(Column(*c) for c in (
    ("device_a", "category", "the drive in A"), ("device_b", "category", "the drive in B"),
    ("do", "Int64", "DO-ID"), ("pnu", "Int64", "parameter number"), ("subindex", "Int64", "array element"),
    ("param", "string", "P<pnu>[<subindex>]"), ("name", "string", "profile parameter name, empty when unknown"),
    ("difference", "string", "differs, only in A, only in B, refused in A/B, unconfirmed in A/B"),
    ("status_a", "string", "ok, refused, unconfirmed or missing: how the last write ended in A (ok: no write)"),
    ("format_a", "string", "data type in A"),
    ("value_a", "string", "the value A last saw (confirmed or read back); with none, the value last tried"),
    ("error_a", "string", "the last refused write's error in A"),
    ("status_b", "string", "the same for B"), ("format_b", "string", "data type in B"),
    ("value_b", "string", "the value B last saw"), ("error_b", "string", "the last refused write's error in B"),
))


class DiffError(ValueError):
    """The two sides cannot be compared as asked (e.g. --by do with several drives on one side)."""


class Side(NamedTuple):
    status: str
    fmt: str
    value: str | None
    error: str


MISSING = Side("missing", "", None, "")


def side_of(st: ElementState | None) -> Side:
    if st is None:
        return MISSING
    tries = [(s.order, what) for s, what in ((st.written, "ok"), (st.refused, "refused"),
                                               (st.unconfirmed, "unconfirmed")) if s is not None]
    status = max(tries)[1] if tries else "ok"
    # the value last seen; with none (every write refused or unconfirmed), the value last tried
    last = st.last or max((s for s in (st.refused, st.unconfirmed) if s is not None), key=lambda s: s.order,
                          default=None)
    error = st.refused.note if st.refused is not None else ""
    return Side(status, last.fmt if last else "", last.value if last else None, error)


def _kind(a: Side, b: Side) -> str:
    """The difference between two sides, empty when they agree."""
    if a is MISSING or b is MISSING:
        return "only in B" if a is MISSING else "only in A"
    if a.status != b.status:
        return ", ".join(f"{side.status} in {n}" for n, side in (("A", a), ("B", b)) if side.status != "ok")
    if not cells_agree(a.fmt, a.value, b.fmt, b.value):
        return "differs"
    return ""


def _devices(state: StateTable) -> list[str]:
    return sorted({k[0] for k in state.elements}, key=device_order)


def _drive(state: StateTable, given: str, side: str) -> str:
    """The drive of a side a --pair names: its address, or the station name it announced."""
    devices = _devices(state)
    if given in devices:
        return given
    named = [d for d in devices if state.stations.get(d) == given]
    if len(named) != 1:
        raise DiffError(f"--pair: {side} holds no drive {given!r} (its drives: {_listed(state)})" if not named else
                        f"--pair: {given!r} names {len(named)} drives of {side} ({', '.join(named)}); give the address")
    return named[0]


def _listed(state: StateTable) -> str:
    return ", ".join(f"{d} ({state.stations[d]})" if state.stations.get(d) else d for d in _devices(state)) or "none"


def drive_pairs(a: StateTable, b: StateTable, pairs: Sequence[tuple[str, str]] = ()) -> list[tuple[str, str]]:
    """The drives --by do compares, (A's, B's): the pairs given; else the one drive of each side; else the drives of
    A and B that announced the same station name, every drive of both sides paired. DiffError says which drives
    are left without a partner and how to name the pairs."""
    if pairs:
        return [(_drive(a, pa, "A"), _drive(b, pb, "B")) for pa, pb in pairs]
    devs_a, devs_b = _devices(a), _devices(b)
    if len(devs_a) <= 1 and len(devs_b) <= 1:
        return [(devs_a[0] if devs_a else "", devs_b[0] if devs_b else "")]
    by_name_b = {}
    for d in devs_b:
        by_name_b.setdefault(b.stations.get(d, ""), []).append(d)
    found, alone = [], []
    for d in devs_a:
        partners = by_name_b.get(a.stations.get(d, ""), []) if a.stations.get(d) else []
        if len(partners) == 1 and [x for x in devs_a if a.stations.get(x) == a.stations[d]] == [d]:
            found.append((d, partners[0]))
        else:
            alone.append(f"A's {d}")
    alone += [f"B's {d}" for d in devs_b if d not in {pb for _, pb in found}]
    if alone:
        raise DiffError(f"--by do pairs the drives of A and B by the station name each announced, but "
                        f"{', '.join(alone)} {'has' if len(alone) == 1 else 'have'} no partner of that name "
                        f"(A: {_listed(a)}; B: {_listed(b)}); name the pairs with --pair A_DRIVE=B_DRIVE (address "
                        "or station name), or use --by device")
    return found


def _keyed(state: StateTable, by: str, drives: Sequence[str]) -> dict[tuple, Key]:
    """The state's elements by the comparison key: the element itself (--by device), or the pair's number, DO,
    PNU and subindex of the paired drives' elements (--by do)."""
    if by == "device":
        return {k: k for k in state.elements}
    pair = {d: i for i, d in enumerate(drives)}
    return {(pair[k[0]], *k[1:]): k for k in state.elements if k[0] in pair}


def diff_rows(a: StateTable, b: StateTable, by: str = "device", pairs: Sequence[tuple[str, str]] = ()) -> list[tuple]:
    """The rows of DIFF_COLUMNS, ordered by device (A's, else B's), DO, PNU, subindex."""
    if by == "device" and pairs:
        raise DiffError("--pair names the drives --by do compares; --by device compares each drive with itself")
    paired = drive_pairs(a, b, pairs) if by == "do" else []
    ka = _keyed(a, by, [pa for pa, _ in paired])
    kb = _keyed(b, by, [pb for _, pb in paired])
    rows = []
    for key in set(ka) | set(kb):
        sa = side_of(a.elements.get(ka[key])) if key in ka else MISSING
        sb = side_of(b.elements.get(kb[key])) if key in kb else MISSING
        kind = _kind(sa, sb)
        if not kind:
            continue
        full = ka.get(key) or kb[key]
        _, do, pnu, sub = full
        if by == "device":
            device_a = device_b = full[0]
        else:
            device_a, device_b = paired[key[0]]
        rows.append((device_a, device_b, do, pnu, sub, f"P{pnu}[{sub}]", a.names.pnu(pnu), kind, *sa, *sb))
    return sorted(rows, key=lambda r: (device_order(r[0] or r[1]), r[2], r[3], r[4]))


def _shown(status: str, value: str | None, error: str) -> str:
    if status == "missing":
        return "-"
    text = value if value is not None else "(no value)"
    if status == "refused":  # the error's number; its text is in the CSV and JSON
        return f"{text}; refused {error.split(' ', 1)[0]}"
    return f"{text}; {status}" if status != "ok" else text


def diff_text(rows: Sequence[tuple], by: str) -> list[str]:
    headings = ["device" if by == "device" else "device A / B", "DO", "parameter", "difference", "A", "B"]
    return aligned(headings, ([r[0] if by == "device" else f"{r[0]} / {r[1]}", r[2], r[5], r[7],
                               _shown(r[8], r[10], r[11]), _shown(r[12], r[14], r[15])] for r in rows))


def diff_formatted(rows: Sequence[tuple], fmt: str) -> str:
    return csv_text(DIFF_COLUMNS, rows) if fmt == "csv" else json_text(DIFF_COLUMNS, rows)
