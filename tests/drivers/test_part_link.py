"""Part link over a real pty against a scripted fixture: command bytes, replies, calibration
write and read-back, streaming without loss, damage counted, silence and absence typed."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from common.clock import ScaledClock
from drivers import fixture_protocol as fp
from drivers.errors import (
    InstrumentError,
    InstrumentTimeout,
    PartAbsent,
    PartSilent,
    StreamCorrupted,
)
from drivers.part_link import FixtureRefused, NoReply, SerialPartLink
from drivers.protocols import CalibrationRegisters
from tests.drivers._fixture_fake import FakeFixture

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def rig():
    made = []

    def build(*, rate_fps=2000.0, speed=1.0, **kw):
        fixture = FakeFixture(rate_fps=rate_fps)
        link = SerialPartLink.open(fixture.path, ScaledClock(speed), **kw)
        made.append((fixture, link))
        return fixture, link

    yield build
    for fixture, link in made:
        link.close()
        fixture.close()


def collect(link, until_n=None, wall_s=1.0):
    blocks = []
    t_end = time.monotonic() + wall_s
    while time.monotonic() < t_end:
        blocks.append(link.read_samples(max_wait_s=0.05))
        if until_n is not None and sum(len(b) for b in blocks) >= until_n:
            break
    return blocks


def test_commands_are_ascii_lines_and_replies_parse(rig):
    fixture, link = rig(reply_timeout_s=0.5)
    ident = link.identify()
    assert (ident.manufacturer, ident.model, ident.serial, ident.firmware) == (
        "TestCo", "FIX-8", "F001", "0.9")
    assert link.part_present() is True
    assert link.read_part_serial() == "SIM-0001"
    link.set_output_rate(200)
    link.set_compensation(True)
    assert link.stop_angle() == (90.13, 0.05)
    assert fixture.commands == [b"IDN?", b"PRESENT?", b"SN?", b"ODR 200", b"COMP 1", b"STOPANGLE?"]


def test_port_opens_at_the_given_baud_rate(rig):
    _, default = rig()
    _, fast = rig(baudrate=460_800)
    assert default._port.baudrate == 115_200
    assert fast._port.baudrate == 460_800
    assert fast.identify().model == "FIX-8"  # a pty carries it whatever the rate


def test_sample_stream_baud_is_frames_times_ten_bits():
    assert fp.sample_stream_baud(500) == 500 * 25 * 10 == 125_000  # above 115,200
    assert [fp.sample_stream_baud(r) for r in fp.OUTPUT_RATES_HZ] == [
        r * fp.SAMPLE_FRAME_SIZE * fp.UART_BITS_PER_BYTE for r in fp.OUTPUT_RATES_HZ
    ]


def test_unsupported_rate_is_refused_locally_and_by_the_fixture(rig):
    fixture, link = rig(reply_timeout_s=0.5)
    with pytest.raises(ValueError, match="not one of"):
        link.set_output_rate(300)
    assert fixture.commands == []
    with pytest.raises(FixtureRefused, match="ERR 2") as info:
        link.command("BOGUS")
    assert info.value.code == 2


def test_calibration_write_is_read_back(rig):
    fixture, link = rig(reply_timeout_s=0.5)
    regs = CalibrationRegisters(
        bias_dps=8.6, scale=1.0567, bias_tc_dps_per_c=0.0071, scale_tc_per_c=2.1e-4,
        bias_vc_dps_per_v=0.05, scale_vc_per_v=1e-3, t0_c=25.0, v0_v=5.0,
    )
    link.write_calibration(regs)
    assert fixture.commands[0] == (
        b"CAL bias=8.6 scale=1.0567 bias_tc=0.0071 scale_tc=0.00021 bias_vc=0.05 "
        b"scale_vc=0.001 t0=25 v0=5"
    )
    assert fixture.commands[1] == b"CAL?"
    assert link.read_calibration() == regs


def test_calibration_that_does_not_stick_is_reported(rig):
    fixture, link = rig(reply_timeout_s=0.5)
    fixture.cal_sticky_bias = 0.0
    with pytest.raises(InstrumentError, match="bias wrote 8.6 read 0"):
        link.write_calibration(CalibrationRegisters(bias_dps=8.6))


def test_absent_part_raises_part_absent(rig):
    fixture, link = rig(reply_timeout_s=0.5)
    fixture.part_present = False
    assert link.part_present() is False
    with pytest.raises(PartAbsent, match="seat a part"):
        link.read_part_serial()


def test_deaf_fixture_raises_no_reply_within_its_timeout(rig):
    fixture, link = rig(reply_timeout_s=0.2)
    fixture.deaf = True
    t0 = time.monotonic()
    with pytest.raises(NoReply) as info:
        link.read_part_serial()
    assert 0.2 <= time.monotonic() - t0 < 0.5
    assert isinstance(info.value, PartAbsent) and isinstance(info.value, InstrumentTimeout)


def test_stream_start_stop_delivers_every_frame_in_order(rig):
    fixture, link = rig(rate_fps=5000.0)
    link.start_stream()
    blocks = collect(link, wall_s=0.4)
    link.stop_stream()
    blocks.append(link.read_samples())
    seq = np.concatenate([b.seq for b in blocks])
    assert seq.size == fixture.sent > 1000
    np.testing.assert_array_equal(seq, np.arange(seq.size) % fp.SEQ_MODULO)
    assert sum(b.frames_lost for b in blocks) == 0
    t = np.concatenate([b.time_s for b in blocks])
    np.testing.assert_allclose(np.diff(t), 1e-3)
    stats = link.stats()
    assert (stats.frames_ok, stats.frames_lost, stats.frames_corrupted) == (seq.size, 0, 0)


def test_damaged_frames_are_counted_and_never_delivered(rig):
    fixture, link = rig(rate_fps=5000.0)
    size = fp.SAMPLE_FRAME_SIZE
    damaged: set[int] = set()

    def mangle(data: bytes, first: int) -> bytes:
        frames = bytearray(data)
        out = bytearray()
        for i in range(len(frames) // size):
            k = first + i
            frame = frames[i * size : (i + 1) * size]
            if k % 97 == 5:  # flip a payload bit
                frame[10] ^= 0x04
                damaged.add(k)
            elif k % 89 == 7:  # drop the frame
                damaged.add(k)
                continue
            elif k % 83 == 3:  # noise before an intact frame
                out += b"\x00\xa5\x13"
            out += frame
        return bytes(out)

    fixture.mangle = mangle
    link.start_stream()
    blocks = collect(link, wall_s=0.5)
    link.stop_stream()
    blocks.append(link.read_samples())
    seq = np.concatenate([b.seq for b in blocks])
    expected = np.array([k for k in range(fixture.sent) if k not in damaged])
    np.testing.assert_array_equal(seq, expected)
    # a frame lost after the last one delivered leaves no gap to see: not counted
    seen = {k for k in damaged if k < seq[-1]}
    assert sum(b.frames_lost for b in blocks) == len(seen)
    assert sum(b.frames_corrupted for b in blocks) in (
        sum(1 for k in seen if k % 97 == 5), sum(1 for k in damaged if k % 97 == 5))
    assert link.stats().frames_lost == len(seen)


def test_loss_limit_raises_stream_corrupted(rig):
    fixture, link = rig(rate_fps=5000.0, loss_limit=10)
    size = fp.SAMPLE_FRAME_SIZE
    fixture.mangle = lambda data, first: b"".join(
        data[i : i + size] for i in range(0, len(data), size) if (first + i // size) % 10
    )
    link.start_stream()
    with pytest.raises(StreamCorrupted, match="more than the 10 allowed"):
        collect(link, wall_s=1.0)


def test_silent_part_raises_part_silent_after_the_station_time_window(rig):
    # 0.5 station s at speed 10 is 0.05 wall s
    fixture, link = rig(rate_fps=2000.0, speed=10.0, silent_after_s=0.5)
    link.start_stream()
    assert len(collect(link, until_n=50, wall_s=1.0)) > 0
    fixture.go_silent = True
    t0 = time.monotonic()
    with pytest.raises(PartSilent, match="stopped sending"):
        collect(link, wall_s=2.0)
    assert time.monotonic() - t0 < 0.05 + 0.3


def _throughput_run(rates: list[float], wall_s: float = 1.5):
    """Stream from fixtures in another process (as the bench is) into links in this one."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen(
        [sys.executable, "-m", "tests.drivers._fixture_fake", *map(str, rates)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=REPO, env=env,
    )
    links = []
    try:
        paths = json.loads(proc.stdout.readline())
        links = [SerialPartLink.open(p, ScaledClock(1.0)) for p in paths]
        for link in links:
            link.start_stream()
        got = [0] * len(links)
        lost = [0] * len(links)
        cpu0 = time.process_time()
        t_end = time.monotonic() + wall_s
        while time.monotonic() < t_end:
            for i, link in enumerate(links):
                block = link.read_samples()
                got[i] += len(block)
                lost[i] += block.frames_lost
            time.sleep(0.01)
        for i, link in enumerate(links):
            link.stop_stream()
            block = link.read_samples()
            got[i] += len(block)
            lost[i] += block.frames_lost
        cpu_s = time.process_time() - cpu0
        proc.stdin.write("stats\n")
        proc.stdin.flush()
        sent, wall, _ = zip(*json.loads(proc.stdout.readline()), strict=True)
    finally:
        for link in links:
            link.close()
        proc.stdin.close()
        proc.wait(5)
    achieved = [s / w for s, w in zip(sent, wall, strict=True)]
    print(f"frames {sum(got)}, station CPU {cpu_s:.2f} s, rates {[round(a) for a in achieved]}")
    return got, list(sent), lost, achieved


def test_nine_fast_sockets_in_one_process_lose_no_frame():
    """8 sockets x 200 Hz x speed 25 and 1 socket x 1 kHz x speed 100, all in this process:
    every frame sent arrives, whatever the machine's load (the rate is the next test's)."""
    got, sent, lost, achieved = _throughput_run([5000.0] * 8 + [100_000.0])
    assert got == sent and lost == [0] * 9 and min(achieved) > 0


@pytest.mark.wallclock
def test_keeps_up_with_eight_sockets_at_5k_and_one_at_100k_frames_per_s():
    # 8 sockets x 200 Hz x speed 25 and 1 socket x 1 kHz x speed 100, all in this process;
    # a wall-clock rate, so not in the default run or CI (pytest -m wallclock, on an idle
    # machine); benchmarks/bench_stream.py measures the rates the bench and link sustain
    rates = [5000.0] * 8 + [100_000.0]
    for _attempt in range(3):
        got, sent, lost, achieved = _throughput_run(rates)
        assert got == sent and lost == [0] * len(rates)  # never a frame lost
        # a pty holds ~4 KB: a reader that falls behind holds its fixture's writes back (a
        # fixed 5 ms pause after small reads often settled near 40k frames/s). The machine is
        # shared, so a starved run is retried.
        if all(a >= 0.8 * r for a, r in zip(achieved, rates, strict=True)):
            return
    pytest.fail(f"fixtures held back in 3 attempts: {[round(a) for a in achieved]} frames/s")


def test_part_link_satisfies_the_protocol(rig):
    from drivers.protocols import PartLink

    _, link = rig()
    assert isinstance(link, PartLink)


def test_port_that_dies_raises_connection_lost(rig):
    from drivers.errors import ConnectionLost

    fixture, link = rig(reply_timeout_s=0.3)
    assert link.read_part_serial() == "SIM-0001"
    fixture.close()  # the fixture's end of the line goes away (cable pulled)
    t0 = time.monotonic()
    with pytest.raises(ConnectionLost, match="cable"):
        while time.monotonic() - t0 < 2.0:
            link.read_samples(max_wait_s=0.05)
    assert time.monotonic() - t0 < 1.0
