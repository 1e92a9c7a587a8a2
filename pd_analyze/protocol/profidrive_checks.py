"""Rules P1-P10, Q1, Q6-Q13 and the vendor limits on parsed PROFIdrive records (protocol.md 5, 6.3, 6.4).

The generic profile always runs (a request value outside it is an error); the selected vendor
profile adds its narrower limits as warnings, each finding naming the seed manual it comes from.
"""

from __future__ import annotations

from functools import cache

from pd_analyze.model import pd_values as pt
from pd_analyze.model.fields import value_text
from pd_analyze.model.rules import Finding, finding
from pd_analyze.protocol.profidrive import Block, Parsed, as_value
from pd_analyze.protocol.profiles import DEFAULT, Limit, Profile, VendorIds, VendorRequest, generic, load


class Checker:
    """The generic profile plus an optional vendor profile, applied to parsed records."""

    def __init__(self, generic: Profile, vendor: Profile | None = None) -> None:
        self.generic = generic
        if generic.record is None:
            raise ValueError(f"profile {generic.name} has no [record] limit to check against")
        self.record = generic.record  # the record limit every check and message uses (protocol.md 3.6)
        self.vendor = vendor if vendor is not None and vendor.name != generic.name else None
        self.names = (self.vendor or self.generic).names  # what the tables and the dump call parameters and errors
        by_key: dict[str, list[tuple[Profile, Limit]]] = {}
        for profile in (self.generic, self.vendor):
            for lim in profile.limits if profile is not None else ():
                by_key.setdefault(lim.key, []).append((profile, lim))
        self._by_key = {key: tuple(pairs) for key, pairs in by_key.items()}  # looked up per field
        # Where every limit of a key is one range, a value inside their intersection breaks none:
        # the common case is decided by two comparisons.
        self._within = {key: (max(lim.ranges[0][0] for _, lim in pairs), min(lim.ranges[0][1] for _, lim in pairs))
                        for key, pairs in self._by_key.items() if all(len(lim.ranges) == 1 for _, lim in pairs)}
        # an address's fields at once: the attribute (a byte, its limit of several ranges) by the values
        # inside every limit, the others by their ranges (None: a limit of several ranges)
        self._attributes = frozenset(v for v in range(256) if not self._breaks("request.attribute", v))
        ranges = [self._within.get(key, (-(1 << 62), 1 << 62) if key not in self._by_key else None)
                  for key in ("request.n_elems", "request.pnu", "request.subindex")]
        self._address_within = None if None in ranges else tuple(x for pair in ranges for x in pair)

    @classmethod
    def for_profile(cls, profile: str = DEFAULT) -> Checker:
        """The checker every path uses: the generic profile plus the named (or file) vendor profile."""
        return cls(generic(), load(profile))

    @property
    def tolerate(self) -> frozenset[str]:
        return self.vendor.tolerate if self.vendor else frozenset()

    @property
    def ids(self) -> VendorIds | None:
        """The vendor profile's own Request/Response IDs (protocol.md 5.5), None when it has none."""
        return self.vendor.ids if self.vendor else None

    def _limits(self, key: str) -> tuple[tuple[Profile, Limit], ...]:
        return self._by_key.get(key, ())

    def limits(self, key: str) -> tuple[Limit, ...]:
        """Every limit of `key`, the generic profile's first: what `limit` checks a value against (the
        columnar decode checks whole columns against them)."""
        return tuple(lim for _, lim in self._limits(key))

    def limit(self, key: str, name: str, value: int, frame: int, out: list[Finding], vendor_only: bool = False
              ) -> None:
        """Findings for every profile limit of `key` that `value` breaks; `vendor_only`: the vendor's
        limits only (a field of the vendor's own Request/Response ID, which the profile does not define)."""
        within = self._within.get(key)
        if within is not None and within[0] <= value <= within[1]:
            return
        for profile, lim in self._by_key.get(key, ()):
            if vendor_only and profile is self.generic:
                continue
            if not lim.allows(value):
                shown = value_text(name, value)
                out.append(finding(lim.rule, frame, name, shown, lim.text(),
                                   f"{name} = {shown} outside the {profile.name} limit {lim.text()} "
                                   f"({lim.source})", source=lim.source))

    def _breaks(self, key: str, value: int) -> bool:
        return any(not lim.allows(value) for _, lim in self._by_key.get(key, ()))

    def describe(self, key: str, value: int) -> str:
        """The dump's check text: each profile's verdict on the value."""
        parts = []
        for profile, lim in self._limits(key):
            verdict = "ok" if lim.allows(value) else f"BREAKS ({lim.rule})"
            parts.append(f"{profile.name} {lim.text()}: {verdict}")
        return "; ".join(parts)

    # --- requests ------------------------------------------------------------------------------
    def request(self, p: Parsed, frame: int) -> list[Finding]:
        out: list[Finding] = []
        if not p.header_ok:
            return out
        vendor = p.vendor is not None  # a vendor service: its ID, attributes and indexes are the vendor's
        self.request_limits(p.ref, p.ident, p.do, p.n, [(a.attr, a.n_elems, a.pnu, a.subindex) for a in p.addresses],
                            frame, out, vendor)
        change = p.ident == pt.REQ_CHANGE
        if isinstance(p.vendor, VendorRequest):  # laid out as its service declares (protocol.md 5.5)
            change = p.vendor.layout_of(p.addresses[0].attr if p.addresses else 0) == "change"
        elif p.ident != pt.REQ_READ and not change:
            return out
        if not change:
            if p.complete and p.end < p.length:
                out.append(finding("read_request_length", frame, "pd.trailing", p.length, 4 + 6 * p.n,
                                   f"read request carries {p.length - p.end} bytes after its addresses"))
            return out
        out += self._change_blocks(p, frame)
        if p.complete and p.end < p.length:
            out.append(finding("request_trailing", frame, "pd.trailing", p.length - p.end, 0,
                               f"{p.length - p.end} bytes left after the parsed change request"))
        return out

    def request_limits(self, ref: int, ident: int, do: int, n: int, addresses: list[tuple[int, int, int, int]],
                       frame: int, out: list[Finding], vendor: bool = False) -> None:
        """The limits of a request's header and addresses (attribute, No. of elements, PNU, subindex);
        `vendor`: a vendor service's (its ID, attributes and PNUs are checked against the vendor alone). The
        engine states them from the columns for a record on which no other rule may report."""
        self.limit("request.ref", "pd.ref", ref, frame, out)
        self.limit("request.req_id", "pd.req_id", ident, frame, out, vendor)
        self.limit("request.do", "pd.do", do, frame, out)
        self.limit("request.n_params", "pd.n_params", n, frame, out)
        within, attributes = self._address_within, self._attributes
        for i, (attr, n_elems, pnu, subindex) in enumerate(addresses):
            if within is not None and (attr in attributes and within[0] <= n_elems <= within[1]
                                       and within[2] <= pnu <= within[3] and within[4] <= subindex <= within[5]):
                continue  # the common case: inside every limit (40 addresses a request are checked per frame)
            names = _address_fields(i)
            self.limit("request.attribute", names[0], attr, frame, out, vendor)
            self.limit("request.n_elems", names[1], n_elems, frame, out)
            self.limit("request.pnu", names[2], pnu, frame, out, vendor)
            self.limit("request.subindex", names[3], subindex, frame, out)

    def _change_blocks(self, p: Parsed, frame: int) -> list[Finding]:
        out: list[Finding] = []
        if p.complete and len(p.blocks) != p.n:
            out.append(finding("change_blocks", frame, "pd.n_params", len(p.blocks), p.n,
                               f"change request has {len(p.blocks)} value blocks for {p.n} addresses"))
        for i, (block, address) in enumerate(zip(p.blocks, p.addresses, strict=False)):
            name = f"pd.val[{i}]"
            addr = address if p.vendor is None else as_value(address)  # a vendor service's attribute
            if block.unknown_size:
                continue
            if block.format in (pt.FMT_ZERO, pt.FMT_ERROR, pt.FMT_AKD_ZERO):
                out.append(finding("change_blocks", frame, f"{name}.format", f"{block.format:#04x}",
                                   "a sized data type", "Zero/Error format in a change request"))
                continue
            fmt, n_values = _value_fields(i)
            self.limit("request.format", fmt, block.format, frame, out)
            self.limit("request.n_values", n_values, block.n_values, frame, out)
            if addr.attr == pt.ATTR_VALUE and not (
                    block.n_values == addr.n_elems or (addr.n_elems == 0 and block.n_values == 1)):
                out.append(finding("n_values_mismatch", frame, f"{name}.n_values", block.n_values,
                                   max(addr.n_elems, 1), f"{addr.label()}: No. of values differs from "
                                   "No. of elements (device answers error 0x18)"))
            if len(block.data) > self.record.max_value_bytes:
                out.append(finding("value_too_long", frame, f"{name}.n_values", len(block.data),
                                   f"<= {self.record.max_value_bytes} bytes", "value list longer than fits a request"))
            if addr.attr in (pt.ATTR_DESCRIPTION, pt.ATTR_TEXT):
                out.append(finding("change_description", frame, f"pd.addr[{i}].attr", f"{addr.attr:#04x}",
                                   "0x10", f"{addr.label()}: change of the "
                                   f"{pt.ATTRIBUTE[addr.attr]} attribute (device answers 0x07/0x20/0x0F)"))
            out += self._values(block, i, frame)
        return out

    def _values(self, block: Block, i: int, frame: int) -> list[Finding]:
        out = []
        if block.format == pt.FMT_AKD_ZERO and "format_00_zero" not in self.tolerate:
            out.append(finding("format_zero_akd", frame, f"pd.val[{i}].format", "0x00", "0x40",
                               "format 0x00 'no data' is an AKD convention; the profile uses 0x40 Zero"))
        if block.format == pt.FMT_DATE and block.size == 8:
            out.append(finding("date_padded", frame, f"pd.val[{i}].format",
                               f"0x{block.format:02x} Date, 8 bytes per value", "7 bytes per value",
                               "Date values padded to 8 bytes (decoded as such)"))
        if block.format == pt.FMT_VISIBLE_STRING and not block.data.decode("latin-1").isprintable():
            out.append(finding("string_nonprintable", frame, f"pd.val[{i}].string", block.data.hex(),
                               "printable ISO 646 characters", "VisibleString with non-printable characters"))
        if block.format == 0x01:
            bad = [b for b in block.data if b not in (0, 1)]
            if bad:
                out.append(finding("boolean_value", frame, f"pd.val[{i}].value[0]", bad[0], "0 or 1",
                                   "Boolean value other than 0/1"))
        return out

    # --- responses -----------------------------------------------------------------------------
    def response(self, p: Parsed, frame: int, request: Parsed | None = None) -> list[Finding]:
        out: list[Finding] = []
        if not p.header_ok:
            self.limit("response.length", "pd.n_params" if p.length < 4 else "iod.record_len", p.length, frame, out)
            return out
        self.response_limits(p.length, p.ref, p.ident, p.do, p.n, frame, out, p.vendor is not None)
        if p.ident == pt.RES_CHANGE and p.vendor is None:
            body = p.length - 4
            if body and "trailing_00_00" in self.tolerate and body == 2 and p.blocks == [] and p.end == 4:
                out.append(finding("akd_trailing_zero", frame, "pd.trailing", "00 00", "no body",
                                   "positive change response followed by 00 00 (AKD documents it)"))
            elif body:
                out.append(finding("change_response_body", frame, "pd.trailing", body, 0,
                                   "positive change response carries a body (it is header-only)"))
            return out
        for i, block in enumerate(p.blocks):
            fmt, n_values = _value_fields(i)
            self.limit("response.format", fmt, block.format, frame, out)
            if block.is_error:
                out += self._error_block(block, i, frame)
            else:
                self.limit("response.n_values", n_values, block.n_values, frame, out)
                out += self._values(block, i, frame)
        out += self._response_ids(p, frame, request)
        if p.complete and p.end < p.length:
            out.append(finding("response_trailing", frame, "pd.trailing", p.length - p.end, 0,
                               f"{p.length - p.end} bytes left after the parsed response"))
        return out

    def response_limits(self, length: int, ref: int, ident: int, do: int, n: int, frame: int, out: list[Finding],
                        vendor: bool = False) -> None:
        """The limits of a response's length (Q11) and header (`vendor`: a vendor service's ID is checked
        against the vendor alone). The engine states them from the columns for a record on which no other
        rule may report."""
        self.limit("response.length", "pd.n_params" if length < 4 else "iod.record_len", length, frame, out)
        self.limit("response.ref", "pd.ref", ref, frame, out)
        self.limit("response.resp_id", "pd.resp_id", ident, frame, out, vendor)
        self.limit("response.do", "pd.do", do, frame, out)
        self.limit("response.n_params", "pd.n_params", n, frame, out)

    def _response_ids(self, p: Parsed, frame: int, request: Parsed | None) -> list[Finding]:
        out = []
        formats = [b.format for b in p.blocks]
        if p.ident == pt.RES_READ:
            for i, b in enumerate(p.blocks):
                if b.format in (pt.FMT_ZERO, pt.FMT_ERROR):
                    out.append(finding("read_response_blocks", frame, f"pd.val[{i}].format", f"{b.format:#04x}",
                                       "a value format", "positive read response with a Zero/Error block"))
            if request is not None:
                out += n_values_read(p, frame, request)
        elif p.ident == pt.RES_READ_NAK and pt.FMT_ERROR not in formats and p.complete:
            out.append(finding("nak_blocks", frame, "pd.resp_id", "0x81", "at least one error block",
                               "negative read response without any error block"))
        elif p.ident == pt.RES_CHANGE_NAK and p.complete:
            zero_ok = {pt.FMT_ZERO} | ({pt.FMT_AKD_ZERO} if "format_00_zero" in self.tolerate else set())
            for i, b in enumerate(p.blocks):
                if not b.is_error and not (b.format in zero_ok and b.n_values == 0):
                    out.append(finding("nak_blocks", frame, f"pd.val[{i}].format", f"{b.format:#04x}",
                                       "0x40 with 0 values, or 0x44", "negative change response block is "
                                                                      "neither 'written' nor an error"))
            if pt.FMT_ERROR not in formats:
                out.append(finding("nak_blocks", frame, "pd.resp_id", "0x82", "at least one error block",
                                   "negative change response without any error block"))
        return out

    def _error_block(self, block: Block, i: int, frame: int) -> list[Finding]:
        out = []
        name = f"pd.val[{i}]"
        if block.n_values not in (1, 2):
            out.append(finding("error_block_count", frame, f"{name}.n_values", block.n_values, "1 or 2",
                               "error block must carry 1 or 2 values (consumed 2 x m bytes)"))
        if block.error < 0:
            return out
        known = pt.ERRORS.get(block.error)
        if known is not None and block.n_values in (1, 2):
            if known.subindex == "yes" and block.n_values == 1:
                out.append(finding("error_subindex_presence", frame, f"{name}.n_values", 1, 2,
                                   f"error {block.error:#04x} normally reports the faulty subindex"))
            elif known.subindex == "no" and block.n_values == 2:
                out.append(finding("error_subindex_presence", frame, f"{name}.error_subindex", 2, 1,
                                   f"error {block.error:#04x} carries a second value it does not define"))
        klass = pt.error_class(block.error)
        ids = self.ids
        if ids is not None and ids.error_text(block.error) is not None:
            return out  # a vendor error word (protocol.md 5.5), shown as its class and additional code
        if klass == "reserved":
            out.append(finding("error_reserved", frame, f"{name}.error", f"{block.error:#04x}",
                               "table 4.5 or 0x65 ... 0xFF", "error number reserved in the profile"))
        elif klass == "manufacturer":
            out.append(finding("error_manufacturer", frame, f"{name}.error", f"{block.error:#04x}", "",
                               self.names.error(block.error)))
        return out

    # --- the IOD header of a PROFIdrive record -------------------------------------------------
    def iod(self, api: int, slot: int, subslot: int, index: int, frame: int) -> list[Finding]:
        out: list[Finding] = []
        self.limit("iod.api", "iod.api", api, frame, out)
        self.limit("iod.slot", "iod.slot", slot, frame, out)
        self.limit("iod.subslot", "iod.subslot", subslot, frame, out)
        self.limit("iod.index", "iod.index", index, frame, out)
        return out


@cache
def _address_fields(i: int) -> tuple[str, str, str, str]:
    """Field names of parameter address i (built once, not per frame)."""
    return f"pd.addr[{i}].attr", f"pd.addr[{i}].n_elems", f"pd.addr[{i}].pnu", f"pd.addr[{i}].subindex"


@cache
def _value_fields(i: int) -> tuple[str, str]:
    return f"pd.val[{i}].format", f"pd.val[{i}].n_values"


def n_values_read(p: Parsed, frame: int, request: Parsed) -> list[Finding]:
    """Q7: a positive read response's No. of values against the requested elements (the channel's last
    parameter request, protocol.md 6.4)."""
    if p.ident != pt.RES_READ:
        return []
    out = []
    for i, (b, a) in enumerate(zip(p.blocks, request.addresses, strict=False)):
        if a.attr == pt.ATTR_VALUE and not b.is_error and b.n_values != max(a.n_elems, 1):
            out.append(finding("n_values_read", frame, f"pd.val[{i}].n_values", b.n_values, max(a.n_elems, 1),
                               f"{a.label()}: No. of values differs from the requested elements"))
    return out
