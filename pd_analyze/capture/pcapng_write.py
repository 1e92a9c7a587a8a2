"""Writing pcapng: a section header, interface descriptions, Enhanced Packet Blocks, and packet blocks
read from a pcapng file with a comment option added (PCAP Next Generation Capture File Format, IETF
draft-ietf-opsawg-pcapng: 4.1 SHB, 4.2 IDB, 4.3 EPB, 3.5 options; opt_comment is option code 1).

Blocks are written in the byte order of the section they belong to: a copied section keeps its own.
"""

from __future__ import annotations

import struct

from pd_analyze.capture.pcapng import PCAPNG_SHB, Block

BT_IDB, BT_PB, BT_SPB, BT_EPB = 1, 2, 3, 6
OPT_END, OPT_COMMENT = 0, 1
SHB_USERAPPL = 4  # shb_userappl: the application that wrote the section
IF_SNAPLEN_MAX = 262_144
IF_TSRESOL = 9
MAX_OPTION = 0xFFFF  # an option's length is 16 bits


def _pad(data: bytes) -> bytes:
    return data + b"\0" * (-len(data) % 4)


def _order(little: bool) -> str:
    return "<" if little else ">"


def option(code: int, value: bytes, little: bool = True) -> bytes:
    return struct.pack(_order(little) + "HH", code, len(value)) + _pad(value)


def comment_option(text: str, little: bool = True) -> bytes:
    """opt_comment, UTF-8, cut at a character boundary to what 16 bits of length can hold."""
    value = text.encode("utf-8", "surrogateescape")
    if len(value) > MAX_OPTION:
        value = value[:MAX_OPTION].decode("utf-8", "ignore").encode("utf-8")
    return option(OPT_COMMENT, value, little)


def _block(btype: int, body: bytes, little: bool) -> bytes:
    order = _order(little)
    length = 12 + len(body)
    return struct.pack(order + "II", btype, length) + body + struct.pack(order + "I", length)


def section_header(application: str, little: bool = True) -> bytes:
    """A Section Header Block, version 1.0, section length unknown (-1)."""
    body = struct.pack(_order(little) + "IHHq", 0x1A2B3C4D, 1, 0, -1)
    body += option(SHB_USERAPPL, application.encode(), little) + option(OPT_END, b"", little)
    return _block(PCAPNG_SHB, body, little)


def interface_description(linktype: int, snaplen: int, resolution: int, little: bool = True) -> bytes:
    """An Interface Description Block; `resolution`: timestamp digits after the second (6 is the default
    and is then not written)."""
    body = struct.pack(_order(little) + "HHI", linktype, 0, snaplen or IF_SNAPLEN_MAX)
    if resolution != 6:
        body += option(IF_TSRESOL, bytes([resolution]), little) + option(OPT_END, b"", little)
    return _block(BT_IDB, body, little)


def enhanced_packet(iface: int, stamp: int, data: bytes, orig_len: int, options: bytes = b"",
                    little: bool = True) -> bytes:
    """An Enhanced Packet Block; `options` are whole options without the end-of-options marker."""
    body = struct.pack(_order(little) + "IIIII", iface, (stamp >> 32) & 0xFFFFFFFF, stamp & 0xFFFFFFFF, len(data),
                       orig_len) + _pad(data)
    if options:
        body += options + option(OPT_END, b"", little)
    return _block(BT_EPB, body, little)


def packet_options(block: Block) -> bytes:
    """The options of a pcapng (Enhanced) Packet Block, whole, without the end-of-options marker."""
    order = _order(block.little)
    raw = block.raw
    end = len(raw) - 4
    at = 28 + block.caplen + (-block.caplen % 4)
    out = []
    while at + 4 <= end:
        code, length = struct.unpack_from(order + "HH", raw, at)
        if code == OPT_END:
            break
        size = 4 + length + (-length % 4)
        if at + size > end:
            break  # a damaged option list: what follows is not carried over
        out.append(raw[at:at + size])
        at += size
    return b"".join(out)


def with_comment(block: Block, comment: str) -> bytes:
    """A pcapng packet block with `comment` added after the options it has (its own comments kept): an
    Enhanced or obsolete Packet Block keeps its type, header and bytes; a Simple Packet Block, which can
    hold no option, becomes an Enhanced Packet Block on interface 0 with the time the reader gave it."""
    little = block.little
    order = _order(little)
    raw = block.raw
    if block.btype == BT_SPB:
        orig_len = struct.unpack_from(order + "I", raw, 8)[0]
        stamp = max(0, round((block.ts - block.ts_offset) * block.divisor))
        data = raw[block.data_at:block.data_at + block.caplen]
        return enhanced_packet(0, stamp, data, orig_len, comment_option(comment, little), little)
    head = raw[8:28 + block.caplen + (-block.caplen % 4)]
    body = head + packet_options(block) + comment_option(comment, little) + option(OPT_END, b"", little)
    return _block(block.btype, body, little)
