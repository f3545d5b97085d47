"""The progress's time left when a step revises its own length (procedures/runtime/
run_context.py Progress.revise): the ramp learns its length from its heating half."""

from __future__ import annotations

from procedures.runtime.progress import ProgressBus, ProgressEvent
from procedures.runtime.run_context import Progress


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def now_s(self) -> float:
        return self.t


def _progress(clock: _Clock) -> tuple[Progress, list[ProgressEvent]]:
    bus, events = ProgressBus(), list[ProgressEvent]()
    bus.subscribe(events.append)
    progress = Progress(bus, clock, [])  # type: ignore[arg-type]
    progress.total_estimate_s = 1000.0 + 100.0  # the step and a 100 s one after it
    return progress, events


def test_a_revised_step_moves_the_time_left_and_the_bar_never_goes_back() -> None:
    clock = _Clock()
    progress, events = _progress(clock)
    progress.begin("ramp_calibration", "", 1000.0)
    clock.t = 900.0
    assert progress.fraction() == (900.0 / 1100.0, 200.0)
    progress.set_phase("cooling")
    progress.revise(600.0)  # the step now says it has 600 s to go
    fraction, left = progress.fraction()
    assert left == 700.0  # its 600 s and the step after it
    assert fraction == 900.0 / 1100.0  # not 900 / 1600: the bar does not go back
    clock.t = 1400.0
    assert progress.fraction() == (1400.0 / 1600.0, 200.0)  # then it moves on
    progress.revise(0.0)  # ends sooner than it thought
    assert progress.fraction()[1] == 100.0
    assert [e.phase for e in events if e.kind == "step"] == ["", "cooling"]
