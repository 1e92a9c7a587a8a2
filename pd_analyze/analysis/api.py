"""The Python API: `analyze(paths)` runs the whole pipeline and returns tidy pandas tables.

    import pd_analyze
    a = pd_analyze.analyze("trace.pcapng", profile="sinamics")
    a.transactions.verdict.value_counts()
    a.parameters.query("error != ''")
    a.fields(12)             # frames and fields of transaction 12, for drill-down
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

from pd_analyze.analysis.capture_run import DEFAULT_TXN_TIMEOUT, CaptureResult, Progress, Settings
from pd_analyze.analysis.drilldown import annotated_frames
from pd_analyze.analysis.jobs import run
from pd_analyze.analysis.rows import Rows
from pd_analyze.analysis.schema import capture_text, frame_of
from pd_analyze.capture.files import expand
from pd_analyze.protocol import profiles
from pd_analyze.protocol.dissector import DEFAULT_RPC_TIMEOUT

if TYPE_CHECKING:
    import pandas as pd


@dataclass
class Analysis:
    """The tables of one or more captures, built once from rows."""

    rows: Rows
    captures: list[CaptureResult]
    profile: str
    txn_timeout: float
    rpc_timeout: float
    chain: tuple[str, ...] = ()  # the files of a --chain analysis, numbered as one capture
    _cache: dict = field(default_factory=dict, repr=False)

    @cached_property
    def transactions(self) -> pd.DataFrame:
        return self._frame("transactions")

    @cached_property
    def parameters(self) -> pd.DataFrame:
        return self._frame("parameters")

    @cached_property
    def findings(self) -> pd.DataFrame:
        return self._frame("findings")

    @cached_property
    def changes(self) -> pd.DataFrame:
        return self._frame("changes")

    @cached_property
    def values(self) -> pd.DataFrame:
        """Every value written or read, one typed row per array element (analysis.values_table)."""
        from pd_analyze.analysis.values_table import values_frame

        return values_frame(self.parameters)

    def _frame(self, name: str) -> pd.DataFrame:
        return table_frame(self.rows, name)

    @cached_property
    def parameter_state(self) -> pd.DataFrame:
        """Per device, DO, PNU and subindex: the last value confirmed written and read back (param_state)."""
        from pd_analyze.analysis.param_state import state_of
        from pd_analyze.analysis.stations import merged

        return state_of(self.rows, merged(self.captures)).frame()

    def check_expected(self, expected: str, strict: bool = False) -> pd.DataFrame:
        """The findings of the parameter state against an intended set (CSV file; see analysis.intended),
        as rows of the findings table; `strict` adds unexpected_write for parameters the set does not list."""
        from pd_analyze.analysis import intended
        from pd_analyze.analysis.param_state import state_of

        found = intended.check(intended.load(expected), state_of(self.rows), strict)
        return intended.findings_frame(found)

    @cached_property
    def accounting(self) -> pd.DataFrame:
        """Per capture: frames read = decoded + skipped + malformed, and why frames were skipped."""
        return accounting_frame(self.captures)

    @property
    def errors(self) -> list[str]:
        return [f"{c.path}: {c.error}" for c in self.captures if c.error]

    def fields(self, txn: int) -> pd.DataFrame:
        """Every field of every frame of one transaction (the dump, as a table): drill-down."""
        import pandas as pd

        row = self.transactions.loc[self.transactions.txn == txn]
        if row.empty:
            raise KeyError(f"no transaction {txn}")
        capture = str(row.capture.iloc[0])
        frames = {int(n) for n in str(row.frames.iloc[0]).split()}
        out = []
        for res in annotated_frames(capture, frames, self.profile, self.rpc_timeout, self.chain):
            for layer in res.layers:
                out += [{"frame": res.frame, "layer": layer.title, "name": f.name, "offset": f.offset,
                         "length": f.length, "raw": f.raw.hex(" "), "value": f.value, "show": f.show,
                         "check": f.check} for f in layer.fields]
        return pd.DataFrame(out)


ACCOUNTING_COLUMNS = {  # name: dtype
    "capture": "str", "read": "int64", "decoded": "int64", "skipped": "int64", "malformed": "int64",
    "balanced": "bool", "transactions": "int64", "error": "str", "skipped_by_reason": "object",
    "malformed_by_reason": "object"}


def table_frame(rows: Rows, name: str) -> pd.DataFrame:
    """One of the four tables as a DataFrame: its rows made one by one (Rows.add) and its pyarrow tables
    (the engine's, Rows.add_table), in that order."""
    tables = rows.tables.get(name)
    if not tables:
        return frame_of(name, getattr(rows, name))
    from pd_analyze.analysis.table_batches import frame_from_batches, rows_to_batch

    return frame_from_batches(name, [rows_to_batch(name, getattr(rows, name)), *tables])


def accounting_frame(captures: Iterable[CaptureResult]) -> pd.DataFrame:
    """Per capture: frames read = decoded + skipped + malformed, and why frames were skipped or malformed."""
    import pandas as pd

    return pd.DataFrame([(
        capture_text(c.path), c.accounting.read, c.accounting.decoded, sum(c.accounting.skipped.values()),
        sum(c.accounting.malformed.values()), c.accounting.balanced(), c.transactions, c.error,
        dict(c.accounting.skipped), dict(c.accounting.malformed)) for c in captures],
        columns=list(ACCOUNTING_COLUMNS)).astype(ACCOUNTING_COLUMNS)


def analyze(paths: str | Iterable[str], profile: str = profiles.DEFAULT, timeout: float = DEFAULT_TXN_TIMEOUT,
            rpc_timeout: float = DEFAULT_RPC_TIMEOUT, progress: Progress | None = None,
            jobs: int = 1, chain: bool = False) -> Analysis:
    """Analyse captures (files, directories or globs) and return the tables as an Analysis.

    `jobs` > 1 analyses files in parallel processes; the tables are identical to one process
    (transactions numbered in file order). `chain` treats the files as one capture continued across
    files (a ring-buffer set, as `mergecap -a` would join them): frame numbers run on across the set
    and a transaction split over two files is still paired.
    A damaged capture keeps every result before the damage; its error is in `Analysis.errors`
    and in the `error` column of `Analysis.accounting`.
    """
    profiles.load(profile)  # an unknown profile fails here, before any work
    rows = Rows()
    files = expand(paths)
    results = run(files, rows, Settings(profile, timeout, rpc_timeout), progress, jobs, chain)
    return Analysis(rows, results, profile, timeout, rpc_timeout, tuple(files) if chain else ())
