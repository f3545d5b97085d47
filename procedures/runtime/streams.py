"""Acquisition: pulling sample blocks from every part link, continuously, into memory and raw.h5.

One background thread reads every streaming `PartLink` (the fixture streams whether or not
the engine is looking, and a blocked serial buffer would lose frames), converts codes to
engineering units (with the product's code format, `ProductConfig.codes`), estimates each
sample's station time, keeps the newest samples in memory for the steps (a fixed number) and
appends everything to the part's raw data file in batches; a window older than memory holds
is read back from that file, so memory does not grow with the run's length or output rate.

Station time of a sample: fixture clock + offset, where the offset is the smallest
(station time at read - fixture time of the newest sample) seen so far; transport latency only
ever makes that difference larger, so the minimum is the best estimate.

Only the acquisition thread touches a link while it streams; other link commands go through
`PartStream.command`, which holds the link's lock.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from common.clock import Clock
from drivers.errors import InstrumentError, PartSilent
from drivers.fixture_protocol import SEQ_MODULO
from drivers.part_codes import ADIS16130, CodeFormat
from drivers.protocols import PartLink, SampleBlock
from procedures.analysis.hysteresis import PlayOperator
from procedures.runtime.rawdata import RawDataWriter
from procedures.runtime.record import StorageError

log = logging.getLogger(__name__)

T = TypeVar("T")
_COLUMNS = (
    "time_s",
    "seq",
    "rate_code",
    "temp_code",
    "status",
    "rate_dps",
    "temp_c",
    "station_time_s",
    "encoder_counts",
)
_DTYPES = {c: np.float64 for c in ("time_s", "rate_dps", "temp_c", "station_time_s")}
# three-axis parts only (in memory; a window of a single-axis part has none of them):
# the decoded x, y, z gyro rates and accelerometer readings, one 1-D column each
XYZ_COLUMNS = (
    "rate_x_dps", "rate_y_dps", "rate_z_dps", "accel_x_mps2", "accel_y_mps2", "accel_z_mps2",
)
# and their wire codes, which raw.h5's /samples_xyz keeps beside the decoded values
XYZ_CODE_COLUMNS = (
    "rate_x_code", "rate_y_code", "rate_z_code", "accel_x_code", "accel_y_code", "accel_z_code",
)
XYZ_GROUP = "samples_xyz"


def _xyz_rows(pending: list[dict[str, NDArray[Any]]]) -> dict[str, NDArray[Any]]:
    """raw.h5's /samples_xyz rows for pending blocks (rows line up with /samples: a block
    without three-axis columns gives NaN values and zero codes)."""
    out: dict[str, list[NDArray[Any]]] = {c: [] for c in (*XYZ_CODE_COLUMNS, *XYZ_COLUMNS)}
    for block in pending:
        n = len(block["time_s"])
        for c in XYZ_CODE_COLUMNS:
            out[c].append(block.get(c, np.zeros(n, dtype=np.int64)))
        for c in XYZ_COLUMNS:
            out[c].append(block.get(c, np.full(n, np.nan)))
    return {c: np.concatenate(v) for c, v in out.items()}
# samples a part gathers before they are appended to raw.h5 (each append costs the same
# few ms of HDF5 bookkeeping whatever its size); at most _FLUSH_WALL_S apart anyway
_FLUSH_SAMPLES = 8192
FIXTURE_WRAP_S = (1 << 32) * 1e-6  # the fixture's u32 microsecond timestamp
_FLUSH_WALL_S = 5.0  # a killed run loses at most this much wall time of samples
# samples kept in memory per part (between this and twice this): 65 s at 1 kHz, 9 MB
KEEP_SAMPLES = 1 << 16
CATCH_UP_WALL_S = 0.5  # lockstep: longest wall wait for an interval's frames
CATCH_UP_WAIT_WALL_S = 0.002  # lockstep: one wait for a socket's frames (woken early)


class _Growable:
    """Columns that grow by doubling, so appends are cheap and slices are views.

    With `keep` set, only about the newest `keep` samples stay (between `keep` and `2 keep`):
    when the buffer would outgrow `2 keep` the newest `keep` move to the front, so memory is
    fixed whatever the run's length and output rate. `dropped` counts the samples let go.
    """

    def __init__(self, keep: int | None = None) -> None:
        self.n = 0
        self.dropped = 0
        self.keep = keep
        self._cap = 0
        self._cols: dict[str, NDArray[Any]] = {}

    def append(self, cols: dict[str, NDArray[Any]]) -> None:
        k = len(next(iter(cols.values())))
        if self.keep is not None and self.n + k > 2 * self.keep:
            self._let_go(max(self.n + k - self.keep, 0))
        if self.n + k > self._cap:
            cap = max(4096, 2 * (self.n + k))
            if self.keep is not None:
                cap = max(cap if cap <= 2 * self.keep else 2 * self.keep, self.n + k)
            for name, values in cols.items():
                new = np.empty(cap, dtype=values.dtype)
                if name in self._cols:
                    new[: self.n] = self._cols[name][: self.n]
                self._cols[name] = new
            self._cap = cap
        for name in cols:
            if name not in self._cols:  # a column that starts late: NaN before it
                self._cols[name] = np.full(self._cap, np.nan, dtype=np.float64)
        for name, values in cols.items():
            self._cols[name][self.n : self.n + k] = values
        self.n += k

    def _let_go(self, count: int) -> None:
        """Drop the oldest `count` samples (all of them when count >= n)."""
        count = min(count, self.n)
        for col in self._cols.values():
            col[: self.n - count] = col[count : self.n]
        self.n -= count
        self.dropped += count

    def column(self, name: str) -> NDArray[Any]:
        if name not in self._cols:
            return np.zeros(0)
        return self._cols[name][: self.n]


class PartStream:
    """One socket's sample stream: in memory, in raw.h5, with its health counters."""

    def __init__(
        self,
        socket: int,
        link: PartLink,
        clock: Clock,
        writer: RawDataWriter | None = None,
        silent_timeout_s: float = 5.0,
        codes: CodeFormat = ADIS16130,
        keep_samples: int = KEEP_SAMPLES,
    ) -> None:
        self.socket = socket
        # how the part's codes read (the product's `codes:`; the run context sets it)
        self.codes = codes
        self.link = link
        self.clock = clock
        self.writer = writer
        self.silent_timeout_s = silent_timeout_s
        self.lock = threading.RLock()
        # with a raw data file only the newest samples stay in memory; older windows are
        # read back from the file (PartStream.window)
        self._data = _Growable(keep_samples if writer is not None else None)
        self._pending: list[dict[str, NDArray[Any]]] = []
        self._pending_n = 0
        self._last_flush = time.monotonic()
        self.offset_s: float | None = None
        self.streaming = False
        self.error: InstrumentError | None = None
        self.frames_ok = 0
        self.frames_lost = 0
        self.frames_corrupted = 0
        self._last_data_station_s = 0.0
        self._wrap_s = 0.0
        self.last_seq: int | None = None  # of the newest frame in (lockstep catch-up)
        self._has_xyz = False  # three-axis frames seen: windows carry XYZ_COLUMNS
        # the part's hysteresis state from every die reading since power-on (set when the
        # product declares its hysteresis; procedures.analysis.hysteresis)
        self.hysteresis: PlayOperator | None = None

    # ------------------------------------------------------------ control (main thread)

    def command(self, fn: Callable[[PartLink], T]) -> T:
        """Run a link command while holding the link (never concurrently with a read)."""
        with self.lock:
            return fn(self.link)

    def start(self) -> None:
        with self.lock:
            self.link.start_stream()
            self.streaming = True
            self._last_data_station_s = self.clock.now_s()

    def stop(self) -> None:
        with self.lock:
            if not self.streaming:
                return
            self.streaming = False
            try:
                self.link.stop_stream()
                self._ingest(self.link.read_samples(0.0))
            finally:
                self.flush()

    # ------------------------------------------------------------ acquisition thread

    def poll(self, wait_wall_s: float = 0.0) -> int:
        """Read what the link has (waiting up to `wait_wall_s` for frames when it has none);
        returns the number of new samples."""
        with self.lock:
            if not self.streaming or self.error is not None:
                return 0
            try:
                block = self.link.read_samples(wait_wall_s)
                n = self._ingest(block)
                now = self.clock.now_s()
                if n:
                    self._last_data_station_s = now
                elif now - self._last_data_station_s > self.silent_timeout_s:
                    raise PartSilent(
                        f"socket {self.socket}: no samples for {self.silent_timeout_s:g} s: "
                        "the part stopped streaming; check its seating and the fixture cable",
                        instrument=f"fixture_{self.socket}",
                    )
            except InstrumentError as exc:
                self.error = exc
                self.streaming = False
                self.flush()
                return 0
            if self._pending_n >= _FLUSH_SAMPLES or (
                self._pending_n and time.monotonic() - self._last_flush > _FLUSH_WALL_S
            ):
                self.flush()
            return n

    def _ingest(self, block: SampleBlock) -> int:
        self.frames_lost += int(block.frames_lost)
        self.frames_corrupted += int(block.frames_corrupted)
        n = len(block)
        if n == 0:
            return 0
        self.frames_ok += n
        self.last_seq = int(block.seq[-1]) % SEQ_MODULO
        time_s = np.asarray(block.time_s, dtype=np.float64) + self._wrap_s
        last = self._data.column("time_s")
        if last.size and time_s[0] < last[-1] - FIXTURE_WRAP_S / 2:
            # the fixture clock wrapped (2^32 us) while the stream was stopped and the link
            # forgot its unwrap state on restart: keep one continuous time base per part
            self._wrap_s += FIXTURE_WRAP_S
            time_s = time_s + FIXTURE_WRAP_S
        now = self.clock.now_s()
        candidate = now - float(time_s[-1])
        if self.offset_s is None or candidate < self.offset_s:
            self.offset_s = candidate
        cols: dict[str, NDArray[Any]] = {
            "time_s": time_s,
            "seq": np.asarray(block.seq, dtype=np.int64),
            "rate_code": np.asarray(block.rate_code, dtype=np.int64),
            "temp_code": np.asarray(block.temp_code, dtype=np.int64),
            "status": np.asarray(block.status, dtype=np.int64),
            "rate_dps": self.codes.rate_code_to_dps(block.rate_code),
            "temp_c": self.codes.temp_code_to_c(block.temp_code),
            "encoder_counts": (
                np.zeros(n, dtype=np.int64)
                if block.encoder_counts is None
                else np.asarray(block.encoder_counts, dtype=np.int64)
            ),
        }
        cols["station_time_s"] = cols["time_s"] + self.offset_s
        if self.hysteresis is not None:
            self.hysteresis.follow(cols["temp_c"])
        xyz = self._xyz_columns(block, n)
        self._data.append({**cols, **{c: xyz[c] for c in XYZ_COLUMNS if c in xyz}})
        self._pending.append({**cols, **xyz})
        self._pending_n += n
        return n

    def _xyz_columns(self, block: SampleBlock, n: int) -> dict[str, NDArray[Any]]:
        """A three-axis block's decoded x, y, z columns; NaN for a single-axis block once
        the stream has had three-axis ones; none for a single-axis stream."""
        rate = getattr(block, "rate_code_xyz", None)
        accel = getattr(block, "accel_code_xyz", None)
        if rate is None or accel is None:
            if not self._has_xyz:
                return {}
            return {**{c: np.full(n, np.nan) for c in XYZ_COLUMNS},
                    **{c: np.zeros(n, dtype=np.int64) for c in XYZ_CODE_COLUMNS}}
        self._has_xyz = True
        rate_codes = np.asarray(rate, dtype=np.int64).reshape(n, 3)
        accel_codes = np.asarray(accel, dtype=np.int64).reshape(n, 3)
        r = self.codes.rate_code_to_dps(rate_codes)
        a = self.codes.accel_code_to_mps2(accel_codes)
        return {**{c: r[:, i] for i, c in enumerate(XYZ_COLUMNS[:3])},
                **{c: a[:, i] for i, c in enumerate(XYZ_COLUMNS[3:])},
                **{c: rate_codes[:, i] for i, c in enumerate(XYZ_CODE_COLUMNS[:3])},
                **{c: accel_codes[:, i] for i, c in enumerate(XYZ_CODE_COLUMNS[3:])}}

    def flush(self) -> None:
        with self.lock:
            if not self._pending or self.writer is None:
                self._pending, self._pending_n = [], 0
                return
            pending = self._pending
            merged = {c: np.concatenate([p[c] for p in pending]) for c in _COLUMNS}
            self._pending, self._pending_n = [], 0
            self._last_flush = time.monotonic()
            try:
                self.writer.append("samples", **merged)
                if self.writer.has_group(XYZ_GROUP):
                    self.writer.append(XYZ_GROUP, **_xyz_rows(pending))
            except StorageError:  # the writer keeps it; the run's next check ends the run
                pass
            except Exception:  # the raw file must never kill the acquisition
                log.exception("socket %d: could not append samples to raw data", self.socket)

    # ------------------------------------------------------------ reading (main thread)

    def fixture_time(self, station_time_s: float) -> float:
        """The fixture-clock time corresponding to a station time."""
        with self.lock:
            if self.offset_s is None:
                raise PartSilent(
                    f"socket {self.socket}: no samples received yet, cannot map times",
                    instrument=f"fixture_{self.socket}",
                )
            return station_time_s - self.offset_s

    def window(self, start_s: float, end_s: float) -> dict[str, NDArray[Any]]:
        """Samples with fixture time in [start_s, end_s) (copies): from memory, or read back
        from the raw data file when the window starts before the samples memory still holds."""
        with self.lock:
            t = self._data.column("time_s")
            if self._data.dropped and self.writer is not None and (not t.size or start_s < t[0]):
                self.flush()
                return self._disk_window(start_s, end_s)
            i0, i1 = np.searchsorted(t, [start_s, end_s], side="left")
            out = {c: self._data.column(c)[i0:i1].copy() for c in _COLUMNS}
            if self._has_xyz:
                out.update({c: self._data.column(c)[i0:i1].copy() for c in XYZ_COLUMNS})
            return out

    def _disk_window(self, start_s: float, end_s: float) -> dict[str, NDArray[Any]]:
        """A window read back from raw.h5 (the three-axis columns from /samples_xyz's rows
        that line up with /samples')."""
        assert self.writer is not None
        disk = self.writer.read_window("samples", "time_s", start_s, end_s)
        out = {c: np.asarray(disk[c], dtype=_DTYPES.get(c, np.int64)) for c in _COLUMNS}
        if self._has_xyz and self.writer.has_group(XYZ_GROUP):
            i0 = self.writer.row_of("samples", "time_s", start_s)
            rows = self.writer.read_rows(XYZ_GROUP, i0, i0 + len(out["time_s"]))
            out.update({c: np.asarray(rows[c], dtype=np.float64) for c in XYZ_COLUMNS})
        return out

    def wait_delivered(self, fixture_s: float, wall_s: float) -> None:
        """Wait (wall time, at most `wall_s`) until the stream holds its samples up to fixture
        time `fixture_s`: they reach the station a little after they are taken. In lockstep
        they are in already (the clock's step waited for them)."""
        if getattr(self.clock, "lockstep", False):
            return
        deadline = time.monotonic() + wall_s
        while time.monotonic() < deadline and self.streaming and self.error is None:
            last = self.last_time_s()
            if last is not None and last >= fixture_s:
                return
            time.sleep(0.005)

    def last_time_s(self) -> float | None:
        with self.lock:
            t = self._data.column("time_s")
            return float(t[-1]) if t.size else None

    @property
    def n_samples(self) -> int:
        return self._data.n


class Acquisition:
    """The background thread that keeps every streaming part drained."""

    def __init__(self, streams: dict[int, PartStream], poll_wall_s: float = 0.005) -> None:
        self.streams = streams
        self.poll_wall_s = poll_wall_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self) -> Acquisition:
        for clock in self._lockstep_clocks():
            clock.add_waiter(self.catch_up)
        self._thread = threading.Thread(target=self._run, name="acquisition", daemon=True)
        self._thread.start()
        return self

    def _lockstep_clocks(self) -> list[Any]:
        clocks = {id(s.clock): s.clock for s in self.streams.values()}
        return [c for c in clocks.values() if hasattr(c, "add_waiter")]

    def catch_up(self, t_s: float, reply: Mapping[str, Any]) -> None:
        """Lockstep: after the bench advanced to `t_s`, wait (wall time, bounded) until every
        stream holds the last frame its fixture sent (`reply["seq"]`), so a step that goes on
        sees the whole interval. A frame lost on the way ends the wait at the bound."""
        sent = reply.get("seq") or {}
        waiting = [s for s in self.streams.values() if str(s.socket) in sent]
        deadline = time.monotonic() + CATCH_UP_WALL_S
        wait_s = 0.0
        while waiting:
            # the first socket still behind waits for its frames (woken as they come, not
            # after a fixed sleep); the others take what they have
            for i, stream in enumerate(waiting):
                stream.poll(wait_s if i == 0 else 0.0)
            waiting = [
                s
                for s in waiting
                if s.streaming and s.error is None and s.last_seq != int(sent[str(s.socket)])
            ]
            if waiting and time.monotonic() > deadline:
                log.debug("lockstep at %.3f s: sockets %s did not catch up", t_s, waiting)
                return
            wait_s = CATCH_UP_WAIT_WALL_S

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _run(self) -> None:
        # in lockstep every clock step catches up itself (catch_up): this thread only drains
        # what arrives between steps, so it need not look as often
        idle_s = self.poll_wall_s * (10 if self._lockstep_clocks() else 1)
        while not self._stop.is_set():
            got = 0
            for stream in list(self.streams.values()):
                got += stream.poll()
            if not got:
                self._stop.wait(idle_s)

    def close(self) -> None:
        for clock in self._lockstep_clocks():
            clock.remove_waiter(self.catch_up)
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for stream in self.streams.values():
            try:
                stream.stop()
            except Exception as exc:  # the link may be gone; the data in memory is kept
                log.warning("socket %d: stop stream failed: %s", stream.socket, exc)
            stream.flush()
