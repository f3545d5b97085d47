"""`station run`, `station demo` and `station schema`."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from procedures.config import ProcedureConfig, ProductConfig
from station.errors import UserError
from station.settings import StationSettings

SCHEMAS = {
    "procedure": ProcedureConfig,
    "product": ProductConfig,
    "station": StationSettings,
}


def _schema(args: argparse.Namespace) -> int:
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create {out}: {exc.strerror}; choose another --out") from exc
    for name, model in SCHEMAS.items():
        path = out / f"{name}.schema.json"
        schema = model.model_json_schema()
        schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
        schema.setdefault("title", f"gyrocal {name} file")
        path.write_text(json.dumps(schema, indent=2) + "\n", encoding="utf-8")
        print(path)
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser(
        "schema", help="write JSON Schemas of the station, product and procedure files"
    )
    p.add_argument("--out", default="schemas", help="folder for the *.schema.json files")
    p.set_defaults(handler=_schema)
