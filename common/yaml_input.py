"""Bounded YAML input: the one reader of every YAML file the product loads.

A YAML file is hostile input until it has been read: a few hundred bytes of nested aliases
(billion laughs) expand to 10^9 nodes, deep nesting overflows the parser's recursion, and
bytes that are not UTF-8 or hold control characters break whatever later writes them. The
reader here refuses all of that before anything else sees the data:

- the file is at most `MAX_BYTES`, strict UTF-8, with no control character except tab and
  line breaks (also none escaped inside a quoted string, e.g. "\\0");
- nesting is at most `MAX_DEPTH` levels, and aliases may expand to at most `MAX_NODES`
  nodes in all, counted while composing (a recursive alias is refused);
- every failure is `ConfigError` (a ValueError) of one line: `file:line: what is wrong;
  what to do`.

The pure-Python composer is used on purpose (it can be made to count); the files are small.
`LoadedYaml.lines` maps each field path to its line, for `format_validation_error`.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from common.regular_file import NotARegularFile, open_regular

# the largest configuration file is a few kB; the pure-Python scanner takes about 10 us a
# character, so this also bounds the time to read any file to well under a second
MAX_BYTES = 64 * 1024
MAX_DEPTH = 32  # nesting levels of mappings and sequences
MAX_NODES = 2_000  # nodes after alias expansion, in all (a procedure has about 150)
MAX_ALIASES = 100  # alias references
# control characters other than tab and line feeds, and the Unicode line separators (a NEL or
# U+2028 in a name would break a one-line message or a record's line)
_CONTROL = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\u2028\u2029]")
_KEY_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029]")
# what YAML itself refuses in a stream: C0/C1 controls, surrogates, U+FFFE and U+FFFF
_UNPRINTABLE = yaml.reader.Reader.NON_PRINTABLE


class ConfigError(ValueError):
    """A configuration file is missing, not YAML, or holds a value that is not allowed."""


@dataclass(frozen=True)
class LoadedYaml:
    path: Path
    data: Any
    lines: dict[tuple[str | int, ...], int]  # field path -> 1-based line of its value
    sha256: str


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _char_name(ch: str) -> str:
    names = {"\x00": "NUL", "\x1b": "ESC", "\x7f": "DEL", "\x85": "NEL"}
    return f"U+{ord(ch):04X}" + (f" ({names[ch]})" if ch in names else "")


class _BoundedLoader(yaml.SafeLoader):
    """SafeLoader that counts nesting depth and alias expansion while composing, and
    remembers the node being constructed (for the line of a constructor failure)."""

    def __init__(self, stream: str, file: Path) -> None:
        super().__init__(stream)
        self._file = file
        self._depth = 0
        self._nodes = 0
        self._aliases = 0
        self._sizes: dict[str, int] = {}  # anchor -> expanded node count of its node
        self.current_node: yaml.Node | None = None

    def _refuse(self, mark: Any, what: str) -> ConfigError:
        line = f":{mark.line + 1}" if mark is not None else ""
        return ConfigError(f"{self._file}{line}: {what}")

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            size = self._sizes.get(event.anchor)
            if size is None and event.anchor in self.anchors:
                raise self._refuse(
                    event.start_mark,
                    f"alias *{event.anchor} refers to the node that contains it; "
                    "recursive aliases are not allowed",
                )
            self._aliases += 1
            self._nodes += size or 0
            if self._aliases > MAX_ALIASES or self._nodes > MAX_NODES:
                raise self._refuse(
                    event.start_mark,
                    f"aliases expand to more than {MAX_NODES} nodes ({self._aliases} alias "
                    "references); write the values out instead of nesting aliases",
                )
            return super().compose_node(parent, index)
        self._depth += 1
        if self._depth > MAX_DEPTH:
            raise self._refuse(
                self.peek_event().start_mark,
                f"nested more than {MAX_DEPTH} levels deep; flatten the structure",
            )
        anchor = getattr(self.peek_event(), "anchor", None)
        start = self._nodes
        node = super().compose_node(parent, index)
        self._nodes += 1
        if self._nodes > MAX_NODES:
            raise self._refuse(node.start_mark, f"more than {MAX_NODES} values in the file")
        if anchor is not None:
            self._sizes[anchor] = self._nodes - start
        self._depth -= 1
        return node

    def construct_object(self, node: yaml.Node, deep: bool = False) -> Any:
        self.current_node = node
        return super().construct_object(node, deep=deep)


def _decode(raw: bytes, path: Path) -> str:
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ConfigError(
            f"{path}:{line}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset "
            f"{exc.start}); save the file as UTF-8"
        ) from None
    bad = _CONTROL.search(text) or _UNPRINTABLE.search(text)
    if bad is not None:
        line = text.count("\n", 0, bad.start()) + 1
        raise ConfigError(
            f"{path}:{line}: control character {_char_name(bad.group())} is not allowed; "
            "remove it (only tab and line breaks may appear)"
        )
    return text


# quoted strings and comments (skipped) or a flow bracket (counted)
_FLOW_TOKEN = re.compile(r"'[^']*'|\"(?:[^\"\\]|\\.)*\"|(?:^|(?<=\s))#[^\n]*|[\[\]{},]", re.M)


def _check_flow_depth(text: str, path: Path) -> None:
    """Refuse deep flow nesting (`[[[[...`) before the parser sees it: PyYAML's scanner reads
    a whole run of open brackets ahead (a simple key may be pending at each), seconds for a
    few hundred kB. The count is approximate (brackets inside plain scalars count), so the
    bound is four times the composer's exact one."""
    depth = items = 0
    for m in _FLOW_TOKEN.finditer(text):
        ch = m.group()
        if ch == "," and depth:
            items += 1
            if items > MAX_NODES:
                line = text.count("\n", 0, m.start()) + 1
                raise ConfigError(f"{path}:{line}: more than {MAX_NODES} values in the file")
        elif ch in "[{":
            depth += 1
            if depth > 4 * MAX_DEPTH:
                line = text.count("\n", 0, m.start()) + 1
                raise ConfigError(
                    f"{path}:{line}: nested more than {MAX_DEPTH} levels deep; flatten the "
                    "structure"
                )
        elif ch in "]}":
            depth = max(depth - 1, 0)


def _read_bytes(path: Path, max_bytes: int) -> bytes:
    try:
        size = path.stat().st_size
        if size > max_bytes:
            raise ConfigError(
                f"{path}: {size} bytes is too large for a configuration file (at most "
                f"{max_bytes}); check that this is the right file"
            )
        with open_regular(path) as fh:
            raw = fh.read(max_bytes + 1)
    except NotARegularFile as exc:
        if path.is_dir():
            raise ConfigError(f"{path}: is a folder; give the path of a YAML file") from None
        raise ConfigError(f"{exc}; give the path of a YAML file") from None
    except FileNotFoundError:
        raise ConfigError(
            f"{path}: file not found; give the path of an existing YAML file"
        ) from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a folder; give the path of a YAML file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if len(raw) > max_bytes:  # grew since stat, or a device
        raise ConfigError(f"{path}: larger than {max_bytes} bytes; check that this is the file")
    return raw


def _parse(text: str, path: Path) -> tuple[yaml.Node | None, Any]:
    try:
        loader = _BoundedLoader(text, path)
    except yaml.YAMLError as exc:  # _decode refuses what the reader would; kept as a guard
        raise ConfigError(f"{path}: not valid YAML: {_one_line(str(exc))}") from None
    try:
        node = loader.get_single_node()
        data = loader.construct_document(node) if node is not None else None
        return node, data
    except ConfigError:
        raise
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = f":{mark.line + 1}" if mark is not None else ""
        what = _one_line(exc.problem or exc.context or str(exc))
        raise ConfigError(f"{path}{line}: not valid YAML: {what}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {_one_line(str(exc))}") from None
    except (ValueError, TypeError, OverflowError, RecursionError) as exc:
        # a scalar the constructor cannot build: a 5000-digit integer, 2026-13-45, ...
        node = loader.current_node
        line = f":{node.start_mark.line + 1}" if node is not None else ""
        raise ConfigError(
            f"{path}{line}: value cannot be read ({_one_line(str(exc))[:200]}); fix or quote it"
        ) from None
    finally:
        loader.dispose()


def _walk(node: yaml.Node, path: tuple[str | int, ...], lines: dict, file: Path) -> None:
    lines[path] = node.start_mark.line + 1
    if isinstance(node, yaml.MappingNode):
        seen: dict[str, int] = {}
        for key_node, value_node in node.value:
            key = key_node.value
            if not isinstance(key, str):
                key = str(key_node.start_mark.line + 1)  # a complex key: pydantic refuses it
            if key in seen:
                raise ConfigError(
                    f"{file}:{key_node.start_mark.line + 1}: field {key!r} appears twice "
                    f"(first on line {seen[key]}); keep only one"
                )
            seen[key] = key_node.start_mark.line + 1
            lines[(*path, key)] = key_node.start_mark.line + 1
            _walk(value_node, (*path, key), lines, file)
            lines[(*path, key)] = key_node.start_mark.line + 1
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _walk(item, (*path, i), lines, file)


def _check_strings(
    data: Any, lines: dict, path: Path, loc: tuple[str | int, ...] = (), key: bool = False
) -> None:
    """No control character in any key or string value (a quoted "\\0" gets this far), and
    no line break or tab in a key."""
    items: Any = ()
    if isinstance(data, dict):
        items = data.items()
    elif isinstance(data, list):
        items = enumerate(data)
    elif isinstance(data, str) and (bad := (_KEY_CONTROL if key else _CONTROL).search(data)):
        line = lines.get(loc)
        where = f"{path}:{line}" if line else str(path)
        field = ".".join(str(p) for p in loc) or "(top level)"
        raise ConfigError(
            f"{where}: field {field}: control character {_char_name(bad.group())} is not "
            "allowed in text; remove it"
        )
    for name, value in items:
        _check_strings(name, lines, path, loc, key=isinstance(data, dict))
        _check_strings(value, lines, path, (*loc, name if isinstance(name, str | int) else "?"))


def read_yaml(path: Path, max_bytes: int = MAX_BYTES) -> LoadedYaml:
    """Read a YAML file within the bounds above, remembering the line of every field."""
    path = Path(path)
    raw = _read_bytes(path, max_bytes)
    text = _decode(raw, path)
    _check_flow_depth(text, path)
    node, data = _parse(text, path)
    lines: dict[tuple[str | int, ...], int] = {}
    if node is not None:
        _walk(node, (), lines, path)
    _check_strings(data, lines, path)
    return LoadedYaml(path=path, data=data, lines=lines, sha256=hashlib.sha256(raw).hexdigest())


# ---------------------------------------------------------------- validation errors


def _field_help(model: type[BaseModel], loc: Sequence[str | int]) -> tuple[str, list[str]]:
    """The description of the field at `loc` and the fields allowed at its level."""
    current: Any = model
    allowed: list[str] = sorted(model.model_fields)
    description = ""
    for part in loc:
        if not (isinstance(current, type) and issubclass(current, BaseModel)):
            break
        allowed = sorted(current.model_fields)
        if not isinstance(part, str) or part not in current.model_fields:
            break
        info = current.model_fields[part]
        description = info.description or ""
        current = _inner_model(info.annotation)
    return description, allowed


def _inner_model(annotation: Any) -> Any:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()) or ():
        found = _inner_model(arg)
        if found is not None:
            return found
    return None


_UNION_TAGS = frozenset(
    {"float", "int", "str", "bool", "constrained-float", "constrained-int", "constrained-str"}
)


def format_validation_error(
    exc: ValidationError, loaded: LoadedYaml, model: type[BaseModel]
) -> str:
    """One line per field in error: `file:line: field a.b: message (what is allowed)`.

    Several errors on one field (the members of a union) are joined with '; or '."""
    by_field: dict[tuple[str, str], list[str]] = {}
    help_of: dict[tuple[str, str], str] = {}
    for err in exc.errors():
        # pydantic adds union member tags (e.g. 'float', 'literal[...]') to loc: drop them
        loc = [p for p in err["loc"] if isinstance(p, int) or not re.match(r"^[a-z\-]+\[", str(p))]
        loc = [p for p in loc if p not in _UNION_TAGS] or loc
        line = None
        for n in range(len(loc), -1, -1):
            line = loaded.lines.get(tuple(loc[:n]))
            if line is not None:
                break
        where = f"{loaded.path}:{line}" if line else str(loaded.path)
        field = ".".join(str(p) if str(p).isprintable() else repr(p) for p in loc)
        field = field or "(top level)"
        description, allowed = _field_help(model, loc)
        msg = _one_line(err["msg"])
        if err["type"] == "extra_forbidden":
            msg = f"unknown field; allowed here: {', '.join(allowed)}"
        elif err["type"] == "missing":
            msg = "required field is missing"
        key = (where, field)
        if msg not in by_field.setdefault(key, []):
            by_field[key].append(msg)
        if description:
            help_of[key] = description
    out = []
    for (where, field), msgs in by_field.items():
        hint = help_of.get((where, field))
        text = "; or ".join(msgs) + (f" ({hint})" if hint else "")
        out.append(f"{where}: field {field}: {text}")
    return "\n".join(out)


M = TypeVar("M", bound=BaseModel)


def load_yaml_model(path: Path, model: type[M]) -> tuple[M, LoadedYaml]:
    """Load and validate `path` as `model`; ConfigError with file:line:field on any problem."""
    loaded = read_yaml(path)
    if not isinstance(loaded.data, dict):
        raise ConfigError(
            f"{loaded.path}:1: expected a mapping of fields at the top level "
            f"(allowed: {', '.join(sorted(model.model_fields))})"
        )
    try:
        return model.model_validate(loaded.data), loaded
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, loaded, model)) from None
