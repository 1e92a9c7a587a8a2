"""The dump's annotated fields: a Field per shown field of a frame, and the shared forms that let the dump
write a frame's headers without making them anew for every frame.

Most header fields repeat from frame to frame (addresses, ports, the interface, the record's header),
so a Layout's View keeps one SharedField per recent value of each field and hands it out again
(`View.fields`), and the renderers keep its text on it. A structure's fields are an Annotated: the list
of them is made only when something changes or indexes it; the dump reads it as runs (`Annotated.pieces`):
the fields whose bytes repeat together as one Run, shared by every frame with those bytes at that
offset, and the few fields whose values keep changing (sequence numbers, checksums) one by one.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, MutableSequence, Sequence
from dataclasses import dataclass
from typing import Any

Converter = Callable[[object], object]
Shower = Callable[[object], str]
# a View's entry: name, offset in the structure, size, memo, converter, shower, source position, own position
Entry = tuple[str, int, int, dict, Converter | None, Shower, int, int]
# a field written from its parts: name, offset, length, raw bytes, value, shown text, check, indent (text only)
Slot = Callable[[str, int, int, bytes, object, str, str, str], str]


@dataclass(slots=True, eq=False)
class Field:
    """One annotated field of a dissected frame."""

    name: str
    offset: int
    length: int
    raw: bytes
    value: object
    show: str
    check: str = ""

    def __eq__(self, other: object) -> bool:  # a SharedField equals a Field with the same contents
        if not isinstance(other, Field):
            return NotImplemented
        return (self.name, self.offset, self.length, self.raw, self.value, self.show, self.check) == \
            (other.name, other.offset, other.length, other.raw, other.value, other.show, other.check)

    __hash__ = None  # type: ignore[assignment]  # mutable

    def as_dict(self) -> dict[str, object]:
        return {"name": self.name, "offset": self.offset, "length": self.length,
                "raw": self.raw.hex(), "value": json_value(self.value), "show": self.show,
                "check": self.check}

    def with_check(self, check: str) -> Field:
        """This field with its check set: itself, changed (a SharedField answers with a sibling instead).
        Code that sets a check writes `fields[i] = fields[i].with_check(text)`."""
        self.check = check
        return self

    def replaced(self, show: str | None = None, check: str | None = None) -> Field:
        """A copy of this field (a plain Field) with another shown text and/or check."""
        return Field(self.name, self.offset, self.length, self.raw, self.value,
                     self.show if show is None else show, self.check if check is None else check)


class _Draft(Field):
    """A SharedField being made: the same slots, set without SharedField's guard (then its class is changed)."""

    __slots__ = ("_checked", "indent", "json", "line", "ok")


class SharedField(_Draft):
    """A field of a Layout, one object for every frame that has these bytes at this offset (Layout.annotate
    hands the same object out again; most header fields repeat from frame to frame). It never changes:
    setting an attribute raises, and `with_check` / `replaced` give the field with another check or text.

    The dump's renderers keep the field's text line and JSON object on it (`line` for the indent `indent`,
    `json`), so a repeated field is formatted once, not once per frame."""

    __slots__ = ()

    @staticmethod
    def make(name: str, offset: int, length: int, raw: bytes, value: object, show: str,
             check: str = "") -> SharedField:
        f = _Draft(name, offset, length, raw, value, show, check)
        f.indent, f.json, f.line, f._checked, f.ok = None, "", "", None, None
        f.__class__ = SharedField  # the same slots: from here on, it does not change
        return f  # type: ignore[return-value]

    def __setattr__(self, name: str, value: object) -> None:
        if name in _RENDER_SLOTS:  # the renderers' texts of this field
            object.__setattr__(self, name, value)
            return
        raise AttributeError(f"{self.name}: a shared field does not change; use with_check() or replaced()")

    def moved(self, offset: int) -> SharedField:
        """The same value shown at another offset."""
        return SharedField.make(self.name, offset, self.length, self.raw, self.value, self.show, self.check)

    def with_check(self, check: str) -> Field:
        if check == self.check:
            return self
        if check == "ok":  # the check of most checked fields: kept in a slot of its own
            found = self.ok
            if found is None:
                found = SharedField.make(self.name, self.offset, self.length, self.raw, self.value, self.show, check)
                object.__setattr__(self, "ok", found)
            return found
        return self.replaced(None, check)

    def replaced(self, show: str | None = None, check: str | None = None) -> Field:
        """This field with another text and/or check: a SharedField too, remembered (the texts repeat: a
        profile's verdict, a PNIOStatus in words; a few hold values)."""
        show = self.show if show is None else show
        check = self.check if check is None else check
        variants = self._checked
        if variants is None:
            variants = {}
            object.__setattr__(self, "_checked", variants)
        found = variants.get((show, check))
        if found is None:
            found = SharedField.make(self.name, self.offset, self.length, self.raw, self.value, show, check)
            if len(variants) < _VARIANTS:
                variants[(show, check)] = found
        return found


_RENDER_SLOTS = frozenset({"indent", "json", "line"})
_VARIANTS = 8  # texts and checks remembered per shared field


def json_value(value: object) -> object:
    if isinstance(value, bytes | bytearray | memoryview):
        return bytes(value).hex()
    if isinstance(value, tuple):
        return list(value)
    return value


class Run:
    """Consecutive fields of a View whose bytes repeat together, with their checks: one object for every
    frame that has those bytes at that offset (View.pieces). The renderers keep the run's text on it."""

    __slots__ = ("fields", "indent", "json", "text")

    def __init__(self, fields: tuple[Field, ...]) -> None:
        self.fields = fields
        self.indent: str | None = None
        self.text = self.json = ""


class Template:
    """The runs of one structure's bytes at one offset (View._template: Runs, and the positions of the changing
    fields), with their texts as the renderers last asked: the lines for `indent`, the JSON objects."""

    __slots__ = ("indent", "json", "pieces", "text")

    def __init__(self, pieces: tuple[Run | int, ...]) -> None:
        self.pieces = pieces
        self.indent: str | None = None
        self.text: tuple[str, ...] = ()
        self.json: tuple[str, ...] = ()

    def texts(self, indent: str, line: Callable[[Field, str], str]) -> tuple[str, ...]:
        """Each run's lines at `indent`, joined (a changing field's place: ""); the whole text when the
        structure has no changing fields."""
        self.text = tuple("\n".join([line(f, indent) for f in piece.fields]) if piece.__class__ is Run else ""
                          for piece in self.pieces)
        self.indent = indent
        return self.text

    def jsons(self, obj: Callable[[Field], str]) -> tuple[str, ...]:
        self.json = tuple(",".join([obj(f) for f in piece.fields]) if piece.__class__ is Run else ""
                          for piece in self.pieces)
        return self.json


class View:
    """The fields the dump shows of a Layout (Layout.shown), each with its converter, how it is shown and
    a memo of recent values: most header fields repeat from frame to frame, so each value is shown once.

    A field that has shown _CHANGING values (a sequence number, a checksum) is taken as changing from frame
    to frame; the others are grouped into runs between such fields (`pieces`)."""

    __slots__ = ("_changing", "_defaults", "_made", "_slots", "_spans", "_templates", "entries", "names")

    def __init__(self, entries: tuple[Entry, ...]) -> None:
        self.entries = entries
        self.names = frozenset(entry[0] for entry in entries)
        self._defaults: dict[frozenset[str], tuple[str, ...]] = {}
        self._made = [0] * len(entries)  # values shown so far, per entry
        self._changing: set[int] = set()  # positions of the entries whose values keep changing
        self._slots: tuple[tuple[int, Entry], ...] = ()  # the changing entries and their places in a template
        self._spans: tuple[tuple[int, int, int, int], ...] = ()  # runs: (first, end entry, first, end byte)
        self._templates: dict[tuple[int, int, bytes], Template] = {}
        self._split()

    def annotate(self, buf: bytes, offset: int, values: tuple, base: int = 0) -> Annotated:
        """The fields of the structure at `offset` in `buf`, shown at `base` + their offset: an Annotated,
        a list of SharedFields made when first changed or indexed (read in order, it makes none).

        `values` as unpacked by the Layout's struct: each field's values are of one type, so equal values
        convert and show alike and the memo may key on the value (its bytes are compared too)."""
        fields = Annotated(self, buf, offset, values, base)
        if type(buf) is not bytes:  # a bytearray or memoryview may change: its fields are made (copied) now
            fields.materialize()
        return fields

    def defaults(self, checked: frozenset[str] | None) -> tuple[str, ...]:
        """Each field's check when no finding names it: "ok" for the fields some rule examines (`checked`)."""
        if not checked:
            return _NO_CHECKS[len(self.entries)] if len(self.entries) < len(_NO_CHECKS) else \
                ("",) * len(self.entries)
        found = self._defaults.get(checked)
        if found is None:
            found = self._defaults[checked] = tuple("ok" if entry[0] in checked else "" for entry in self.entries)
        return found

    def fields(self, buf: bytes, offset: int, values: tuple, base: int, checks: tuple[str, ...]) -> Iterator[Field]:
        """The SharedField of each entry, with its check (`checks`, "" or "ok" per entry)."""
        shared = self._shared
        for entry in self.entries:
            yield shared(entry, buf, offset, values, base + offset, checks[entry[7]])

    def _shared(self, entry: Entry, buf: bytes, offset: int, values: tuple, at: int, check: str) -> Field:
        """The SharedField of one entry of the structure at `offset` (shown at `at`), with its check.

        The memo is keyed by the value and where it is shown: the same structure at two offsets in turn (a
        VLAN tag before it in every other frame) keeps both fields, and a field is made with its check."""
        name, rel, size, memo, conv, show_value, src, i = entry
        value = values[src]
        raw = buf[offset + rel:offset + rel + size]
        if type(raw) is not bytes:  # a slice of bytes is bytes already; of anything else, copied
            raw = bytes(raw)
        key = (value, at + rel)
        known = memo.get(key)
        if known is not None and known.raw == raw:
            return known if known.check == check else known.with_check(check)
        if len(memo) >= _MEMO_SIZE:  # a field whose values keep changing (sequence numbers...)
            memo.clear()
        made = self._made[i] = self._made[i] + 1
        if made == _CHANGING:  # written one by one from now on, not in a run
            self._changing.add(i)
            self._split()
        converted = value if conv is None else conv(value)
        known = memo[key] = SharedField.make(name, at + rel, size, raw, converted, show_value(converted), check)
        return known

    def pieces(self, buf: bytes, offset: int, values: tuple, base: int, checks: tuple[str, ...]
               ) -> Sequence[Run | Field]:
        """The fields in order as the dump writes them: each run of fields whose values do not keep
        changing as one Run, found by the bytes of all the runs together (one look-up for the structure),
        the changing fields one by one. The same SharedFields as `fields`, grouped."""
        found, made = self._find(buf, offset, values, base, checks)
        if made is not None:
            return made
        slots = self._slots
        if not slots:
            return found.pieces  # runs only
        out = list(found.pieces)
        shared, at = self._shared, base + offset
        for j, entry in slots:
            out[j] = shared(entry, buf, offset, values, at, checks[entry[7]])
        return out

    def text(self, buf: bytes, offset: int, values: tuple, base: int, checks: tuple[str, ...], indent: str,
             line: Callable[[Field, str], str], slot: Slot) -> str:
        """The fields' text lines at `indent`, joined: the runs' lines kept on the structure's template for
        this indent (`line` writes a field's), each changing field's line written from its parts (`slot`),
        no SharedField made for a value that will not come again."""
        found, made = self._find(buf, offset, values, base, checks)
        if made is not None:
            return "\n".join([line(f, indent) for f in made])
        parts = found.text if found.indent == indent else found.texts(indent, line)
        return self._filled(parts, buf, offset, values, base, checks, slot, indent, "\n")

    def json(self, buf: bytes, offset: int, values: tuple, base: int, checks: tuple[str, ...],
             obj: Callable[[Field], str], slot: Slot) -> str:
        """The fields' JSON objects joined by commas, kept and written as `text` keeps and writes the lines."""
        found, made = self._find(buf, offset, values, base, checks)
        if made is not None:
            return ",".join([obj(f) for f in made])
        parts = found.json or found.jsons(obj)
        return self._filled(parts, buf, offset, values, base, checks, slot, "", ",")

    def _filled(self, parts: Sequence[str], buf: bytes, offset: int, values: tuple, base: int,
                checks: tuple[str, ...], slot: Slot, indent: str, sep: str) -> str:
        """The kept parts with each changing field's part written in its slot, joined by `sep`."""
        slots = self._slots
        if not slots:
            return parts[0]
        out = list(parts)
        at = base + offset
        for j, (name, rel, size, _memo, conv, show_value, src, i) in slots:
            value = values[src] if conv is None else conv(values[src])
            start = offset + rel
            out[j] = slot(name, at + rel, size, buf[start:start + size], value, show_value(value), checks[i], indent)
        return sep.join(out)

    def _find(self, buf: bytes, offset: int, values: tuple, base: int, checks: tuple[str, ...]
              ) -> tuple[Template, None] | tuple[None, list[Field]]:
        """The template of the structure's runs (found by their bytes), or the fields made one by one: the
        first time these bytes are met, for a buffer that may change, or when the runs were split anew
        while the fields were made (the template would not match the slots)."""
        spans = self._spans
        if len(spans) == 1:
            key = buf[offset + spans[0][2]:offset + spans[0][3]]
        else:
            key = b"".join([buf[offset + lo:offset + hi] for _, _, lo, hi in spans])
        templates = self._templates
        found = templates.get((id(checks), base + offset, key))
        if found is not None and type(buf) is bytes:
            return found, None
        made = list(self.fields(buf, offset, values, base, checks))
        if spans is self._spans and type(buf) is bytes:  # not split again while the fields were made
            if len(templates) >= _TEMPLATES:
                templates.clear()
            found = templates[(id(checks), base + offset, bytes(key))] = Template(self._template(made))
            if not self._slots:
                return found, None
        return None, made

    def _template(self, made: list[Field]) -> tuple[Run | int, ...]:
        """The runs of `made` (one frame's fields) as Runs, the changing fields as their positions."""
        out: list[Run | int] = []
        last = 0
        for first, end, _, _ in self._spans:
            out += range(last, first)
            out.append(Run(tuple(made[first:end])))
            last = end
        out += range(last, len(made))
        return tuple(out)

    def _split(self) -> None:
        """The runs between the changing fields, and the bytes each covers (of its own entries)."""
        spans = []
        first = None
        for i, entry in enumerate((*self.entries, None)):
            if entry is not None and i not in self._changing:
                if first is None:
                    first = i
                continue
            if first is not None:
                run = self.entries[first:i]
                spans.append((first, i, min(e[1] for e in run), max(e[1] + e[2] for e in run)))
                first = None
        self._spans = tuple(spans)
        # where a template (_template) holds each changing entry, and the entry
        slots, j, last = [], 0, 0
        for first, end, _, _ in (*spans, (len(self.entries), len(self.entries), 0, 0)):
            for i in range(last, first):
                slots.append((j, self.entries[i]))
                j += 1
            j += 1 if end > first else 0
            last = end
        self._slots = tuple(slots)
        self._templates.clear()


class Annotated(MutableSequence[Field]):
    """The fields of one structure of one frame (View.annotate): a list of Fields whose objects are made
    only when the list is changed or indexed. Iterated as it is, it yields the View's SharedFields one by
    one, each with its check; `pieces` gives them grouped in runs, for the dump.

    `checked`: set by mark_checks (protocol.frames) when no finding names one of these fields: the fields
    some rule examines show "ok", as mark_checks would have set on each."""

    __slots__ = ("_list", "base", "buf", "checked", "offset", "values", "view")

    def __init__(self, view: View, buf: bytes, offset: int, values: tuple, base: int) -> None:
        self.view, self.buf, self.offset, self.values, self.base = view, buf, offset, values, base
        self.checked: frozenset[str] | None = None
        self._list: list[Field] | None = None

    @property
    def made(self) -> bool:
        """The fields are a list of their own now (changed or indexed): iteration no longer makes them."""
        return self._list is not None

    def materialize(self) -> list[Field]:
        if self._list is None:
            self._list = list(self.view.fields(self.buf, self.offset, self.values, self.base,
                                               self.view.defaults(self.checked)))
        return self._list

    def pieces(self) -> list[Run | Field]:
        """The fields in runs (View.pieces) while the list is not made; once made, its fields."""
        if self._list is not None:
            return self._list  # type: ignore[return-value]
        return self.view.pieces(self.buf, self.offset, self.values, self.base, self.view.defaults(self.checked))

    def text(self, indent: str, line: Callable[[Field, str], str], slot: Slot) -> str:
        """The fields' lines at `indent` (View.text), or from the list once it is made."""
        if self._list is not None:
            return "\n".join([line(f, indent) for f in self._list])
        view = self.view
        return view.text(self.buf, self.offset, self.values, self.base, view.defaults(self.checked), indent, line,
                         slot)

    def json(self, obj: Callable[[Field], str], slot: Slot) -> str:
        """The fields' JSON objects joined by commas (View.json), or from the list once it is made."""
        if self._list is not None:
            return ",".join([obj(f) for f in self._list])
        view = self.view
        return view.json(self.buf, self.offset, self.values, self.base, view.defaults(self.checked), obj, slot)

    def __iter__(self) -> Iterator[Field]:
        if self._list is not None:
            return iter(self._list)
        return self.view.fields(self.buf, self.offset, self.values, self.base, self.view.defaults(self.checked))

    def __len__(self) -> int:
        return len(self._list) if self._list is not None else len(self.view.entries)

    def __getitem__(self, index: int | slice) -> Any:  # a Field, or a list of them for a slice
        return self.materialize()[index]

    def __setitem__(self, index: int | slice, value: Any) -> None:
        self.materialize()[index] = value

    def __delitem__(self, index: int | slice) -> None:
        del self.materialize()[index]

    def insert(self, index: int, value: Field) -> None:
        self.materialize().insert(index, value)

    def __eq__(self, other: object) -> bool:
        if isinstance(other, Annotated | list):
            return list(self) == list(other)
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]  # mutable

    def __add__(self, other: Iterable[Field]) -> list[Field]:  # as a list's: the fields, then the other's
        return [*self, *other]

    def __radd__(self, other: Iterable[Field]) -> list[Field]:
        return [*other, *self]

    def __repr__(self) -> str:
        return f"Annotated({list(self)!r})"


_MEMO_SIZE = 256  # per View entry; a SharedField with its texts is some 500 bytes
_TEMPLATES = 1024  # runs remembered per View (by their bytes and offset)
_CHANGING = 48  # values shown before a field counts as changing (more than the sessions of most captures)
_NO_CHECKS = tuple(("",) * n for n in range(64))
