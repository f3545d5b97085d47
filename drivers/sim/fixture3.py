"""The fixture socket's three-axis part: its commands and its sample frames.

Kept apart from drivers/sim/fixture.py (which calls in here for a three-axis part only), so a
single-axis socket runs exactly the code it ran before. Wire format: docs/fixture-protocol.md
section 7 (`AXES?`, `CAL3? <key>`, `CAL3 <key>=<v>,...`, frame type 0x03).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers import fixture_protocol as fp
from drivers.part_codes import ADIS16130
from drivers.sim.gyro import PartModel
from drivers.sim.gyro3 import PartModel3

if TYPE_CHECKING:
    from drivers.sim.fixture import FixtureSocket

_ERR = fp.ReplyError


def _err(code: fp.ReplyError, text: str) -> str:
    return f"ERR {int(code)} {text}"


def answer(sock: FixtureSocket, text: str, part_error: str | None) -> str | None:
    """The reply to a three-axis command (or to CAL?/CAL on a three-axis part); None for any
    other command (the socket answers it as before)."""
    upper = text.upper()
    word = upper.split(" ", 1)[0]
    part = sock.part
    if word == fp.Command.AXES:
        return part_error or f"OK {3 if isinstance(part, PartModel3) else 1}"
    if word not in ("CAL3?", "CAL3", "CAL?", "CAL"):
        return None
    if word in ("CAL?", "CAL"):  # single-axis register commands
        if part_error is None and isinstance(part, PartModel3):
            return _err(_ERR.BAD_REGISTER, "three-axis part: use CAL3? <key> and CAL3")
        return None
    if part_error:
        return part_error
    if not isinstance(part, PartModel3):
        return _err(_ERR.BAD_REGISTER, "single-axis part: use CAL? and CAL")
    if word == "CAL3?":
        return _read(part, text[5:].strip().lower())
    return _write(part, text[4:])


def _unknown(key: str) -> str:
    return _err(_ERR.BAD_REGISTER, f"no register {key[:20]!r}; use {','.join(fp.CAL3_KEYS)}")


def _values(part: PartModel3, key: str) -> list[float]:
    return [float(v) for v in np.ravel(getattr(part.cal3, fp.CAL3_FIELDS[key]))]


def _read(part: PartModel3, key: str) -> str:
    if key not in fp.CAL3_SIZES:
        return _unknown(key)
    return f"OK {key}=" + ",".join(repr(v) for v in _values(part, key))


def _write(part: PartModel3, assignments: str) -> str:
    updates: dict[str, Any] = {}
    for item in assignments.split():
        key, sep, value = item.partition("=")
        key = key.lower()
        if not sep:
            return _err(_ERR.SYNTAX, f"expected key=v,v,..., got {item[:30]!r}")
        if key not in fp.CAL3_SIZES:
            return _unknown(key)
        try:
            numbers = [float(v) for v in value.split(",")]
        except ValueError:
            return _err(_ERR.SYNTAX, f"{key}: not a number")
        size = fp.CAL3_SIZES[key]
        if len(numbers) != size:
            return _err(_ERR.SYNTAX, f"{key}: needs {size} values, got {len(numbers)}")
        if not all(math.isfinite(v) for v in numbers):
            return _err(_ERR.OUT_OF_RANGE, f"{key}: not finite")
        updates[fp.CAL3_FIELDS[key]] = (
            numbers[0] if size == 1 else np.reshape(numbers, (3, 3)) if size == 9 else numbers
        )
    if not updates:
        return _err(_ERR.SYNTAX, "no assignments")
    new = replace(part.cal3, **updates)
    if abs(float(np.linalg.det(np.asarray(new.matrix)))) < 1e-6:
        return _err(_ERR.OUT_OF_RANGE, "matrix is singular")
    part.cal3 = new
    return "OK"


def produce(
    sock: FixtureSocket,
    part: PartModel,
    times: np.ndarray,
    table_rate_dps: np.ndarray,
    table_angle_deg: np.ndarray,
    supply_v: float,
    dt_s: float,
) -> bytes:
    """The three-axis sample frames of one batch: the table's mean rate over each period is
    about the table's (vertical) axis, seen in the part frame through the cube's attitude,
    plus the operator's turning; the accelerometer reads gravity through the same attitude."""
    assert isinstance(part, PartModel3)
    world = sock.world
    up = sock.cube.up_in_part(times)
    rate_xyz = up * table_rate_dps[:, None] + sock.cube.turn_rate_dps(times)
    accel = part.accel_output(sock.cube.specific_force_mps2(times))
    raw, die = part.raw_output3(times, rate_xyz, accel, supply_v, dt_s)
    n = times.size
    status = np.zeros(n, dtype=np.int64)
    encoder = None
    if world.config.fixture.encoder_input:
        encoder = world.table.absolute_counts(table_angle_deg)
        status |= fp.SampleStatus.ENCODER_LATCHED
    out = raw
    if part.compensation:
        out = part.compensate3(raw, accel, die, supply_v)
        status |= fp.SampleStatus.COMPENSATED
    rate_code = ADIS16130.rate_dps_to_code(out)
    status[(np.abs(out) > fp.RATED_RANGE_DPS).any(axis=1)] |= fp.SampleStatus.OVER_RANGE
    status[ADIS16130.rate_code_at_rail(rate_code).any(axis=1)] |= fp.SampleStatus.SATURATED
    if supply_v < world.config.part_physics.supply_low_v:
        status |= fp.SampleStatus.SUPPLY_LOW
    temp_noise = sock.rng.normal(0.0, world.config.part_physics.temp_noise_c, n)
    seq = sock.seq + np.arange(n, dtype=np.int64)
    sock.seq += n
    sock.frames_sent += n
    return fp.encode_samples3(
        seq,
        np.rint((times + sock.clock_offset_s) * 1e6).astype(np.int64),
        rate_code,
        ADIS16130.accel_mps2_to_code(accel),
        fp.temp_c_to_code(die + temp_noise),
        status,
        encoder,
    )
