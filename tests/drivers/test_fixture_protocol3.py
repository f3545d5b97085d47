"""The three-axis sample frame (docs/fixture-protocol.md section 7): exact bytes, the page's
worked example, chunked and corrupted streams, replies in between."""

from __future__ import annotations

import re
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from drivers import fixture_protocol as fp
from drivers.part_codes import ADIS16130

DOC = Path(__file__).resolve().parents[2] / "docs" / "fixture-protocol.md"


def _stream3(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    seq = np.arange(n, dtype=np.int64)
    t_us = 5_000 + seq * 5000
    rate = rng.integers(0, fp.CODE_MAX + 1, (n, 3))
    accel = rng.integers(0, fp.CODE_MAX + 1, (n, 3))
    temp = rng.integers(0, fp.CODE_MAX + 1, n)
    status = rng.integers(0, 64, n)
    encoder = rng.integers(0, fp.ENCODER_MODULO, n)
    data = fp.encode_samples3(seq, t_us, rate, accel, temp, status, encoder)
    return data, seq, t_us, rate, accel, temp, status, encoder


def test_three_axis_frame_bytes_field_by_field() -> None:
    data = fp.encode_samples3(
        np.array([0x1234]), np.array([0x075BCD15]), np.array([[1, 0x020304, 0xFFFFFF]]),
        np.array([[0xABCDEF, 0, 7]]), np.array([0x800000]), np.array([0x25]),
        np.array([-1]),
    )
    assert len(data) == fp.SAMPLE3_FRAME_SIZE == 40
    expected_body = (
        bytes([0x03, 32]) + b"\x12\x34" + b"\x07\x5b\xcd\x15"
        + b"\x00\x00\x01" + b"\x02\x03\x04" + b"\xff\xff\xff"
        + b"\xab\xcd\xef" + b"\x00\x00\x00" + b"\x00\x00\x07"
        + b"\x80\x00\x00" + b"\x25" + b"\xff\xff\xff\xff"
    )
    assert data == b"\xa5\x5a" + expected_body + struct.pack(">I", zlib.crc32(expected_body))


def test_three_axis_stream_decodes_losslessly_in_any_chunking() -> None:
    data, seq, t_us, rate, accel, temp, status, encoder = _stream3(300)
    for chunk in (1, 7, 40, 4096):
        parser = fp.FrameParser()
        out = [parser.feed(data[i : i + chunk]) for i in range(0, len(data), chunk)]
        got = [r for r in out if r.seq.size]
        assert all(r.rate_code_xyz is not None and r.accel_code_xyz is not None for r in got)
        np.testing.assert_array_equal(np.concatenate([r.seq for r in got]), seq)
        np.testing.assert_allclose(np.concatenate([r.time_s for r in got]), t_us * 1e-6)
        xyz = np.concatenate([r.rate_code_xyz for r in got])  # type: ignore[misc]
        np.testing.assert_array_equal(xyz, rate)
        np.testing.assert_array_equal(np.concatenate([r.rate_code for r in got]), rate[:, 0])
        np.testing.assert_array_equal(
            np.concatenate([r.accel_code_xyz for r in got]), accel  # type: ignore[misc]
        )
        np.testing.assert_array_equal(np.concatenate([r.temp_code for r in got]), temp)
        np.testing.assert_array_equal(np.concatenate([r.status for r in got]), status)
        np.testing.assert_array_equal(np.concatenate([r.encoder for r in got]), encoder)
        assert parser.frames_lost == parser.frames_corrupted == parser.bytes_discarded == 0


def test_single_axis_results_carry_no_xyz_columns() -> None:
    one = fp.encode_samples(np.array([0]), np.array([0]), np.array([5]), np.array([6]),
                            np.array([0]))
    res = fp.FrameParser().feed(one)
    assert res.rate_code_xyz is None and res.accel_code_xyz is None


def test_a_corrupted_three_axis_frame_is_counted_and_the_parser_resynchronises() -> None:
    data, seq, *_ = _stream3(50, seed=2)
    raw = bytearray(data)
    raw[10 * fp.SAMPLE3_FRAME_SIZE + 15] ^= 0x40  # inside frame 10's gyro codes
    reply = fp.encode_reply("OK 3")
    cut = 20 * fp.SAMPLE3_FRAME_SIZE
    res = fp.FrameParser().feed(bytes(raw[:cut]) + reply + bytes(raw[cut:]))
    assert res.frames_corrupted == 1 and res.frames_lost == 1
    assert res.replies == ["OK 3"]
    assert 10 not in res.seq.tolist() and res.seq.size == 49


def test_the_pages_three_axis_example_decodes_to_what_it_says() -> None:
    text = DOC.read_text(encoding="utf-8")
    m = re.search(r"<!-- example: sample3 -->\s*```text\n(.*?)```", text, re.S)
    assert m is not None
    frame = bytes.fromhex(m.group(1))
    res = fp.FrameParser().feed(frame)
    assert res.frames_corrupted == 0 and res.bytes_discarded == 0 and res.seq.tolist() == [4660]
    assert res.rate_code_xyz is not None and res.accel_code_xyz is not None
    np.testing.assert_allclose(ADIS16130.rate_code_to_dps(res.rate_code_xyz)[0],
                               [10.0, -5.0, 0.5], atol=1e-4)
    np.testing.assert_allclose(ADIS16130.accel_code_to_mps2(res.accel_code_xyz)[0],
                               [0.0, 0.0, 9.80665], atol=1e-5)
    assert res.encoder.tolist() == [fp.ENCODER_MODULO - 1000]
    for word in ("AXES?", "CAL3?", "CAL3 "):
        assert f"`{word}" in text


@pytest.mark.parametrize(("axes", "size"), [(1, fp.SAMPLE_FRAME_SIZE), (3, 40)])
def test_stream_baud_counts_the_frame_kind(axes: int, size: int) -> None:
    assert fp.sample_stream_baud(200, axes) == 200 * size * 10


def test_a_single_axis_frame_among_three_axis_ones_keeps_its_place_and_rate() -> None:
    data, seq, _, rate, *_ = _stream3(4, seed=4)
    one = fp.encode_samples(np.array([4]), np.array([25_000]), np.array([1234]),
                            np.array([5]), np.array([0]))
    res = fp.FrameParser().feed(data + one)
    assert res.seq.tolist() == [0, 1, 2, 3, 4] and res.frames_lost == 0
    assert res.rate_code_xyz is not None and res.accel_code_xyz is not None
    assert res.rate_code_xyz[4].tolist() == [1234, 0, 0]
    assert res.accel_code_xyz[4].tolist() == [0, 0, 0]
    assert res.rate_code.tolist() == [*rate[:, 0].tolist(), 1234]


def test_mutated_three_axis_streams_never_raise_nor_invent_frames() -> None:
    data, seq, *_ = _stream3(200, seed=8)
    rng = np.random.default_rng(8)
    for _ in range(30):
        raw = np.frombuffer(data, dtype=np.uint8).copy()
        hits = rng.random(raw.size) < rng.uniform(0.0, 0.01)
        raw[hits] ^= rng.integers(1, 256, int(hits.sum()), dtype=np.uint8)
        parser = fp.FrameParser()
        cut = int(rng.integers(1, raw.size))
        results = [parser.feed(raw[:cut].tobytes()), parser.feed(raw[cut:].tobytes())]
        got = np.concatenate([r.seq for r in results])
        assert set(got.tolist()) <= set(seq.tolist())  # no frame invented
        intact = ~hits.reshape(-1, fp.SAMPLE3_FRAME_SIZE).any(axis=1)
        assert set(seq[intact].tolist()) <= set(got.tolist())  # every intact frame decoded
