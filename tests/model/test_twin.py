"""The twin: a model as a simulated part entry, and the simulation gap (window matching,
duration-weighted RMS, noise floor over the windows). Fast, no bench."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from drivers.sim.config import parse_sim_config
from drivers.sim.thermal_physics import draw_thermal, socket_air_offset_c
from procedures.model.gyro_model import GyroModel, first_order_model, zero_params
from procedures.model.noise import NoiseModel
from procedures.model.trajectory import Segment, Trajectory
from procedures.model.twin import (
    MAX_RAMP_TEMP_MISMATCH_C,
    compare,
    die_offset_c,
    part_entry,
    twin_config,
    window_floor_dps,
    windows_of,
)

RATE_HZ = 20.0


def test_part_entry_carries_every_term_the_bench_reads() -> None:
    effects = {e: dict(zero_params(e)) for e in first_order_model().effects}
    effects["bias_temperature"] = {"bias_temp_coeff_dps_per_c": 0.007}
    effects["scale_supply"] = {"scale_supply_coeff_per_v": -1e-3}
    effects["k2_quadratic"] = {"k2_per_dps": 2e-6}
    effects["lib_dTdt"] = {"coeff": 0.9}
    effects["lib_angleh2"] = {"amplitude_dps": 0.02, "phase_deg": 30.0}
    effects["lib_dTdir"] = {"coeff": 0.005}  # hysteresis (temperature_direction)
    model = GyroModel(name="x", bias_dps=1.25, scale=1.03, effects=effects)
    entry = part_entry(model, "SIM-7", measured_arw_deg_per_sqrt_h=0.3, supply_current_a=0.02)
    part = parse_sim_config({"parts": [entry]}).parts[0]  # the bench accepts it as it is
    assert (part.bias_dps, part.scale) == (1.25, 1.03)
    assert part.bias_temp_coeff_dps_per_c == 0.007
    assert part.scale_supply_coeff_per_v == -1e-3
    assert part.scale_temp_coeff_per_c == 0.0 and part.bias_supply_coeff_dps_per_v == 0.0
    assert part.effects == {
        "k2_quadratic": {"k2_per_dps": 2e-6},
        "lib_dTdt": {"coeff": 0.9},
        "lib_angleh2": {"amplitude_dps": 0.02, "phase_deg": 30.0},
        "lib_dTdir": {"coeff": 0.005},
    }
    assert part.arw_deg_per_sqrt_h == pytest.approx(0.003)  # quiet: 1 % of the measured
    assert part.bias_instability_deg_per_h == 0.0 and part.rrw_deg_per_h_per_sqrt_h == 0.0
    assert part.supply_current_a == 0.02


def test_a_twin_runs_without_the_bench_s_thermal_physics_and_carries_the_found_terms(
) -> None:
    """The found thermal term is the twin's generic term; the bench's hidden element lag,
    gradient bias and hysteresis are off (else the twin carried them twice)."""
    effects = {e: dict(zero_params(e)) for e in first_order_model().effects}
    effects["lib_w_dTdt"] = {"coeff": -2.5e-4}
    model = GyroModel(name="extended", bias_dps=0.4, scale=1.01, effects=effects)
    config = parse_sim_config(twin_config(part_entry(model, "SIM-2931", socket=3)))
    assert draw_thermal("SIM-2931", config.part_physics.thermal).ideal
    assert config.parts[0].effects == {"lib_w_dTdt": {"coeff": -2.5e-4}}
    assert config.parts[0].socket == 3
    # the die's own heat path stays the bench's: die lag, self-heating, the socket's air
    default = parse_sim_config({}).part_physics
    assert config.part_physics.die_tau_s == default.die_tau_s
    assert socket_air_offset_c(0, 3, config.part_physics.thermal) == socket_air_offset_c(
        0, 3, default.thermal) != 0.0


def test_a_base_model_twin_has_no_first_order_terms_of_its_own() -> None:
    """Left out, the bench would draw them from the population: they are set to zero."""
    entry = part_entry(GyroModel(name="base", bias_dps=0.5, scale=1.0), "SIM-8")
    part = parse_sim_config({"parts": [entry]}).parts[0]
    assert part.bias_temp_coeff_dps_per_c == 0.0 and part.scale_temp_coeff_per_c == 0.0
    assert part.effects == {}


# windows: (condition, kind, seconds, rate, angle)
PLAN = [
    ("T25", "static", 10.0, 0.0, 0.0),
    ("T25", "static", 10.0, 0.0, 90.0),
    ("T25", "static", 10.0, 0.0, 180.0),
    ("T25", "plateau", 5.0, 50.0, 0.0),
    ("T25", "plateau", 5.0, -50.0, 0.0),
    ("T35", "static", 10.0, 0.0, 270.0),
    ("T35", "stop_static", 4.0, 0.0, 90.0),
]


def _traj(signal: np.ndarray | None = None, plan: list | None = None, gap_s: float = 3.0,
          temp_c_per_s: float = 0.0, temp_offset_c: float = 0.0) -> Trajectory:
    t_parts, rate, angle, segs = [], [], [], []
    t0 = 0.0
    for cond, kind, dur, w, ang in plan or PLAN:
        n = int(dur * RATE_HZ)
        t = t0 + np.arange(n) / RATE_HZ
        t_parts.append(t)
        rate.append(np.full(n, w))
        a = ang + w * (t - t0)
        angle.append(a % 360.0)
        segs.append(Segment(kind, float(t[0]), float(t[-1]) + 1e-9, cond))
        t0 = float(t[-1]) + gap_s
    time_s = np.concatenate(t_parts)
    n = time_s.size
    return Trajectory(
        time_s=time_s,
        gyro_dps=np.zeros(n) if signal is None else signal,
        ref_rate_dps=np.concatenate(rate),
        ref_angle_deg=np.concatenate(angle),
        temp_c=25.0 + temp_offset_c + temp_c_per_s * time_s,
        supply_v=np.full(n, 5.0),
        time_since_power_on_s=time_s + 100.0,
        segments=tuple(segs),
    )


def _white(n_dps_rt_s: float) -> NoiseModel:
    return NoiseModel(white_dps_rt_s=n_dps_rt_s, floor_dps=0.0, tau_s=np.zeros(0),
                      adev_dps=np.zeros(0))


def test_simulation_gap_is_the_weighted_rms_of_window_mean_differences() -> None:
    base = _traj()
    pattern = 0.05 * np.cos(np.radians(2 * base.ref_angle_deg))
    rng = np.random.default_rng(1)
    noise = rng.normal(0.0, 0.01, base.n)
    measured = dataclasses.replace(base, gyro_dps=1.0 + base.ref_rate_dps + pattern + noise)
    after = dataclasses.replace(base, gyro_dps=1.0 + base.ref_rate_dps + pattern)
    before = dataclasses.replace(base, gyro_dps=1.0 + base.ref_rate_dps)
    cmp = compare(measured, before, after, _white(0.01 / math.sqrt(RATE_HZ)))
    assert len(cmp.keys) == len(PLAN) == cmp.windows_measured
    w = windows_of(measured)
    wb = windows_of(before)
    d = w.mean_dps - wb.mean_dps
    expected = math.sqrt(float(np.sum(w.duration_s * d**2) / np.sum(w.duration_s)))
    assert cmp.gap_before_dps == pytest.approx(expected, rel=1e-12)
    # the extended twin leaves only the measured noise: near the floor; the starting one
    # misses the twice-per-turn pattern (0.05 deg/s at rest, averaged out on the plateaus)
    assert cmp.gap_after_dps < 1.5 * cmp.noise_floor_dps
    assert cmp.gap_before_dps > 10 * cmp.noise_floor_dps


def test_windows_the_twin_does_not_hold_or_holds_elsewhere_are_not_compared() -> None:
    measured = _traj()
    short_plan = [p for p in PLAN if p[1] != "stop_static"]  # the twin ran no stop method
    moved = [(*p[:4], 45.0) if k == 1 else p for k, p in enumerate(short_plan)]  # other angle
    twin = _traj(plan=moved, gap_s=7.0)  # its own timing: windows still match by key
    cmp = compare(measured, twin, twin, _white(0.001))
    keys = set(cmp.keys)
    assert ("T35", "stop_static", 0, 0) not in keys
    assert ("T25", "static", 1, 0) not in keys  # at 45 deg in the twin, 90 deg measured
    assert len(keys) == len(PLAN) - 2
    assert "2 of 7 measured window pieces" in cmp.notes[0]


def test_long_windows_are_compared_in_pieces_matched_from_their_start() -> None:
    """A 93 s stabilisation window counts as nine pieces of ~10 s (the last 3 s join the
    ninth), not as one mean that outweighs every other window; a twin that held the window
    for 41 s matches only its first four pieces."""
    plan = [("T25", "static", 93.0, 0.0, 0.0), ("T25", "plateau", 5.0, 50.0, 0.0)]
    measured = _traj(plan=plan)
    w = windows_of(measured)
    assert [k[3] for k in w.keys if k[1] == "static"] == list(range(9))
    assert w.duration_s[8] == pytest.approx(13.0, abs=0.1)
    assert np.all(w.duration_s[:8] == pytest.approx(10.0, abs=0.1))
    twin = _traj(plan=[("T25", "static", 41.0, 0.0, 0.0), plan[1]])
    cmp = compare(measured, twin, twin, _white(0.001))
    assert [k for k in cmp.keys if k[1] == "static"] == [("T25", "static", 0, i)
                                                         for i in range(4)]
    assert ("T25", "plateau", 0, 0) in cmp.keys
    assert "5 of 10 measured window pieces" in cmp.notes[0]


def test_no_common_window_is_an_error_that_says_why() -> None:
    measured = _traj()
    other = _traj(plan=[("X", "plateau", 5.0, 20.0, 0.0)])
    with pytest.raises(ValueError, match="same procedure"):
        compare(measured, other, other, _white(0.001))


def test_window_floor_of_white_noise_matches_its_formula() -> None:
    n_white = 0.02
    t = np.array([10.0, 5.0, 20.0])
    centre = np.array([5.0, 30.0, 60.0])
    w = t / t.sum()
    var = n_white**2 / t * (1 - 2 * w) + np.sum(w**2 * n_white**2 / t)
    expected = math.sqrt(float(np.sum(t * var) / t.sum()))
    assert window_floor_dps(_white(n_white), centre, t) == pytest.approx(expected, rel=1e-12)


def test_a_model_the_bench_cannot_hold_is_refused_before_any_bench_starts() -> None:
    from station.discrepancy_simulate import _check_entry
    from station.errors import UserError

    entry = part_entry(GyroModel(name="odd", bias_dps=0.0, scale=3.0), "SIM-9")
    with pytest.raises(UserError, match="cannot be a simulated part.*scale"):
        _check_entry(entry, "odd")


# a ramp: plateaus of 6 s at the rate set while the die heats (eol-ramp), a static dwell
SWEEP = [("", "ramp_plateau", 6.0, w, 0.0) for w in (200.0, -200.0, 100.0, -100.0)]
RAMP = SWEEP * 3 + [("ramp_top", "static", 5.0, 0.0, 90.0)]
HEAT = 0.05  # C/s: 3 C/min; a plateau every 8.95 s, a sweep of the rate set 1.8 C
PLATEAU_EVERY_S = 6.0 - 1 / RATE_HZ + 3.0  # _traj: a window's last sample + the gap


def _ramp(plan: list, offset_c: float = 0.0) -> Trajectory:
    """A heating ramp whose output is a bias in the die temperature (0.01 deg/s per C)."""
    traj = _traj(plan=plan, temp_c_per_s=HEAT, temp_offset_c=offset_c)
    return dataclasses.replace(traj, gyro_dps=0.01 * (traj.temp_c - 25.0))


def test_ramp_plateaus_are_compared_by_key_rate_and_die_temperature() -> None:
    """In lockstep the twin of a part run alone ramps on the measured timeline: every ramp
    plateau is compared (the dies 0.1 C apart: a socket's air). One a plateau late is
    0.45 C off at every plateau: none compared. A twin
    whose ramp ran a sweep of the rate set more before (as a part alone turns at another
    time than six together) holds each plateau's key at the same rate but 1.8 C colder:
    those are not compared, and the note says why."""
    measured = _ramp(RAMP)
    w = windows_of(measured)
    assert [k[2] for k in w.keys if k[1] == "ramp_plateau"] == list(range(12))
    same = _ramp(RAMP, offset_c=0.1)
    cmp = compare(measured, same, same, _white(0.001))
    assert len(cmp.keys) == 13 and not cmp.notes
    assert np.allclose(cmp.twin_temp_c - cmp.temp_c, 0.1)
    assert np.allclose(cmp.residual_after_dps[:12], -0.01 * 0.1)
    late = _ramp(RAMP, offset_c=-HEAT * PLATEAU_EVERY_S)  # a plateau later: 0.45 C colder
    assert compare(measured, late, late, _white(0.001)).keys == (("ramp_top", "static", 0, 0),)
    longer = _ramp(SWEEP + RAMP, offset_c=-HEAT * 4 * PLATEAU_EVERY_S)
    cmp = compare(measured, longer, longer, _white(0.001))
    assert cmp.keys == (("ramp_top", "static", 0, 0),)
    assert "12 of 13 measured window pieces" in cmp.notes[0]
    assert "another die temperature" in cmp.notes[0]
    assert HEAT * 4 * PLATEAU_EVERY_S > MAX_RAMP_TEMP_MISMATCH_C


def _record(folder: Path, serial: str, socket: int, started: str, sha: str = "abc") -> Path:
    from procedures.runtime.record import Dut, FileRef, RunRecord, Verdict, write_record

    folder.mkdir(parents=True)
    write_record(folder, RunRecord(
        run_id=folder.name, verdict=Verdict.PASS, started_utc=started,
        dut=Dut(serial=serial, socket=socket), product=FileRef(path="p.yaml", sha256=""),
        procedure=FileRef(path="eol-ramp.yaml", sha256=sha)))
    return folder


def test_the_twin_runs_among_the_other_parts_of_the_measured_cycle(tmp_path: Path) -> None:
    """A ramp turns when the last die of the load has covered the span: the twin's bench
    holds the other parts the measured run started with (same procedure, within seconds),
    not parts of another run or another procedure."""
    from station.discrepancy_simulate import companions

    t = "2026-11-28T03:30:50.{:03d}+00:00"
    measured = _record(tmp_path / "A_SIM-2932", "SIM-2932", 2, t.format(120))
    _record(tmp_path / "A_SIM-2931", "SIM-2931", 1, t.format(100))
    _record(tmp_path / "A_SIM-2933", "SIM-2933", 3, t.format(140))
    _record(tmp_path / "B_SIM-2934", "SIM-2934", 4, "2026-11-28T04:10:00.000+00:00")
    _record(tmp_path / "A_SIM-2935", "SIM-2935", 5, t.format(150), sha="other")
    assert companions(measured) == {1: tmp_path / "A_SIM-2931", 3: tmp_path / "A_SIM-2933"}
    alone = _record(tmp_path / "alone" / "C_SIM-2936", "SIM-2936", 1, t.format(0))
    assert companions(alone) == {}


def test_a_twin_s_air_is_given_where_its_die_is_not_the_measured_one_s() -> None:
    """The dies' offset is read over a run's first pieces (before any ramp turns), and the
    twin's bench takes it as the socket's air."""
    measured = _ramp(RAMP)
    warm = _ramp(RAMP, offset_c=0.11)  # a twin on air 0.11 C warmer than the measured part's
    assert die_offset_c(measured, warm) == pytest.approx(-0.11)
    assert die_offset_c(measured, measured) == 0.0
    bench = parse_sim_config(twin_config(part_entry(GyroModel(name="m", bias_dps=0.0,
                                                              scale=1.0), "SIM-1", socket=2),
                                         air_c={2: -0.11}))
    assert socket_air_offset_c(0, 2, bench.part_physics.thermal) == -0.11
    assert draw_thermal("SIM-1", bench.part_physics.thermal).ideal
