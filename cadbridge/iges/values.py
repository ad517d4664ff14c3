"""Conversion of free-format tokens to IGES integers, reals and strings (strict, located)."""

from __future__ import annotations

import re

from cadbridge.iges.errors import IgesError
from cadbridge.iges.lexer import Token

__all__ = ["parse_int", "parse_real", "parse_int_text", "parse_real_text", "MAX_TOKEN"]

MAX_TOKEN = 64  # longer numeric tokens are rejected (no megabyte integers)
_INT = re.compile(r"[+-]?\d+")
_REAL = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([EeDd][+-]?\d+)?")


def parse_int(tok: Token, default: int = 0) -> int:
    """IGES integer; an empty field gives ``default``. Reals with an integral value such as
    ``2.`` are accepted (some writers emit them). Raises ValueError with a short reason."""
    return parse_int_text(tok.text, tok.is_string, default)


def parse_int_text(s: str, is_string: bool = False, default: int = 0) -> int:
    """`parse_int` on a token's text (no Token object needed)."""
    if is_string:
        raise ValueError(f"expected an integer, got the string {s[:20]!r}")
    if not s:
        return default
    if len(s) > MAX_TOKEN:
        raise ValueError(f"number too long ({len(s)} characters)")
    if s.isdecimal() or (s[0] in "+-" and s[1:].isdecimal()) or _INT.fullmatch(s):  # isdecimal == \d
        return int(s)
    if _REAL.fullmatch(s):
        x = float(s.replace("D", "E").replace("d", "e"))
        if x.is_integer():
            return int(x)
    raise ValueError(f"expected an integer, got {s[:20]!r}")


def parse_real(tok: Token, default: float = 0.0) -> float:
    """IGES real (``1.``, ``.5``, ``1.0D0``, ``1E-008``, integers); empty gives ``default``.
    Raises ValueError for anything else, including values that overflow to infinity."""
    return parse_real_text(tok.text, tok.is_string, default)


def parse_real_text(s: str, is_string: bool = False, default: float = 0.0) -> float:
    """`parse_real` on a token's text (no Token object needed)."""
    if is_string:
        raise ValueError(f"expected a real, got the string {s[:20]!r}")
    if not s:
        return default
    if len(s) > MAX_TOKEN or not _REAL.fullmatch(s):
        raise ValueError(f"expected a real number, got {s[:20]!r}")
    x = float(s.replace("D", "E").replace("d", "e"))
    if x in (float("inf"), float("-inf")):
        raise ValueError(f"real number {s!r} overflows")
    return x
