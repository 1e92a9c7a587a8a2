"""Derived captures for the benchmark: records of a generated pcap copied byte for byte to new files.

Only the layout make_capture writes is handled (classic pcap, little-endian, microseconds): the
benchmark needs exact copies of its own records, not a general reader.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Iterator
from pathlib import Path

from pd_analyze import capture
from pd_analyze.protocol.dissector import Dissector, dissect_frames

_FILE_HEADER = 24
_RECORD_HEADER = 16
_MAGIC = b"\xd4\xc3\xb2\xa1"
_BUFFER = 1 << 20


def file_header(path: Path) -> bytes:
    with path.open("rb") as f:
        head = f.read(_FILE_HEADER)
    if len(head) < _FILE_HEADER or head[:4] != _MAGIC:
        raise ValueError(f"{path}: not a little-endian microsecond pcap as make_capture writes")
    return head


def records(path: Path) -> Iterator[bytes]:
    """Every record whole (16-byte header and data), in file order."""
    file_header(path)
    with path.open("rb", buffering=_BUFFER) as f:
        f.seek(_FILE_HEADER)
        while head := f.read(_RECORD_HEADER):
            caplen = struct.unpack_from("<I", head, 8)[0] if len(head) == _RECORD_HEADER else -1
            data = f.read(caplen) if caplen >= 0 else b""
            if caplen < 0 or len(data) < caplen:
                raise ValueError(f"{path}: truncated record at byte {f.tell()}")
            yield head + data


def write(path: Path, header: bytes, recs: Iterable[bytes]) -> int:
    """A pcap of `header` and `recs`; returns the record count."""
    count = 0
    with path.open("wb", buffering=_BUFFER) as out:
        out.write(header)
        for rec in recs:
            out.write(rec)
            count += 1
    return count


def pnio_frames(path: Path) -> set[int]:
    """Numbers of the frames the project's dissector decodes as PNIO RPC, with any IP or CL fragments
    a PDU was reassembled from (those are PNIO traffic too, though only the last one yields a result)."""
    found: set[int] = set()
    for res in dissect_frames(capture.frames(str(path)), Dissector()):
        found.add(res.frame)
        if res.pdu is not None:
            found.update(res.pdu.fragments)
    return found


def split_classes(path: Path, chosen: set[int], yes: Path, no: Path) -> tuple[int, int]:
    """Frames numbered in `chosen` (from 1) to `yes`, the others to `no`; returns both counts."""
    header = file_header(path)
    counts = [0, 0]
    with yes.open("wb", buffering=_BUFFER) as a, no.open("wb", buffering=_BUFFER) as b:
        a.write(header)
        b.write(header)
        for number, rec in enumerate(records(path), 1):
            hit = number in chosen
            (a if hit else b).write(rec)
            counts[0 if hit else 1] += 1
    return counts[0], counts[1]


def repeat(path: Path, times: int, out: Path) -> int:
    """The records of `path` written `times` over, one after the other; returns the count written.
    (Skipped frames cost so little that one copy of them runs shorter than start-up varies.)"""
    header = file_header(path)
    return write(out, header, (rec for _ in range(times) for rec in records(path)))


def head(path: Path, frames: int, out: Path) -> int:
    """The first `frames` records of `path` as a pcap of their own; returns the count written."""
    recs = records(path)
    try:
        return write(out, file_header(path), (rec for _, rec in zip(range(frames), recs, strict=False)))
    finally:
        recs.close()  # closes the file at once, not when the generator is collected


def split_even(path: Path, parts: int, out_dir: Path) -> list[Path]:
    """The capture cut at record boundaries into `parts` files of consecutive frames, sizes within one."""
    total = sum(1 for _ in records(path))
    header = file_header(path)
    bounds = [total * k // parts for k in range(parts + 1)]
    paths = [out_dir / f"part-{k + 1}.pcap" for k in range(parts)]
    recs = records(path)
    for k, part in enumerate(paths):
        write(part, header, (next(recs) for _ in range(bounds[k + 1] - bounds[k])))
    recs.close()
    return paths
