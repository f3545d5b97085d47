"""The screen's time left is wall time: the bench's speed on a scaled clock, the pace
measured so far in lockstep (where station time runs as fast as the station computes)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from station.ui import runner_adapter
from station.ui.runner_adapter import WallPace


def test_a_scaled_clock_divides_by_its_speed() -> None:
    pace = WallPace(SimpleNamespace(speed=25.0, lockstep=False))
    assert pace.wall_s(2500.0, 0.0) == 100.0
    assert WallPace(None).wall_s(60.0, 0.0) == 60.0  # real instruments


def test_lockstep_uses_the_pace_measured_so_far(monkeypatch: pytest.MonkeyPatch) -> None:
    now = [100.0]
    monkeypatch.setattr(runner_adapter.time, "monotonic", lambda: now[0])
    pace = WallPace(SimpleNamespace(speed=100.0, lockstep=True))  # its speed means nothing
    assert pace.wall_s(3000.0, 0.0) is None  # nothing measured yet
    now[0] += 1.0
    assert pace.wall_s(2900.0, 100.0) is None  # too soon to tell
    now[0] += 4.0
    # 500 station s in 5 wall s: 100 station s per wall s, 2500 s left -> 25 wall s
    assert pace.wall_s(2500.0, 500.0) == pytest.approx(25.0)
