"""Frame format and parser: byte layout, 10^6 frames lossless, corruption counted exactly,
and property-based tests (arbitrary and mutated bytes)."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers import fixture_protocol as fp


def _stream(n: int, *, seed: int = 0, seq0: int = 0, t0_us: int = 0, legacy_until: int = 0):
    """n sample frames and the columns the parser must give back. Frames before
    `legacy_until` use the older firmware's layout (no encoder: decoded as 0, bit clear);
    the others carry a random encoder count with ENCODER_LATCHED set."""
    rng = np.random.default_rng(seed)
    seq = np.arange(seq0, seq0 + n, dtype=np.int64)
    t_us = t0_us + np.arange(n, dtype=np.int64) * 1000
    rate = rng.integers(0, fp.CODE_MAX + 1, n)
    temp = rng.integers(0, fp.CODE_MAX + 1, n)
    status = rng.integers(0, 32, n)
    encoder = rng.integers(0, fp.ENCODER_MODULO, n)
    k = min(max(legacy_until, 0), n)
    encoder[:k] = 0
    status[k:] |= fp.SampleStatus.ENCODER_LATCHED
    old = fp.encode_samples(seq[:k], t_us[:k], rate[:k], temp[:k], status[:k], legacy=True)
    new = fp.encode_samples(seq[k:], t_us[k:], rate[k:], temp[k:], status[k:], encoder[k:])
    return old + new, seq, t_us, rate, temp, status, encoder


def _feed_chunks(parser: fp.FrameParser, data: bytes, chunk: int):
    out = [parser.feed(data[i : i + chunk]) for i in range(0, len(data), chunk)]
    return (
        np.concatenate([r.seq for r in out]),
        np.concatenate([r.time_s for r in out]),
        np.concatenate([r.rate_code for r in out]),
        np.concatenate([r.temp_code for r in out]),
        np.concatenate([r.status for r in out]),
        np.concatenate([r.encoder for r in out]),
        [t for r in out for t in r.replies],
    )


def _assert_decoded(got, seq, t_us, rate, temp, status, encoder):
    got_seq, got_t, got_rate, got_temp, got_status, got_encoder, _ = got
    np.testing.assert_array_equal(got_seq, seq % fp.SEQ_MODULO)
    np.testing.assert_allclose(got_t, t_us * 1e-6, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(got_rate, rate)
    np.testing.assert_array_equal(got_temp, temp)
    np.testing.assert_array_equal(got_status, status)
    np.testing.assert_array_equal(got_encoder, encoder)


# ---------------------------------------------------------------- byte layout


def test_sample_frame_bytes_are_exactly_the_documented_layout():
    status = fp.SampleStatus.OVER_RANGE | fp.SampleStatus.ENCODER_LATCHED
    data = fp.encode_samples(
        np.array([0x1234]), np.array([0x0A0B0C0D]), np.array([0x800000]),
        np.array([0x7A9F3B]), np.array([status]), np.array([(1 << 32) + 0x01020304]),
    )
    body = bytes([0x01, 17, 0x12, 0x34, 0x0A, 0x0B, 0x0C, 0x0D,
                  0x80, 0x00, 0x00, 0x7A, 0x9F, 0x3B, 0x21, 0x01, 0x02, 0x03, 0x04])
    assert data == b"\xa5\x5a" + body + struct.pack(">I", zlib.crc32(body))
    assert len(data) == fp.SAMPLE_FRAME_SIZE
    res = fp.FrameParser().feed(data)
    assert res.encoder.tolist() == [0x01020304]  # the counter wraps at 2^32
    assert res.status.tolist() == [int(status)]
    # without an encoder input the field is 0 and the bit stays clear
    bare = fp.FrameParser().feed(fp.encode_samples(
        np.array([1]), np.array([2]), np.array([3]), np.array([4]), np.array([0])))
    assert bare.encoder.tolist() == [0] and bare.status.tolist() == [0]


def test_legacy_sample_frame_bytes_are_the_older_firmwares_layout():
    data = fp.encode_samples(
        np.array([0x1234]), np.array([0x0A0B0C0D]), np.array([0x800000]),
        np.array([0x7A9F3B]), np.array([fp.SampleStatus.OVER_RANGE]), legacy=True,
    )
    body = bytes([0x01, 13, 0x12, 0x34, 0x0A, 0x0B, 0x0C, 0x0D,
                  0x80, 0x00, 0x00, 0x7A, 0x9F, 0x3B, 0x01])
    assert data == b"\xa5\x5a" + body + struct.pack(">I", zlib.crc32(body))
    assert len(data) == fp.LEGACY_SAMPLE_FRAME_SIZE
    res = fp.FrameParser().feed(data)
    assert res.seq.tolist() == [0x1234] and res.rate_code.tolist() == [0x800000]
    assert res.encoder.tolist() == [0] and res.status.tolist() == [1]
    with pytest.raises(ValueError, match="no encoder"):
        fp.encode_samples(np.array([1]), np.array([2]), np.array([3]), np.array([4]),
                          np.array([0]), np.array([5]), legacy=True)


def test_reply_frame_bytes_and_decode():
    frame = fp.encode_reply("OK SIM-0001")
    body = b"\x02\x0bOK SIM-0001"
    assert frame == b"\xa5\x5a" + body + struct.pack(">I", zlib.crc32(body))
    result = fp.FrameParser().feed(frame)
    assert result.replies == ["OK SIM-0001"]
    assert len(result.seq) == 0


def test_seq_and_time_wrap_and_are_unwrapped():
    n = 3000
    seq0 = fp.SEQ_MODULO - 1000
    t0 = fp.TIME_MODULO_US - 500_000  # wraps after 500 frames of 1 ms
    data, *expected = _stream(n, seq0=seq0, t0_us=t0)
    parser = fp.FrameParser()
    got = _feed_chunks(parser, data, 997)
    assert parser.frames_lost == 0
    _assert_decoded(got, *expected)
    assert np.all(np.diff(got[1]) > 0)


def test_code_conversions_match_the_adis16130_numbers():
    assert fp.rate_dps_to_code(np.array([0.0, 250.0]))[1] == 14_260_608
    assert fp.rate_code_to_dps(8_388_608) == 0.0
    back_c = fp.temp_code_to_c(fp.temp_c_to_code(np.array([25.0])))[0]
    assert back_c == pytest.approx(25.0, abs=1e-4)


# ---------------------------------------------------------------- 10^6 frames


def test_million_frames_none_lost_all_values_exact():
    n = 1_000_000
    data, *expected = _stream(n, seed=1)
    parser = fp.FrameParser()
    got = _feed_chunks(parser, data, 4096)
    assert got[0].size == n
    assert parser.frames_ok == n
    assert parser.frames_lost == 0 and parser.frames_corrupted == 0
    assert parser.bytes_discarded == 0
    _assert_decoded(got, *expected)
    assert got[-1] == []


def test_million_frames_with_corruption_and_drops_counted_exactly():
    n = 1_000_000
    data, seq, *_, encoder = _stream(n, seed=2)
    rng = np.random.default_rng(3)
    # damaged frames never adjacent, so each damaged frame is followed by an intact one
    victims = np.unique(rng.choice(n // 2, size=3000, replace=False) * 2)
    kind = rng.integers(0, 2, victims.size)  # 0: flip a byte, 1: drop the frame
    offset = rng.integers(0, fp.SAMPLE_FRAME_SIZE, victims.size)
    frames = np.frombuffer(data, dtype=np.uint8).reshape(n, fp.SAMPLE_FRAME_SIZE).copy()
    keep = np.ones(n, dtype=bool)
    flipped = victims[kind == 0]
    frames[flipped, offset[kind == 0]] ^= 0x10
    keep[victims[kind == 1]] = False
    stream = frames[keep].tobytes()
    parser = fp.FrameParser()
    got_seq, *_, got_encoder, _ = _feed_chunks(parser, stream, 4093)
    expected = np.setdiff1d(np.arange(n), victims)
    np.testing.assert_array_equal(got_seq, expected % fp.SEQ_MODULO)  # none passed on
    np.testing.assert_array_equal(got_encoder, encoder[expected])
    assert parser.frames_lost == victims.size
    # a flip in the payload or CRC fails the CRC; one in sync/type/length makes noise
    assert parser.frames_corrupted == int(np.sum(offset[kind == 0] >= fp.HEADER_SIZE))
    assert parser.frames_ok == expected.size


def test_resynchronises_on_the_very_next_frame_after_each_kind_of_damage():
    data, *_ = _stream(5)
    size = fp.SAMPLE_FRAME_SIZE
    def flip(at: int, mask: int) -> bytes:
        return data[:at] + bytes([data[at] ^ mask]) + data[at + 1 :]

    cases = {
        "flip crc": (flip(2 * size + 20, 1), 1),
        "flip payload": (flip(2 * size + 9, 0x80), 1),
        "truncate": (data[: 2 * size + 9] + data[3 * size :], 1),
        "flip sync": (data[: 2 * size] + b"\xa4" + data[2 * size + 1 :], 0),
    }
    for name, (stream, corrupted) in cases.items():
        for chunk in (1, 7, len(stream)):
            parser = fp.FrameParser()
            got, *_ = _feed_chunks(parser, stream, chunk)
            assert list(got) == [0, 1, 3, 4], (name, chunk)
            assert parser.frames_lost == 1, (name, chunk)
            assert parser.frames_corrupted == corrupted, (name, chunk)


def test_false_sync_announcing_a_long_reply_does_not_hold_back_the_next_frames():
    data, *_ = _stream(3)
    for garbage in (b"\xa5\x5a\x02\xf0\x00", b"\xa5\x5a\x02\xf0OK"):
        parser = fp.FrameParser()
        got, *_ = _feed_chunks(parser, garbage + data, 5)
        assert list(got) == [0, 1, 2]
        assert parser.frames_lost == 0
        assert parser.bytes_discarded == len(garbage)


def test_reply_between_samples_is_delivered_and_samples_keep_order():
    data, *_ = _stream(4)
    size = fp.SAMPLE_FRAME_SIZE
    stream = data[: 2 * size] + fp.encode_reply("OK bias=0.0") + data[2 * size :]
    for chunk in (3, 64, len(stream)):
        got, *_, replies = _feed_chunks(fp.FrameParser(), stream, chunk)
        assert list(got) == [0, 1, 2, 3]
        assert replies == ["OK bias=0.0"]


# ---------------------------------------------------------------- older fixture firmware


def test_vector_crc_matches_zlib_for_both_frame_layouts():
    # the table-driven numpy CRC (runs of >= _VECTOR_CRC_MIN_FRAMES) against zlib per frame
    n = fp._VECTOR_CRC_MIN_FRAMES + 3
    for legacy_until, size in ((0, fp.SAMPLE_FRAME_SIZE), (n, fp.LEGACY_SAMPLE_FRAME_SIZE)):
        data, *_ = _stream(n, seed=5, legacy_until=legacy_until)
        raw = np.frombuffer(data, dtype=np.uint8).reshape(n, size)
        want = [zlib.crc32(bytes(row[2 : size - fp.CRC_SIZE])) for row in raw]
        assert fp._sample_crcs(raw).tolist() == want
        assert fp._sample_crcs(raw[:7]).tolist() == want[:7]  # the per-frame zlib path


@pytest.mark.parametrize("chunk", [1, 7, 20, 21, 22, 997, 50_000])
def test_older_firmware_frames_decode_with_encoder_zero(chunk):
    n = 1000  # the whole stream in one feed takes the vectorised CRC path
    data, *expected = _stream(n, seed=6, seq0=fp.SEQ_MODULO - 300, legacy_until=n)
    assert len(data) == n * fp.LEGACY_SAMPLE_FRAME_SIZE
    parser = fp.FrameParser()
    got = _feed_chunks(parser, data, chunk)
    _assert_decoded(got, *expected)
    assert not got[5].any()  # encoder 0
    assert not (got[4] & fp.SampleStatus.ENCODER_LATCHED).any()
    assert parser.frames_ok == n
    assert parser.frames_lost == parser.frames_corrupted == parser.bytes_discarded == 0
    assert parser.buffered_bytes == 0


@pytest.mark.parametrize("chunk", [1, 7, 23, 500, 997, 50_000])
@pytest.mark.parametrize("switch", [1, 450, 999])
def test_firmware_update_mid_stream_decodes_every_sample(chunk, switch):
    # old frames until `switch`, then the new layout, seq and time running on (and back)
    n = 1000
    data, *expected = _stream(n, seed=7, legacy_until=switch)
    parser = fp.FrameParser()
    got = _feed_chunks(parser, data, chunk)
    _assert_decoded(got, *expected)
    assert not got[5][:switch].any() and got[5][switch:].any()
    assert parser.frames_ok == n
    assert parser.frames_lost == parser.frames_corrupted == parser.bytes_discarded == 0
    # and back: new frames, then old ones, a reply between
    new, seq, *_ = _stream(10, seed=8)
    old, *_ = _stream(5, seed=9, seq0=10, t0_us=10_000, legacy_until=5)
    stream = new + fp.encode_reply("OK") + old
    got = _feed_chunks(fp.FrameParser(), stream, chunk)
    assert got[0].tolist() == list(range(15)) and got[-1] == ["OK"]


def test_damaged_frame_at_the_firmware_switch_costs_only_that_frame():
    n, switch = 40, 20
    data, *_ = _stream(n, seed=10, legacy_until=switch)
    old_size = fp.LEGACY_SAMPLE_FRAME_SIZE
    for victim, at in ((switch - 1, (switch - 1) * old_size + 9), (switch, switch * old_size + 9)):
        stream = data[:at] + bytes([data[at] ^ 0x40]) + data[at + 1 :]
        for chunk in (1, 13, len(stream)):
            parser = fp.FrameParser()
            got = _feed_chunks(parser, stream, chunk)
            assert got[0].tolist() == [i for i in range(n) if i != victim], (victim, chunk)
            assert parser.frames_lost == parser.frames_corrupted == 1, (victim, chunk)


# ---------------------------------------------------------------- property-based


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600), st.integers(1, 64))
def test_arbitrary_bytes_never_crash_and_never_yield_a_sample(data, chunk):
    parser = fp.FrameParser()
    total = 0
    for i in range(0, len(data), chunk):
        total += len(parser.feed(data[i : i + chunk]).seq)
    # a random 25-byte (or older firmware's 21-byte) window passing sync, type, length and
    # CRC-32 has odds below 2^-56
    assert total == 0
    assert parser.buffered_bytes <= fp.HEADER_SIZE + fp.MAX_REPLY_PAYLOAD + fp.CRC_SIZE


_mutation = st.one_of(
    st.tuples(st.just("flip"), st.integers(0, 10_000), st.integers(1, 255)),
    st.tuples(st.just("delete"), st.integers(0, 10_000), st.integers(1, 40)),
    st.tuples(st.just("insert"), st.integers(0, 10_000), st.binary(min_size=1, max_size=30)),
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(_mutation, max_size=8),
    st.integers(1, 200),
    st.integers(0, 999),
    st.sampled_from([0, 25, 60]),  # older firmware's frames: none, the first 25, all
)
def test_mutated_stream_never_passes_a_damaged_frame(mutations, chunk, seed, legacy_until):
    n = 60
    data, seq, t_us, rate, temp, status, encoder = _stream(
        n, seed=seed, legacy_until=legacy_until
    )
    originals = {
        int(s): (int(t), int(r), int(c), int(x), int(e))
        for s, t, r, c, x, e in zip(seq, t_us, rate, temp, status, encoder, strict=True)
    }
    stream = bytearray(data)
    for op, where, arg in mutations:
        at = where % (len(stream) + 1)
        if op == "flip" and at < len(stream):
            stream[at] ^= arg
        elif op == "delete":
            del stream[at : at + arg]
        elif op == "insert":
            stream[at:at] = arg
    parser = fp.FrameParser()
    got_seq, got_t, got_rate, got_temp, got_status, got_encoder, _ = _feed_chunks(
        parser, bytes(stream), chunk
    )
    # every sample passed on is an original frame, unchanged, in order
    assert list(got_seq) == sorted(set(int(s) for s in got_seq))
    for s, t, r, c, x, e in zip(
        got_seq, got_t, got_rate, got_temp, got_status, got_encoder, strict=True
    ):
        assert originals[int(s)] == (round(t * 1e6), int(r), int(c), int(x), int(e))
    # every frame not passed on between the first and the last delivered is counted lost
    if got_seq.size:
        assert parser.frames_lost == int(got_seq[-1] - got_seq[0] + 1 - got_seq.size)


@settings(max_examples=150, deadline=None)
@given(
    st.integers(1, 18),
    st.sampled_from(["flip", "delete", "insert"]),
    st.integers(0, fp.SAMPLE_FRAME_SIZE - 1),
    st.integers(1, 255),
    st.integers(1, 64),
    st.booleans(),
)
def test_one_damaged_frame_costs_exactly_that_frame(k, op, offset, value, chunk, legacy):
    n = 20
    data, *_ = _stream(n, seed=k, legacy_until=n if legacy else 0)
    size = fp.LEGACY_SAMPLE_FRAME_SIZE if legacy else fp.SAMPLE_FRAME_SIZE
    offset %= size
    frame = bytearray(data[k * size : (k + 1) * size])
    if op == "flip":
        frame[offset] ^= value
    elif op == "delete":
        del frame[offset : offset + 1 + value % 20]
    else:
        frame[offset:offset] = bytes([value]) * (1 + value % 7)
    stream = data[: k * size] + bytes(frame) + data[(k + 1) * size :]
    parser = fp.FrameParser()
    got, *_ = _feed_chunks(parser, stream, chunk)
    expected = [i for i in range(n) if i != k]
    if op == "flip":
        assert list(got) == expected
    else:  # an insertion at the frame's very start leaves the frame itself intact
        assert list(got) in (expected, list(range(n)))
    assert parser.frames_lost == n - len(got)
