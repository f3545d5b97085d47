"""The step types' reference in Markdown, generated from the registry (docs/procedures.md).

`reference_markdown()` is what docs/procedures.md holds between its two GENERATED markers;
`python -m procedures.steps.reference docs/procedures.md` rewrites that block, and a test
checks it is up to date.
"""

from __future__ import annotations

import sys
import types
from pathlib import Path
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

from procedures.steps.registry import StepPolicy, StepType, step_types

BEGIN = "<!-- GENERATED: step types (python -m procedures.steps.reference docs/procedures.md) -->"
END = "<!-- END GENERATED -->"


def _type_text(annotation: Any) -> str:
    """A field's type in words: "number", "list of number", "`a` / `b`", "... or none"."""
    origin, args = get_origin(annotation), get_args(annotation)
    if origin is Annotated:
        return _type_text(args[0])
    if origin in (Union, types.UnionType):
        words = [_type_text(a) for a in args if a is not type(None)]
        return " or ".join(words) + (" or none" if type(None) in args else "")
    if origin is Literal:
        return " / ".join(f"`{v}`" for v in args)
    if origin in (list, tuple):
        return f"list of {_type_text(args[0])}" if args else "list"
    if origin is dict:
        return "mapping"
    names = {float: "number", int: "whole number", str: "text", bool: "true / false"}
    return names.get(annotation, getattr(annotation, "__name__", str(annotation)))


def _default(field: Any) -> str:
    if field.default_factory is not None:
        return f"`{field.default_factory()}`"
    if field.default is PydanticUndefined:
        return "required"
    return f"`{field.default}`"


def _settings_rows(model: type[BaseModel]) -> list[str]:
    rows = []
    for name, field in model.model_fields.items():
        desc = (field.description or "").replace("|", "\\|")
        rows.append(f"| `{name}` | {_type_text(field.annotation)} | {_default(field)} | {desc} |")
    return rows


def _step_section(name: str, cls: type[StepType[Any]]) -> list[str]:
    doc = (cls.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
    out = [f"### `{name}`", "", doc, ""]
    notes = []
    if cls.uses_table:
        notes.append("needs a rate table")
    if cls.provides:
        notes.append("provides " + ", ".join(sorted(cls.provides)))
    if notes:
        out += ["*" + "; ".join(notes) + ".*", ""]
    fields = _settings_rows(cls.Settings)
    if fields:
        out += ["| setting | type | default | meaning |", "|---|---|---|---|", *fields, ""]
    else:
        out += ["No settings.", ""]
    try:
        settings = cls.Settings.model_validate(
            {k: [50.0, -50.0] for k, f in cls.Settings.model_fields.items() if f.is_required()}
        )
        declared = cls.measurements(settings)
    except Exception:  # a Settings with other required fields: declared without it
        declared = []
    if declared:
        out += ["| measurement | units | product limit | notes |", "|---|---|---|---|"]
        for d in declared:
            notes_d = [n for n, on in (("informational", d.informational),
                                       ("per condition", d.per_condition),
                                       ("only when the data allow it", d.optional)) if on]
            limit = "none" if d.informational else f"`{d.limit_key}`"
            out.append(f"| `{d.name}` | {d.units} | {limit} | {', '.join(notes_d)} |")
        out.append("")
    return out


def reference_markdown() -> str:
    """Every registered step type: its settings and its declared measurements."""
    out = [BEGIN, "", "Every entry may also give (the step's policy):", "",
           "| key | type | default | meaning |", "|---|---|---|---|",
           *_settings_rows(StepPolicy),
           "| `informational` | list of names | `[]` | these declared measurements need no "
           "product limit |", ""]
    for name, cls in step_types().items():
        out += _step_section(name, cls)
    out.append(END)
    return "\n".join(out) + "\n"


def rewrite(doc: Path) -> None:
    text = doc.read_text(encoding="utf-8")
    head, _, rest = text.partition(BEGIN)
    _, _, tail = rest.partition(END + "\n")
    doc.write_text(head + reference_markdown() + tail, encoding="utf-8")


if __name__ == "__main__":
    rewrite(Path(sys.argv[1]))
