"""The serial part link against the bench's fixture twin over a pty, with a three-axis part:
identity of axes, the three-axis registers written and read back over CAL3, three-axis
frames decoded into SampleBlock's xyz columns, and the cube turned by the simulated operator
on a relayed orientation prompt (the station's ProgressEvent -> prompt relay -> bench)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np
import pytest

from common.clock import ScaledClock
from drivers.orientation import face_from_accel
from drivers.part_codes import ADIS16130
from drivers.part_link import SerialPartLink
from drivers.protocols import CalibrationRegisters3, CalibrationStore3, SampleBlock
from drivers.sim.launcher import BenchHandle, launch_bench
from drivers.supply import ScpiSupply
from procedures.runtime.progress import ProgressEvent
from station.prompt_relay import PromptRelay

SPEED = 20.0
QUIET = {"arw_deg_per_sqrt_h": 0.0, "bias_instability_deg_per_h": 0.0,
         "rrw_deg_per_h_per_sqrt_h": 0.0}


@pytest.fixture(scope="module")
def rig() -> Iterator[tuple[BenchHandle, SerialPartLink]]:
    config = {"parts": [{"socket": 1, "serial": "IMU-0042", "three_axis": {}, **QUIET},
                        {"socket": 2, "serial": "SIM-0002"}]}
    with launch_bench(config=config, speed=SPEED) as bench:
        ep = bench.endpoints
        supply = ScpiSupply.open(ep.supply, timeout_s=1.0)
        link = SerialPartLink.open(ep.duts[1], ScaledClock(SPEED), socket=1,
                                   reply_timeout_s=1.0, silent_after_s=SPEED)
        try:
            supply.set_voltage(5.0)
            supply.set_current_limit(0.1)
            supply.output(True)
            yield bench, link
        finally:
            link.close()
            supply.close()


def _stream(link: SerialPartLink, wall_s: float) -> SampleBlock:
    link.start_stream()
    time.sleep(wall_s)
    link.stop_stream()
    return link.read_samples(max_wait_s=0.2)


def test_axes_of_a_three_axis_and_a_single_axis_part(rig) -> None:  # noqa: ANN001
    bench, link = rig
    assert isinstance(link, CalibrationStore3)
    assert link.axes() == 3
    other = SerialPartLink.open(bench.endpoints.duts[2], ScaledClock(SPEED), socket=2)
    try:
        assert other.axes() == 1
    finally:
        other.close()


def test_three_axis_registers_round_trip_over_the_link(rig) -> None:  # noqa: ANN001
    bench, link = rig
    rng = np.random.default_rng(5)
    regs = CalibrationRegisters3(
        bias_dps=rng.normal(0, 2, 3), matrix=np.eye(3) + rng.normal(0, 0.01, (3, 3)),
        g_sensitivity_dps_per_mps2=rng.normal(0, 0.01, (3, 3)),
        bias_tc_dps_per_c=rng.normal(0, 0.01, 3), bias_vc_dps_per_v=rng.normal(0, 0.05, 3),
        scale_tc_per_c=rng.normal(0, 2e-4, 3), scale_vc_per_v=rng.normal(0, 1e-3, 3),
        t0_c=24.5, v0_v=5.05,
    )
    link.write_calibration3(regs)
    back = link.read_calibration3()
    for name in ("bias_dps", "matrix", "g_sensitivity_dps_per_mps2", "scale_tc_per_c"):
        np.testing.assert_allclose(getattr(back, name), getattr(regs, name), rtol=1e-8)
    assert (back.t0_c, back.v0_v) == (24.5, 5.05)
    truth = bench.control.truth()["sockets"]["1"]["calibration"]
    np.testing.assert_allclose(truth["matrix"], regs.matrix, rtol=1e-8)
    link.write_calibration3(CalibrationRegisters3())  # erased again for the next test
    assert link.read_calibration3() == CalibrationRegisters3()


def test_stream_carries_xyz_columns_and_the_operator_turns_the_cube(rig) -> None:  # noqa: ANN001
    bench, link = rig
    link.set_output_rate(100)
    block = _stream(link, 0.3)
    assert len(block) > 100 and block.rate_code_xyz is not None
    assert block.accel_code_xyz is not None and block.rate_code_xyz.shape == (len(block), 3)
    np.testing.assert_array_equal(block.rate_code, block.rate_code_xyz[:, 0])
    accel = ADIS16130.accel_code_to_mps2(block.accel_code_xyz)
    assert face_from_accel(accel.mean(axis=0)) == "+z"
    truth = bench.control.truth()["sockets"]["1"]
    rate = ADIS16130.rate_code_to_dps(block.rate_code_xyz).mean(axis=0)
    assert np.allclose(rate, truth["parameters"]["bias_dps"], atol=0.5)  # at rest: ~bias

    relay = PromptRelay(bench.endpoints.raw["operator"])
    try:
        relay(ProgressEvent(kind="prompt", step="orient", message=(
            "Turn socket 1's cube so that face +Y points up"), sockets={1: "PROMPT"},
            orientation="+y"))
    finally:
        relay.close()
    deadline = time.monotonic() + 60.0
    while bench.control.truth()["sockets"]["1"]["cube"]["face"] != "+y":
        assert time.monotonic() < deadline, "the simulated operator did not turn the cube"
        time.sleep(0.05)
    block = _stream(link, 0.3)
    assert block.accel_code_xyz is not None
    accel = ADIS16130.accel_code_to_mps2(block.accel_code_xyz)
    assert face_from_accel(accel.mean(axis=0)) == "+y"
    turns = bench.control.truth()["sockets"]["1"]["cube"]["turns"]
    assert [t["to"] for t in turns] == ["+y"] and turns[0]["angle_deg"] == pytest.approx(90.0)
