"""The message catalog: every string the operator screen shows, one JSON file per language.

`station/ui/messages/<lang>.json` maps a key to a text with `{name}` placeholders. English
(`en`) is complete by definition; every other language must hold the same keys (a test checks
it). The language is chosen once per page: station.yaml's `ui.language` when set, else the
first of the browser's languages the station has, else English.
"""

from __future__ import annotations

import functools
import json
import re
from pathlib import Path

MESSAGES_DIR = Path(__file__).parent / "messages"
DEFAULT_LANGUAGE = "en"
_LANG = re.compile(r"^[a-z]{2,3}$")


def available() -> list[str]:
    """The languages the station ships, e.g. ["de", "en"]."""
    return sorted(p.stem for p in MESSAGES_DIR.glob("*.json") if _LANG.match(p.stem))


@functools.cache
def load(language: str) -> dict[str, str]:
    """The catalog of `language` (a shipped one); ValueError when it is not shipped."""
    if language not in available():
        raise ValueError(
            f"no message catalog for language {language!r}; shipped: {', '.join(available())}"
        )
    data = json.loads((MESSAGES_DIR / f"{language}.json").read_text(encoding="utf-8"))
    if not isinstance(data, dict) or not all(
        isinstance(k, str) and isinstance(v, str) for k, v in data.items()
    ):
        raise ValueError(f"{language}.json must be one object of key -> text")
    return data


def choose(configured: str | None, requested: list[str]) -> str:
    """The page's language: the station's own setting, else the browser's first shipped one."""
    shipped = available()
    if configured:
        return configured if configured in shipped else DEFAULT_LANGUAGE
    for tag in requested:
        base = tag.strip().lower().split("-")[0].split(";")[0]
        if base in shipped:
            return base
    return DEFAULT_LANGUAGE


def accept_language(header: str) -> list[str]:
    """Languages of an Accept-Language header, best first ("de-DE,de;q=0.9,en;q=0.8")."""
    ranked: list[tuple[float, int, str]] = []
    for i, part in enumerate(header.split(",")[:20]):
        tag, _, rest = part.strip().partition(";")
        quality = 1.0
        if rest.strip().startswith("q="):
            try:
                quality = float(rest.strip()[2:])
            except ValueError:
                quality = 0.0
        if tag:
            ranked.append((-quality, i, tag))
    return [tag for _, _, tag in sorted(ranked)]
