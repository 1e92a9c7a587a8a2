"""The parameter state checked against an intended parameter set (`pd-analyze audit --expect SET.csv`).

The set is a CSV file with a header row and the columns `device,do,pnu,subindex,value` (device: an IPv4
address, or `*` for every device of the capture; value: a number, or the text of a string parameter) and
optionally `tolerance` (absolute, for numbers). Blank lines and lines starting with `#` are skipped. A
line that names a device overrides a `*` line for the same DO, PNU and subindex.

Each intended element gets at most one finding (rules S1-S5 of model/rules.py), at the frame of the last
write or read that decides it:

- `expect_refused` (E): every write was refused; the message gives the error and the value read back, if any;
- `expect_unconfirmed` (W): the last write ended without a parameter response and nothing read it back;
- `expect_mismatch` (E): the value the capture last saw (confirmed written or read back) is not the
  intended one, compared in the format seen on the wire (analysis.param_values);
- `expect_missing` (W): never written or read; reported at the set's file and line.

`strict` adds `unexpected_write` (I) for every element written that the set does not list.
"""

from __future__ import annotations

import csv
import io
import ipaddress
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

from pd_analyze.analysis.param_state import ElementState, Key, Seen, StateTable
from pd_analyze.analysis.param_values import NotAValueError, parse_int, same, wire
from pd_analyze.model.files import open_problem
from pd_analyze.model.rules import Finding, finding

if TYPE_CHECKING:
    import pandas as pd

REQUIRED = ("device", "do", "pnu", "subindex", "value")
OPTIONAL = ("tolerance",)
ANY_DEVICE = "*"
_RANGES = {"do": 255, "pnu": 65535, "subindex": 65535}


class ExpectError(ValueError):
    """A malformed intended set: the message names the file and line."""


@dataclass(frozen=True, slots=True)
class Expected:
    """One line of the intended set."""

    line: int
    device: str  # an IPv4 address, or ANY_DEVICE
    do: int
    pnu: int
    subindex: int
    value: str
    tolerance: float = 0.0

    @property
    def label(self) -> str:
        return f"P{self.pnu}[{self.subindex}]"


@dataclass(frozen=True, slots=True)
class ExpectedSet:
    path: str
    lines: tuple[Expected, ...]


def load(path: str) -> ExpectedSet:
    """Read and check an intended set (ExpectError names the line of the first problem)."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as exc:
        raise ExpectError(f"{path}: {open_problem(exc)}") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise ExpectError(f"{path}:{line}: not UTF-8 text") from None
    return ExpectedSet(path, tuple(parse(text, path)))


def parse(text: str, name: str = "EXPECTED.csv") -> list[Expected]:
    """The lines of an intended set given as text (`name` for the messages)."""
    reader = csv.reader(io.StringIO(text, newline=""))
    header: list[str] | None = None
    out: list[Expected] = []
    seen: dict[tuple, int] = {}
    try:
        for cells in reader:
            line = reader.line_num
            if not any(c.strip() for c in cells) or cells[0].lstrip().startswith("#"):
                continue
            if header is None:
                header = _header(cells, name, line)
                continue
            item = _line(cells, header, name, line)
            key = (item.device, item.do, item.pnu, item.subindex)
            if key in seen:
                raise ExpectError(f"{name}:{line}: {item.label} of {item.device} DO {item.do} is already on line "
                                  f"{seen[key]}")
            seen[key] = line
            out.append(item)
    except csv.Error as exc:
        raise ExpectError(f"{name}:{reader.line_num}: {exc}") from None
    if header is None:
        raise ExpectError(f"{name}:1: no header row (expected {','.join(REQUIRED)}[,tolerance])")
    return out


def _header(cells: list[str], name: str, line: int) -> list[str]:
    cols = [c.strip().lower() for c in cells]
    for c in cols:
        if c not in REQUIRED and c not in OPTIONAL:
            raise ExpectError(f"{name}:{line}: unknown column {c!r} (the columns are {', '.join(REQUIRED + OPTIONAL)})")
        if cols.count(c) > 1:
            raise ExpectError(f"{name}:{line}: column {c!r} given twice")
    missing = [c for c in REQUIRED if c not in cols]
    if missing:
        raise ExpectError(f"{name}:{line}: the header lacks {', '.join(missing)} (expected "
                          f"{','.join(REQUIRED)}[,tolerance])")
    return cols


def _line(cells: list[str], header: list[str], name: str, line: int) -> Expected:
    if len(cells) > len(header) and any(c.strip() for c in cells[len(header):]):
        raise ExpectError(f"{name}:{line}: {len(cells)} fields, the header has {len(header)}")
    if any(c in REQUIRED for c in header[len(cells):]):  # (an optional column at the end may be left out)
        raise ExpectError(f"{name}:{line}: {len(cells)} fields, the header has {len(header)}")
    cell = dict(zip(header, cells, strict=False))
    where = f"{name}:{line}"
    device = cell["device"].strip()
    if device != ANY_DEVICE:
        try:
            device = str(ipaddress.IPv4Address(device))
        except ValueError:
            raise ExpectError(f"{where}: device {device!r} is neither an IPv4 address nor *") from None
    numbers = {}
    for col, top in _RANGES.items():
        text = cell[col].strip()
        try:
            numbers[col] = parse_int(text)
        except NotAValueError:
            numbers[col] = -1
        if not 0 <= numbers[col] <= top or "." in text:
            raise ExpectError(f"{where}: {col} {text!r} is not a whole number from 0 to {top}")
    value = cell["value"]
    if not value.strip():
        raise ExpectError(f"{where}: value is empty")
    if _is_nan(value):  # a NaN equals no value, itself included: every check of it would be a mismatch
        raise ExpectError(f"{where}: value {value.strip()!r} cannot be intended: NaN equals no value, not even NaN "
                          "(give the number meant)")
    tolerance = 0.0
    text = cell.get("tolerance", "").strip()
    if text:
        try:
            tolerance = float(text)
        except ValueError:
            tolerance = -1.0
        if not math.isfinite(tolerance) or tolerance < 0:
            raise ExpectError(f"{where}: tolerance {text!r} is not a number >= 0")
    return Expected(line, device, numbers["do"], numbers["pnu"], numbers["subindex"], value, tolerance)


def _is_nan(text: str) -> bool:
    try:
        return math.isnan(float(text))
    except ValueError:
        return False


# --- the check ----------------------------------------------------------------------------------------------

def targets(expected: ExpectedSet, state: StateTable) -> list[tuple[Expected, str]]:
    """(line, device) pairs to check: a `*` line for every device of the state, unless a line names it."""
    devices = sorted({k[0] for k in state.elements})
    named = {(e.device, e.do, e.pnu, e.subindex) for e in expected.lines if e.device != ANY_DEVICE}
    out = []
    for e in expected.lines:
        if e.device != ANY_DEVICE:
            out.append((e, e.device))
            continue
        mine = [d for d in devices if (d, e.do, e.pnu, e.subindex) not in named]
        out += [(e, d) for d in mine] if devices else [(e, ANY_DEVICE)]
    return out


class Outcome(NamedTuple):
    """The check of one intended element: `result` is "as intended" or the name of its finding."""

    key: Key
    line: Expected
    result: str
    message: str


AS_INTENDED = "as intended"


def outcomes(expected: ExpectedSet, state: StateTable) -> list[Outcome]:
    """Every intended element of every device with its result (the HTML report's expected-set columns)."""
    out = []
    for e, device in targets(expected, state):
        key = (device, e.do, e.pnu, e.subindex)
        found = _check_one(expected.path, e, key, state.elements.get(key))
        out.append(Outcome(key, e, found[1].name, found[1].message) if found else Outcome(key, e, AS_INTENDED, ""))
    return out


def check(expected: ExpectedSet, state: StateTable, strict: bool = False) -> list[tuple[str, Finding]]:
    """(capture, finding) per element that is not as intended; a missing one's capture is the set's file and
    its frame the set's line. Ordered: findings in captures by capture and frame, then the missing ones."""
    out = []
    listed: set[Key] = set()
    for e, device in targets(expected, state):
        key = (device, e.do, e.pnu, e.subindex)
        listed.add(key)
        found = _check_one(expected.path, e, key, state.elements.get(key))
        if found is not None:
            out.append(found)
    if strict:
        out += _unexpected(expected.path, state, listed)
    from pd_analyze.analysis.schema import RULE_RANK

    missing = [x for x in out if x[1].name == "expect_missing"]
    found = [x for x in out if x[1].name != "expect_missing"]
    found.sort(key=lambda x: (x[0], x[1].frame, RULE_RANK[x[1].name]))
    missing.sort(key=lambda x: x[1].frame)
    return found + missing


def _where(key: Key) -> str:
    device, do, pnu, sub = key
    return f"P{pnu}[{sub}] of {device} DO {do}"


def _check_one(path: str, e: Expected, key: Key, st: ElementState | None) -> tuple[str, Finding] | None:
    source = f"{path}, line {e.line}"
    want = e.value + (f" +- {e.tolerance:g}" if e.tolerance else "")
    if st is None:
        return path, finding("expect_missing", e.line, "value", "", want,
                             f"{_where(key)}: intended {e.value}, never written or read in the capture", source)
    read = f"; read back {st.read.value} (frame {st.read.frame})" if st.read is not None else "; not read back"
    if st.writes and st.n_refused == st.writes:
        ref = st.refused or Seen((0, 0), None, "", path, None, None)  # (a refused write always has one)
        return ref.capture, finding(
            "expect_refused", ref.frame or 0, "value", ref.value or "", want,
            f"{_where(key)}: every write refused ({st.n_refused} of {st.writes}), last error {ref.note}; intended "
            f"{e.value}{read}", source)
    last = st.last
    unconf = st.unconfirmed
    if unconf is not None and (last is None or unconf.order > last.order):
        return unconf.capture, finding(
            "expect_unconfirmed", unconf.frame or 0, "value", unconf.value or "", want,
            f"{_where(key)}: {unconf.value} written but not confirmed (the transaction ended {unconf.note}) and "
            f"not read back after it; intended {e.value}", source)
    if last is None:
        return None  # only refused and unconfirmed writes: handled above
    try:
        intended = wire(last.fmt, e.value)
    except NotAValueError as exc:
        return _mismatch(key, e, last, st, want, source, f" ({exc})")
    if last.value is not None and same(last.fmt, last.value, intended, e.tolerance):
        return None
    return _mismatch(key, e, last, st, want, source, "")


def _mismatch(key: Key, e: Expected, last: Seen, st: ElementState, want: str, source: str,
              why: str) -> tuple[str, Finding]:
    how = "read back" if last is st.read else "confirmed written"
    return last.capture, finding(
        "expect_mismatch", last.frame or 0, "value", last.value or "", want,
        f"{_where(key)}: intended {e.value}{why}, {how} {last.value} ({last.fmt}, frame {last.frame})", source)


def _unexpected(path: str, state: StateTable, listed: Iterable[Key]) -> list[tuple[str, Finding]]:
    listed = set(listed)
    out = []
    for key in state.ordered():
        st = state.elements[key]
        if not st.writes or key in listed:
            continue
        tries = [s for s in (st.written, st.refused, st.unconfirmed) if s is not None]
        last = max(tries, key=lambda s: s.order)
        out.append((last.capture, finding(
            "unexpected_write", last.frame or 0, "value", last.value or "", "",
            f"{_where(key)}: written {_times(st.writes)}, last {last.value}; not in the intended set", path)))
    return out


def _times(n: int) -> str:
    return "once" if n == 1 else f"{n} times"


def finding_rows(found: list[tuple[str, Finding]]) -> list[tuple]:
    """The findings as rows of the findings table (no transaction)."""
    from pd_analyze.analysis.rows import finding_row

    return [finding_row(capture, f, None) for capture, f in found]


def findings_frame(found: list[tuple[str, Finding]]) -> pd.DataFrame:
    """The findings as a typed findings table, in check()'s order (a missing one's frame is a line number)."""
    import pandas as pd

    from pd_analyze.analysis.schema import COLUMNS, pandas_dtype

    df = pd.DataFrame.from_records(finding_rows(found), columns=[c.name for c in COLUMNS["findings"]])
    return df.astype({c.name: pandas_dtype(c) for c in COLUMNS["findings"]})
