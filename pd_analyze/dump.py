"""The Wireshark-style dump: a text tree or JSON Lines, one entry per PNIO RPC frame."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable

from pd_analyze.dissect import FrameResult
from pd_analyze.rules import ERROR, INFO, WARNING, Finding
from pd_analyze.structs import Field, json_value

Style = Callable[[str, str], str]  # (text, role) -> text, roles: severity names, "frame", "dim"
_SEV_LETTER = {ERROR: "E", WARNING: "W", INFO: "I"}


def plain_style(text: str, role: str) -> str:
    del role
    return text


def safe(text: str) -> str:
    """Control characters and escape sequences shown escaped, never emitted raw to a terminal."""
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii") for ch in text)


def mark_checks(result: FrameResult, checked: frozenset[str]) -> None:
    """Each field's check result: the finding that names it, or 'ok' for a checked field."""
    by_field: dict[str, list[Finding]] = {}
    for f in result.findings:
        by_field.setdefault(f.field, []).append(f)
    for fld in result.fields():
        mark_field(fld, by_field, checked)


def mark_field(fld: Field, by_field: dict[str, list[Finding]], checked: frozenset[str]) -> None:
    found = by_field.get(fld.name)
    if found:
        broken = "; ".join(f"{f.rule} {f.severity}: {f.message}" for f in found)
        fld.check = broken
    elif not fld.check and fld.name in checked:
        fld.check = "ok"


def frame_json(result: FrameResult) -> str:
    """One JSON Lines object; fields are written directly (names are registry names, strings are
    escaped by the json module's encoder), as json.dumps of a dict per field costs several times more."""
    fields = ",".join(
        f'{{"name":"{f.name}","offset":{f.offset},"length":{f.length},"raw":"{f.raw.hex()}",'
        f'"value":{_json_value(f.value)},"show":{_esc(f.show)},"check":{_esc(f.check)}}}'
        for layer in result.layers for f in layer.fields)
    head = json.dumps({"frame": result.frame, "time": result.ts, "src": result.src, "dst": result.dst,
                       "summary": result.summary}, ensure_ascii=True, separators=(",", ":"))
    findings = json.dumps([f.as_dict() for f in result.findings], ensure_ascii=True, separators=(",", ":"))
    return f'{head[:-1]},"fields":[{fields}],"findings":{findings}}}'


_esc = json.encoder.encode_basestring_ascii


def _json_value(value: object) -> str:
    if isinstance(value, bool) or value is None:
        return "true" if value is True else "false" if value is False else "null"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return _esc(value)
    return json.dumps(json_value(value), ensure_ascii=True, separators=(",", ":"))


def frame_text(result: FrameResult, style: Style = plain_style, findings_only: bool = False) -> str:
    head = style(f"Frame {result.frame}", "frame") + \
        f"  {result.ts:.6f}  {result.src} -> {result.dst}  {safe(result.summary)}"
    lines = [head]
    if not findings_only:
        for layer in result.layers:
            indent = "  " * (layer.depth + 1)
            lines.append(f"{indent}{safe(layer.title)}")
            lines += [_field_line(f, indent + "  ", style) for f in layer.fields]
    lines += [finding_line(f, "  ", style) for f in result.findings]
    return "\n".join(lines)


def decoded_text(sections: list[tuple[str, list[Field]]], findings: list[Finding], style: Style = plain_style) -> str:
    """`pd-analyze decode` as text: the same tree as the dump, offsets within the pasted bytes."""
    lines = []
    for title, fields in sections:
        lines.append(f"  {safe(title)}")
        lines += [_field_line(f, "    ", style) for f in fields]
    lines += [finding_line(f, "  ", style) for f in findings]
    if not findings:
        lines.append("  no findings")
    return "\n".join(lines)


def decoded_json(sections: list[tuple[str, list[Field]]], findings: list[Finding]) -> str:
    return json.dumps({"fields": [f.as_dict() for _, fields in sections for f in fields],
                       "findings": [f.as_dict() for f in findings]}, ensure_ascii=True, separators=(",", ":"))


def _field_line(f: Field, indent: str, style: Style) -> str:
    if f.offset < 0:
        where = " " * 32
    else:
        raw = f.raw[:8].hex(" ") + (" .." if len(f.raw) > 8 else "")
        where = f"{f.offset:04x}  {raw:<26}"
    line = f"{indent}{style(where, 'dim')}  {f.name} = {safe(f.show)}"
    if f.check:
        line += "  " + style(f"[{safe(f.check)}]", _check_role(f.check))
    return line


def _check_role(check: str) -> str:
    for sev in (ERROR, WARNING, INFO):
        if f" {sev}:" in check:
            return sev
    return "warning" if "BREAKS" in check else "dim"


def finding_line(f: Finding, indent: str = "", style: Style = plain_style) -> str:
    letter = _SEV_LETTER.get(f.severity, "?")
    detail = []
    if f.value:
        detail.append(f"value {f.value}")
    if f.expected:
        detail.append(f"expected {f.expected}")
    extra = f" ({'; '.join(detail)})" if detail else ""
    text = f"{indent}! {letter} {f.rule} {f.name} [{f.field}]: {f.message}{extra}"
    return style(safe(text), f.severity)


def parse_frames(spec: str) -> Callable[[int], bool]:
    """'1,5-9,20-' to a frame-number predicate; ValueError with a helpful message if malformed."""
    ranges: list[tuple[int, int]] = []
    for part in spec.split(","):
        part = part.strip()
        if not part:
            continue
        lo, sep, hi = part.partition("-")
        try:
            start = int(lo) if lo else 1
            end = int(hi) if hi else (10**12 if sep else start)
        except ValueError:
            raise ValueError(f"bad frame range {part!r}: use numbers like 1,5-9,20-") from None
        if start < 1 or end < start:
            raise ValueError(f"bad frame range {part!r}: frames are numbered from 1, low before high")
        ranges.append((start, end))
    if not ranges:
        raise ValueError("empty frame selection: use numbers like 1,5-9,20-")
    return lambda n: any(lo <= n <= hi for lo, hi in ranges)


def render(results: Iterable[FrameResult], fmt: str, write: Callable[[str], None], style: Style,
           findings_only: bool, checked: frozenset[str]) -> int:
    """Write each result; returns the number of frames written."""
    count = 0
    for result in results:
        if findings_only and not result.findings:
            continue
        mark_checks(result, checked)
        write(frame_json(result) if fmt == "json" else frame_text(result, style, findings_only) + "\n")
        count += 1
    return count
