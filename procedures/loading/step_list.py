"""A procedure's `steps:` list: parsed and checked at load, expanded into step instances.

    steps:
      - step: power_identify             # an entry: a step type and its settings
      - for_each: condition              # the temperature x supply plan, in its planned order
        steps: [{step: thermal}, {step: bias, dwell_s: 30}]
      - repeat: 3                        # N times
        steps: [{step: stop_method}]

Every problem is reported with the file and line of the entry (`where`), all at once.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from typing import Any, Literal

from pydantic import ValidationError

from common.bounded import MAX_LIST, MAX_REPEATS
from common.yaml_input import ConfigError, LoadedYaml, format_validation_error
from procedures.runtime.conditions import Condition
from procedures.steps.registry import (
    COMMON_KEYS,
    Declared,
    Place,
    StepPolicy,
    StepType,
    UnknownStepType,
    step_type,
    step_types,
)

Path_ = tuple[str | int, ...]
MAX_DEPTH = 4  # loops inside loops


@dataclass(frozen=True)
class StepEntry:
    """One `step:` entry: its type, validated settings and policy, and where it is."""

    type: type[StepType[Any]]
    settings: Any
    policy: StepPolicy
    path: Path_
    informational: frozenset[str] = frozenset()

    @property
    def type_name(self) -> str:
        return self.type.type_name

    def declared(self) -> list[Declared]:
        return [replace(d, informational=True) if d.name in self.informational else d
                for d in self.type.measurements(self.settings)]


@dataclass(frozen=True)
class Loop:
    """`for_each: condition` or `repeat: N` with its nested steps."""

    kind: Literal["for_each", "repeat"]
    count: int  # repeat: N; 0 for for_each
    body: tuple[Node, ...]
    path: Path_


Node = StepEntry | Loop


def _dotted(path: Path_) -> str:
    return ".".join(str(p) for p in path)


class _Parser:
    def __init__(self, loaded: LoadedYaml | None) -> None:
        self.loaded = loaded
        self.problems: list[str] = []

    def where(self, path: Path_) -> str:
        if self.loaded is None:
            return "procedure"
        for n in range(len(path), 0, -1):
            line = self.loaded.lines.get(path[:n])
            if line is not None:
                return f"{self.loaded.path}:{line}"
        return str(self.loaded.path)

    def problem(self, path: Path_, text: str) -> None:
        self.problems.append(f"{self.where(path)}: {_dotted(path)}: {text}")

    def nodes(self, raw: Any, path: Path_, depth: int, in_for_each: bool) -> tuple[Node, ...]:
        if not isinstance(raw, list) or not raw:
            self.problem(path, "expected a non-empty list of steps (each '- step: <type>', "
                         "'- for_each: condition' or '- repeat: N')")
            return ()
        if len(raw) > MAX_LIST:
            self.problem(path, f"{len(raw)} entries, more than the {MAX_LIST} allowed")
            return ()
        out: list[Node] = []
        for i, entry in enumerate(raw):
            node = self.node(entry, (*path, i), depth, in_for_each)
            if node is not None:
                out.append(node)
        return tuple(out)

    def node(self, entry: Any, path: Path_, depth: int, in_for_each: bool) -> Node | None:
        if not isinstance(entry, dict):
            self.problem(path, "each entry is a mapping: '- step: <type>' with its settings, "
                         "'- for_each: condition' or '- repeat: N' with nested 'steps:'")
            return None
        kinds = [k for k in ("step", "for_each", "repeat") if k in entry]
        if len(kinds) != 1:
            self.problem(path, "give exactly one of step, for_each, repeat "
                         f"(found: {', '.join(kinds) or 'none'})")
            return None
        if kinds[0] == "step":
            return self.step(entry, path)
        return self.loop(entry, kinds[0], path, depth, in_for_each)

    def loop(self, entry: dict[str, Any], kind: str, path: Path_, depth: int,
             in_for_each: bool) -> Loop | None:
        extra = sorted(set(entry) - {kind, "steps"})
        if extra:
            self.problem((*path, extra[0]), f"unknown field {extra[0]!r} in a {kind} loop; "
                         "allowed: " + f"{kind}, steps")
        if depth >= MAX_DEPTH:
            self.problem(path, f"loops nested more than {MAX_DEPTH} deep")
            return None
        value = entry[kind]
        count = 0
        if kind == "for_each":
            if value != "condition":
                self.problem((*path, kind), f"for_each: {value!r}: only 'condition' is known "
                             "(the temperature x supply plan of conditions:)")
                return None
            if in_for_each:
                self.problem((*path, kind), "for_each: condition inside another for_each: "
                             "condition; a condition loop cannot be nested")
                return None
        else:
            if isinstance(value, bool) or not isinstance(value, int) or not (
                1 <= value <= MAX_REPEATS
            ):
                self.problem((*path, kind), f"repeat: {value!r}: give a whole number "
                             f"1..{MAX_REPEATS}")
                return None
            count = value
        if "steps" not in entry:
            self.problem(path, f"{kind} loop without 'steps:' (the steps it repeats)")
            return None
        body = self.nodes(entry["steps"], (*path, "steps"), depth + 1,
                          in_for_each or kind == "for_each")
        return Loop("for_each" if kind == "for_each" else "repeat", count, body, path)

    def step(self, entry: dict[str, Any], path: Path_) -> StepEntry | None:
        name = entry["step"]
        try:
            cls = step_type(str(name))
        except UnknownStepType as exc:
            self.problem((*path, "step"), str(exc))
            return None
        policy_raw = {k: v for k, v in entry.items() if k in StepPolicy.model_fields}
        settings_raw = {k: v for k, v in entry.items() if k not in COMMON_KEYS}
        ok = True
        try:
            policy = StepPolicy.model_validate(policy_raw)
        except ValidationError as exc:
            self.validation(exc, StepPolicy, path, name)
            ok = False
        try:
            settings = cls.Settings.model_validate(settings_raw)
        except ValidationError as exc:
            self.validation(exc, cls.Settings, path, name)
            ok = False
        if not ok:
            return None
        informational = self.informational(entry.get("informational", []), cls, settings, path)
        return StepEntry(cls, settings, policy, path, informational)

    def informational(self, raw: Any, cls: type[StepType[Any]], settings: Any,
                      path: Path_) -> frozenset[str]:
        """`informational: [names]`: each must be a measurement the step declares."""
        names = raw if isinstance(raw, list) else [raw]
        known = [d.name for d in cls.measurements(settings)]
        out = set()
        for i, name in enumerate(names):
            if name in known:
                out.add(str(name))
            else:
                self.problem((*path, "informational", i),
                             f"step {cls.type_name} has no measurement {name!r}; it declares: "
                             f"{', '.join(known) or 'none'}")
        return frozenset(out)

    def validation(self, exc: ValidationError, model: Any, path: Path_, name: str) -> None:
        """pydantic's errors on one entry, with the entry's file:line for each field."""
        if self.loaded is None:
            self.problems.append(f"{_dotted(path)} (step {name}): {exc}")
            return
        n = len(path)
        view = LoadedYaml(
            path=self.loaded.path,
            data=None,
            lines={k[n:]: v for k, v in self.loaded.lines.items() if k[:n] == path},
            sha256=self.loaded.sha256,
        )
        text = format_validation_error(exc, view, model)
        prefix = _dotted(path)
        for line in text.splitlines():
            where, _, rest = line.partition(": field ")
            field, _, message = rest.partition(": ")
            self.problems.append(f"{where}: field {prefix}.{field} (step {name}): {message}")


def parse_steps(raw: Any, loaded: LoadedYaml | None = None) -> tuple[Node, ...]:
    """The `steps:` list as nodes; ConfigError with one line per problem (file:line)."""
    parser = _Parser(loaded)
    nodes = parser.nodes(raw, ("steps",), 0, False)
    if not parser.problems:
        _order_problems(nodes, parser)
    if parser.problems:
        raise ConfigError("\n".join(parser.problems))
    return nodes


def _order_problems(nodes: tuple[Node, ...], parser: _Parser) -> None:
    """Each entry's `requires` must be provided by an entry before it (in file order)."""
    provided: dict[str, str] = {}
    for entry in entries(nodes):
        missing = sorted(entry.type.requires(entry.settings) - set(provided))
        if missing:
            givers = sorted(n for n, cls in step_types().items() if set(missing) & cls.provides)
            parser.problem(entry.path, f"step {entry.type_name} needs {', '.join(missing)} "
                           f"from an earlier step ({', '.join(givers) or 'none registered'}); "
                           "add one before it or change this step's settings")
        for item in entry.type.provides:
            provided.setdefault(item, entry.type_name)


def entries(nodes: tuple[Node, ...]) -> Iterator[StepEntry]:
    """Every step entry, loops walked in file order (each once)."""
    for node in nodes:
        if isinstance(node, StepEntry):
            yield node
        else:
            yield from entries(node.body)


def expand(nodes: tuple[Node, ...], conditions: list[Condition],
           base: Place | None = None) -> list[StepType[Any]]:
    """The step instances the engine runs, loops unrolled, each with its place."""
    base = base or Place()
    out: list[StepType[Any]] = []
    for node in nodes:
        if isinstance(node, StepEntry):
            place = Place(base.condition, base.condition_index, base.previous, base.repeat,
                          _dotted(node.path))
            step = node.type(node.settings, place, node.policy)
            if step.runs_here():
                out.append(step)
        elif node.kind == "for_each":
            for i, cond in enumerate(conditions):
                inner = Place(cond, i, conditions[i - 1] if i else None, base.repeat)
                body = expand(node.body, conditions, inner)
                out.extend(body + [s for step in body for s in step.after_condition(body)])
        else:
            for r in range(node.count):
                inner = Place(base.condition, base.condition_index, base.previous, r)
                out.extend(expand(node.body, conditions, inner))
    return out


# the engine sets these on every part, whatever the steps
ENGINE_MEASUREMENTS = (
    Declared("frames_lost_fraction", "1", "lost frames / expected frames over the run"),
)


def declared_in(nodes: tuple[Node, ...]) -> Iterator[tuple[Declared, StepEntry | None]]:
    """Every declared measurement with the entry that declares it (None: the engine)."""
    for d in ENGINE_MEASUREMENTS:
        yield d, None
    for entry in entries(nodes):
        for d in entry.declared():
            yield d, entry


def measurement_problems(
    nodes: tuple[Node, ...], limit_names: set[str], where: Callable[[Path_], str], product: str
) -> tuple[list[str], list[str]]:
    """(problems, warnings): a declared, judged measurement with no product limit is a problem;
    a product limit no step declares is a warning."""
    problems: list[str] = []
    declared_keys: set[str] = set()
    for d, entry in declared_in(nodes):
        declared_keys.add(d.limit_key)
        if d.informational or d.limit_key in limit_names:
            continue
        at = where(entry.path) if entry else "procedure"
        who = f"step {entry.type_name} ({_dotted(entry.path)})" if entry else "the engine"
        problems.append(
            f"{at}: {who} measures {d.name!r} but the product file ({product}) has no limit "
            f"{d.limit_key!r}: add limits.{d.limit_key} to the product file (or correct the "
            "name)"
        )
    warnings = [
        f"product limit {name!r} ({product}) is never measured by this procedure"
        for name in sorted(limit_names - declared_keys)
    ]
    return problems, warnings


def known_step_types() -> list[str]:
    return list(step_types())


def procedure_json_schema(base: dict[str, Any]) -> dict[str, Any]:
    """The procedure file's JSON Schema (`base`: ProcedureConfig's) with `steps:` spelt out:
    each item one registered step type with its settings, or a loop with nested steps."""
    defs = base.setdefault("$defs", {})
    policy = StepPolicy.model_json_schema()["properties"]
    choices: list[dict[str, Any]] = []
    for name, cls in step_types().items():
        schema = cls.Settings.model_json_schema(ref_template="#/$defs/{model}")
        defs.update(schema.pop("$defs", {}))
        props = {"step": {"const": name}, **schema.get("properties", {}), **policy,
                 "informational": {"type": "array", "items": {"type": "string"}}}
        defs[f"Step_{name}"] = {
            "type": "object",
            "title": f"step {name}",
            "description": (cls.__doc__ or "").strip().split("\n\n")[0],
            "properties": props,
            "required": ["step", *schema.get("required", [])],
            "additionalProperties": False,
        }
        choices.append({"$ref": f"#/$defs/Step_{name}"})
    loop_steps = {"$ref": "#/$defs/StepList"}
    choices.append({"type": "object", "title": "for_each loop", "additionalProperties": False,
                    "properties": {"for_each": {"const": "condition"}, "steps": loop_steps},
                    "required": ["for_each", "steps"]})
    choices.append({"type": "object", "title": "repeat loop", "additionalProperties": False,
                    "properties": {"repeat": {"type": "integer", "minimum": 1,
                                              "maximum": MAX_REPEATS},
                                   "steps": loop_steps},
                    "required": ["repeat", "steps"]})
    defs["StepList"] = {"type": "array", "minItems": 1, "maxItems": MAX_LIST,
                        "items": {"oneOf": choices}}
    description = base["properties"]["steps"].get("description", "")
    base["properties"]["steps"] = {"$ref": "#/$defs/StepList", "description": description}
    return base
