"""Captures read as batches of frames: one buffer and numpy columns per batch, for the columnar report path.

`batches(path)` yields the same frames as `capture.frames(path)` (same numbers, times, link types, bytes,
the same CaptureError after every good frame), a batch at a time: frame i of a batch is
`batch.buf[batch.start[i] : batch.start[i] + batch.caplen[i]]`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from pd_analyze.capture.raw import CaptureInfo, RawFrame

BATCH_FRAMES = 65_536  # frames per batch by default (a batch of full-size frames: about 100 MB)


@dataclass(slots=True)
class FrameBatch:
    """Consecutive frames of one capture as columns over one buffer."""

    buf: bytes  # the bytes of every frame of the batch (and possibly more, e.g. pcap record headers)
    number: np.ndarray  # int64: frame numbers, as capture.frames numbers them (1-based)
    ts: np.ndarray  # float64: seconds since the epoch, the same float as RawFrame.ts
    linktype: np.ndarray  # int32: link type of each frame's interface
    start: np.ndarray  # int64: offset of each frame's first byte in buf
    caplen: np.ndarray  # int64: bytes captured of each frame
    iface: np.ndarray  # int32: pcapng interface id (0 for pcap)

    def __len__(self) -> int:
        return len(self.number)

    def raw_frame(self, i: int) -> RawFrame:
        """Frame i as the per-frame dissector takes it."""
        start = int(self.start[i])
        return RawFrame(int(self.number[i]), float(self.ts[i]), int(self.linktype[i]),
                        bytes(self.buf[start:start + int(self.caplen[i])]), int(self.iface[i]))


def batches(path: str, size: int = BATCH_FRAMES, info: CaptureInfo | None = None) -> Iterator[FrameBatch]:
    """The frames of a capture (`-`: standard input) in batches of at most `size` frames.

    A damaged file: every good frame is yielded (the last batch may be short), then CaptureError."""
    raise NotImplementedError
