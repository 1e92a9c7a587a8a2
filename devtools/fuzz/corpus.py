"""The seed corpus of the fuzzer: every capture of sample_pcaps/ and ../shared/captures/, each frame with
the offsets of its decoded fields (from the dump path) and its layer starts, where mutations aim.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from pd_analyze import capture
from pd_analyze.capture import CaptureError, RawFrame
from pd_analyze.protocol import link, rpc
from pd_analyze.protocol.dissector import Dissector
from pd_analyze.protocol.frames import FrameResult

ROOT = Path(__file__).resolve().parents[2]  # the repository
SEED_DIRS = (ROOT / "sample_pcaps", ROOT.parent / "shared" / "captures")
CAPTURE_GLOBS = ("*.pcap", "*.pcapng", "*.gz", "*.cap")
_SKIP_FIELDS_AFTER = ("Reassembled body", "User Datagram Protocol (reassembled)")


@dataclass(slots=True)
class SeedFrame:
    raw: RawFrame
    fields: tuple[tuple[int, int], ...]  # (offset, length) of decoded fields inside the frame
    cuts: tuple[int, ...]  # layer starts: truncation points
    rpc: int  # offset of the DCE/RPC header in the frame, -1 when none


@dataclass(slots=True)
class Seed:
    name: str
    path: str
    frames: list[SeedFrame]
    data: bytes  # the file as stored


def seed_paths(dirs: Sequence[Path | str] = SEED_DIRS) -> list[str]:
    out: list[str] = []
    for d in dirs:
        path = Path(d)
        if path.is_file():
            out.append(str(path))
            continue
        if not path.is_dir():
            continue
        found = {p for pattern in CAPTURE_GLOBS for p in path.glob(pattern) if p.is_file()}
        out += sorted(str(p) for p in found)
    return out


def load_seeds(paths: Sequence[str]) -> list[Seed]:
    """Each capture's frames with the offsets of their decoded fields (from the dump path)."""
    seeds = []
    for path in paths:
        try:
            raws = list(capture.frames(path))
        except CaptureError:
            continue
        if not raws:
            continue
        known: dict[int, list[tuple[int, int]]] = {}
        d = Dissector(annotate=True)
        for res in [r for raw in raws for r in d.feed(raw)] + d.finish():
            data = raws[res.frame - 1].data
            known[res.frame] = [(f.offset, f.length) for f in frame_fields(res)
                                if f.length and f.offset >= 0 and f.offset + f.length <= len(data)]
        frames = []
        for raw in raws:
            extra, cuts, at = _landmarks(raw.linktype, raw.data)
            fields = tuple(sorted(set(known.get(raw.number, [])) | set(extra)))
            frames.append(SeedFrame(raw, fields, cuts, at))
        seeds.append(Seed(Path(path).name, path, frames, Path(path).read_bytes()))
    return seeds


def frame_fields(res: FrameResult) -> Iterator:
    """Fields whose offsets are in the frame: those before a reassembled body or datagram."""
    for layer in res.layers:
        if layer.title.startswith(_SKIP_FIELDS_AFTER):
            return
        yield from layer.fields


def _landmarks(linktype: int, data: bytes) -> tuple[list[tuple[int, int]], tuple[int, ...], int]:
    """IPv4, UDP and DCE/RPC header fields found by position, for frames the dump does not show."""
    fields: list[tuple[int, int]] = []
    cuts = {0, 6, 12, 14}
    l3 = link.l3_offset(linktype, data) if len(data) >= 16 else -1
    if l3 < 0 or len(data) < l3 + 20:
        return fields, tuple(sorted(c for c in cuts if c < len(data))), -1
    cuts.add(l3)
    fields += [(l3, 1), (l3 + 2, 2), (l3 + 4, 2), (l3 + 6, 2), (l3 + 9, 1)]
    udp = l3 + (data[l3] & 0x0F) * 4
    cuts.update({udp, udp + 4, udp + 8})
    fields += [(udp, 2), (udp + 2, 2), (udp + 4, 2)]
    at = udp + 8
    if not rpc.plausible(data[at:]):
        return fields, tuple(sorted(c for c in cuts if c < len(data))), -1
    fields += [(at + o, n) for o, n in ((1, 1), (2, 1), (4, 1), (7, 1), (56, 4), (60, 4), (64, 4), (68, 2),
                                        (74, 2), (76, 2), (78, 1), (79, 1))]
    cuts.update(at + o for o in (0, 40, 80, 84, 100, 104, 120, 164, 165, 168, 174, 180))
    return fields, tuple(sorted(c for c in cuts if c < len(data))), at
