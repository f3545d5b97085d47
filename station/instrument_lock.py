"""One station process at a time per instrument: an OS file lock on each instrument's address.

A run holds an exclusive `flock` on one lock file per address it will drive (the rate table,
chamber, supply and inclinometer addresses and every fixture port, all as the run resolves
them: station.yaml's, or the simulated bench's endpoints with `--sim`). A second process that
would drive any of them is refused before it recovers, opens or commands anything, in one
line naming the instrument and the process that holds it. The kernel drops the lock when
the holding process ends however it ends (kill -9 included), so a crashed station never
leaves a stale lock behind; the lock files themselves stay (an empty file is not a lock).

The files live in `lock_dir()`: $STATION_LOCK_DIR, else /run/lock/gyro-station when /run/lock
is writable, else the temporary directory's gyro-station-locks. Every station on one machine
must use the same folder, which is why it is not a station.yaml setting. Two addresses are
the same instrument when their text is the same (device paths resolved through symlinks, so
/dev/serial/by-id/... and /dev/ttyUSB0 are one port).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import fcntl
import hashlib
import os
import sys
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path
from types import TracebackType

from station.errors import UserError

LOCK_DIR_ENV = "STATION_LOCK_DIR"


class InstrumentsBusy(UserError):
    """Another process holds an instrument this run would drive (one line; exit 2)."""


def lock_dir() -> Path:
    """The machine's folder of instrument lock files (see the module docstring)."""
    given = os.environ.get(LOCK_DIR_ENV)
    if given:
        return Path(given)
    run_lock = Path("/run/lock")
    if run_lock.is_dir() and os.access(run_lock, os.W_OK):
        return run_lock / "gyro-station"
    return Path(tempfile.gettempdir()) / "gyro-station-locks"


def same_instrument_key(address: str) -> str:
    """The address as the lock knows it: stripped, a device path resolved."""
    text = address.strip()
    if text.startswith("/"):
        text = os.path.realpath(text)
    return text


def _lock_path(folder: Path, key: str) -> Path:
    digest = hashlib.sha256(key.encode("utf-8")).hexdigest()[:24]
    return folder / f"{digest}.lock"


class InstrumentLock:
    """Exclusive locks on a set of instrument addresses, held until `release()` (or the
    process's end). `instruments` maps each address to the words naming it in a refusal."""

    def __init__(self, instruments: Mapping[str, str], folder: Path | None = None) -> None:
        self.folder = folder or lock_dir()
        self.instruments = {
            same_instrument_key(a): label for a, label in instruments.items() if a.strip()
        }
        self._fds: list[int] = []

    def acquire(self) -> InstrumentLock:
        """Take every lock (sorted, so two stations never each hold half), or none: raise
        InstrumentsBusy naming the first instrument another process holds."""
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            with contextlib.suppress(OSError):  # a shared folder: every station user may lock
                self.folder.chmod(0o1777)
            for key in sorted(self.instruments):
                self._take(key)
        except BaseException:
            self.release()
            raise
        return self

    def _take(self, key: str) -> None:
        path = _lock_path(self.folder, key)
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        except OSError as exc:
            raise UserError(
                f"cannot open the instrument lock {path} ({exc.strerror}): let every station "
                f"user write to {self.folder}, or set {LOCK_DIR_ENV} to a folder they can"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(fd)
            os.close(fd)
            raise InstrumentsBusy(
                f"the {self.instruments[key]} is in use by another station process "
                f"({holder}): wait for its run to end, or stop it; this run was refused and "
                "touched no instrument"
            ) from None
        self._fds.append(fd)
        _write_holder(fd, key)

    def release(self) -> None:
        """Drop every lock this object holds (closing the descriptor drops the flock)."""
        while self._fds:
            with contextlib.suppress(OSError):
                os.close(self._fds.pop())

    def __enter__(self) -> InstrumentLock:
        # lock_instruments() hands out a lock already taken: entering it holds it, no more
        return self if self._fds else self.acquire()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.release()


def held_by_a_station(address: str, folder: Path | None = None) -> bool:
    """Whether a station process holds the lock of `address` now (a probe: nothing is taken).
    The simulated bench asks it of each pseudo-terminal it is given, so it never serves an
    instrument at a port number a station still holds from a bench that died."""
    path = _lock_path(folder or lock_dir(), same_instrument_key(address))
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return False  # no lock file: nobody ever locked it
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)  # closing drops the probe's shared lock
    return False


def _write_holder(fd: int, key: str) -> None:
    """Who holds the lock, for the refusal of the next process (best effort)."""
    started = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    command = " ".join(os.path.basename(a) if i == 0 else a for i, a in enumerate(sys.argv))
    text = f"pid {os.getpid()} since {started} UTC: {command[:200]} [{key}]\n"
    with contextlib.suppress(OSError):
        os.ftruncate(fd, 0)
        os.pwrite(fd, text.encode("utf-8", "replace"), 0)


def _read_holder(fd: int) -> str:
    try:
        text = os.pread(fd, 400, 0).decode("utf-8", "replace").strip()
    except OSError:
        text = ""
    return (text.split(" [", 1)[0] or "process unknown").splitlines()[0][:250]


def lock_instruments(instruments: Iterable[tuple[str, str]]) -> InstrumentLock:
    """Take the locks of (address, label) pairs; see InstrumentLock."""
    return InstrumentLock(dict(instruments)).acquire()
