"""A capture's records exactly as they are in the file, for writing a copy of some or all of its frames
(`pd-analyze annotate`, `extract`): pcapng blocks of every type, classic pcap records with their header.

Frame numbers are those `reader.frames` gives (the same readers check and count the records), so what
the analysis says of frame N is said of the record numbered N here.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from typing import BinaryIO

from pd_analyze.capture.pcap import pcap_header, pcap_records
from pd_analyze.capture.pcapng import Block, pcapng_blocks
from pd_analyze.capture.raw import CaptureError, CaptureInfo
from pd_analyze.capture.reader import in_decompressed, open_capture

PCAP_RECORD = -1  # Block.btype of a classic pcap record

__all__ = ["PCAP_RECORD", "Block", "CaptureCopy"]


class CaptureCopy:
    """An open capture read record by record: `format` ("pcap" or "pcapng"), for a pcap its 24-byte file
    `header`, `little` (its byte order), `linktype`, `snaplen` and timestamp `resolution` (6 or 9 digits);
    `blocks()` every record or block in file order. Close it (or use it as a context manager)."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.info = CaptureInfo(path)
        self._stream: BinaryIO
        self._stream, self.format = open_capture(path, self.info)
        self.header = b""
        self.little, self.linktype, self.snaplen, self.resolution = True, 0, 0, 6
        try:
            if self.format == "pcap":
                self.header = self._stream.read(24)
                self.little, divisor, self.linktype = pcap_header(path, self.header)
                self.snaplen = struct.unpack_from("<I" if self.little else ">I", self.header, 16)[0]
                self.resolution = 9 if divisor == 1e9 else 6
        except BaseException:
            self._stream.close()
            raise

    def blocks(self) -> Iterator[Block]:
        try:
            if self.format == "pcapng":
                yield from pcapng_blocks(self.path, self._stream, self.info)
                return
            divisor = 10 ** self.resolution
            for number, (raw, sec, frac, caplen, orig) in enumerate(
                    pcap_records(self.path, self._stream, self.header), 1):
                yield Block(raw, PCAP_RECORD, self.little, number, sec + frac / divisor, self.linktype, 16, caplen,
                            0, float(divisor), 0, sec * divisor + frac, orig)
        except CaptureError as exc:
            if not self.info.compressed or exc.offset is None:
                raise
            raise in_decompressed(exc) from None

    def close(self) -> None:
        self._stream.close()

    def __enter__(self) -> CaptureCopy:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
