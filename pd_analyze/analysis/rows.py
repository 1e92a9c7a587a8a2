"""Closed transactions to rows of the four tidy tables: transactions, parameters, findings, changes.

Columns are declared once here (name, dtype, description); the DataFrames, the streamed report files
and `pd-analyze fields --tables` read the declaration. Rows are plain tuples; pandas is imported only
when a DataFrame is built (`frame_of`), never in the per-frame loop nor on the CSV/JSON report path.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from pd_analyze.analysis.transactions import PART_MARK, LastDone, Transaction, param_label, reuse_finding
from pd_analyze.model import pd_values as pt
from pd_analyze.model.rules import SEVERITIES, Finding
from pd_analyze.model.verdicts import ANSWERED, VERDICTS
from pd_analyze.protocol.link import ip_text
from pd_analyze.protocol.profidrive import Block, values_of

if TYPE_CHECKING:
    import pandas as pd

VERDICT = "category:verdict"  # categoricals with fixed categories (the same in every chunk and file)
SEVERITY = "category:severity"
FIXED_CATEGORIES = {VERDICT: (VERDICTS, False), SEVERITY: (SEVERITIES, True)}
TIME = "datetime64[ns, UTC]"
MAX_TIME_SECONDS = 9.2e9  # datetime64[ns] spans 1677 ... 2262


@dataclass(frozen=True, slots=True)
class Column:
    name: str
    dtype: str  # a pandas dtype name, or VERDICT / SEVERITY
    description: str


def _cols(*cols: tuple[str, str, str]) -> tuple[Column, ...]:
    return tuple(Column(*c) for c in cols)


COLUMNS: Mapping[str, tuple[Column, ...]] = MappingProxyType({
    "transactions": _cols(
        ("txn", "Int64", "transaction number, 1, 2, ... in the order of the write request frames"),
        ("capture", "category", "capture file"),
        ("device", "category", "device (drive) IP address"),
        ("controller", "category", "controller (PLC) IP address"),
        ("ar", "string", "ARUUID of the channel"),
        ("index", "category", "record index (0xb02e, 0xb02f, 0x002f)"),
        ("api", "Int64", "API"), ("slot", "Int64", "slot"), ("subslot", "Int64", "subslot"),
        ("ref", "Int64", "Request Reference"), ("req_id", "category", "Request ID"),
        ("do", "Int64", "DO-ID"), ("n_params", "Int64", "No. of parameters"),
        ("params", "string", "parameters addressed, e.g. P964[0] P2000[0..2]"),
        ("resp_id", "category", "Response ID"),
        ("verdict", VERDICT, "malformed, pnio_error, timeout, reference_mismatch, nak or ok"),
        ("errors", "string", "PROFIdrive errors per parameter, e.g. P964[0]:0x02"),
        ("pnio_status", "string", "PNIOStatus that closed the transaction (8 hex digits), empty when none"),
        ("b5_retries", "Int64", "reads answered B5 (state conflict: not ready)"),
        ("reads", "Int64", "read calls"),
        ("rpc_retransmissions", "Int64", "duplicate request PDUs"),
        ("write_req_frame", "Int64", "frame of the write request"),
        ("write_res_frame", "Int64", "frame of the write response"),
        ("read_req_frames", "string", "frames of the read requests"),
        ("read_res_frame", "Int64", "frame of the final read response"),
        ("frames", "string", "every frame of the transaction (requests, responses, B5 answers)"),
        ("t_start", TIME, "time of the write request"),
        ("t_write_rtt", "Float64", "seconds from write request to write response"),
        ("t_total", "Float64", "seconds from write request to the final read response"),
        ("t_final_read_rtt", "Float64", "seconds from the final read request to its response"),
        ("t_first_read_gap", "Float64", "seconds from write response to the first read request"),
        ("capture_ended", "boolean", "still open when the capture ended"),
        ("closed_by", "category", "response, pnio_error, deadline, superseded, capture_end or evicted"),
    ),
    "parameters": _cols(
        ("txn", "Int64", "transaction"), ("capture", "category", "capture file"),
        ("device", "category", "device IP address"), ("do", "Int64", "DO-ID"),
        ("param", "string", "P<pnu>[<subindex>..]"), ("pnu", "Int64", "parameter number"),
        ("subindex", "Int64", "first subindex"), ("elements", "Int64", "No. of elements"),
        ("attribute", "category", "Value, Description or Text"), ("format", "category", "data type"),
        ("values_written", "string", "values of a change request"),
        ("values_read", "string", "values of the response"),
        ("error", "string", "PROFIdrive error number (0x..), empty when none"),
        ("error_text", "string", "meaning of the error number"),
    ),
    "findings": _cols(
        ("capture", "category", "capture file"), ("frame", "Int64", "frame number"),
        ("txn", "Int64", "transaction, empty when the frame belongs to none"),
        ("severity", SEVERITY, "info, warning or error"), ("rule", "category", "rule id (protocol.md 6)"),
        ("name", "category", "rule name"), ("field", "string", "field name (pd-analyze fields)"),
        ("value", "string", "observed value"), ("expected", "string", "expected value or range"),
        ("source", "string", "document the limit comes from"), ("message", "string", "one-line message"),
    ),
    "changes": _cols(
        ("capture", "category", "capture file"), ("device", "category", "device IP address"),
        ("do", "Int64", "DO-ID"), ("txn", "Int64", "transaction"), ("frame", "Int64", "write request frame"),
        ("t", TIME, "time of the change request"), ("param", "string", "P<pnu>[<subindex>..]"),
        ("pnu", "Int64", "parameter number"), ("subindex", "Int64", "first subindex"),
        ("value_written", "string", "values written"),
        ("result", "string", "ok, the PROFIdrive error, or the transaction verdict"),
        ("value_before", "string", "last value read earlier in the capture, empty when unknown"),
    ),
})


def block_values(block: Block | None, values: list | None = None) -> str:
    """Values of a value block as one text cell (strings quoted, scaled types raw); `values`: its
    values_of, when the caller has them already."""
    if block is None or block.is_error or block.format in (pt.FMT_ZERO, pt.FMT_AKD_ZERO):
        return ""
    values = values_of(block) if values is None else values
    if pt.FORMATS.get(block.format, pt.FORMATS[0x41]).kind in ("hex", "bits", "nibbles"):
        return " ".join(f"0x{v:0{2 * block.size}x}" for _, _, v, _ in values if isinstance(v, int))
    return " ".join(_cell(value) for _, _, value, _ in values)


def _cell(value: object) -> str:
    if isinstance(value, str):
        return repr(value) if not value.isprintable() else value if " " not in value else f'"{value}"'
    if isinstance(value, float):
        return f"{value:.7g}"
    return str(value)


def _hex(value: int) -> str:
    return f"0x{value:02x}" if value >= 0 else ""


_CHANNEL_CACHE = 65536  # channels whose text cells are remembered (a flood of new channels only clears it)


@dataclass(slots=True)
class Rows:
    """Rows of the four tables for one or more captures.

    The four attributes are lists for `analyze()`; the streaming report puts spools there instead
    (anything with `append` and `extend`), so the same code builds the rows for both.
    """

    transactions: list[tuple] = field(default_factory=list)
    parameters: list[tuple] = field(default_factory=list)
    findings: list[tuple] = field(default_factory=list)
    changes: list[tuple] = field(default_factory=list)
    _last_read: dict[tuple, str] = field(default_factory=dict)
    _channels: dict[tuple, tuple[str, str, str, str]] = field(default_factory=dict)
    # A part of a split capture (`split_end`: its range ends before that frame; 0 = not a part) cannot
    # see reads before its lead-in: it lists the changes whose value_before it does not know, and the
    # last value read per element with the frame that closed the read, for the parent to stitch.
    split_end: int | None = 0
    unresolved: list[tuple[int, list[tuple], list[str | None]]] = field(default_factory=list)
    reads: dict[tuple, tuple[int, str]] = field(default_factory=dict)
    # Likewise for T1: where a Request Reference check waits for the channel's last transaction
    # (findings index, capture, channel, ref, frame, txn), and each channel's last transaction here.
    reuse_slots: list[tuple[int, str, tuple, int, int, int]] = field(default_factory=list)
    channel_last: dict[tuple, tuple[int, int, str]] = field(default_factory=dict)

    def new_capture(self) -> None:
        """The next rows come from a capture analysed on its own: forget the values read so far."""
        self._last_read.clear()

    def extend(self, other: Rows, offset: int) -> None:
        """Append another capture's rows, its transaction numbers shifted by `offset`."""
        def shift(rows: list[tuple], col: int) -> list[tuple]:
            if not offset:
                return rows
            return [r[:col] + ((r[col] + offset if r[col] is not None else None),) + r[col + 1:] for r in rows]

        self.transactions.extend(shift(other.transactions, 0))
        self.parameters.extend(shift(other.parameters, 0))
        self.findings.extend(shift(other.findings, 2))
        self.changes.extend(shift(other.changes, 3))

    def _channel(self, v: tuple) -> tuple[str, str, str, str]:
        """device, controller, ARUUID and index of a channel as text (the same few channels recur)."""
        text = self._channels.get(v)
        if text is None:
            if len(self._channels) >= _CHANNEL_CACHE:
                self._channels.clear()
            text = self._channels[v] = (ip_text(v[0]), ip_text(v[1]), _uuid(v[2]), f"0x{v[6]:04x}")
        return text

    def add(self, capture: str, txn: Transaction, offset: int = 0) -> None:
        number = txn.txn + offset
        device, controller, ar, index = self._channel(txn.channel)
        request, response = txn.request, txn.response
        errors = []
        blocks = response.blocks if response is not None else []
        addresses = request.addresses if request is not None else []
        written_blocks = request.blocks if request is not None else []
        append = self.parameters.append
        for i, addr in enumerate(addresses):
            res_block = blocks[i] if i < len(blocks) else None
            written = written_blocks[i] if i < len(written_blocks) else None
            err = res_block.error if res_block is not None and res_block.is_error else -1
            label = addr.label()
            if err >= 0:
                errors.append(f"{label}:{_hex(err)}")
            fmt = written if written is not None else res_block
            read_values = values_of(res_block) if res_block is not None and not res_block.is_error else None
            append((
                number, capture, device, txn.do, label, addr.pnu, addr.subindex, addr.n_elems,
                pt.ATTRIBUTE.get(addr.attr) or _hex(addr.attr),  # (a default argument is built every time)
                (pt.FORMAT_NAME.get(fmt.format) or _hex(fmt.format)) if fmt is not None and not fmt.is_error else "",
                block_values(written), block_values(res_block, read_values), _hex(err),
                pt.error_text(err) if err >= 0 else ""))
            self._trail(capture, txn, number, addr, label, written, res_block, device, read_values)
        if response is not None and len(blocks) == 1 and blocks[0].is_error and len(addresses) > 1:
            errors = [f"*:{_hex(blocks[0].error)}"]  # header-level error: the whole request refused
        fig = txn.figures()
        v = txn.channel
        self.transactions.append((
            number, capture, device, controller, ar, index, v[3], v[4], v[5],
            _int(txn.ref), _hex(txn.req_id), _int(txn.do), _int(txn.n_params), param_label(txn),
            _hex(response.ident) if response is not None else "", txn.verdict, " ".join(errors), txn.pnio_status,
            txn.b5_retries, len(txn.read_req_frames), txn.rpc_retransmissions, txn.write_req_frame,
            txn.write_res_frame or None, " ".join(map(str, txn.read_req_frames)), txn.read_res_frame or None,
            " ".join(map(str, sorted(txn.frames))),
            txn.t_start, fig["t_write_rtt"], fig["t_total"], fig["t_final_read_rtt"], fig["t_first_read_gap"],
            txn.capture_ended, txn.closed_by))
        if self.split_end != 0:
            if txn.reuse_slot is not None:
                at, frame = txn.reuse_slot
                self.reuse_slots.append((len(self.findings) + at, capture, txn.channel, txn.ref, frame, number))
            if txn.txn and (self.split_end is None or txn.write_req_frame < self.split_end):
                self.channel_last[txn.channel] = (number, txn.ref, txn.verdict)
        for f in txn.findings:
            self.add_finding(capture, f, number)

    def add_finding(self, capture: str, f: Finding, txn: int | None = None) -> None:
        self.findings.append(finding_row(capture, f, txn))

    def _trail(self, capture: str, txn: Transaction, number: int, addr: Any, label: str,
               written: Block | None, res_block: Block | None, device: str, read_values: list | None) -> None:
        """The change trail, and the last values read per element to show what a change replaced."""
        change = txn.req_id == pt.REQ_CHANGE and written is not None
        read = txn.req_id == pt.REQ_READ and txn.verdict in ANSWERED and res_block is not None \
            and addr.attr == pt.ATTR_VALUE and not res_block.is_error
        if not (change or read):  # neither remembers nor looks up a value: no keys needed
            return
        count = max(addr.n_elems, 1)
        keys = [(capture, device, txn.do, addr.pnu, addr.subindex + j) for j in range(count)]
        if read:
            values = [_cell(v) for _, _, v, _ in (read_values if read_values is not None else values_of(res_block))]
            pairs = list(zip(keys, values, strict=True)) if len(values) == len(keys) else \
                [(keys[0], values[0])] if len(values) == 1 else []
            self._last_read.update(pairs)
            if self.split_end != 0 and (self.split_end is None or txn.read_res_frame < self.split_end):
                self.reads.update((k, (txn.read_res_frame, v)) for k, v in pairs)
        if not change:
            return
        before = [self._last_read.get(k) for k in keys]
        if self.split_end != 0 and not all(before):
            self.unresolved.append((len(self.changes), keys, before))
        if res_block is not None and res_block.is_error:
            result = f"error {_hex(res_block.error)}: {pt.error_text(res_block.error)}"
        else:
            result = "ok" if txn.verdict in ANSWERED else txn.verdict
        self.changes.append((capture, device, txn.do, number, txn.write_req_frame, txn.t_start, label,
                             addr.pnu, addr.subindex, block_values(written), result,
                             " ".join(b for b in before if b is not None) if all(before) else ""))


def finding_row(capture: str, f: Finding, txn: int | None) -> tuple:
    return (capture, f.frame, txn, f.severity, f.rule, f.name, f.field, f.value, f.expected, f.source, f.message)


def stitch_part(part: Rows, offset: int, channels: dict[tuple, LastDone], numbers: dict[int, int],
                keep_from: int) -> None:
    """Make a split part's findings read as in one process, before its numbers are shifted by `offset`.

    T1 for the transactions whose channel's last transaction the part did not know: `channels` holds
    each channel's last transaction in the parts before; the part's own go there afterwards. The marks
    messages name transactions by (transactions.PART_MARK) become numbers in the whole capture: the
    part's own shifted, a lead-in one's looked up by its write request frame in `numbers` (the parts
    before); there go the part's own transactions from frame `keep_from` on (the next part's lead-in)."""
    for at, capture, channel, ref, frame, number in reversed(part.reuse_slots):
        last = channels.get(channel)
        found = reuse_finding(last, ref, frame) if last is not None else None
        if found is not None:
            part.findings.insert(at, finding_row(capture, found, number))

    def number_of(mark: re.Match) -> str:
        value = int(mark.group(2))
        return str(value + offset if mark.group(1) == "T" else numbers.get(value, 0))

    for i, row in enumerate(part.findings):
        if "\x00" in row[8] or "\x00" in row[10]:  # expected, message
            part.findings[i] = (*row[:8], PART_MARK.sub(number_of, row[8]), row[9], PART_MARK.sub(number_of, row[10]))
    for channel, (number, ref, verdict) in part.channel_last.items():
        channels[channel] = LastDone(str(number + offset), ref, verdict)
    for frame in [f for f in numbers if f < keep_from]:
        del numbers[frame]
    write_frame = [c.name for c in COLUMNS["transactions"]].index("write_req_frame")
    numbers.update((row[write_frame], row[0] + offset) for row in part.transactions if row[write_frame] >= keep_from)


def stitch_values_before(part: Rows, known: dict[tuple, tuple[int, str]]) -> None:
    """Fill in a split part's unknown `value_before` from `known` (the reads of the parts before it,
    each closed before this part's range began), then add the part's own reads to `known`."""
    for index, keys, before in part.unresolved:
        values = [b if b is not None else known.get(k, (0, None))[1] for k, b in zip(keys, before, strict=True)]
        if all(values):
            row = part.changes[index]
            part.changes[index] = (*row[:-1], " ".join(values))
    for key, (frame, value) in part.reads.items():
        if frame > known.get(key, (0, ""))[0]:
            known[key] = (frame, value)


def _uuid(raw: bytes) -> str:
    import uuid

    return str(uuid.UUID(bytes=raw)) if len(raw) == 16 else ""


def _int(value: int) -> int | None:
    return value if value >= 0 else None


# The order of each table: by this column, ties in the order the rows were added (a stable sort).
SORT_COLUMN: Mapping[str, int] = MappingProxyType({"transactions": 0, "parameters": 0, "findings": 1, "changes": 3})
_LAST = float("inf")  # a missing key sorts last, as pandas puts NA last


def sort_key(name: str, by_capture: bool = False) -> Callable[[tuple], object]:
    """The sort key of a table's rows; `by_capture` groups findings by capture first (audit, Parquet)."""
    col = SORT_COLUMN[name]
    if by_capture:
        return lambda r: (r[0], _LAST if r[col] is None else r[col])
    return lambda r: _LAST if r[col] is None else r[col]


def micros(seconds: object) -> int | None:
    """A capture time as the tables hold it: whole microseconds (None beyond datetime64[ns])."""
    if seconds is None:
        return None
    s = float(seconds)  # type: ignore[arg-type]
    if not abs(s) < MAX_TIME_SECONDS:  # NaN fails too
        return None
    return round(s * 1e6)


def pandas_dtype(col: Column) -> object:
    """The pandas dtype of a column (pandas imported here, on first use)."""
    import pandas as pd

    if col.dtype in FIXED_CATEGORIES:
        categories, ordered = FIXED_CATEGORIES[col.dtype]
        return pd.CategoricalDtype(list(categories), ordered=ordered)
    return col.dtype


def __getattr__(name: str) -> object:
    # the pandas dtypes of the fixed categoricals, for callers that used the module constants
    if name in ("VERDICT_DTYPE", "SEVERITY_DTYPE"):
        return pandas_dtype(Column("", VERDICT if name == "VERDICT_DTYPE" else SEVERITY, ""))
    raise AttributeError(name)


def frame_of(name: str, rows: Iterable[tuple]) -> pd.DataFrame:
    """A typed DataFrame of one table from its rows."""
    import pandas as pd

    cols = COLUMNS[name]
    df = pd.DataFrame.from_records(list(rows), columns=[c.name for c in cols])
    for c in cols:
        if c.dtype == TIME:  # capture times to the microsecond (float seconds carry no more)
            seconds = df[c.name].astype("float64")
            seconds = seconds.where(seconds.abs() < MAX_TIME_SECONDS)  # a pcapng time beyond datetime64: NaT
            micro = (seconds * 1e6).round().astype("Int64")
            df[c.name] = pd.to_datetime(micro, unit="us", utc=True).astype(TIME)
        else:
            df[c.name] = df[c.name].astype(pandas_dtype(c))
    if len(df):
        df = df.sort_values([cols[SORT_COLUMN[name]].name], kind="stable").reset_index(drop=True)
    return df
