"""The Wireshark-style dump: a text tree or JSON Lines, one entry per PNIO RPC frame."""

from __future__ import annotations

import gc
import json
import math
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import IO

from pd_analyze.model.rules import ERROR, INFO, WARNING, Finding
from pd_analyze.model.shown import Annotated, Field, SharedField, json_value
from pd_analyze.output.terminal import safe
from pd_analyze.protocol.frames import FrameResult

Style = Callable[[str, str], str]  # (text, role) -> text, roles: severity names, "frame", "dim"
_SEV_LETTER = {ERROR: "E", WARNING: "W", INFO: "I"}


def plain_style(text: str, role: str) -> str:
    del role
    return text


def frame_json(result: FrameResult) -> str:
    """One JSON Lines object, written directly rather than by json.dumps of a dict per field (several
    times dearer). The text equals json.dumps(..., ensure_ascii=True, separators=(",", ":")): names
    are registry names, strings go through the json module's own escaping, numbers as json writes them.
    A Layout's field (SharedField) keeps its JSON object, made for the first frame that has it, and a
    Layout's structure its runs' objects (Annotated.json)."""
    fields = []
    add = fields.append
    for layer in result.layers:
        shown = layer.fields
        if shown.__class__ is Annotated and not shown.made:
            add(shown.json(_shared_json, _slot_json))
            continue
        for f in shown:
            if f.__class__ is SharedField:
                add(f.json or _shared_json(f))
            else:
                add(_json_field(f))
    head = (f'{{"frame":{_json_value(result.frame)},"time":{_json_value(result.ts)},"src":{_json_value(result.src)},'
            f'"dst":{_json_value(result.dst)},"summary":{_json_value(result.summary)}')
    findings = json.dumps([f.as_dict() for f in result.findings], ensure_ascii=True, separators=(",", ":")) \
        if result.findings else "[]"
    return f'{head},"fields":[{",".join(fields)}],"findings":{findings}}}'


def _shared_json(f: SharedField) -> str:
    f.json = text = _json_field(f)
    return text


def _json_field(f: Field) -> str:
    """A field's JSON object."""
    value, check = f.value, f.check
    return (f'{{"name":"{f.name}","offset":{f.offset},"length":{f.length},"raw":"{f.raw.hex()}",'
            f'"value":{value if type(value) is int else _json_value(value)},"show":{_esc(f.show)},'
            f'"check":{_CHECKS.get(check) or _esc(check)}}}')


def _slot_json(name: str, offset: int, length: int, raw: bytes, value: object, show: str, check: str,
               indent: str) -> str:
    """_json_field of a field given by its parts (a Layout's field whose values keep changing: shown.Slot)."""
    del indent
    return (f'{{"name":"{name}","offset":{offset},"length":{length},"raw":"{raw.hex()}",'
            f'"value":{value if type(value) is int else _json_value(value)},"show":{_esc(show)},'
            f'"check":{_CHECKS.get(check) or _esc(check)}}}')


_esc = json.encoder.encode_basestring_ascii
_CHECKS = {"": '""', "ok": '"ok"'}  # nearly every field's check


def _json_value(value: object) -> str:
    kind = type(value)  # the exact types first: bool is an int, and int/float subclasses may print otherwise
    if kind is str:
        return _esc(value)
    if kind is int:
        return int.__repr__(value)
    if kind is bytes:
        return f'"{value.hex()}"'
    if kind is float and math.isfinite(value):
        return float.__repr__(value)
    if isinstance(value, bool) or value is None:
        return "true" if value is True else "false" if value is False else "null"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return _esc(value)
    return json.dumps(json_value(value), ensure_ascii=True, separators=(",", ":"))


# How a frame's time is shown, as tshark's -t: e seconds since the epoch (the default), ad / a local date and
# time / time, ud / u the same in UTC, r seconds since the capture's first PNIO RPC frame, dd seconds since
# the previous frame shown.
TIME_FORMATS = ("e", "ad", "a", "ud", "u", "r", "dd")


class Clock:
    """A frame's time as text in one of TIME_FORMATS; `first` is set from the first frame dissected."""

    def __init__(self, fmt: str = "e") -> None:
        self.fmt = fmt
        self.first: float | None = None
        self._shown: float | None = None

    def watch(self, results: Iterable[FrameResult]) -> Iterator[FrameResult]:
        """The results unchanged; the first one's time is where relative times count from."""
        for res in results:
            if self.first is None:
                self.first = res.ts
            yield res

    def text(self, ts: float) -> str:
        fmt = self.fmt
        if ts != ts or fmt == "e":
            return f"{ts:.6f}"
        if fmt == "r":
            return f"{ts - (ts if self.first is None else self.first):.6f}"
        if fmt == "dd":
            delta = 0.0 if self._shown is None else ts - self._shown
            self._shown = ts
            return f"{delta:.6f}"
        when = datetime.fromtimestamp(ts, UTC if fmt in ("ud", "u") else None)
        if fmt in ("ad", "ud"):
            return when.strftime("%Y-%m-%d %H:%M:%S.%f") + (" UTC" if fmt == "ud" else "")
        return when.strftime("%H:%M:%S.%f")


def frame_text(result: FrameResult, style: Style = plain_style, findings_only: bool = False,
               clock: Clock | None = None) -> str:
    return frame_head(result, style, clock) + frame_body(result, style, findings_only)


def frame_head(result: FrameResult | Spooled, style: Style = plain_style, clock: Clock | None = None) -> str:
    """A frame's first line: number, time (`clock`'s, in the order the frames are written), addresses, summary."""
    when = clock.text(result.ts) if clock is not None else f"{result.ts:.6f}"
    return style(f"Frame {result.frame}", "frame") + f"  {when}  {result.src} -> {result.dst}  {safe(result.summary)}"


def frame_body(result: FrameResult, style: Style = plain_style, findings_only: bool = False) -> str:
    """The lines of a frame's text after its head, each after a newline: its layers and fields, its findings."""
    lines = [""]
    if not findings_only:
        add = lines.append
        kept = style is plain_style  # without colour, a Layout's fields keep their lines (SharedField, Template)
        for layer in result.layers:
            depth = layer.depth
            indent = _INDENTS[depth] if depth < len(_INDENTS) else "  " * (depth + 1)
            title = layer.title
            add(indent + (title if title.isprintable() else safe(title)))
            indent += "  "
            shown = layer.fields
            if not kept:
                lines += [_field_line(f, indent, style) for f in shown]
            elif shown.__class__ is Annotated and not shown.made:
                add(shown.text(indent, _shared_line, _slot_line))
            else:
                for f in shown:
                    if f.__class__ is SharedField:
                        add(f.line if f.indent == indent else _shared_line(f, indent))
                    else:
                        add(_field_line(f, indent, style))
    if result.findings:
        lines += [finding_line(f, "  ", style) for f in result.findings]
    return "\n".join(lines) if len(lines) > 1 else ""


class FrameSpool:
    """Frames written before their turn and kept on disk until it comes: a dump that must hold many frames
    back (behind a fragment whose PDU is still to be reassembled: output.dump_file) holds a few hundred as
    results and writes the others here. A frame's text is written whole but for its head line, made in turn
    (its time may count from the frame shown before it: -t dd); a JSON object is written whole."""

    def __init__(self, fmt: str, style: Style = plain_style, findings_only: bool = False) -> None:
        self.json_lines, self.style, self.findings_only = fmt == "json", style, findings_only
        self._file: IO[bytes] | None = None
        self._end = 0  # where the next frame is written
        self.held = 0  # frames on disk, not yet taken

    def put(self, result: FrameResult) -> Spooled:
        """`result` (its findings set) written to disk; what stands for it until its turn."""
        text = frame_json(result) if self.json_lines else frame_body(result, self.style, self.findings_only)
        data = text.encode("utf-8", "surrogatepass")
        if self._file is None:
            self._file = tempfile.TemporaryFile()  # noqa: SIM115  (open while frames wait: close())
        self._file.seek(self._end)
        self._file.write(data)
        out = Spooled(result.frame, result.ts, result.src, result.dst, result.summary, bool(result.findings), self,
                      self._end, len(data))
        self._end += len(data)
        self.held += 1
        return out

    def take(self, spooled: Spooled) -> str:
        assert self._file is not None
        self._file.seek(spooled.at)
        text = self._file.read(spooled.size).decode("utf-8", "surrogatepass")
        self.held -= 1
        if not self.held:  # every frame written has been taken: the file starts again
            self._end = 0
            self._file.truncate(0)
        return text

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


@dataclass(slots=True)
class Spooled:
    """A frame on a FrameSpool: what its head line and `render` need; the rest is on disk."""

    frame: int
    ts: float
    src: str
    dst: str
    summary: str
    findings: bool
    spool: FrameSpool
    at: int
    size: int

    def text(self, style: Style, clock: Clock | None) -> str:
        body = self.spool.take(self)
        return body if self.spool.json_lines else frame_head(self, style, clock) + body


_INDENTS = tuple("  " * (depth + 1) for depth in range(8))  # a layer's indent by its depth


def _shared_line(f: SharedField, indent: str) -> str:
    """A shared field's line, kept on it for the next frame with the field at this indent."""
    text = _field_line(f, indent, plain_style)
    f.line, f.indent = text, indent
    return text


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
    if style is plain_style:
        return _slot_line(f.name, f.offset, f.length, f.raw, f.value, f.show, f.check, indent)
    if f.offset < 0:
        where = _NOWHERE
    else:
        raw = f.raw[:8].hex(" ") + (" .." if len(f.raw) > 8 else "")
        where = f"{f.offset:04x}  {raw:<26}"
    text = f"{style(where, 'dim')}  {f.name} = {safe(f.show)}"
    check = f.check
    if not check:
        return f"{indent}{text}"
    return f"{indent}{text}  {style(*_mark(check))}"


def _slot_line(name: str, offset: int, length: int, raw: bytes, value: object, show: str, check: str,
               indent: str) -> str:
    """A field's text line without colour, from its parts (shown.Slot): at `indent`, its offset and first
    bytes (none for a derived field, offset -1), name, shown value and its check in brackets."""
    del length, value
    where = f"{offset:04x}  {raw[:8].hex(' ') + (' ..' if len(raw) > 8 else ''):<26}" if offset >= 0 else _NOWHERE
    if not show.isprintable():
        show = safe(show)
    if not check:
        return f"{indent}{where}  {name} = {show}"
    return f"{indent}{where}  {name} = {show}  {(_MARKS.get(check) or _mark(check))[0]}"


_NOWHERE = " " * 32  # the offset and bytes columns of a derived field


def _mark(check: str) -> tuple[str, str]:
    """A check's bracketed text and its style role, kept for the next field with this check."""
    mark = _MARKS.get(check)
    if mark is None:
        mark = (f"[{safe(check)}]", _check_role(check))
        if len(_MARKS) < 4096:  # check texts repeat ("ok", the profile limits); a few hold values
            _MARKS[check] = mark
    return mark


_MARKS: dict[str, tuple[str, str]] = {}  # check text -> (its bracketed text, its style role)


def _check_role(check: str) -> str:
    for sev in (ERROR, WARNING, INFO):
        if f" {sev}:" in check:
            return sev
    if check.startswith("failed: "):  # a PNIOStatus reporting a failed record service
        return ERROR
    if check.startswith("not ready: "):  # B5 polling: normal while the drive works on the request
        return WARNING
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
    ranges = frame_ranges(spec)
    return lambda n: any(lo <= n <= hi for lo, hi in ranges)


OPEN_END = 10**12  # the last frame of an open range (20-)


def frame_ranges(spec: str) -> list[tuple[int, int]]:
    """'1,5-9,20-' as (first, last) pairs, an open end as OPEN_END; ValueError if malformed."""
    ranges: list[tuple[int, int]] = []
    for part in spec.split(","):
        part = part.strip()
        if not part:
            continue
        lo, sep, hi = part.partition("-")
        try:
            start = int(lo) if lo else 1
            end = int(hi) if hi else (OPEN_END if sep else start)
        except ValueError:
            raise ValueError(f"bad frame range {part!r}: use numbers like 1,5-9,20-") from None
        if start < 1 or end < start:
            raise ValueError(f"bad frame range {part!r}: frames are numbered from 1, low before high")
        ranges.append((start, end))
    if not ranges:
        raise ValueError("empty frame selection: use numbers like 1,5-9,20-")
    return ranges


def render(results: Iterable[FrameResult | Spooled], fmt: str, write: Callable[[str], None], style: Style,
           findings_only: bool, clock: Clock | None = None) -> int:
    """Write each result (`write` takes one frame's text or JSON object and ends it with a newline); returns
    the number of frames written. Frames are handed to `write` in blocks of about BLOCK_CHARS, joined by
    newlines (the same bytes as one call each: a call per frame cost more than its text), the last block
    when the results end or fail (a capture damaged after its good frames). The results are usually made
    while this loop draws them (the dissector), so the garbage collector's young generation is collected
    less often meanwhile (see fewer_collections)."""
    count = size = 0
    block: list[str] = []
    add = block.append
    json_lines = fmt == "json"
    try:
        with fewer_collections():
            for result in results:
                if findings_only and not result.findings:
                    continue
                if result.__class__ is Spooled:
                    text = result.text(style, clock) + ("" if json_lines else "\n")  # type: ignore[union-attr]
                else:
                    text = frame_json(result) if json_lines else frame_text(result, style, findings_only, clock) + "\n"
                add(text)
                count += 1
                size += len(text)
                if size >= BLOCK_CHARS:
                    text = "\n".join(block)
                    block.clear()
                    size = 0
                    write(text)
    finally:
        if block:  # (emptied before each write: a write that failed is not tried again)
            text = "\n".join(block)
            block.clear()
            write(text)
    return count


BLOCK_CHARS = 1 << 18  # characters of frames written at once (some 50 frames of a text dump)


@contextmanager
def fewer_collections(young: int = 20_000, older: int = 100) -> Iterator[None]:
    """The cyclic garbage collector's young generation collected every `young` allocations (default 700),
    the older ones every `older` collections of the one before (default 10), and what exists before the
    dump (modules, the first pass's facts) out of its sight (gc.freeze) until it ends. A dumped frame
    allocates some 200 objects that live until it is written (its result, layers, texts), and the second
    pass held a part's frames until its odd frames were known (it holds a few hundred since): at the
    defaults, a collection ran every few frames and walked the held frames again each time (a quarter of the
    dump's time), and each collection of the middle generation walked them all once more (a tenth of it,
    measured on a 50,000-frame fault-rich capture). Cycles are rare here (none in the frames of that
    capture), so little waits longer to be freed."""
    before = gc.get_threshold()
    gc.freeze()
    gc.set_threshold(max(young, before[0]), max(older, before[1]), max(older, before[2]))
    try:
        yield
    finally:
        gc.set_threshold(*before)
        gc.unfreeze()
