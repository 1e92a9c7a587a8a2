"""The Python API: `analyze(paths)` runs the whole pipeline and returns tidy pandas tables.

    import pd_analyze
    a = pd_analyze.analyze("trace.pcapng", profile="sinamics")
    a.transactions.verdict.value_counts()
    a.parameters.query("error != ''")
    a.fields(12)             # frames and fields of transaction 12, for drill-down
"""

from __future__ import annotations

import glob
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import cached_property

import pandas as pd

from pd_analyze import profiles
from pd_analyze.capture import CaptureError
from pd_analyze.dissect import DEFAULT_RPC_TIMEOUT, Accounting, Dissector, dissect
from pd_analyze.pd_checks import Checker
from pd_analyze.tables_out import Rows, frame_of
from pd_analyze.transactions import DEFAULT_TXN_TIMEOUT, TransactionEngine, iter_closed

CAPTURE_SUFFIXES = (".pcap", ".pcapng", ".cap", ".pcap.gz", ".pcapng.gz", ".gz")


@dataclass(slots=True)
class CaptureResult:
    path: str
    accounting: Accounting
    error: str = ""
    transactions: int = 0


@dataclass
class Analysis:
    """The tables of one or more captures, built once from rows."""

    rows: Rows
    captures: list[CaptureResult]
    profile: str
    txn_timeout: float
    rpc_timeout: float
    _cache: dict = field(default_factory=dict, repr=False)

    @cached_property
    def transactions(self) -> pd.DataFrame:
        return frame_of("transactions", self.rows.transactions)

    @cached_property
    def parameters(self) -> pd.DataFrame:
        return frame_of("parameters", self.rows.parameters)

    @cached_property
    def findings(self) -> pd.DataFrame:
        return frame_of("findings", self.rows.findings)

    @cached_property
    def changes(self) -> pd.DataFrame:
        return frame_of("changes", self.rows.changes)

    @cached_property
    def accounting(self) -> pd.DataFrame:
        """Per capture: frames read = decoded + skipped + malformed, and why frames were skipped."""
        return pd.DataFrame([{
            "capture": c.path, "read": c.accounting.read, "decoded": c.accounting.decoded,
            "skipped": sum(c.accounting.skipped.values()), "malformed": sum(c.accounting.malformed.values()),
            "balanced": c.accounting.balanced(), "transactions": c.transactions, "error": c.error,
            "skipped_by_reason": dict(c.accounting.skipped), "malformed_by_reason": dict(c.accounting.malformed),
        } for c in self.captures])

    @property
    def errors(self) -> list[str]:
        return [f"{c.path}: {c.error}" for c in self.captures if c.error]

    def fields(self, txn: int) -> pd.DataFrame:
        """Every field of every frame of one transaction (the dump, as a table): drill-down."""
        row = self.transactions.loc[self.transactions.txn == txn]
        if row.empty:
            raise KeyError(f"no transaction {txn}")
        capture = str(row.capture.iloc[0])
        frames = {int(n) for n in str(row.frames.iloc[0]).split()}
        checker = Checker(profiles.generic(), profiles.load(self.profile))
        out = []
        d = Dissector(annotate=True, rpc_timeout=self.rpc_timeout, checker=checker)
        for res in dissect(capture, dissector=d):
            if res.frame in frames:
                for layer in res.layers:
                    out += [{"frame": res.frame, "layer": layer.title, "name": f.name, "offset": f.offset,
                             "length": f.length, "raw": f.raw.hex(" "), "value": f.value, "show": f.show,
                             "check": f.check} for f in layer.fields]
        return pd.DataFrame(out)


def expand(paths: str | Iterable[str]) -> list[str]:
    """Files, directories (their captures, sorted) and glob patterns to a list of capture paths."""
    items = [paths] if isinstance(paths, str) else list(paths)
    out: list[str] = []
    for item in items:
        if item != "-" and os.path.isdir(item):
            out += sorted(os.path.join(item, n) for n in os.listdir(item)
                          if n.endswith(CAPTURE_SUFFIXES) and os.path.isfile(os.path.join(item, n)))
        elif any(ch in item for ch in "*?[") and not os.path.exists(item):
            out += sorted(glob.glob(item, recursive=True))
        else:
            out.append(item)
    return out


def analyze(paths: str | Iterable[str], profile: str = profiles.DEFAULT, timeout: float = DEFAULT_TXN_TIMEOUT,
            rpc_timeout: float = DEFAULT_RPC_TIMEOUT, progress: Callable[[str, int], None] | None = None,
            ) -> Analysis:
    """Analyse captures (files, directories or globs) and return the tables as an Analysis.

    A damaged capture keeps every result before the damage; its error is in `Analysis.errors`
    and in the `error` column of `Analysis.accounting`.
    """
    checker = Checker(profiles.generic(), profiles.load(profile))
    rows = Rows()
    results = []
    offset = 0
    for path in expand(paths):
        result = analyze_one(path, checker, rows, offset, timeout, rpc_timeout, progress)
        offset += result.transactions
        results.append(result)
    return Analysis(rows, results, profile, timeout, rpc_timeout)


def analyze_one(path: str, checker: Checker, rows: Rows, offset: int, timeout: float, rpc_timeout: float,
                progress: Callable[[str, int], None] | None = None) -> CaptureResult:
    """One capture into `rows`; transaction numbers continue after `offset`."""
    d = Dissector(annotate=False, rpc_timeout=rpc_timeout, checker=checker)
    engine = TransactionEngine(timeout)
    result = CaptureResult(path, d.accounting)
    last = [float("-inf")]

    def frames():  # noqa: ANN202 - the dissector's results, with progress and loose findings drained
        for res in dissect(path, dissector=d):
            if progress is not None:
                progress(path, d.accounting.read)
            yield res
            _drain(engine, d, rows, path)

    try:
        for txn in iter_closed(engine, frames(), last):
            rows.add(path, txn, offset)
            result.transactions += 1
    except CaptureError as exc:
        result.error = exc.reason if exc.offset is None else f"byte {exc.offset}: {exc.reason}"
        for txn in engine.finish(last[0]):
            rows.add(path, txn, offset)
            result.transactions += 1
    _drain(engine, d, rows, path)
    return result


def _drain(engine: TransactionEngine, d: Dissector, rows: Rows, path: str) -> None:
    for f in engine.loose:
        rows.add_finding(path, f)
    engine.loose.clear()
    for f in d.loose_findings:
        rows.add_finding(path, f)
    d.loose_findings.clear()
