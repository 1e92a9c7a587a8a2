"""Transaction verdicts (protocol.md 7.4): the one definition of their names and order."""

from __future__ import annotations

# Precedence: the first verdict whose condition holds is the transaction's (protocol.md 7.4).
PRECEDENCE = ("malformed", "pnio_error", "timeout", "reference_mismatch", "nak", "ok")
# Display order, best first: the categories of the `verdict` column, the summary and the plots.
VERDICTS = tuple(reversed(PRECEDENCE))
# The device answered the parameter request (positively or with a NAK): its values count as read.
ANSWERED = frozenset({"ok", "nak"})
# The controller may retry these with the same Request Reference (T4) rather than reuse it (T1).
FAILED_UNANSWERED = frozenset({"pnio_error", "timeout"})
# The exchange failed (T8 txn_failed, protocol.md 6.5): the drive never gave a parameter response that counts.
FAILED = frozenset({"malformed", "pnio_error", "timeout"})
