"""One PROFIdrive transaction (protocol.md 7.3): what it holds from its write, its reads and how it
ended; its figures (7.6) and its verdict (7.4). The engine in `transactions` fills it in."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

from pd_analyze.model import pd_values as pt
from pd_analyze.model.rules import Finding, finding
from pd_analyze.model.verdicts import ANSWERED, FAILED_UNANSWERED, PRECEDENCE
from pd_analyze.protocol.profidrive import Address, Parsed
from pd_analyze.protocol.profidrive_view import cell_text, values_of

# How a transaction that got no final answer ended (its verdict is then timeout, protocol.md 7.4).
UNANSWERED_ENDS = frozenset({"deadline", "superseded", "capture_end", "evicted"})

Channel = tuple  # device, controller, AR, API, slot, subslot, index (protocol.md 7.2)
Element = tuple  # device, DO, PNU, subindex: one array element of one drive's parameter



@dataclass(slots=True)
class Transaction:
    """One parameter access: the write of a request, its reads, and how it ended."""

    txn: int
    channel: Channel
    request: Parsed | None
    write_req_frame: int
    t_start: float
    ref: int = -1
    req_id: int = -1
    do: int = -1
    n_params: int = -1
    response: Parsed | None = None
    write_res_frame: int = 0
    t_write_res: float | None = None
    read_req_frames: list[int] = field(default_factory=list)
    t_read_reqs: list[float] = field(default_factory=list)
    read_res_frame: int = 0
    t_read_res: float | None = None
    b5_retries: int = 0
    last_b5_res: float | None = None
    rpc_retransmissions: int = 0
    rpc_calls: list = field(default_factory=list)  # the RPC calls of its requests: their copies are its retransmissions
    pnio_status: str = ""
    malformed: bool = False
    mismatch: bool = False
    closed_by: str = ""  # "response", "pnio_error", "deadline", "superseded", "capture_end"
    capture_ended: bool = False
    fallback: bool = False
    frames: list[int] = field(default_factory=list)
    findings: list[Finding] = field(default_factory=list)
    verdict: str = ""
    # A change: per address, the values of its elements last read back before its write request (None:
    # not read in the capture). A read answered (ok, nak): the values it read, per element.
    values_before: list[list[str | None]] = field(default_factory=list)
    values_read: list[tuple[Element, str]] = field(default_factory=list)

    @property
    def device(self) -> bytes:
        return self.channel[0]

    @property
    def controller(self) -> bytes:
        return self.channel[1]

    def figures(self) -> dict[str, float | None]:
        """Timing figures of protocol.md 7.6 (seconds; None where the capture has no such frame)."""
        res = self.t_write_res
        final_req = self.t_read_reqs[-1] if self.t_read_reqs else None
        done = self.t_read_res if self.closed_by == "response" else None
        return {
            "t_write_rtt": None if res is None else res - self.t_start,
            "t_total": None if done is None else done - self.t_start,
            "t_final_read_rtt": None if done is None or final_req is None else done - final_req,
            "t_first_read_gap": None if res is None or not self.t_read_reqs else self.t_read_reqs[0] - res,
            "t_ready_after": None if res is None or done is None else (
                0.0 if self.last_b5_res is None else self.last_b5_res - res),
            "t_ready_by": None if res is None or done is None or final_req is None else final_req - res,
        }


class LastDone(NamedTuple):
    """What T1/T4 need of the last closed transaction of a channel."""

    frame: int  # its write request frame: messages name a transaction by it, the same in every split part
    ref: int
    verdict: str


def reuse_finding(last: LastDone, ref: int, frame: int) -> Finding | None:
    """T1: a write with the Request Reference of the channel's last transaction (a retry after a failure)."""
    if last.ref != ref:
        return None
    if last.verdict in ANSWERED:
        return finding("reference_reused", frame, "pd.ref", ref, f"a reference other than {last.ref}",
                       f"Request Reference {ref} reused from the transaction of frame {last.frame}")
    if last.verdict in FAILED_UNANSWERED:
        return finding("retry", frame, "pd.ref", ref, "",
                       f"retry of the transaction of frame {last.frame} ({last.verdict}) with the same reference")
    return None


def verdict_of(txn: Transaction) -> str:
    """protocol.md 7.4: the first verdict, in PRECEDENCE order, whose condition holds."""
    holds = {
        "malformed": txn.malformed,
        "pnio_error": txn.closed_by == "pnio_error",
        "timeout": txn.closed_by in UNANSWERED_ENDS,
        "reference_mismatch": txn.mismatch,
        "nak": txn.response is not None and bool(txn.response.ident & 0x80),
        "ok": True,
    }
    return next(verdict for verdict in PRECEDENCE if holds[verdict])


def elements(txn: Transaction, addr: Address) -> list[Element]:
    """The array elements an address names (one for a single value)."""
    return [(txn.channel[0], txn.do, addr.pnu, addr.subindex + j) for j in range(max(addr.n_elems, 1))]


def elements_read(txn: Transaction) -> list[tuple[Element, str]]:
    """What an answered read transaction read back: (element, value as a table cell) per element of
    each Value address answered with values (all elements, or the first when the drive gave one value)."""
    if txn.req_id != pt.REQ_READ or txn.verdict not in ANSWERED or txn.request is None or txn.response is None:
        return []
    out: list[tuple[Element, str]] = []
    for addr, block in zip(txn.request.addresses, txn.response.blocks, strict=False):
        if addr.attr != pt.ATTR_VALUE or block.is_error:
            continue
        keys = elements(txn, addr)
        values = [cell_text(v) for _, _, v, _ in values_of(block)]
        if len(values) == len(keys):
            out += zip(keys, values, strict=True)
        elif len(values) == 1:
            out.append((keys[0], values[0]))
    return out


def param_label(txn: Transaction) -> str:
    """P964[0] P2000[0..2]: the parameters of a transaction."""
    if txn.request is None:
        return ""
    return " ".join(a.label() for a in txn.request.addresses)
