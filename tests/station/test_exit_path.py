"""station/exit_path.py in-process: what a signal and an uncaught thread exception do before
and after a run is attached (the whole commands are in test_signal_grid.py)."""

from __future__ import annotations

import io
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator

import pytest

from procedures.engine.safe_state import SafeStatePolicy
from station.exit_path import ExitPath, exit_bound_s


class Stops:
    def __init__(self) -> None:
        self.calls: list[tuple[str, bool]] = []
        self.called = threading.Event()

    def __call__(self, reason: str, error: bool) -> None:
        self.calls.append((reason, error))
        self.called.set()


@pytest.fixture
def exits() -> Iterator[list[int]]:
    yield []


@pytest.fixture(autouse=True)
def hangups_as_from_a_terminal() -> Iterator[None]:
    """Each test starts with SIGHUP's default action, whatever started pytest (nohup starts
    it ignored, which the exit path keeps), and leaves it as it found it."""
    found = signal.signal(signal.SIGHUP, signal.SIG_DFL)
    yield
    signal.signal(signal.SIGHUP, found)


def _wait(cond: object, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < deadline:  # type: ignore[operator]
        time.sleep(0.01)


@pytest.mark.parametrize(
    ("sig", "words"),
    [(signal.SIGTERM, "SIGTERM"), (signal.SIGINT, "Ctrl-C"), (signal.SIGHUP, "SIGHUP"),
     (signal.SIGQUIT, "SIGQUIT")],
)
def test_each_signal_stops_the_run_once_and_a_second_is_said_not_obeyed(
    sig: signal.Signals, words: str, exits: list[int], capfd: pytest.CaptureFixture[str]
) -> None:
    stops = Stops()
    stdout, stderr = sys.stdout, sys.stderr
    try:
        with ExitPath("run", bound_s=60, exit_now=exits.append) as path:
            path.attach(stops)
            os.kill(os.getpid(), sig)
            assert stops.called.wait(5)
            os.kill(os.getpid(), signal.SIGTERM)  # while the run's end goes on
            _wait(lambda: len(path.signals) == 2)
        assert stops.calls == [(stops.calls[0][0], False)] and words in stops.calls[0][0]
        assert path.signalled and path.reason == stops.calls[0][0] and not path.error
        assert exits == []  # ended within its bound: no forced exit
    finally:
        sys.stdout, sys.stderr = stdout, stderr
    err = capfd.readouterr().err
    assert "making the bench safe" in err and "SIGTERM again" in err
    # the process's own handlers are back
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    assert signal.getsignal(signal.SIGHUP) is signal.SIG_DFL


def test_a_hangup_ignored_at_start_stays_ignored(exits: list[int]) -> None:
    """`nohup station run ...` asked that a closed terminal not stop the run: SIGHUP stays
    ignored, and SIGTERM still stops the run the usual way."""
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    stops = Stops()
    with ExitPath("run", bound_s=60, exit_now=exits.append) as path:
        path.attach(stops)
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
        os.kill(os.getpid(), signal.SIGHUP)
        assert not stops.called.wait(0.3) and not path.signals
        os.kill(os.getpid(), signal.SIGTERM)
        assert stops.called.wait(5)
    assert "SIGTERM" in stops.calls[0][0] and exits == []
    assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN


def test_before_a_run_is_attached_a_signal_unwinds_as_ctrl_c() -> None:
    with pytest.raises(KeyboardInterrupt), ExitPath("run"):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # interrupted by the handler at once
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def test_an_uncaught_exception_in_any_thread_ends_the_run_error(
    caplog: pytest.LogCaptureFixture,
) -> None:
    stops = Stops()
    with ExitPath("ui") as path:
        path.attach(stops)

        def bug() -> None:
            raise ValueError("bad frame")

        t = threading.Thread(target=bug, name="acquisition")
        t.start()
        t.join()
        assert stops.called.wait(5)
    reason, error = stops.calls[0]
    assert error and path.error
    assert "thread 'acquisition'" in reason and "ValueError: bad frame" in reason
    assert "uncaught exception in thread acquisition" in caplog.text  # the traceback: the log
    assert threading.excepthook != path._on_thread_exception  # the process's own hook is back


def test_a_stop_that_outlasts_its_bound_exits_2(exits: list[int]) -> None:
    """A safe-state pass that never ends (a bug, a hung driver) must not keep the process
    forever: exit 2 at the bound; the folder is recovered at the next start."""
    with ExitPath("run", bound_s=0.3, exit_now=exits.append) as path:
        path.attach(lambda reason, error: None)  # the run never ends
        os.kill(os.getpid(), signal.SIGTERM)
        _wait(lambda: exits == [2], 5.0)
    assert exits == [2]


def test_after_sighup_a_dead_terminal_cannot_fail_the_run(exits: list[int]) -> None:
    class Dead(io.StringIO):
        def write(self, text: str) -> int:
            raise OSError(5, "Input/output error")

    stdout, stderr = sys.stdout, sys.stderr
    try:
        sys.stdout, sys.stderr = Dead(), Dead()
        stops = Stops()
        with ExitPath("run", exit_now=exits.append) as path:
            path.attach(stops)
            os.kill(os.getpid(), signal.SIGHUP)
            assert stops.called.wait(5)
            print("the run's summary line")  # would raise EIO on a closed terminal
            sys.stdout.flush()
    finally:
        sys.stdout, sys.stderr = stdout, stderr


def test_the_bound_covers_the_safe_state_pass_and_the_sealing() -> None:
    policy = SafeStatePolicy(deadline_s=120.0, wall_floor_s=10.0)
    assert exit_bound_s(policy) > 120.0 + 60.0
    assert exit_bound_s(SafeStatePolicy(deadline_s=1.0, wall_floor_s=30.0)) > 30.0
