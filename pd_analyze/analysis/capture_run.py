"""What an analysis run is given (Settings) and gives back per capture (CaptureResult), for every path
a capture takes (analysis.pipeline frame by frame, analysis.columnar in batches)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

from pd_analyze.analysis.transactions import DEFAULT_TXN_TIMEOUT, TransactionEngine
from pd_analyze.capture import CaptureError
from pd_analyze.protocol import profiles
from pd_analyze.protocol.dissector import DEFAULT_RPC_TIMEOUT, Dissector
from pd_analyze.protocol.frames import Accounting
from pd_analyze.protocol.profidrive_checks import Checker

Progress = Callable[[str, int], None]  # (capture, frames read so far)


@dataclass(frozen=True, slots=True)
class Settings:
    """What an analysis is run with (the same in every worker process)."""

    profile: str = profiles.DEFAULT
    txn_timeout: float = DEFAULT_TXN_TIMEOUT  # seconds a transaction may wait for its final response
    rpc_timeout: float = DEFAULT_RPC_TIMEOUT  # seconds a call may wait for its response
    # how captures are read: in batches of frames as columns (analysis.columnar: True), frame by frame by
    # the per-frame reference (analysis.pipeline: False; the differential tests compare the two), or by
    # their size (None: analysis.jobs.COLUMNS_MIN_BYTES)
    columns: bool | None = None
    batch_frames: int = 0  # frames per batch of the columnar path (0: capture.batches' default)

    def checker(self) -> Checker:
        return Checker.for_profile(self.profile)

    def dissector(self) -> Dissector:
        return Dissector(annotate=False, rpc_timeout=self.rpc_timeout, checker=self.checker())

    def engine(self) -> TransactionEngine:
        return TransactionEngine(self.txn_timeout)


@dataclass(slots=True)
class CaptureResult:
    path: str
    accounting: Accounting
    error: str = ""
    transactions: int = 0
    stations: dict[str, str] = field(default_factory=dict)  # IP address -> PN-DCP station name (analysis.stations)


def error_text(exc: CaptureError) -> str:
    return exc.reason if exc.offset is None else f"byte {exc.offset}: {exc.reason}"


def snapshot(acc: Accounting) -> Accounting:
    return Accounting(acc.read, acc.decoded, Counter(acc.skipped), Counter(acc.malformed))


def difference(acc: Accounting, before: Accounting) -> Accounting:
    return Accounting(acc.read - before.read, acc.decoded - before.decoded, acc.skipped - before.skipped,
                      acc.malformed - before.malformed)
