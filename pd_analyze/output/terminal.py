"""Text for a terminal: what any command prints of a capture's strings goes through `safe`.

Its own module, not the dump's: every command's errors use it, and `report` should not load the dump (its
JSON writer, its tree) to print one line."""

from __future__ import annotations


def safe(text: str) -> str:
    """Control characters and escape sequences shown escaped, never emitted raw to a terminal."""
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii") for ch in text)
