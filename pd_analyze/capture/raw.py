"""What every capture reader hands on: frames, the errors of a damaged file, what was learnt of it."""

from __future__ import annotations

from typing import BinaryIO, NamedTuple

MAX_CAPLEN = 262_144  # the largest snaplen tools write (tcpdump, Wireshark)
PCAPNG_SHB = 0x0A0D0D0A  # a pcapng's first word, its Section Header Block's type (here: reader tells formats
# apart by it without loading the pcapng modules, and with them dpkt)


class CaptureError(Exception):
    """A capture cannot be read (further); `offset` is the byte offset of the damage, if known."""

    def __init__(self, path: str, message: str, offset: int | None = None) -> None:
        self.path = path
        self.offset = offset
        self.reason = message
        where = f"byte {offset}: " if offset is not None else ""
        super().__init__(f"{path}: {where}{message}")

    def __reduce__(self) -> tuple:
        return CaptureError, (self.path, self.reason, self.offset)  # (raised in a worker, re-raised here)


class RawFrame(NamedTuple):
    """A frame; or, from an `ip_only` reader, a run of `run` skipped frames ending at `number`."""

    number: int
    ts: float
    linktype: int
    data: bytes
    iface: int = 0
    run: int = 0  # > 0: this record stands for that many Ethernet frames without IPv4 (data is empty)
    # the time exactly, in integer nanoseconds since the epoch, as the file's units give it (the readers set
    # it; None: a frame made elsewhere, whose time is `ts` taken to the microsecond)
    ns: int | None = None




class CaptureInfo:
    """What the reader learnt about the file: format, compression, interfaces."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.format = ""
        self.compressed = False
        self.linktypes: list[int] = []
        # decimals of a second its timestamps carry (model.times): the pcap header's, or a pcapng's finest
        # interface so far (an interface description may come late; frames come after theirs)
        self.digits = 0


def peek(stream: BinaryIO, size: int) -> bytes:
    peek = getattr(stream, "peek", None)
    data = peek(size)[:size] if peek else b""
    return data
