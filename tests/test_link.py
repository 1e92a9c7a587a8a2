"""Link layer to UDP: Ethernet/VLAN/SLL/SLL2/raw IP, IPv4 reassembly, skip reasons."""

import struct

from pd_analyze.model import capped
from pd_analyze.protocol import link
from pd_analyze.protocol.link import LinkDecoder

SRC, DST = bytes([192, 168, 0, 1]), bytes([192, 168, 0, 2])


def ipv4(payload: bytes, ident: int = 7, offset: int = 0, mf: bool = False, proto: int = 17,
         total: int | None = None) -> bytes:
    flags = (0x2000 if mf else 0) | (offset // 8)
    length = total if total is not None else 20 + len(payload)
    return struct.pack(">BBHHHBBH4s4s", 0x45, 0, length, ident, flags, 64, proto, 0, SRC, DST) + payload


def udp(body: bytes, sport: int = 49152, dport: int = 34964) -> bytes:
    return struct.pack(">HHHH", sport, dport, 8 + len(body), 0) + body


def eth(l3: bytes, tags: tuple[tuple[int, int], ...] = (), etype: int = 0x0800) -> bytes:
    head = bytes(6) + bytes([2, 0, 0, 0, 0, 1])
    for tpid, vid in tags:
        head += struct.pack(">HH", tpid, vid)
    return head + struct.pack(">H", etype) + l3


def test_plain_ethernet_udp():
    d = LinkDecoder().datagram(1, 1, eth(ipv4(udp(b"hello"))) + b"\x00" * 8)  # Ethernet padding ignored
    assert isinstance(d, link.Datagram)
    assert (d.src, d.dst, d.sport, d.dport, d.payload) == (SRC, DST, 49152, 34964, b"hello")
    assert d.payload_offset == 14 + 20 + 8 and not d.truncated


def test_stacked_vlan_tags():
    frame = eth(ipv4(udp(b"x")), tags=((0x88A8, 100), (0x8100, 0x2000 | 7)))
    d = LinkDecoder().datagram(1, 1, frame)
    assert isinstance(d, link.Datagram) and d.payload == b"x" and d.payload_offset == 14 + 8 + 28
    assert link.vlan_ids(1, frame) == (100, 7)
    titles = [title for title, _ in link.annotate(1, frame, d)]
    assert titles.count("802.1Q tag") == 2


def test_sll_sll2_and_raw_ip():
    l3 = ipv4(udp(b"abc"))
    sll = struct.pack(">HHH8sH", 0, 1, 6, bytes(8), 0x0800) + l3
    sll2 = struct.pack(">HHIHBB8s", 0x0800, 0, 3, 1, 0, 6, bytes(8)) + l3
    for linktype, frame, off in ((113, sll, 16), (276, sll2, 20), (101, l3, 0), (228, l3, 0)):
        d = LinkDecoder().datagram(1, linktype, frame)
        assert isinstance(d, link.Datagram) and d.payload == b"abc" and d.ip_offset == off, linktype


def test_skip_reasons():
    dec = LinkDecoder()
    assert dec.datagram(1, 1, eth(b"\x00" * 40, etype=0x8892)) == link.SKIP_NOT_IPV4
    assert dec.datagram(2, 1, eth(ipv4(b"\x00" * 20, proto=6))) == link.SKIP_NOT_UDP
    assert dec.datagram(3, 147, b"\x00" * 60) == link.SKIP_LINKTYPE
    assert dec.datagram(4, 1, eth(b"\x45")) == link.SKIP_SHORT
    assert dec.findings == []


def test_snaplen_truncation_is_marked():
    frame = eth(ipv4(udp(b"y" * 100)))[:80]
    d = LinkDecoder().datagram(1, 1, frame)
    assert isinstance(d, link.Datagram) and d.truncated and len(d.payload) == 80 - 42


def test_ip_fragments_out_of_order():
    datagram = udp(bytes(range(256)) * 4)
    pieces = [(0, datagram[:400], True), (400, datagram[400:800], True), (800, datagram[800:], False)]
    dec = LinkDecoder()
    order = [pieces[2], pieces[0], pieces[1]]
    results = [dec.datagram(n, 1, eth(ipv4(p, offset=o, mf=mf))) for n, (o, p, mf) in enumerate(order, 1)]
    assert results[:2] == [link.SKIP_FRAGMENT, link.SKIP_FRAGMENT]
    whole = results[2]
    assert isinstance(whole, link.Datagram)
    assert whole.payload == bytes(range(256)) * 4 and whole.fragments == (1, 2, 3) and whole.payload_offset == -1
    assert dec.finish() == []


def test_ip_fragment_overlap_keeps_first_and_warns():
    datagram = udp(b"A" * 32)
    dec = LinkDecoder()
    dec.datagram(1, 1, eth(ipv4(datagram[:24], offset=0, mf=True)))
    dec.datagram(2, 1, eth(ipv4(b"B" * 8, offset=16, mf=True)))
    whole = dec.datagram(3, 1, eth(ipv4(datagram[24:], offset=24)))
    assert isinstance(whole, link.Datagram) and whole.payload == b"A" * 32
    assert [(f.name, f.frame, f.severity) for f in dec.findings] == [("ip_frag_overlap", 2, "warning")]


def test_incomplete_fragments_reported_at_end():
    dec = LinkDecoder()
    dec.datagram(5, 1, eth(ipv4(udp(b"z" * 40)[:24], ident=0x42, mf=True)))
    (f,) = dec.finish()
    assert (f.name, f.frame, f.severity, f.value) == ("ip_frag_incomplete", 5, "info", "0x0042")


def test_reassembly_table_is_capped():
    dec = LinkDecoder()
    for n in range(capped.IP_DATAGRAMS.count + 10):
        dec.datagram(n + 1, 1, eth(ipv4(b"q" * 16, ident=n, mf=True)))
    evicted = [f for f in dec.findings if f.name == "ip_frag_evicted"]
    assert len(evicted) == 10 and len(dec._open) == capped.IP_DATAGRAMS.count


def test_inconsistent_udp_length_is_a_finding():
    frame = eth(ipv4(struct.pack(">HHHH", 1, 2, 500, 0) + b"x" * 10))
    dec = LinkDecoder()
    assert dec.datagram(9, 1, frame) == link.SKIP_MALFORMED
    assert [(f.name, f.field, f.value) for f in dec.findings] == [("link_malformed", "udp.len", "500")]
