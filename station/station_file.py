"""Loading station.yaml: the settings model read (station.settings), then every instrument's
settings checked by its own driver's model (station.instruments), without connecting.

Above both modules it uses: the settings model is what the instruments read, so the loader
that checks the one with the other sits on top of them.
"""

from __future__ import annotations

from pathlib import Path

from common.yaml_input import ConfigError, load_yaml_model
from station.instruments import settings_problems
from station.settings import DEFAULT_STATION_FILE, LoadedSettings, StationSettings


def load_settings(path: Path | None = None) -> LoadedSettings:
    """Load station.yaml (default: config/station.yaml of this installation)."""
    model, loaded = load_yaml_model(Path(path or DEFAULT_STATION_FILE), StationSettings)
    settings = LoadedSettings(settings=model, source=loaded)
    # each instrument's settings belong to its driver: checked by the driver's own model
    problems = settings_problems(settings)
    if problems:
        raise ConfigError("\n".join(problems))
    return settings
