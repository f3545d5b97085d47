"""A three-axis part's stream: decoded x, y, z gyro and accelerometer columns in windows."""

from __future__ import annotations

import numpy as np

from common.clock import ScaledClock
from drivers.part_codes import CodeFormat
from drivers.protocols import SampleBlock
from procedures.runtime.streams import XYZ_COLUMNS, PartStream
from tests.procedures.test_streams import FakeLink, block

CODES = CodeFormat()


def block3(t: np.ndarray, rate_dps: tuple[float, float, float],
           accel_mps2: tuple[float, float, float]) -> SampleBlock:
    n = t.size
    rate = np.column_stack([CODES.rate_dps_to_code(np.full(n, r)) for r in rate_dps])
    acc = np.column_stack([CODES.accel_mps2_to_code(np.full(n, a)) for a in accel_mps2])
    single = block(t, rate_dps[0])
    return SampleBlock(single.seq, t, rate[:, 0], single.temp_code, single.status,
                       rate_code_xyz=rate, accel_code_xyz=acc)


def test_three_axis_window_carries_xyz_and_single_axis_does_not() -> None:
    link = FakeLink()
    stream = PartStream(1, link, ScaledClock(1.0), codes=CODES)  # type: ignore[arg-type]
    stream.start()
    link.blocks.append(block3(np.arange(0.0, 1.0, 0.01), (1.5, -2.0, 30.0), (0.0, 0.2, 9.8)))
    link.blocks.append(block(np.arange(1.0, 1.5, 0.01), 7.0))  # a single-axis frame among them
    stream.poll()
    stream.poll()
    w = stream.window(0.0, 2.0)
    assert set(XYZ_COLUMNS) <= set(w)
    assert np.allclose(w["rate_y_dps"][:100], -2.0, atol=1e-4)
    assert np.allclose(w["accel_z_mps2"][:100], 9.8, atol=1e-4)
    assert np.all(np.isnan(w["rate_z_dps"][100:]))
    assert np.allclose(w["rate_dps"][:100], w["rate_x_dps"][:100])

    plain = PartStream(2, FakeLink(), ScaledClock(1.0))  # type: ignore[arg-type]
    plain.link.blocks.append(block(np.arange(0.0, 1.0, 0.01), 3.0))  # type: ignore[attr-defined]
    plain.start()
    plain.poll()
    assert not set(XYZ_COLUMNS) & set(plain.window(0.0, 2.0))
