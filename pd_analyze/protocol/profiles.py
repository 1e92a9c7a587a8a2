"""Vendor profiles: limits per field as data (TOML), each with the source it comes from.

The packaged profiles live in pd_analyze/profiles/*.toml; a user adds one for another drive by
writing a TOML file in the same form and passing its path (or putting it in a directory named by
PD_ANALYZE_PROFILES). Profiles are data only: a file is parsed with tomllib, never executed.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from functools import cache
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Any

from pd_analyze.model.fields import value_text
from pd_analyze.model.files import open_problem
from pd_analyze.model.pd_values import Names
from pd_analyze.model.rules import AKD, RULES, YASKAWA_EP3

# Limit keys: the field each one constrains and where it applies.
LIMIT_KEYS: Mapping[str, tuple[str, str]] = MappingProxyType({
    "request.ref": ("pd.ref", "parameter request: Request Reference"),
    "request.req_id": ("pd.req_id", "parameter request: Request ID"),
    "request.do": ("pd.do", "parameter request: DO-ID"),
    "request.n_params": ("pd.n_params", "parameter request: No. of parameters"),
    "request.attribute": ("pd.addr[i].attr", "parameter address: Attribute"),
    "request.n_elems": ("pd.addr[i].n_elems", "parameter address: No. of elements"),
    "request.pnu": ("pd.addr[i].pnu", "parameter address: PNU"),
    "request.subindex": ("pd.addr[i].subindex", "parameter address: Subindex"),
    "request.format": ("pd.val[i].format", "change request: Format"),
    "request.n_values": ("pd.val[i].n_values", "change request: No. of values"),
    "response.ref": ("pd.ref", "parameter response: Request Reference"),
    "response.resp_id": ("pd.resp_id", "parameter response: Response ID"),
    "response.do": ("pd.do", "parameter response: DO-ID"),
    "response.n_params": ("pd.n_params", "parameter response: No. of parameters"),
    "response.format": ("pd.val[i].format", "parameter response: Format of each block"),
    "response.n_values": ("pd.val[i].n_values", "parameter response: No. of values of value blocks"),
    "response.length": ("iod.record_len", "parameter response: record length"),
    "iod.api": ("iod.api", "PROFIdrive record request: API"),
    "iod.slot": ("iod.slot", "PROFIdrive record request: SlotNumber"),
    "iod.subslot": ("iod.subslot", "PROFIdrive record request: SubslotNumber"),
    "iod.index": ("iod.index", "PROFIdrive record request: Index"),
})
TOLERATIONS = MappingProxyType({
    "format_00_zero": f"Format 0x00 accepted as Zero 'no data' ({AKD})",
    "trailing_00_00": f"positive change response followed by 00 00 is only noted ({AKD})",
    "api_dap": f"API 0x0000 on 0xB02E is only noted ({YASKAWA_EP3})",
})
DEFAULT = "generic"
ENV_DIR = "PD_ANALYZE_PROFILES"


class ProfileError(Exception):
    """A profile cannot be found or is not a valid profile file."""


@dataclass(frozen=True, slots=True)
class Limit:
    key: str
    field: str
    ranges: tuple[tuple[int, int], ...]
    source: str
    rule: str  # finding name when broken

    def allows(self, value: int) -> bool:
        for lo, hi in self.ranges:  # noqa: SIM110 - a plain loop: this runs for every field checked
            if lo <= value <= hi:
                return True
        return False

    def text(self) -> str:
        hexa = value_text(self.field, 0).startswith("0x")  # the registry decides, as for the field itself
        return ", ".join(_num(lo, hexa) if lo == hi else f"{_num(lo, hexa)} ... {_num(hi, hexa)}"
                         for lo, hi in self.ranges)


def _num(value: int, hexa: bool = False) -> str:
    return f"0x{value:02x}" if hexa else str(value)


@dataclass(frozen=True, slots=True)
class RecordLimit:
    """The longest parameter request or response a profile allows, and the limits that follow from it."""

    max_length: int
    source: str

    @property
    def max_params(self) -> int:
        """Parameter addresses that fit a request: 4-byte header, 6 bytes each."""
        return (self.max_length - 4) // 6

    @property
    def max_elements(self) -> int:
        """Elements of 1-byte values that fit a response: 4-byte header, Format and No. of values."""
        return self.max_length - 6

    @property
    def max_value_bytes(self) -> int:
        """One parameter's values in a change request: header, one address, Format and No. of values."""
        return self.max_length - 12

    def limits(self, rule: str) -> tuple[Limit, ...]:
        """The limits the record length implies, as if the profile file listed them."""
        src, top = self.source, self.max_length
        return (
            Limit("request.n_params", LIMIT_KEYS["request.n_params"][0], ((1, self.max_params),),
                  f"{src}: 4 + {self.max_params} x 6 <= {top}", rule),
            Limit("request.n_elems", LIMIT_KEYS["request.n_elems"][0], ((0, self.max_elements),),
                  f"{src}: {top} - 6 bytes of 1-byte values", rule),
            Limit("response.length", LIMIT_KEYS["response.length"][0], ((0, top),),
                  f"{src}: longer responses are refused with error 0x15; < 4 is Q1", "response_too_long"),
        )


LAYOUTS = ("read", "change")  # a vendor request laid out as a request parameter or a change parameter (3.1)
ERROR_WORDS = ("", "class_code")  # how a vendor shows error values above the profile's (5.5)


@dataclass(frozen=True, slots=True)
class Service:
    """What a vendor request does, named by its Attribute's high nibble (e.g. SEW MOVILINK, protocol.md 5.5)."""

    name: str
    layout: str  # "read": addresses only; "change": addresses, then one value block each


@dataclass(frozen=True, slots=True)
class VendorRequest:
    """A vendor's own Request ID carried in the PROFIdrive record, with its layout and the answers it gets."""

    ident: int
    name: str
    layout: str
    answers: tuple[int, ...]  # the Response IDs that answer it (Q3)
    source: str
    services: Mapping[int, Service] = field(default_factory=dict)  # by Attribute & 0xF0; empty: none

    def service(self, attribute: int) -> Service | None:
        return self.services.get(attribute & 0xF0) if self.services else None

    def layout_of(self, attribute: int) -> str:
        """The layout of a request whose first address carries `attribute`."""
        service = self.service(attribute)
        return service.layout if service is not None else self.layout


@dataclass(frozen=True, slots=True)
class VendorResponse:
    """A vendor's own Response ID: positive ones carry value blocks (or nothing), negative ones error blocks."""

    ident: int
    name: str
    negative: bool
    source: str
    error_words: str = ""  # the profile's error_words: how its error values above 0xFF read

    def error_text(self, value: int) -> str | None:
        return error_word_text(self.error_words, value)


@dataclass(frozen=True, slots=True)
class VendorIds:
    """A profile's own request and response IDs (protocol.md 5.5): what the parse and the checks add to the
    PROFIdrive ones under that profile. Under any other profile the IDs stay reserved."""

    requests: Mapping[int, VendorRequest]
    responses: Mapping[int, VendorResponse]
    error_words: str = ""  # "class_code": an error value above 0xFF is a class (high byte) and a code (low)

    def error_text(self, value: int) -> str | None:
        return error_word_text(self.error_words, value)

    def listing(self) -> list[str]:
        """The IDs as `pd-analyze profiles` lists them, each with its source."""
        lines = []
        for r in self.requests.values():
            answers = "/".join(f"{a:#04x}" for a in r.answers)
            lines.append(f"    Request ID {r.ident:#04x} {r.name} (layout {r.layout}, answered {answers})"
                         f"  <- {r.source}")
            lines += [f"      Attribute {attr:#04x}: {svc.name} ({svc.layout})" for attr, svc in r.services.items()]
        for res in self.responses.values():
            lines.append(f"    Response ID {res.ident:#04x} {res.name}  <- {res.source}")
        if self.error_words:
            lines.append("    error values above 0x64: class (high byte) and additional code (low byte)")
        return lines


def error_word_text(words: str, value: int) -> str | None:
    """A vendor's error word as class and additional code (protocol.md 5.5: above the PROFIdrive numbers
    0x00 ... 0x64); None when it is a PROFIdrive error number or the profile has no error words."""
    if words != "class_code" or value <= 0x64:
        return None
    high, low = value >> 8, value & 0xFF
    if high == 0 and value >= 0x80:  # one manual writes 0x0080 + additional code
        return f"vendor error: 0x0080 + additional code {value - 0x80:#04x}"
    return f"vendor error: class {high:#04x}, additional code {low:#04x}"


@dataclass(frozen=True, slots=True)
class Profile:
    name: str
    title: str
    description: str
    limits: tuple[Limit, ...]
    error_texts: Mapping[int, str] = field(default_factory=dict)
    tolerate: frozenset[str] = frozenset()
    vendor_ids: tuple[int, ...] = ()
    path: str = ""
    record: RecordLimit | None = None  # the generic profile always has one
    ids: VendorIds | None = None  # the profile's own request/response IDs, if it has any
    pnu_names: Mapping[int, str] = field(default_factory=dict)  # the drive's own parameter names ([pnu_names])

    @property
    def names(self) -> Names:
        """The parameter names and error texts this profile adds to the PROFIdrive ones."""
        return Names(dict(self.pnu_names), dict(self.error_texts))  # (plain dicts: Rows carry them across processes)

    def limits_for(self, key: str) -> tuple[Limit, ...]:
        return tuple(lim for lim in self.limits if lim.key == key)


def load_file(path: str | Path, default_rule: str = "vendor_limit") -> Profile:
    """A profile from a TOML file; ProfileError names the file and what is wrong."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ProfileError(f"{path}: {open_problem(exc)}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ProfileError(f"{path}: not valid TOML ({exc})") from None
    return _profile(data, str(path), default_rule)


def _profile(data: dict, where: str, default_rule: str) -> Profile:
    def fail(message: str) -> ProfileError:
        return ProfileError(f"{where}: {message}")

    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise fail("missing 'name' (a short profile name)")
    unknown = set(data) - {"name", "title", "description", "limit", "error_texts", "tolerate", "vendor_ids", "record",
                           "request_id", "response_id", "error_words", "pnu_names"}
    if unknown:
        raise fail(f"unknown top-level keys {sorted(unknown)}")

    def typed(table: dict, key: str, kind: type, what: str, default: object) -> Any:
        """A value of the file, of the type the profile format wants (TOML can hold any type anywhere)."""
        value = table.get(key, default)
        if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
            raise fail(f"'{key}' must be {what}, not {type(value).__name__} {value!r}"[:300])
        return value

    for key in ("title", "description"):
        typed(data, key, str, "a string", "")
    limits = []
    for n, item in enumerate(typed(data, "limit", list, "an array of tables ([[limit]])", []), 1):
        if not isinstance(item, dict):
            raise fail(f"limit #{n} is not a table")
        key = typed(item, "key", str, "a string (see LIMIT_KEYS)", "")
        if key not in LIMIT_KEYS:
            raise fail(f"limit #{n}: unknown key {key!r} (known: {', '.join(LIMIT_KEYS)})")
        source = item.get("source")
        if not isinstance(source, str) or not source:
            raise fail(f"limit #{n} ({key}): every limit needs its 'source' (manual and table)")
        rule = typed(item, "rule", str, "a rule name", default_rule)
        if rule not in RULES:
            raise fail(f"limit #{n} ({key}): unknown rule {rule!r}")
        allowed = typed(item, "allowed", list, 'a list of numbers or "lo-hi" ranges, e.g. ["1-16"]', [])
        ranges = tuple(_range(v, fail, n, key) for v in allowed)
        if not ranges:
            raise fail(f"limit #{n} ({key}): 'allowed' must list values or 'lo-hi' ranges")
        limits.append(Limit(key, LIMIT_KEYS[key][0], ranges, source, rule))
    texts = {}
    for k, v in typed(data, "error_texts", dict, 'a table ([error_texts], "0x70" = "text")', {}).items():
        try:
            texts[int(k, 0)] = str(v)
        except ValueError:
            raise fail(f"error_texts: key {k!r} is not a number like \"0x65\"") from None
    names = {}
    for k, v in typed(data, "pnu_names", dict, 'a table ([pnu_names], "1082" = "maximum speed")', {}).items():
        pnu = _pnu(k)
        if pnu is None:
            raise fail(f"pnu_names: key {k!r} is not a parameter number 1 ... 65535 like \"1082\" or \"p1082\"")
        if not isinstance(v, str) or not v.strip():
            raise fail(f"pnu_names: the name of {k!r} must be a non-empty string")
        names[pnu] = v.strip()
    tolerate_list = typed(data, "tolerate", list, "a list of names", [])
    if not all(isinstance(t, str) for t in tolerate_list):
        raise fail(f"tolerate entries must be names (known: {', '.join(TOLERATIONS)})")
    tolerate = frozenset(tolerate_list)
    if tolerate - set(TOLERATIONS):
        raise fail(f"unknown tolerate entries {sorted(tolerate - set(TOLERATIONS))} "
                   f"(known: {', '.join(TOLERATIONS)})")
    vendor_ids = tuple(typed(data, "vendor_ids", list, "a list of integers", []))
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in vendor_ids):
        raise fail("vendor_ids must be integers")
    record = None
    if "record" in data:
        table = typed(data, "record", dict, "a table ([record] max_length, source)", {})
        record = RecordLimit(typed(table, "max_length", int, "an integer", 0),
                             typed(table, "source", str, "a string", ""))
        if record.max_length < 10 or not record.source:
            raise fail("[record] needs max_length (at least 10 bytes) and its source")
        limits += [lim for lim in record.limits(default_rule) if not any(k.key == lim.key for k in limits)]
    elif name == DEFAULT:
        raise fail("the generic profile needs its [record] max_length and source (protocol.md 3.6)")
    return Profile(name, str(data.get("title", name)), str(data.get("description", "")), tuple(limits),
                   MappingProxyType(texts), tolerate, vendor_ids, where, record, _ids(data, typed, fail),
                   MappingProxyType(names))


def _pnu(key: str) -> int | None:
    """A parameter number as a name table writes it: "1082", "0x43A", or with the r/p prefix drive manuals
    print ("p1082", "r0947"); None when it is none of these or outside 1 ... 65535."""
    text = key.strip()
    if text[:1] in ("p", "P", "r", "R"):
        text = text[1:]
    try:
        number = int(text, 16) if text.lower().startswith("0x") else int(text, 10)
    except ValueError:
        return None
    return number if 1 <= number <= 0xFFFF else None


def _ids(data: dict, typed, fail) -> VendorIds | None:  # noqa: ANN001
    """[[request_id]] and [[response_id]] tables: a vendor's own IDs in the PROFIdrive record (5.5)."""
    def number(table: dict, key: str, what: str) -> int:
        value = typed(table, key, int, f"an integer ({what})", -1)
        if not 0 <= value <= 0xFF:
            raise fail(f"{what}: {key} must be 0x00 ... 0xFF")
        return value

    def text(table: dict, key: str, what: str) -> str:
        value = typed(table, key, str, "a string", "")
        if not value:
            raise fail(f"{what}: every entry needs its '{key}'")
        return value

    def layout(table: dict, what: str) -> str:
        value = typed(table, "layout", str, f"one of {', '.join(LAYOUTS)}", "read")
        if value not in LAYOUTS:
            raise fail(f"{what}: layout {value!r} is not one of {', '.join(LAYOUTS)}")
        return value

    def entries(key: str) -> Iterator[tuple[str, dict]]:
        """The tables of an array of tables ([[key]]), each with how an error names it."""
        for n, item in enumerate(typed(data, key, list, f"an array of tables ([[{key}]])", []), 1):
            if not isinstance(item, dict):
                raise fail(f"{key} #{n} is not a table")
            yield f"{key} #{n}", item

    requests: dict[int, VendorRequest] = {}
    for what, item in entries("request_id"):
        ident = number(item, "id", what)
        if ident in (0x01, 0x02):
            raise fail(f"{what}: 0x01 and 0x02 are the profile's own Request IDs")
        answers = typed(item, "answers", list, "a list of Response IDs", [])
        if not answers or not all(isinstance(a, int) and not isinstance(a, bool) for a in answers):
            raise fail(f"{what}: 'answers' must list the Response IDs that answer it")
        services = {}
        for k, svc in enumerate(typed(item, "service", list, "an array of tables ([[request_id.service]])", []), 1):
            where = f"{what} service #{k}"
            if not isinstance(svc, dict):
                raise fail(f"{where} is not a table")
            attribute = number(svc, "attribute", where)
            services[attribute & 0xF0] = Service(text(svc, "name", where), layout(svc, where))
        requests[ident] = VendorRequest(ident, text(item, "name", what), layout(item, what), tuple(answers),
                                        text(item, "source", what), MappingProxyType(services))
    words = typed(data, "error_words", str, f"one of {ERROR_WORDS}", "")
    if words not in ERROR_WORDS:
        raise fail(f"error_words {words!r} is not one of {', '.join(repr(w) for w in ERROR_WORDS)}")
    responses: dict[int, VendorResponse] = {}
    for what, item in entries("response_id"):
        ident = number(item, "id", what)
        if ident in (0x01, 0x02, 0x80, 0x81, 0x82):
            raise fail(f"{what}: {ident:#04x} is one of the profile's own Response IDs")
        responses[ident] = VendorResponse(ident, text(item, "name", what), bool(ident & 0x80),
                                          text(item, "source", what), words)
    if not requests and not responses and not words:
        return None
    return VendorIds(MappingProxyType(requests), MappingProxyType(responses), words)


def _range(value: object, fail, n: int, key: str) -> tuple[int, int]:  # noqa: ANN001
    if isinstance(value, bool):
        raise fail(f"limit #{n} ({key}): {value!r} is not a number")
    if isinstance(value, int):
        return value, value
    if isinstance(value, str):
        lo, sep, hi = value.partition("-")
        try:
            low = int(lo.strip(), 0)
            return (low, int(hi.strip(), 0)) if sep else (low, low)
        except ValueError:
            pass
    raise fail(f"limit #{n} ({key}): {value!r} is not a number or a 'lo-hi' range")


def packaged() -> dict[str, Path]:
    """The profiles shipped with pd-analyze, by name, plus those in $PD_ANALYZE_PROFILES."""
    found = {}
    for entry in resources.files("pd_analyze.protocol").joinpath("profile_data").iterdir():
        if entry.name.endswith(".toml"):
            found[entry.name[:-5]] = Path(str(entry))
    extra = os.environ.get(ENV_DIR)
    if extra and Path(extra).is_dir():
        for path in sorted(Path(extra).glob("*.toml")):
            found[path.stem] = path
    return found


def load(name_or_path: str) -> Profile:
    """A profile by name (packaged or in $PD_ANALYZE_PROFILES) or by path to a .toml file."""
    if name_or_path.endswith(".toml") or os.sep in name_or_path:
        return load_file(name_or_path, "pd_request_range" if Path(name_or_path).stem == DEFAULT
                         else "vendor_limit")
    known = packaged()
    if name_or_path not in known:
        raise ProfileError(f"unknown profile {name_or_path!r} (known: {', '.join(sorted(known))}; "
                           "or give the path of a .toml profile file)")
    return load_file(known[name_or_path], "pd_request_range" if name_or_path == DEFAULT else "vendor_limit")


def generic() -> Profile:
    return load(DEFAULT)


@cache
def generic_record() -> RecordLimit:
    """The generic profile's record limit, read once (for callers not given a Checker's)."""
    record = generic().record
    assert record is not None  # _profile refuses a generic profile without one
    return record
