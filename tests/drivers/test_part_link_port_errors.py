"""The serial part link turns every OS and tty-layer error of its port into ConnectionLost
with the reason in the message (never a bare OSError or termios.error)."""

from __future__ import annotations

import errno
import termios
import time

import pytest

from common.clock import ScaledClock
from drivers import part_link
from drivers.errors import ConnectionLost
from drivers.part_link import SerialPartLink


class DyingPort:
    """A SerialLike whose every call raises `error` once `dead` is set."""

    def __init__(self, error: BaseException) -> None:
        self.error = error
        self.dead = False

    def _check(self) -> None:
        if self.dead:
            raise self.error

    @property
    def in_waiting(self) -> int:
        self._check()
        return 0

    def read(self, size: int = 1) -> bytes:
        self._check()
        time.sleep(0.002)
        return b""

    def write(self, data: bytes) -> int:
        self._check()
        return len(data)

    def reset_input_buffer(self) -> None:
        self._check()

    def close(self) -> None:  # pyserial closes with os.close: only ever an OSError
        if self.dead:
            raise OSError(errno.EIO, "Input/output error")


ERRORS = [
    pytest.param(termios.error(errno.EIO, "Input/output error"), "Input/output error [EIO]",
                 id="termios"),
    pytest.param(OSError(errno.ENXIO, "No such device or address"),
                 "No such device or address [ENXIO]", id="oserror"),
]


@pytest.mark.parametrize(("error", "reason"), ERRORS)
def test_a_port_that_fails_while_reading_raises_connection_lost_with_the_reason(error, reason):
    port = DyingPort(error)
    link = SerialPartLink(port, ScaledClock(1.0), socket=3, reply_timeout_s=0.2)
    try:
        port.dead = True
        t_end = time.monotonic() + 2.0
        with pytest.raises(ConnectionLost) as info:
            while time.monotonic() < t_end:
                link.read_samples(max_wait_s=0.05)
        assert reason in str(info.value) and "socket 3" in str(info.value)
        assert info.value.__cause__ is error
        with pytest.raises(ConnectionLost, match=reason.replace("[", r"\[")):
            link.read_part_serial()  # commands say the same
    finally:
        link.close()  # and closing a dead port does not raise


@pytest.mark.parametrize(("error", "reason"), ERRORS)
def test_a_port_that_fails_on_write_raises_connection_lost_with_the_reason(error, reason):
    port = DyingPort(error)
    link = SerialPartLink(port, ScaledClock(1.0), reply_timeout_s=0.2)
    try:
        port.write = lambda data: (_ for _ in ()).throw(error)  # type: ignore[method-assign]
        with pytest.raises(ConnectionLost, match="cannot write") as info:
            link.identify()
        assert reason in str(info.value)
    finally:
        link.close()


@pytest.mark.parametrize(
    "error",
    [termios.error(errno.EINVAL, "Invalid argument"), ValueError("Failed to set custom baud")],
)
def test_errors_pyserial_lets_through_at_open_become_connection_lost(monkeypatch, error):
    def failing_open(path, **kwargs):
        raise error

    monkeypatch.setattr(part_link, "open_serial", failing_open)
    with pytest.raises(ConnectionLost, match=r"/dev/ttyX9 at 250000 baud") as info:
        SerialPartLink.open("/dev/ttyX9", ScaledClock(1.0), baudrate=250000)
    assert info.value.__cause__ is error


def test_a_missing_port_is_connection_lost():
    with pytest.raises(ConnectionLost, match="/dev/no-such-fixture"):
        SerialPartLink.open("/dev/no-such-fixture", ScaledClock(1.0))
