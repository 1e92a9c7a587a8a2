"""PROFIdrive parameter request/response records (index 0xB02E, 0xB02F, 0x002F).

The hook the record layer calls for every PROFIdrive record. The field-by-field decode of the
parameter request and response belongs here; until it lands the record is shown as raw bytes.
"""

from __future__ import annotations

from pd_analyze.rules import Finding
from pd_analyze.structs import Field, plain


def dissect_record(record: bytes, response: bool, frame: int, base: int,
                   annotate: bool) -> tuple[list[Field], list[Finding]]:
    """Fields and findings of one PROFIdrive record (`base`: offset of the record in its buffer)."""
    del response, frame
    fields = [plain("record.data", 0, record, len(record), record, base)] if annotate else []
    return fields, []
