"""The transaction-level rules of protocol.md 6.4 and 6.5 and the verdicts of 7.4, as the engine applies
them: the findings' texts in one place."""

from __future__ import annotations

from typing import NamedTuple

from pd_analyze.analysis.engine.facts import Head
from pd_analyze.analysis.engine.txn import Txn
from pd_analyze.model import pd_values as pt
from pd_analyze.model.rules import Finding, finding
from pd_analyze.model.values import status_text
from pd_analyze.model.verdicts import ANSWERED, FAILED, FAILED_UNANSWERED, PRECEDENCE

# How a transaction that got no final answer ended (its verdict is then timeout, protocol.md 7.4).
UNANSWERED_ENDS = frozenset({"deadline", "superseded", "capture_end", "evicted"})
# The ends where the controller gave up inside the capture: its next write, or the deadline passed (7.3 step 5)
GAVE_UP_ENDS = frozenset({"deadline", "superseded"})
ANSWERS = {pt.REQ_READ: (pt.RES_READ, pt.RES_READ_NAK), pt.REQ_CHANGE: (pt.RES_CHANGE, pt.RES_CHANGE_NAK)}


class LastDone(NamedTuple):
    """What T1/T4 need of the last closed transaction of a channel."""

    frame: int  # its write request frame: messages name a transaction by it
    ref: int
    verdict: str


def refused_busy(closed_by: str, capture_ended: bool, b5_retries: int, reads: int) -> bool:
    """protocol.md 7.3 step 5: every read of a transaction the controller gave up on was answered DE 80 B5.
    The drive answered each time (it refused, it did not go silent): pnio_error with DE80B500, not a
    timeout. A capture that ends before the deadline leaves it a timeout (capture_ended)."""
    if not b5_retries or b5_retries != reads:
        return False
    return closed_by in GAVE_UP_ENDS or (closed_by == "capture_end" and not capture_ended)


def verdict_of(txn: Txn) -> str:
    """protocol.md 7.4: the first verdict, in PRECEDENCE order, whose condition holds."""
    for verdict in PRECEDENCE:
        if verdict == "malformed" and txn.malformed:
            return verdict
        if verdict == "pnio_error" and (txn.closed_by == "pnio_error" or refused_busy(
                txn.closed_by, txn.capture_ended, txn.b5, len(txn.read_frames))):
            return verdict
        if verdict == "timeout" and txn.closed_by in UNANSWERED_ENDS:
            return verdict
        if verdict == "reference_mismatch" and txn.mismatch:
            return verdict
        if verdict == "nak" and txn.response_head is not None and txn.response_head.ident & 0x80:
            return verdict
    return "ok"


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


def ends(txn: Txn) -> str:
    """How a closed transaction ends, as T3 and T7 name it: the verdict it gets (protocol.md 6.5 T3)."""
    if txn.verdict == "timeout":
        return "as a timeout"
    if txn.verdict == "pnio_error":
        busy = " (busy: every read answered B5)" if txn.closed_by in UNANSWERED_ENDS else ""
        return f"as pnio_error {txn.pnio_status}{busy}"
    return txn.verdict if txn.verdict == "malformed" else f"as {txn.verdict}"


def superseded_finding(ref: int, old: Txn, frame: int) -> Finding:
    """T3: a write (reference `ref`, at `frame`) while the transaction `old` is pending (closed by it just now)."""
    return finding("write_while_pending", frame, "pd.ref", ref,
                   f"none pending (the transaction of frame {old.write_frame})",
                   f"write while the transaction of frame {old.write_frame} (ref {old.ref}) is pending: it ends "
                   f"{ends(old)}")


def failed_finding(txn: Txn, timeout: float) -> list[Finding]:
    """T8 of a closed transaction whose verdict is malformed, pnio_error or timeout (`timeout`: the transaction
    timeout, seconds): at the frame that decided the verdict, naming the verdict and its cause in words."""
    verdict = txn.verdict
    if verdict not in FAILED:
        return []
    if verdict == "malformed":
        at = txn.malformed_at or txn.admitted
        return [failed_at(verdict, at, txn.write_frame, f"the {_role(txn, at)} of frame {at} cannot be decoded")]
    if txn.closed_by == "pnio_error":
        at = txn.read_res_frame or txn.write_res_frame
        return [failed_at(verdict, at, txn.write_frame,
                          answered_with(txn.pnio_status, "read" if at == txn.read_res_frame else "write"))]
    at = txn.ended_at if txn.closed_by in ("superseded", "evicted") else txn.admitted
    if txn.closed_by == "superseded":
        end = f"superseded by the write of frame {at}"
    elif txn.closed_by == "evicted":
        end = f"dropped by the analyser's limits at frame {at}"
    elif txn.closed_by == "capture_end" and txn.capture_ended:
        end = "the capture ended"
    else:
        end = f"no final response within {timeout:g} s"
    if verdict == "pnio_error":  # every read answered B5 until the controller gave up (protocol.md 7.3 step 5)
        cause = f"{status_text(txn.pnio_status)}: every read answered B5 ({txn.b5}), {end}"
    else:
        cause = end + (f", after {txn.b5} B5 answer{'s' if txn.b5 != 1 else ''}" if txn.b5 else "")
    return [failed_at(verdict, at, txn.write_frame, cause)]


def answered_with(status: str, service: str) -> str:
    """The cause of a pnio_error closed by an answer (a response, fault or reject) to a "write" or "read": its
    status in words."""
    return f"{status_text(status)} (in the answer to the {service})"


def failed_at(verdict: str, frame: int, write_frame: int, cause: str) -> Finding:
    """T8 at `frame` for the transaction of `write_frame`."""
    return finding("txn_failed", frame, "txn.verdict", verdict, "ok or nak",
                   f"the transaction of frame {write_frame} failed: {verdict}: {cause}")


def refused_finding(frame: int, write_frame: int, errors: list[str]) -> Finding:
    """T9: the drive refused the transaction of `write_frame` (verdict nak) in its response at `frame`; `errors`:
    each error in words (`refusal`)."""
    said = "; ".join(errors) if errors else "no error number given"
    return finding("txn_refused", frame, "txn.verdict", "nak", "ok",
                   f"the drive refused the transaction of frame {write_frame}: {said}")


WHOLE = ""  # refusal's label of an error that refused the whole request (protocol.md 3.3)


def refusal(label: str, error: int, text: str) -> str:
    """One error of a NAK in words: 'P964[0]: error 0x02 (low or high limit exceeded)', or for the whole
    request (`label` WHOLE) 'the whole request: error 0x22 (...)'."""
    return f"{label or 'the whole request'}: error 0x{error:02x} ({text})"


def _role(txn: Txn, frame: int) -> str:
    """Which PDU of the transaction `frame` is."""
    if frame == txn.read_res_frame:
        return "read response"
    if frame == txn.write_res_frame:
        return "write response"
    if frame in (txn.admitted, txn.write_frame):
        return "write request"
    return "PDU"


def b5_finding(retries: int, threshold: int, frame: int) -> Finding:
    """T5: the read answer that took a transaction's B5 answers above the threshold."""
    return finding("b5_polling", frame, "txn.b5_retries", retries, f"<= {threshold}",
                   f"more than {threshold} B5 (not ready) answers")


def mirroring(txn: Txn, r: Head, frame: int) -> tuple[list[Finding], bool]:
    """Q2-Q5: a response mirrors the request's reference, Request ID, DO and No. of parameters (protocol.md
    6.4); (findings, whether Q2 or Q3 failed: the verdict is then reference_mismatch). A request field
    not known is -1 and not compared; `txn.vendor`: the Response IDs of a vendor's own Request ID (5.5)."""
    out = []
    mismatch = False
    if txn.ref >= 0 and r.ref != txn.ref:
        out.append(finding("reference_mismatch", frame, "pd.ref", r.ref, txn.ref,
                           f"response reference {r.ref} does not mirror the request's {txn.ref}"))
        mismatch = True
    expected = txn.vendor or ANSWERS.get(txn.req_id, (pt.RES_NOT_SUPPORTED,))
    if txn.req_id >= 0 and r.ident not in expected:  # (a request cut before its header: nothing to answer)
        out.append(finding("response_id_mismatch", frame, "pd.resp_id", f"{r.ident:#04x}",
                           "/".join(f"{e:#04x}" for e in expected),
                           f"Response ID {r.ident:#04x} does not answer Request ID {txn.req_id:#04x}"))
        mismatch = True
    if txn.do >= 0 and r.do != txn.do:
        out.append(finding("do_not_mirrored", frame, "pd.do", r.do, txn.do, "DO-ID not mirrored"))
    header_level = r.ident & 0x80 and r.blocks == 1 and r.first_error
    if txn.n_params >= 0 and r.n != txn.n_params and not header_level:
        out.append(finding("n_params_not_mirrored", frame, "pd.n_params", r.n, txn.n_params,
                           "No. of parameters not mirrored"))
    return out, mismatch
