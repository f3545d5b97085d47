"""`station procedure convert`: an old section-form procedure file in the step-list form."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import yaml

from common.yaml_input import ConfigError
from procedures.loading.config import is_section_form, load_procedure, load_yaml
from procedures.loading.legacy_procedure import convert, load_section_procedure
from station.errors import UserError

HEADER = (
    "# Converted from {source} by `station procedure convert`: the same steps, in the same\n"
    "# order, with the same settings, written as a list of steps (docs/procedures.md).\n"
)


class _Dumper(yaml.SafeDumper):
    """Mappings as blocks, lists of numbers or words on one line."""


def _list(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    flow = all(not isinstance(x, dict | list) for x in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _list)


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("procedure", help="procedure files: convert the old form")
    sub = parser.add_subparsers(dest="procedure_command", metavar="ACTION")
    conv = sub.add_parser(
        "convert",
        help="convert a procedure in the old section form to the list of steps",
        description="Read a procedure file in the old section form (power:, bias:, "
        "rate_table:, ... sections) and write the same procedure as a list of steps.",
    )
    conv.add_argument("old", type=Path, help="procedure file in the old section form")
    conv.add_argument("-o", "--out", type=Path, default=None,
                      help="where to write the new file (default: print it)")
    conv.set_defaults(handler=_convert)
    parser.set_defaults(handler=lambda args: (parser.print_help(), 2)[1])


def convert_text(old_path: Path) -> str:
    """The step-list form of an old-form file, as YAML text (checked by loading it back)."""
    loaded = load_yaml(old_path)
    if not is_section_form(loaded.data):
        raise UserError(f"{old_path}: already a list of steps; nothing to convert")
    try:
        old, _ = load_section_procedure(old_path)
    except ConfigError as exc:
        raise UserError(f"{old_path}: not a valid old-form procedure:\n{exc}") from None
    new = convert(old, loaded.data)
    return HEADER.format(source=old_path.name) + yaml.dump(
        new, Dumper=_Dumper, sort_keys=False, default_flow_style=False, width=100,
        allow_unicode=True,
    )


def _convert(args: argparse.Namespace) -> int:
    text = convert_text(args.old)
    if args.out is None:
        print(text, end="")
        return 0
    if args.out.resolve() == args.old.resolve():
        raise UserError("give a different -o file: the old file is kept as it is")
    args.out.write_text(text, encoding="utf-8")
    try:  # the written file must load (relative product paths from its own folder)
        load_procedure(args.out)
    except ConfigError as exc:
        raise UserError(f"{args.out}: the converted file does not load:\n{exc}") from None
    print(f"wrote {args.out}")
    return 0
