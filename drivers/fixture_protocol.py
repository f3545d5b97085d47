"""Wire format of the part fixture (one microcontroller per socket on its own serial port).

Stated once; used by the driver (`drivers.part_link`) and by the simulated fixture twin.

Host to fixture: ASCII command lines terminated by LF (see `Command`). Fixture to host:
binary frames only, so replies and samples share one stream and one parser:

    offset size  field
    0      2     sync 0xA5 0x5A
    2      1     type: 0x01 sample, 0x02 reply, 0x03 three-axis sample
    3      1     payload length n (17 for a sample, 13 from older firmware, 0..250 for a reply,
                 32 for a three-axis sample)
    4      n     payload
    4+n    4     CRC-32 (zlib/IEEE 802.3) of bytes 2 .. 4+n-1, big-endian

Sample payload (17 bytes, big-endian): seq u16 (wraps), fixture time u32 in microseconds
(wraps every 2^32 us; the parser unwraps), rate code u24, temperature code u24, status u8,
encoder u32: the rate table's encoder count latched by the fixture at the sample instant
(the table's quadrature output wired to the fixture's counter input). It is valid only when
status bit ENCODER_LATCHED is set; a fixture without its encoder input connected sends 0 and
leaves the bit clear. This hardware sync gives every sample its own table reference, so
motion between analysed windows (where a sensor lag shows) is known sample by sample.

The fixture's counter is zeroed once, at the encoder's first index pulse after power-up, and
from then on runs freely: it counts up and down with the table, wraps only at 2^32 (a
negative count arrives as its two's complement), and is NOT reset at each later index pulse
(once per table revolution) nor by START or STOP. Counts are therefore continuous across a
stream restart: the difference of two latches, taken modulo 2^32 as a signed 32-bit
number, is the table's motion between them, even when they come from different streams
(only a power cycle of the fixture starts the count again).

Older fixture firmware sends a 13-byte sample payload: the same fields without the encoder.
The parser accepts both lengths, also mixed in one stream (a firmware update between START
and STOP), and decodes the encoder of an old frame as 0 (its ENCODER_LATCHED bit is whatever
the status byte says, normally clear).

Three-axis sample payload (32 bytes, a three-axis part's fixture): seq u16, time u32, gyro
rate codes x, y, z (u24 each), accelerometer codes x, y, z (u24 each, `codes:` accel_*),
temperature code u24, status u8, encoder u32; the same meanings as the single-axis sample's.
The parser decodes its x rate code as `rate_code`, so single-axis consumers keep working.
Such a fixture answers `AXES?` with 3 and holds the part's three-axis registers (`CAL3`).

Reply payload: printable ASCII (0x20..0x7E), "OK[ data]" or "ERR <code> <text>".

On the serial line (10 bits a byte) the sample stream alone needs output rate x 250 baud
(`sample_stream_baud`): 500 Hz needs 125,000 baud, more than the usual 115,200; the station
refuses a procedure whose rate the fixture's configured baud cannot carry.

The rate and temperature fields carry the part's codes as the part gives them; what they mean
in deg/s and C is the product's (`codes:` in its product file, `drivers.part_codes`). The
simulated part's codes are the ADIS16130's: rate offset binary, 0 deg/s = 8,388,608 counts,
23,488 counts per deg/s; temperature 0 C = 8,036,283 counts, 14,093 counts per C.
The full specification, for a fixture's firmware: docs/fixture-protocol.md.

A frame whose CRC fails is counted as corrupted and dropped; the parser then searches for
the next sync word from the byte after the bad frame's sync, so it resynchronises on the
next intact frame. `frames_lost` counts every missing sequence number (dropped in transit or
dropped here for a bad CRC); `frames_corrupted` counts the bad-CRC frames among them (a
frame whose sync, type or length byte is damaged cannot be told from noise: it is counted as
lost and its bytes as discarded, but not as corrupted; unless the damaged header still reads
as a valid one, e.g. a sample length 17 turned into 13, then its CRC fails and it counts as
corrupted).
"""

from __future__ import annotations

import math
import re
import struct
import zlib
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from drivers.part_codes import ADIS16130, CODE_FIELD_BITS
from drivers.protocols import ENCODER_MODULO as ENCODER_MODULO  # the wire carries both as
from drivers.protocols import SampleStatus as SampleStatus  # every part link reports them

SYNC = b"\xa5\x5a"
HEADER_SIZE = 4
CRC_SIZE = 4
SAMPLE_PAYLOAD_SIZE = 17
SAMPLE_FRAME_SIZE = HEADER_SIZE + SAMPLE_PAYLOAD_SIZE + CRC_SIZE  # 25
LEGACY_SAMPLE_PAYLOAD_SIZE = 13  # older fixture firmware: no encoder field
LEGACY_SAMPLE_FRAME_SIZE = HEADER_SIZE + LEGACY_SAMPLE_PAYLOAD_SIZE + CRC_SIZE  # 21
MAX_REPLY_PAYLOAD = 250
# three-axis parts (docs/fixture-protocol.md section 7): frame type 0x03, 32-byte payload
SAMPLE3_PAYLOAD_SIZE = 32
SAMPLE3_FRAME_SIZE = HEADER_SIZE + SAMPLE3_PAYLOAD_SIZE + CRC_SIZE  # 40

# the ADIS16130's codes; a product states its own in its file (drivers.part_codes.CodeFormat)
RATE_ZERO_CODE = ADIS16130.rate_zero_code
RATE_COUNTS_PER_DPS = ADIS16130.rate_counts_per_dps
TEMP_ZERO_CODE = ADIS16130.temp_zero_code
TEMP_COUNTS_PER_C = ADIS16130.temp_counts_per_c
CODE_MAX = (1 << CODE_FIELD_BITS) - 1
RATED_RANGE_DPS = 250.0

OUTPUT_RATES_HZ = (50, 100, 200, 500, 1000)
SEQ_MODULO = 1 << 16
TIME_MODULO_US = 1 << 32
UART_BITS_PER_BYTE = 10  # start bit, 8 data bits, stop bit


def sample_stream_baud(output_rate_hz: float, axes: int = 1) -> int:
    """Baud rate a stream of sample frames needs at `output_rate_hz` (replies not counted);
    `axes=3`: a three-axis part's frames."""
    size = SAMPLE3_FRAME_SIZE if axes == 3 else SAMPLE_FRAME_SIZE
    return math.ceil(output_rate_hz * size * UART_BITS_PER_BYTE)


class FrameType(IntEnum):
    SAMPLE = 0x01
    REPLY = 0x02
    SAMPLE3 = 0x03  # a three-axis part's sample: gyro and accelerometer x, y, z


class Command:
    """Command lines the fixture understands (each terminated by LF)."""

    IDENTIFY = "IDN?"  # -> OK manufacturer,model,serial,firmware
    PRESENT = "PRESENT?"  # -> OK 1 | OK 0
    PART_SERIAL = "SN?"  # -> OK <serial>   | ERR 10 no part | ERR 11 part not powered
    OUTPUT_RATE = "ODR {hz:d}"  # -> OK         | ERR 3 rate not supported
    START = "START"  # -> OK, then sample frames
    STOP = "STOP"  # -> OK after the last sample frame
    # -> OK 1 from START to STOP (whether or not the part is powered and sending) | OK 0;
    # firmware before 1.5 answers ERR 2 (the host then relies on STOP's OK)
    STREAM_STATE = "STREAM?"
    # CAL? -> OK bias=.. scale=.. bias_tc=.. scale_tc=.. bias_vc=.. scale_vc=.. t0=.. v0=..
    CAL_READ = "CAL?"
    CAL_WRITE = "CAL {assignments}"  # key=value pairs as CAL? gives them -> OK | ERR 4 ...
    COMPENSATION = "COMP {on:d}"  # -> OK
    STOP_ANGLE = "STOPANGLE?"  # -> OK <angle_deg> <std_uncertainty_deg>
    # three-axis parts (fixture firmware 1.4 and later; older firmware answers ERR 2)
    AXES = "AXES?"  # -> OK 1 | OK 3 (the part's rate axes) | ERR 10/11 as SN?
    CAL3_READ = "CAL3? {key}"  # -> OK <key>=<v>[,<v>...] (one register, row-major)
    CAL3_WRITE = "CAL3 {assignments}"  # <key>=<v>,<v>,... pairs -> OK | ERR 1/3/4


CAL_KEYS = ("bias", "scale", "bias_tc", "scale_tc", "bias_vc", "scale_vc", "t0", "v0")
# registers beyond first order in temperature, on parts that hold them (CAL? lists them after
# the eight; a fixture whose part has none answers the eight and refuses these with ERR 4)
CAL_KEYS_HIGHER_ORDER = ("bias_tc2", "bias_tc3", "scale_tc2", "scale_tc3")
# a three-axis part's registers (CAL3? <key> / CAL3 <key>=...) and how many values each holds
# (matrices row-major: row i is output axis i); see drivers.protocols.CalibrationRegisters3
CAL3_SIZES = {
    "bias": 3,
    "matrix": 9,
    "gsens": 9,
    "bias_tc": 3,
    "bias_vc": 3,
    "scale_tc": 3,
    "scale_vc": 3,
    "t0": 1,
    "v0": 1,
}
CAL3_KEYS = tuple(CAL3_SIZES)
# CAL3 keys -> the CalibrationRegisters3 field each one fills
CAL3_FIELDS = {
    "bias": "bias_dps",
    "matrix": "matrix",
    "gsens": "g_sensitivity_dps_per_mps2",
    "bias_tc": "bias_tc_dps_per_c",
    "bias_vc": "bias_vc_dps_per_v",
    "scale_tc": "scale_tc_per_c",
    "scale_vc": "scale_vc_per_v",
    "t0": "t0_c",
    "v0": "v0_v",
}
assert tuple(CAL3_FIELDS) == CAL3_KEYS


class ReplyError(IntEnum):
    SYNTAX = 1
    UNKNOWN_COMMAND = 2
    OUT_OF_RANGE = 3
    BAD_REGISTER = 4
    BUSY_STREAMING = 5
    NO_PART = 10
    NOT_POWERED = 11


# ---------------------------------------------------------------- code conversions


# The ADIS16130's conversion (the simulated part's codes). The station converts with the
# product file's `codes:` (drivers.part_codes.CodeFormat), whose defaults are these.


def rate_dps_to_code(rate_dps: NDArray[np.float64]) -> NDArray[np.int64]:
    return ADIS16130.rate_dps_to_code(rate_dps)


def rate_code_to_dps(code: NDArray[np.int64] | int) -> NDArray[np.float64]:
    return ADIS16130.rate_code_to_dps(code)


def temp_c_to_code(temp_c: NDArray[np.float64]) -> NDArray[np.int64]:
    return ADIS16130.temp_c_to_code(temp_c)


def temp_code_to_c(code: NDArray[np.int64] | int) -> NDArray[np.float64]:
    return ADIS16130.temp_code_to_c(code)


# ---------------------------------------------------------------- CRC over many sample frames


def _make_crc_table() -> NDArray[np.uint32]:
    table = np.zeros(256, dtype=np.uint32)
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0xEDB88320 if c & 1 else c >> 1
        table[i] = c
    return table


_CRC_TABLE = _make_crc_table()
_VECTOR_CRC_MIN_FRAMES = 400  # below this, one zlib call per frame is faster than numpy


def _sample_crcs(raw: NDArray[np.uint8]) -> NDArray[np.uint32]:
    """CRC-32 of every row of `raw` (n x frame size: sample frames of one layout), computed
    over each frame's bytes 2 .. frame size - 5 (type, length and payload)."""
    n, size = raw.shape
    body_len = size - CRC_SIZE - 2
    if n < _VECTOR_CRC_MIN_FRAMES:
        flat = memoryview(np.ascontiguousarray(raw).tobytes())
        crc32 = zlib.crc32
        return np.fromiter(
            (crc32(flat[i : i + body_len]) for i in range(2, n * size, size)),
            dtype=np.uint32,
            count=n,
        )
    # table-driven CRC, one byte column at a time for all frames at once
    crc = np.full(n, 0xFFFFFFFF, dtype=np.uint32)
    for column in raw[:, 2 : 2 + body_len].T:
        crc = _CRC_TABLE[(crc ^ column) & 0xFF] ^ (crc >> 8)
    return crc ^ np.uint32(0xFFFFFFFF)


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
        ("encoder", ">u4"),
        ("crc", ">u4"),
    ]
)
assert _SAMPLE_DTYPE.itemsize == SAMPLE_FRAME_SIZE
# the older firmware's frame: the same fields without the encoder
_LEGACY_SAMPLE_DTYPE = np.dtype([f for f in _SAMPLE_DTYPE.descr if f[0] != "encoder"])
assert _LEGACY_SAMPLE_DTYPE.itemsize == LEGACY_SAMPLE_FRAME_SIZE
# a three-axis part's frame: gyro x, y, z and accelerometer x, y, z codes (u24 each)
_SAMPLE3_DTYPE = np.dtype(
    [
        ("sync", ">u2"),
        ("type", "u1"),
        ("len", "u1"),
        ("seq", ">u2"),
        ("t_us", ">u4"),
        ("rate", "u1", (3, 3)),
        ("accel", "u1", (3, 3)),
        ("temp", "u1", (3,)),
        ("status", "u1"),
        ("encoder", ">u4"),
        ("crc", ">u4"),
    ]
)
assert _SAMPLE3_DTYPE.itemsize == SAMPLE3_FRAME_SIZE


def _u24_bytes(values: NDArray[np.int64]) -> NDArray[np.uint8]:
    v = np.asarray(values, dtype=np.int64)
    return np.stack([(v >> 16) & 0xFF, (v >> 8) & 0xFF, v & 0xFF], axis=-1).astype(np.uint8)


def encode_samples(
    seq: NDArray[np.int64],
    time_us: NDArray[np.int64],
    rate_code: NDArray[np.int64],
    temp_code: NDArray[np.int64],
    status: NDArray[np.int64],
    encoder: NDArray[np.int64] | None = None,
    *,
    legacy: bool = False,
) -> bytes:
    """Encode a batch of samples as consecutive sample frames (seq, time and encoder wrap
    here); without `encoder` the field is 0 (set ENCODER_LATCHED in `status` only with it).

    `legacy=True` writes the older firmware's 13-byte payload, which has no encoder field
    (for tests of the parser's backward compatibility).
    """
    if legacy and encoder is not None:
        raise ValueError("the legacy sample frame has no encoder field")
    dtype = _LEGACY_SAMPLE_DTYPE if legacy else _SAMPLE_DTYPE
    n = len(seq)
    frames = np.zeros(n, dtype=dtype)
    frames["sync"] = 0xA55A
    frames["type"] = FrameType.SAMPLE
    frames["len"] = dtype.itemsize - HEADER_SIZE - CRC_SIZE
    frames["seq"] = np.asarray(seq, dtype=np.int64) % SEQ_MODULO
    frames["t_us"] = np.asarray(time_us, dtype=np.int64) % TIME_MODULO_US
    frames["rate"] = _u24_bytes(rate_code)
    frames["temp"] = _u24_bytes(temp_code)
    frames["status"] = np.asarray(status, dtype=np.int64) & 0xFF
    if encoder is not None:
        frames["encoder"] = np.asarray(encoder, dtype=np.int64) % ENCODER_MODULO
    raw = frames.view(np.uint8).reshape(n, dtype.itemsize)
    frames["crc"] = _sample_crcs(raw)
    return frames.tobytes()


def encode_samples3(
    seq: NDArray[np.int64],
    time_us: NDArray[np.int64],
    rate_code_xyz: NDArray[np.int64],
    accel_code_xyz: NDArray[np.int64],
    temp_code: NDArray[np.int64],
    status: NDArray[np.int64],
    encoder: NDArray[np.int64] | None = None,
) -> bytes:
    """Encode a batch of a three-axis part's samples (codes (n, 3) columns x, y, z) as
    consecutive three-axis sample frames; otherwise as `encode_samples`."""
    n = len(seq)
    frames = np.zeros(n, dtype=_SAMPLE3_DTYPE)
    frames["sync"] = 0xA55A
    frames["type"] = FrameType.SAMPLE3
    frames["len"] = SAMPLE3_PAYLOAD_SIZE
    frames["seq"] = np.asarray(seq, dtype=np.int64) % SEQ_MODULO
    frames["t_us"] = np.asarray(time_us, dtype=np.int64) % TIME_MODULO_US
    frames["rate"] = _u24_bytes(np.asarray(rate_code_xyz).reshape(n, 3))
    frames["accel"] = _u24_bytes(np.asarray(accel_code_xyz).reshape(n, 3))
    frames["temp"] = _u24_bytes(temp_code)
    frames["status"] = np.asarray(status, dtype=np.int64) & 0xFF
    if encoder is not None:
        frames["encoder"] = np.asarray(encoder, dtype=np.int64) % ENCODER_MODULO
    raw = frames.view(np.uint8).reshape(n, SAMPLE3_FRAME_SIZE)
    frames["crc"] = _sample_crcs(raw)
    return frames.tobytes()


def encode_reply(text: str) -> bytes:
    """A reply frame; characters outside printable ASCII are sent as '?'."""
    printable = "".join(c if " " <= c <= "~" else "?" for c in text)
    payload = printable.encode("ascii")[:MAX_REPLY_PAYLOAD]
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
    encoder: NDArray[np.int64]  # raw latched counts (wrapping u32); see ENCODER_LATCHED
    replies: list[str] = field(default_factory=list)
    frames_lost: int = 0
    frames_corrupted: int = 0
    bytes_discarded: int = 0
    # three-axis frames (None when the call decoded none): codes (n, 3), columns x, y, z;
    # `rate_code` is then the x column. A single-axis frame decoded in the same call (the
    # protocol does not mix them in one stream) gets its rate code as x and 0 elsewhere.
    rate_code_xyz: NDArray[np.int64] | None = None
    accel_code_xyz: NDArray[np.int64] | None = None


_EMPTY_I = np.zeros(0, dtype=np.int64)
_EMPTY_F = np.zeros(0, dtype=np.float64)
_SYNC_WORD = 0xA55A
_HALF_TIME_US = TIME_MODULO_US >> 1
_TYPE_SAMPLE = int(FrameType.SAMPLE)  # plain ints: enum lookups cost per frame
_TYPE_REPLY = int(FrameType.REPLY)
_NOT_TEXT = re.compile(rb"[^\x20-\x7e]")
# sample payload length -> frame layout (plain int keys: looked up with a byte of the buffer)
_SAMPLE_DTYPES = {
    SAMPLE_PAYLOAD_SIZE: _SAMPLE_DTYPE,
    LEGACY_SAMPLE_PAYLOAD_SIZE: _LEGACY_SAMPLE_DTYPE,
}
_SAMPLE_PAYLOAD_SIZES = frozenset(_SAMPLE_DTYPES)
_TYPE_SAMPLE3 = int(FrameType.SAMPLE3)


def _is_three_axis(frames: NDArray[np.void]) -> bool:
    return "accel" in (frames.dtype.names or ())


def _u24(column: NDArray[np.uint8]) -> NDArray[np.int64]:
    c = column.astype(np.int64)
    return (c[..., 0] << 16) | (c[..., 1] << 8) | c[..., 2]


def _frame_end(buf: bytearray, start: int, n: int) -> int:
    """Where the frame whose header is at `start` ends (beyond `n`: not all here yet), or 0
    when the header announces no valid frame (a false sync word, or a damaged header)."""
    ftype = buf[start + 2]
    plen = buf[start + 3]
    end = start + HEADER_SIZE + plen + CRC_SIZE
    valid_header = (
        (ftype == _TYPE_SAMPLE and plen in _SAMPLE_PAYLOAD_SIZES)
        or (ftype == _TYPE_SAMPLE3 and plen == SAMPLE3_PAYLOAD_SIZE)
    ) or (
        ftype == _TYPE_REPLY
        and plen <= MAX_REPLY_PAYLOAD
        # replies are printable ASCII: a false sync inside sample data announcing a
        # long reply is rejected at its first non-text byte, not after 250 bytes
        and _NOT_TEXT.search(buf, start + HEADER_SIZE, min(n, end - CRC_SIZE)) is None
    )
    return end if valid_header else 0


class FrameParser:
    """Incremental decoder: feed it bytes in any chunking, get samples and replies out.

    Never raises on bad input; every byte that is not part of a valid frame is counted as
    discarded, every frame that fails its CRC as corrupted, every gap in the sequence counter
    as lost frames.

    Runs of well-formed sample frames of one layout (current or older firmware) are checked
    and decoded with numpy in one go; only replies, damaged frames and partial frames take
    the byte-by-byte path.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._last_seq: int | None = None
        self._last_t_us: int | None = None
        self._t_wraps = 0
        # end (buffer index) of the last frame counted as corrupted: a sync word found
        # inside its bytes is not counted a second time
        self._bad_until = 0
        self.frames_ok = 0
        self.frames_lost = 0
        self.frames_corrupted = 0
        self.bytes_discarded = 0

    def reset_sequence(self) -> None:
        """Forget the last sequence number (call when streaming restarts)."""
        self._last_seq = None
        self._last_t_us = None
        self._t_wraps = 0

    @property
    def buffered_bytes(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> ParseResult:
        buf = self._buf
        buf += data
        runs, replies, corrupted, discarded, pos = self._scan(buf)
        del buf[:pos]
        self._bad_until = max(0, self._bad_until - pos)
        self.frames_corrupted += corrupted
        self.bytes_discarded += discarded
        self.frames_ok += len(replies)
        if not runs:
            return ParseResult(
                seq=_EMPTY_I,
                time_s=_EMPTY_F,
                rate_code=_EMPTY_I,
                temp_code=_EMPTY_I,
                status=_EMPTY_I,
                encoder=_EMPTY_I,
                replies=replies,
                frames_lost=0,
                frames_corrupted=corrupted,
                bytes_discarded=discarded,
            )
        if any(_is_three_axis(run) for run in runs):
            return self._three_axis_result(runs, replies, corrupted, discarded)
        return self._single_axis_result(runs, replies, corrupted, discarded)

    def _scan(
        self, buf: bytearray
    ) -> tuple[list[NDArray[np.void]], list[str], int, int, int]:
        """The frames in `buf`: runs of sample frames, replies, frames corrupted, bytes
        discarded, and how many bytes were consumed (the rest waits for more)."""
        runs: list[NDArray[np.void]] = []
        replies: list[str] = []
        corrupted = discarded = 0
        pos = 0
        n = len(buf)
        bad_until = self._bad_until
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
            run = self._sample_run(buf, start, n)
            if run is not None:
                frames, size = run
                runs.append(frames)
                pos = start + frames.shape[0] * size
                continue
            end = _frame_end(buf, start, n)
            if not end:
                discarded += 1
                pos = start + 1
                continue
            if end > n:
                pos = start
                break
            body = bytes(buf[start + 2 : end - CRC_SIZE])
            (crc,) = struct.unpack_from(">I", buf, end - CRC_SIZE)
            if crc32(body) != crc:
                if start >= bad_until:
                    corrupted += 1
                    bad_until = end
                discarded += 1
                pos = start + 1
                continue
            # a valid sample frame is always taken by _sample_run, so this is a reply
            replies.append(body[2:].decode("ascii", "replace"))
            pos = end
        self._bad_until = bad_until
        return runs, replies, corrupted, discarded, pos

    def _single_axis_result(
        self, runs: list[NDArray[np.void]], replies: list[str], corrupted: int, discarded: int
    ) -> ParseResult:
        frames = runs[0] if len(runs) == 1 else np.concatenate(runs)
        seq = frames["seq"].astype(np.int64)
        time_s, lost = self._timeline(seq, frames["t_us"].astype(np.int64))
        return ParseResult(
            seq=seq,
            time_s=time_s,
            rate_code=_u24(frames["rate"]),
            temp_code=_u24(frames["temp"]),
            status=frames["status"].astype(np.int64),
            encoder=frames["encoder"].astype(np.int64),
            replies=replies,
            frames_lost=lost,
            frames_corrupted=corrupted,
            bytes_discarded=discarded,
        )

    def _timeline(self, seq: NDArray[np.int64], t_us: NDArray[np.int64]) -> tuple[
        NDArray[np.float64], int
    ]:
        """The frames' unwrapped times (s) and the frames lost before and between them,
        counted into the parser's totals."""
        lost = self._count_lost(seq)
        time_us = self._unwrap_time(t_us)
        self.frames_ok += seq.size
        self.frames_lost += lost
        return time_us.astype(np.float64) * 1e-6, lost

    def _three_axis_result(
        self, runs: list[NDArray[np.void]], replies: list[str], corrupted: int, discarded: int
    ) -> ParseResult:
        """A call's result when it decoded three-axis frames (runs of either kind, in order)."""
        rates, accels = [], []
        for run in runs:
            if _is_three_axis(run):
                rates.append(_u24(run["rate"]))
                accels.append(_u24(run["accel"]))
            else:  # not expected in one stream: x carries the rate code, the rest 0
                xyz = np.zeros((run.shape[0], 3), dtype=np.int64)
                xyz[:, 0] = _u24(run["rate"])
                rates.append(xyz)
                accels.append(np.zeros((run.shape[0], 3), dtype=np.int64))
        common = ("seq", "t_us", "temp", "status", "encoder")
        parts = [{name: run[name] for name in common} for run in runs]
        seq = np.concatenate([p["seq"] for p in parts]).astype(np.int64)
        t_us = np.concatenate([p["t_us"] for p in parts]).astype(np.int64)
        rate_xyz = np.concatenate(rates)
        time_s, lost = self._timeline(seq, t_us)
        return ParseResult(
            seq=seq,
            time_s=time_s,
            rate_code=rate_xyz[:, 0].copy(),
            temp_code=np.concatenate([_u24(p["temp"]) for p in parts]),
            status=np.concatenate([p["status"] for p in parts]).astype(np.int64),
            encoder=np.concatenate([p["encoder"] for p in parts]).astype(np.int64),
            replies=replies,
            frames_lost=lost,
            frames_corrupted=corrupted,
            bytes_discarded=discarded,
            rate_code_xyz=rate_xyz,
            accel_code_xyz=np.concatenate(accels),
        )

    @staticmethod
    def _sample_run(buf: bytearray, start: int, n: int) -> tuple[NDArray[np.void], int] | None:
        """The longest run of intact sample frames of one layout at `start` (a copy, in the
        current layout: an older firmware's frames get encoder 0; three-axis frames in their
        own) and its frame size, or None.
        """
        if buf[start + 2] == _TYPE_SAMPLE3:
            dtype = _SAMPLE3_DTYPE if buf[start + 3] == SAMPLE3_PAYLOAD_SIZE else None
        else:
            dtype = _SAMPLE_DTYPES.get(buf[start + 3])
        if dtype is None:
            return None
        size = dtype.itemsize
        count = (n - start) // size
        if count == 0:
            return None
        chunk = bytes(buf[start : start + count * size])
        frames = np.frombuffer(chunk, dtype=dtype)
        header_ok = (
            (frames["sync"] == _SYNC_WORD)
            & (frames["type"] == (_TYPE_SAMPLE3 if dtype is _SAMPLE3_DTYPE else _TYPE_SAMPLE))
            & (frames["len"] == size - HEADER_SIZE - CRC_SIZE)
        )
        good = count if bool(header_ok.all()) else int(np.argmin(header_ok))
        if good == 0:
            return None
        raw = np.frombuffer(chunk, dtype=np.uint8, count=good * size)
        crc_ok = _sample_crcs(raw.reshape(good, size)) == frames["crc"][:good]
        if not bool(crc_ok.all()):
            good = int(np.argmin(crc_ok))
            if good == 0:
                return None
        frames = frames[:good]
        if dtype is _LEGACY_SAMPLE_DTYPE:
            current = np.zeros(good, dtype=_SAMPLE_DTYPE)  # encoder 0
            for name in dtype.names or ():
                current[name] = frames[name]
            frames = current
        return frames, size

    def _count_lost(self, seq: NDArray[np.int64]) -> int:
        prev = np.empty_like(seq)
        prev[1:] = seq[:-1]
        prev[0] = seq[0] - 1 if self._last_seq is None else self._last_seq
        self._last_seq = int(seq[-1])
        return int(((seq - prev - 1) % SEQ_MODULO).sum())

    def _unwrap_time(self, t_us: NDArray[np.int64]) -> NDArray[np.int64]:
        prev = np.empty_like(t_us)
        prev[1:] = t_us[:-1]
        prev[0] = t_us[0] if self._last_t_us is None else self._last_t_us
        wraps = np.cumsum(t_us < prev - _HALF_TIME_US) + self._t_wraps
        self._t_wraps = int(wraps[-1])
        self._last_t_us = int(t_us[-1])
        return t_us + wraps * TIME_MODULO_US
