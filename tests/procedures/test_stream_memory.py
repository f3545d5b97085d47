"""Bounded memory: a stream keeps only its newest samples; older windows come back from raw.h5."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from common.clock import ScaledClock
from drivers.fixture_protocol import rate_dps_to_code, temp_c_to_code
from drivers.protocols import SampleBlock
from procedures.runtime.rawdata import RawDataWriter
from procedures.runtime.streams import PartStream


class FakeLink:
    def __init__(self) -> None:
        self.blocks: list[SampleBlock] = []

    def start_stream(self) -> None: ...

    def stop_stream(self) -> None: ...

    def read_samples(self, max_wait_s: float = 0.0) -> SampleBlock:
        if self.blocks:
            return self.blocks.pop(0)
        e = np.zeros(0, dtype=np.int64)
        return SampleBlock(e, np.zeros(0), e, e, e)


def ramp_block(first: int, n: int, rate_hz: float) -> SampleBlock:
    """Samples first..first+n-1 whose rate is the sample index (each window is checkable)."""
    k = np.arange(first, first + n)
    return SampleBlock(
        k % 65536,
        k / rate_hz,
        rate_dps_to_code(np.clip(k * 1e-3, -200.0, 200.0)),
        temp_c_to_code(np.full(n, 25.0)),
        np.zeros(n, dtype=np.int64),
        encoder_counts=k.astype(np.int64),
    )


def feed(stream: PartStream, link: FakeLink, blocks: int, per_block: int, rate_hz: float) -> None:
    for b in range(blocks):
        link.blocks.append(ramp_block(b * per_block, per_block, rate_hz))
        assert stream.poll() == per_block


@pytest.mark.parametrize("keep", [1000, 4096])
def test_memory_stays_fixed_and_old_windows_come_back_from_the_raw_file(
    tmp_path: Path, keep: int
) -> None:
    link = FakeLink()
    writer = RawDataWriter(tmp_path / "raw.h5", {"serial": "X"})
    stream = PartStream(1, link, ScaledClock(1.0), writer, keep_samples=keep)  # type: ignore[arg-type]
    stream.start()
    rate_hz = 1000.0
    feed(stream, link, blocks=60, per_block=700, rate_hz=rate_hz)  # 42000 samples, 42 s
    assert keep <= stream.n_samples <= 2 * keep  # memory holds a fixed number, not the run
    # a window long gone from memory: read back, every column as it was taken
    old = stream.window(1.0, 3.0)
    assert old["time_s"].size == 2000
    assert old["time_s"].dtype == np.float64 and old["status"].dtype == np.int64
    assert old["encoder_counts"][0] == 1000 and old["encoder_counts"][-1] == 2999
    assert np.allclose(old["rate_dps"], np.arange(1000, 3000) * 1e-3, atol=2e-3)
    # a recent window comes from memory and reads the same as the file would
    recent = stream.window(41.5, 42.0)
    assert recent["encoder_counts"][0] == 41500 and recent["time_s"].size == 500
    # a window spanning both: whole and in order
    both = stream.window(40.0 - keep / rate_hz, 42.0)
    assert np.all(np.diff(both["encoder_counts"]) == 1)
    assert both["time_s"].size == 2000 + keep
    stream.stop()
    writer.close()
    with h5py.File(tmp_path / "raw.h5", "r") as f:
        assert f["samples/time_s"].shape[0] == 42000  # everything on disk


def test_without_a_raw_file_the_stream_keeps_every_sample() -> None:
    link = FakeLink()
    stream = PartStream(1, link, ScaledClock(1.0), None, keep_samples=500)  # type: ignore[arg-type]
    stream.start()
    feed(stream, link, blocks=10, per_block=300, rate_hz=100.0)
    assert stream.n_samples == 3000
    assert stream.window(0.0, 1.0)["time_s"].size == 100


def test_read_window_finds_the_rows_of_a_sorted_column(tmp_path: Path) -> None:
    writer = RawDataWriter(tmp_path / "raw.h5", {"serial": "X"})
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.001, 0.01, 30000))
    zeros = np.zeros(t.size)
    writer.append(
        "chamber", station_time_s=t, setpoint_c=zeros, temp_c=np.arange(t.size, dtype=float)
    )
    for start, end in [(t[0] - 1, t[5]), (t[100], t[20000]), (t[-3], t[-1] + 1), (5e9, 6e9)]:
        got = writer.read_window("chamber", "station_time_s", start, end)
        want = (t >= start) & (t < end)
        assert np.array_equal(got["temp_c"], np.flatnonzero(want).astype(float))
    writer.close()
