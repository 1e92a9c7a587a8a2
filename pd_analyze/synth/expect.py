"""What a sample is built to contain, recorded while it is built.

A sample function states each injected violation next to the line that
injects it (`Intent.on(frames, rule)`), and each PROFIdrive transaction with
the verdict protocol.md 7.4 gives it (`Intent.txn`). Frame objects are
resolved to 1-based frame numbers only when the file is complete, so the
expectations follow the frames if a sample grows.

The result is written to sample_pcaps/expected/<file>.json:

    {"file": ..., "profiles": [{"profile": "generic", "findings": [[frame, rule], ...]}, ...],
     "transactions": [{"ref": .., "frames": [first, last], "verdict": .., ...}, ...]}

"profiles" holds the frame-level rules of protocol.md 6.1-6.4 (rule names of
pd_analyze/rules.py), per vendor profile; "transactions" the transaction
model (7.3, 7.4) for each PROFIdrive transaction: first/last frame, verdict,
reads, B5 answers, and the transaction-level findings (Q2-Q5, T1-T6, which
do not depend on the profile). Nothing here consults the analyser.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from .scenario import Call, Capture
from .writers import Frame

GENERIC = "generic"


@dataclass
class _Txn:
    calls: list[Call]
    ref: int
    verdict: str
    note: str
    findings: list[tuple[Frame, str]]
    extra: dict[str, Any]


@dataclass
class Intent:
    """Expected findings (per profile) and transactions of one capture."""

    cap: Capture
    profiles: tuple[str, ...] = (GENERIC,)
    _findings: list[tuple[Frame, str, tuple[str, ...]]] = field(default_factory=list)
    _txns: list[_Txn] = field(default_factory=list)

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
        ref: int,
        verdict: str,
        note: str = "",
        *,
        findings: Sequence[tuple[Frame, str]] = (),
        **extra: Any,
    ) -> list[Call]:
        """One PROFIdrive transaction: its calls (write, reads), reference
        and verdict; reads and b5_retries (all reads but the last) are
        counted from the calls, `extra` adds or overrides figures.
        `findings` are the transaction-level rules (protocol.md 6.4 Q2-Q5,
        6.5 T1-T6) the pairing must report, as (frame, rule)."""
        self._txns.append(_Txn(list(calls), ref, verdict, note, list(findings), extra))
        return list(calls)

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
            frames = [num(f) for c in t.calls for f in c.request + c.response]
            reads = t.calls[1:]
            item: dict[str, Any] = {"ref": t.ref, "frames": [min(frames), max(frames)], "verdict": t.verdict}
            if reads:
                # every read but the last is a B5 answer (the last delivers the response or ends the txn)
                item["reads"] = len(reads)
                item["b5_retries"] = len(reads) - 1
            item.update(t.extra)
            if t.findings:
                item["findings"] = sorted([num(f), rule] for f, rule in t.findings)
            if t.note:
                item["note"] = t.note
            txns.append(item)
        return {"file": name, "profiles": profiles, "transactions": txns}


def dumps(expected: dict[str, Any]) -> str:
    """Stable JSON with one finding / transaction per line (diff-friendly)."""
    lines = ["{", f'  "file": {json.dumps(expected["file"])},', '  "profiles": [']
    profs = expected["profiles"]
    for i, p in enumerate(profs):
        lines.append(f'    {{"profile": {json.dumps(p["profile"])}, "findings": [')
        items = [f"      {json.dumps(x)}" for x in p["findings"]]
        lines += [s + ("," if k < len(items) - 1 else "") for k, s in enumerate(items)]
        lines.append("    ]}" + ("," if i < len(profs) - 1 else ""))
    txns = expected.get("transactions", [])
    lines.append("  ]," if txns else "  ]")
    if txns:
        lines.append('  "transactions": [')
        items = [f"    {json.dumps(t, ensure_ascii=False)}" for t in txns]
        lines += [s + ("," if k < len(items) - 1 else "") for k, s in enumerate(items)]
        lines.append("  ]")
    lines.append("}")
    return "\n".join(lines) + "\n"
