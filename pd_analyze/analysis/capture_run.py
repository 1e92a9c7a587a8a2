"""What an analysis run is given (Settings) and gives back per capture (CaptureResult)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

from pd_analyze.capture import CaptureError
from pd_analyze.protocol import profiles
from pd_analyze.protocol.dissector import DEFAULT_RPC_TIMEOUT
from pd_analyze.protocol.frames import Accounting
from pd_analyze.protocol.profidrive_checks import Checker

Progress = Callable[[str, int], None]  # (capture, frames read so far)
DEFAULT_TXN_TIMEOUT = 10.0  # protocol.md 7.5
DEFAULT_B5_THRESHOLD = 50  # protocol.md 6.5 T5


@dataclass(frozen=True, slots=True)
class Settings:
    """What an analysis is run with (the same in every worker process)."""

    profile: str = profiles.DEFAULT
    txn_timeout: float = DEFAULT_TXN_TIMEOUT  # seconds a transaction may wait for its final response
    rpc_timeout: float = DEFAULT_RPC_TIMEOUT  # seconds a call may wait for its response
    batch_frames: int = 0  # frames per batch (0: capture.batches' default)
    # the ordinary sequences taken whole as vector expressions (False: every row through the engine's loop,
    # with the same tables: the tests compare the two)
    vector: bool = True

    def checker(self) -> Checker:
        return Checker.for_profile(self.profile)


@dataclass(slots=True)
class CaptureResult:
    path: str
    accounting: Accounting
    error: str = ""
    transactions: int = 0
    stations: dict[str, str] = field(default_factory=dict)  # IP address -> PN-DCP station name (analysis.stations)
    # how the engine's work went (report -v, the benchmark): PNIO RPC PDUs in all, those the column decode
    # read (the rest the per-frame dissector), those the vector path took whole (the rest the loop)
    pnio_pdus: int = 0
    column_pdus: int = 0
    vector_pdus: int = 0

    def work_text(self) -> str:
        """The line `report -v` prints (the benchmark reads it)."""
        return (f"{self.path}: {self.column_pdus} of {self.pnio_pdus} PNIO RPC frames decoded by the columns, "
                f"{self.vector_pdus} taken whole by the vector path")


def error_text(exc: CaptureError) -> str:
    return exc.reason if exc.offset is None else f"byte {exc.offset}: {exc.reason}"


def snapshot(acc: Accounting) -> Accounting:
    return Accounting(acc.read, acc.decoded, Counter(acc.skipped), Counter(acc.malformed))


def difference(acc: Accounting, before: Accounting) -> Accounting:
    return Accounting(acc.read - before.read, acc.decoded - before.decoded, acc.skipped - before.skipped,
                      acc.malformed - before.malformed)
