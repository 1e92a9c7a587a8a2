"""A pcapng's record fields read from the batches: frame.time_epoch as tshark prints it whatever the interface's
time units (microseconds, nanoseconds, powers of two, picoseconds with an offset), none for a Simple Packet
Block; frame.iface, frame.linktype, frame.caplen per record. `dump -T fields` and `-Y` on such a file print what
the per-frame path prints (PD_ANALYZE_PER_FRAME=1), byte for byte, and `annotate -Y` writes the same copy;
only the frames whose nanoseconds do not hold their time carry their record's stamp (FrameBatch.stamps)."""

from __future__ import annotations

import struct
from pathlib import Path

import dpkt
import pytest

from pd_analyze.capture.batches import batches
from pd_analyze.capture.pcapng_write import BT_EPB, BT_SPB, IF_TSRESOL, OPT_END, option, section_header
from tests.test_copy_filter import same_copies
from tests.test_dump_columns import same_as_per_frame

ROOT = Path(__file__).resolve().parents[1]
IF_TSOFFSET = 14
LINKTYPE_ETHERNET = 1
# (if_tsresol, if_tsoffset seconds): microseconds, nanoseconds, 2^-20 s, picoseconds after an offset
INTERFACES = ((6, 0), (9, 0), (0x94, 0), (12, 1_767_225_000))


def _block(btype: int, body: bytes) -> bytes:
    return struct.pack("<II", btype, 12 + len(body)) + body + struct.pack("<I", 12 + len(body))


def _idb(resol: int, offset: int) -> bytes:
    options = option(IF_TSRESOL, bytes([resol]))
    if offset:
        options += option(IF_TSOFFSET, struct.pack("<q", offset))
    return _block(1, struct.pack("<HHI", LINKTYPE_ETHERNET, 0, 262_144) + options + option(OPT_END, b""))


def _stamp(seconds: float, resol: int, offset: int) -> int:
    units = 2 ** (resol & 0x7F) if resol & 0x80 else 10 ** resol
    return round((seconds - offset) * units) + 7  # + 7 units: a time finer than the interface's coarser cousins


def _pad(data: bytes) -> bytes:
    return data + b"\0" * (-len(data) % 4)


def mixed_units(source: Path, path: Path) -> int:
    """The frames of a sample capture, each on the next of four interfaces of different time units, every
    fifth as a Simple Packet Block (interface 0, no time)."""
    out = [section_header("test"), *(_idb(resol, offset) for resol, offset in INTERFACES)]
    with source.open("rb") as f:
        frames = list(dpkt.pcap.Reader(f))
    for n, (ts, data) in enumerate(frames):
        if n % 5 == 4:
            out.append(_block(BT_SPB, struct.pack("<I", len(data)) + _pad(data)))
            continue
        iface = n % len(INTERFACES)
        stamp = _stamp(ts, *INTERFACES[iface])
        out.append(_block(BT_EPB, struct.pack("<IIIII", iface, stamp >> 32, stamp & 0xFFFFFFFF, len(data), len(data))
                          + _pad(data)))
    path.write_bytes(b"".join(out))
    return len(frames)


FIELDS = ["-e", "frame.number", "-e", "frame.time_epoch", "-e", "frame.iface", "-e", "frame.linktype", "-e",
          "frame.caplen", "-e", "pd.ref"]


@pytest.mark.parametrize("sample", ["pd_negative.pcap", "fault_trace.pcap", "ip_fragments.pcap"])
def test_every_time_unit_is_printed_as_the_records_hold_it(sample: str, tmp_path: Path) -> None:
    path = tmp_path / "units.pcapng"
    count = mixed_units(ROOT / "sample_pcaps" / sample, path)
    assert count >= 9
    stamped = {f: s[0] for b in batches(str(path)) for f, s in (b.stamps or {}).items()}
    # the SPBs and the frames of the binary and picosecond interfaces carry their stamp; the others do not
    assert {f for f, t in stamped.items() if t == BT_SPB} == {n + 1 for n in range(count) if n % 5 == 4}
    assert {f for f, t in stamped.items() if t == BT_EPB} == {n + 1 for n in range(count)
                                                               if n % 5 != 4 and n % len(INTERFACES) >= 2}
    same_as_per_frame(path, ["-T", "fields", *FIELDS])
    for expression in ("frame.time_epoch > 1767225600.0015", "frame.iface == 2 or !frame.time_epoch",
                       "frame.caplen >= 100 and pd.ref"):
        same_as_per_frame(path, ["-T", "fields", "-Y", expression, *FIELDS])
    same_copies(path, ["frame.time_epoch > 1767225600.0015", "frame.iface == 3"], tmp_path)


def test_the_fields_of_a_pcapng_file_are_read_from_the_columns(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """frame.time_epoch of a pcapng no longer sends every frame to the dissector: only the frames the columns
    cannot decode are fed to it."""
    from pd_analyze.output import fields_file

    path = tmp_path / "units.pcapng"
    mixed_units(ROOT / "sample_pcaps" / "pd_negative.pcap", path)
    fed: list[int] = []
    original = fields_file.Dissector.feed

    def feed(self: object, frame: object) -> list:
        fed.append(frame.number)  # type: ignore[attr-defined]
        return original(self, frame)  # type: ignore[arg-type]

    monkeypatch.setattr(fields_file.Dissector, "feed", feed)
    from click.testing import CliRunner

    from pd_analyze.cli.base import main

    result = CliRunner().invoke(main, ["dump", str(path), "-T", "fields", *FIELDS])
    assert result.exit_code == 0 and result.stdout.count("\n") > 10
    assert len(fed) < result.stdout.count("\n") // 2, fed
