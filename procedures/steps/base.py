"""What every step shares: the part's samples in a window, and the window checks."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers.fixture_protocol import SEQ_MODULO
from drivers.protocols import SampleStatus
from procedures.runtime.record import Verdict
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun

DELIVERY_WAIT_WALL_S = 3.0


def sample_rate_hz(ctx: RunContext) -> float:
    return float(ctx.procedure.output_rate_hz)


def samples_between(
    ctx: RunContext, part: PartRun, t0_station_s: float, t1_station_s: float
) -> dict[str, NDArray[Any]]:
    """The part's samples between two station times (mapped to its fixture clock)."""
    stream = part.stream
    assert stream is not None
    f0 = stream.fixture_time(t0_station_s)
    f1 = stream.fixture_time(t1_station_s)
    # samples reach the station a little after they are taken: wait (wall time, bounded)
    # until the stream has delivered the whole window before cutting it
    stream.wait_delivered(f1, DELIVERY_WAIT_WALL_S)
    return stream.window(f0, f1)


def frames_lost_in(data: dict[str, NDArray[Any]]) -> int:
    """Frames missing inside a window: the gaps in its (wrapping) sequence numbers."""
    seq = np.asarray(data["seq"], dtype=np.int64)
    if seq.size < 2:
        return 0
    steps = np.diff(seq) % SEQ_MODULO
    return int(np.sum(np.maximum(steps - 1, 0)))


def check_window(
    ctx: RunContext, part: PartRun, data: dict[str, NDArray[Any]], what: str, expected_s: float
) -> bool:
    """Refuse a window with too few samples, more lost frames than the per-window limit
    (`stream.max_lost_frames_per_window`, or the lost fraction if that allows more), or
    over-range samples; drops the part if so."""
    fs = sample_rate_hz(ctx)
    n = int(data["time_s"].size)
    expected = expected_s * fs
    if expected > 0 and n < 0.5 * expected:
        # a shorted part browns out: say so, for every part on the supply
        ctx.instruments.supply_reading()
        ctx.parts.drop(
            part,
            Verdict.ERROR,
            f"{what}: only {n} samples where about {expected:.0f} were expected: the part "
            "stopped streaming or the stream is losing data; check the part's seating "
            "and the fixture cable",
        )
        return False
    lost = frames_lost_in(data)
    allowed = max(
        ctx.procedure.stream.max_lost_frames_per_window,
        int(ctx.procedure.stream.max_lost_fraction * (n + lost)),
    )
    if lost > allowed:
        ctx.parts.drop(
            part,
            Verdict.ERROR,
            f"{what}: stream damaged: {lost} frames lost in this window of {n + lost} (at most "
            f"{allowed} allowed per window): the window cannot be trusted; check the fixture "
            "cable and its grounding",
        )
        return False
    over = int(
        np.count_nonzero(data["status"] & (SampleStatus.OVER_RANGE | SampleStatus.SATURATED))
    )
    if over:
        ctx.parts.drop(
            part,
            Verdict.FAIL,
            f"{what}: {over} samples over range or saturated; the part must never "
            "over-range during a measurement (reduce the rate set or check the part)",
        )
        return False
    return True
