"""Counts as a reader says them ("1 trial", "3 trials"), for every message that counts things."""

from __future__ import annotations


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """`n` and the noun, singular for exactly one (the plural adds an s unless given)."""
    return f"{n:,} {noun if n == 1 else plural or noun + 's'}"


def verb(n: int, one: str, many: str) -> str:
    """The verb that agrees with a count of `n` ("1 trial is", "3 trials are")."""
    return one if n == 1 else many
