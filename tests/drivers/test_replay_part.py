"""Part driver `replay`: a recorded raw.h5 or CSV played back as a live part, paced by the
station clock (a fake one here), with in-memory calibration registers and compensation."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from common.clock import LockstepClock
from drivers import fixture_protocol as fp
from drivers.errors import ConnectionLost, PartSilent
from drivers.part_codes import ADIS16130, CodeFormat
from drivers.part_link import FixtureRefused
from drivers.protocols import CalibrationRegisters, PartLink
from drivers.replay_part import RecordingEnded, ReplayPartLink, factory
from drivers.replay_source import RAW_FORMAT, RecordingError
from procedures.runtime.rawdata import FORMAT, RawDataWriter
from procedures.runtime.streams import PartStream

PERIOD_S = 0.01
N = 300
T0_S = 1000.0  # fixture time of the first recorded sample


class FakeClock:
    """Station time that moves only when told to (or when someone sleeps)."""

    speed = 1.0

    def __init__(self, t_s: float = 50.0) -> None:
        self.t_s = t_s

    def now_s(self) -> float:
        return self.t_s

    def sleep_s(self, duration_s: float) -> None:
        self.t_s += max(0.0, duration_s)

    def wall_timeout_s(self, duration_s: float) -> float:
        return duration_s

    def advance(self, duration_s: float) -> None:
        self.t_s += duration_s


def recorded(n: int = N) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(11)
    k = np.arange(n)
    rate_code = ADIS16130.rate_dps_to_code(20.0 * np.sin(k / 30.0) + rng.normal(0, 0.1, n))
    temp_code = ADIS16130.temp_c_to_code(30.0 + 0.01 * k)
    status = np.full(n, int(fp.SampleStatus.ENCODER_LATCHED))
    time_s = T0_S + k * PERIOD_S
    time_s[200:] += 0.5  # the original stream was stopped for half a second here
    return {
        "time_s": time_s,
        "seq": (k + 7) % 65536,
        "rate_code": rate_code,
        "temp_code": temp_code,
        "status": status,
        "rate_dps": ADIS16130.rate_code_to_dps(rate_code),
        "temp_c": ADIS16130.temp_code_to_c(temp_code),
        "station_time_s": time_s - 900.0,
        "encoder_counts": (k * 1000 - 50_000) % (1 << 32),
    }


@pytest.fixture
def run_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "2026-11-20T10-00-00Z_SIM-0042"
    folder.mkdir()
    with RawDataWriter(folder / "raw.h5", {"serial": "SIM-0042", "run_id": folder.name}) as w:
        w.append("samples", **recorded())
        # the supply was at 5 V, then 4.5 V from station time 101.5 s (sample 150)
        w.append("supply", station_time_s=[0.0, 101.499, 101.5, 500.0],
                 voltage_v=[5.0, 5.0, 4.5, 4.5], current_a=[0.01] * 4)
    return folder


def open_replay(path: Path, clock: FakeClock, **settings) -> ReplayPartLink:
    link = factory({"path": str(path), **settings})
    link.attach_clock(clock)
    return link


def concat(blocks) -> dict[str, np.ndarray]:
    names = ("seq", "time_s", "rate_code", "temp_code", "status", "encoder_counts")
    return {n: np.concatenate([getattr(b, n) for b in blocks]) for n in names}


def test_a_run_folder_replays_with_the_recorded_codes_times_and_identity(run_folder):
    clock = FakeClock()
    link = open_replay(run_folder, clock, stop_angle_deg=89.95)
    assert isinstance(link, PartLink)
    assert link.read_part_serial() == "SIM-0042" and link.part_present()
    ident = link.identify()
    assert (ident.model, ident.serial) == ("replay", run_folder.name)
    assert link.stop_angle() == (89.95, 0.01)
    link.set_output_rate(100)
    link.start_stream()
    blocks = []
    while True:
        clock.advance(0.037)
        try:
            blocks.append(link.read_samples())
        except RecordingEnded:
            break
    got, want = concat(blocks), recorded()
    for name in ("seq", "time_s", "rate_code", "temp_code", "status"):
        assert np.array_equal(got[name], want[name]), name
    assert np.array_equal(got["encoder_counts"], want["encoder_counts"])
    assert link.stats().frames_ok == N


def test_samples_are_due_by_the_station_clock_from_stream_start(run_folder):
    clock = FakeClock(50.0)
    link = open_replay(run_folder, clock)
    link.start_stream()  # sample 0 is due one period after START
    assert len(link.read_samples()) == 0
    clock.advance(PERIOD_S * 0.999)
    assert len(link.read_samples()) == 0
    clock.advance(PERIOD_S * 0.002)
    first = link.read_samples()
    assert first.seq.tolist() == [7] and first.time_s[0] == T0_S
    clock.advance(1.0)  # 100 more periods
    assert len(link.read_samples()) == 100
    # the recorded 0.5 s gap is played as silence
    clock.advance(0.99)  # up to sample 199
    assert link.read_samples().seq[-1] == 199 + 7
    clock.advance(0.49)
    assert len(link.read_samples()) == 0
    clock.advance(0.02)
    assert link.read_samples().seq.tolist() == [200 + 7]


def test_read_samples_waits_on_the_station_clock(run_folder):
    clock = FakeClock(10.0)
    link = open_replay(run_folder, clock)
    link.start_stream()
    block = link.read_samples(max_wait_s=1.0)  # sleeps (fake) until sample 0 is due
    assert len(block) == 1 and clock.now_s() == pytest.approx(10.0 + PERIOD_S)
    block = link.read_samples(max_wait_s=0.002)  # not long enough for the next one
    assert len(block) == 0 and clock.now_s() == pytest.approx(10.0 + PERIOD_S + 0.002)


def test_in_lockstep_a_read_never_moves_station_time(run_folder):
    """Only the station's own waits step a lockstep clock: a read that waits for frames
    (the acquisition's catch-up, itself called from the clock's step) returns what is due."""
    steps: list[float] = []
    clock = LockstepClock(lambda t_s: steps.append(t_s) or {})
    clock.start_at(10.0)
    link = open_replay(run_folder, clock)
    link.start_stream()
    wall0 = time.monotonic()
    assert len(link.read_samples(max_wait_s=1.0)) == 0
    assert time.monotonic() - wall0 < 0.5 and steps == [] and clock.now_s() == 10.0
    clock.sleep_s(PERIOD_S * 1.5)  # the station waits: sample 0 comes due
    assert steps == [pytest.approx(10.0 + PERIOD_S * 1.5)]
    assert link.read_samples(max_wait_s=1.0).seq.tolist() == [7]
    assert len(steps) == 1


def test_stop_then_start_resumes_with_the_fixture_clock_running_on(run_folder):
    clock = FakeClock()
    link = open_replay(run_folder, clock)
    link.start_stream()
    clock.advance(0.505)
    link.stop_stream()  # what was due before STOP is still delivered
    before = link.read_samples()
    assert len(before) == 50
    clock.advance(3.0)
    assert len(link.read_samples()) == 0  # stopped: nothing
    link.start_stream()
    clock.advance(PERIOD_S)
    after = link.read_samples()
    assert after.seq.tolist() == [50 + 7]  # the recording goes on where it stopped
    # and its fixture time goes on with the station clock (3 s later), as a real fixture's
    assert after.time_s[0] - before.time_s[-1] == pytest.approx(3.0 + 0.005 + PERIOD_S, abs=1e-9)
    assert after.rate_code[0] == recorded()["rate_code"][50]


def test_the_end_of_the_recording_is_a_clear_silence_unless_it_loops(run_folder):
    clock = FakeClock()
    link = open_replay(run_folder, clock)
    link.start_stream()
    clock.advance(10.0)
    assert len(link.read_samples()) == N
    with pytest.raises(RecordingEnded, match="loop: true") as info:
        link.read_samples()
    assert isinstance(info.value, PartSilent)
    looped = open_replay(run_folder, clock, loop=True)
    looped.start_stream()
    clock.advance(2 * 3.5 + PERIOD_S / 2)  # twice the recording (3.49 s and a period)
    block = looped.read_samples()
    assert len(block) == 2 * N
    assert np.array_equal(block.rate_code[N:], block.rate_code[:N])
    assert np.all(np.diff(block.time_s) > 0)
    assert block.time_s[N] - block.time_s[N - 1] == pytest.approx(PERIOD_S)


def test_calibration_registers_and_compensation_work_like_the_part(run_folder):
    clock = FakeClock()
    link = open_replay(run_folder, clock)
    assert link.read_calibration() == CalibrationRegisters()
    regs = CalibrationRegisters(bias_dps=1.5, scale=1.02, bias_tc_dps_per_c=0.01,
                                scale_tc_per_c=1e-4, bias_vc_dps_per_v=0.2, t0_c=25.0, v0_v=5.0)
    link.write_calibration(regs)
    assert link.read_calibration() == regs
    with pytest.raises(FixtureRefused, match="scale"):
        link.write_calibration(replace(regs, scale=2.5))
    assert link.read_calibration() == regs  # a refused write changes nothing
    link.set_compensation(True)
    link.start_stream()
    clock.advance(10.0)
    block = link.read_samples()
    want = recorded()
    temp_c = ADIS16130.temp_code_to_c(want["temp_code"])
    supply_v = np.where(np.arange(N) < 150, 5.0, 4.5)  # from the recorded supply log
    bias = 1.5 + 0.01 * (temp_c - 25.0) + 0.2 * (supply_v - 5.0)
    scale = 1.02 * (1 + 1e-4 * (temp_c - 25.0))
    expected = ADIS16130.rate_dps_to_code((want["rate_dps"] - bias) / scale)
    assert np.array_equal(block.rate_code, expected)
    assert np.all(block.status & fp.SampleStatus.COMPENSATED)
    assert np.array_equal(block.temp_code, want["temp_code"])


def test_the_acquisition_reads_a_replay_like_a_fixture(run_folder):
    clock = FakeClock()
    stream = PartStream(1, open_replay(run_folder, clock), clock)  # type: ignore[arg-type]
    stream.start()
    clock.advance(10.0)
    assert stream.poll() == N
    w = stream.window(0.0, 1e6)
    assert np.array_equal(w["rate_dps"], recorded()["rate_dps"])
    assert np.array_equal(w["time_s"], recorded()["time_s"])


def _csv(path: Path, rows: list[str]) -> Path:
    path.write_text("\n".join(rows) + "\n")
    return path


def test_a_csv_replays_converted_with_the_product_codes(tmp_path):
    codes = {"rate_width_bits": 16, "rate_signed": True, "rate_zero_code": 0,
             "rate_counts_per_dps": 80.0, "temp_zero_code": 0, "temp_zero_c": 25.0,
             "temp_signed": True, "temp_width_bits": 16, "temp_counts_per_c": 16.0}
    fmt = CodeFormat(**codes)
    rate = [0.0, -10.5, 99.9, -250.0]
    temp = [25.0, 30.0, 20.5, -10.0]
    path = _csv(tmp_path / "part-7.csv", ["time_s,rate_dps,temp_c,supply_v,note"] + [
        f"{0.005 * i},{r},{t},{4.0 + i},x" for i, (r, t) in enumerate(zip(rate, temp, strict=True))
    ])
    clock = FakeClock()
    link = open_replay(path, clock, codes=codes)
    assert link.read_part_serial() == "part-7" and link.identify().firmware == "csv"
    link.write_calibration(CalibrationRegisters(bias_vc_dps_per_v=1.0, v0_v=5.0))
    link.start_stream()
    clock.advance(0.02)
    raw = link.read_samples()
    assert raw.time_s.tolist() == [0.0, 0.005, 0.01, 0.015]
    assert np.allclose(fmt.rate_code_to_dps(raw.rate_code), rate, atol=0.5 / 80)
    assert np.allclose(fmt.temp_code_to_c(raw.temp_code), temp, atol=0.5 / 16)
    assert not np.allclose(ADIS16130.rate_code_to_dps(raw.rate_code), rate, atol=1)
    # compensation takes the supply from the CSV's supply_v column
    named = open_replay(path, clock, codes=codes, serial="SIM-0007", loop=True)
    assert named.read_part_serial() == "SIM-0007"
    named.write_calibration(CalibrationRegisters(bias_vc_dps_per_v=1.0, v0_v=5.0))
    named.set_compensation(True)
    named.start_stream()
    clock.advance(0.02)
    comp = fmt.rate_code_to_dps(named.read_samples().rate_code)
    assert np.allclose(comp, np.array(rate) - (np.arange(4) + 4.0 - 5.0), atol=1 / 80)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda d: d / "nothing-here.h5", r"nothing-here\.h5: no such file"),
        (lambda d: d, r"no raw\.h5 in this folder"),
        (lambda d: _csv(d / "x.txt", ["a"]), r"x\.txt: not a recording"),
        (lambda d: _csv(d / "x.h5", ["not hdf5"]), r"x\.h5: raw data file cannot be read"),
        (lambda d: _csv(d / "x.csv", [""]), r"x\.csv: empty CSV"),
        (lambda d: _csv(d / "x.csv", ["time_s,rate_dps"]), r"lacks temp_c"),
        (lambda d: _csv(d / "x.csv", ["time_s,rate_dps,temp_c"]), r"header but no samples"),
        (lambda d: _csv(d / "x.csv", ["time_s,rate_dps,temp_c", "0,1,2", "0.01,fast,2"]),
         r"x\.csv:3: rate_dps is 'fast', not a number"),
        (lambda d: _csv(d / "x.csv", ["time_s,rate_dps,temp_c", "0,1,2", "0.01,1,nan"]),
         r"x\.csv:3: temp_c is 'nan', not a finite number"),
        (lambda d: _csv(d / "x.csv", ["time_s,rate_dps,temp_c", "0,1,2", "0,1,2"]),
         r"time_s does not increase at sample 1"),
    ],
)
def test_a_missing_or_invalid_recording_is_a_clear_error(tmp_path, make, message):
    path = make(tmp_path)
    with pytest.raises(RecordingError, match=message) as info:
        factory({"path": str(path)})
    assert isinstance(info.value, ConnectionLost)


def test_a_raw_file_of_another_format_or_code_format_is_refused(tmp_path, run_folder):
    other = tmp_path / "other.h5"
    with RawDataWriter(other, {"format": "something-else/2"}):
        pass
    with pytest.raises(RecordingError, match="not a raw data file of format gyrocal-raw/1"):
        factory({"path": str(other)})
    with pytest.raises(RecordingError, match="give the replay the `codes:` of the product"):
        factory({"path": str(run_folder), "codes": {"rate_counts_per_dps": 20000.0}})


def test_settings_are_checked(run_folder):
    with pytest.raises(ValidationError, match="baud"):
        factory({"path": str(run_folder), "baud": 9600})
    with pytest.raises(ValidationError, match="stop_angle_deg"):
        factory({"path": str(run_folder), "stop_angle_deg": float("nan")})
    with pytest.raises(ValidationError, match="no recording to replay"):
        factory({"socket": 2})


def test_the_station_gives_each_socket_its_recording_as_its_address(run_folder, tmp_path):
    csv_path = _csv(tmp_path / "part-9.csv", ["time_s,rate_dps,temp_c", "0,1,25", "0.01,2,25"])
    # what the station hands the part driver: the socket's `ports` entry and its number
    by_address = factory({"address": str(run_folder), "socket": 2})
    assert by_address.read_part_serial() == "SIM-0042" and "socket 2" in by_address.name
    assert by_address.probe() == ""
    # `path` wins over the address (the bench gives its own port to a configured driver)
    by_path = factory({"address": "/dev/pts/7", "socket": 1, "path": str(csv_path)})
    assert by_path.read_part_serial() == "part-9"


def test_a_closed_replay_says_so_and_rates_are_checked(run_folder):
    link = open_replay(run_folder, FakeClock())
    with pytest.raises(ValueError, match="not one of"):
        link.set_output_rate(123)
    link.start_stream()
    with pytest.raises(FixtureRefused, match="stop streaming first"):
        link.set_output_rate(100)
    link.close()
    with pytest.raises(ConnectionLost, match="closed"):
        link.read_samples()
    with pytest.raises(ConnectionLost, match="closed"):
        link.probe()


def test_the_replay_reads_the_format_procedures_write():
    assert RAW_FORMAT == FORMAT
