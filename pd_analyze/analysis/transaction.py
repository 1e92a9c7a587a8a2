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
from pd_analyze.protocol.profiles import VendorRequest

# How a transaction that got no final answer ended (its verdict is then timeout, protocol.md 7.4).
UNANSWERED_ENDS = frozenset({"deadline", "superseded", "capture_end", "evicted"})
# The ends where the controller gave up inside the capture: its next write, or the deadline passed (7.3 step 5)
GAVE_UP_ENDS = frozenset({"deadline", "superseded"})


def refused_busy(closed_by: str, capture_ended: bool, b5_retries: int, reads: int) -> bool:
    """protocol.md 7.3 step 5: every read of a transaction the controller gave up on was answered DE 80 B5.
    The drive answered each time (it refused, it did not go silent): pnio_error with DE80B500, not a
    timeout. A capture that ends before the deadline leaves it a timeout (capture_ended)."""
    if not b5_retries or b5_retries != reads:
        return False
    return closed_by in GAVE_UP_ENDS or (closed_by == "capture_end" and not capture_ended)


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
    closed_by: str = ""  # "response", "pnio_error", "deadline", "superseded", "capture_end", "evicted"
    capture_ended: bool = False
    fallback: bool = False
    frames: list[int] = field(default_factory=list)
    findings: list[Finding] = field(default_factory=list)
    verdict: str = ""
    # A change: per address, the values of its elements last read back before its write request (None:
    # not read in the capture).
    values_before: list[list[str | None]] = field(default_factory=list)

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
            "t_last_read": final_req - self.t_start if final_req is not None else None,
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


def superseded_finding(ref: int, old_frame: int, old_ref: int, frame: int) -> Finding:
    """T3: a write (reference `ref`, at `frame`) while the transaction of `old_frame` is pending."""
    return finding("write_while_pending", frame, "pd.ref", ref, f"none pending (the transaction of frame {old_frame})",
                   f"write while the transaction of frame {old_frame} (ref {old_ref}) is pending: it ends as a timeout")


def b5_finding(retries: int, threshold: int, frame: int) -> Finding:
    """T5: the read answer that took a transaction's B5 answers above the threshold."""
    return finding("b5_polling", frame, "txn.b5_retries", retries, f"<= {threshold}",
                   f"more than {threshold} B5 (not ready) answers")


def mirroring_findings(ref: int, req_id: int, do: int, n_params: int, r: Parsed,
                       frame: int, answers: tuple[int, ...] | None = None) -> tuple[list[Finding], bool]:
    """Q2-Q5: a response mirrors the request's reference, Request ID, DO and No. of parameters (protocol.md
    6.4); (findings, whether Q2 or Q3 failed: the verdict is then reference_mismatch). A request field it
    does not know is -1 and not compared. `answers`: the Response IDs of a vendor's own Request ID
    (protocol.md 5.5), in place of the profile's."""
    out = []
    mismatch = False
    if ref >= 0 and r.ref != ref:
        out.append(finding("reference_mismatch", frame, "pd.ref", r.ref, ref,
                           f"response reference {r.ref} does not mirror the request's {ref}"))
        mismatch = True
    expected = answers or ANSWERS.get(req_id, (pt.RES_NOT_SUPPORTED,))
    if req_id >= 0 and r.ident not in expected:  # (a request cut before its header: nothing to answer)
        out.append(finding("response_id_mismatch", frame, "pd.resp_id", f"{r.ident:#04x}",
                           "/".join(f"{e:#04x}" for e in expected),
                           f"Response ID {r.ident:#04x} does not answer Request ID {req_id:#04x}"))
        mismatch = True
    if do >= 0 and r.do != do:
        out.append(finding("do_not_mirrored", frame, "pd.do", r.do, do, "DO-ID not mirrored"))
    header_level = r.ident & 0x80 and len(r.blocks) == 1 and r.blocks[0].is_error
    if n_params >= 0 and r.n != n_params and not header_level:
        out.append(finding("n_params_not_mirrored", frame, "pd.n_params", r.n, n_params,
                           "No. of parameters not mirrored"))
    return out, mismatch


ANSWERS = {pt.REQ_READ: (pt.RES_READ, pt.RES_READ_NAK), pt.REQ_CHANGE: (pt.RES_CHANGE, pt.RES_CHANGE_NAK)}


def vendor_answers(request: Parsed | None) -> tuple[int, ...] | None:
    """The Response IDs that answer a vendor's own Request ID (protocol.md 5.5); None for the profile's."""
    vendor = request.vendor if request is not None else None
    return vendor.answers if isinstance(vendor, VendorRequest) else None


def verdict_of(txn: Transaction) -> str:
    """protocol.md 7.4: the first verdict, in PRECEDENCE order, whose condition holds."""
    holds = {
        "malformed": txn.malformed,
        "pnio_error": txn.closed_by == "pnio_error" or refused_busy(
            txn.closed_by, txn.capture_ended, txn.b5_retries, len(txn.read_req_frames)),
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
        values = [cell_text(v, size) for _, size, v, _ in values_of(block)]
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
