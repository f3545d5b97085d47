"""A run folder from a real (simulated-bench) station run, replayed: the replay reads the
station's own raw.h5, gives back every sample as recorded, and its compensation with the
registers the station programmed removes the part's bias as the part itself did."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivers.part_codes import ADIS16130
from drivers.protocols import CalibrationRegisters, SampleStatus
from drivers.replay_part import RecordingEnded, factory
from procedures.runtime.rawdata import read_raw
from procedures.runtime.record import Verdict, read_record
from tests.drivers.test_replay_part import FakeClock
from tests.procedures.conftest import DATA, run_on_bench


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    run = run_on_bench(out, [{"socket": 1, "serial": "SIM-0731"}], speed=150,
                       procedure=DATA / "stop_short.yaml")
    folder = run.result.folders[1]
    assert read_record(folder).verdict is Verdict.PASS
    return folder


def play_all(link, clock: FakeClock, step_s: float = 7.3):
    blocks = []
    link.start_stream()
    while True:
        clock.advance(step_s)
        try:
            blocks.append(link.read_samples())
        except RecordingEnded:
            return blocks


def test_a_station_run_folder_replays_sample_for_sample(run_folder: Path) -> None:
    raw = read_raw(run_folder / "raw.h5")["samples"]
    clock = FakeClock()
    link = factory({"address": str(run_folder), "socket": 1})
    link.attach_clock(clock)
    assert link.read_part_serial() == "SIM-0731"
    blocks = play_all(link, clock)
    for name, column in (("seq", "seq"), ("time_s", "time_s"), ("rate_code", "rate_code"),
                         ("temp_code", "temp_code"), ("status", "status"),
                         ("encoder_counts", "encoder_counts")):
        got = np.concatenate([getattr(b, name) for b in blocks])
        assert np.array_equal(got, raw[column]), name
    # the encoder was latched on the bench, and the replay keeps it
    assert np.all(raw["status"] & SampleStatus.ENCODER_LATCHED)


def test_replayed_compensation_removes_the_bias_the_station_fitted(run_folder: Path) -> None:
    record = read_record(run_folder)
    assert record.calibration is not None and record.calibration.readback
    registers = CalibrationRegisters(**record.calibration.readback)
    data = read_raw(run_folder / "raw.h5")
    samples = data["samples"]
    first_static = next(
        i for i, kind in enumerate(data["segments"]["kind"]) if kind == "static"
    )
    start_s = data["segments"]["start_s"][first_static]
    end_s = data["segments"]["end_s"][first_static]
    clock = FakeClock()
    link = factory({"address": str(run_folder)})
    link.attach_clock(clock)
    link.write_calibration(registers)
    link.set_compensation(True)
    blocks = play_all(link, clock)
    time_s = np.concatenate([b.time_s for b in blocks])
    rate_dps = ADIS16130.rate_code_to_dps(np.concatenate([b.rate_code for b in blocks]))
    at_rest = (time_s >= start_s) & (time_s <= end_s)
    assert at_rest.sum() > 100
    raw_bias_dps = float(np.mean(samples["rate_dps"][at_rest]))
    compensated_dps = float(np.mean(rate_dps[at_rest]))
    assert abs(raw_bias_dps) > 0.05  # the part had a bias to remove
    assert abs(compensated_dps) < 0.05  # the product's residual-bias limit
