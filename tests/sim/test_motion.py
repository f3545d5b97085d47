import numpy as np
import pytest

from drivers.sim import motion
from drivers.sim.config import BounceConfig


def _check_limits(prof: motion.Profile, t0: float, t1: float, accel: float, vmax: float) -> None:
    t = np.linspace(t0, t1, 20001)
    v = prof.velocity_dps(t)
    a = np.diff(v) / np.diff(t)
    assert np.max(np.abs(a)) <= accel * 1.001
    assert np.max(np.abs(v)) <= vmax * 1.0001
    # velocity is the derivative of position
    p = prof.position_deg(t)
    dt = float(t[1] - t[0])
    assert np.allclose(np.diff(p) / np.diff(t), 0.5 * (v[1:] + v[:-1]), atol=accel * dt)


@pytest.mark.parametrize("distance", [90.0, -90.0, 0.5, 720.0])
def test_trapezoid_reaches_target_within_limits(distance: float) -> None:
    prof = motion.trapezoid_move(10.0, 5.0, 0.0, 5.0 + distance, 100.0, 90.0)
    assert prof.position_deg(prof.motion_end_s + 1.0)[0] == pytest.approx(5.0 + distance, abs=1e-9)
    _check_limits(prof, 10.0, prof.motion_end_s + 0.5, 100.0, 90.0)
    # a triangle move is shorter than one at the speed limit would be
    assert prof.motion_end_s - 10.0 >= abs(distance) / 90.0


def test_smooth_move_takes_the_given_time_and_stops() -> None:
    prof = motion.smooth_move(2.0, 0.0, 0.0, 90.0, 3.5, 500.0)
    assert prof.motion_end_s == pytest.approx(5.5)
    p, v = prof.at(5.5)
    assert p == pytest.approx(90.0, abs=1e-9) and v == pytest.approx(0.0, abs=1e-9)
    assert prof.velocity_dps(3.75)[0] == pytest.approx(1.875 * 90 / 3.5)


def test_rate_profile_from_moving_state_ramps_then_holds() -> None:
    prof = motion.rate_profile(0.0, 0.0, -20.0, 100.0, 60.0)
    assert prof.motion_end_s == pytest.approx(2.0)
    assert prof.velocity_dps(1.0)[0] == pytest.approx(40.0)
    assert prof.velocity_dps([3.0, 50.0]) == pytest.approx([100.0, 100.0])
    # position after the ramp: -20*2 + 0.5*60*4 = 80, then 100 deg/s
    assert prof.position_deg(12.0)[0] == pytest.approx(80.0 + 1000.0)


def test_move_from_motion_stops_first() -> None:
    prof = motion.smooth_move(0.0, 0.0, 50.0, 0.0, 2.0, 100.0)
    assert prof.position_deg(0.5)[0] == pytest.approx(12.5)  # decelerating forward first
    assert prof.position_deg(prof.motion_end_s)[0] == pytest.approx(0.0, abs=1e-9)


def test_bounce_decays_and_settles() -> None:
    bc = BounceConfig(amplitude_deg=0.05, frequency_hz=5.0, decay_s=0.2)
    prof = motion.smooth_move(0.0, 0.0, 0.0, 90.0, 3.0, 500.0, bc)
    assert prof.bounce is not None
    t = np.linspace(3.0, 3.3, 301)
    assert np.max(np.abs(prof.position_deg(t) - 90.0)) > 0.02  # there is a visible bounce
    settle = prof.bounce.settled_at_s(0.001)
    late = np.linspace(settle, settle + 2, 200)
    assert np.max(np.abs(prof.position_deg(late) - 90.0)) <= 0.001
