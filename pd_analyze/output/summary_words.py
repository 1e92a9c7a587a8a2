"""The summary's words: how a failure, a refusal, a parameter list, a drive and a time read in its lines (the
counting is output.summary's)."""

from __future__ import annotations

from pd_analyze.model import pd_values as pt
from pd_analyze.model.times import DEFAULT_DIGITS, ms_text


def missing(value: object) -> bool:
    return value is None or (isinstance(value, float) and value != value)


def ms(seconds: float, digits: int = DEFAULT_DIGITS, column: bool = True) -> str:
    """Seconds as milliseconds at a capture's resolution of `digits` decimals of a second ('-' missing): in a
    column every decimal, in a sentence (`column` False) no trailing zero."""
    return ms_text(seconds, digits, column)


def na_text(value: object) -> str:
    return "<NA>" if missing(value) else str(value)


def device_key(device: object) -> tuple:
    """A device key, (capture, address): named when the text is written, by its own capture's station names."""
    capture, address = device if isinstance(device, tuple) else ("", device)
    return (na_text(capture), na_text(address))


def known(value: object) -> str:
    """A slot or DO as the summary prints it: the number, or 'unknown' (a request not decoded), never <NA>."""
    return "unknown" if missing(value) else str(value)


# What stands for the parameters where a row names none: a request that names no parameter (it was decoded:
# No. of parameters 0), and an error that refused the whole request (counted once, not once per parameter)
NO_PARAMETER, WHOLE_REQUEST = "(request of no parameter)", "(whole request)"


def params_label(params: object, n_params: object) -> str:
    """`transactions.params`, or NO_PARAMETER for a request of no parameter (empty too, but decoded)."""
    text = na_text(params)
    return NO_PARAMETER if text in ("", "<NA>") and not missing(n_params) and n_params == 0 else text


FAILED = frozenset({"pnio_error", "timeout", "malformed", "reference_mismatch"})
_UNANSWERED = {"deadline": "no answer within the transaction timeout",
               "superseded": "the controller wrote the next request before an answer came",
               "capture_end": "the capture ended before an answer came",
               "evicted": "dropped by the analyser's limits (too many open transactions or frames)"}


def reason(verdict: object, status: object, closed_by: object, b5: object, last_read: object = None,
           digits: int = DEFAULT_DIGITS) -> str:
    """Why a transaction failed, in words; for a timeout, how long the controller kept reading (at the
    capture's resolution, `digits` decimals of a second)."""
    if verdict == "pnio_error":
        return str(status) if status and not missing(status) else "record service refused"
    if verdict == "timeout":
        why = _UNANSWERED.get(str(closed_by), "no answer")
        stopped = "its last read" if closed_by == "capture_end" else "the controller gave up: last read"
        asked = [] if missing(last_read) else [f"{stopped} {ms(last_read, digits, False)} ms after the write"]  # type: ignore[arg-type]
        if not missing(b5) and b5:
            asked.append(f"{b5} B5 answer{'s' if b5 != 1 else ''}")
        return f"timeout: {why}" + (f" ({', '.join(asked)})" if asked else "")
    if verdict == "malformed":
        return "malformed: a PDU could not be decoded (see the findings)"
    return "reference mismatch: the response does not answer the request"


REFUSED, REFUSED_WHOLE = "refused: error ", "refused as a whole request: error "


def refused_entries(errors: object, params: str) -> list[tuple[str, str]]:
    """(parameter, reason) of each error a NAK carries (`transactions.errors`: 'P1082[0]:0x02 *:0x22'); an error
    of the whole request (`*`) names the request's parameters. The error's text is added when the summary is
    written (`in_words`), from the parameters table: the words the run's profile gives it."""
    out = []
    for item in str(errors).split() if not missing(errors) else ():
        label, _, code = item.rpartition(":")
        out.append((params, REFUSED_WHOLE + code) if label == "*" else (label, REFUSED + code))
    return out


def in_words(why: str, error_texts: dict[str, str]) -> str:
    """A reason with its error number's text: 'refused: error 0x02 (low or high limit exceeded)'."""
    if not why.startswith((REFUSED, REFUSED_WHOLE)):
        return why
    head, _, code = why.rpartition(" ")
    return f"{head} {error_words(code, error_texts)}"


def error_words(code: str, error_texts: dict[str, str]) -> str:
    """An error number with its one text (the run's profile's words, else the PROFIdrive profile's): '0x02 (low
    or high limit exceeded)'; the number alone when it is none."""
    text = error_texts.get(code)
    if text is None:
        try:
            text = pt.error_text(int(code, 16))
        except ValueError:
            return code
    return f"{code} ({text})"


def few(params: str, names: dict[int, str], most: int = 4) -> str:
    """A transaction's parameter list, shortened when long: 'P2000[0] P2001[0] P2002[0] ... (39 parameters)'; one
    parameter with its name where the parameters table gives one: 'P964[0] (drive unit identification)'."""
    if params == NO_PARAMETER:
        return params
    labels = params.split()
    if not labels:
        return "(parameters not decoded)"
    if len(labels) == 1:
        return named(labels[0], names)
    return params if len(labels) <= most else " ".join(labels[:most - 1]) + f" ... ({len(labels)} parameters)"


def named(label: str, names: dict[int, str]) -> str:
    """'P964[0]' as 'P964[0] (drive unit identification)' where the parameters table names its PNU."""
    pnu = label[1:].partition("[")[0]
    name = names.get(int(pnu), "") if label.startswith("P") and pnu.isdigit() else ""
    return f"{label} ({name})" if name else label
