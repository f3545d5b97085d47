"""station.yaml's safe_state section sets how long the end-of-run safe-state pass keeps trying
an instrument it cannot make safe (docs/safety.md)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from common.yaml_input import ConfigError
from procedures.engine.safe_state import SafeStatePolicy
from station.station_file import load_settings
from station.uut import UutRunner

ROOT = Path(__file__).resolve().parents[2]
STATION = ROOT / "config" / "station.yaml"
PROCEDURE = ROOT / "config" / "procedures" / "eol-rate-table.yaml"


def _station(tmp_path: Path, safe_state: dict[str, object] | None) -> Path:
    """config/station.yaml with `safe_state` set, written in `tmp_path`."""
    data = yaml.safe_load(STATION.read_text(encoding="utf-8"))
    if safe_state is not None:
        data["safe_state"] = safe_state
    path = tmp_path / "station.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


@pytest.fixture
def station_file(tmp_path: Path, request: pytest.FixtureRequest) -> Path:
    return _station(tmp_path, request.param)


def _runner(station_file: Path, **kwargs: object) -> UutRunner:
    return UutRunner(
        load_settings(station_file),
        procedure_path=PROCEDURE,
        out=station_file.parent / "runs",
        certificate=False,
        **kwargs,  # type: ignore[arg-type]
    )


@pytest.mark.parametrize("station_file", [None], indirect=True)
def test_by_default_the_pass_retries_for_two_station_minutes(station_file: Path) -> None:
    runner = _runner(station_file)
    assert runner.safe_state_policy == SafeStatePolicy()
    assert (runner.safe_state_policy.deadline_s, runner.safe_state_policy.wall_floor_s) == (
        120.0,
        10.0,
    )


@pytest.mark.parametrize(
    "station_file", [{"retry_for_s": 600, "wall_floor_s": 30}], indirect=True
)
def test_the_station_file_sets_how_long_the_pass_retries(station_file: Path) -> None:
    runner = _runner(station_file)
    policy = runner.safe_state_policy
    assert (policy.deadline_s, policy.wall_floor_s) == (600.0, 30.0)
    assert policy.deadline_wall_s(speed=1.0) == 600.0  # a real bench: station s are wall s
    assert policy.deadline_wall_s(speed=100.0) == 30.0  # a fast simulated clock: the floor
    # a caller's own policy (a test rig that loses links on purpose) wins
    own = SafeStatePolicy(deadline_s=5.0)
    runner = _runner(station_file, safe_state_policy=own)
    assert runner.safe_state_policy is own


@pytest.mark.parametrize(
    "station_file", [{"retry_for_s": -1}, {"wall_floor_s": 0}, {"retry_after": 5}], indirect=True
)
def test_a_bad_safe_state_section_is_a_clear_error(station_file: Path) -> None:
    with pytest.raises(ConfigError) as info:
        load_settings(station_file)
    message = str(info.value)
    assert "safe_state" in message and station_file.name in message
