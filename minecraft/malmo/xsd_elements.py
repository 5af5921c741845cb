"""XML Schema elements as Python data, and the check of an element tree against them.

A ``Rule`` says what one element may hold: its attributes (each checked by an
``xsd_types`` value check), which of them are required, and its content: nothing, text,
children in order (``xs:sequence``, with ``xs:choice`` as a particle of several names),
children in any order (``xs:all``) or anything (not checked below). ``el``, ``text``,
``seq``, ``all_of``, ``one``, ``opt`` and ``many`` write rules the way the schema reads.
``check`` walks an element tree in Malmo's namespace against a rule and raises
``SchemaError`` on the first violation, naming the element and what was wrong.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Optional

from minecraft.malmo.xsd_types import (
    DECIMAL,
    INT,
    STRING,
    Check,
    did_you_mean,
    int_range,
    string,
)

NS = "http://ProjectMalmo.microsoft.com"


class SchemaError(ValueError):
    """The mission breaks Malmo's schema; the message names the element."""


@dataclass(frozen=True)
class Rule:
    """What one element may hold.

    Attributes:
        attrs: attribute name -> value check (undeclared attributes are refused).
        required: attributes that must be present.
        kind: ``empty``, ``text`` (checked by ``text``), ``seq`` (``particles`` in
            order), ``all`` (``children`` in any order, each at most once, ``needed``
            ones present) or ``any`` (not checked below this element).
        particles: for ``seq``: (child name -> rule, min, max or None) in order; a
            particle with several names is a choice.
        children: for ``all``: child name -> rule.
        needed: for ``all``: children that must be present.
        text: for ``text``: the value check.
    """

    attrs: Mapping[str, Check] = field(default_factory=dict)
    required: frozenset[str] = frozenset()
    kind: str = "empty"
    particles: tuple[tuple[Mapping[str, Rule], int, Optional[int]], ...] = ()
    children: Mapping[str, Rule] = field(default_factory=dict)
    needed: frozenset[str] = frozenset()
    text: Check = string


Particle = tuple[Mapping[str, Rule], int, Optional[int]]


def el(attrs: Optional[Mapping[str, Check]] = None, req: str = "") -> Rule:
    """An element without content; ``attrs`` its attributes, ``req`` the required ones."""
    return Rule(dict(attrs or {}), frozenset(req.split()))


def text(check: Check) -> Rule:
    """An element holding a value, checked by ``check``."""
    return Rule(kind="text", text=check)


def seq(*particles: Particle, attrs: Optional[Mapping[str, Check]] = None, req: str = "") -> Rule:
    """An element whose children come in the order of ``particles``."""
    return Rule(dict(attrs or {}), frozenset(req.split()), "seq", particles)


def all_of(
    children: Mapping[str, Rule], needed: str = "", attrs: Optional[Mapping[str, Check]] = None
) -> Rule:
    """An element whose children come in any order, each at most once."""
    return Rule(
        dict(attrs or {}), kind="all", children=dict(children), needed=frozenset(needed.split())
    )


def one(name: str, rule: Rule) -> Particle:
    return ({name: rule}, 1, 1)


def opt(name: str, rule: Rule) -> Particle:
    return ({name: rule}, 0, 1)


def many(rules: Mapping[str, Rule], lo: int = 1) -> Particle:
    return (rules, lo, None)


ANY = Rule(kind="any")
EMPTY = Rule()
POS = {"x": DECIMAL, "y": DECIMAL, "z": DECIMAL}
INT_POS = {"x": INT, "y": INT, "z": INT}
DIM = {"dimension": int_range(0)}
DESC = {"description": STRING}


# ------------------------------------------------------------------- check
def local_name(e: ET.Element, where: str) -> str:
    """The element's name in Malmo's namespace (``where``: its path, for the error)."""
    tag = e.tag
    if not isinstance(tag, str) or not tag.startswith("{"):
        raise SchemaError(f"{where}<{tag}> is not in Malmo's namespace {NS!r} (add xmlns)")
    uri, local = tag[1:].split("}", 1)
    if uri != NS:
        raise SchemaError(f"{where}<{local}> is in namespace {uri!r}, not Malmo's {NS!r}")
    return local


def check(e: ET.Element, rule: Rule, path: str) -> None:
    """Check element ``e`` (at ``path``) and everything below it against ``rule``.

    Raises:
        SchemaError: the first violation, naming the element.
    """
    if rule.kind == "any":
        return
    for attr, value in e.attrib.items():
        if attr.startswith("{"):
            continue  # xsi:... and other namespaced attributes
        check = rule.attrs.get(attr)
        if check is None:
            raise SchemaError(
                f"{path}: attribute {attr!r} is not allowed" + did_you_mean(attr, rule.attrs)
            )
        problem = check(value)
        if problem is not None:
            raise SchemaError(f"{path}: {attr}={value!r} {problem}")
    for attr in sorted(rule.required - set(e.attrib)):
        raise SchemaError(f"{path}: required attribute {attr!r} is missing")
    kids = list(e)
    if rule.kind == "text":
        if kids:
            raise SchemaError(f"{path}: holds <{local_name(kids[0], path + '/')}> but only text")
        problem = rule.text(e.text or "")
        if problem is not None:
            raise SchemaError(f"{path}: {(e.text or '').strip()!r} {problem}")
        return
    if (e.text or "").strip() or any((k.tail or "").strip() for k in kids):
        raise SchemaError(f"{path}: text is not allowed here")
    if rule.kind == "empty":
        if kids:
            raise SchemaError(f"{path}: must be empty, holds <{local_name(kids[0], path + '/')}>")
    elif rule.kind == "all":
        _check_all(kids, rule, path)
    else:
        _check_seq(kids, rule, path)


def _child_path(path: str, name: str, index: int) -> str:
    return f"{path}/<{name}>" + (f"[{index}]" if index else "")


def _check_all(kids: list[ET.Element], rule: Rule, path: str) -> None:
    seen: set[str] = set()
    for k in kids:
        name = local_name(k, path + "/")
        child = rule.children.get(name)
        if child is None:
            raise SchemaError(
                f"{path}: unknown element <{name}>" + did_you_mean(name, rule.children)
            )
        if name in seen:
            raise SchemaError(f"{path}: <{name}> appears twice (at most once)")
        seen.add(name)
        check(k, child, _child_path(path, name, 0))
    for name in sorted(rule.needed - seen):
        raise SchemaError(f"{path}: required element <{name}> is missing")


def _check_seq(kids: list[ET.Element], rule: Rule, path: str) -> None:
    i = 0
    names = [local_name(k, path + "/") for k in kids]
    for choices, lo, hi in rule.particles:
        count = 0
        while i < len(kids) and names[i] in choices and (hi is None or count < hi):
            check(kids[i], choices[names[i]], _child_path(path, names[i], count))
            i, count = i + 1, count + 1
        if count < lo:
            wanted = " or ".join(f"<{n}>" for n in choices)
            found = f", found <{names[i]}>" if i < len(names) else ""
            raise SchemaError(f"{path}: expected {wanted}{found}")
    if i < len(kids):
        name = names[i]
        known = {n for choices, _, _ in rule.particles for n in choices}
        if name in known:
            raise SchemaError(f"{path}: <{name}> is out of order or repeated")
        raise SchemaError(f"{path}: unknown element <{name}>" + did_you_mean(name, known))
