"""Wire format of the part fixture (one microcontroller per socket on its own serial port).

Stated once; used by the driver (`drivers.part_link`) and by the simulated fixture twin.

Host to fixture: ASCII command lines terminated by LF (see `Command`). Fixture to host:
binary frames only, so replies and samples share one stream and one parser:

    offset size  field
    0      2     sync 0xA5 0x5A
    2      1     type: 0x01 sample, 0x02 reply
    3      1     payload length n (13 for a sample, 0..250 for a reply)
    4      n     payload
    4+n    4     CRC-32 (zlib/IEEE 802.3) of bytes 2 .. 4+n-1, big-endian

Sample payload (13 bytes, big-endian): seq u16 (wraps), fixture time u32 in microseconds
(wraps every 2^32 us; the parser unwraps), rate code u24, temperature code u24, status u8.
Reply payload: ASCII, "OK[ data]" or "ERR <code> <text>".

Codes are the ADIS16130's: rate offset binary, 0 deg/s = 8,388,608 counts, 23,488 counts per
deg/s; temperature 0 C = 8,036,283 counts, 14,093 counts per C.

A frame whose CRC fails is counted as corrupted and dropped; the parser then searches for
the next sync word from the byte after the bad frame's sync, so it resynchronises on the
next intact frame. `frames_lost` counts every missing sequence number (dropped in transit or
dropped here for a bad CRC); `frames_corrupted` counts the bad-CRC frames among them.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from enum import IntEnum, IntFlag

import numpy as np
from numpy.typing import NDArray

SYNC = b"\xa5\x5a"
HEADER_SIZE = 4
CRC_SIZE = 4
SAMPLE_PAYLOAD_SIZE = 13
SAMPLE_FRAME_SIZE = HEADER_SIZE + SAMPLE_PAYLOAD_SIZE + CRC_SIZE  # 21
MAX_REPLY_PAYLOAD = 250

RATE_ZERO_CODE = 8_388_608
RATE_COUNTS_PER_DPS = 23_488.0
TEMP_ZERO_CODE = 8_036_283
TEMP_COUNTS_PER_C = 14_093.0
CODE_MAX = (1 << 24) - 1
RATED_RANGE_DPS = 250.0

OUTPUT_RATES_HZ = (50, 100, 200, 500, 1000)
SEQ_MODULO = 1 << 16
TIME_MODULO_US = 1 << 32


class FrameType(IntEnum):
    SAMPLE = 0x01
    REPLY = 0x02


class SampleStatus(IntFlag):
    OVER_RANGE = 1 << 0  # |output| beyond the rated range (250 deg/s): out of specification
    SATURATED = 1 << 1  # the rate code hit a rail: the sample is clipped
    COMPENSATED = 1 << 2  # the part applied its calibration registers to this sample
    TEMP_INVALID = 1 << 3  # the on-chip temperature sensor reading is not valid
    SUPPLY_LOW = 1 << 4  # the part's supply is below its operating minimum


class Command:
    """Command lines the fixture understands (each terminated by LF)."""

    IDENTIFY = "IDN?"  # -> OK manufacturer,model,serial,firmware
    PRESENT = "PRESENT?"  # -> OK 1 | OK 0
    PART_SERIAL = "SN?"  # -> OK <serial>   | ERR 10 no part | ERR 11 part not powered
    OUTPUT_RATE = "ODR {hz:d}"  # -> OK         | ERR 3 rate not supported
    START = "START"  # -> OK, then sample frames
    STOP = "STOP"  # -> OK after the last sample frame
    CAL_READ = "CAL?"  # -> OK bias=.. scale=.. bias_tc=.. scale_tc=.. bias_vc=.. scale_vc=.. t0=.. v0=..
    CAL_WRITE = "CAL {assignments}"  # key=value pairs as CAL? gives them -> OK | ERR 4 ...
    COMPENSATION = "COMP {on:d}"  # -> OK
    STOP_ANGLE = "STOPANGLE?"  # -> OK <angle_deg> <std_uncertainty_deg>


CAL_KEYS = ("bias", "scale", "bias_tc", "scale_tc", "bias_vc", "scale_vc", "t0", "v0")


class ReplyError(IntEnum):
    SYNTAX = 1
    UNKNOWN_COMMAND = 2
    OUT_OF_RANGE = 3
    BAD_REGISTER = 4
    BUSY_STREAMING = 5
    NO_PART = 10
    NOT_POWERED = 11


# ---------------------------------------------------------------- code conversions


def rate_dps_to_code(rate_dps: NDArray[np.float64]) -> NDArray[np.int64]:
    code = np.rint(np.asarray(rate_dps) * RATE_COUNTS_PER_DPS + RATE_ZERO_CODE)
    return np.clip(code, 0, CODE_MAX).astype(np.int64)


def rate_code_to_dps(code: NDArray[np.int64] | int) -> NDArray[np.float64]:
    return (np.asarray(code, dtype=np.float64) - RATE_ZERO_CODE) / RATE_COUNTS_PER_DPS


def temp_c_to_code(temp_c: NDArray[np.float64]) -> NDArray[np.int64]:
    code = np.rint(np.asarray(temp_c) * TEMP_COUNTS_PER_C + TEMP_ZERO_CODE)
    return np.clip(code, 0, CODE_MAX).astype(np.int64)


def temp_code_to_c(code: NDArray[np.int64] | int) -> NDArray[np.float64]:
    return (np.asarray(code, dtype=np.float64) - TEMP_ZERO_CODE) / TEMP_COUNTS_PER_C


# ---------------------------------------------------------------- encoding (fixture side)

_SAMPLE_DTYPE = np.dtype(
    [
        ("sync", ">u2"),
        ("type", "u1"),
        ("len", "u1"),
        ("seq", ">u2"),
        ("t_us", ">u4"),
        ("rate", "u1", (3,)),
        ("temp", "u1", (3,)),
        ("status", "u1"),
        ("crc", ">u4"),
    ]
)
assert _SAMPLE_DTYPE.itemsize == SAMPLE_FRAME_SIZE


def _u24_bytes(values: NDArray[np.int64]) -> NDArray[np.uint8]:
    v = np.asarray(values, dtype=np.int64)
    return np.stack([(v >> 16) & 0xFF, (v >> 8) & 0xFF, v & 0xFF], axis=-1).astype(np.uint8)


def encode_samples(
    seq: NDArray[np.int64],
    time_us: NDArray[np.int64],
    rate_code: NDArray[np.int64],
    temp_code: NDArray[np.int64],
    status: NDArray[np.int64],
) -> bytes:
    """Encode a batch of samples as consecutive sample frames (seq and time wrap here)."""
    n = len(seq)
    frames = np.zeros(n, dtype=_SAMPLE_DTYPE)
    frames["sync"] = 0xA55A
    frames["type"] = FrameType.SAMPLE
    frames["len"] = SAMPLE_PAYLOAD_SIZE
    frames["seq"] = np.asarray(seq, dtype=np.int64) % SEQ_MODULO
    frames["t_us"] = np.asarray(time_us, dtype=np.int64) % TIME_MODULO_US
    frames["rate"] = _u24_bytes(rate_code)
    frames["temp"] = _u24_bytes(temp_code)
    frames["status"] = np.asarray(status, dtype=np.int64) & 0xFF
    raw = frames.view(np.uint8).reshape(n, SAMPLE_FRAME_SIZE)
    body = memoryview(raw.tobytes())
    crc = np.fromiter(
        (
            zlib.crc32(body[i * SAMPLE_FRAME_SIZE + 2 : (i + 1) * SAMPLE_FRAME_SIZE - CRC_SIZE])
            for i in range(n)
        ),
        dtype=np.uint32,
        count=n,
    )
    frames["crc"] = crc
    return frames.tobytes()


def encode_reply(text: str) -> bytes:
    payload = text.encode("ascii", "replace")[:MAX_REPLY_PAYLOAD]
    body = bytes((FrameType.REPLY, len(payload))) + payload
    return SYNC + body + struct.pack(">I", zlib.crc32(body))


# ---------------------------------------------------------------- parsing (host side)


@dataclass
class ParseResult:
    """What one `FrameParser.feed` call decoded."""

    seq: NDArray[np.int64]
    time_s: NDArray[np.float64]
    rate_code: NDArray[np.int64]
    temp_code: NDArray[np.int64]
    status: NDArray[np.int64]
    replies: list[str] = field(default_factory=list)
    frames_lost: int = 0
    frames_corrupted: int = 0
    bytes_discarded: int = 0


_EMPTY_I = np.zeros(0, dtype=np.int64)
_EMPTY_F = np.zeros(0, dtype=np.float64)


class FrameParser:
    """Incremental decoder: feed it bytes in any chunking, get samples and replies out.

    Never raises on bad input; every byte that is not part of a valid frame is counted as
    discarded, every frame that fails its CRC as corrupted, every gap in the sequence counter
    as lost frames.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._last_seq: int | None = None
        self._last_t_us: int | None = None
        self._t_wraps = 0
        self.frames_ok = 0
        self.frames_lost = 0
        self.frames_corrupted = 0
        self.bytes_discarded = 0

    def reset_sequence(self) -> None:
        """Forget the last sequence number (call when streaming restarts)."""
        self._last_seq = None
        self._last_t_us = None
        self._t_wraps = 0

    def feed(self, data: bytes) -> ParseResult:
        buf = self._buf
        buf += data
        seqs: list[int] = []
        times: list[int] = []
        rates: list[int] = []
        temps: list[int] = []
        stats: list[int] = []
        replies: list[str] = []
        lost = corrupted = discarded = 0
        pos = 0
        n = len(buf)
        crc32 = zlib.crc32
        while True:
            start = buf.find(SYNC, pos)
            if start < 0:
                # keep a trailing 0xA5 that may begin the next sync word
                keep = 1 if n > pos and buf[n - 1] == 0xA5 else 0
                discarded += n - pos - keep
                pos = n - keep
                break
            discarded += start - pos
            if start + HEADER_SIZE > n:
                pos = start
                break
            ftype = buf[start + 2]
            plen = buf[start + 3]
            valid_header = (ftype == FrameType.SAMPLE and plen == SAMPLE_PAYLOAD_SIZE) or (
                ftype == FrameType.REPLY and plen <= MAX_REPLY_PAYLOAD
            )
            if not valid_header:
                discarded += 1
                pos = start + 1
                continue
            end = start + HEADER_SIZE + plen + CRC_SIZE
            if end > n:
                pos = start
                break
            body = bytes(buf[start + 2 : end - CRC_SIZE])
            (crc,) = struct.unpack_from(">I", buf, end - CRC_SIZE)
            if crc32(body) != crc:
                corrupted += 1
                discarded += 1
                pos = start + 1
                continue
            if ftype == FrameType.SAMPLE:
                seq, t_us = struct.unpack_from(">HI", body, 2)
                p = body[8:15]
                rates.append((p[0] << 16) | (p[1] << 8) | p[2])
                temps.append((p[3] << 16) | (p[4] << 8) | p[5])
                stats.append(p[6])
                if self._last_seq is not None:
                    lost += (seq - self._last_seq - 1) % SEQ_MODULO
                self._last_seq = seq
                if self._last_t_us is not None and t_us < self._last_t_us - (TIME_MODULO_US >> 1):
                    self._t_wraps += 1
                self._last_t_us = t_us
                seqs.append(seq)
                times.append(t_us + self._t_wraps * TIME_MODULO_US)
            else:
                replies.append(body[2:].decode("ascii", "replace"))
            pos = end
        del buf[:pos]
        self.frames_ok += len(seqs) + len(replies)
        self.frames_lost += lost
        self.frames_corrupted += corrupted
        self.bytes_discarded += discarded
        if seqs:
            return ParseResult(
                seq=np.asarray(seqs, dtype=np.int64),
                time_s=np.asarray(times, dtype=np.float64) * 1e-6,
                rate_code=np.asarray(rates, dtype=np.int64),
                temp_code=np.asarray(temps, dtype=np.int64),
                status=np.asarray(stats, dtype=np.int64),
                replies=replies,
                frames_lost=lost,
                frames_corrupted=corrupted,
                bytes_discarded=discarded,
            )
        return ParseResult(
            seq=_EMPTY_I,
            time_s=_EMPTY_F,
            rate_code=_EMPTY_I,
            temp_code=_EMPTY_I,
            status=_EMPTY_I,
            replies=replies,
            frames_lost=lost,
            frames_corrupted=corrupted,
            bytes_discarded=discarded,
        )
