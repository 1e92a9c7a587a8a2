"""The columnar PROFIdrive decode against the per-frame reference, record by record.

Records: every PROFIdrive record of the sample and shared captures (as the per-frame dissector finds
them), synthetic ones of every format and case, and seeded random mutations of both, under each
packaged profile. A regular record decodes to the reference's header, addresses, blocks and table
cells; an unflagged one has no finding of the parse or of the record's own checks; `plausible` is the
reference's everywhere. A batch decodes as its records one at a time.
"""

from __future__ import annotations

import pickle
import random
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from devtools.synth.pd_encode import (
    FORMAT_SIZE,
    ParamAddress,
    akd_echo_response,
    change_ok,
    change_request,
    date_value,
    description,
    error_block,
    pd_request,
    pd_response,
    read_request,
    value_block,
    zero_block,
)
from pd_analyze import capture
from pd_analyze.analysis.rows import block_values
from pd_analyze.model import pd_values as pt
from pd_analyze.model.values import PROFIDRIVE_INDICES
from pd_analyze.protocol import pnio, profidrive
from pd_analyze.protocol import profidrive_batch as batch
from pd_analyze.protocol import profidrive_batch_checks as batch_checks
from pd_analyze.protocol.dissector import dissect
from pd_analyze.protocol.profidrive_checks import Checker
from pd_analyze.protocol.profiles import LIMIT_KEYS
from tests.support import SHARED_CAPTURES

REPO = Path(__file__).resolve().parents[1]
FOLDERS = (REPO / "sample_pcaps", SHARED_CAPTURES)
PATTERNS = ("*.pcap", "*.pcapng", "*.gz")
PROFILES = ("generic", "sinamics", "yaskawa", "akd")
MUTANTS = 5000

Record = tuple[bytes, bool]  # the record, and whether it is a parameter response


# --- the records ---------------------------------------------------------------------------------
@cache
def capture_records() -> tuple[Record, ...]:
    """Every write-request and read-response record at a PROFIdrive index, as the dissector frames them."""
    found = []
    for folder in FOLDERS:
        paths = sorted({p for pattern in PATTERNS for p in folder.glob(pattern)}) if folder.is_dir() else []
        for path in paths:
            try:
                for res in dissect(str(path)):
                    stub = res.pdu.stub if res.pdu is not None else None
                    for block in stub.blocks if stub is not None else ():
                        if block.index in PROFIDRIVE_INDICES and block.layout in (pnio.WRITE_REQ, pnio.READ_RES):
                            found.append((bytes(block.record), stub.response))
            except capture.CaptureError:
                pass  # the good frames before the damage are in
    return tuple(found)


def _values(fmt: int, count: int, rng: random.Random) -> list:
    if fmt in (0x08, 0x0F):
        return [rng.choice((0.0, -0.0, 1.5, -2.25e-7, 3.4e38, 1e16, 0.1, 123456789.0, float("nan"),
                            float("inf"), float("-inf"), rng.uniform(-1e6, 1e6))) for _ in range(count)]
    size = FORMAT_SIZE[fmt]
    edges = (0, 1, 2, (1 << (8 * size - 1)) - 1, 1 << (8 * size - 1), (1 << (8 * size)) - 1)
    if fmt == 0x01:
        edges = (0, 1)
    return [rng.choice(edges) if rng.random() < 0.5 else rng.randrange(1 << (8 * size)) for _ in range(count)]


def _block(fmt: int, count: int, rng: random.Random, pad: bytes | None = None) -> bytes:
    if fmt == 0x09:
        return value_block(fmt, rng.choice(("", "abc", "a b", "tab\there", "é ñ", "\x00\x7f", "P1120 text")
                                           )[:count] if count < 99 else "x" * count, pad=pad)
    if fmt == 0x0A:
        return value_block(fmt, bytes(rng.randrange(256) for _ in range(count)), pad=pad)
    if fmt == 0x27:
        return value_block(fmt, rng.choice(("", "Ab", "a b", "\u00e9\u4e2d", "\x01x")), pad=pad)
    if fmt == 0x32:
        return value_block(fmt, b"".join(date_value(2024, 5, 17, 12, 30, 1500) for _ in range(count)), pad=pad)
    if fmt in (0x40, 0x00):
        return zero_block(fmt=fmt, n_values=count if count < 2 else 0)
    if fmt == 0x44:
        return error_block(0x14, 3)
    return value_block(fmt, _values(fmt, count, rng), pad=pad)


@cache
def synthetic_records() -> tuple[Record, ...]:
    """Every format with odd and even counts, pads zero, non-zero and missing, error blocks, every
    Response ID, many parameters, strings, NaN/Inf floats, the AKD echo, header-level errors."""
    rng = random.Random(7)
    out: list[Record] = []
    a = ParamAddress
    for fmt in pt.FORMATS:
        for count in (0, 1, 2, 3, 4, 5):
            for pad in (None, b"\x00", b"\x55", b""):
                block = _block(fmt, count, rng, pad)
                out.append((pd_response(1, 0x01, 1, [block]), True))
                out.append((pd_response(2, 0x81, 1, [block, error_block(0x00), _block(fmt, count, rng, pad)]), True))
                out.append((change_request(3, 1, [(a(1000, 0, max(count, 1)), block)]), False))
                out.append((change_request(4, 0, [(a(1001, 2, count), block), (a(7, 0, 1), value_block(0x06, [9]))]),
                            False))
    for resp_id in (0x00, 0x01, 0x02, 0x03, 0x7F, 0x80, 0x81, 0x82, 0x83, 0xFF):
        for n in (0, 1, 2):
            out.append((pd_response(5, resp_id, 1, [error_block(0x21)] * n), True))
            out.append((pd_response(5, resp_id, 1, [], n_params=n), True))
            out.append((pd_response(5, resp_id, 1, [value_block(0x42, [1])], n_params=n), True))
    for n_values, extra in ((0, ()), (1, ()), (2, ()), (3, ()), (2, (9,)), (5, (1, 2))):
        for number in (0x00, 0x01, 0x03, 0x10, 0x15, 0x24, 0x64, 0x65, 0xFF, 0x100, 0xFFFF):
            words = [number, 4, *extra][:max(n_values, 0)]
            blk = error_block(words[0] if words else number, words[1] if len(words) > 1 else None,
                              n_values=n_values, extra=words[2:])
            out.append((pd_response(6, 0x81, 1, [blk]), True))
            out.append((pd_response(6, 0x82, 1, [zero_block(), blk]), True))
            out.append((pd_response(6, 0x80, 1, [blk], n_params=0), True))
    for header_error in (0x19, 0x21, 0x22, 0x23, 0x05):
        out.append((pd_response(7, 0x81, 1, [error_block(header_error)], n_params=3), True))
        out.append((pd_response(7, 0x82, 1, [error_block(header_error)], n_params=3), True))
    many = [a(900 + i, i, 1 + i % 3) for i in range(39)]
    out.append((read_request(8, 1, many), False))
    out.append((pd_request(8, 2, 1, many, [value_block(0x43, [i] * (1 + i % 3)) for i in range(39)]), False))
    out.append((pd_response(8, 1, 1, [value_block(0x41, [i] * (1 + i % 3)) for i in range(39)]), True))
    out.append((pd_response(8, 1, 1, [value_block(0x05, [i]) for i in range(80)], n_params=80), True))
    # requests: read with junk, unknown Request IDs, attributes, elements, subindex 0xFFFF, PNU 0
    for req_id in (0x00, 0x01, 0x02, 0x03, 0x81):
        out.append((pd_request(9, req_id, 1, [a(5), a(6, 0xFFFF, 0)]), False))
        out.append((pd_request(9, req_id, 1, [a(5)], trailer=b"\x01\x02"), False))
    for attr in (0x00, 0x10, 0x20, 0x30, 0x40):
        out.append((change_request(10, 1, [(a(0, 0, 1, attr), value_block(0x06, [1]))]), False))
        out.append((read_request(10, 0, [a(1, 0, 235, attr)]), False))
    out.append((change_request(11, 1, [(a(12), value_block(0x41, list(range(250)), n_values=250))]), False))
    out.append((change_request(11, 1, [(a(12, 0, 200), value_block(0x05, list(range(200))))]), False))
    out.append((pd_request(12, 2, 1, [a(1), a(2)], [value_block(0x06, [1])]), False))  # fewer blocks
    out.append((pd_request(12, 2, 1, [], n_params=0), False))
    out.append((pd_request(12, 2, 1, [], n_params=0, trailer=b"\x00\x00"), False))
    out.append((pd_request(12, 1, 1, [a(1)], n_params=2), False))  # ends inside the addresses
    for short in (b"", b"\x01", b"\x01\x02\x01"):
        out += [(short, False), (short, True)]
    # positive change responses, the AKD trailing 00 00, the AKD address echo
    out += [(change_ok(13, 0, 1), True), (change_ok(13, 0, 1) + b"\x00\x00", True),
            (change_ok(13, 0, 1) + b"\x01", True), (change_ok(0, 0, 0), True)]
    for blk in (value_block(0x42, [7]), value_block(0x05, [1]), value_block(0x05, [1], pad=b""),
                value_block(0x41, [1], pad=b"\x09"), error_block(0x14, 1)):
        out.append((akd_echo_response(14, 0x01, 0, a(1234), blk), True))
    # descriptions and texts, pads before following blocks that decide the look-ahead
    out.append((pd_response(15, 1, 1, [value_block(0x0A, description(0x0142, 1, "Speed setpoint"))]), True))
    out.append((pd_response(15, 1, 1, [value_block(0x09, "Off             On              ")]), True))
    for pad in (b"\x00", b"\x42", b"\x41", b""):
        for nxt in (value_block(0x42, [1]), value_block(0x41, [0x41]), error_block(0x02, 1)):
            out.append((pd_response(16, 0x81, 1, [value_block(0x05, [3], pad=pad), nxt]), True))
            out.append((change_request(16, 1, [(a(1), value_block(0x05, [3], pad=pad)), (a(2), nxt)]), False))
    out += [(pd_response(17, 1, 1, [value_block(0x32, date_value(2001, 1, 1) + b"\x00")]), True)]
    # within every profile's limits (the AKD's are the narrowest): records that must not be flagged
    for ref in range(1, 101):
        fmt = (0x41, 0x42, 0x43)[ref % 3]
        value = value_block(fmt, _values(fmt, 1, rng))
        do = ref % 2
        out += [(read_request(ref, do, [a(rng.randrange(1, 65536), 0, 1)]), False),
                (pd_response(ref, 1, do, [value]), True),
                (change_request(ref, do, [(a(rng.randrange(1, 65536), 0, 1), value)]), False),
                (change_ok(ref, do, 1), True),
                (pd_response(ref, 0x81, do, [value, error_block(0x14, 0)]), True),
                (pd_response(ref, 0x82, do, [zero_block(fmt=0x00 if do == 0 else 0x40), error_block(0x17)]), True)]
    return tuple(out)


@cache
def mutated_records() -> tuple[Record, ...]:
    """Seeded random byte flips, truncations, extensions and n changes of the other records."""
    rng = random.Random(20240517)
    base = [r for r in synthetic_records() + capture_records() if len(r[0]) >= 4]
    out = []
    for _ in range(MUTANTS):
        data, response = rng.choice(base)
        data = bytearray(data)
        for _ in range(rng.choice((1, 1, 2, 3))):
            what = rng.random()
            if what < 0.5 and data:
                data[rng.randrange(len(data))] = rng.choice((0, 1, 2, 0x40, 0x44, 0x80, rng.randrange(256)))
            elif what < 0.7 and data:
                del data[rng.randrange(len(data)):]
            elif what < 0.85:
                data += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 4)))
            elif len(data) >= 4:
                data[3] = rng.randrange(6)
        out.append((bytes(data), response if rng.random() < 0.9 else not response))
    return tuple(out)


def all_records() -> tuple[Record, ...]:
    return capture_records() + synthetic_records() + mutated_records()


# --- the comparison --------------------------------------------------------------------------------
def packed(records: list[Record], rng: random.Random | None = None) -> tuple[bytes, np.ndarray, np.ndarray,
                                                                              np.ndarray]:
    """The records in one buffer (with random gaps when given a generator), and their columns."""
    parts, starts, at = [], [], 0
    for data, _ in records:
        gap = bytes(rng.randrange(256) for _ in range(rng.randrange(4))) if rng is not None else b""
        parts += [gap, data]
        at += len(gap)
        starts.append(at)
        at += len(data)
    return (b"".join(parts), np.array(starts, np.int64), np.array([len(d) for d, _ in records], np.int64),
            np.array([r for _, r in records], bool))


def reference(data: bytes, response: bool, checker: Checker) -> tuple[profidrive.Parsed, list]:
    found: list = []
    if response:
        p = profidrive.parse_response(data, 1, found)
        return p, found + checker.response(p, 1, None)
    p = profidrive.parse_request(data, 1, found)
    return p, found + checker.request(p, 1)


@cache
def checker(profile: str) -> Checker:
    return Checker.for_profile(profile)


@pytest.mark.parametrize("profile", PROFILES)
def test_columns_agree_with_the_per_frame_reference(profile: str) -> None:
    records = list(all_records())
    buf, start, length, response = packed(records)
    chk = checker(profile)
    d = batch.decode(buf, start, length, response, chk)
    r = d.records
    text = d.blocks.text.to_pylist()
    wrong = []
    for i, (data, resp) in enumerate(records):
        p, found = reference(data, resp, chk)
        if bool(r.plausible[i]) != profidrive.plausible(data, resp, chk.record.max_params):
            wrong.append((i, "plausible", data.hex(), resp))
        if len(data) >= 4 and (r.ref[i], r.ident[i], r.do[i], r.n[i]) != (p.ref, p.ident, p.do, p.n):
            wrong.append((i, "header", data.hex(), resp))
        if not r.flag[i] and found:
            wrong.append((i, "unflagged", data.hex(), resp, [f.name for f in found]))
        if not r.regular[i]:
            continue
        if batch.parsed(d, buf, int(start[i]), len(data), resp, i) != p or not p.complete or p.echo:
            wrong.append((i, "parse", data.hex(), resp))
        first = int(r.first_block[i])
        cells = text[first:first + int(r.n_blocks[i])]
        if cells != [block_values(block) for block in p.blocks]:
            wrong.append((i, "text", data.hex(), resp, cells, [block_values(block) for block in p.blocks]))
    assert wrong == []
    # the differential test is only worth something if many records are decoded and cleared
    assert r.regular.sum() > len(records) // 2 and (~r.flag).sum() > len(records) // 40


def test_every_block_row_belongs_to_its_record() -> None:
    records = list(all_records())
    d = batch.decode(*packed(records), checker("generic"))
    r, a, k = d.records, d.addresses, d.blocks
    assert np.array_equal(a.record, np.repeat(np.arange(len(records)), r.n_addr))
    assert np.array_equal(k.record, np.repeat(np.arange(len(records)), r.n_blocks))
    assert np.array_equal(r.first_addr[1:], np.cumsum(r.n_addr)[:-1])
    assert np.array_equal(r.first_block[1:], np.cumsum(r.n_blocks)[:-1])
    assert (r.n_addr[~r.regular] == 0).all() and (r.n_blocks[~r.regular] == 0).all()
    assert len(d.blocks.text) == len(k.record)
    assert {c.dtype for c in (r.ref, r.ident, r.do, r.n, a.attr, a.n_elems, k.format, k.n_values)} == {
        np.dtype(np.uint8)}
    assert a.pnu.dtype == a.subindex.dtype == np.uint16
    assert k.error.dtype == k.error_subindex.dtype == np.int32


def test_the_texts_are_made_on_first_use_and_before_pickling() -> None:
    """The value blocks' table texts are made when asked (the dump's paths never ask), and when the columns are
    pickled (a worker's decode sent to the engine): then in the worker, and without the batch's buffer."""
    records = list(all_records())[:300]
    d = batch.decode(*packed(records), checker("generic"))
    blocks = d.blocks
    assert blocks.made_text is None and blocks.buf is not None
    again = pickle.loads(pickle.dumps(blocks))
    assert blocks.buf is None and again.buf is None
    expected = [block_values(b) for i, (data, response) in enumerate(records) if d.records.regular[i]
                for b in reference(data, response, checker("generic"))[0].blocks]
    assert len(expected) > 100
    assert again.text.to_pylist() == blocks.text.to_pylist() == expected
    assert np.array_equal(again.data_start, blocks.data_start) and np.array_equal(again.format, blocks.format)


def _one(d: batch.DecodedRecords, i: int, start: int) -> tuple:
    """Record i's columns, its rows' offsets relative to the record's start."""
    r, a, k = d.records, d.addresses, d.blocks
    rows = slice(int(r.first_addr[i]), int(r.first_addr[i]) + int(r.n_addr[i]))
    blocks = slice(int(r.first_block[i]), int(r.first_block[i]) + int(r.n_blocks[i]))
    return (bool(r.regular[i]), bool(r.flag[i]), bool(r.plausible[i]), int(r.ref[i]), int(r.ident[i]),
            int(r.do[i]), int(r.n[i]), int(r.end[i]),
            [a.attr[rows].tolist(), a.n_elems[rows].tolist(), a.pnu[rows].tolist(), a.subindex[rows].tolist()],
            [k.format[blocks].tolist(), k.n_values[blocks].tolist(), (k.data_start[blocks] - start).tolist(),
             k.data_len[blocks].tolist(), k.error[blocks].tolist(), k.error_subindex[blocks].tolist(),
             k.pad[blocks].tolist(), k.text.to_pylist()[blocks]])


@pytest.mark.parametrize("profile", ("generic", "akd"))
def test_a_mixed_batch_decodes_like_one_record_at_a_time(profile: str) -> None:
    rng = random.Random(3)
    records = list(all_records())
    rng.shuffle(records)
    records = records[:1500]
    chk = checker(profile)
    buf, start, length, response = packed(records, rng)
    together = batch.decode(buf, start, length, response, chk)
    for i, record in enumerate(records):
        alone = batch.decode(*packed([record]), chk)
        assert _one(together, i, int(start[i])) == _one(alone, 0, 0), record


def test_an_empty_batch() -> None:
    d = batch.decode(b"", np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, bool), checker("generic"))
    assert len(d.records.regular) == len(d.addresses.record) == len(d.blocks.record) == len(d.blocks.text) == 0


def test_the_plain_cases_are_regular_and_unflagged() -> None:
    """The ordinary records of a parameter access leave the per-frame path entirely."""
    a = ParamAddress
    plain = [(read_request(1, 1, [a(964), a(2000, 0, 3)]), False),
             (pd_response(1, 1, 1, [value_block(0x42, [1]), value_block(0x43, [1, 2, 3])]), True),
             (change_request(2, 1, [(a(1120), value_block(0x08, [1.5]))]), False),
             (change_request(2, 1, [(a(1121), value_block(0x05, [7]))]), False),
             (change_ok(2, 1, 1), True),
             (pd_response(3, 0x81, 1, [value_block(0x06, [1]), error_block(0x00)]), True),
             (pd_response(3, 0x82, 1, [zero_block(), error_block(0x02, 0)]), True)]
    d = batch.decode(*packed(plain), checker("generic"))
    assert d.records.regular.all() and not d.records.flag.any() and d.records.plausible.all()
    assert d.blocks.text.to_pylist() == ["0x0001", "0x00000001 0x00000002 0x00000003", "1.5", "7", "1", "", "",
                                         ""]
    assert d.blocks.pad.tolist() == [-1, -1, -1, 0, -1, -1, -1, -1]


@pytest.mark.parametrize("profile", PROFILES)
def test_breaks_is_checker_limit_for_every_key_and_value(profile: str) -> None:
    chk = checker(profile)
    values = np.r_[0:300, 1000:1010, 0x7FF0:0x8010, 0xFF00:0x10000, 0x10000:0x10010]
    for key in (k for k in LIMIT_KEYS if not k.startswith("iod.")):
        found = np.array([bool(_limit_findings(chk, key, int(v))) for v in values])
        assert np.array_equal(batch_checks.breaks(chk, key, values), found), key


def _limit_findings(chk: Checker, key: str, value: int) -> list:
    out: list = []
    chk.limit(key, "x", value, 1, out)
    return out


@pytest.mark.parametrize("fmt", sorted(code for code, spec in pt.FORMATS.items()
                                       if spec.size and code not in (pt.FMT_ERROR, pt.FMT_DATE)))
def test_cells_of_random_values_of_every_format(fmt: int) -> None:
    """Random bit patterns (NaN payloads, subnormals, signed extremes, control characters) in every
    sized format: the cells are block_values' exactly."""
    rng = random.Random(fmt)
    size = pt.FORMATS[fmt].size
    records = []
    for count in (1, 2, 3, 7, 20):
        for _ in range(40):
            raw = bytes(rng.randrange(256) for _ in range(count * size))
            records.append((pd_response(1, 1, 1, [bytes([fmt, count]) + raw + b"\x00" * (len(raw) % 2)]), True))
    buf, start, length, response = packed(records)
    d = batch.decode(buf, start, length, response, checker("generic"))
    assert d.records.regular.all()
    expected = [block_values(profidrive.parse_response(data, 1, []).blocks[0]) for data, _ in records]
    assert d.blocks.text.to_pylist() == expected
