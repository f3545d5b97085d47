"""The OS lock per instrument address (station/instrument_lock.py): a second holder is refused
in one line naming the instrument and the holder; the kernel frees it when the holder dies."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from station.instrument_lock import InstrumentLock, InstrumentsBusy, lock_instruments

ROOT = Path(__file__).resolve().parents[2]
TABLE = {"127.0.0.1:5020": "rate table at 127.0.0.1:5020"}


def test_a_second_holder_is_refused_in_one_line(tmp_path: Path) -> None:
    with InstrumentLock(TABLE, tmp_path):
        with pytest.raises(InstrumentsBusy) as caught:
            InstrumentLock({"/dev/null": "supply", **TABLE}, tmp_path).acquire()
        text = str(caught.value)
        assert "\n" not in text
        assert text.startswith("the rate table at 127.0.0.1:5020 is in use by another station")
        assert f"pid {os.getpid()}" in text
        # the refused one kept nothing: the supply it got first is free again
        InstrumentLock({"/dev/null": "supply"}, tmp_path).acquire().release()
        InstrumentLock({"127.0.0.1:5021": "another table"}, tmp_path).acquire().release()
    InstrumentLock(TABLE, tmp_path).acquire().release()  # released with the block


def test_one_port_by_two_names_is_one_instrument(tmp_path: Path) -> None:
    link = tmp_path / "by-id"
    link.symlink_to("/dev/null")
    locks = tmp_path / "locks"
    with (
        InstrumentLock({"/dev/null": "fixture of socket 1"}, locks),
        pytest.raises(InstrumentsBusy, match="fixture of socket 1 at by-id"),
    ):
        InstrumentLock({str(link): "fixture of socket 1 at by-id"}, locks).acquire()


def test_the_kernel_frees_the_lock_of_a_killed_holder(tmp_path: Path) -> None:
    code = (
        "import sys, time\n"
        "from pathlib import Path\n"
        "from station.instrument_lock import InstrumentLock\n"
        f"InstrumentLock({TABLE!r}, Path({str(tmp_path)!r})).acquire()\n"
        "print('held', flush=True)\n"
        "time.sleep(60)\n"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.PIPE,
                              text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(InstrumentsBusy, match=f"pid {holder.pid}"):
            InstrumentLock(TABLE, tmp_path).acquire()
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait(10)
    InstrumentLock(TABLE, tmp_path).acquire().release()  # no stale lock after kill -9



def test_a_lock_taken_then_entered_is_held_once_and_released(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # UutRunner.preflight: `with self.lock_instruments():` on a lock already taken
    monkeypatch.setenv("STATION_LOCK_DIR", str(tmp_path))
    with lock_instruments(TABLE.items()), pytest.raises(InstrumentsBusy):
        InstrumentLock(TABLE, tmp_path).acquire()
    InstrumentLock(TABLE, tmp_path).acquire().release()


def test_a_bench_passes_over_a_pty_number_a_station_still_holds(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """CI finding: a station whose bench died still held its supply's pty path while its
    safe-state pass reconnected by that path; the kernel gave the number to a new bench,
    and the old station commanded the new bench's instrument. A bench now passes over
    every pty number a station holds the lock of (the kernel hands out the lowest free
    number, so without that the bench's first port would be the held one)."""
    from drivers.sim.launcher import launch_bench
    from station.instrument_lock import held_by_a_station

    monkeypatch.setenv("STATION_LOCK_DIR", str(tmp_path))
    master, slave = os.openpty()
    held = os.ttyname(slave)
    lock = InstrumentLock({held: f"DC supply at {held}"}).acquire()
    os.close(master)
    os.close(slave)  # the bench that served it is gone: the number is free again
    try:
        assert held_by_a_station(held)
        with launch_bench(config={"parts": [{"socket": 1, "serial": "SIM-0001"}]}) as bench:
            ports = [bench.endpoints.supply, *bench.endpoints.duts.values()]
            assert all(p.startswith("/dev/pts/") for p in ports), ports
            assert held not in ports, (held, ports)
    finally:
        lock.release()
    assert not held_by_a_station(held)
