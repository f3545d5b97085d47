"""Part driver `replay`: a recorded part played back as a live one.

Plays a run folder's raw.h5 (or a CSV of time_s, rate_dps, temp_c[, supply_v]) through the
`drivers.protocols.PartLink` contract, so a recorded part can be put through any procedure
again. In station.yaml, each socket's recording in place of its serial port:

    instruments:
      part:                       # (or fixture:)
        driver: replay
        sockets: 2
        ports: {1: runs/2026-11-20T10-00-00Z_SIM-0001, 2: recordings/part-7.csv}
        loop: false

(`path:` instead names one recording for every socket, and is kept when the simulated bench
gives the part driver its own port.)

Playback: START maps the next unplayed sample to one recorded period after the station's
clock at START; from then on a sample is delivered once the station clock has passed its
recorded time (gaps in the recording are played as silence, as they happened). The samples
keep their recorded fixture times, sequence numbers, codes, status and encoder counts; after
STOP and START again, or a loop back to the start, the fixture times go on from where the
station clock is, as a real fixture's free-running clock would. At the end of the recording
the part goes silent (`RecordingEnded`, a `PartSilent`) unless `loop` is set.

The part's calibration registers live in memory (erased at first); with compensation on, the
part's correction is applied to each played sample as the real part does (the formula of
`drivers.protocols.CalibrationRegisters`), using the recorded die temperature and the
recorded supply voltage (else `supply_v`, else the registers' v0). A sample that was recorded
already compensated is played as recorded.
"""

from __future__ import annotations

import logging
import math
import threading
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

from common.clock import Clock, ScaledClock
from drivers.errors import ConnectionLost, PartSilent
from drivers.fixture_protocol import OUTPUT_RATES_HZ, ReplyError
from drivers.part_codes import CodeFormat
from drivers.part_link import FixtureRefused
from drivers.protocols import (
    CalibrationRegisters,
    InstrumentIdentity,
    LinkStats,
    SafeReadback,
    SampleBlock,
    SampleStatus,
)
from drivers.replay_source import Recording, RecordingError, load_recording

log = logging.getLogger(__name__)

__all__ = ["RecordingEnded", "RecordingError", "ReplayPartLink", "Settings", "factory"]

_SCALE_LIMITS = (0.5, 2.0)  # the part refuses a scale register outside these (as the fixture)
_RATE_MISMATCH_REL = 0.01


class Settings(BaseModel):
    """The `part` role's entry in station.yaml for `driver: replay`."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    address: str = Field(
        "",
        description="the recording of this socket: a run folder (its raw.h5), a raw.h5 file or "
        "a CSV file with columns time_s, rate_dps, temp_c and optionally supply_v (the station "
        "gives each socket's entry of `ports` here)",
    )
    path: str | None = Field(
        None,
        min_length=1,
        description="the recording, overriding `address` (one recording for every socket, "
        "kept also when the simulated bench hands the part driver its own port)",
    )
    timeout_s: float = Field(
        1.0, gt=0, le=3600, description="not used: a replay answers every command at once"
    )
    socket: int = Field(1, ge=1, le=64, description="the fixture socket, for messages")
    loop: bool = Field(False, description="start the recording again when it ends")
    serial: str | None = Field(
        None,
        min_length=1,
        max_length=64,
        description="the part serial the replayed part reports (default: the recording's; "
        "a CSV's default is its file name without .csv)",
    )
    stop_angle_deg: float = Field(
        90.0, gt=10.0, lt=350.0, description="the fixture's angle between its stops, deg"
    )
    stop_angle_uncertainty_deg: float = Field(
        0.01, gt=0.0, le=10.0, description="standard uncertainty of stop_angle_deg, deg"
    )
    supply_v: float | None = Field(
        None,
        gt=0.0,
        le=60.0,
        description="supply voltage for the part's compensation where the recording has "
        "none (default: the registers' v0, so the supply term is 0)",
    )
    codes: CodeFormat = Field(
        default_factory=CodeFormat,
        description="the product's code format (its product file's `codes:`): turns a CSV's "
        "deg/s and C into codes and reads codes for compensation",
    )


    @model_validator(mode="after")
    def _has_recording(self) -> Settings:
        if not (self.path or self.address):
            raise ValueError(
                "no recording to replay: give the socket's run folder, raw.h5 or CSV in "
                "`ports` (or as `path`)"
            )
        return self

    @property
    def recording_path(self) -> Path:
        return Path(self.path or self.address)


class RecordingEnded(PartSilent):
    """The replayed recording has been played to its end (and `loop` is off)."""


@dataclass
class _Playback:
    """Where playback stands: next sample, and recorded time -> fixture/station time."""

    next: int = 0
    shift_s: float = 0.0  # fixture time = recorded time + shift_s
    station_offset_s: float | None = None  # station time = fixture time + this (set at START)


class ReplayPartLink:
    """`drivers.protocols.PartLink` that plays a `Recording` back, paced by the station clock."""

    def __init__(self, recording: Recording, settings: Settings) -> None:
        self.recording = recording
        self.settings = settings
        self.name = f"replayed part on socket {settings.socket}"
        self._codes = settings.codes
        self._clock: Clock = ScaledClock(1.0)
        self._lock = threading.RLock()
        self._play = _Playback()
        self._streaming = False
        self._closed = False
        self._held: list[SampleBlock] = []  # due before STOP, not read yet
        self._frames_ok = 0
        self._registers = CalibrationRegisters()
        self._compensation = False
        self._odr_hz: int | None = None

    def attach_clock(self, clock: Clock) -> None:
        self._clock = clock

    # ------------------------------------------------------------ identity

    def identify(self) -> InstrumentIdentity:
        self._check_open()
        return InstrumentIdentity(
            manufacturer="gyrocal-station",
            model="replay",
            serial=self.recording.name,
            firmware=self.recording.kind,
        )

    def probe(self) -> str:
        """'' while the replay is open (the instrument lights' health check)."""
        self._check_open()
        return ""

    def part_present(self) -> bool:
        self._check_open()
        return True

    def read_part_serial(self) -> str:
        self._check_open()
        if self.settings.serial:
            return self.settings.serial
        if self.recording.serial:
            return self.recording.serial
        return self.recording.source.stem

    def stop_angle(self) -> tuple[float, float]:
        self._check_open()
        return self.settings.stop_angle_deg, self.settings.stop_angle_uncertainty_deg

    def set_output_rate(self, rate_hz: int) -> None:
        self._check_open()
        if rate_hz not in OUTPUT_RATES_HZ:
            raise ValueError(f"output data rate {rate_hz} Hz is not one of {OUTPUT_RATES_HZ}")
        if self._streaming:
            raise FixtureRefused(
                f"the {self.name} refused 'ODR {rate_hz}': stop streaming first",
                code=int(ReplyError.BUSY_STREAMING),
                instrument=self.name,
            )
        recorded_hz = 1.0 / self.recording.period_s
        if abs(recorded_hz - rate_hz) > _RATE_MISMATCH_REL * rate_hz:
            log.warning(
                "%s: %s was recorded at %.4g Hz; it is played at that rate, not %d Hz",
                self.name, self.recording.source, recorded_hz, rate_hz,
            )
        self._odr_hz = rate_hz

    # ------------------------------------------------------------ calibration registers

    def read_calibration(self) -> CalibrationRegisters:
        self._check_open()
        return self._registers

    def write_calibration(self, registers: CalibrationRegisters) -> None:
        self._check_open()
        values = asdict(registers)
        bad = [k for k, v in values.items() if not math.isfinite(v)]
        if bad:
            raise ValueError(f"calibration values must be finite: {', '.join(bad)}")
        low, high = _SCALE_LIMITS
        if not low < registers.scale < high:
            raise FixtureRefused(
                f"the {self.name} refused the calibration: ERR {int(ReplyError.OUT_OF_RANGE)} "
                f"scale must be between {low:g} and {high:g} (got {registers.scale:.9g})",
                code=int(ReplyError.OUT_OF_RANGE),
                instrument=self.name,
            )
        with self._lock:
            self._registers = CalibrationRegisters(**{k: float(v) for k, v in values.items()})

    def set_compensation(self, enabled: bool) -> None:
        self._check_open()
        with self._lock:
            self._compensation = bool(enabled)

    # ------------------------------------------------------------ streaming

    def start_stream(self) -> None:
        self._check_open()
        with self._lock:
            if self._streaming:
                return  # START while streaming: the stream goes on (as the fixture does)
            rec, play = self.recording, self._play
            if play.next >= len(rec):
                if not self.settings.loop:
                    raise self._ended()
                self._wrap()
            now_s = self._clock.now_s()
            first_s = rec.time_s[play.next]
            if play.station_offset_s is None:  # the first START: recorded times as they are
                play.shift_s = 0.0
                play.station_offset_s = now_s + rec.period_s - first_s
            else:  # the fixture's clock ran on while stopped
                play.shift_s = now_s + rec.period_s - play.station_offset_s - first_s
            self._held = []
            self._frames_ok = 0
            self._streaming = True

    def stop_stream(self) -> None:
        self._check_open()
        with self._lock:
            if self._streaming:
                self._held.append(self._due(self._clock.now_s()))
            self._streaming = False

    def check_stream_stopped(self) -> SafeReadback:
        with self._lock:
            streaming = self._streaming
        return SafeReadback(not streaming, "stream started" if streaming else "stream stopped")

    def read_samples(self, max_wait_s: float = 0.0) -> SampleBlock:
        self._check_open()
        with self._lock:
            streaming = self._streaming
            next_due_s = self._next_due_s() if streaming else None
        # In lockstep station time moves only by the station's own waits, so a wait here
        # cannot bring a frame due (and must not step the clock from the acquisition thread,
        # or from inside a clock waiter): a read takes what is due and returns.
        lockstep = bool(getattr(self._clock, "lockstep", False))
        if next_due_s is not None and max_wait_s > 0 and not lockstep:
            wait_s = min(next_due_s - self._clock.now_s(), max_wait_s * self._clock.speed)
            if wait_s > 0:
                self._clock.sleep_s(wait_s)
        with self._lock:
            blocks, self._held = self._held, []
            if self._streaming:
                blocks.append(self._due(self._clock.now_s()))
            block = _concat(blocks)
            if (
                self._streaming
                and not len(block)
                and self._play.next >= len(self.recording)
                and not self.settings.loop
            ):
                raise self._ended()
        return block

    def stats(self) -> LinkStats:
        with self._lock:
            return LinkStats(frames_ok=self._frames_ok)

    def close(self) -> None:
        with self._lock:
            self._closed = True
            self._streaming = False

    # ------------------------------------------------------------ playback

    def _next_due_s(self) -> float | None:
        """Station time at which the next sample is due (None: nothing more to play)."""
        play, rec = self._play, self.recording
        if play.station_offset_s is None:
            return None
        if play.next >= len(rec):
            if not self.settings.loop:
                return None
            return float(rec.time_s[-1] + play.shift_s + rec.period_s + play.station_offset_s)
        return float(rec.time_s[play.next] + play.shift_s + play.station_offset_s)

    def _due(self, now_s: float) -> SampleBlock:
        """Take every sample due by station time `now_s` (looping if set)."""
        play, rec = self._play, self.recording
        assert play.station_offset_s is not None
        blocks: list[SampleBlock] = []
        while True:
            recorded_now_s = now_s - play.station_offset_s - play.shift_s
            end = int(np.searchsorted(rec.time_s, recorded_now_s, side="right"))
            if end > play.next:
                blocks.append(self._samples(play.next, end))
                play.next = end
            if play.next < len(rec) or not self.settings.loop:
                break
            self._wrap()
        block = _concat(blocks)
        self._frames_ok += len(block)
        return block

    def _wrap(self) -> None:
        """Back to the recording's first sample, one period after its last (loop)."""
        rec, play = self.recording, self._play
        play.shift_s += rec.time_s[-1] - rec.time_s[0] + rec.period_s
        play.next = 0

    def _samples(self, i0: int, i1: int) -> SampleBlock:
        rec = self.recording
        rate_code = rec.rate_code[i0:i1].copy()
        status = rec.status[i0:i1].copy()
        if self._compensation:
            rate_code, status = self._compensate(i0, i1, rate_code, status)
        return SampleBlock(
            seq=rec.seq[i0:i1].copy(),
            time_s=rec.time_s[i0:i1] + self._play.shift_s,
            rate_code=rate_code,
            temp_code=rec.temp_code[i0:i1].copy(),
            status=status,
            encoder_counts=rec.encoder_counts[i0:i1].copy(),
        )

    def _compensate(
        self, i0: int, i1: int, rate_code: NDArray[np.int64], status: NDArray[np.int64]
    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """The part's own correction, on the samples not recorded compensated."""
        rec, reg, codes = self.recording, self._registers, self._codes
        raw = (status & SampleStatus.COMPENSATED) == 0
        if not raw.any():
            return rate_code, status
        fallback_v = self.settings.supply_v if self.settings.supply_v is not None else reg.v0_v
        supply_v = np.where(np.isnan(rec.supply_v[i0:i1]), fallback_v, rec.supply_v[i0:i1])
        d_t = codes.temp_code_to_c(rec.temp_code[i0:i1]) - reg.t0_c
        d_v = supply_v - reg.v0_v
        bias = reg.bias_dps + reg.bias_tc_dps_per_c * d_t + reg.bias_vc_dps_per_v * d_v
        scale = reg.scale * (1.0 + reg.scale_tc_per_c * d_t + reg.scale_vc_per_v * d_v)
        # registers beyond first order in temperature (0 on a first-order calibration)
        bias = bias + reg.bias_tc2_dps_per_c2 * d_t**2 + reg.bias_tc3_dps_per_c3 * d_t**3
        scale = scale + reg.scale * (reg.scale_tc2_per_c2 * d_t**2 + reg.scale_tc3_per_c3 * d_t**3)
        out = codes.rate_dps_to_code((codes.rate_code_to_dps(rate_code) - bias) / scale)
        rate_code = np.where(raw, out, rate_code)
        status = np.where(raw, status | SampleStatus.COMPENSATED, status)
        saturated = raw & codes.rate_code_at_rail(rate_code)
        status = np.where(saturated, status | SampleStatus.SATURATED, status)
        return rate_code.astype(np.int64), status.astype(np.int64)

    # ------------------------------------------------------------ errors

    def _ended(self) -> RecordingEnded:
        rec = self.recording
        return RecordingEnded(
            f"the {self.name} has played {rec.source} to its end ({len(rec)} samples, "
            f"{rec.duration_s:.1f} s): the part is silent now; set loop: true in the replay's "
            "settings to repeat the recording, or give a longer one",
            instrument=self.name,
        )

    def _check_open(self) -> None:
        if self._closed:
            raise ConnectionLost(
                f"the {self.name} was closed; open the replay again", instrument=self.name
            )


def _concat(blocks: list[SampleBlock]) -> SampleBlock:
    blocks = [b for b in blocks if len(b)]
    if not blocks:
        empty = np.zeros(0, dtype=np.int64)
        return SampleBlock(empty, np.zeros(0), empty, empty, empty, encoder_counts=empty)
    if len(blocks) == 1:
        return blocks[0]

    def cat(name: str) -> NDArray[Any]:
        return np.concatenate([getattr(b, name) for b in blocks])

    return SampleBlock(
        seq=cat("seq"),
        time_s=cat("time_s"),
        rate_code=cat("rate_code"),
        temp_code=cat("temp_code"),
        status=cat("status"),
        encoder_counts=cat("encoder_counts"),
    )


def factory(settings: dict[str, Any]) -> ReplayPartLink:
    """Validate `settings` (pydantic's ValidationError propagates), load the recording
    (`RecordingError`, a `ConnectionLost`, if it is missing or not a recording)."""
    s = Settings.model_validate(settings)
    recording = load_recording(s.recording_path, s.codes)
    log.info("replaying %s (%d samples, %.1f s) as socket %d", recording.source,
             len(recording), recording.duration_s, s.socket)
    return ReplayPartLink(recording, s)
