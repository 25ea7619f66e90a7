"""Did-you-mean suggestions for names a user mistyped (node types, ports, params, keys…).

One helper for the engine and for node libraries (``nodes/huang`` uses it for cosmetic names),
so every message suggests names the same way: a case-insensitive exact match first, then the
closest spelling by :func:`difflib.get_close_matches` (ratio ≥ 0.6).
"""
from __future__ import annotations

import difflib
from typing import Iterable


def closest(word: str, choices: Iterable[str], cutoff: float = 0.6) -> str | None:
    """The choice ``word`` most likely meant, or None when none is close."""
    choices = [str(c) for c in choices]
    word = str(word)
    low = {c.lower(): c for c in choices}
    if word.lower() in low and low[word.lower()] != word:
        return low[word.lower()]
    m = difflib.get_close_matches(word, choices, n=1, cutoff=cutoff)
    return m[0] if m else None


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """``"; did you mean 'X'?"`` to append to a message, or ``""``."""
    c = closest(word, choices)
    return f"; did you mean '{c}'?" if c else ""


def unknown_keys(doc, path: tuple, mapping: dict, allowed, what: str) -> None:
    """Report every key of ``mapping`` not in ``allowed`` at its place: ``WHAT: unknown key 'x'; did
    you mean 'y'?`` (``doc`` is a graph document: ``doc.at(path, message, key=True)``)."""
    for k in mapping:
        if k not in allowed:
            doc.at(path + (k,), f"{what}unknown key '{k}'{did_you_mean(k, allowed)}", key=True)


__all__ = ["closest", "did_you_mean", "unknown_keys"]
