"""Shared helpers for the model tests: generator runs as Trajectories."""

from __future__ import annotations

from synth_gyro import Profile

from procedures.model.data import trajectory_from_columns
from procedures.model.trajectory import Segment, Trajectory

# Short records with two temperatures x two supplies, kept fast for the 50-seed test.
TINY = Profile(rates_dps=(20, 200), plateau_s=3.0, static_s=6.0, stabilise_s=20.0,
               rate_hz=25.0, stop_wait_s=3.0)
# The rate set cannot separate k2_quadratic from scale_asymmetry: one magnitude, both signs.
SPARSE = Profile(rates_dps=(100,), plateau_s=6.0, static_s=8.0, stabilise_s=40.0, rate_hz=50.0)


def as_trajectory(run: dict[str, object]) -> Trajectory:
    cols = {k: v for k, v in run.items() if k != "segments"}
    segs = [Segment(*s) for s in run["segments"]]  # type: ignore[union-attr]
    return trajectory_from_columns(cols, segments=segs)  # type: ignore[arg-type]
