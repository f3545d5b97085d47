"""How a SCPI instrument reads a program message (SCPI-1999 vol. 1 ch. 6-7, IEEE 488.2 ch. 7),
for the simulated bench's SCPI twins.

A message is program message units separated by `;`; a unit is a header (`*CLS`, `VOLT`,
`:SOUR2:VOLT:LEV`), `?` for a query, and comma-separated parameters. A unit without a leading
`:` continues from the path of the unit before it in the same message (`:OUTP:OVP ON;VAL 5`
is `:OUTP:OVP:VAL 5`); common commands leave the path alone. A header matches a command's
pattern (`[SOURce#]:VOLTage[:LEVel][:IMMediate][:AMPLitude]`) in its short or long form, case
ignored, optional nodes left out, `#` a numeric suffix. What an instrument refuses is a
`Refused` with the SCPI error code and text it queues.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache


class Refused(Exception):
    """A unit the instrument refuses: its SCPI error (code, text) goes to the error queue."""

    def __init__(self, code: int, text: str) -> None:
        super().__init__(f"{code},{text}")
        self.code = code
        self.text = text


UNDEFINED_HEADER = Refused(-113, "Undefined header")
MISSING_PARAMETER = Refused(-109, "Missing parameter")
PARAMETER_NOT_ALLOWED = Refused(-108, "Parameter not allowed")
DATA_TYPE_ERROR = Refused(-104, "Data type error")
OUT_OF_RANGE = Refused(-222, "Data out of range")
ILLEGAL_VALUE = Refused(-224, "Illegal parameter value")


@dataclass(frozen=True)
class Unit:
    """One program message unit: its header nodes (uppercase, path resolved), whether it is
    a query, and its parameters as written (stripped)."""

    nodes: tuple[str, ...]
    query: bool
    params: tuple[str, ...]

    @property
    def common(self) -> bool:
        return bool(self.nodes) and self.nodes[0].startswith("*")

    @property
    def header(self) -> str:
        return ":".join(self.nodes) + ("?" if self.query else "")

    def arity(self, low: int, high: int | None = None) -> tuple[str, ...]:
        """The parameters, refused unless there are `low`..`high` of them."""
        high = low if high is None else high
        if len(self.params) < low:
            raise MISSING_PARAMETER
        if len(self.params) > high:
            raise PARAMETER_NOT_ALLOWED
        return self.params


def _split(text: str, sep: str) -> list[str]:
    """`text` split at `sep` outside quotes and parentheses (channel lists hold commas)."""
    parts, depth, quote, start = [], 0, "", 0
    for i, ch in enumerate(text):
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch == "(":
            depth += 1
        elif ch == ")":
            depth = max(0, depth - 1)
        elif ch == sep and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return parts


_HEADER = re.compile(r"(:?)(\*?[A-Za-z][A-Za-z0-9_]*(?::[A-Za-z][A-Za-z0-9_]*)*)(\?)?")


def units(message: str) -> Iterator[Unit]:
    """The units of one message, each header resolved against the path before it; a header
    that does not parse is `Refused` -102 when reached (the units before it are served)."""
    path: tuple[str, ...] = ()
    for raw in _split(message.strip(), ";"):
        text = raw.strip()
        if not text:
            continue
        head, rest = _split_header(text)
        m = _HEADER.fullmatch(head)
        if m is None:
            raise Refused(-102, "Syntax error")
        nodes = tuple(n.upper() for n in m.group(2).split(":"))
        params = tuple(p.strip() for p in _split(rest, ",")) if rest.strip() else ()
        if nodes[0].startswith("*"):
            yield Unit(nodes, bool(m.group(3)), params)
            continue
        full = nodes if m.group(1) else path + nodes
        path = full[:-1]
        yield Unit(full, bool(m.group(3)), params)


def _split_header(text: str) -> tuple[str, str]:
    """(header, parameters): the header ends at the first white space."""
    m = re.match(r"\S+", text)
    head = m.group(0) if m else ""
    return head, text[len(head):]


# ---------------------------------------------------------------- header patterns


@dataclass(frozen=True)
class _Node:
    short: str
    long: str
    optional: bool
    suffix: bool  # takes a numeric suffix (SOURce2, MEASure1)

    def match(self, token: str) -> int | None | bool:
        """False: no match; None: matched, no suffix given; an int: the suffix given."""
        m = re.fullmatch(r"([A-Z*]+?)(\d*)", token)
        if m is None:
            return False
        word, digits = m.groups()
        if digits and not self.suffix:
            word, digits = token, ""
        if word not in (self.short, self.long):
            return False
        return int(digits) if digits else None


@lru_cache(maxsize=512)
def _pattern(pattern: str) -> tuple[_Node, ...]:
    nodes = []
    for part in re.findall(r"\[:?[^\]]+\]|:?[^:\[]+", pattern):
        optional = part.startswith("[")
        word = part.strip("[]:")
        suffix = word.endswith("#")
        word = word.rstrip("#")
        short = "".join(ch for ch in word if ch.isupper() or ch == "*" or ch.isdigit())
        nodes.append(_Node(short, word.upper(), optional, suffix))
    return tuple(nodes)


def match(unit: Unit, pattern: str, *, query: bool | None = None) -> list[int | None] | None:
    """The numeric suffixes of `pattern`'s suffix nodes if `unit`'s header matches it (and its
    query form, when `query` is given), else None."""
    if query is not None and unit.query != query:
        return None
    return _match(unit.nodes, _pattern(pattern))


def _match(tokens: tuple[str, ...], nodes: tuple[_Node, ...]) -> list[int | None] | None:
    if not nodes:
        return [] if not tokens else None
    node, rest = nodes[0], nodes[1:]
    if tokens:
        got = node.match(tokens[0])
        if got is not False:
            tail = _match(tokens[1:], rest)
            if tail is not None:
                return ([got] if node.suffix else []) + tail
    if node.optional:
        tail = _match(tokens, rest)
        if tail is not None:
            return ([None] if node.suffix else []) + tail
    return None


# ---------------------------------------------------------------- parameters


_KEYWORDS = {"MIN": "MIN", "MINIMUM": "MIN", "MAX": "MAX", "MAXIMUM": "MAX",
             "DEF": "DEF", "DEFAULT": "DEF"}  # fmt: skip
_SUFFIXES = {"": 1.0, "V": 1.0, "MV": 1e-3, "A": 1.0, "MA": 1e-3, "W": 1.0}
_NRF = re.compile(r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([A-Za-z]*)")


def keyword(text: str) -> str | None:
    """MIN, MAX or DEF for their short or long forms (any case), else None."""
    return _KEYWORDS.get(text.strip().upper())


def number(text: str, low: float, high: float, default: float | None = None) -> float:
    """A decimal numeric parameter (NRf, an optional V/mV/A/mA suffix, MIN|MAX|DEF) within
    [low, high]; -104 for a non-number, -222 outside the range."""
    word = keyword(text)
    if word == "MIN":
        return low
    if word == "MAX":
        return high
    if word == "DEF":
        if default is None:
            raise DATA_TYPE_ERROR
        return default
    m = _NRF.fullmatch(text.strip())
    if m is None or m.group(2).upper() not in _SUFFIXES:
        raise DATA_TYPE_ERROR
    value = float(m.group(1)) * _SUFFIXES[m.group(2).upper()]
    if not low <= value <= high:
        raise OUT_OF_RANGE
    return value


def boolean(text: str) -> bool:
    """Boolean program data: ON/OFF or a number (non-zero is true, SCPI-1999 7.3)."""
    word = text.strip().upper()
    if word in ("ON", "OFF"):
        return word == "ON"
    m = _NRF.fullmatch(word)
    if m is None or m.group(2):
        raise DATA_TYPE_ERROR
    return round(float(m.group(1))) != 0


def integer(text: str, low: int, high: int) -> int:
    """An NR1-like register value (rounded, SCPI-1999 7.2) within [low, high]."""
    m = _NRF.fullmatch(text.strip())
    if m is None or m.group(2):
        raise DATA_TYPE_ERROR
    value = round(float(m.group(1)))
    if not low <= value <= high:
        raise OUT_OF_RANGE
    return value


def channel_list(text: str) -> list[int]:
    """`(@1)`, `(@1,3)`, `(@1:3)` -> [1], [1, 3], [1, 2, 3]; -104 if not a channel list."""
    m = re.fullmatch(r"\(\s*@([\d\s,:]+)\)", text.strip())
    if m is None:
        raise DATA_TYPE_ERROR
    out: list[int] = []
    for item in m.group(1).split(","):
        first, _, last = item.strip().partition(":")
        if not first.strip().isdigit() or (last and not last.strip().isdigit()):
            raise DATA_TYPE_ERROR
        start, end = int(first), int(last or first)
        out += list(range(start, end + 1)) if start <= end else list(range(start, end - 1, -1))
    return out
