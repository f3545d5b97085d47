"""One fixture socket's stream in the world, decoded frame by frame (no pty)."""

import numpy as np
import pytest

from drivers import fixture_protocol as fp
from drivers.sim import motion
from drivers.sim.config import parse_sim_config
from drivers.sim.world import World


def _world(**part: object) -> World:
    spec = {
        "socket": 1,
        "serial": "SIM-FX",
        "arw_deg_per_sqrt_h": 0.0,
        "bias_instability_deg_per_h": 0.0,
        "rrw_deg_per_h_per_sqrt_h": 0.0,
        **part,
    }
    # the ideal thermal physics (docs/simulated-bench.md): the compensated output is exact
    raw = {"parts": [spec], "table": {"ripple_dps": 0.0},
           "part_physics": {"thermal": {"mode": "ideal"}}}
    w = World(parse_sim_config(raw), speed=1.0)
    for line in ("VOLT 5.0", "CURR 0.5", "OUTP ON"):
        w.supply.handle(line)
    w.advance()
    return w


def _decode(data: bytes) -> fp.ParseResult:
    return fp.FrameParser().feed(data)


def test_stream_timestamps_seq_and_stop_after_last_frame() -> None:
    w = _world()
    s = w.sockets[1]
    assert _decode(s.handle_line("ODR 500", 0.0)).replies == ["OK"]
    assert _decode(s.handle_line("START", 1.0)).replies == ["OK"]
    res = _decode(s.produce(1.1) + s.handle_line("STOP", 1.2051))
    assert list(res.seq) == list(range(102))  # 2 ms apart from 1.002 to 1.204
    assert res.replies == ["OK"]
    steps = np.diff(res.time_s)
    assert np.allclose(steps, 0.002, atol=1e-9)
    assert res.time_s[0] == pytest.approx(1.002 + s.clock_offset_s, abs=1e-6)
    assert s.produce(5.0) == b""  # stopped


def test_over_range_and_saturation_bits() -> None:
    w = _world(
        bias_dps=0.0,
        scale=1.0,
        bias_temp_coeff_dps_per_c=0.0,
        bias_supply_coeff_dps_per_v=0.0,
        scale_temp_coeff_per_c=0.0,
        scale_supply_coeff_per_v=0.0,
    )
    s = w.sockets[1]
    s.handle_line("ODR 1000", 0.0)
    s.handle_line("START", 0.0)
    for rate, expect in (
        (100.0, 0),
        (300.0, fp.SampleStatus.OVER_RANGE),
        (400.0, fp.SampleStatus.OVER_RANGE | fp.SampleStatus.SATURATED),
        (-400.0, fp.SampleStatus.OVER_RANGE | fp.SampleStatus.SATURATED),
    ):
        t0 = s._t_start + s._next_k / s.odr_hz
        # constant rate from the last sample's angle on (a sample is the mean rate since the
        # previous one)
        piece = motion.Piece(t0 - 1 / s.odr_hz, np.inf, (s._last_angle_deg, rate))
        w.table.profile = motion.Profile((piece,), 0.0)
        res = _decode(s.produce(t0 + 0.05))
        latched = int(fp.SampleStatus.ENCODER_LATCHED)
        assert set(res.status.tolist()) == {int(expect) | latched}, rate
        if rate == 400.0:
            assert set(res.rate_code.tolist()) == {fp.CODE_MAX}
        elif rate == -400.0:
            assert set(res.rate_code.tolist()) == {0}
        else:
            assert fp.rate_code_to_dps(res.rate_code) == pytest.approx(rate, abs=1 / 23488)


def test_compensated_output_and_supply_low_bit() -> None:
    w = _world(
        bias_dps=8.6,
        scale=1.0567,
        bias_temp_coeff_dps_per_c=0.0,
        bias_supply_coeff_dps_per_v=0.0,
        scale_temp_coeff_per_c=0.0,
        scale_supply_coeff_per_v=0.0,
    )
    s = w.sockets[1]
    assert _decode(s.handle_line("CAL bias=8.6 scale=1.0567", 0.0)).replies == ["OK"]
    s.handle_line("COMP 1", 0.0)
    s.handle_line("START", 0.0)
    w.table.profile = motion.Profile((motion.Piece(0.0, np.inf, (0.0, 50.0)),), 0.0)
    res = _decode(s.produce(0.2))
    assert fp.rate_code_to_dps(res.rate_code) == pytest.approx(50.0, abs=1e-4)
    assert set(res.status.tolist()) == {
        int(fp.SampleStatus.COMPENSATED | fp.SampleStatus.ENCODER_LATCHED)
    }
    w.supply.handle("VOLT 4.3")  # above brown-out (4.0 V), below the part's 4.5 V minimum
    w.advance()
    res = _decode(s.produce(0.4))
    assert all(st & fp.SampleStatus.SUPPLY_LOW for st in res.status)
    w.supply.handle("VOLT 3.0")  # brown-out: the part stops
    w.advance()
    assert s.produce(0.6) == b""
    assert _decode(s.handle_line("SN?", 0.6)).replies[0].startswith("ERR 11")


def test_temperature_code_follows_the_die() -> None:
    w = _world()
    s = w.sockets[1]
    s.handle_line("START", 0.0)
    res = _decode(s.produce(0.5))
    temp = fp.temp_code_to_c(res.temp_code)
    die = s.part.die_temp_c()  # type: ignore[union-attr]
    assert float(np.mean(temp)) == pytest.approx(die, abs=0.02)


def test_latched_encoder_follows_the_table_and_matches_the_sampled_rate() -> None:
    """Hardware sync: each frame carries the table's encoder count at the sample instant,
    and the part's sample is the mean rate since the previous one, so differences of two
    latches are the reference for every sample, through accelerations too."""
    w = _world(bias_dps=0.0, scale=1.0, bias_temp_coeff_dps_per_c=0.0,
               bias_supply_coeff_dps_per_v=0.0, scale_temp_coeff_per_c=0.0,
               scale_supply_coeff_per_v=0.0)
    s = w.sockets[1]
    s.handle_line("ODR 100", 0.0)
    s.handle_line("START", 0.0)
    w.table.profile = motion.rate_profile(0.5, 0.0, 0.0, 100.0, 200.0)  # ramp 0.5 .. 1.0 s
    res = _decode(s.produce(2.0))
    assert np.all(res.status & fp.SampleStatus.ENCODER_LATCHED)
    cpr = w.table.cpr
    angle = res.encoder * 360.0 / cpr
    true_angle = w.table.angle_deg(res.time_s - s.clock_offset_s)
    assert np.max(np.abs(angle - true_angle)) <= 360.0 / cpr  # one count
    ref = np.diff(angle) / np.diff(res.time_s)
    gyro = fp.rate_code_to_dps(res.rate_code)[1:]
    ramp = (res.time_s[1:] - s.clock_offset_s > 0.52) & (res.time_s[1:] - s.clock_offset_s < 0.98)
    assert ramp.sum() > 40 and np.ptp(ref[ramp]) > 80.0  # the table really accelerates
    # the mean rate between latches equals the part's sample to a count over a period
    assert np.max(np.abs(gyro - ref)) < 360.0 / cpr / 0.01 + 1e-4


def test_fixture_without_encoder_input_leaves_the_bit_clear() -> None:
    w = World(parse_sim_config({"parts": [{"socket": 1, "serial": "SIM-NE"}],
                                "fixture": {"encoder_input": False}}), speed=1.0)
    for line in ("VOLT 5.0", "CURR 0.5", "OUTP ON"):
        w.supply.handle(line)
    w.advance()
    s = w.sockets[1]
    s.handle_line("START", 0.0)
    res = _decode(s.produce(0.5))
    assert res.seq.size > 10
    assert not np.any(res.status & fp.SampleStatus.ENCODER_LATCHED)
    assert not np.any(res.encoder)
