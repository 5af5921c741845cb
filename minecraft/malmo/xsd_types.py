"""XML Schema simple types as value checks: ``xs:int``, ``xs:decimal`` and ``xs:boolean``
(whitespace collapsed, as the schema's types do), ranges, enumerations and lists, and the
Minecraft name types of Malmo's ``Types.xsd`` (blocks, items, mobs, colours, variants).

A check takes the attribute or element text and returns None when it is valid, else a
phrase saying what is wrong (``"is not an integer"``).
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Callable, Iterable
from typing import Optional

from minecraft import names as N

Check = Callable[[str], Optional[str]]  # the value -> None if valid, else what is wrong

_INT = re.compile(r"[+-]?\d+$")
_DECIMAL = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)$")
_XML_NAME = re.compile(r"[A-Za-z_:][\w.:-]*$")


def int_range(lo: Optional[float] = None, hi: Optional[float] = None) -> Check:
    """``xs:int``, optionally restricted to [lo, hi]."""

    def check(v: str) -> Optional[str]:
        v = v.strip()
        if not _INT.match(v) or not -(2**31) <= int(v) < 2**31:
            return "is not an integer"
        return _in_range(int(v), lo, hi)

    return check


def decimal_range(lo: Optional[float] = None, hi: Optional[float] = None) -> Check:
    """``xs:decimal`` (no exponent), optionally restricted to [lo, hi]. A decimal too
    long for a double (it would read as infinity) is refused: nothing simulates it."""

    def check(v: str) -> Optional[str]:
        v = v.strip()
        if not _DECIMAL.match(v):
            return "is not a decimal number"
        x = float(v)
        if not math.isfinite(x):
            return "is not a finite number (beyond a double's range)"
        return _in_range(x, lo, hi)

    return check


def _in_range(x: float, lo: Optional[float], hi: Optional[float]) -> Optional[str]:
    if (lo is not None and x < lo) or (hi is not None and x > hi):
        return f"is outside [{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]"
    return None


def boolean(v: str) -> Optional[str]:
    """``xs:boolean``."""
    return None if v.strip() in ("true", "false", "1", "0") else "is not true/false/1/0"


def string(v: str) -> Optional[str]:
    """``xs:string``: anything."""
    return None


def xml_name(v: str) -> Optional[str]:
    """``xs:Name``."""
    return None if _XML_NAME.match(v.strip()) else "is not an XML name"


def hex3(v: str) -> Optional[str]:
    """Three bytes of ``xs:hexBinary`` (a colour)."""
    return None if re.fullmatch(r"[0-9a-fA-F]{6}", v.strip()) else "is not 6 hex digits"


def one_of(allowed: frozenset[str] | tuple[str, ...], what: str) -> Check:
    """An enumeration; ``what`` names it in the message (with the closest value)."""
    allowed_set = frozenset(allowed)

    def check(v: str) -> Optional[str]:
        v = v.strip()
        if v in allowed_set:
            return None
        return f"is not {what}" + did_you_mean(v, allowed_set)

    return check


def list_of(allowed: frozenset[str] | tuple[str, ...], what: str) -> Check:
    """``xs:list`` of an enumeration: space-separated values, each checked."""
    one = one_of(allowed, what)

    def check(v: str) -> Optional[str]:
        for item in v.split():
            problem = one(item)
            if problem is not None:
                return f"names {item!r}, which " + problem
        return None

    return check


def did_you_mean(v: str, choices: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``choices``, or nothing."""
    close = difflib.get_close_matches(v, list(choices), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


BLOCK = one_of(N.BLOCK_TYPES, "a Minecraft block type")
BLOCK_OR_ITEM = one_of(N.BLOCK_OR_ITEM_TYPES, "a Minecraft block or item type")
BLOCK_LIST = list_of(N.BLOCK_TYPES, "a Minecraft block type")
BLOCK_OR_ITEM_LIST = list_of(N.BLOCK_OR_ITEM_TYPES, "a Minecraft block or item type")
MOB_LIST = list_of(N.LIVING_ENTITY_TYPES, "a Minecraft mob type")
COLOUR = one_of(N.COLOURS, "a colour")
VARIANT = one_of(N.VARIANTS, "a variant")
FACING = one_of(N.FACINGS, "a facing")
COLOUR_LIST = list_of(N.COLOURS, "a colour")
VARIANT_LIST = list_of(N.VARIANTS, "a variant")
BOOL, STRING, INT, DECIMAL = boolean, string, int_range(), decimal_range()
