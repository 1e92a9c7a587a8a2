"""Capture times as the tables hold and write them.

A capture time is an integer of nanoseconds since the epoch, taken from the file's own integer units (never
through a float of seconds, which resolves only about 0.24 us today). A duration is the exact difference of
two such integers, held as float seconds (ns / 1e9: the nearest double, whose shortest text is the exact
decimal). Both are written at the capture's resolution: as many decimals of a second as its timestamps carry
(`digits`: 6 for a microsecond pcap, 9 for a nanosecond one, a pcapng's finest interface), so a microsecond
capture's write RTT reads `0.001499`, never `0.001499176025390625` nor `0.001499000`.
"""

from __future__ import annotations

import math
from datetime import datetime, timedelta

NS = 1_000_000_000  # nanoseconds a second
MAX_DIGITS = 9  # the tables hold nanoseconds: nothing is written finer
DEFAULT_DIGITS = MAX_DIGITS  # a capture whose resolution is unknown (rows made by hand): every nanosecond held
MAX_TIME_NS = 9_200_000_000 * NS  # datetime64[ns] spans 1677 ... 2262: a time beyond is missing (NaT)
_EXACT = 2**53  # a duration is written from the integer of its last decimal while a double holds that exactly
_EPOCH = datetime(1970, 1, 1)  # naive: the zone is written by time_text


def resol_digits(resol: int) -> int:
    """The decimals of a second a pcapng if_tsresol gives: 10^-k s units need k, 2^-n s units (the 0x80 bit)
    need n (a binary fraction of n bits ends n decimals on); at most MAX_DIGITS (nanoseconds are held)."""
    return min(MAX_DIGITS, resol & 0x7F)


def nanos(value: object) -> int | None:
    """A capture time cell as the tables hold it: integer nanoseconds since the epoch; None when missing or
    beyond datetime64[ns] (a pcapng time after 2262)."""
    if value is None or (isinstance(value, float) and value != value):
        return None
    ns = round(value) if isinstance(value, float) else int(value)  # type: ignore[call-overload]
    return ns if -MAX_TIME_NS < ns < MAX_TIME_NS else None


def time_text(ns: int, digits: int, sep: str = " ", zone: str = "+00:00") -> str:
    """A capture time in UTC with `digits` decimals of a second (cut, as a clock reads): CSV's
    `2026-01-01 00:00:00.002936+00:00`; JSON's with sep "T" and zone "Z"."""
    seconds, frac = divmod(ns, NS)
    text = (_EPOCH + timedelta(seconds=seconds)).isoformat(sep)
    return text + (f".{frac:09d}"[:digits + 1] if digits > 0 else "") + zone


def duration_text(seconds: float, digits: int) -> str:
    """Seconds to `digits` decimals (the nearest), without trailing zeros but one, never in exponent form:
    `0.001499`, `0.0015`, `1.0`, `0.000015` (repr would write 1.5e-05). A value too large for the integer of
    its last decimal to be exact in a double, or not finite, as repr writes it."""
    scale = 10**digits
    scaled = seconds * scale
    if not math.isfinite(scaled) or abs(scaled) >= _EXACT:
        return repr(seconds)
    k = round(scaled)
    whole, frac = divmod(abs(k), scale)
    decimals = f"{frac:0{digits}d}".rstrip("0") if digits else ""
    return f"{'-' if k < 0 else ''}{whole}.{decimals or '0'}"


def ms_decimals(digits: int) -> int:
    """Decimals of a millisecond a capture of `digits` decimals of a second resolves."""
    return max(0, digits - 3)


def ms_text(seconds: float, digits: int, column: bool = True) -> str:
    """Seconds as milliseconds to the capture's resolution: in a `column`, with every decimal (aligned):
    `1.500` for a microsecond capture, `1.500000` for a nanosecond one; in a sentence without trailing zeros
    (`1.5`, `1004`); '-' when missing."""
    if seconds != seconds:
        return "-"
    text = f"{seconds * 1000:.{ms_decimals(digits)}f}"
    return text if column or "." not in text else text.rstrip("0").rstrip(".")
