"""Chart helpers: ticks, decimation, log axes, robustness to bad data."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import assume, given
from hypothesis import strategies as st
from reportlab.graphics.shapes import PolyLine, Rect, String

from reports.charts import Chart, decimate, log_ticks, message_box, nice_ticks


@given(st.floats(-1e6, 1e6), st.floats(1e-6, 1e6))
def test_nice_ticks_cover_the_range_with_round_steps(lo: float, span: float) -> None:
    assume(span > 1e-9 * abs(lo))  # below that, float spacing itself is not round
    hi = lo + span
    ticks = nice_ticks(lo, hi)
    assert 2 <= len(ticks) <= 12
    assert all(lo - 1e-9 * span <= t <= hi + 1e-9 * span for t in ticks)
    step = ticks[1] - ticks[0]
    mant = step / 10 ** math.floor(math.log10(step))
    assert any(math.isclose(mant, m, rel_tol=1e-6) for m in (1, 2, 2.5, 5, 10))


def test_log_ticks_are_decades_inside_the_range() -> None:
    assert log_ticks(0.01, 1000) == [0.01, 0.1, 1, 10, 100, 1000]
    assert log_ticks(1, 10) == [1, 2, 5, 10]


def test_decimate_keeps_extremes_and_order() -> None:
    x = np.arange(100_000, dtype=float)
    y = np.sin(x / 1000)
    y[54_321] = 50.0  # a spike a naive stride would lose
    xs, ys = decimate(x, y, 400)
    assert xs.size <= 800
    assert ys.max() == 50.0 and ys.min() == y.min()
    assert np.all(np.diff(xs) > 0)


def test_lines_with_nan_and_log_axes_with_zeros_draw() -> None:
    ch = Chart(300, 150, title="t", log_x=True, log_y=True)
    ch.line([0.0, 1.0, 10.0, np.nan, 100.0], [1.0, 0.1, -1.0, 0.01, 0.001])
    d = ch.drawing()
    lines = [s for s in d.contents if isinstance(s, PolyLine)]
    assert lines and all(np.all(np.isfinite(pl.points)) for pl in lines)


def test_out_of_range_points_break_the_line_instead_of_sticking_to_the_frame() -> None:
    ch = Chart(300, 150, y_range=(-1.0, 1.0))
    ch.line([0, 1, 2, 3, 4, 5], [0, 0.5, 9, 9, 0.5, 0])
    lines = [s for s in ch.drawing().contents if isinstance(s, PolyLine)]
    assert len(lines) == 2


def test_shading_is_drawn_under_the_data() -> None:
    ch = Chart(300, 150)
    ch.line([0, 10], [0, 1], label="data")
    ch.shade_x(2, 4, label="window")
    contents = ch.drawing().contents
    i_rect = next(i for i, s in enumerate(contents) if isinstance(s, Rect) and s.width < 100)
    i_line = next(i for i, s in enumerate(contents) if isinstance(s, PolyLine))
    assert i_rect < i_line


def test_message_box_carries_the_reason() -> None:
    d = message_box(300, 100, "Allan", "Not drawn: analysis.allan missing.")
    assert "analysis.allan" in " ".join(s.text for s in d.contents if isinstance(s, String))


def test_rate_table_residual_line_runs_in_input_rate_order_per_condition() -> None:
    from reports.cert_plots import rate_table_charts
    from reports.record_keys import RatePoints

    rin = [0.0, 100.0, -100.0, 300.0, -300.0, 100.0]  # procedure order, one rate repeated
    resid = [0.001, 0.002, -0.002, 0.004, -0.004, 0.003]
    points = [RatePoints(c, rin, [r * 1.02 for r in rin], resid, 1.02, 0.0)
              for c in ("T25_V4.75", "T45_V5.25")]
    _left, right = rate_table_charts(points)
    lines = [s for s in right._series if s.kind == "line"]
    assert len(lines) == 2  # one per condition, not one joining both
    for s in lines:
        assert list(s.xs) == sorted(rin)
        # each residual stays with its own input rate
        pairs = sorted(zip(rin, resid, strict=True), key=lambda p: p[0])
        assert list(zip(s.xs, s.ys, strict=True)) == pairs
