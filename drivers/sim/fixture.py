"""One fixture socket in the world: the microcontroller's command set and its sample stream.

Byte-level only (no I/O): `handle_line` answers a command with reply frames, `produce`
returns the sample frames due up to a world time. Wire format: drivers/fixture_protocol.py.
"""

from __future__ import annotations

import math
import re
from dataclasses import fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from drivers import fixture_protocol as fp
from drivers.part_codes import ADIS16130
from drivers.protocols import CalibrationRegisters
from drivers.sim import fixture3
from drivers.sim.cube import Cube
from drivers.sim.gyro import PartModel
from drivers.sim.gyro3 import PartModel3
from drivers.sim.hand import HandFixture

if TYPE_CHECKING:
    from drivers.sim.world import World

# CAL? keys -> CalibrationRegisters fields, in CAL_KEYS order
_CAL_FIELDS = dict(
    zip(
        fp.CAL_KEYS + fp.CAL_KEYS_HIGHER_ORDER,
        [f.name for f in fields(CalibrationRegisters)],
        strict=True,
    )
)
# the higher-order keys a part calibrated to `order` holds (order 2: the two tc2 registers)
_ORDER_KEYS = {
    1: (),
    2: ("bias_tc2", "scale_tc2"),
    3: fp.CAL_KEYS_HIGHER_ORDER,
}
_ERR = fp.ReplyError
# a single-axis part's sample frame fields, in `fp.encode_samples` argument order
SampleFields = tuple[
    NDArray[np.int64],
    NDArray[np.int64],
    NDArray[np.int64],
    NDArray[np.int64],
    NDArray[np.int64],
    "NDArray[np.int64] | None",
]


def _err(code: fp.ReplyError, text: str) -> str:
    return f"ERR {int(code)} {text}"


class FixtureSocket:
    """A socket of the fixture: its microcontroller, and the part loaded in it (if any)."""

    def __init__(
        self,
        world: World,
        socket: int,
        stop_angle_deg: float,
        stop_angle_u_deg: float,
        clock_offset_s: float,
    ) -> None:
        self.world = world
        self.socket = socket
        self.stop_angle_deg = stop_angle_deg
        self.stop_angle_u_deg = stop_angle_u_deg
        self.clock_offset_s = clock_offset_s
        self.air_offset_c = 0.0  # this position's air minus the chamber's (honest physics)
        self.part: PartModel | None = None
        self.odr_hz = 200
        self.streaming = False
        self._t_start = 0.0
        self._next_k = 0
        self._last_angle_deg = 0.0  # table angle at the previous sample (interval start)
        self.seq = 0
        self.frames_sent = 0
        self.frames_overflowed = 0
        self.frames_fault_dropped = 0
        self.bytes_corrupted = 0
        # faults
        self.absent = False
        self.part_silent = False
        self.fixture_silent = False
        self.corrupt_byte_rate = 0.0
        self.drop_frame_rate = 0.0
        self.rng = np.random.default_rng([socket, world.config.seed, 77])
        # the fixture turns by hand between its stops (on top of the table, if any)
        self.hand = HandFixture(world.config.hand, stop_angle_deg, world.config.seed, socket)
        # a three-axis part sits in a cube the operator turns face by face (issue 18)
        self.cube = Cube(world.config.cube, world.config.seed, socket)

    # ------------------------------------------------------------ state

    def part_present(self) -> bool:
        return self.part is not None and not self.absent

    def part_powered(self) -> bool:
        return self.part_present() and self.part is not None and self.part.powered

    def angle_deg(self, t_s: Any) -> Any:
        """The part's angle about its sensitive axis: the table's plus the hand fixture's."""
        return self.world.table.angle_deg(t_s) + self.hand.angle_deg(t_s)

    @property
    def frame_size(self) -> int:
        """Bytes of one sample frame this socket sends (a three-axis part's are longer)."""
        return fp.SAMPLE3_FRAME_SIZE if isinstance(self.part, PartModel3) else fp.SAMPLE_FRAME_SIZE

    def fixture_time_us(self, t_s: float) -> int:
        return int(round((t_s + self.clock_offset_s) * 1e6))

    # ------------------------------------------------------------ commands

    def handle_line(self, line: str, t_s: float) -> bytes:
        """Answer one command line (reply frame), after the samples due before it."""
        if self.fixture_silent:
            return b""
        text = line.strip()
        # STOP answers after the last sample frame
        head = self.produce(t_s) if text.upper() == fp.Command.STOP else b""
        return head + fp.encode_reply(self._answer(text, t_s))

    def _answer(self, text: str, t_s: float) -> str:
        upper = text.upper()
        if not text:
            return _err(_ERR.SYNTAX, "empty command")
        if upper == fp.Command.IDENTIFY:
            return f"OK SIMFIX,GF-100,FX-{self.socket:04d},1.3"
        if upper == fp.Command.PRESENT:
            return f"OK {int(self.part_present())}"
        if upper == fp.Command.STOP_ANGLE:
            return f"OK {self.stop_angle_deg:.4f} {self.stop_angle_u_deg:.4f}"
        if upper == fp.Command.STOP:
            self.streaming = False
            return "OK"
        if upper == fp.Command.STREAM_STATE:  # the stream's state, powered part or not
            return f"OK {int(self.streaming)}"
        part_error = self._part_error()
        three_axis = fixture3.answer(self, text, part_error)  # AXES?, CAL3?, CAL3
        if three_axis is not None:
            return three_axis
        if upper == fp.Command.PART_SERIAL:
            return part_error or f"OK {self.part.params.serial}"  # type: ignore[union-attr]
        if upper.startswith("ODR"):
            return self._odr(text)
        if upper == fp.Command.START:
            if part_error:
                return part_error
            if not self.streaming:
                self.streaming = True
                self._t_start = t_s
                self._next_k = 1
                self._last_angle_deg = float(self.angle_deg(t_s)[0])
                self.seq = 0
            return "OK"
        if upper == fp.Command.CAL_READ:
            if part_error:
                return part_error
            cal = self.part.cal  # type: ignore[union-attr]
            return "OK " + " ".join(f"{k}={getattr(cal, _CAL_FIELDS[k])!r}" for k in self._keys())
        if upper.startswith("CAL "):
            return part_error or self._cal_write(text[4:])
        if upper.startswith("COMP"):
            m = re.fullmatch(r"COMP\s+([01])", upper)
            if not m:
                return _err(_ERR.SYNTAX, "use COMP 0 or COMP 1")
            if part_error:
                return part_error
            self.part.compensation = m.group(1) == "1"  # type: ignore[union-attr]
            return "OK"
        return _err(_ERR.UNKNOWN_COMMAND, f"unknown command {text[:40]!r}")

    def _keys(self) -> tuple[str, ...]:
        """The calibration registers this socket's part holds, in CAL? order."""
        return fp.CAL_KEYS + _ORDER_KEYS[self.world.config.fixture.calibration_order]

    def _part_error(self) -> str | None:
        if not self.part_present():
            return _err(_ERR.NO_PART, "no part in socket")
        if self.part_silent:
            return _err(_ERR.NO_PART, "part not responding")
        if not self.part_powered():
            return _err(_ERR.NOT_POWERED, "part not powered")
        return None

    def _odr(self, text: str) -> str:
        m = re.fullmatch(r"ODR\s+(\d+)", text.strip(), flags=re.IGNORECASE)
        if not m:
            return _err(_ERR.SYNTAX, "use ODR <hz>")
        if self.streaming:
            return _err(_ERR.BUSY_STREAMING, "stop streaming first")
        hz = int(m.group(1))
        if hz not in fp.OUTPUT_RATES_HZ:
            return _err(_ERR.OUT_OF_RANGE, f"rate not supported; use one of {fp.OUTPUT_RATES_HZ}")
        self.odr_hz = hz
        return "OK"

    def _cal_write(self, assignments: str) -> str:
        updates: dict[str, float] = {}
        for item in assignments.split():
            key, sep, value = item.partition("=")
            if not sep:
                return _err(_ERR.SYNTAX, f"expected key=value, got {item[:30]!r}")
            if key.lower() not in self._keys():
                return _err(
                    _ERR.BAD_REGISTER, f"no register {key[:20]!r}; use {','.join(self._keys())}"
                )
            try:
                number = float(value)
            except ValueError:
                return _err(_ERR.SYNTAX, f"{key}: not a number")
            if not math.isfinite(number):
                return _err(_ERR.OUT_OF_RANGE, f"{key}: not finite")
            updates[_CAL_FIELDS[key.lower()]] = number
        if not updates:
            return _err(_ERR.SYNTAX, "no assignments")
        new = replace(self.part.cal, **updates)  # type: ignore[union-attr]
        if not 0.5 < new.scale < 2.0:
            return _err(_ERR.OUT_OF_RANGE, "scale must be between 0.5 and 2")
        self.part.cal = new  # type: ignore[union-attr]
        return "OK"

    # ------------------------------------------------------------ stream

    def produce(self, t_s: float) -> bytes:
        """Sample frames due up to world time `t_s` (empty when not streaming)."""
        times = self.due_times(t_s)
        if times is None:
            return b""
        return self.frames_at(times, self.world.table.angle_deg(times))

    def due_times(self, t_s: float) -> NDArray[np.float64] | None:
        """The world times of the samples due up to `t_s`, taken as due (None: none due).
        `frames_at` must then be called with them: `produce` in two halves, so the bench can
        evaluate the table's angle once for every socket (`World.produce_all`)."""
        if not self.streaming:
            return None
        last_k = math.floor((t_s - self._t_start) * self.odr_hz + 1e-9)
        if last_k < self._next_k:
            return None
        k = np.arange(self._next_k, last_k + 1, dtype=np.int64)
        self._next_k = last_k + 1
        return (self._t_start + k * (1.0 / self.odr_hz)).astype(np.float64)

    def frames_at(self, times: NDArray[np.float64], table_angle: NDArray[np.float64]) -> bytes:
        """The sample frames at `times` (from `due_times`), the table at `table_angle` then."""
        fields_or_frames = self.sample_fields(times, table_angle)
        if isinstance(fields_or_frames, bytes):
            return fields_or_frames
        return self.finish_frames(fp.encode_samples(*fields_or_frames))

    def sample_fields(
        self, times: NDArray[np.float64], table_angle: NDArray[np.float64]
    ) -> SampleFields | bytes:
        """`frames_at` before its encoding: a single-axis part's frame fields (the arguments
        of `fp.encode_samples`; `finish_frames` takes the encoded bytes), or the finished
        frames of anything else (none from a silent part, a three-axis part's). The bench
        encodes every socket's fields in one call (`World.produce_all`)."""
        dt = 1.0 / self.odr_hz
        n = times.size
        # the fixture turned by hand adds its angle (nothing to add until the hand moves it)
        angle = table_angle + self.hand.angle_deg(times) if self.hand.moves else table_angle
        if self.part_silent or not self.part_powered():
            self._last_angle_deg = float(angle[-1])
            return b""  # a silent or unpowered part sends nothing
        part = self.part
        assert part is not None
        supply_v = self.world.supply.output_v()
        # the part's decimation filter averages its rate over the output period, so a sample
        # is the mean rate since the previous one: exactly what two encoder latches give
        start = np.concatenate(([self._last_angle_deg], angle[:-1]))
        rate = (angle - start) / dt
        self._last_angle_deg = float(angle[-1])
        if isinstance(part, PartModel3):  # three-axis frames (drivers/sim/fixture3.py)
            frames3 = fixture3.produce(self, part, times, rate, table_angle, supply_v, dt)
            return self._apply_stream_faults(frames3, fp.SAMPLE3_FRAME_SIZE)
        raw, die = part.raw_output_dps(times, rate, angle, supply_v, dt)
        status = np.zeros(n, dtype=np.int64)
        encoder = None
        if self.world.config.fixture.encoder_input:
            encoder = self.world.table.absolute_counts(table_angle)
            status |= fp.SampleStatus.ENCODER_LATCHED
        out = raw
        if part.compensation:
            out = part.compensate(raw, die, supply_v)
            status |= fp.SampleStatus.COMPENSATED
        rate_code = fp.rate_dps_to_code(out)  # the simulated part's codes are the ADIS16130's
        status[np.abs(out) > fp.RATED_RANGE_DPS] |= fp.SampleStatus.OVER_RANGE
        status[ADIS16130.rate_code_at_rail(rate_code)] |= fp.SampleStatus.SATURATED
        if supply_v < self.world.config.part_physics.supply_low_v:
            status |= fp.SampleStatus.SUPPLY_LOW
        temp_noise = self.rng.normal(0.0, self.world.config.part_physics.temp_noise_c, n)
        seq = self.seq + np.arange(n, dtype=np.int64)
        self.seq += n
        self.frames_sent += n
        return (
            seq,
            np.rint((times + self.clock_offset_s) * 1e6).astype(np.int64),
            rate_code,
            fp.temp_c_to_code(die + temp_noise),
            status,
            encoder,
        )

    def finish_frames(self, frames: bytes) -> bytes:
        """The encoded frames of `sample_fields` as the socket sends them (its stream faults)."""
        return self._apply_stream_faults(frames)

    def _apply_stream_faults(self, frames: bytes, size: int = fp.SAMPLE_FRAME_SIZE) -> bytes:
        if self.drop_frame_rate > 0:
            n = len(frames) // size
            keep = self.rng.random(n) >= self.drop_frame_rate
            self.frames_fault_dropped += int(n - keep.sum())
            arr = np.frombuffer(frames, dtype=np.uint8).reshape(n, size)[keep]
            frames = arr.tobytes()
        if self.corrupt_byte_rate > 0 and frames:
            arr = np.frombuffer(frames, dtype=np.uint8).copy()
            hits = self.rng.random(arr.size) < self.corrupt_byte_rate
            arr[hits] ^= self.rng.integers(1, 256, int(hits.sum()), dtype=np.uint8)
            self.bytes_corrupted += int(hits.sum())
            frames = arr.tobytes()
        return frames

    def truth(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "present": self.part_present(),
            "streaming": self.streaming and self.part_powered() and not self.part_silent,
            "stream_enabled": self.streaming,
            "odr_hz": self.odr_hz,
            "frames_sent": self.frames_sent,
            "frames_dropped": self.frames_overflowed + self.frames_fault_dropped,
            "frames_overflowed": self.frames_overflowed,
            "frames_fault_dropped": self.frames_fault_dropped,
            "bytes_corrupted": self.bytes_corrupted,
            "stop_angle_deg": self.stop_angle_deg,
            "fixture_clock_offset_s": self.clock_offset_s,  # fixture time = world time + this
            "air_offset_c": self.air_offset_c,  # this socket's air = the chamber's + this
            "hand": self.hand.truth(self.world.now_s()),
            "faults": {
                "absent": self.absent,
                "part_silent": self.part_silent,
                "fixture_silent": self.fixture_silent,
                "corrupt_byte_rate": self.corrupt_byte_rate,
                "drop_frame_rate": self.drop_frame_rate,
            },
        }
        if isinstance(self.part, PartModel3):
            out["cube"] = self.cube.truth(self.world.now_s())
        if self.part is not None:
            out.update(self.part.truth())
        else:
            out["serial"] = None
        return out
