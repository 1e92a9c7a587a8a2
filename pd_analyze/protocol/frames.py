"""What the dissector hands on per frame: its layers of annotated fields, its findings, its PDU; and the
accounting of every frame read."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator, MutableSequence
from dataclasses import dataclass, field

from pd_analyze.model.rules import Finding
from pd_analyze.model.shown import Annotated, Field
from pd_analyze.protocol import link
from pd_analyze.protocol import pnio as rec
from pd_analyze.protocol.rpc_calls import Call


@dataclass(slots=True)
class Layer:
    title: str
    depth: int
    fields: MutableSequence[Field]  # a list, or a Layout's Annotated (the same fields, made as they are read)


@dataclass(slots=True)
class Pdu:
    """A complete PNIO RPC PDU (request, response, fault or reject) with its decoded stub."""

    frame: int
    ts: float
    src: bytes
    dst: bytes
    sport: int
    dport: int
    ptype: int
    opnum: int
    activity: bytes
    seq: int
    stub: rec.Stub | None = None
    request: Call | None = None  # for responses/faults: the call they answer
    retransmission: bool = False
    fault_status: int | None = None
    malformed: bool = False
    fragments: tuple[int, ...] = ()  # frames of the IP/CL fragments it was reassembled from
    first_ts: float | None = None  # a request is timed at its first frame (protocol.md 7.6)
    interface: bytes = b""
    unpaired: bool = False  # a PDU cut before its body could be read as a request or response: no call
    digest: tuple[int, int] = (0, 0)  # a request's body: CRC-32 and size (a copy or a reused key, 2.4)


@dataclass(slots=True)
class FrameResult:
    frame: int
    ts: float
    src_ip: bytes
    dst_ip: bytes
    summary: str
    ptype: int
    layers: list[Layer] = field(default_factory=list)
    findings: list[Finding] = field(default_factory=list)
    pdu: Pdu | None = None
    # A dissector without pairing (`Dissector(pairing=False)`, the analysis engine's decoder) leaves these
    # to its caller: whether the frame is PNIO at all is decided by its call or activity (`decide`: a PDU
    # other than a request whose interface is not a PNIO one, counted as `counted` says), and the call
    # key of a request fragment it dropped as an identical copy (`fragment_copy`: the call counts it)
    decide: bool = False
    counted: str = ""  # "" decoded, else the malformed reason it was counted under
    fragment_copy: tuple[bytes, int] | None = None
    key: tuple[bytes, int] | None = None  # the call (activity, sequence number) of the frame's RPC header
    truncated: bool = False  # captured shorter than its IP total length

    @property
    def src(self) -> str:
        return link.ip_text(self.src_ip)

    @property
    def dst(self) -> str:
        return link.ip_text(self.dst_ip)

    def fields(self) -> Iterator[Field]:
        for layer in self.layers:
            yield from layer.fields


@dataclass(slots=True)
class Accounting:
    """Every frame read is decoded, skipped (by reason) or malformed (by reason)."""

    read: int = 0
    decoded: int = 0
    skipped: Counter = field(default_factory=Counter)
    malformed: Counter = field(default_factory=Counter)

    def balanced(self) -> bool:
        return self.read == self.decoded + sum(self.skipped.values()) + sum(self.malformed.values())

    def line(self) -> str:
        skipped = sum(self.skipped.values())
        parts = [f"{self.read} frames read", f"{self.decoded} PNIO RPC decoded", f"{skipped} skipped"]
        if self.skipped:
            parts[-1] += " (" + ", ".join(f"{n} {why}" for why, n in ranked(self.skipped)) + ")"
        if self.malformed:
            parts.append(f"{sum(self.malformed.values())} malformed (" + ", ".join(
                f"{n} {why}" for why, n in ranked(self.malformed)) + ")")
        return ", ".join(parts)


def ranked(reasons: Counter) -> list[tuple[str, int]]:
    """Reasons by count, most first, ties by name: the same whatever order the frames were counted in."""
    return sorted(reasons.items(), key=lambda item: (-item[1], item[0]))


def mark_checks(result: FrameResult, checked: frozenset[str]) -> None:
    """Each field's check result: the finding that names it, or 'ok' for a checked field. A field is
    replaced by itself with the check (a Layout's fields are shared between frames, SharedField)."""
    by_field: dict[str, list[Finding]] = {}
    for f in result.findings:
        by_field.setdefault(f.field, []).append(f)
    for layer in result.layers:
        fields = layer.fields
        if fields.__class__ is Annotated:
            if not fields.made and by_field.keys().isdisjoint(fields.view.names):
                fields.checked = checked  # no finding names these fields: the checked ones show "ok" as read
                continue
            fields = fields.materialize()
        for i, fld in enumerate(fields):  # some 60 a frame: two set lookups each, a call only where a finding is
            name = fld.name
            if name in by_field:
                fields[i] = mark_field(fld, by_field, checked)
            elif name in checked and not fld.check:
                fields[i] = fld.with_check("ok")


def mark_field(fld: Field, by_field: dict[str, list[Finding]], checked: frozenset[str]) -> Field:
    """The field with its check: the findings that name it, else 'ok' for a checked field."""
    found = by_field.get(fld.name)
    if found:
        return fld.with_check("; ".join(f"{f.rule} {f.severity}: {f.message}" for f in found))
    if not fld.check and fld.name in checked:
        return fld.with_check("ok")
    return fld
