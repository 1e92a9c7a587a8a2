"""One frame as display filters and `dump -T fields` see it: the dissector's fields by registry name (or the
tshark name the registry maps), the frame's own fields, and what the analysis says of it.

A field name resolves to a `FieldRef` once; `FrameView.values(ref)` gives every occurrence of it in a frame
(a repeated field, such as pd.addr.pnu of a multi-parameter request, has several), `FrameView.shown(ref)`
the occurrences as tshark 4.0 prints them in `-T fields`.
"""

from __future__ import annotations

import re
import struct
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from decimal import ROUND_HALF_EVEN, Decimal
from functools import lru_cache
from typing import Generic, TypeVar

from pd_analyze.capture import CaptureError
from pd_analyze.capture.pcapng import Block
from pd_analyze.capture.pcapng_write import BT_SPB
from pd_analyze.model import fields as registry
from pd_analyze.model.layout import Field
from pd_analyze.output.frame_layers import fields_of
from pd_analyze.output.frame_notes import FrameNote
from pd_analyze.protocol.frames import FrameResult

LAYERS, FRAME, ANALYSIS = "layers", "frame", "analysis"
# the frame's own fields: from the result or the record, not from a layer
FRAME_FIELDS = frozenset({"frame.no", "frame.ts", "frame.iface", "frame.linktype", "frame.caplen"})
_INDEXES = re.compile(r"\[(?:\d+|[ijk])\]")


@lru_cache(maxsize=65_536)
def plain(name: str) -> str:
    """A field name without its indexes: pd.val[1].value[2] and pd.val[i].value[j] -> pd.val.value."""
    return _INDEXES.sub("", name) if "[" in name else name


@lru_cache(maxsize=65_536)
def template_of(name: str) -> str:
    """registry.template, cached: concrete names repeat frame after frame."""
    return registry.template(name)


def _own_names() -> dict[str, tuple[str, ...]]:
    out: dict[str, list[str]] = {}
    for name in registry.FIELDS:  # pd.addr[i].pnu and pd.addr[2].pnu are both pd.addr.pnu
        out.setdefault(plain(name), []).append(name)
    return {name: tuple(names) for name, names in out.items()}


def _tshark_names() -> dict[str, tuple[str, ...]]:
    out: dict[str, list[str]] = {}
    for name, fdef in registry.FIELDS.items():
        for alias in (fdef.tshark or "").split("|"):
            if alias:
                out.setdefault(alias, []).append(name)
    return {alias: tuple(names) for alias, names in out.items()}


OWN = _own_names()  # name without indexes -> registry (template) names
TSHARK = _tshark_names()  # tshark name -> registry (template) names


@dataclass(frozen=True, slots=True)
class FieldRef:
    """A field name as a filter or `-e` gives it, resolved against the registry."""

    text: str
    kind: str  # LAYERS, FRAME or ANALYSIS
    names: tuple[str, ...]  # registry (template) names it covers
    fdef: registry.FieldDef  # the (first) registry entry: its type decides what a literal may be
    exact: str = ""  # a concrete indexed name (pd.addr[1].pnu): only that occurrence
    width: int = -1  # a tshark name that takes the values of one width in bytes (0: floats); -1 all


def resolve(name: str) -> FieldRef | None:
    """The field a name means: a registry name (indexes left out, or given for one occurrence), or the tshark
    4.0 name of a registry field; None when it is neither."""
    if "[" in name:
        if name in registry.FIELDS:  # the template itself: every occurrence
            return FieldRef(name, LAYERS, (name,), registry.FIELDS[name])
        template = registry.template(name)
        if template not in registry.FIELDS:
            return None
        return FieldRef(name, LAYERS, (template,), registry.FIELDS[template], exact=name)
    names = OWN.get(name)
    width = -1
    if names is None:
        names = TSHARK.get(name)
        if names is None:
            return None
        width = registry.TSHARK_VALUE_WIDTH.get(name, -1)
    return FieldRef(name, _kind(names[0]), names, registry.FIELDS[names[0]], width=width)


def _kind(plain_name: str) -> str:
    if plain_name in FRAME_FIELDS:
        return FRAME
    return ANALYSIS if plain_name in registry.ANALYSIS_FIELDS else LAYERS


class FrameView:
    """One frame: its dissected result (None for a frame that is not PNIO RPC), its record (None unless
    read, as annotate and extract do), what the analysis says of it (None: nothing, or not asked)."""

    __slots__ = ("_index", "block", "note", "number", "result", "ts")

    def __init__(self, number: int, ts: float, result: FrameResult | None, block: Block | None = None,
                 note: FrameNote | None = None) -> None:
        self.number, self.ts, self.result, self.block, self.note = number, ts, result, block, note
        self._index: dict[str, list[Field]] | None = None

    def fields(self, ref: FieldRef) -> list[Field]:
        """The dissector's fields a LAYERS reference names, in frame order; of a frame it passed by (not PNIO RPC),
        the headers it holds (output.frame_layers), when its record was read."""
        if self.result is None and self.block is None:
            return []
        if ref.exact:
            found = [f for f in self._all() if f.name == ref.exact]
        elif len(ref.names) == 1:
            found = self._by_name().get(ref.names[0], [])
        else:
            index = self._by_name()
            found = sorted((f for n in ref.names for f in index.get(n, ())), key=lambda f: f.offset)
        if ref.width >= 0:
            found = [f for f in found if _width_of(f) == ref.width]
        return found

    def _all(self) -> list[Field]:
        if self.result is not None:
            return self.result.fields()
        block = self.block
        return fields_of(block.linktype, block.raw[block.data_at:block.data_at + block.caplen])  # type: ignore[union-attr]

    def _by_name(self) -> dict[str, list[Field]]:
        if self._index is None:
            self._index = {}
            for f in self._all():
                self._index.setdefault(template_of(f.name), []).append(f)
        return self._index

    def values(self, ref: FieldRef) -> list[object]:
        """Every occurrence of the field in this frame (a list field's items each count as one)."""
        if ref.kind == LAYERS:
            out: list[object] = []
            for f in self.fields(ref):
                if isinstance(f.value, tuple | list):
                    out.extend(f.value)
                else:
                    out.append(f.value)
            return out
        if ref.kind == FRAME:
            return self._frame_values(ref.names[0])
        return self._analysis_values(ref.names[0])

    def _frame_values(self, name: str) -> list[object]:
        if name == "frame.no":
            return [self.number]
        if name == "frame.ts":
            return [] if self.block is not None and self.block.btype == BT_SPB else [self.ts]
        block = self.block
        if block is None:
            return []
        return [{"frame.iface": block.iface, "frame.linktype": block.linktype, "frame.caplen": block.caplen}[name]]

    def _analysis_values(self, name: str) -> list[object]:
        note = self.note
        if note is None:
            return []
        if name == "txn.id":
            return [t.txn for t in note.txns]
        if name == "txn.verdict":
            return [t.verdict for t in note.txns]
        if name == "txn.b5_retries":
            return [t.b5_retries for t in note.txns]
        if name == "finding.rule":
            return [f.rule for f in note.findings]
        return [f.severity for f in note.findings]

    def shown(self, ref: FieldRef) -> list[str]:
        """The occurrences as tshark 4.0 prints them in `-T fields` (hex where it shows hex)."""
        if ref.kind == LAYERS:
            return [text for f in self.fields(ref) for text in _tshark_text(f, self.ts)]
        if ref.names[0] == "frame.ts":
            if self.block is None:
                return [epoch_text(self.ts)]
            exact = record_time(self.block)
            return [exact] if exact else []
        return [str(v) for v in self.values(ref)]


def _width_of(f: Field) -> int:
    return 0 if isinstance(f.value, float) else f.length if isinstance(f.value, int) else -2


def _tshark_text(f: Field, ts: float) -> list[str]:
    fdef = registry.field(f.name)
    value = f.value
    shown = fdef.tshark_shown or {registry.HEX: registry.SHOWN_HEX, registry.FLAGS: registry.SHOWN_HEX}.get(
        fdef.type, "")
    if isinstance(value, tuple | list):
        return [str(v) for v in value]
    if isinstance(value, bool) or not isinstance(value, int | float):
        return [value.hex() if isinstance(value, bytes | bytearray) else str(value)]
    if isinstance(value, float):
        if shown == registry.SHOWN_RELTIME:
            return [reltime_text(value, ts)]
        if fdef.type == registry.TIME:
            return [epoch_text(value)]
        return [f"{value:.6g}"]  # tshark's FT_FLOAT: FLT_DIG significant digits
    if shown == registry.SHOWN_HEX:
        if value < 0 or len(f.raw) != f.length:
            return [f"0x{f.raw.hex()}" if f.raw else str(value)]
        return [f"0x{value:0{2 * max(f.length, 1)}x}"]
    if shown == registry.SHOWN_DATE:
        return [time.strftime("%b %e, %Y %H:%M:%S", time.gmtime(value)) + ".000000000 UTC"]
    return [str(value)]


def record_time(block: Block) -> str:
    """A record's time as tshark prints frame.time_epoch, exactly from its timestamp units (a float holds
    no more than ~0.2 us of a nanosecond stamp); '' for a Simple Packet Block, which has none."""
    if block.btype == BT_SPB:
        return ""
    stamp = block.stamp
    if stamp < 0:  # a pcapng (Enhanced) Packet Block: 32 + 32 bits after the interface id (and drops count)
        high, low = struct.unpack_from("<II" if block.little else ">II", block.raw, 12)
        stamp = (high << 32) | low
    seconds = Decimal(stamp) / Decimal(block.divisor) + block.ts_offset
    whole, _, frac = format(seconds.quantize(Decimal("1e-9"), ROUND_HALF_EVEN), "f").partition(".")
    return f"{whole}.{(frac + '0' * 9)[:9]}"


def epoch_text(ts: float) -> str:
    """Seconds with nine decimals as tshark prints frame.time_epoch: the float's shortest decimal form
    (exact for a microsecond capture; a float holds no more than ~0.2 us of a nanosecond one)."""
    whole, _, frac = format(Decimal(repr(float(ts))), "f").partition(".")
    return f"{whole}.{(frac + '0' * 9)[:9]}"


def reltime_text(seconds: float, ts: float) -> str:
    """A time difference with nine decimals (dcerpc.time): the difference of two floats carries their
    rounding (0.0016999244 for 1.7 ms), so in a capture whose times have at most microseconds (the
    frame's own time says so) it is rounded to them, as tshark computes it from the exact stamps."""
    frac = format(Decimal(repr(float(ts))), "f").partition(".")[2]
    return f"{round(seconds, 6) if len(frac) <= 6 else seconds:.9f}"


T = TypeVar("T")


class Cursor(Generic[T]):
    """Items of a frame-ordered stream, asked for in increasing frame order (`at`); the stream is read
    no further than asked. A damaged capture ends the stream: whoever reads the records reports it."""

    def __init__(self, items: Iterable[T], frame_of: str = "frame") -> None:
        self._items: Iterator[T] = iter(items)
        self._attr = frame_of
        self._next: T | None = self._read()

    def _read(self) -> T | None:
        try:
            return next(self._items, None)
        except CaptureError:
            return None

    def at(self, frame: int) -> T | None:
        attr = self._attr
        item = self._next
        while item is not None and getattr(item, attr) < frame:
            item = self._read()
        self._next = item
        if item is not None and getattr(item, attr) == frame:
            return item
        return None
