"""Averaging blocks: the record cut into windows whose mean residuals the workflow compares.

Each segment (and each stretch between segments, a `transition`) is split into blocks of at
most `max_block_s` seconds and at most `max_travel_deg` of table travel, so that a block's
mean keeps the signatures of rate, angle and time. Block means are what the fit, the gap and
the significance tests use: averaging removes most of the sample-to-sample noise and keeps
the number of rows small.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from procedures.model.trajectory import FloatArray, Trajectory

MIN_BLOCK_SAMPLES = 3


@dataclass(frozen=True)
class Blocks:
    """Contiguous sample ranges [start, stop) and their block means of the trajectory."""

    start: NDArray[np.int64]
    stop: NDArray[np.int64]
    kind: tuple[str, ...]
    duration_s: FloatArray
    center_s: FloatArray
    rate_dps: FloatArray
    angle_deg: FloatArray
    temp_c: FloatArray
    supply_v: FloatArray
    time_since_power_on_s: FloatArray

    @property
    def count(self) -> int:
        return int(self.start.shape[0])

    @property
    def has_motion_changes(self) -> bool:
        """True if any block holds a change of rate (transitions, stop moves)."""
        return any(k in ("transition", "stop_move") for k in self.kind)

    def mean(self, values: FloatArray) -> FloatArray:
        """Block means of a per-sample array (n,) or (n, k)."""
        return block_mean(values, self.start, self.stop)


def block_mean(values: FloatArray, start: NDArray[np.int64], stop: NDArray[np.int64]) -> FloatArray:
    x = np.asarray(values, dtype=float)
    padded = np.concatenate([x, np.zeros((1, *x.shape[1:]))], axis=0)
    edges = np.empty(2 * start.size, dtype=np.int64)
    edges[0::2] = start
    edges[1::2] = stop
    sums = np.add.reduceat(padded, edges, axis=0)[0::2]
    counts = (stop - start).astype(float)
    if x.ndim > 1:
        counts = counts[:, None]
    return sums / counts


def _sample_labels(traj: Trajectory) -> NDArray[np.int64]:
    labels = np.full(traj.n, -1, dtype=np.int64)
    for i, seg in enumerate(traj.segments):
        a = int(np.searchsorted(traj.time_s, seg.start_s, side="left"))
        b = int(np.searchsorted(traj.time_s, seg.end_s, side="left"))
        free = labels[a:b] == -1
        labels[a:b][free] = i
    return labels


def _runs(labels: NDArray[np.int64], time_s: FloatArray) -> list[tuple[int, int, int]]:
    dt = np.diff(time_s)
    step = float(np.median(dt))
    change = np.flatnonzero((np.diff(labels) != 0) | (dt > 3.0 * step)) + 1
    edges = [0, *change.tolist(), labels.size]
    return [(a, b, int(labels[a])) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def make_blocks(
    traj: Trajectory, max_block_s: float = 10.0, max_travel_deg: float = 180.0
) -> Blocks:
    labels = _sample_labels(traj)
    step = float(np.median(np.diff(traj.time_s)))
    starts: list[int] = []
    stops: list[int] = []
    kinds: list[str] = []
    angle_travel = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(traj.ref_angle_deg)))])
    for a, b, label in _runs(labels, traj.time_s):
        kind = traj.segments[label].kind if label >= 0 else "transition"
        i = a
        while i < b:
            t_end = traj.time_s[i] + max_block_s
            j_time = int(np.searchsorted(traj.time_s, t_end - 0.5 * step, side="left"))
            j_travel = int(
                np.searchsorted(angle_travel, angle_travel[i] + max_travel_deg, side="left")
            )
            j = max(min(j_time, j_travel, b), i + 1)
            if b - j < MIN_BLOCK_SAMPLES:  # do not leave a sliver at the end
                j = b
            if j - i >= MIN_BLOCK_SAMPLES:
                starts.append(i)
                stops.append(j)
                kinds.append(kind)
            i = j
    if not starts:
        raise ValueError("the record has no window long enough to average; check the data")
    start = np.asarray(starts, dtype=np.int64)
    stop = np.asarray(stops, dtype=np.int64)
    t0 = traj.time_s[start]
    t1 = traj.time_s[stop - 1] + step
    ang = np.deg2rad(traj.ref_angle_deg)
    cos_m = block_mean(np.cos(ang), start, stop)
    sin_m = block_mean(np.sin(ang), start, stop)
    return Blocks(
        start=start,
        stop=stop,
        kind=tuple(kinds),
        duration_s=t1 - t0,
        center_s=0.5 * (t0 + t1),
        rate_dps=block_mean(traj.ref_rate_dps, start, stop),
        angle_deg=np.rad2deg(np.arctan2(sin_m, cos_m)) % 360.0,
        temp_c=block_mean(traj.temp_c, start, stop),
        supply_v=block_mean(traj.supply_v, start, stop),
        time_since_power_on_s=block_mean(traj.time_since_power_on_s, start, stop),
    )
