"""Closed transactions to rows of the four tidy tables: transactions, parameters, findings, changes.

`Rows` collects a capture's rows: the tables the engine makes as pyarrow tables (`add_table`), the rows
of the few transactions whose records were parsed frame by frame (`add`; the row types and columns are
declared in `schema`), findings that belong to no transaction one by one. The same collector feeds
`analyze()` (lists) and the streamed report (spools), so their tables cannot differ.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass, field
from typing import Any

from pd_analyze.analysis.engine.rules import WHOLE, refusal, refused_finding
from pd_analyze.analysis.schema import ROW_TYPES, ChangeRow, FindingRow, ParameterRow, TransactionRow
from pd_analyze.model import pd_values as pt
from pd_analyze.model.rules import Finding
from pd_analyze.model.values import status_text
from pd_analyze.model.verdicts import ANSWERED
from pd_analyze.protocol.profidrive import Address, Block, Parsed, error_meaning, service_name, writes_values
from pd_analyze.protocol.profidrive_view import cell_text, values_of


def block_values(block: Block | None, values: list | None = None) -> str:
    """Values of a value block as one text cell (strings quoted, scaled types raw); `values`: its
    values_of, when the caller has them already."""
    if block is None or block.is_error or block.format in (pt.FMT_ZERO, pt.FMT_AKD_ZERO):
        return ""
    values = values_of(block) if values is None else values
    if pt.FORMATS.get(block.format, pt.FORMATS[0x41]).kind in ("hex", "bits", "nibbles"):
        return " ".join(f"0x{v:0{2 * block.size}x}" for _, _, v, _ in values if isinstance(v, int))
    return " ".join(cell_text(value, size) for _, size, value, _ in values)


def _hex(value: int) -> str:
    return f"0x{value:02x}" if value >= 0 else ""


_CHANNEL_CACHE = 4096  # channels whose text cells are remembered (a capture has tens; a flood of new
# channels only clears it: 65,536 held some 20 MB)


@dataclass(slots=True)
class Rows:
    """Rows of the four tables for one or more captures.

    The four attributes are lists for `analyze()`; the streaming report puts spools there instead
    (anything with `append` and `extend`), so the same code builds the rows for both.
    """

    transactions: list[TransactionRow] = field(default_factory=list)
    parameters: list[ParameterRow] = field(default_factory=list)
    findings: list[FindingRow] = field(default_factory=list)
    changes: list[ChangeRow] = field(default_factory=list)
    # rows the columnar path made as pyarrow tables (table_batches.batch_schema), by table, in arrival order
    tables: dict[str, list] = field(default_factory=dict)
    # what the run's profile calls parameters and errors (Checker.names; set by the capture loops)
    names: pt.Names = pt.PROFIDRIVE_NAMES
    # each capture's resolution: the decimals of a second its times carry (model.times), the finest read so
    # far; the report's writers and summary hold this very dict and write each row's times with its capture's
    digits: dict[str, int] = field(default_factory=dict)
    _channels: dict[tuple, tuple[str, str, str, str]] = field(default_factory=dict)

    def extend(self, other: Rows, offset: int) -> None:
        """Append another capture's rows, its transaction numbers shifted by `offset`."""
        self.transactions.extend(_shifted(other.transactions, offset))
        self.parameters.extend(_shifted(other.parameters, offset))
        self.findings.extend(_shifted(other.findings, offset))
        self.changes.extend(_shifted(other.changes, offset))
        for capture, digits in other.digits.items():
            self.note_digits(capture, digits)
        for name, tables in other.tables.items():
            for table in tables:
                self.add_table(name, _shifted_table(table, offset))

    def note_digits(self, capture: str, digits: int) -> None:
        """A capture's times carry `digits` decimals of a second (its resolution as far as it was read)."""
        if digits > self.digits.get(capture, -1):
            self.digits[capture] = digits

    def use_names(self, names: pt.Names) -> None:
        """Name parameters and errors as the run's profile does (Checker.names)."""
        self.names = names

    def transaction_count(self) -> int:
        """Transactions held: rows made one by one and the tables' rows."""
        return len(self.transactions) + sum(t.num_rows for t in self.tables.get("transactions", ()))  # type: ignore[attr-defined]

    def add_table(self, name: str, table: object) -> None:
        """Rows of one table made as a pyarrow table (the columnar path)."""
        self.tables.setdefault(name, []).append(table)

    def batch_done(self) -> None:
        """The engine finished a batch (a streaming end may pass its rows on now).

        Here the rows made one by one in the batch join the tables after the batch's own tables, as the
        streaming report hands them on (report._ReportRows): rows that tie in a table's order (findings of
        one frame number in two captures) then come in the same order in `analyze()`'s DataFrames, in a
        worker's rows and in the report's files. Rows stay rows where they go elsewhere (a spool, a sink)."""
        for name in ROW_TYPES:
            rows = getattr(self, name)
            if type(rows) is list and rows:
                from pd_analyze.analysis.table_batches import rows_to_batch

                self.add_table(name, rows_to_batch(name, rows))
                rows.clear()

    def add_calls(self, requests: Any, answers: Any, decided: Any) -> None:
        """The RPC calls the engine paired in a batch: the frame of each request and of its first answer
        (response, fault or reject; numpy int64 arrays), and the frames of PDUs whose interface is not PNIO's
        that it took as PNIO by their call or activity. Only the dump asks (output.dump_facts: its links are
        the report's pairing); the tables do not need them."""

    def channel_texts(self, ch: tuple) -> tuple[str, str, str, str]:
        """device, controller, ARUUID and index of an engine channel (integers) as text."""
        text = self._channels.get(ch)
        if text is None:
            if len(self._channels) >= _CHANNEL_CACHE:
                self._channels.clear()
            device, controller, ar_hi, ar_lo, _api, _slot, _subslot, index = ch
            ar = str(uuid.UUID(int=ar_hi << 64 | ar_lo))
            text = self._channels[ch] = (_ip(device), _ip(controller), ar, f"0x{index:04x}")
        return text

    def add(self, capture: str, txn: Any, records: Any, offset: int = 0) -> None:
        """A closed transaction (analysis.engine.txn.Txn) whose records `records` resolves (the rows of one
        whose records the batch's columns do not hold: analysis.engine.tables makes the others')."""
        number = txn.number + offset
        device, controller, ar, index = self.channel_texts(txn.channel)
        request, response = records.parsed(txn.request), records.parsed(txn.response)
        errors = []
        refusals: list[str] = []  # each error in words (T9)
        blocks = response.blocks if response is not None else []
        addresses = request.addresses if request is not None else []
        written_blocks = request.blocks if request is not None else []
        append = self.parameters.append
        whole = whole_request_error(request, response)
        if whole is not None and not addresses:  # a request of no parameter: one row, no PNU
            append(ParameterRow._make((number, capture, device, _int(txn.do), "", None, "", None, None, "", "", "", "",
                                       _hex(whole.error), error_meaning(whole.error, response, self.names),
                                       whole.error_subindex if whole.error_subindex >= 0 else None, True)))
        changes = writes_values(request)
        for i, addr in enumerate(addresses):
            res_block = whole if whole is not None else blocks[i] if i < len(blocks) else None
            written = written_blocks[i] if i < len(written_blocks) else None
            err = res_block.error if res_block is not None and res_block.is_error else -1
            label = addr.label()
            if err >= 0 and whole is None:
                errors.append(f"{label}:{_hex(err)}")
                refusals.append(refusal(label, err, error_meaning(err, response, self.names)))
            fmt = written if written is not None else res_block
            read_values = values_of(res_block) if res_block is not None and not res_block.is_error else None
            append(ParameterRow._make((
                number, capture, device, txn.do, label, addr.pnu, self.names.pnu(addr.pnu), addr.subindex,
                addr.n_elems, service_name(request, addr.attr) or pt.ATTRIBUTE.get(addr.attr) or _hex(addr.attr),
                (pt.FORMAT_NAME.get(fmt.format) or _hex(fmt.format)) if fmt is not None and not fmt.is_error else "",
                block_values(written), block_values(res_block, read_values), _hex(err),
                error_meaning(err, response, self.names) if err >= 0 else "",
                res_block.error_subindex if err >= 0 and res_block.error_subindex >= 0 else None, whole is not None)))
            if written is not None and changes:
                self._change(capture, txn, number, i, addr, label, written, res_block, response, device)
        if whole is not None:
            errors = [f"*:{_hex(whole.error)}"]  # header-level error: the whole request refused
            refusals = [refusal(WHOLE, whole.error, error_meaning(whole.error, response, self.names))]
        if txn.verdict == "nak":
            txn.findings.append(refused_finding(txn.read_res_frame, txn.write_frame, refusals))
        fig = txn.figures()
        v = txn.channel
        self.transactions.append(TransactionRow._make((
            number, capture, device, controller, ar, index, v[4], v[5], v[6],
            _int(txn.ref), _hex(txn.req_id), _int(txn.do), _int(txn.n_params),
            " ".join(a.label() for a in addresses),
            _hex(response.ident) if response is not None else "", txn.verdict, " ".join(errors), txn.pnio_status,
            status_text(txn.pnio_status), txn.b5, len(txn.read_frames), txn.retransmissions, txn.write_frame,
            txn.write_res_frame or None, " ".join(map(str, txn.read_frames)), txn.read_res_frame or None,
            " ".join(map(str, sorted(txn.frames))), txn.t_start, fig["t_write_rtt"], fig["t_total"],
            fig["t_final_read_rtt"], fig["t_first_read_gap"], fig["t_last_read"], txn.capture_ended, txn.closed_by)))
        for f in txn.findings:
            self.add_finding(capture, f, number)

    def _change(self, capture: str, txn: Any, number: int, i: int, addr: Address, label: str,
                       written: Block, res_block: Block | None, response: Parsed | None, device: str) -> None:
        """The change trail of an engine transaction: what was written, how it ended, the values it replaced."""
        before = txn.values_before[i] if i < len(txn.values_before) else ""
        if res_block is not None and res_block.is_error:
            result = f"error {_hex(res_block.error)}: {error_meaning(res_block.error, response, self.names)}"
        else:
            result = "ok" if txn.verdict in ANSWERED else txn.verdict
        self.changes.append(ChangeRow._make((
            capture, device, txn.do, number, txn.write_frame, txn.t_start, label, addr.pnu,
            self.names.pnu(addr.pnu), addr.subindex,
            block_values(written), result, before)))

    def add_finding(self, capture: str, f: Finding, txn: int | None = None) -> None:
        self.findings.append(finding_row(capture, f, txn))

def whole_request_error(request: Parsed | None, response: Parsed | None) -> Block | None:
    """The one error block a device answered for the whole request (protocol.md 3.3: a header-level error
    such as 0x22/0x23 with No. of parameters mirrored, or any one error block for a request of no or of
    several parameters), None when the errors are per parameter."""
    if request is None or response is None or len(response.blocks) != 1 or len(request.addresses) == 1:
        return None
    block = response.blocks[0]
    return block if block.is_error else None


def finding_row(capture: str, f: Finding, txn: int | None) -> FindingRow:
    return FindingRow._make((capture, f.frame, txn, f.severity, f.rule, f.name, f.field, f.value, f.expected,
                             f.source, f.message))


def _shifted(rows: list[Any], offset: int) -> list[Any]:
    """Rows with their transaction numbers shifted by `offset` (a finding of no transaction keeps None)."""
    if not offset:
        return rows
    return [r._replace(txn=r.txn + offset) if r.txn is not None else r for r in rows]


def _shifted_table(table: object, offset: int) -> object:
    """A table's transaction numbers shifted by `offset`."""
    if not offset:
        return table
    import pyarrow.compute as pc

    i = table.schema.get_field_index("txn")  # type: ignore[attr-defined]
    return table.set_column(i, "txn", pc.add(table.column(i), offset))  # type: ignore[attr-defined]


def _ip(value: int) -> str:
    return f"{value >> 24}.{value >> 16 & 255}.{value >> 8 & 255}.{value & 255}"


def _int(value: int) -> int | None:
    return value if value >= 0 else None
