"""Calibration registers beyond first order over a real pty: the exact bytes written, the
optional keys read, stale higher-order registers cleared, a part without them named."""

from __future__ import annotations

import pytest

from common.clock import ScaledClock
from drivers.part_link import FixtureRefused, SerialPartLink
from drivers.protocols import CalibrationRegisters
from tests.drivers._fixture_fake import FakeFixture

FIRST = dict(
    bias_dps=8.6, scale=1.0567, bias_tc_dps_per_c=0.0071, scale_tc_per_c=2.1e-4,
    bias_vc_dps_per_v=0.05, scale_vc_per_v=1e-3, t0_c=25.0, v0_v=5.0,
)
FIRST_BYTES = (
    b"CAL bias=8.6 scale=1.0567 bias_tc=0.0071 scale_tc=0.00021 bias_vc=0.05 "
    b"scale_vc=0.001 t0=25 v0=5"
)


@pytest.fixture
def rig():
    fixture = FakeFixture(rate_fps=100.0)
    link = SerialPartLink.open(fixture.path, ScaledClock(1.0), reply_timeout_s=0.5)
    yield fixture, link
    link.close()
    fixture.close()


def test_second_order_registers_are_written_after_the_eight_and_read_back(rig) -> None:
    fixture, link = rig
    regs = CalibrationRegisters(**FIRST, bias_tc2_dps_per_c2=-1.25e-4, scale_tc2_per_c2=-3e-6)
    link.write_calibration(regs)
    assert fixture.commands[0] == FIRST_BYTES + b" bias_tc2=-0.000125 scale_tc2=-3e-06"
    assert fixture.commands[1] == b"CAL?"
    assert len(fixture.commands) == 2
    assert link.read_calibration() == regs


def test_first_order_write_clears_a_stale_higher_order_register(rig) -> None:
    fixture, link = rig
    fixture.cal += " bias_tc2=0.0002 bias_tc3=0 scale_tc2=0 scale_tc3=0"
    link.write_calibration(CalibrationRegisters(**FIRST))
    assert fixture.commands[0] == FIRST_BYTES
    assert fixture.commands[1] == b"CAL?"
    assert fixture.commands[2] == b"CAL bias_tc2=0"
    back = link.read_calibration()
    assert back == CalibrationRegisters(**FIRST) and back.bias_tc2_dps_per_c2 == 0.0


def test_a_part_listing_only_eight_registers_reads_zero_higher_terms(rig) -> None:
    _, link = rig
    regs = link.read_calibration()
    assert regs.bias_tc2_dps_per_c2 == 0.0 and regs.scale_tc3_per_c3 == 0.0


def test_a_part_without_higher_order_registers_is_named(rig) -> None:
    fixture, link = rig
    fixture.cal_keys = {"bias", "scale", "bias_tc", "scale_tc", "bias_vc", "scale_vc", "t0", "v0"}
    with pytest.raises(FixtureRefused, match="no register for bias_tc2.*fit_orders") as info:
        link.write_calibration(CalibrationRegisters(**FIRST, bias_tc2_dps_per_c2=1e-4))
    assert info.value.code == 4
    link.write_calibration(CalibrationRegisters(**FIRST))  # first order still fine
