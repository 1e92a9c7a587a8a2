"""The dump's exact output, and the precomputed shortcuts behind it staying equal to their definitions.

Layouts resolve each field's show function once and hand out one SharedField for every frame with the
same bytes at the same offset, grouped in runs; the JSON and text writers keep their texts on them. Each
shortcut is checked here against the plain definition (show_def, the uuid module, json.dumps of the fields'
dicts, the text line spelt out).
"""

import json
import random
import uuid
from pathlib import Path

import pytest

from pd_analyze.model import fields as registry
from pd_analyze.model import layout as structs
from pd_analyze.model import shown
from pd_analyze.model.layout import Field, Layout
from pd_analyze.output import dump
from pd_analyze.protocol import pnio_checks as checks
from pd_analyze.protocol.dissector import Dissector, dissect
from pd_analyze.protocol.frames import FrameResult, mark_checks

REPO = Path(__file__).resolve().parent.parent
SAMPLES = sorted(p for p in (REPO / "sample_pcaps").iterdir() if p.is_file() and p.name != "README.md")


def _results(path: Path) -> list[FrameResult]:
    out = []
    for res in dissect(str(path), dissector=Dissector(annotate=True)):
        mark_checks(res, checks.CHECKED_FIELDS)
        out.append(res)
    return out


def _sample_values(fdef: registry.FieldDef) -> list[object]:
    ints = [0, 1, 2, 0x7F, 0xFF, 0x100, 0xFFFF, 0x10000, 0xDEA00001, -1, True, False]
    ints += list(fdef.values or {}) + list(fdef.flags or {})
    if fdef.flags:
        ints.append(sum(fdef.flags))  # every bit set
    others = [b"", b"\x01\x02\x03", bytes(range(6)), bytes(range(16)), bytes(range(40)), bytearray(b"\xff" * 6),
              0.0, 1.5, 1e-9, float("nan"), "text", "", (1, 2, 3), [4], (), None]
    return ints + others


@pytest.mark.parametrize("name", sorted(registry.FIELDS))
def test_every_registry_field_shows_as_defined(name: str) -> None:
    fdef = registry.FIELDS[name]
    show = structs.shower(fdef)
    for value in _sample_values(fdef):
        assert show(value) == structs.show_def(fdef, value), (name, value)


def test_show_by_concrete_name_uses_the_template_entry() -> None:
    for name in ("pd.val[3].value[1]", "pd.addr[0].attr", "pd.val[12].error", "iod.index", "rpc.flags1"):
        fdef = registry.field(name)
        for value in _sample_values(fdef):
            assert structs.show(name, value) == structs.show_def(fdef, value), (name, value)


def test_uuid_text_as_the_uuid_module() -> None:
    rng = random.Random(7)
    for raw in [bytes(16), b"\xff" * 16] + [rng.randbytes(16) for _ in range(200)]:
        assert structs.convert("rpc.activity", raw, little=False) == str(uuid.UUID(bytes=raw))
        assert structs.convert("rpc.activity", raw, little=True) == str(uuid.UUID(bytes_le=raw))
    assert structs.convert("ip.src", b"\xc0\xa8\x00\x01") == "192.168.0.1"
    assert structs.convert("rpc.seq", 5) == 5
    with pytest.raises(ValueError):
        structs.convert("rpc.activity", b"short")


def _fresh(layout: Layout, buf: bytes, offset: int, values: tuple, base: int) -> list[Field]:
    """annotate spelt out without plan or memo."""
    out = []
    for fdef, rel, size, value in zip(layout.defs, layout.offsets, layout.sizes, values, strict=True):
        start = offset + rel
        value = structs.convert(fdef.name, value, layout.order == "<")
        out.append(Field(fdef.name, base + start, size, bytes(buf[start:start + size]), value,
                         structs.show_def(fdef, value)))
    return out


def test_layout_memo_follows_the_bytes_and_stays_bounded() -> None:
    layout = Layout("test", "<", (("rpc.activity", "16s"), ("rpc.seq", "I"), ("iod.index", "H"), ("rpc.flags1", "B")))
    rng = random.Random(3)
    for _ in range(3 * shown._MEMO_SIZE):
        buf = b"\xaa" + rng.randbytes(layout.size) + b"\xbb"
        values = layout.unpack(buf, 1)
        assert layout.annotate(buf, 1, values, 40) == _fresh(layout, buf, 1, values, 40)
        assert layout.annotate(bytearray(buf), 1, values, 0) == _fresh(layout, buf, 1, values, 0)
    assert all(len(entry[3]) <= shown._MEMO_SIZE for entry in layout.view.entries)
    # the same values over other bytes (a caller's values need not come from this buffer): raw follows the buffer
    buf = bytes(range(layout.size))
    values = layout.unpack(buf)
    layout.annotate(buf, 0, values)
    other = bytes(reversed(buf))
    assert [f.raw for f in layout.annotate(other, 0, values)] == [f.raw for f in _fresh(layout, other, 0, values, 0)]


def _reference_json(res: FrameResult) -> str:
    return json.dumps({"frame": res.frame, "time": res.ts, "src": res.src, "dst": res.dst, "summary": res.summary,
                       "fields": [f.as_dict() for f in res.fields()],
                       "findings": [f.as_dict() for f in res.findings]}, ensure_ascii=True, separators=(",", ":"))


def _reference_text(res: FrameResult) -> str:
    lines = [f"Frame {res.frame}  {res.ts:.6f}  {res.src} -> {res.dst}  {dump.safe(res.summary)}"]
    for layer in res.layers:
        indent = "  " * (layer.depth + 1)
        lines.append(f"{indent}{dump.safe(layer.title)}")
        for f in layer.fields:
            raw = f.raw[:8].hex(" ") + (" .." if len(f.raw) > 8 else "")
            where = " " * 32 if f.offset < 0 else f"{f.offset:04x}  {raw:<26}"
            check = f"  [{dump.safe(f.check)}]" if f.check else ""
            lines.append(f"{indent}  {where}  {f.name} = {dump.safe(f.show)}{check}")
    lines += [dump.finding_line(f, "  ") for f in res.findings]
    return "\n".join(lines)


def test_json_and_text_of_every_sample_equal_their_definitions() -> None:
    frames = 0
    for path in SAMPLES:
        for _ in range(2):  # the second pass renders from the text kept by the first
            for res in _results(path):
                assert dump.frame_json(res) == _reference_json(res), (path.name, res.frame)
                assert dump.frame_text(res) == _reference_text(res), (path.name, res.frame)
                frames += 1
    assert frames > 200


def test_a_shared_field_is_one_object_never_changed_but_replaced() -> None:
    first, second = _results(REPO / "sample_pcaps" / "worked_example.pcap")[:2]
    dump.frame_json(first), dump.frame_text(first)  # the texts of the header fields are made (kept on them)
    ver = next(f for f in second.fields() if f.name == "rpc.ver")
    assert ver is next(f for f in first.fields() if f.name == "rpc.ver")  # the same bytes at the same offset
    assert isinstance(ver, shown.SharedField)
    with pytest.raises(AttributeError, match=r"rpc\.ver: a shared field does not change"):
        ver.show = "four"
    checked = ver.with_check("ok")
    assert checked is not ver and checked is ver.with_check("ok") and checked.check == "ok" and ver.check == ""
    assert checked == Field("rpc.ver", 42, 1, b"\x04", 4, "4", "ok")
    layer = next(layer for layer in second.layers if any(f is ver for f in layer.fields))
    layer.fields[[id(f) for f in layer.fields].index(id(ver))] = ver.replaced("four", "seen")
    assert '"name":"rpc.ver","offset":42,"length":1,"raw":"04","value":4,"show":"four","check":"seen"' in \
        dump.frame_json(second)
    assert "    002a  04                          rpc.ver = four  [seen]" in dump.frame_text(second).split("\n")
    assert "    002a  04                          rpc.ver = 4" in dump.frame_text(first).split("\n")  # unchanged
    assert dump.frame_json(second) == _reference_json(second)
    assert dump.frame_text(second) == _reference_text(second)


def test_worked_example_read_response_text_exactly() -> None:
    res = _results(REPO / "sample_pcaps" / "worked_example.pcap")[5]
    lines = dump.frame_text(res).split("\n")
    assert lines[0] == ("Frame 6  1767225600.016300  192.168.0.2 -> 192.168.0.1  Read response, seq 3, "
                        "IODReadResHeader api 0x3a00 slot 1/0x1 index 0xb02e 22 bytes")
    for line in ("                                      rpc.rtt = 0.001700 s",
                 "    007c  00                          ndr.status.decode = 0x00 (OK)  [ok]",
                 "      00a6  00 00 3a 00                 iod.api = 0x00003a00 (PROFIdrive)  [ok]",
                 "        00cf  01                          pd.resp_id = 0x01 (request parameter, positive)  "
                 "[generic 0x01, 0x02, 0x80, 0x81, 0x82: ok]",
                 "        00d4  12 34                       pd.val[0].value[0] = 0x1234"):
        assert line in lines


def test_equal_bytes_at_another_offset_are_written_at_theirs() -> None:
    from pd_analyze.protocol.frames import Layer

    layout = Layout("test", ">", (("udp.sport", "H"), ("udp.dport", "H"), ("rpc.activity", "16s")))
    buf = bytes(range(20))
    values = layout.unpack(buf)
    res = FrameResult(1, 1.5, b"\x01\x02\x03\x04", b"\x05\x06\x07\x08", "s", 0, layers=[
        Layer(f"at {base}", 0, layout.annotate(buf, 0, values, base)) for base in (0, 4, 0, 100, 4)])
    for _ in range(2):
        assert dump.frame_json(res) == _reference_json(res)
        assert dump.frame_text(res) == _reference_text(res)


def _flat(pieces: list) -> list[Field]:
    return [f for piece in pieces for f in (piece.fields if isinstance(piece, shown.Run) else (piece,))]


def test_runs_hold_the_fields_of_the_frame_as_values_start_to_change() -> None:
    """A View groups its fields into runs found by their bytes; a field that keeps changing leaves the runs.
    Whatever the grouping, the pieces are the frame's own fields, and the text and JSON equal the definitions."""
    from pd_analyze.protocol.frames import Layer

    layout = Layout("test", ">", (("udp.sport", "H"), ("rpc.seq", "I"), ("iod.index", "H"), ("rpc.activity", "16s"),
                                  ("rpc.flags1", "B")))
    view = layout.shown(*layout.names)
    rng = random.Random(5)
    activities = [rng.randbytes(16) for _ in range(3)]
    checked = frozenset({"rpc.seq", "rpc.flags1"})
    for n in range(3 * shown._CHANGING):
        buf = (b"\x88\x94" + n.to_bytes(4, "big") + rng.choice([b"\xb0\x2e", b"\xb0\x2f"]) + rng.choice(activities)
               + bytes([rng.choice([0x20, 0x0a])]))
        values = layout.unpack(buf)
        fields = view.annotate(buf, 0, values, 14)
        fields.checked = checked if n % 2 else None
        expected = [f.with_check("ok") if fields.checked and f.name in checked else f
                    for f in _fresh(layout, buf, 0, values, 14)]
        assert list(fields) == expected
        assert _flat(fields.pieces()) == expected
        assert all(a is b for a, b in zip(_flat(fields.pieces()), fields, strict=True))  # the same objects
        res = FrameResult(n, 1.5, b"\x01\x02\x03\x04", b"\x05\x06\x07\x08", "s", 0, layers=[Layer("t", 1, fields)])
        assert dump.frame_text(res) == _reference_text(res)
        assert dump.frame_json(res) == _reference_json(res)
        assert not fields.made  # written from the runs, no list of fields made
    assert [view.entries[i][0] for i in sorted(view._changing)] == ["rpc.seq"]  # the others repeat
    assert len(view._spans) == 2  # sport; index, activity, flags1


def test_an_annotated_structure_is_a_list_of_its_fields() -> None:
    layout = Layout("test", "<", (("rpc.activity", "16s"), ("rpc.seq", "I"), ("iod.index", "H")))
    buf = bytes(range(22))
    fields = layout.annotate(buf, 0, layout.unpack(buf), 8)
    expected = _fresh(layout, buf, 0, layout.unpack(buf), 8)
    assert len(fields) == 3 and not fields.made and fields == expected
    assert fields[1].name == "rpc.seq" and fields.made  # indexed: the list is made, the same fields
    fields[1] = fields[1].with_check("seen")
    fields.append(Field("rpc.rtt", -1, 0, b"", 0.5, "0.500000 s"))
    assert [f.check for f in fields] == ["", "seen", "", ""] and len(fields) == 4
    assert list(fields.pieces()) == list(fields)  # once made, the renderers read the list
    copied = layout.annotate(bytearray(buf), 0, layout.unpack(buf), 8)  # bytes that may change: made at once
    assert copied.made and copied == expected and all(type(f.raw) is bytes for f in copied)


def test_checks_of_an_annotated_structure_as_mark_checks_sets_them() -> None:
    from pd_analyze.model.rules import finding
    from pd_analyze.protocol import rpc
    from pd_analyze.protocol.frames import Layer

    buf = bytes(range(rpc.HEADER_SIZE))
    values = rpc.HEADER_LE.unpack(buf)
    plain_res = FrameResult(1, 1.0, b"\x01\x02\x03\x04", b"\x05\x06\x07\x08", "s", 0, layers=[
        Layer("t", 0, list(rpc.HEADER_LE.annotate(buf, 0, values, 42)))])
    lazy_res = FrameResult(1, 1.0, b"\x01\x02\x03\x04", b"\x05\x06\x07\x08", "s", 0, layers=[
        Layer("t", 0, rpc.HEADER_LE.annotate(buf, 0, values, 42))])
    for res in (plain_res, lazy_res):
        mark_checks(res, checks.CHECKED_FIELDS)
    assert not lazy_res.layers[0].fields.made  # no finding names its fields: the checks come as it is read
    assert list(lazy_res.fields()) == list(plain_res.fields())
    assert {f.name for f in lazy_res.fields() if f.check == "ok"} == \
        {f.name for f in plain_res.fields()} & checks.CHECKED_FIELDS
    assert dump.frame_text(lazy_res) == dump.frame_text(plain_res) == _reference_text(plain_res)
    cut = finding("rpc_truncated", 1, "rpc.frag_len", 94, "<= 90", "fragment body cut")
    for res in (plain_res, lazy_res):
        res.findings.append(cut)
        mark_checks(res, checks.CHECKED_FIELDS)
    assert lazy_res.layers[0].fields.made
    assert next(f.check for f in lazy_res.fields() if f.name == "rpc.frag_len") == "R1 error: fragment body cut"
    assert list(lazy_res.fields()) == list(plain_res.fields())


def test_a_structure_at_two_offsets_in_turn_keeps_its_fields() -> None:
    """The memo is keyed by value and offset: a header behind a VLAN tag in every other frame is not remade."""
    layout = Layout("test", ">", (("udp.sport", "H"), ("udp.dport", "H")))
    buf = bytes(range(4))
    values = layout.unpack(buf)
    first = [list(layout.annotate(buf, 0, values, base)) for base in (34, 38)]
    again = [list(layout.annotate(buf, 0, values, base)) for base in (34, 38)]
    assert all(a is b for x, y in zip(first, again, strict=True) for a, b in zip(x, y, strict=True))
    assert [f.offset for f in again[1]] == [38, 40]


def _sections_fresh(parsed, data, base, checker, request):
    from pd_analyze.protocol import profidrive_view

    profidrive_view._SECTIONS.clear()
    return profidrive_view.annotate(parsed, data, base, checker, request)


@pytest.mark.parametrize("profile", ["generic", "sew", "akd", "sinamics", "yaskawa"])
def test_record_sections_kept_equal_the_sections_made_anew(profile: str) -> None:
    """A record's header, addresses and value blocks are kept per checker (profidrive_view._memo); every
    PROFIdrive record of the samples shows the same fields whether its sections were kept or made anew (with
    each vendor profile: its own IDs, services and names), and each call hands out lists of its own
    (mark_checks may replace a field in one frame's list)."""
    from pd_analyze.protocol import profidrive_view
    from pd_analyze.protocol.profidrive_checks import Checker

    checker = Checker.for_profile(profile)
    records = []
    for path in SAMPLES:
        for res in dissect(str(path), dissector=Dissector(annotate=True, checker=checker)):
            for block in res.pdu.stub.blocks if res.pdu is not None and res.pdu.stub is not None else []:
                if isinstance(block.pd, tuple) and block.pd[0] is not None:
                    records.append((block.pd[0], block.record, 100 + block.record_offset, block.pd[1]))
    assert len(records) > 100
    for parsed, data, base, request in records:
        made = _sections_fresh(parsed, data, base, checker, request)
        kept = profidrive_view.annotate(parsed, data, base, checker, request)
        assert kept == made
        kept[0][1][0] = kept[0][1][0].with_check("changed")  # one frame's list changed ...
        assert profidrive_view.annotate(parsed, data, base, checker, request) == made  # ... not the kept one
    for parsed, data, base, request in records:  # all kept at once, then read again
        assert profidrive_view.annotate(parsed, data, base, checker, request) == \
            _sections_fresh(parsed, data, base, checker, request)


def test_frames_are_written_in_blocks_and_the_last_block_before_damage() -> None:
    from pd_analyze.capture import CaptureError

    results = _results(REPO / "sample_pcaps" / "pd_commissioning.pcap")
    one_by_one: list[str] = []
    for res in results:
        one_by_one.append(dump.frame_text(res) + "\n")
    for fmt, single in (("text", one_by_one), ("json", [dump.frame_json(res) for res in results])):
        calls: list[str] = []
        assert dump.render(results, fmt, calls.append, dump.plain_style, False) == len(results)
        assert len(calls) < len(results) / 2 or len(results) < 4
        assert "".join(text + "\n" for text in calls) == "".join(text + "\n" for text in single)

    def damaged():
        yield from results[:3]
        raise CaptureError("x.pcap", "record header cut", 100)

    calls = []
    with pytest.raises(CaptureError):
        dump.render(damaged(), "text", calls.append, dump.plain_style, False)
    assert calls == ["\n".join(one_by_one[:3])]  # the frames before the damage, written before the error


def test_fewer_collections_restores_the_collector() -> None:
    import gc

    before, frozen = gc.get_threshold(), gc.get_freeze_count()
    with dump.fewer_collections(30_000):
        assert gc.get_threshold() == (max(30_000, before[0]), max(100, before[1]), max(100, before[2]))
        assert gc.get_freeze_count() >= frozen
    assert gc.get_threshold() == before and gc.get_freeze_count() == 0
