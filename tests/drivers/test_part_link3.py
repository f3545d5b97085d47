"""The part link's three-axis commands, byte for byte, against a scripted fixture on a pty:
AXES?, the CAL3 write lines and CAL3? read-back, their failures typed, and three-axis
sample frames decoded into SampleBlock's xyz columns."""

from __future__ import annotations

import os
import threading
import time
import tty
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from common.clock import ScaledClock
from drivers import fixture_protocol as fp
from drivers.errors import InstrumentError, ProtocolError
from drivers.part_link import FixtureRefused, SerialPartLink
from drivers.protocols import CalibrationRegisters3
from tests.drivers.expected_protocol import lines_from, write_all


class ScriptedFixture:
    """Answers each command line with `answer(line)`; records the lines; `send` writes
    raw bytes (frames) to the host."""

    def __init__(self, answer: Callable[[str], str]) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.answer = answer
        self.commands: list[bytes] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def send(self, data: bytes) -> None:
        write_all(self.master, data)

    def _serve(self) -> None:
        for line in lines_from(self.master, self._stop):
            self.commands.append(line)
            self.send(fp.encode_reply(self.answer(line.decode())))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1.0)
        os.close(self.master)
        os.close(self.slave)


class Registers:
    """A three-axis part's register store as the fixture keeps it (CAL3 / CAL3?)."""

    def __init__(self) -> None:
        self.values = {"bias": "0,0,0", "matrix": "1,0,0,0,1,0,0,0,1", "gsens": "0,0,0,0,0,0,0,0,0",
                       "bias_tc": "0,0,0", "bias_vc": "0,0,0", "scale_tc": "0,0,0",
                       "scale_vc": "0,0,0", "t0": "25", "v0": "5"}
        self.sticky: dict[str, str] = {}

    def __call__(self, line: str) -> str:
        word, _, arg = line.partition(" ")
        if word == "CAL3?":
            return f"OK {arg}={self.values[arg]}"
        if word == "CAL3":
            for item in arg.split():
                key, _, value = item.partition("=")
                self.values[key] = self.sticky.get(key, value)
            return "OK"
        if word == "AXES?":
            return "OK 3"
        return "ERR 2 unknown command"


@pytest.fixture
def rig() -> Iterator[Callable[..., tuple[ScriptedFixture, SerialPartLink]]]:
    made: list[tuple[ScriptedFixture, SerialPartLink]] = []

    def build(answer: Callable[[str], str]) -> tuple[ScriptedFixture, SerialPartLink]:
        fixture = ScriptedFixture(answer)
        link = SerialPartLink.open(fixture.path, ScaledClock(1.0), reply_timeout_s=0.5)
        made.append((fixture, link))
        return fixture, link

    yield build
    for fixture, link in made:
        link.close()
        fixture.close()


REGS = CalibrationRegisters3(
    bias_dps=(1.5, -0.25, 0.125),
    matrix=((1.01, 0.002, -0.003), (0.001, 0.99, 0.0), (0.0, -0.004, 1.0)),
    g_sensitivity_dps_per_mps2=((0.01, 0, 0), (0, -0.02, 0), (0.005, 0, 0.03)),
    bias_tc_dps_per_c=(0.007, 0, -0.007),
    bias_vc_dps_per_v=(0.05, 0.04, 0.03),
    scale_tc_per_c=(2e-4, -1e-4, 0),
    scale_vc_per_v=(1e-3, 0, -1e-3),
    t0_c=25.0,
    v0_v=5.0,
)


def test_axes_query_bytes_and_answers(rig) -> None:  # noqa: ANN001
    fixture, link = rig(lambda line: "OK 3")
    assert link.axes() == 3
    assert fixture.commands == [b"AXES?"]
    _, old = rig(lambda line: "ERR 2 unknown command")
    assert old.axes() == 1  # firmware before three-axis parts
    _, odd = rig(lambda line: "OK 2")
    with pytest.raises(ProtocolError, match="not 1 or 3"):
        odd.axes()
    _, unpowered = rig(lambda line: "ERR 11 part not powered")
    with pytest.raises(FixtureRefused, match="switch the supply"):
        unpowered.axes()


def test_calibration3_write_lines_and_read_back(rig) -> None:  # noqa: ANN001
    store = Registers()
    fixture, link = rig(store)
    link.write_calibration3(REGS)
    assert fixture.commands[:4] == [
        b"CAL3 bias=1.5,-0.25,0.125 bias_tc=0.007,0,-0.007 bias_vc=0.05,0.04,0.03 t0=25 v0=5",
        b"CAL3 matrix=1.01,0.002,-0.003,0.001,0.99,0,0,-0.004,1",
        b"CAL3 gsens=0.01,0,0,0,-0.02,0,0.005,0,0.03",
        b"CAL3 scale_tc=0.0002,-0.0001,0 scale_vc=0.001,0,-0.001",
    ]
    assert fixture.commands[4:] == [f"CAL3? {k}".encode() for k in fp.CAL3_KEYS]
    assert all(len(c) < fp.MAX_REPLY_PAYLOAD for c in fixture.commands)
    assert link.read_calibration3() == REGS


def test_a_register_that_does_not_stick_is_reported(rig) -> None:  # noqa: ANN001
    store = Registers()
    store.sticky["matrix"] = "1,0,0,0,1,0,0,0,1"
    _, link = rig(store)
    with pytest.raises(InstrumentError, match=r"matrix\[0\] wrote 1.01 read 1;.*reject the part"):
        link.write_calibration3(REGS)


@pytest.mark.parametrize("reply", ["OK bias=1,2", "OK bias=1,2,x", "OK matrix=1,2,3", "OK",
                                   "OK bias=1,2,inf"])
def test_a_malformed_cal3_reply_is_a_protocol_error(rig, reply: str) -> None:  # noqa: ANN001
    _, link = rig(lambda line: reply)
    with pytest.raises(ProtocolError, match="CAL3\\? bias"):
        link.read_calibration3()


def test_non_finite_registers_are_refused_before_anything_is_sent(rig) -> None:  # noqa: ANN001
    fixture, link = rig(Registers())
    with pytest.raises(ValueError, match="finite: gsens"):
        link.write_calibration3(CalibrationRegisters3(
            g_sensitivity_dps_per_mps2=np.full((3, 3), np.nan)))
    assert fixture.commands == []


def test_three_axis_frames_arrive_as_xyz_columns(rig) -> None:  # noqa: ANN001
    fixture, link = rig(lambda line: "OK")
    n = 500
    rng = np.random.default_rng(9)
    rate = rng.integers(0, fp.CODE_MAX + 1, (n, 3))
    accel = rng.integers(0, fp.CODE_MAX + 1, (n, 3))
    temp = rng.integers(0, fp.CODE_MAX + 1, n)
    link.start_stream()
    fixture.send(fp.encode_samples3(np.arange(n), np.arange(n) * 5000, rate, accel, temp,
                                    np.zeros(n, dtype=np.int64)))
    got = []
    deadline = time.monotonic() + 5.0
    while sum(len(b) for b in got) < n and time.monotonic() < deadline:
        got.append(link.read_samples(max_wait_s=0.05))
    link.stop_stream()
    blocks = [b for b in got if len(b)]
    assert all(b.rate_code_xyz is not None and b.accel_code_xyz is not None for b in blocks)
    np.testing.assert_array_equal(np.concatenate([b.rate_code_xyz for b in blocks]), rate)
    np.testing.assert_array_equal(np.concatenate([b.accel_code_xyz for b in blocks]), accel)
    np.testing.assert_array_equal(np.concatenate([b.rate_code for b in blocks]), rate[:, 0])
    assert link.stats().frames_lost == 0


def test_a_single_axis_part_refusing_cal3_is_named_as_such(rig) -> None:  # noqa: ANN001
    _, link = rig(lambda line: "ERR 4 single-axis part: use CAL? and CAL")
    with pytest.raises(FixtureRefused, match="not a three-axis part") as info:
        link.read_calibration3()
    assert info.value.code == 4
    with pytest.raises(FixtureRefused, match="not a three-axis part"):
        link.write_calibration3(REGS)
