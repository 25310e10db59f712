"""Counts as a reader says them ("1 trial", "3 trials"), for every message that counts things."""

from __future__ import annotations


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """`n` and the noun, singular for exactly one (the plural adds an s unless given)."""
    return f"{n:,} {noun if n == 1 else plural or noun + 's'}"
