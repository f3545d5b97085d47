"""The twin learns the part: a gyro model as a simulated part, and the simulation gap.

`part_entry` turns a model (the starting model fitted to the run, or the extended one) into
a config/sim `parts` entry: the bias, scale and first-order coefficients as the part's own
keys, every other catalog effect and every library term under `effects` by its id, with the
model's parameters (the bench carries library terms as generic terms, drivers/sim/
generic_terms.py). The twin is quiet (its white noise 1 % of the measured one, no bias
wander), so a comparison with it shows the model's error, not the twin's noise.

`compare` is the comparison measurement-vs-simulation: the analysed windows of the measured
run (static, plateau, stop_static), cut into pieces of at most `MAX_PIECE_S` from each
window's start as the workflow cuts its blocks, are matched to the twin run's pieces of the
same condition, kind, order and piece number; the **simulation gap** is the
duration-weighted RMS over the matched pieces of (measured mean - simulated mean), in deg/s,
`sqrt(sum T_w d_w^2 / sum T_w)`; its noise floor is the same RMS of what the measured noise
model alone leaves in a piece mean about the record mean (NoiseModel.floor_per_block_dps
with the pieces as blocks). Without the cut, a thermal stabilisation window of several
hundred seconds weighed as much as all the other windows together, so the gap rested on a
handful of window means (about 5 effective windows of 52) and a model that is right could
land at twice the floor by chance. Pure functions: no I/O.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from procedures.model.blocks import Blocks, block_mean
from procedures.model.gyro_model import GyroModel
from procedures.model.noise import NoiseModel
from procedures.model.trajectory import FloatArray, Trajectory

# model effect -> the sim part's own first-order key (drivers/sim/config.py PartSpec)
FIRST_ORDER_KEYS = {
    "bias_temperature": "bias_temp_coeff_dps_per_c",
    "scale_temperature": "scale_temp_coeff_per_c",
    "bias_supply": "bias_supply_coeff_dps_per_v",
    "scale_supply": "scale_supply_coeff_per_v",
}
TWIN_NOISE_FRACTION = 0.01  # the twin's white noise, relative to the measured part's
COMPARED_KINDS = ("static", "plateau", "stop_static", "ramp_plateau")
MAX_RATE_MISMATCH_DPS = 1.0  # matched windows must be at the same table rate
MAX_ANGLE_MISMATCH_DEG = 5.0  # and, at rest, the same table angle
# and a ramp's plateau at the same die temperature. In lockstep a part run alone and its
# twin (alone, in its socket) ramp on the same timeline, plateau for plateau, the dies equal
# on the default bench. They part when the ramp turns elsewhere: a run of several parts
# turns when the last die has covered the span (so the twin runs among the measured cycle's
# other parts, station/discrepancy_simulate.py); a twin whose die is 0.11 C off (a bench
# whose socket air is not the twin's) can turn a plateau later. The same plateau (order,
# rate) is then 0.4-0.6 C away on eol-ramp (a plateau's time at the die's rate), a sweep of
# the rate set ~5 C: not compared beyond this. With
# 1 C, a turn a plateau apart kept its shifted pieces, compared at another die rate (2.06 x
# the floor on a part whose lag the twin carried). Matching by the nearest die temperature
# instead was tried: near the turn the die barely moves, so a 0.1 C offset picked plateaus
# tens of seconds away at another die rate (2.26 against 1.64 x the floor, a part alone)
MAX_RAMP_TEMP_MISMATCH_C = 0.3
# the twin's bench: the model's effects only. The part's honest thermal physics (element
# lag, gradient bias, hysteresis: drivers/sim/thermal_physics.py) is off, or the twin would
# carry them twice (once as the model's terms, once as the bench's hidden draws); the die's
# own heat path stays the bench's: chamber -> die lag, self-heating and the air at the
# socket (drawn per socket from the bench's seed, so a twin in the measured part's socket of
# the default bench has the measured die's air: with it left out, `mode: ideal`, the twin's
# die ran 0.11 C warmer, and on eol-ramp a part's turn at the top came a plateau apart)
TWIN_SIM_CONFIG: dict[str, Any] = {"part_physics": {"thermal": {
    "element_tau_s": 0.0, "element_tau_sigma_s": 0.0,
    "gradient_dps_per_c_per_min": 0.0, "gradient_sigma_dps_per_c_per_min": 0.0,
    "hysteresis_dps": 0.0, "hysteresis_sigma_dps": 0.0,
}}}
MIN_WINDOW_SAMPLES = 3
MAX_PIECE_S = 10.0  # windows are compared in pieces of at most this (the workflow's blocks)

# (condition, kind, ordinal within condition and kind, piece within the window)
WindowKey = tuple[str, str, int, int]


def part_entry(
    model: GyroModel,
    serial: str,
    *,
    socket: int = 1,
    measured_arw_deg_per_sqrt_h: float = 0.0,
    supply_current_a: float | None = None,
) -> dict[str, Any]:
    """A config/sim `parts` entry that behaves as `model` says (plain YAML-able values)."""
    entry: dict[str, Any] = {
        "socket": socket,
        "serial": serial,
        "bias_dps": float(model.bias_dps),
        "scale": float(model.scale),
        **{key: 0.0 for key in FIRST_ORDER_KEYS.values()},
        "arw_deg_per_sqrt_h": TWIN_NOISE_FRACTION * max(measured_arw_deg_per_sqrt_h, 0.0),
        "bias_instability_deg_per_h": 0.0,
        "rrw_deg_per_h_per_sqrt_h": 0.0,
    }
    if supply_current_a is not None and 0 < supply_current_a <= 0.5:
        entry["supply_current_a"] = float(supply_current_a)
    effects: dict[str, dict[str, float]] = {}
    for effect_id, params in model.effects.items():
        if effect_id in FIRST_ORDER_KEYS:
            entry[FIRST_ORDER_KEYS[effect_id]] = float(next(iter(params.values())))
        else:
            effects[effect_id] = {p: float(v) for p, v in params.items()}
    entry["effects"] = effects
    return entry


def twin_bench(air_c: dict[int, float] | None = None) -> dict[str, Any]:
    """The twin's bench (sim config keys besides the parts): the part's thermal physics off;
    `air_c` gives fixture positions' air (socket -> C) instead of the bench's draw."""
    thermal = dict(TWIN_SIM_CONFIG["part_physics"]["thermal"])
    if air_c:
        thermal["socket_air_c"] = {int(k): float(v) for k, v in air_c.items()}
    return {"part_physics": {"thermal": thermal}}


def twin_config(entry: dict[str, Any], air_c: dict[int, float] | None = None) -> dict[str, Any]:
    """The twin's sim config: its part on the twin's bench (`twin_bench`)."""
    return {**twin_bench(air_c), "parts": [entry]}


DIE_OFFSET_PIECES = 5  # the first pieces of a run, before any ramp turns: the dies' offset


def die_offset_c(measured: Trajectory, twin: Trajectory) -> float:
    """The measured die minus the twin run's over the first pieces both runs hold (same key),
    median, C: what the socket's air (or a real part's mount) puts between them; nan if none."""
    meas, sim = windows_of(measured), windows_of(twin)
    index = {k: j for j, k in enumerate(sim.keys)}
    diffs = [meas.temp_c[i] - sim.temp_c[index[k]] for i, k in enumerate(meas.keys)
             if k in index][:DIE_OFFSET_PIECES]
    return float(np.median(diffs)) if diffs else math.nan


@dataclass(frozen=True)
class Windows:
    """The analysed windows of one record: sample ranges, by key, in time order."""

    keys: tuple[WindowKey, ...]
    start: np.ndarray
    stop: np.ndarray
    mean_dps: FloatArray
    rate_dps: FloatArray
    angle_deg: FloatArray
    duration_s: FloatArray
    center_s: FloatArray
    temp_c: FloatArray


def _pieces(a: int, b: int, per_piece: int) -> list[tuple[int, int]]:
    """[a, b) cut into pieces of `per_piece` samples from its start; a last piece shorter
    than half that joins the one before."""
    edges = list(range(a, b, per_piece)) + [b]
    if len(edges) > 2 and edges[-1] - edges[-2] < per_piece / 2:
        del edges[-2]
    return list(zip(edges[:-1], edges[1:], strict=True))


def windows_of(traj: Trajectory) -> Windows:
    """Every analysed window of a compared kind with enough samples, cut into pieces of at
    most MAX_PIECE_S, keyed by (condition, kind, ordinal, piece) so the same piece of the
    same window of another run of the same procedure can be found."""
    seen: dict[tuple[str, str], int] = defaultdict(int)
    keys: list[WindowKey] = []
    starts: list[int] = []
    stops: list[int] = []
    step = float(np.median(np.diff(traj.time_s)))
    per_piece = max(int(round(MAX_PIECE_S / step)), MIN_WINDOW_SAMPLES)
    for seg in traj.segments:
        if seg.kind not in COMPARED_KINDS:
            continue
        ordinal = seen[(seg.condition, seg.kind)]
        seen[(seg.condition, seg.kind)] += 1
        a = int(np.searchsorted(traj.time_s, seg.start_s, side="left"))
        b = int(np.searchsorted(traj.time_s, seg.end_s, side="left"))
        if b - a < MIN_WINDOW_SAMPLES:
            continue
        for piece, (pa, pb) in enumerate(_pieces(a, b, per_piece)):
            keys.append((seg.condition, seg.kind, ordinal, piece))
            starts.append(pa)
            stops.append(pb)
    start = np.asarray(starts, dtype=np.int64)
    stop = np.asarray(stops, dtype=np.int64)
    if not keys:
        empty = np.zeros(0)
        return Windows((), start, stop, empty, empty, empty, empty, empty, empty)
    t0 = traj.time_s[start]
    t1 = traj.time_s[stop - 1] + step
    ang = np.deg2rad(traj.ref_angle_deg)
    angle = np.rad2deg(np.arctan2(block_mean(np.sin(ang), start, stop),
                                  block_mean(np.cos(ang), start, stop))) % 360.0
    return Windows(
        keys=tuple(keys),
        start=start,
        stop=stop,
        mean_dps=block_mean(traj.gyro_dps, start, stop),
        rate_dps=block_mean(traj.ref_rate_dps, start, stop),
        angle_deg=angle,
        duration_s=t1 - t0,
        center_s=0.5 * (t0 + t1),
        temp_c=block_mean(traj.temp_c, start, stop),
    )


@dataclass(frozen=True)
class TwinComparison:
    """Measured window means against one twin's (the windows both runs have)."""

    keys: tuple[WindowKey, ...]
    residual_dps: FloatArray  # measured - simulated window mean
    gap_dps: float


@dataclass(frozen=True)
class SimulationComparison:
    """The comparison measurement-vs-simulation with the starting and the extended model."""

    keys: tuple[WindowKey, ...]  # windows compared with both twins (measured order)
    center_s: FloatArray  # measured window centres (station time of the measured run)
    duration_s: FloatArray
    rate_dps: FloatArray
    residual_before_dps: FloatArray  # measured - starting-model twin, per window
    residual_after_dps: FloatArray  # measured - extended-model twin
    gap_before_dps: float
    gap_after_dps: float
    noise_floor_dps: float  # over the same windows, from the measured noise model
    windows_measured: int
    temp_c: FloatArray  # the measured pieces' die temperature
    twin_temp_c: FloatArray  # the extended-model twin's matched pieces'
    notes: tuple[str, ...] = field(default_factory=tuple)

    def to_json(self) -> dict[str, Any]:
        return {
            "simulation_gap_before_dps": self.gap_before_dps,
            "simulation_gap_after_dps": self.gap_after_dps,
            "simulation_noise_floor_dps": self.noise_floor_dps,
            "simulation_windows_compared": len(self.keys),
            "simulation_windows_measured": self.windows_measured,
            "simulation_notes": list(self.notes),
            "simulation_windows": [
                {
                    "condition": k[0],
                    "kind": k[1],
                    "ordinal": k[2],
                    "piece": k[3],
                    "duration_s": float(d),
                    "residual_before_dps": float(rb),
                    "residual_after_dps": float(ra),
                    "die_temp_c": float(tm),
                    "twin_die_temp_c": float(tt),
                }
                for k, d, rb, ra, tm, tt in zip(
                    self.keys, self.duration_s, self.residual_before_dps,
                    self.residual_after_dps, self.temp_c, self.twin_temp_c, strict=True
                )
            ],
        }


def _matches(meas: Windows, i: int, twin: Windows, j: int) -> bool:
    if abs(meas.rate_dps[i] - twin.rate_dps[j]) > MAX_RATE_MISMATCH_DPS:
        return False
    if (meas.keys[i][1] == "ramp_plateau"
            and abs(meas.temp_c[i] - twin.temp_c[j]) > MAX_RAMP_TEMP_MISMATCH_C):
        return False  # the twin's ramp ran this plateau at another point of the ramp
    if abs(meas.rate_dps[i]) > MAX_RATE_MISMATCH_DPS:
        return True  # a plateau turns the table: its mean angle says nothing
    diff = (meas.angle_deg[i] - twin.angle_deg[j] + 180.0) % 360.0 - 180.0
    return abs(diff) <= MAX_ANGLE_MISMATCH_DEG


def residuals_against(meas: Windows, twin: Windows) -> dict[WindowKey, tuple[float, float]]:
    """(measured - simulated mean, the twin piece's die temperature) of every window both
    runs hold (same key, same rate and angle; a ramp plateau: and die temperature)."""
    index = {k: j for j, k in enumerate(twin.keys)}
    out: dict[WindowKey, tuple[float, float]] = {}
    for i, key in enumerate(meas.keys):
        j = index.get(key)
        if j is not None and _matches(meas, i, twin, j):
            out[key] = (float(meas.mean_dps[i] - twin.mean_dps[j]), float(twin.temp_c[j]))
    return out


def weighted_rms(values: FloatArray, duration_s: FloatArray) -> float:
    if values.size == 0:
        return math.nan
    return float(np.sqrt(np.sum(duration_s * values**2) / np.sum(duration_s)))


def window_floor_dps(noise: NoiseModel, center_s: FloatArray, duration_s: FloatArray) -> float:
    """What the measured noise alone leaves in these windows' means about the record mean,
    as a duration-weighted RMS (the noise floor of the simulation gap)."""
    n = center_s.size
    if n == 0:
        return math.nan
    idx = np.arange(n, dtype=np.int64)
    zeros = np.zeros(n)
    blocks = Blocks(start=idx, stop=idx + 1, kind=("window",) * n, duration_s=duration_s,
                    center_s=center_s, rate_dps=zeros, angle_deg=zeros, temp_c=zeros,
                    supply_v=zeros, time_since_power_on_s=zeros)
    sigma = noise.floor_per_block_dps(blocks)
    return weighted_rms(sigma, duration_s)


def compare(
    measured: Trajectory, before: Trajectory, after: Trajectory, noise: NoiseModel
) -> SimulationComparison:
    """The simulation gap with the starting-model twin (`before`) and the extended-model
    twin (`after`) over the windows the measured run and both twin runs hold."""
    meas = windows_of(measured)
    r_before = residuals_against(meas, windows_of(before))
    r_after = residuals_against(meas, windows_of(after))
    chosen = [i for i, k in enumerate(meas.keys) if k in r_before and k in r_after]
    if not chosen:
        raise ValueError(
            "the twin runs hold none of the measured run's windows (static, plateau, "
            "stop_static, ramp_plateau); was the same procedure simulated?"
        )
    idx = np.asarray(chosen, dtype=np.int64)
    keys = tuple(meas.keys[i] for i in chosen)
    duration = meas.duration_s[idx]
    center = meas.center_s[idx]
    rb = np.array([r_before[k][0] for k in keys])
    ra = np.array([r_after[k][0] for k in keys])
    notes = []
    if len(keys) < len(meas.keys):
        notes.append(
            f"{len(meas.keys) - len(keys)} of {len(meas.keys)} measured window pieces have no "
            "matching piece in both twin runs (a retry, a step the twin ran differently, a "
            "window the twin held for a shorter time, or a ramp plateau the twin ran at "
            "another die temperature) and are not compared"
        )
    return SimulationComparison(
        keys=keys,
        center_s=center,
        duration_s=duration,
        rate_dps=meas.rate_dps[idx],
        residual_before_dps=rb,
        residual_after_dps=ra,
        gap_before_dps=weighted_rms(rb, duration),
        gap_after_dps=weighted_rms(ra, duration),
        noise_floor_dps=window_floor_dps(noise, center, duration),
        windows_measured=len(meas.keys),
        temp_c=meas.temp_c[idx],
        twin_temp_c=np.array([r_after[k][1] for k in keys]),
        notes=tuple(notes),
    )
