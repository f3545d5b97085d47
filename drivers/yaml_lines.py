"""YAML files for driver configuration (e.g. servo register profiles), with file:line errors.

A small loader of the driver layer's own: drivers must not import `procedures`, so this keeps
what a driver needs (the line of every field, one line per validation problem) without the
procedure files' extras. The format matches `procedures.config`: `file:line: field a.b: msg`.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

M = TypeVar("M", bound=BaseModel)
Lines = dict[tuple[str | int, ...], int]


class DriverConfigError(ValueError):
    """A driver's configuration file is missing, not YAML, or holds a value not allowed."""


def _walk(node: yaml.Node, path: tuple[str | int, ...], lines: Lines, file: Path) -> None:
    lines[path] = node.start_mark.line + 1
    if isinstance(node, yaml.MappingNode):
        seen: set[str] = set()
        for key_node, value_node in node.value:
            key = key_node.value
            if key in seen:
                raise DriverConfigError(
                    f"{file}:{key_node.start_mark.line + 1}: field {key!r} appears twice; "
                    "keep only one"
                )
            seen.add(key)
            _walk(value_node, (*path, key), lines, file)
            lines[(*path, key)] = key_node.start_mark.line + 1
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _walk(item, (*path, i), lines, file)


def read_yaml(path: Path) -> tuple[Any, Lines]:
    """The file's data and the 1-based line of each field path."""
    try:
        text = Path(path).read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError as exc:
        raise DriverConfigError(f"{path}: file not found; give an existing YAML file") from exc
    except OSError as exc:
        raise DriverConfigError(f"{path}: cannot be read ({exc.strerror})") from exc
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = f":{mark.line + 1}" if mark is not None else ""
        raise DriverConfigError(f"{path}{line}: not valid YAML: {exc.problem or exc}") from exc
    except yaml.YAMLError as exc:
        raise DriverConfigError(f"{path}: not valid YAML: {exc}") from exc
    lines: Lines = {}
    if node is not None:
        _walk(node, (), lines, Path(path))
    return data, lines


def format_errors(exc: ValidationError, path: Path, lines: Lines) -> str:
    """One line per problem: `file:line: field a.b: message`."""
    out = []
    for err in exc.errors():
        loc = [p for p in err["loc"] if isinstance(p, int) or not re.match(r"^[a-z\-]+\[", p)]
        line = None
        for n in range(len(loc), -1, -1):
            line = lines.get(tuple(loc[:n]))
            if line is not None:
                break
        where = f"{path}:{line}" if line else str(path)
        field = ".".join(str(p) for p in loc) or "(top level)"
        msg = "unknown field" if err["type"] == "extra_forbidden" else err["msg"]
        out.append(f"{where}: field {field}: {msg}")
    return "\n".join(out)


def load_model(path: Path, model: type[M]) -> M:
    """`path` validated as `model`; DriverConfigError naming file, line and field."""
    data, lines = read_yaml(path)
    if not isinstance(data, dict):
        raise DriverConfigError(f"{path}:1: expected a mapping of fields at the top level")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise DriverConfigError(format_errors(exc, path, lines)) from None
