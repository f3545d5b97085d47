from __future__ import annotations

from pathlib import Path

import numpy as np

from common.clock import ScaledClock
from drivers.fixture_protocol import rate_dps_to_code, temp_c_to_code
from drivers.protocols import SampleBlock
from procedures.runtime.rawdata import RawDataWriter, read_raw
from procedures.runtime.streams import FIXTURE_WRAP_S, PartStream


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


def block(t: np.ndarray, rate: float) -> SampleBlock:
    n = t.size
    return SampleBlock(
        np.arange(n),
        t,
        rate_dps_to_code(np.full(n, rate)),
        temp_c_to_code(np.full(n, 30.0)),
        np.zeros(n, dtype=np.int64),
    )


def test_stream_keeps_one_time_base_across_a_wrap_and_writes_raw(tmp_path: Path) -> None:
    link = FakeLink()
    writer = RawDataWriter(tmp_path / "raw.h5", {"serial": "X"})
    stream = PartStream(1, link, ScaledClock(1.0), writer)  # type: ignore[arg-type]
    stream.start()
    t1 = np.arange(4290.0, 4294.0, 0.01)
    link.blocks.append(block(t1, 10.0))
    assert stream.poll() == t1.size
    stream.stop()
    # the link restarted and its timestamps wrapped at 2^32 us
    stream.start()
    t2 = np.arange(4296.0, 4298.0, 0.01) - FIXTURE_WRAP_S
    link.blocks.append(block(t2, -5.0))
    assert stream.poll() == t2.size
    w = stream.window(4295.0, 4300.0)
    assert w["time_s"].size == t2.size
    assert np.allclose(w["rate_dps"], -5.0, atol=1e-4) and np.allclose(w["temp_c"], 30.0, atol=1e-3)
    stream.stop()
    writer.close()
    raw = read_raw(tmp_path / "raw.h5")
    assert raw["samples"]["time_s"].size == t1.size + t2.size
    assert np.all(np.diff(raw["samples"]["time_s"]) > 0)


def test_offset_maps_station_to_fixture_time() -> None:
    link = FakeLink()
    clock = ScaledClock(1.0)
    stream = PartStream(1, link, clock)  # type: ignore[arg-type]
    stream.start()
    now = clock.now_s()
    link.blocks.append(
        block(np.arange(-1.0, 0.0, 0.01) + 100.01 + now, 0.0)
    )  # fixture = station + 100
    stream.poll()
    assert abs(stream.fixture_time(now + 5.0) - (now + 105.0)) < 0.05


def test_a_lost_stream_is_named_by_its_cause() -> None:
    """Frames with a bad CRC: corrupted; none: dropped on the way (the operator checks the
    cable either way, but the record says which)."""
    from types import SimpleNamespace

    from procedures.runtime.run_context import _stream_loss_reason

    dropped = SimpleNamespace(frames_lost=40, frames_ok=960, frames_corrupted=0)
    corrupted = SimpleNamespace(frames_lost=40, frames_ok=960, frames_corrupted=12)
    drop_text = _stream_loss_reason(3, dropped, 0.001)  # type: ignore[arg-type]
    corrupt_text = _stream_loss_reason(3, corrupted, 0.001)  # type: ignore[arg-type]
    assert drop_text.startswith("socket 3: stream losing frames: 40 of 1000 frames lost (0 ")
    assert corrupt_text.startswith("socket 3: stream corrupted: 40 of 1000 frames lost (12 ")
    assert "0.001 allowed" in drop_text
