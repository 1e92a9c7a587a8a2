"""What a sample is built to contain, recorded while it is built.

A sample function states each injected violation next to the line that
injects it (`Intent.on(frames, rule)`), and each PROFIdrive transaction with
the verdict protocol.md 7.4 gives it (`Intent.txn`). Frame objects are
resolved to 1-based frame numbers only when the file is complete, so the
expectations follow the frames if a sample grows.

The result is written to sample_pcaps/expected/<file>.json:

    {"file": ..., "profiles": [{"profile": "generic", "findings": [[frame, rule], ...]}, ...],
     "transactions": [{"ref": .., "frames": [first, last], "verdict": .., ...}, ...],
     "loose": [[frame, rule], ...]}

"profiles" holds the frame-level rules of protocol.md 6.1-6.4 (rule names of
pd_analyze/model/rules.py), per vendor profile; "transactions" the transaction
model (7.3, 7.4, 7.6) for each PROFIdrive transaction, in the order of the
write requests: first/last frame, reference, verdict, read calls, B5
answers, duplicate request PDUs, the PNIOStatus that ended it (or DE80B500
when it timed out after a B5), whether it was still open at capture end,
t_write_rtt and t_total in seconds as written to the file (µs or ns; null
where the transaction has no such frame), and the transaction-level findings (Q2-Q5,
T1-T6, which do not depend on the profile). "loose" lists the
transaction-level findings on frames of no transaction (T2). The figures
come from the generator's own frame times and answers (`Call.status`,
`Call.fault`, `Call.retransmits`); nothing here consults the analyser.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from .capture_files import Frame
from .pnio_encode import STATUS_B5, STATUS_OK
from .rpc_session import Call
from .sim_capture import Capture

GENERIC = "generic"
B5_TEXT = STATUS_B5.hex().upper()


@dataclass
class _Txn:
    calls: list[Call]
    ref: int | None
    verdict: str
    note: str
    findings: list[tuple[Frame, str]]
    extra: dict[str, Any]
    decided: Frame | None = None  # the frame that decided a failed verdict (T8), when not the default
    copies: list[Frame] = field(default_factory=list)  # copies of its calls' frames (a mirror port's)


@dataclass
class Intent:
    """Expected findings (per profile) and transactions of one capture."""

    cap: Capture
    profiles: tuple[str, ...] = (GENERIC,)
    resolution_ns: int | Mapping[int, int] = 1000  # timestamp unit as written (per interface for pcapng)
    _findings: list[tuple[Frame, str, tuple[str, ...]]] = field(default_factory=list)
    _txns: list[_Txn] = field(default_factory=list)
    _loose: list[tuple[Frame, str]] = field(default_factory=list)

    def on(self, frames: Frame | Iterable[Frame], rule: str, *, profiles: Sequence[str] | None = None) -> None:
        """Rule `rule` fires once on each frame given, under `profiles`
        (default: every profile of this file)."""
        where = tuple(self.profiles if profiles is None else profiles)
        unknown = set(where) - set(self.profiles)
        if unknown:
            raise ValueError(f"profiles {sorted(unknown)} not declared for this file")
        for f in [frames] if isinstance(frames, Frame) else list(frames):
            self._findings.append((f, rule, where))

    def txn(
        self,
        calls: Sequence[Call],
        ref: int | None,
        verdict: str,
        note: str = "",
        *,
        findings: Sequence[tuple[Frame, str]] = (),
        decided: Frame | None = None,
        copies: Sequence[Frame] = (),
        **extra: Any,
    ) -> list[Call]:
        """One PROFIdrive transaction: its calls (write, reads), reference
        (None: not in the capture, the request cut before it) and verdict;
        reads, b5_retries (reads answered DE 80 B5 00), rpc_retransmissions,
        pnio_status and the figures are derived from the calls, `extra` adds or overrides (e.g. capture_ended=True for a
        transaction still open at capture end). `findings` are the
        transaction-level rules (protocol.md 6.4 Q2-Q5, 6.5 T1-T6) the
        pairing must report, as (frame, rule). T8 txn_failed and T9 txn_refused (protocol.md 6.5) are added
        at the frame that decided the verdict (`_decided`); `decided` states it where the calls cannot: the
        undecodable PDU of a malformed transaction (or `superseded`, for the write that ended it)."""
        self._txns.append(_Txn(list(calls), ref, verdict, note, list(findings), extra, decided, list(copies)))
        return list(calls)

    def superseded(self, calls: Sequence[Call], by: Frame) -> None:
        """The transaction of `calls` ended by the write request at `by` (T3 is the new one's): its T8 there."""
        txn = next(t for t in self._txns if t.calls == list(calls))
        txn.decided = by

    def loose(self, frames: Frame | Iterable[Frame], rule: str) -> None:
        """A transaction-level rule (e.g. T2 read_without_request) on a frame of no transaction."""
        for f in [frames] if isinstance(frames, Frame) else list(frames):
            self._loose.append((f, rule))

    # ---- frame selectors for the usual places of a finding -------------------------------------------
    @staticmethod
    def write_req(calls: Sequence[Call]) -> Frame:
        return calls[0].request[0]

    @staticmethod
    def read_reqs(calls: Sequence[Call]) -> list[Frame]:
        return [c.request[0] for c in calls[1:]]

    @staticmethod
    def final_res(calls: Sequence[Call]) -> Frame:
        return calls[-1].response[-1]

    # ---- output ----------------------------------------------------------------------------------------
    def render(self, name: str) -> dict[str, Any]:
        num = self.cap.number
        profiles = []
        for prof in self.profiles:
            found = sorted((num(f), rule) for f, rule, where in self._findings if prof in where)
            profiles.append({"profile": prof, "findings": [list(x) for x in found]})
        txns = []
        for t in self._txns:
            frames = [num(f) for c in t.calls for f in c.request + c.response] + [num(f) for f in t.copies]
            item: dict[str, Any] = {"ref": t.ref, "frames": [min(frames), max(frames)], "verdict": t.verdict}
            item.update(self._figures(t))
            item.update(t.extra)
            outcome = self._outcome(t)
            if t.findings or outcome:
                item["findings"] = sorted([num(f), rule] for f, rule in [*t.findings, *outcome])
            if t.note:
                item["note"] = t.note
            txns.append(item)
        txns.sort(key=lambda item: item["frames"][0])  # the order of the write requests
        out: dict[str, Any] = {"file": name, "profiles": profiles, "transactions": txns}
        if self._loose:
            out["loose"] = sorted([num(f), rule] for f, rule in self._loose)
        return out

    @staticmethod
    def _outcome(t: _Txn) -> list[tuple[Frame, str]]:
        """T8 or T9 at the frame that decided the verdict (protocol.md 6.5): a NAK's final response; the answer
        that refused a record service (a fault or reject too); for a transaction that got no final answer
        (a timeout, or a busy drive given up) the write that superseded it (`superseded`), else its write
        request, where the deadline or the capture's end closed it; a malformed one's undecodable PDU."""
        if t.verdict == "nak":
            return [(t.calls[-1].response[-1], "txn_refused")]
        if t.verdict not in ("pnio_error", "timeout", "malformed"):
            return []
        if t.decided is not None:
            return [(t.decided, "txn_failed")]
        if t.verdict == "malformed":
            raise ValueError(f"malformed transaction {t.note!r}: state its undecodable PDU (decided=)")
        ending = next((c for c in t.calls if c.fault is not None or c.status not in (None, STATUS_OK, STATUS_B5)),
                      None)
        if ending is not None:
            return [(ending.response[-1], "txn_failed")]
        return [(t.calls[0].request[-1], "txn_failed")]

    def _ticks(self, frame: Frame) -> int:
        """The frame time as written to the file, in ns (truncated to the file's resolution)."""
        res = self.resolution_ns if isinstance(self.resolution_ns, int) else self.resolution_ns[frame.iface]
        return (frame.ts_ns or 0) // res * res

    def _figures(self, t: _Txn) -> dict[str, Any]:
        """protocol.md 7.6 from the calls: a request is timed at its first frame, a response at its last."""
        write, reads = t.calls[0], t.calls[1:]
        start = self._ticks(write.request[0])
        b5 = sum(1 for c in reads if c.status == STATUS_B5)
        ending = next((c for c in t.calls if c.fault is not None or c.status not in (None, STATUS_OK, STATUS_B5)), None)
        status = ""
        if ending is not None:
            status = f"{ending.fault:08X}" if ending.fault is not None else (ending.status or b"").hex().upper()
        elif t.verdict in ("timeout", "pnio_error") and b5:
            status = B5_TEXT  # the last answer was B5 (a timeout), or every one (7.3 step 5)
        final = reads[-1] if reads else None
        delivered = final is not None and final.response and final.status == STATUS_OK and t.verdict != "timeout"

        def seconds(frame: Frame) -> float:
            return round((self._ticks(frame) - start) / 1e9, 9)

        return {
            "reads": len(reads),
            "b5_retries": b5,
            "rpc_retransmissions": sum(c.retransmits for c in t.calls),
            "pnio_status": status,
            "capture_ended": False,
            "t_write_rtt": seconds(write.response[-1]) if write.response else None,
            "t_total": seconds(final.response[-1]) if delivered and final is not None else None,
        }


def dumps(expected: dict[str, Any]) -> str:
    """Stable JSON with one finding / transaction per line (diff-friendly)."""
    lines = ["{", f'  "file": {json.dumps(expected["file"])},', '  "profiles": [']
    profs = expected["profiles"]
    for i, p in enumerate(profs):
        lines.append(f'    {{"profile": {json.dumps(p["profile"])}, "findings": [')
        items = [f"      {json.dumps(x)}" for x in p["findings"]]
        lines += [s + ("," if k < len(items) - 1 else "") for k, s in enumerate(items)]
        lines.append("    ]}" + ("," if i < len(profs) - 1 else ""))
    lines.append("  ],")
    txns = expected.get("transactions", [])
    loose = expected.get("loose", [])
    lines.append('  "transactions": [')
    items = [f"    {json.dumps(t, ensure_ascii=False)}" for t in txns]
    lines += [s + ("," if k < len(items) - 1 else "") for k, s in enumerate(items)]
    lines.append("  ]," if loose else "  ]")
    if loose:
        lines.append(f'  "loose": {json.dumps(loose)}')
    lines.append("}")
    return "\n".join(lines) + "\n"
