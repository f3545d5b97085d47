"""The part's link: the fixture microcontroller of one socket, on its own serial port.

Wire format and command set: `drivers.fixture_protocol`. A background thread reads the port
and feeds one `FrameParser`; sample frames pile up for `read_samples`, reply frames go to
the command that is waiting for them (one command at a time, with a wall-clock timeout).
While streaming, a part that sends nothing for `silent_after_s` of station time makes
`read_samples` raise `PartSilent`; a fixture that does not answer a command raises
`NoReply` (a `PartAbsent` and an `InstrumentTimeout`).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import math
import queue
import threading
import time
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from common.clock import Clock, ScaledClock
from drivers.errors import (
    ConnectionLost,
    InstrumentError,
    InstrumentTimeout,
    PartAbsent,
    PartSilent,
    ProtocolError,
    StreamCorrupted,
)
from drivers.fixture_protocol import (
    CAL3_FIELDS,
    CAL3_SIZES,
    CAL_KEYS,
    CAL_KEYS_HIGHER_ORDER,
    OUTPUT_RATES_HZ,
    Command,
    FrameParser,
    ReplyError,
)
from drivers.protocols import (
    CalibrationRegisters,
    CalibrationRegisters3,
    InstrumentIdentity,
    LinkStats,
    SafeReadback,
    SampleBlock,
)
from drivers.scpi import SerialLike, open_serial

log = logging.getLogger(__name__)

# CAL? keys and the CalibrationRegisters field each one fills
CAL_FIELDS = {
    "bias": "bias_dps",
    "scale": "scale",
    "bias_tc": "bias_tc_dps_per_c",
    "scale_tc": "scale_tc_per_c",
    "bias_vc": "bias_vc_dps_per_v",
    "scale_vc": "scale_vc_per_v",
    "t0": "t0_c",
    "v0": "v0_v",
}
assert tuple(CAL_FIELDS) == CAL_KEYS
# registers beyond first order in temperature: optional in CAL? (a part without them lists
# only the eight, and they read as 0); written only when non-zero or the part holds them
CAL_FIELDS_HIGHER_ORDER = {
    "bias_tc2": "bias_tc2_dps_per_c2",
    "bias_tc3": "bias_tc3_dps_per_c3",
    "scale_tc2": "scale_tc2_per_c2",
    "scale_tc3": "scale_tc3_per_c3",
}
assert tuple(CAL_FIELDS_HIGHER_ORDER) == CAL_KEYS_HIGHER_ORDER
# CAL3 write lines: each under the fixture's 250-character line limit at 9 significant digits
_CAL3_WRITE_GROUPS = (("bias", "bias_tc", "bias_vc", "t0", "v0"), ("matrix",), ("gsens",),
                      ("scale_tc", "scale_vc"))
# The reader pauses between reads so frames arrive in batches (the parser's cost is mostly
# per call). A pty buffers only about 4 KB, so the pause is sized from the measured byte
# rate to let no more than _PAUSE_FILL_BYTES pile up: at 100k frames/s (2.5 MB/s of 25-byte
# frames) a fixed 5 ms pause would hold the fixture back to about 33k frames/s.
_PAUSE_FILL_BYTES = 1024
_RATE_WINDOW_S = 0.05


def _pause_for(rate_bytes_per_s: float, longest_s: float) -> float:
    return min(longest_s, _PAUSE_FILL_BYTES / max(rate_bytes_per_s, 1.0))

_LOCKSTEP_READ_TIMEOUT_S = 0.2
_CAL_TOLERANCE_REL = 1e-5
_CAL_TOLERANCE_ABS = 1e-9


def _port_errors() -> tuple[type[BaseException], ...]:
    """What a serial port raises when the device goes away: OSError (pyserial's
    SerialException is one) and, from the tty layer, termios.error (which is not)."""
    try:
        import termios
    except ImportError:  # not a POSIX system: no tty layer
        return (OSError,)
    return (OSError, termios.error)


_PORT_ERRORS = _port_errors()
_OPEN_ERRORS: tuple[type[BaseException], ...] = (*_PORT_ERRORS, ValueError)  # pyserial open


def port_error_reason(exc: BaseException) -> str:
    """A serial port error as a reason for an operator: its text, with the OS error's name."""
    number, text = getattr(exc, "errno", None), getattr(exc, "strerror", None)
    if not isinstance(exc, OSError) and len(exc.args) == 2:  # termios.error(errno, text)
        number, text = exc.args
    if isinstance(number, int) and text:
        return f"{text} [{errno_name(number)}]"
    return str(exc) or type(exc).__name__


def errno_name(number: int) -> str:
    return errno.errorcode.get(number, f"errno {number}")


class NoReply(PartAbsent, InstrumentTimeout):
    """The fixture did not answer a command at all."""


class FixtureRefused(InstrumentError):  # noqa: N818 - named like drivers.errors
    """The fixture answered a command with ERR <code> <text>."""

    def __init__(self, message: str, *, code: int, instrument: str | None = None) -> None:
        super().__init__(message, instrument=instrument)
        self.code = code


class _Pending:
    """Samples decoded since the last read_samples, plus counters (guarded by the link's lock)."""

    def __init__(self) -> None:
        self.chunks: list[tuple[np.ndarray, ...]] = []
        self.xyz_chunks: list[tuple[np.ndarray, np.ndarray]] = []  # three-axis frames
        self.lost = self.corrupted = self.discarded = 0


class SerialPartLink:
    """`drivers.protocols.PartLink` for one fixture socket.

    Args:
        port: an open serial port (pyserial `Serial` with a short read timeout).
        clock: the station clock (silence is judged in station seconds).
        socket: the fixture socket's name, for messages.
        reply_timeout_s: wall seconds a command waits for its reply.
        silent_after_s: station seconds without a frame, while streaming, before PartSilent.
        loss_limit: more frames lost than this since start_stream makes read_samples raise
            StreamCorrupted (None: never; the counts are in each SampleBlock either way).
        batch_s: wall seconds the reader pauses after a small read so frames arrive in
            batches (keeps the per-frame cost low at high rates).
    """

    def __init__(
        self,
        port: SerialLike,
        clock: Clock,
        *,
        socket: str | int = 1,
        reply_timeout_s: float = 1.0,
        silent_after_s: float = 2.0,
        loss_limit: int | None = None,
        batch_s: float = 0.005,
    ) -> None:
        self._port = port
        self._clock = clock
        self.name = f"fixture on socket {socket}"
        self.reply_timeout_s = reply_timeout_s
        self.silent_after_s = silent_after_s
        self.loss_limit = loss_limit
        self._batch_s = batch_s
        self._parser = FrameParser()
        self._lock = threading.Lock()
        self._command_lock = threading.Lock()
        self._replies: queue.Queue[str] = queue.Queue()
        self._data = threading.Event()
        self._pending = _Pending()
        self._totals = LinkStats()
        self._reset_seq = False
        self._streaming = False
        self._last_frame_s = clock.now_s()
        self._reader_error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read_loop, name=self.name, daemon=True)
        self._thread.start()

    @classmethod
    def open(
        cls, path: str, clock: Clock, *, baudrate: int = 115200, **kwargs: Any
    ) -> SerialPartLink:
        """Open the fixture's serial port at `baudrate` (the fixture's configured rate; see
        `drivers.fixture_protocol.sample_stream_baud` for what an output rate needs)."""
        try:
            port = open_serial(path, baudrate=baudrate, read_timeout_s=0.02)
        except _OPEN_ERRORS as exc:  # pyserial lets termios.error and ValueError through
            raise ConnectionLost(
                f"cannot open the fixture's serial port {path} at {baudrate} baud "
                f"({port_error_reason(exc)}): check the port name and that the port supports "
                "that baud rate",
            ) from exc
        return cls(port, clock, **kwargs)

    def attach_clock(self, clock: Clock) -> None:
        """Judge silence in station time on `clock` from now on."""
        with self._lock:
            self._clock = clock
            self._last_frame_s = clock.now_s()
        if getattr(clock, "lockstep", False) and hasattr(self._port, "timeout"):
            # in lockstep frames come only when the station's clock steps: an idle reader
            # need not wake every 20 ms (32 of them cost more CPU than the streams)
            self._port.timeout = _LOCKSTEP_READ_TIMEOUT_S

    def probe(self) -> str:
        """'' when the fixture answers its identity query (its port is open and it talks)."""
        self.identify()
        return ""

    # ------------------------------------------------------------ reader thread

    def _read_loop(self) -> None:
        port = self._port
        window_t0 = time.monotonic()
        window_bytes = 0
        pause_s = self._batch_s
        try:
            while not self._stop.is_set():
                waiting = port.in_waiting
                data = port.read(waiting or 1)
                if not data:
                    continue
                if not waiting:
                    more = port.in_waiting
                    if more:
                        data += port.read(more)
                self._consume(data)
                window_bytes += len(data)
                now = time.monotonic()
                if now - window_t0 >= _RATE_WINDOW_S:
                    pause_s = _pause_for(window_bytes / (now - window_t0), self._batch_s)
                    window_t0, window_bytes = now, 0
                # in lockstep the bench sends an interval's frames at once and waits for the
                # station to read them: a pause would only delay the station's next step
                lockstep = getattr(self._clock, "lockstep", False)
                if pause_s > 0 and len(data) < _PAUSE_FILL_BYTES and not lockstep:
                    time.sleep(pause_s)
        except Exception as exc:  # noqa: BLE001 - reported to the caller by _check_reader
            if not self._stop.is_set():
                log.error("%s: reader stopped: %s", self.name, exc)
                self._reader_error = exc
                self._data.set()

    def _consume(self, data: bytes) -> None:
        if self._reset_seq:
            self._parser.reset_sequence()
            self._reset_seq = False
        result = self._parser.feed(data)
        with self._lock:
            p = self._pending
            if result.seq.size:
                p.chunks.append(
                    (
                        result.seq,
                        result.time_s,
                        result.rate_code,
                        result.temp_code,
                        result.status,
                        result.encoder,
                    )
                )
                if result.rate_code_xyz is not None and result.accel_code_xyz is not None:
                    p.xyz_chunks.append((result.rate_code_xyz, result.accel_code_xyz))
                self._last_frame_s = self._clock.now_s()
            p.lost += result.frames_lost
            p.corrupted += result.frames_corrupted
            p.discarded += result.bytes_discarded
        for reply in result.replies:
            self._replies.put(reply)
        if result.seq.size:
            self._data.set()

    def _check_reader(self) -> None:
        if self._reader_error is not None:
            raise ConnectionLost(
                f"the serial port of the {self.name} failed "
                f"({port_error_reason(self._reader_error)}): check the fixture's cable, then "
                "reconnect",
                instrument=self.name,
            ) from self._reader_error

    # ------------------------------------------------------------ commands

    def command(self, text: str) -> str:
        """Send one command line; return the data after OK, raise on ERR or no reply."""
        with self._command_lock:
            self._check_reader()
            while not self._replies.empty():  # a late reply to an earlier command
                log.warning("%s: discarding stale reply %r", self.name, self._replies.get_nowait())
            try:
                self._port.write(text.encode("ascii") + b"\n")
            except Exception as exc:  # noqa: BLE001 - pyserial raises several types
                raise ConnectionLost(
                    f"cannot write to the {self.name} ({port_error_reason(exc)}): check its "
                    "cable",
                    instrument=self.name,
                ) from exc
            try:
                reply = self._replies.get(timeout=self.reply_timeout_s)
            except queue.Empty:
                self._check_reader()
                raise NoReply(
                    f"the {self.name} did not answer {text!r} within {self.reply_timeout_s:g} s: "
                    "check that the fixture is powered and its cable is in, and that a part "
                    "is seated in the socket",
                    instrument=self.name,
                ) from None
        return self._parse_reply(text, reply)

    def _parse_reply(self, text: str, reply: str) -> str:
        if reply == "OK" or reply.startswith("OK "):
            return reply[3:]
        if reply.startswith("ERR"):
            parts = reply.split(" ", 2)
            try:
                code = int(parts[1])
            except (IndexError, ValueError):
                code = -1
            detail = parts[2] if len(parts) > 2 else ""
            if code == ReplyError.NO_PART:
                raise PartAbsent(
                    f"no part in the {self.name} ({detail}): seat a part and retry",
                    instrument=self.name,
                )
            advice: str = {
                int(ReplyError.NOT_POWERED): "switch the supply output on first",
                int(ReplyError.BUSY_STREAMING): "stop streaming first",
                int(ReplyError.OUT_OF_RANGE): "use a supported value",
            }.get(code, "check the command against drivers/fixture_protocol.py")
            raise FixtureRefused(
                f"the {self.name} refused {text!r}: ERR {code} {detail}; {advice}",
                code=code,
                instrument=self.name,
            )
        raise ProtocolError(
            f"the {self.name} answered {text!r} with {reply!r}, neither OK nor ERR",
            instrument=self.name,
        )

    def identify(self) -> InstrumentIdentity:
        reply = self.command(Command.IDENTIFY)
        parts = [p.strip() for p in reply.split(",")]
        if len(parts) != 4:
            raise ProtocolError(
                f"the {self.name} identified as {reply!r}, not 'maker,model,serial,firmware'",
                instrument=self.name,
            )
        return InstrumentIdentity(*parts)

    def part_present(self) -> bool:
        reply = self.command(Command.PRESENT).strip()
        if reply not in ("0", "1"):
            raise ProtocolError(f"PRESENT? answered {reply!r}, not 0 or 1", instrument=self.name)
        return reply == "1"

    def read_part_serial(self) -> str:
        serial = self.command(Command.PART_SERIAL).strip()
        if not serial:
            raise ProtocolError(
                f"the part in the {self.name} gave an empty serial number", instrument=self.name
            )
        return serial

    def set_output_rate(self, rate_hz: int) -> None:
        if rate_hz not in OUTPUT_RATES_HZ:
            raise ValueError(f"output data rate {rate_hz} Hz is not one of {OUTPUT_RATES_HZ}")
        self.command(Command.OUTPUT_RATE.format(hz=rate_hz))

    def set_compensation(self, enabled: bool) -> None:
        self.command(Command.COMPENSATION.format(on=int(bool(enabled))))

    def stop_angle(self) -> tuple[float, float]:
        reply = self.command(Command.STOP_ANGLE).split()
        try:
            angle, sigma = float(reply[0]), float(reply[1])
        except (IndexError, ValueError):
            raise ProtocolError(
                f"STOPANGLE? answered {' '.join(reply)!r}, not '<angle_deg> <uncertainty_deg>'",
                instrument=self.name,
            ) from None
        return angle, sigma

    # ------------------------------------------------------------ calibration registers

    def read_calibration(self) -> CalibrationRegisters:
        """The part's registers; higher-order ones it does not list read as 0."""
        regs, _ = self._read_calibration()
        return regs

    def _read_calibration(self) -> tuple[CalibrationRegisters, set[str]]:
        """(registers, the higher-order CAL? keys the part listed)."""
        reply = self.command(Command.CAL_READ)
        values: dict[str, float] = {}
        fields = {**CAL_FIELDS, **CAL_FIELDS_HIGHER_ORDER}
        for item in reply.split():
            key, sep, value = item.partition("=")
            if not sep or key not in fields:
                continue
            try:
                values[fields[key]] = float(value)
            except ValueError:
                raise ProtocolError(
                    f"CAL? gave {item!r}, not a number: {reply!r}", instrument=self.name
                ) from None
        missing = [k for k, f in CAL_FIELDS.items() if f not in values]
        if missing:
            raise ProtocolError(
                f"CAL? answered {reply!r}, missing {', '.join(missing)}", instrument=self.name
            )
        listed = {k for k in CAL_FIELDS_HIGHER_ORDER if f" {k}=" in f" {reply}"}
        return CalibrationRegisters(**values), listed

    def write_calibration(self, registers: CalibrationRegisters) -> None:
        """Write the calibration registers, then read them back and compare.

        The eight first-order registers always; a higher-order one when it is not 0 (a part
        without it refuses the write: ERR 4). A part that still holds a non-zero higher-order
        register the new calibration leaves at 0 gets it cleared by a second write."""
        wanted = {k: float(getattr(registers, f)) for k, f in CAL_FIELDS.items()}
        higher = {k: float(getattr(registers, f)) for k, f in CAL_FIELDS_HIGHER_ORDER.items()}
        bad = [k for k, v in (wanted | higher).items() if not math.isfinite(v)]
        if bad:
            raise ValueError(f"calibration values must be finite: {', '.join(bad)}")
        wanted.update({k: v for k, v in higher.items() if v != 0.0})
        self._cal_write(wanted)
        back, listed = self._read_calibration()
        stale = {
            k: 0.0
            for k in listed - set(wanted)
            if getattr(back, CAL_FIELDS_HIGHER_ORDER[k]) != 0.0
        }
        if stale:
            self._cal_write(stale)
            back, _ = self._read_calibration()
            wanted.update(stale)
        fields = {**CAL_FIELDS, **CAL_FIELDS_HIGHER_ORDER}
        diffs = [
            f"{k} wrote {v:.9g} read {getattr(back, fields[k]):.9g}"
            for k, v in wanted.items()
            if not math.isclose(
                getattr(back, fields[k]), v, rel_tol=_CAL_TOLERANCE_REL, abs_tol=_CAL_TOLERANCE_ABS
            )
        ]
        if diffs:
            raise InstrumentError(
                f"the part in the {self.name} did not keep its calibration ({'; '.join(diffs)}): "
                "the write failed; retry once, then reject the part",
                instrument=self.name,
            )

    def _cal_write(self, values: dict[str, float]) -> None:
        assignments = " ".join(f"{k}={v:.9g}" for k, v in values.items())
        try:
            self.command(Command.CAL_WRITE.format(assignments=assignments))
        except FixtureRefused as exc:
            higher = [k for k in values if k in CAL_FIELDS_HIGHER_ORDER]
            if exc.code != ReplyError.BAD_REGISTER or not higher:
                raise
            raise FixtureRefused(
                f"the part in the {self.name} has no register for {', '.join(higher)} (ERR 4): "
                "it cannot hold a temperature fit beyond first order; list only the orders it "
                "holds in the product file's calibration.fit_orders",
                code=exc.code,
                instrument=self.name,
            ) from None

    # ------------------------------------------------------------ three-axis parts

    def axes(self) -> int:
        """The part's rate axes, 1 or 3 (`AXES?`; a fixture whose firmware does not know the
        command has single-axis parts: 1)."""
        try:
            reply = self.command(Command.AXES).strip()
        except FixtureRefused as exc:
            if exc.code == ReplyError.UNKNOWN_COMMAND:
                return 1
            raise
        if reply not in ("1", "3"):
            raise ProtocolError(f"AXES? answered {reply!r}, not 1 or 3", instrument=self.name)
        return int(reply)

    def read_calibration3(self) -> CalibrationRegisters3:
        """A three-axis part's registers (one `CAL3? <key>` each)."""
        values: dict[str, object] = {}
        for key, size in CAL3_SIZES.items():
            numbers = self._cal3_read(key, size)
            values[CAL3_FIELDS[key]] = (
                numbers[0] if size == 1 else np.reshape(numbers, (3, 3)) if size == 9 else numbers
            )
        return CalibrationRegisters3(**values)  # type: ignore[arg-type]

    def _cal3_command(self, command: str) -> str:
        """A CAL3 command; a part without three-axis registers (ERR 4, or ERR 2 from older
        fixture firmware) is reported as what it is."""
        try:
            return self.command(command)
        except FixtureRefused as exc:
            if exc.code not in (ReplyError.BAD_REGISTER, ReplyError.UNKNOWN_COMMAND):
                raise
            raise FixtureRefused(
                f"the part in the {self.name} has no three-axis registers ({exc}): it is not "
                "a three-axis part (check the product file's axes and the part seated)",
                code=exc.code,
                instrument=self.name,
            ) from None

    def _cal3_read(self, key: str, size: int) -> list[float]:
        command = Command.CAL3_READ.format(key=key)
        reply = self._cal3_command(command).strip()
        name, sep, text = reply.partition("=")
        try:
            numbers = [float(v) for v in text.split(",")] if sep and name == key else []
        except ValueError:
            numbers = []
        if len(numbers) != size or not all(math.isfinite(v) for v in numbers):
            raise ProtocolError(
                f"{command!r} answered {reply!r}, not '{key}=' and {size} finite numbers",
                instrument=self.name,
            )
        return numbers

    def write_calibration3(self, registers: CalibrationRegisters3) -> None:
        """Write a three-axis part's registers (a few `CAL3` lines), read them back, compare."""
        wanted = {key: _flat(getattr(registers, f)) for key, f in CAL3_FIELDS.items()}
        bad = [k for k, v in wanted.items() if not all(math.isfinite(x) for x in v)]
        if bad:
            raise ValueError(f"calibration values must be finite: {', '.join(bad)}")
        for group in _CAL3_WRITE_GROUPS:
            assignments = " ".join(
                f"{k}=" + ",".join(f"{v:.9g}" for v in wanted[k]) for k in group
            )
            self._cal3_command(Command.CAL3_WRITE.format(assignments=assignments))
        back = self.read_calibration3()
        diffs = []
        for key, field_name in CAL3_FIELDS.items():
            got = _flat(getattr(back, field_name))
            for i, (w, g) in enumerate(zip(wanted[key], got, strict=True)):
                if not math.isclose(g, w, rel_tol=_CAL_TOLERANCE_REL, abs_tol=_CAL_TOLERANCE_ABS):
                    diffs.append(f"{key}[{i}] wrote {w:.9g} read {g:.9g}")
        if diffs:
            raise InstrumentError(
                f"the part in the {self.name} did not keep its calibration ({'; '.join(diffs)}): "
                "the write failed; retry once, then reject the part",
                instrument=self.name,
            )

    # ------------------------------------------------------------ streaming

    def start_stream(self) -> None:
        with self._lock:
            self._pending = _Pending()
            self._totals = LinkStats()
            self._last_frame_s = self._clock.now_s()
            self._reset_seq = True
        self._data.clear()
        self.command(Command.START)
        with self._lock:
            self._streaming = True
            self._last_frame_s = self._clock.now_s()

    def stop_stream(self) -> None:
        """STOP whatever this link believes (a stream another process started is stopped too:
        STOP while stopped answers OK)."""
        self._streaming = False
        self.command(Command.STOP)

    def check_stream_stopped(self) -> SafeReadback:
        """The fixture's own stream state (`STREAM?`). Firmware that does not know the query
        (ERR 2) is asked `STOP` again: its OK says that no sample frame follows."""
        try:
            reply = self.command(Command.STREAM_STATE).strip()
        except FixtureRefused as exc:
            if exc.code != ReplyError.UNKNOWN_COMMAND:
                raise
            self.command(Command.STOP)
            return SafeReadback(True, "STOP answered OK (this fixture cannot report its stream)")
        if reply not in ("0", "1"):
            raise ProtocolError(f"STREAM? answered {reply!r}, not 0 or 1", instrument=self.name)
        if reply == "1":
            return SafeReadback(False, "the fixture reports its stream still started (STREAM? 1)")
        return SafeReadback(True, "stream stopped (STREAM? 0)")

    def _take(self) -> SampleBlock:
        with self._lock:
            p = self._pending
            self._pending = _Pending()
            self._data.clear()
            block = self._block(p)
            t = self._totals
            self._totals = LinkStats(
                frames_ok=t.frames_ok + len(block),
                frames_lost=t.frames_lost + block.frames_lost,
                frames_corrupted=t.frames_corrupted + block.frames_corrupted,
                bytes_discarded=t.bytes_discarded + block.bytes_discarded,
            )
        return block

    @staticmethod
    def _block(p: _Pending) -> SampleBlock:
        if not p.chunks:
            empty_i = np.zeros(0, dtype=np.int64)
            block = SampleBlock(empty_i, np.zeros(0), empty_i, empty_i, empty_i,
                                p.lost, p.corrupted, p.discarded)
        else:
            cols = [np.concatenate(c) if len(c) > 1 else c[0] for c in zip(*p.chunks, strict=True)]
            block = SampleBlock(cols[0], cols[1], cols[2], cols[3], cols[4], frames_lost=p.lost,
                                frames_corrupted=p.corrupted, bytes_discarded=p.discarded,
                                encoder_counts=cols[5], **_xyz_columns(p, cols[0].size))
        return block

    def read_samples(self, max_wait_s: float = 0.0) -> SampleBlock:
        self._check_reader()
        if max_wait_s > 0 and not self._data.is_set():
            self._data.wait(max_wait_s)
            self._check_reader()
        block = self._take()
        if self.loss_limit is not None and self._totals.frames_lost > self.loss_limit:
            t = self._totals
            raise StreamCorrupted(
                f"the {self.name} lost {t.frames_lost} frames ({t.frames_corrupted} corrupted, "
                f"{t.bytes_discarded} bytes discarded) since streaming started, more than the "
                f"{self.loss_limit} allowed: check the fixture cable and its grounding",
                instrument=self.name,
            )
        if self._streaming and not len(block):
            silent_s = self._clock.now_s() - self._last_frame_s
            if silent_s > self.silent_after_s:
                raise PartSilent(
                    f"the part in the {self.name} stopped sending frames {silent_s:.1f} s ago "
                    f"while streaming: check its supply and seating; the run cannot continue "
                    "with this part",
                    instrument=self.name,
                )
        return block

    def stats(self) -> LinkStats:
        with self._lock:
            p = self._pending
            pending_ok = sum(c[0].size for c in p.chunks)
            t = self._totals
            return LinkStats(
                frames_ok=t.frames_ok + pending_ok,
                frames_lost=t.frames_lost + p.lost,
                frames_corrupted=t.frames_corrupted + p.corrupted,
                bytes_discarded=t.bytes_discarded + p.discarded,
            )

    def close(self) -> None:
        self._stop.set()
        cancel = getattr(self._port, "cancel_read", None)
        if cancel is not None:
            with contextlib.suppress(Exception):  # best effort on the way out
                cancel()
        self._thread.join(1.0)
        try:
            self._port.close()
        except OSError as exc:
            log.warning("closing the %s: %s", self.name, exc)


def _flat(value: object) -> list[float]:
    """A register's values as CAL3 lists them: a number, a vector, a matrix row-major."""
    return [float(v) for v in np.ravel(np.asarray(value, dtype=np.float64))]


def _xyz_columns(p: _Pending, n: int) -> dict[str, np.ndarray]:
    """The block's three-axis columns when every frame in it was a three-axis one."""
    if not p.xyz_chunks or sum(c[0].shape[0] for c in p.xyz_chunks) != n:
        return {}
    rate = [c[0] for c in p.xyz_chunks]
    accel = [c[1] for c in p.xyz_chunks]
    return {
        "rate_code_xyz": rate[0] if len(rate) == 1 else np.concatenate(rate),
        "accel_code_xyz": accel[0] if len(accel) == 1 else np.concatenate(accel),
    }


# ---------------------------------------------------------------- configuration (part.fixture)


class Settings(BaseModel):
    """One socket's `part.fixture` link: station.yaml `instruments.fixture` (its baud and
    timeout_s) with the socket's serial port from `ports` as `address` and its number as
    `socket` (the station fills both). Silence is judged after the procedure's
    stream.silent_timeout_s: the station sets `silent_after_s` on the link."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    address: str = Field(min_length=1, description="serial device of the socket's fixture")
    socket: int = Field(1, ge=1, le=64, description="fixture socket number (for messages)")
    baud: int = Field(115200, gt=0, le=10_000_000, description="serial baud rate")
    timeout_s: float = Field(1.0, gt=0, le=60, description="wall seconds a command waits")


def factory(settings: dict[str, Any]) -> SerialPartLink:
    """Validate `settings` (ValidationError propagates), open the port, return the link."""
    s = Settings.model_validate(settings)
    return SerialPartLink.open(
        s.address,
        ScaledClock(1.0),
        baudrate=s.baud,
        socket=s.socket,
        reply_timeout_s=s.timeout_s,
        loss_limit=None,  # the engine judges loss against the procedure's fraction
    )
